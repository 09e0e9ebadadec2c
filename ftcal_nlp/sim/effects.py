"""Hook for effect injectors: unmodelled physics added where true wrenches become readings.

The simulator computes, for every recording, the true applied wrench ``w_a`` of
each leg (report eq. 1) and the true orientation ``R_WB``. Readings are then

    w_m = inject_readings(w_a + w_o) + n,    R_meas = inject_orientation(R_WB exp([delta]))

where ``n`` is sensor noise and ``delta`` motion-capture jitter. An injector
(issue 7: offset drift, gain crosstalk, casing load, mocap bias, chassis flex,
tether force, hysteresis, leg inertia, wrong robot mass, sensor nonlinearity)
sees an :class:`InjectionContext` and returns modified arrays; it never changes
the truth it is compared against. Injectors are registered by canonical name in
:data:`EFFECTS` (a plain dict of factories); the effect library's injectors
(:mod:`ftcal_nlp.sim.injectors`) register there when :mod:`ftcal_nlp.sim` is
imported. This module holds only the hook (context, protocol, registry, the
``apply_*`` helpers); it needs nothing from the diagnosis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class InjectionContext:
    """What an injector may look at, for one recording of N samples and K legs.

    ``kind``: hanging | standing | walking; ``name``: recording name; ``t`` (N,) s;
    ``phi`` (N, K) rad; ``R_WB`` (N, 3, 3) true body orientation; ``applied``
    (N, K, 6) true applied wrench in ft_k (N, N*m); ``pose_index`` (N,) int,
    the standing pose a sample belongs to (-1 outside standing); ``truth`` the
    :class:`~ftcal_nlp.sim.robot_model.TrueRobot`; ``rng`` a generator private
    to this injector and recording.
    """

    kind: str
    name: str
    t: np.ndarray
    phi: np.ndarray
    R_WB: np.ndarray
    applied: np.ndarray
    pose_index: np.ndarray
    truth: Any
    rng: np.random.Generator


@runtime_checkable
class Injector(Protocol):
    """An effect added to simulated readings. ``name`` is its canonical effect name
    (``OUTPUT_FORMAT.md``), written to ``truth.json`` as ``effect``; ``scale`` its size."""

    name: str
    scale: float

    def readings(self, ctx: InjectionContext, w: np.ndarray) -> np.ndarray:
        """Noise-free readings (N, K, 6) in ft_k -> modified readings (same shape)."""
        ...

    def orientation(self, ctx: InjectionContext, R_meas: np.ndarray) -> np.ndarray:
        """Motion-capture orientation (N, 3, 3) -> modified (same shape)."""
        ...


class NoEffect:
    """Identity injector; a base class whose methods effects override as needed.

    Besides the two protocol methods an injector may define ``robot(robot) ->
    Robot``: the robot description written to ``robot.toml`` (e.g. a wrongly
    weighed mass); the simulation itself always uses the true robot.
    """

    name = "none"
    scale = 0.0

    def readings(self, ctx: InjectionContext, w: np.ndarray) -> np.ndarray:
        return w

    def orientation(self, ctx: InjectionContext, R_meas: np.ndarray) -> np.ndarray:
        return R_meas

    def robot(self, robot):
        return robot


# Canonical effect name -> factory(**kwargs) -> Injector. Filled by ftcal_nlp.sim.injectors on import.
EFFECTS: dict[str, Callable[..., Injector]] = {}

# Names the diagnosis library knows (OUTPUT_FORMAT.md), for truth.json's "in_library".
LIBRARY_EFFECTS = (
    "offset_drift", "gain_crosstalk", "casing_load", "mocap_bias", "chassis_flex", "tether_force",
    "hysteresis", "leg_inertia", "robot_mass", "sensor_nonlinearity", "moving_com",
)


def make_effects(spec: Any, *, where: str = "effects") -> tuple[Injector, ...]:
    """Injectors from a TOML value: a list of names or of tables ``{name = "...", ...kwargs}``."""
    if not isinstance(spec, (list, tuple)):
        raise ValueError(f"{where}: expected a list of effect names or tables, got {type(spec).__name__}")
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
            raise ValueError(f"{where}[{i}]: expected an effect name or a table with key 'name', got {item!r}")
        if name not in EFFECTS:
            raise ValueError(f"{where}[{i}]: unknown effect '{name}'; known effects: {sorted(EFFECTS) or '(none registered)'}")
        out.append(EFFECTS[name](**kw))
    return tuple(out)


def effect_label(effects: tuple) -> tuple[str, float, bool]:
    """``(effect, scale, in_library)`` for truth.json: "none" without injectors,
    else the names joined by "+" and the first injector's scale."""
    if not effects:
        return "none", 1.0, False
    names = [e.name for e in effects]
    return "+".join(names), float(getattr(effects[0], "scale", 1.0)), all(n in LIBRARY_EFFECTS for n in names)


def apply_readings(effects: tuple, ctx_args: dict, w: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
    """Apply each injector's ``readings`` in turn (each with its own generator)."""
    for eff, rng in zip(effects, rngs):
        w = eff.readings(InjectionContext(rng=rng, **ctx_args), w)
    return w


def apply_orientation(effects: tuple, ctx_args: dict, R: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
    """Apply each injector's ``orientation`` in turn."""
    for eff, rng in zip(effects, rngs):
        R = eff.orientation(InjectionContext(rng=rng, **ctx_args), R)
    return R


def apply_robot(effects: tuple, robot):
    """The robot description as the user would write it (injectors with a ``robot`` method)."""
    for eff in effects:
        if hasattr(eff, "robot"):
            robot = eff.robot(robot)
    return robot
