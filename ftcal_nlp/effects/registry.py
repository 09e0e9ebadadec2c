"""The effect registry: the contract's names, one unit module each, in a plain dict.

``LIBRARY_EFFECTS`` is the contract's name list (``OUTPUT_FORMAT.md``: the effects the
diagnosis may name, in this order). Each name has its unit, the module
``ftcal_nlp/effects/<name>.py``, whose ``EFFECT`` (an :class:`~.unit.Effect`) declares
the effect's kind, injector, model faces, correction and off-face shapes; ``EFFECTS``
maps the names to those units. Adding an effect: write its unit and add its name here.

Everything that needs effects (the simulator's injector names, the diagnosis' candidates,
``correction.py``, detection sizes, the validation sweep) reads this dict, or a copy
of it passed as ``registry`` (a toy effect in a test: ``with_units(ToyEffect())``).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping

from ..core.errors import ConfigError
from .injection import EXPECT_NONE, EXPECT_UNEXPLAINED, EffectInjector, OffFaceInjector
from .unit import EFFECT_KINDS, Effect

LIBRARY_EFFECTS = (
    "offset_drift", "gain_crosstalk", "casing_load", "mocap_bias", "chassis_flex", "tether_force",
    "hysteresis", "leg_inertia", "robot_mass", "sensor_nonlinearity", "moving_com",
    "clock_offset", "creep", "inertial_load", "joint_limit_contact", "temperature",
)


def check_unit(unit: Effect, name: str | None = None) -> Effect:
    """``unit`` if it declares a consistent effect (its name, kind, injector and shapes); else a TypeError naming it."""
    where = f"effect unit {name or unit.name!r}"
    if not isinstance(unit, Effect):
        raise TypeError(f"{where}: expected an Effect instance, got {type(unit).__name__}")
    if name is not None and unit.name != name:
        raise TypeError(f"{where}: its EFFECT is named {unit.name!r}")
    if unit.kind not in EFFECT_KINDS:
        raise TypeError(f"{where}: kind must be one of {list(EFFECT_KINDS)}, got {unit.kind!r}")
    inj = unit.injector_cls
    if not (isinstance(inj, type) and issubclass(inj, EffectInjector) and inj.name == unit.name):
        raise TypeError(f"{where}: injector_cls must be an EffectInjector subclass named {unit.name!r}, got {inj!r}")
    if unit.magnitude is not inj.magnitude:
        raise TypeError(f"{where}: magnitude differs from its injector's")
    for shape in unit.shapes:
        if not (isinstance(shape, type) and issubclass(shape, OffFaceInjector) and shape.expect == unit.name):
            raise TypeError(f"{where}: shape {shape!r} must be an OffFaceInjector subclass whose expect is {unit.name!r}")
    return unit


def load_units(names=LIBRARY_EFFECTS) -> dict[str, Effect]:
    """``{name: ftcal_nlp.effects.<name>.EFFECT}`` for ``names``, each checked (:func:`check_unit`)."""
    return {n: check_unit(importlib.import_module(f"{__package__}.{n}").EFFECT, n) for n in names}


EFFECTS: dict[str, Effect] = load_units()


def with_units(*units: Effect, registry: Mapping[str, Effect] | None = None) -> dict[str, Effect]:
    """A copy of ``registry`` (default :data:`EFFECTS`) with ``units`` added (checked); the registry itself is unchanged."""
    out = dict(EFFECTS if registry is None else registry)
    for u in units:
        if u.name in out:
            raise ValueError(f"effect {u.name!r} is already in the registry")
        out[u.name] = check_unit(u)
    return out


def resolve_effects(names, registry: Mapping[str, Effect] | None = None) -> list[Effect]:
    """Effects by canonical name (None: the whole registry); unknown names list the known ones."""
    reg = EFFECTS if registry is None else registry
    if names is None:
        return list(reg.values())
    out = []
    for n in names:
        if n not in reg:
            raise ConfigError(f"unknown effect {n!r}; known effects: {sorted(reg)}", key="diagnose.effects")
        out.append(reg[n])
    return out


def shape_classes(registry: Mapping[str, Effect] | None = None) -> dict[str, type[OffFaceInjector]]:
    """Every unit's off-face validation shapes, ``{shape name: class}``, in registry order."""
    return {s.name: s for u in (EFFECTS if registry is None else registry).values() for s in u.shapes}


def injector_classes(registry: Mapping[str, Effect] | None = None) -> dict[str, type[EffectInjector]]:
    """``{name: injector class}`` of every unit and every off-face shape (what a simulator config may name)."""
    reg = EFFECTS if registry is None else registry
    return {**{n: u.injector_cls for n, u in reg.items()}, **shape_classes(reg)}


def applies_to(name: str, registry: Mapping[str, Effect] | None = None) -> frozenset:
    """The simulators (``Effect.applies_to``) the injector ``name`` works in: its unit's, or for an off-face
    shape its own ``applies_to`` if it declares one, else its effect's; a name outside the registry
    (a fault of ``sim/variants.py``): the hexapod's."""
    reg = EFFECTS if registry is None else registry
    if name in reg:
        return frozenset(reg[name].applies_to)
    for u in reg.values():
        for s in u.shapes:
            if s.name == name:
                return frozenset(getattr(s, "applies_to", u.applies_to))
    return frozenset({"hexapod"})


def expectations(registry: Mapping[str, Effect] | None = None) -> tuple[str, ...]:
    """What a correct diagnosis may say: ``none``, ``unexplained`` or a name of the registry."""
    return (EXPECT_NONE, EXPECT_UNEXPLAINED, *(EFFECTS if registry is None else registry))
