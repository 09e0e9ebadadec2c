"""The effect library (issue 7): every canonical effect of ``OUTPUT_FORMAT.md`` as one plug-in
with an injector (simulator face) and an augmentation of the calibration model (model face).

``LIBRARY`` is a plain dict, canonical name -> :class:`~.base.Effect`. This package
holds the model faces (``base``: what an effect is; ``sensor``, ``body``: the
augmentations). The injectors, their base :class:`EffectInjector` and sizes
:class:`Magnitude` live in the simulator (:mod:`ftcal_nlp.sim.injectors`, re-exported
here) and are registered in :data:`ftcal_nlp.sim.effects.EFFECTS` when
:mod:`ftcal_nlp.sim` is imported, so that ``SimConfig.from_dict({"effects":
["tether_force"]})`` and ``make_effects([{"name": "tether_force", "scale": 1.5,
"seed": 3}])`` resolve the names without the diagnosis (the keyword arguments are
``scale`` in the effect's unit and ``seed``). Each :class:`Effect` names its
injector class (``injector_cls``) and takes its ``magnitude`` from it.
"""

from __future__ import annotations

from ...sim.effects import EFFECTS, LIBRARY_EFFECTS  # noqa: F401  (EFFECTS: kept importable from here)
from ...sim.injectors import INJECTORS
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

for _name, _effect in LIBRARY.items():  # each model face is paired with the simulator's injector of its name
    if _effect.injector_cls is not INJECTORS[_name] or _effect.magnitude is not INJECTORS[_name].magnitude:
        raise RuntimeError(f"effect {_name!r}: injector or magnitude differs from ftcal_nlp.sim.injectors")


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
