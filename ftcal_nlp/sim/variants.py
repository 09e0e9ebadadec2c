"""Faults outside the effect library (issue 13, item 5), and the off-face injectors by name.

The library's injectors follow the same formulas as the diagnosis' faces, so a
validation on them alone can be passed by a diagnosis tuned to those formulas. The
off-face injectors add what real effects do instead. Those that are another shape
of a library effect (other drift shapes and time constants, other shaft-angle
harmonics) are declared by that effect's unit (``Effect.shapes`` in
``ftcal_nlp/effects/<name>.py``); this module adds the faults no library effect
describes: wiring faults of one leg, a leg whose mass changed after hanging, and
larger per-pose motion-capture noise. Each class declares what a correct diagnosis
should say about it (``expect``: ``"unexplained"`` for an effect outside the
library, then ``expect_legs`` names the leg(s) it lives on, or ``"none"`` for pure
measurement noise).

Injected on the noise-free reading ``w = w_a + w_o`` (report eq. 1), ``w_a = ctx.applied``:

* leg_axes_swapped       leg k's fx and fy channels exchanged in every recording (wiring):
                         w_k[:2] <- (1 - s) w_k[:2] + s (w_ky, w_kx),  s = ``scale`` (1: the fault)
* leg_axis_flipped       leg k's channel j mis-signed in every recording: w_kj <- (1 - 2 s) w_kj
* leg_mass_changed       standing and walking only: leg k carries ``dm = +-scale`` kg more at its CoM
                         ``r_k(phi)``: ``w_k += [dm g u_k; r_k x dm g u_k]`` (``u_k`` the gravity direction in
                         ft_k), and the feet in contact carry ``dm g`` (least-norm, as ``tether_force``);
                         the hanging recordings and ``robot.toml`` predate the change
* mocap_pose_noise       standing only: motion capture reports ``R_meas exp([delta_p])``, ``delta_p`` ~
                         N(0, ``scale`` deg) per axis, held through pose p (the simulator's own is 0.05 deg)

Every injector's random parameters come from its ``seed`` and its full name; the
affected leg, axis and sign are drawn at construction, so a plan knows them before
simulating. :data:`VARIANTS` is every off-face injector: the units' shapes (from the
effect registry) then these; importing :mod:`ftcal_nlp.sim` registers them in
:data:`ftcal_nlp.sim.effects.EFFECTS`; they are not in ``LIBRARY_EFFECTS``, so the
diagnosis never fits them.
"""

from __future__ import annotations

import numpy as np

from ..core.data import WRENCH_COMPONENTS
from ..core.geometry import rotvec_to_rotation
from ..effects.injection import (  # noqa: F401  (EXPECT_*, OffFaceInjector, variant_key: importable from here)
    EXPECT_NONE,
    EXPECT_UNEXPLAINED,
    InjectionContext,
    Magnitude,
    OffFaceInjector,
    distribute_over_feet,
    variant_key,
)
from ..effects.registry import expectations, shape_classes
from .effects import EFFECTS
from .robot_model import LEGS


def _pick(value: str | None, choices: tuple[str, ...], rng: np.random.Generator, where: str) -> str:
    """``value`` if given (checked against ``choices``), else one drawn from ``rng``."""
    if value is None:
        return choices[int(rng.integers(len(choices)))]
    if value not in choices:
        raise ValueError(f"{where}: unknown value {value!r}; known: {list(choices)}")
    return value


def _leg_index(ctx: InjectionContext, leg: str, where: str) -> int:
    legs = tuple(ctx.truth.legs)
    if leg not in legs:
        raise ValueError(f"{where}: leg {leg!r} is not a leg of the simulated robot {list(legs)}")
    return legs.index(leg)


def _fraction(scale: float, where: str) -> float:
    if not 0.0 <= scale <= 1.0:
        raise ValueError(f"{where}.scale: expected the fraction of the fault in [0, 1] (1 = the fault), got {scale!r}")
    return scale


# ============================================================================= one leg's wiring


class _OneLeg(OffFaceInjector):
    """An effect outside the library on one leg (``leg``; None: drawn from the seed)."""

    expect = EXPECT_UNEXPLAINED

    def __init__(self, scale: float | None = None, seed: int = 0, leg: str | None = None):
        super().__init__(scale, seed)
        self.leg = _pick(leg, LEGS, self.rng, f"{self.name}.leg")

    @property
    def expect_legs(self) -> tuple[str, ...]:
        return (self.leg,)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(scale={self.scale:g}, seed={self.seed}, leg={self.leg!r})"


class LegAxesSwappedInjector(_OneLeg):
    """Leg ``leg``'s fx and fy channels exchanged in every recording (``scale`` 1: the fault)."""

    name = "leg_axes_swapped"
    magnitude = Magnitude("fraction of the fault (1 = the leg's fx and fy exchanged; all or nothing)", (1.0, 1.0), 1.0)

    def readings(self, ctx, w):
        s = _fraction(self.scale, self.name)
        k = _leg_index(ctx, self.leg, f"{self.name}.leg")
        out = w.copy()
        out[:, k, :2] += s * (w[:, k, 1::-1] - w[:, k, :2])
        return out


class LegAxisFlippedInjector(_OneLeg):
    """Leg ``leg``'s channel ``axis`` (fx..tz; None: one force axis drawn from the seed) mis-signed."""

    name = "leg_axis_flipped"
    magnitude = Magnitude("fraction of the fault (1 = the channel's sign flipped; all or nothing)", (1.0, 1.0), 1.0)

    def __init__(self, scale: float | None = None, seed: int = 0, leg: str | None = None, axis: str | None = None):
        super().__init__(scale, seed, leg)
        self.axis = _pick(axis, WRENCH_COMPONENTS if axis is not None else WRENCH_COMPONENTS[:3], self.rng, f"{self.name}.axis")

    def readings(self, ctx, w):
        s = _fraction(self.scale, self.name)
        k = _leg_index(ctx, self.leg, f"{self.name}.leg")
        j = WRENCH_COMPONENTS.index(self.axis)
        out = w.copy()
        out[:, k, j] *= 1.0 - 2.0 * s
        return out

    def __repr__(self) -> str:
        return f"{type(self).__name__}(scale={self.scale:g}, seed={self.seed}, leg={self.leg!r}, axis={self.axis!r})"


# ============================================================================= a leg changed after hanging


class LegMassChangedInjector(_OneLeg):
    """After hanging, leg ``leg`` carries ``dm = sign * scale`` kg more (sign drawn from the seed) at its CoM."""

    name = "leg_mass_changed"
    magnitude = Magnitude("kg added to (or removed from) one leg between hanging and standing", (0.05, 0.2), 0.15)

    def __init__(self, scale: float | None = None, seed: int = 0, leg: str | None = None, sign: float | None = None):
        super().__init__(scale, seed, leg)
        self.sign = float(self.rng.choice([-1.0, 1.0]) if sign is None else np.sign(sign))
        if self.sign == 0.0:
            raise ValueError(f"{self.name}.sign: expected +1 (mass added) or -1 (removed), got {sign!r}")

    @property
    def delta_kg(self) -> float:
        return self.sign * self.scale

    def extra_wrench(self, ctx: InjectionContext) -> tuple[int, np.ndarray, np.ndarray]:
        """``(k, w_k (N, 6) in ft_k, f_B (N, 3))``: the extra weight's wrench on leg k's transducer
        about its origin, and the extra weight in B."""
        truth = ctx.truth
        k = _leg_index(ctx, self.leg, f"{self.name}.leg")
        u_B = -ctx.R_WB[:, 2, :]                                   # gravity direction in B (R_WB^T (-e_z))
        f_B = self.delta_kg * truth.g * u_B
        f_k = f_B @ truth.R[k]                                     # R_k^T f_B, row-wise
        r_k = truth.leg_com_ft(ctx.phi)[:, k]
        return k, np.concatenate([f_k, np.cross(r_k, f_k)], axis=-1), f_B

    def readings(self, ctx, w):
        if ctx.kind == "hanging":  # the change came after the hanging recordings
            return w
        truth = ctx.truth
        k, w_k, f_B = self.extra_wrench(ctx)
        a_B = truth.ft_to_body(truth.leg_com_ft(ctx.phi))[:, k]   # where the extra weight acts, B
        w_B = np.concatenate([f_B, np.cross(a_B - truth.com_body_m, f_B)], axis=-1)
        out = w + distribute_over_feet(w_B, ctx)                  # the feet carry it ...
        out[:, k] += w_k                                          # ... through leg k, which weighs it
        return out

    def __repr__(self) -> str:
        return f"{type(self).__name__}(scale={self.scale:g}, seed={self.seed}, leg={self.leg!r}, delta_kg={self.delta_kg:+g})"


# ============================================================================= motion capture noise


class MocapPoseNoiseInjector(OffFaceInjector):
    """Standing: a motion-capture error of ``scale`` deg per axis held through each pose (measurement noise)."""

    name = "mocap_pose_noise"
    expect = EXPECT_NONE
    magnitude = Magnitude("deg per axis of mocap error held through each standing pose (simulator: 0.05)", (0.2, 0.3), 0.3)

    def pose_errors(self, ctx: InjectionContext, n_poses: int) -> np.ndarray:
        """``delta_p`` (P, 3) rad: a function of the seed and the recording's name only."""
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, variant_key(self.name, ctx.name)]))
        return rng.normal(0.0, np.radians(self.scale), (n_poses, 3))

    def orientation(self, ctx, R_meas):
        idx = np.asarray(ctx.pose_index)
        if ctx.kind != "standing" or not np.any(idx >= 0):
            return R_meas
        delta = self.pose_errors(ctx, int(idx.max()) + 1)
        held = idx >= 0
        out = np.array(R_meas, float, copy=True)
        out[held] = R_meas[held] @ rotvec_to_rotation(delta[idx[held]])
        return out


# ============================================================================= registry

#: canonical name -> off-face injector class
OUTSIDE: dict[str, type[OffFaceInjector]] = {
    c.name: c for c in (LegAxesSwappedInjector, LegAxisFlippedInjector, LegMassChangedInjector, MocapPoseNoiseInjector)
}

#: every off-face injector: the effect units' shapes, then the faults outside the library
VARIANTS: dict[str, type[OffFaceInjector]] = {**shape_classes(), **OUTSIDE}

for _name, _cls in OUTSIDE.items():
    if EFFECTS.get(_name, _cls) is not _cls:
        raise RuntimeError(f"off-face injector name {_name!r} is taken by another effect")
for _name, _cls in VARIANTS.items():
    if _cls.expect not in expectations():
        raise RuntimeError(f"{_cls.__name__}.expect: {_cls.expect!r} is neither a library effect, 'none' nor 'unexplained'")
    EFFECTS[_name] = _cls

__all__ = [
    "EXPECT_NONE",
    "EXPECT_UNEXPLAINED",
    "OUTSIDE",
    "VARIANTS",
    "LegAxesSwappedInjector",
    "LegAxisFlippedInjector",
    "LegMassChangedInjector",
    "MocapPoseNoiseInjector",
    "OffFaceInjector",
    "variant_key",
]
