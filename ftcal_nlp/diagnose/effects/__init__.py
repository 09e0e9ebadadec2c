"""The effect library (issue 7): every canonical effect of ``OUTPUT_FORMAT.md`` as one plug-in
with an injector (simulator face) and an augmentation of the calibration model (model face).

``LIBRARY`` is a plain dict, canonical name -> :class:`~.base.Effect`. Importing
this module registers every injector class in :data:`ftcal_nlp.sim.effects.EFFECTS`,
so that ``SimConfig.from_dict({"effects": ["tether_force"]})`` and
``make_effects([{"name": "tether_force", "scale": 1.5, "seed": 3}])`` resolve the
names (the keyword arguments are ``scale`` in the effect's unit and ``seed``).
"""

from __future__ import annotations

from ...sim.effects import EFFECTS, LIBRARY_EFFECTS
from .base import (
    AugContext,
    Effect,
    EffectInjector,
    HangingLeg,
    Magnitude,
    ParamBlock,
    PoseSym,
)
from .body import LegInertia, MocapBias, MovingCom, RobotMass, TetherForce, design_check
from .sensor import (
    CasingLoad,
    ChassisFlex,
    GainCrosstalk,
    Hysteresis,
    OffsetDrift,
    SensorNonlinearity,
)

LIBRARY: dict[str, Effect] = {
    e.name: e
    for e in (
        OffsetDrift(), GainCrosstalk(), CasingLoad(), MocapBias(), ChassisFlex(), TetherForce(),
        Hysteresis(), LegInertia(), RobotMass(), SensorNonlinearity(), MovingCom(),
    )
}

if set(LIBRARY) != set(LIBRARY_EFFECTS):  # the contract's names and ours must not drift apart
    raise RuntimeError(f"effect library {sorted(LIBRARY)} differs from OUTPUT_FORMAT.md's {sorted(LIBRARY_EFFECTS)}")

for _name, _effect in LIBRARY.items():
    EFFECTS.setdefault(_name, _effect.injector_cls)


def resolve_effects(names) -> list[Effect]:
    """Effects by canonical name (None: the whole library); unknown names list the known ones."""
    if names is None:
        return list(LIBRARY.values())
    out = []
    for n in names:
        if n not in LIBRARY:
            raise ValueError(f"unknown effect {n!r}; known effects: {sorted(LIBRARY)}")
        out.append(LIBRARY[n])
    return out


__all__ = [
    "LIBRARY",
    "AugContext",
    "Effect",
    "EffectInjector",
    "HangingLeg",
    "Magnitude",
    "ParamBlock",
    "PoseSym",
    "design_check",
    "resolve_effects",
]
