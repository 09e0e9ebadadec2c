"""The simulator's effect names: injectors by name, for ``[simulate] effects`` and ``truth.json``.

Readings are ``w_m = inject_readings(w_a + w_o) + n`` and ``R_meas =
inject_orientation(R_WB exp([delta]))`` (the hook, :mod:`ftcal_nlp.effects.injection`,
re-exported here). :data:`EFFECTS` maps a name to an injector factory: every effect
unit's injector and off-face shapes (``ftcal_nlp.effects.injector_classes``, read from
the effect registry) and the faults outside the library (:mod:`.variants`, registered
when :mod:`ftcal_nlp.sim` is imported). :func:`make_effects` builds injectors from a
TOML value; the diagnosis is never needed to simulate an effect.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Callable

from ..effects.injection import (  # noqa: F401  (the hook, re-exported for the simulator's modules)
    InjectionContext,
    Injector,
    NoEffect,
    apply_orientation,
    apply_readings,
    apply_robot,
)
from ..effects.registry import LIBRARY_EFFECTS, injector_classes
from ..core.errors import ConfigError

# Name -> factory(**kwargs) -> Injector: the registry's injectors and shapes; sim/variants.py adds the faults
# outside the library.
EFFECTS: dict[str, Callable[..., Injector]] = dict(injector_classes())


def make_effects(spec: Any, *, where: str = "effects", injectors: Mapping[str, Callable[..., Injector]] | None = None
                 ) -> tuple[Injector, ...]:
    """Injectors from a TOML value: a list of names or of tables ``{name = "...", ...kwargs}`` (or injectors);
    names are looked up in ``injectors`` (default :data:`EFFECTS`)."""
    known = EFFECTS if injectors is None else injectors
    if not isinstance(spec, (list, tuple)):
        raise ConfigError(f"{where}: expected a list of effect names or tables, got {type(spec).__name__}")
    out = []
    for i, item in enumerate(spec):
        if isinstance(item, str):
            name, kw = item, {}
        elif isinstance(item, dict) and isinstance(item.get("name"), str):
            kw = {k: v for k, v in item.items() if k != "name"}
            name = item["name"]
        elif isinstance(item, Injector):
            out.append(item)
            continue
        else:
            raise ConfigError(f"{where}[{i}]: expected an effect name or a table with key 'name', got {item!r}")
        if name not in known:
            raise ConfigError(f"{where}[{i}]: unknown effect '{name}'; known effects: {sorted(known) or '(none registered)'}")
        out.append(known[name](**kw))
    return tuple(out)


def effect_label(effects: tuple) -> tuple[str, float, bool]:
    """``(effect, scale, in_library)`` for truth.json: "none" without injectors,
    else the names joined by "+" and the first injector's scale."""
    if not effects:
        return "none", 1.0, False
    names = [e.name for e in effects]
    return "+".join(names), float(getattr(effects[0], "scale", 1.0)), all(n in LIBRARY_EFFECTS for n in names)
