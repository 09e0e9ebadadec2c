"""The effect library's injectors (issue 7): the simulator face of every canonical effect.

Each class adds one effect of ``OUTPUT_FORMAT.md`` to simulated readings through the
hook of :mod:`ftcal_nlp.sim.effects` (``readings(ctx, w)``, ``orientation(ctx, R)``,
``robot(robot)``); its ``scale`` is the effect's size in the unit of its
:class:`Magnitude` (default: the test size), ``seed`` fixes its own random
parameters. Importing :mod:`ftcal_nlp.sim` registers every class here in
:data:`ftcal_nlp.sim.effects.EFFECTS` under its canonical name. The other face of
each effect, the augmentation of the calibration model, lives in
``ftcal_nlp.diagnose.effects`` (which imports these classes; the simulator never
imports the diagnosis).

Injected on the noise-free reading ``w = w_a + w_o`` (report eq. 1), ``w_a = ctx.applied``.

At the transducer (every recording; hysteresis: standing only):

* offset_drift        w_o(t) = w_o + d_k (1 - exp(-t/tau)) / (1 - exp(-1 h/tau))   (warm-up, d_k = drift after 1 h)
* gain_crosstalk      w = w_o + (I + E_k) w_a,  E_k on the 3x3 force block
* sensor_nonlinearity w = w_o + w_a + q_k (.) w_a^2,  q_kj = s_j scale (1 +- 0.2) / ref_j
* hysteresis          w = w_a + h (w_a,prev pose - w_a) while standing
* casing_load         w += [M_k (cos phi, sin phi); 0, 0, 0, 0]  (force in the ft xy plane)
* chassis_flex        w = w_o + Rot(-delta_k) w_a,  delta_k = c_k (n_k . f_a) / 20 N, c_k horizontal in B

Outside the transducers:

* tether_force   a constant wrench on the body (a cable), force ``scale`` N in the
                 heading frame H (z up, x the body's heading: a cable that trails
                 the robot), at a point ``a`` on the body; standing and walking. The
                 feet carry it: the least-norm change of the contact forces with
                 ``sum_k dF_k = -f`` and ``sum_k (foot_k - c) x dF_k = -(a - c) x f``
                 (body-without-legs CoM ``c``), read as ``[dF; foot x dF]`` in ft_k.
* robot_mass     ``robot.toml`` says ``mass_kg + scale`` (the simulation keeps the true mass).
* mocap_bias     motion capture reports ``R_WB R_b``, ``R_b`` a ``scale`` degree tilt.
* leg_inertia    the leg's inertial force ``-m_k a_k``, ``a_k = r_k''(phi) phi_dot^2``
                 (centripetal, shaft speed squared), times ``scale`` (1 = physical).
* moving_com     no injector: exact physics; the gap appears when the calibration
                 uses the report's fixed-CoM balance (eq. 9).

Sizes are in ``Magnitude``: a realistic range for an ATI Gamma on an 8 kg robot and
a test size at which the effect is clearly detectable.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from ..geometry import remove_yaw, rotvec_to_rotation
from .effects import EFFECTS, LIBRARY_EFFECTS, NoEffect

HOUR_S = 3600.0
REF_FORCE_N = 20.0    # reference load for loads-dependent effects (a leg's stance load is ~13-25 N)
REF_TORQUE_NM = 2.0

_REF = np.array([REF_FORCE_N] * 3 + [REF_TORQUE_NM] * 3)
_DEG = np.pi / 180.0


@dataclass(frozen=True)
class Magnitude:
    """``unit`` of ``scale``; ``realistic`` (lo, hi) range; ``test`` a clearly detectable size."""

    unit: str
    realistic: tuple[float, float]
    test: float


class EffectInjector(NoEffect):
    """Base of the library's injectors: ``scale`` in the effect's unit (default: its
    ``magnitude.test``), ``seed`` fixes the effect's own random parameters (the same
    for every recording of a session; the generator is seeded by seed and name)."""

    name = "none"
    magnitude: ClassVar[Magnitude] = Magnitude("", (0.0, 0.0), 0.0)

    def __init__(self, scale: float | None = None, seed: int = 0):
        self.scale = float(self.default_scale() if scale is None else scale)
        self.seed = int(seed)
        self.rng = np.random.default_rng(np.random.SeedSequence([self.seed, _name_key(self.name)]))

    @classmethod
    def default_scale(cls) -> float:
        return cls.magnitude.test

    def __repr__(self) -> str:
        return f"{type(self).__name__}(scale={self.scale:g}, seed={self.seed})"


def _name_key(name: str) -> int:
    return int.from_bytes(name.encode()[:8].ljust(8, b"\0"), "little")


def rotvec_rotate(delta: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by the rotation vectors ``delta`` (..., 3) (Rodrigues)."""
    th = np.linalg.norm(delta, axis=-1, keepdims=True)
    ths = np.where(th < 1e-12, 1.0, th)
    n = delta / ths
    c, s = np.cos(th), np.sin(th)
    return v * c + np.cross(n, v) * s + n * np.sum(n * v, axis=-1, keepdims=True) * (1 - c)


def shaft_speed(t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``d phi / dt`` (N, K) by central differences on the session clock."""
    if len(t) < 2:
        return np.zeros_like(phi)
    return np.gradient(phi, t, axis=0)


# ============================================================================= at the transducer
# ----------------------------------------------------------------------------- offset drift


class OffsetDriftInjector(EffectInjector):
    """Warm-up drift: ``scale`` N of force drift per leg after one hour (torque: scale x 2 cm)."""

    name = "offset_drift"
    magnitude = Magnitude("N of force drift per leg after one hour", (1.0, 4.0), 3.0)

    def __init__(self, scale: float | None = None, seed: int = 0, tau_s: float = 1200.0):
        super().__init__(scale, seed)
        self.tau_s = float(tau_s)
        self._dir = None

    def _drift(self, K: int) -> np.ndarray:
        if self._dir is None or len(self._dir) != K:
            f = self.rng.normal(size=(K, 3))
            f /= np.linalg.norm(f, axis=1, keepdims=True)
            t = self.rng.normal(size=(K, 3))
            t /= np.linalg.norm(t, axis=1, keepdims=True)
            amp = self.rng.uniform(0.7, 1.3, (K, 1))
            self._dir = np.hstack([f, 0.02 * t]) * amp
        return self.scale * self._dir

    def readings(self, ctx, w):
        K = w.shape[1]
        frac = (1 - np.exp(-ctx.t / self.tau_s)) / (1 - np.exp(-HOUR_S / self.tau_s))
        return w + frac[:, None, None] * self._drift(K)[None]


# ----------------------------------------------------------------------------- gain crosstalk


class GainCrosstalkInjector(EffectInjector):
    """``(I + E_k)`` on the applied force; entries of E_k ~ N(0, scale) (a fraction)."""

    name = "gain_crosstalk"
    magnitude = Magnitude("rms of the force-gain matrix entries (fraction)", (0.01, 0.03), 0.02)

    def matrices(self, K: int) -> np.ndarray:
        if not hasattr(self, "_E") or len(self._E) != K:
            self._E = self.rng.normal(0.0, 1.0, (K, 3, 3))
        return self.scale * self._E

    def readings(self, ctx, w):
        E = self.matrices(w.shape[1])
        out = w.copy()
        out[..., :3] += np.einsum("kij,nkj->nki", E, ctx.applied[..., :3])
        return out


# ----------------------------------------------------------------------------- sensor nonlinearity


class SensorNonlinearityInjector(EffectInjector):
    """``q_kj w_a,j^2``: ``scale`` is the relative error at the reference load (20 N, 2 N*m)."""

    name = "sensor_nonlinearity"
    magnitude = Magnitude("relative error at 20 N / 2 N*m", (0.003, 0.01), 0.01)

    def coefficients(self, K: int) -> np.ndarray:
        if not hasattr(self, "_q") or len(self._q) != K:
            sign = self.rng.choice([-1.0, 1.0], 6)
            self._q = sign * self.rng.uniform(0.8, 1.2, (K, 6)) / _REF
        return self.scale * self._q

    def readings(self, ctx, w):
        return w + self.coefficients(w.shape[1])[None] * ctx.applied**2


# ----------------------------------------------------------------------------- hysteresis


class HysteresisInjector(EffectInjector):
    """A standing reading keeps the fraction ``scale`` of the previous pose's load."""

    name = "hysteresis"
    magnitude = Magnitude("fraction of the previous pose's load kept", (0.005, 0.02), 0.02)

    def readings(self, ctx, w):
        if ctx.kind != "standing":
            return w
        idx = ctx.pose_index
        P = int(idx.max()) + 1
        last = np.searchsorted(idx, np.arange(P), side="right") - 1  # poses come in order: last sample of each
        prev_load = np.zeros_like(ctx.applied)
        has = idx >= 1
        prev_load[has] = ctx.applied[last[idx[has] - 1]]
        out = w.copy()
        out[has] += self.scale * (prev_load[has] - ctx.applied[has])
        return out


# ----------------------------------------------------------------------------- casing load


class CasingLoadInjector(EffectInjector):
    """Parasitic force in the ft xy plane, ``M_k (cos phi, sin phi)``, amplitude ~``scale`` N."""

    name = "casing_load"
    magnitude = Magnitude("N, amplitude of the shaft-angle dependent force", (0.3, 1.5), 1.0)

    def matrices(self, K: int) -> np.ndarray:
        if not hasattr(self, "_M") or len(self._M) != K:
            self._M = self.rng.normal(0.0, 1.0 / np.sqrt(2.0), (K, 2, 2))
        return self.scale * self._M

    def readings(self, ctx, w):
        M = self.matrices(w.shape[1])
        cs = np.stack([np.cos(ctx.phi), np.sin(ctx.phi)], axis=-1)  # (N, K, 2)
        out = w.copy()
        out[..., :2] += np.einsum("kij,nkj->nki", M, cs)
        return out


# ----------------------------------------------------------------------------- chassis flex


class ChassisFlexInjector(EffectInjector):
    """The transducer tilts by ``scale`` degrees per 20 N of its own vertical load (axis horizontal in B)."""

    name = "chassis_flex"
    magnitude = Magnitude("deg of tilt per 20 N of the transducer's vertical load", (0.3, 1.0), 1.0)

    def axes(self, truth) -> np.ndarray:
        """Rotation per newton of vertical load, rad/N, in ft_k (K, 3)."""
        K = len(truth.legs)
        if not hasattr(self, "_c") or len(self._c) != K:
            ang = self.rng.uniform(0, 2 * np.pi, K)
            amp = self.rng.uniform(0.7, 1.3, K)
            c_B = np.stack([np.cos(ang), np.sin(ang), np.zeros(K)], axis=1) * amp[:, None]
            self._c = np.einsum("kji,kj->ki", truth.R, c_B)  # R_k^T c_B
        return self.scale * _DEG / REF_FORCE_N * self._c

    def readings(self, ctx, w):
        truth = ctx.truth
        n = truth.R[:, 2, :]  # R_k^T e_z: the ft axis vertical in B
        load = np.einsum("ki,nki->nk", n, ctx.applied[..., :3])
        delta = self.axes(truth)[None] * load[..., None]
        wa = ctx.applied
        rot = np.concatenate([rotvec_rotate(-delta, wa[..., :3]), rotvec_rotate(-delta, wa[..., 3:])], axis=-1)
        return w - wa + rot


# ============================================================================= outside the transducers
# ----------------------------------------------------------------------------- tether force


def distribute_over_feet(w_B: np.ndarray, ctx) -> np.ndarray:
    """Reading changes (N, K, 6) that carry the external wrench ``w_B`` (N, 6; B axes,
    about the body-without-legs CoM) through the feet in contact (least-norm forces)."""
    truth = ctx.truth
    K = len(truth.legs)
    u_B = -ctx.R_WB[:, 2, :]
    f_leg = truth.weights_N[None, :, None] * np.einsum("kji,nj->nki", truth.R, u_B)
    f_ground = ctx.applied[..., :3] - f_leg
    contact = np.linalg.norm(f_ground, axis=-1) > 1e-6                       # (N, K)
    foot_ft = truth.foot_ft(ctx.phi)                                         # (N, K, 3)
    lever = truth.ft_to_body(foot_ft) - truth.com_body_m                     # (N, K, 3)
    N = len(ctx.t)
    A = np.zeros((N, 6, 3 * K))
    eye = np.eye(3)
    for k in range(K):
        m = contact[:, k, None, None]
        A[:, 0:3, 3 * k : 3 * k + 3] = np.where(m, eye, 0.0)
        lx = np.zeros((N, 3, 3))
        l = lever[:, k]
        lx[:, 0, 1], lx[:, 0, 2], lx[:, 1, 0], lx[:, 1, 2], lx[:, 2, 0], lx[:, 2, 1] = -l[:, 2], l[:, 1], l[:, 2], -l[:, 0], -l[:, 1], l[:, 0]
        A[:, 3:6, 3 * k : 3 * k + 3] = np.where(m, lx, 0.0)
    AAt = A @ np.swapaxes(A, 1, 2) + 1e-12 * np.eye(6)
    dF = np.einsum("nji,nj->ni", A, np.linalg.solve(AAt, -w_B[..., None])[..., 0]).reshape(N, K, 3)
    dF_ft = np.einsum("kji,nkj->nki", truth.R, dF)                           # R_k^T dF
    return np.concatenate([dF_ft, np.cross(foot_ft, dF_ft)], axis=-1)


class TetherForceInjector(EffectInjector):
    """A cable: force of ``scale`` N, fixed in the heading frame, attached at ``a`` on the body."""

    name = "tether_force"
    magnitude = Magnitude("N of cable force", (1.0, 3.0), 2.0)

    def params(self, truth) -> tuple[np.ndarray, np.ndarray]:
        if not hasattr(self, "_f"):
            az = self.rng.uniform(-np.pi, np.pi)
            el = self.rng.uniform(np.radians(-20.0), np.radians(60.0))
            self._f = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            self._a = self.rng.uniform([-0.2, -0.1, 0.02], [0.2, 0.1, 0.08])
        return self.scale * self._f, self._a

    def readings(self, ctx, w):
        if ctx.kind == "hanging":  # the rig holds the body: the cable does not load the legs
            return w
        f_H, a = self.params(ctx.truth)
        R_HB = remove_yaw(ctx.R_WB)
        f_B = np.einsum("nji,j->ni", R_HB, f_H)
        w_B = np.concatenate([f_B, np.cross(a - ctx.truth.com_body_m, f_B)], axis=-1)
        return w + distribute_over_feet(w_B, ctx)


# ----------------------------------------------------------------------------- robot mass


class RobotMassInjector(EffectInjector):
    """The weighed mass in ``robot.toml`` is off by ``scale`` kg (sign drawn from the seed)."""

    name = "robot_mass"
    magnitude = Magnitude("kg of weighing error", (0.05, 0.2), 0.15)

    def robot(self, robot):
        if not hasattr(self, "_sign"):
            self._sign = float(self.rng.choice([-1.0, 1.0]))
        return replace(robot, mass_kg=float(robot.mass_kg + self._sign * self.scale))


# ----------------------------------------------------------------------------- mocap bias


class MocapBiasInjector(EffectInjector):
    """Motion capture reports ``R_WB R_b``: ``R_b`` tilts by ``scale`` degrees about a horizontal axis
    (a heading component would be invisible and harmless: the heading never enters)."""

    name = "mocap_bias"
    magnitude = Magnitude("deg of tilt between the mocap body and B", (2.0, 3.0), 3.0)

    def rotation(self) -> np.ndarray:
        if not hasattr(self, "_Rb"):
            ang = self.rng.uniform(0, 2 * np.pi)
            self._Rb = rotvec_to_rotation(np.radians(self.scale) * np.array([np.cos(ang), np.sin(ang), 0.0]))
        return self._Rb

    def orientation(self, ctx, R_meas):
        return R_meas @ self.rotation()


# ----------------------------------------------------------------------------- leg inertia


class LegInertiaInjector(EffectInjector):
    """``scale`` times the leg's centripetal inertial wrench (1 = physical for these slow legs;
    ``scale = s`` is the physical value of legs turning ``sqrt(s)`` times faster)."""

    name = "leg_inertia"
    magnitude = Magnitude("x the physical centripetal wrench (legs sqrt(x) times faster)", (30.0, 100.0), 100.0)

    def readings(self, ctx, w):
        truth = ctx.truth
        omega = shaft_speed(ctx.t, ctx.phi)                                       # (N, K)
        r_dd = -truth.com_amp * np.sin(ctx.phi[..., None] + truth.com_phase)     # d2 r / d phi2 (N, K, 3)
        m = truth.weights_N / truth.g
        f = -m[None, :, None] * r_dd * omega[..., None] ** 2                      # -m a
        r = truth.leg_com_ft(ctx.phi)
        return w + self.scale * np.concatenate([f, np.cross(r, f)], axis=-1)


# ----------------------------------------------------------------------------- moving CoM


class MovingComInjector(EffectInjector):
    """Exact physics (nothing added): the legs' CoMs move, as they always do."""

    name = "moving_com"
    magnitude = Magnitude("(none: exact physics; a calibration with balance = 'report')", (1.0, 1.0), 1.0)

    def __init__(self, scale: float | None = None, seed: int = 0):
        super().__init__(1.0 if scale is None else scale, seed)


# ============================================================================= registry

#: canonical name -> injector class, in the order of ``LIBRARY_EFFECTS``
INJECTORS: dict[str, type[EffectInjector]] = {
    c.name: c
    for c in (
        OffsetDriftInjector, GainCrosstalkInjector, CasingLoadInjector, MocapBiasInjector, ChassisFlexInjector,
        TetherForceInjector, HysteresisInjector, LegInertiaInjector, RobotMassInjector, SensorNonlinearityInjector,
        MovingComInjector,
    )
}

if set(INJECTORS) != set(LIBRARY_EFFECTS):  # the contract's names and ours must not drift apart
    raise RuntimeError(f"effect injectors {sorted(INJECTORS)} differ from OUTPUT_FORMAT.md's {sorted(LIBRARY_EFFECTS)}")

for _name, _cls in INJECTORS.items():
    EFFECTS.setdefault(_name, _cls)

__all__ = [
    "HOUR_S",
    "INJECTORS",
    "REF_FORCE_N",
    "REF_TORQUE_NM",
    "CasingLoadInjector",
    "ChassisFlexInjector",
    "EffectInjector",
    "GainCrosstalkInjector",
    "HysteresisInjector",
    "LegInertiaInjector",
    "Magnitude",
    "MocapBiasInjector",
    "MovingComInjector",
    "OffsetDriftInjector",
    "RobotMassInjector",
    "SensorNonlinearityInjector",
    "TetherForceInjector",
    "distribute_over_feet",
    "rotvec_rotate",
    "shaft_speed",
]
