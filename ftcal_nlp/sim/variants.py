"""Off-face injectors (issue 13, item 5): effects whose shapes differ from the diagnosis' model faces.

The library's injectors (:mod:`ftcal_nlp.sim.injectors`) follow the same formulas
as the diagnosis' faces, so a validation on them alone can be passed by a
diagnosis tuned to those formulas. These injectors add what real effects do
instead: other drift shapes and time constants, other shaft-angle harmonics,
wiring faults of one leg, a leg whose mass changed after hanging, and larger
per-pose motion-capture noise. Each class declares what a correct diagnosis
should say about it:

* ``expect``: the library effect it should be named as (a drift of another shape
  is still ``offset_drift``), ``"unexplained"`` for an effect outside the library
  (then ``expect_legs`` names the leg(s) it lives on), or ``"none"`` for pure
  measurement noise;
* ``expect_legs``: the affected legs (empty: not leg-specific).

Injected on the noise-free reading ``w = w_a + w_o`` (report eq. 1), ``w_a = ctx.applied``,
session time ``t`` (s), shaft angle ``phi``; ``d_k`` is ``offset_drift``'s per-leg drift
vector (force ~``scale`` N, torque ``scale`` x 2 cm, drawn from the seed):

* offset_drift_ramp      w_o(t) = w_o + d_k t / 1 h                       (linear, no saturation)
* offset_drift_step      w_o(t) = w_o + d_k [t >= t_s]                    (``scale`` N at once; t_s: the middle
                         of the standing recording unless ``t_step_s`` is given; hanging before, walking after)
* offset_drift_fast      w_o(t) = w_o + d_k (1 - exp(-t/tau)) / (1 - exp(-1 h/tau)),  tau = 150 s
                         (``offset_drift`` injects tau = 1200 s: this warm-up is mostly over when standing starts)
* casing_load_harmonics  w[:2] += scale sum_h a_h M_hk (cos h phi, sin h phi),  h = (3, 5), a = (1, 0.6)
                         (``casing_load`` injects the first harmonic only)
* leg_axes_swapped       leg k's fx and fy channels exchanged in every recording (wiring):
                         w_k[:2] <- (1 - s) w_k[:2] + s (w_ky, w_kx),  s = ``scale`` (1: the fault)
* leg_axis_flipped       leg k's channel j mis-signed in every recording: w_kj <- (1 - 2 s) w_kj
* leg_mass_changed       standing and walking only: leg k carries ``dm = +-scale`` kg more at its CoM
                         ``r_k(phi)``: ``w_k += [dm g u_k; r_k x dm g u_k]`` (``u_k`` the gravity direction in
                         ft_k), and the feet in contact carry ``dm g`` (least-norm, as ``tether_force``);
                         the hanging recordings and ``robot.toml`` predate the change
* mocap_pose_noise       standing only: motion capture reports ``R_meas exp([delta_p])``, ``delta_p`` ~
                         N(0, ``scale`` deg) per axis, held through pose p (the simulator's own is 0.05 deg)

Every injector's random parameters come from its ``seed`` and its full name (so a
variant never shares the draws of the library injector it resembles); the
affected leg, axis and sign are drawn at construction, so a plan knows them
before simulating. Importing :mod:`ftcal_nlp.sim` registers every class here in
:data:`ftcal_nlp.sim.effects.EFFECTS`; they are not in ``LIBRARY_EFFECTS``, so the
diagnosis never fits them.
"""

from __future__ import annotations

import zlib
from typing import ClassVar

import numpy as np

from ..data import WRENCH_COMPONENTS
from ..geometry import rotvec_to_rotation
from .effects import EFFECTS, LIBRARY_EFFECTS, InjectionContext
from .injectors import HOUR_S, EffectInjector, Magnitude, OffsetDriftInjector, distribute_over_feet
from .robot_model import LEGS

EXPECT_NONE = "none"
EXPECT_UNEXPLAINED = "unexplained"


def variant_key(*parts: str) -> int:
    """A process-independent 32-bit key of names (CRC-32; ``hash`` is salted per process)."""
    return zlib.crc32("/".join(parts).encode())


class OffFaceInjector(EffectInjector):
    """Base of the off-face injectors: an :class:`EffectInjector` whose generator is seeded by
    ``seed`` and the whole name, with what a correct diagnosis should say (``expect``, ``expect_legs``)."""

    expect: ClassVar[str] = EXPECT_NONE

    def __init__(self, scale: float | None = None, seed: int = 0, **kwargs):
        super().__init__(scale, seed, **kwargs)
        self.rng = np.random.default_rng(np.random.SeedSequence([self.seed, variant_key(self.name)]))

    @property
    def expect_legs(self) -> tuple[str, ...]:
        return ()


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


# ============================================================================= offset drift, other shapes


class _DriftShape(OffFaceInjector, OffsetDriftInjector):
    """Offset drift ``w_o + fraction(ctx) d_k`` with ``offset_drift``'s per-leg vectors ``d_k``."""

    expect = "offset_drift"

    def fraction(self, ctx: InjectionContext) -> np.ndarray:
        raise NotImplementedError

    def readings(self, ctx, w):
        return w + self.fraction(ctx)[:, None, None] * self._drift(w.shape[1])[None]


class OffsetDriftRampInjector(_DriftShape):
    """Linear drift: ``d_k t / 1 h`` on the session clock (``scale`` N of force after one hour)."""

    name = "offset_drift_ramp"
    magnitude = Magnitude("N of force drift per leg after one hour (linear)", (1.0, 4.0), 3.0)

    def fraction(self, ctx):
        return np.asarray(ctx.t, float) / HOUR_S


class OffsetDriftStepInjector(_DriftShape):
    """A step of ``d_k`` (``scale`` N of force) at ``t_step_s`` on the session clock; None: the middle
    of the standing recording (hanging recordings come before it, walking after)."""

    name = "offset_drift_step"
    magnitude = Magnitude("N of force step per leg", (0.5, 2.0), 2.0)

    def __init__(self, scale: float | None = None, seed: int = 0, t_step_s: float | None = None):
        super().__init__(scale, seed)
        self.t_step_s = None if t_step_s is None else float(t_step_s)

    def fraction(self, ctx):
        t = np.asarray(ctx.t, float)
        if self.t_step_s is not None:
            return (t >= self.t_step_s).astype(float)
        if ctx.kind == "standing":
            return (t >= 0.5 * (t[0] + t[-1])).astype(float)
        return np.full(len(t), 1.0 if ctx.kind == "walking" else 0.0)


class OffsetDriftFastInjector(_DriftShape):
    """Warm-up with time constant ``tau_s`` (default 150 s, far from ``offset_drift``'s 1200 s),
    normalised as the library's: ``scale`` N of force after one hour."""

    name = "offset_drift_fast"
    magnitude = Magnitude("N of force drift per leg after one hour (tau 150 s)", (1.0, 4.0), 3.0)

    def __init__(self, scale: float | None = None, seed: int = 0, tau_s: float = 150.0):
        super().__init__(scale, seed, tau_s=tau_s)
        if not self.tau_s > 0:
            raise ValueError(f"{self.name}.tau_s: expected a positive time constant in s, got {tau_s!r}")

    def fraction(self, ctx):
        return (1 - np.exp(-np.asarray(ctx.t, float) / self.tau_s)) / (1 - np.exp(-HOUR_S / self.tau_s))


# ============================================================================= casing load, higher harmonics


class CasingLoadHarmonicsInjector(OffFaceInjector):
    """Parasitic force in the ft xy plane, ``scale sum_h a_h M_hk (cos h phi, sin h phi)``; entries of
    ``M_hk`` ~ N(0, 1/2) as ``casing_load``'s, harmonics ``h`` and weights ``a_h`` configurable."""

    name = "casing_load_harmonics"
    expect = "casing_load"
    magnitude = Magnitude("N, amplitude of the shaft-angle dependent force (3rd + 5th harmonic)", (0.3, 1.5), 1.0)

    def __init__(self, scale: float | None = None, seed: int = 0, harmonics: tuple = (3, 5), weights: tuple = (1.0, 0.6)):
        super().__init__(scale, seed)
        self.harmonics = tuple(int(h) for h in harmonics)
        self.weights = np.asarray(weights, float)
        if len(self.harmonics) != len(self.weights) or not self.harmonics:
            raise ValueError(f"{self.name}: harmonics {harmonics!r} and weights {weights!r} need the same non-zero length")
        self._M: np.ndarray | None = None

    def matrices(self, K: int) -> np.ndarray:
        """``scale a_h M_hk`` (H, K, 2, 2)."""
        if self._M is None or self._M.shape[1] != K:
            self._M = self.rng.normal(0.0, 1.0 / np.sqrt(2.0), (len(self.harmonics), K, 2, 2))
        return self.scale * self.weights[:, None, None, None] * self._M

    def readings(self, ctx, w):
        M = self.matrices(w.shape[1])
        hphi = np.asarray(self.harmonics, float)[:, None, None] * ctx.phi[None]      # (H, N, K)
        cs = np.stack([np.cos(hphi), np.sin(hphi)], axis=-1)                        # (H, N, K, 2)
        out = w.copy()
        out[..., :2] += np.einsum("hkij,hnkj->nki", M, cs)
        return out


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
VARIANTS: dict[str, type[OffFaceInjector]] = {
    c.name: c
    for c in (
        OffsetDriftRampInjector, OffsetDriftStepInjector, OffsetDriftFastInjector, CasingLoadHarmonicsInjector,
        LegAxesSwappedInjector, LegAxisFlippedInjector, LegMassChangedInjector, MocapPoseNoiseInjector,
    )
}

for _name, _cls in VARIANTS.items():
    if _name in LIBRARY_EFFECTS or EFFECTS.get(_name, _cls) is not _cls:
        raise RuntimeError(f"off-face injector name {_name!r} is taken by another effect")
    if _cls.expect not in (EXPECT_NONE, EXPECT_UNEXPLAINED) + LIBRARY_EFFECTS:
        raise RuntimeError(f"{_cls.__name__}.expect: {_cls.expect!r} is neither a library effect, 'none' nor 'unexplained'")
    EFFECTS[_name] = _cls

__all__ = [
    "EXPECT_NONE",
    "EXPECT_UNEXPLAINED",
    "VARIANTS",
    "CasingLoadHarmonicsInjector",
    "LegAxesSwappedInjector",
    "LegAxisFlippedInjector",
    "LegMassChangedInjector",
    "MocapPoseNoiseInjector",
    "OffFaceInjector",
    "OffsetDriftFastInjector",
    "OffsetDriftRampInjector",
    "OffsetDriftStepInjector",
    "variant_key",
]
