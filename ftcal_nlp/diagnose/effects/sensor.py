"""Effects inside or at the transducer: offset drift, gain crosstalk, sensor nonlinearity,
hysteresis, casing load, chassis flex. Each: injector (sim face) + augmentation (model face).

Injected on the noise-free reading ``w = w_a + w_o`` (report eq. 1) of every
recording (hysteresis: standing only), with ``w_a = ctx.applied``:

* offset_drift        w_o(t) = w_o + d_k (1 - exp(-t/tau)) / (1 - exp(-1 h/tau))   (warm-up, d_k = drift after 1 h)
* gain_crosstalk      w = w_o + (I + E_k) w_a,  E_k on the 3x3 force block
* sensor_nonlinearity w = w_o + w_a + q_k (.) w_a^2,  q_kj = s_j scale (1 +- 0.2) / ref_j
* hysteresis          w = w_a + h (w_a,prev pose - w_a) while standing
* casing_load         w += [M_k (cos phi, sin phi); 0, 0, 0, 0]  (force in the ft xy plane)
* chassis_flex        w = w_o + Rot(-delta_k) w_a,  delta_k = c_k (n_k . f_a) / 20 N, c_k horizontal in B

Augmentations (standing face, eq. (A) of base.py; ``t_h`` hours since hanging):

* offset_drift        e_p = -(D1 t_h + D2 t_h^2)                  12 parameters (B axes)
* gain_crosstalk      c_k = w - [diag(g_k) (f - f_o); 0]           3K (hanging, swing: a full E_k on the weight)
* sensor_nonlinearity c_k = w - q_k (.) (w - w_o)^2               K + 6 (vertical axis per leg, others shared)
* hysteresis          c_k = w - h (w_prev - w)                    1
* casing_load         c_k = w - [M_k (cos phi, sin phi); 0]        4K
* chassis_flex        c_k = w + [delta x f; delta x tau], delta = c_k (n_k . f)/20 N   3K

Every effect here acts while hanging too, so the hanging offsets absorbed part of it:
their standing faces also get the offset shift, a constant wrench in B (6 parameters,
``standing_fit.py``). Parameters are scaled to O(1) (percent, degrees, N per hour) for IPOPT.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ...geometry import skew
from .base import (
    HOUR_S,
    REF_FORCE_N,
    REF_TORQUE_NM,
    WRENCH,
    AugContext,
    Effect,
    EffectInjector,
    HangingLeg,
    LinearFace,
    Magnitude,
    ParamBlock,
    PoseSym,
    per_leg_face,
    rotvec_rotate,
)

_REF = np.array([REF_FORCE_N] * 3 + [REF_TORQUE_NM] * 3)
_DEG = np.pi / 180.0


# ----------------------------------------------------------------------------- offset drift


class OffsetDriftInjector(EffectInjector):
    """Warm-up drift: ``scale`` N of force drift per leg after one hour (torque: scale x 2 cm)."""

    name = "offset_drift"

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


class OffsetDrift(Effect):
    name = "offset_drift"
    description = "offsets change slowly with time over the session (warm-up)"
    explains = "time"
    magnitude = Magnitude("N of force drift per leg after one hour", (1.0, 4.0), 3.0)
    injector_cls = OffsetDriftInjector
    shifts_offsets = True

    def standing_params(self, ctx):
        return ParamBlock.bounded(tuple(f"D1.{c} [/h]" for c in WRENCH) + tuple(f"D2.{c} [/h^2]" for c in WRENCH), 100.0)

    def standing(self, eta, pose: PoseSym, ctx):
        # (plus the offset shift: the hanging offsets average a drift that was already moving)
        return pose.w, None, -(eta[0:6] * pose.t_h + eta[6:12] * pose.t_h2)

    def hanging_features(self, legs):
        def make(l: HangingLeg):
            X = np.zeros((len(l.t), 6, 6))
            X[:, np.arange(6), np.arange(6)] = ((l.t - l.t_ref) / HOUR_S)[:, None]
            return X

        return per_leg_face(legs, make, tuple(f"{c}/h" for c in WRENCH))

    swing_features = hanging_features


# ----------------------------------------------------------------------------- gain crosstalk


class GainCrosstalkInjector(EffectInjector):
    """``(I + E_k)`` on the applied force; entries of E_k ~ N(0, scale) (a fraction)."""

    name = "gain_crosstalk"

    def matrices(self, K: int) -> np.ndarray:
        if not hasattr(self, "_E") or len(self._E) != K:
            self._E = self.rng.normal(0.0, 1.0, (K, 3, 3))
        return self.scale * self._E

    def readings(self, ctx, w):
        E = self.matrices(w.shape[1])
        out = w.copy()
        out[..., :3] += np.einsum("kij,nkj->nki", E, ctx.applied[..., :3])
        return out


class GainCrosstalk(Effect):
    name = "gain_crosstalk"
    description = "readings are (I + E) times the applied wrench, E small"
    explains = "load"
    magnitude = Magnitude("rms of the force-gain matrix entries (fraction)", (0.01, 0.03), 0.02)
    injector_cls = GainCrosstalkInjector
    shifts_offsets = True

    def standing_params(self, ctx):
        return ParamBlock.bounded((f"g[{k}].{c} [%]" for k in ctx.legs for c in "xyz"), 10.0)

    def standing(self, eta, pose, ctx):
        out = []
        for k, w in enumerate(pose.w):
            g = 0.01 * eta[3 * k : 3 * k + 3]
            f = w[0:3] - ctx.w_o[k][0:3]
            out.append(ca.vertcat(w[0:3] - g * f, w[3:6]))
        return out, None, None

    def hanging_features(self, legs):
        # (I + E) on the leg's weight: per recording a constant force error E f_j. Twelve numbers
        # per leg meet twelve parameters of the hanging fit (tilts, weight, force offset), but the
        # torques (r x f_a read, r x f_read modelled) pull the joint fit off, leaving most of E f_j.
        def make(l: HangingLeg):
            X = np.zeros((len(l.t), 6, 9))
            for a in range(3):
                for b in range(3):
                    X[:, a, 3 * a + b] = 0.01 * l.f[:, b]
            return X

        return per_leg_face(legs, make, tuple(f"E{a}{b}%" for a in "xyz" for b in "xyz"))

    swing_features = hanging_features  # a swing leg reads (I + E) on its weight's force


# ----------------------------------------------------------------------------- sensor nonlinearity


class SensorNonlinearityInjector(EffectInjector):
    """``q_kj w_a,j^2``: ``scale`` is the relative error at the reference load (20 N, 2 N*m)."""

    name = "sensor_nonlinearity"

    def coefficients(self, K: int) -> np.ndarray:
        if not hasattr(self, "_q") or len(self._q) != K:
            sign = self.rng.choice([-1.0, 1.0], 6)
            self._q = sign * self.rng.uniform(0.8, 1.2, (K, 6)) / _REF
        return self.scale * self._q

    def readings(self, ctx, w):
        return w + self.coefficients(w.shape[1])[None] * ctx.applied**2


class SensorNonlinearity(Effect):
    name = "sensor_nonlinearity"
    description = "a small quadratic term per axis"
    explains = "load"
    magnitude = Magnitude("relative error at 20 N / 2 N*m", (0.003, 0.01), 0.01)
    injector_cls = SensorNonlinearityInjector
    shifts_offsets = True

    def standing_params(self, ctx):
        # Each transducer has its own curve; standing loads are mostly along the vertical axis,
        # so that one is per leg and the others, small there, are shared.
        return ParamBlock.bounded([f"q[{k}].vertical [% at ref]" for k in ctx.legs] + [f"q.{c} [% at ref]" for c in WRENCH], 10.0)

    def standing(self, eta, pose, ctx):
        K = ctx.K
        out = []
        for k, (w, w2) in enumerate(zip(pose.w, pose.w2)):
            n = np.abs(ctx.vertical_axis(k))  # the vertical axis of a design frame is a coordinate axis here
            qk = eta[K:] * ca.DM(np.r_[1 - n, np.ones(3)]) + eta[k] * ca.DM(np.r_[n, np.zeros(3)])
            q = 0.01 * qk / ca.DM(_REF)
            # (w - w_o)^2 = w^2 - 2 w_o w + w_o^2, linear in the features w2 and w
            out.append(w - q * (w2 - 2 * ctx.w_o[k] * w + ctx.w_o[k] ** 2))
        return out, None, None

    def hanging_features(self, legs):
        out = []
        for l in legs:
            X = np.zeros((len(l.t), 6, 6))
            X[:, np.arange(6), np.arange(6)] = 0.01 * l.applied**2 / _REF
            out.append(X)
        return LinearFace(out, tuple(f"q.{c}%" for c in WRENCH), False)


# ----------------------------------------------------------------------------- hysteresis


class HysteresisInjector(EffectInjector):
    """A standing reading keeps the fraction ``scale`` of the previous pose's load."""

    name = "hysteresis"

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


class Hysteresis(Effect):
    name = "hysteresis"
    description = "a reading keeps a fraction of the previous pose's load"
    explains = "pose_history"
    magnitude = Magnitude("fraction of the previous pose's load kept", (0.005, 0.02), 0.02)
    injector_cls = HysteresisInjector

    def standing_params(self, ctx):
        return ParamBlock.bounded(("h [%]",), 10.0)

    def standing(self, eta, pose, ctx):
        h = 0.01 * eta[0]
        return [w - h * (p - w) for w, p in zip(pose.w, pose.prev)], None, None


# ----------------------------------------------------------------------------- casing load


class CasingLoadInjector(EffectInjector):
    """Parasitic force in the ft xy plane, ``M_k (cos phi, sin phi)``, amplitude ~``scale`` N."""

    name = "casing_load"

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


class CasingLoad(Effect):
    name = "casing_load"
    description = "a parasitic load on the transducer that depends on shaft angle but not on gravity"
    explains = "shaft_angle"
    magnitude = Magnitude("N, amplitude of the shaft-angle dependent force", (0.3, 1.5), 1.0)
    injector_cls = CasingLoadInjector
    shifts_offsets = True

    def standing_params(self, ctx):
        return ParamBlock.bounded((f"M[{k}].{c} [N]" for k in ctx.legs for c in ("x_cos", "x_sin", "y_cos", "y_sin")), 10.0)

    def standing(self, eta, pose, ctx):
        out = []
        for k, w in enumerate(pose.w):
            a = eta[4 * k : 4 * k + 4]
            c, s = pose.cphi[k], pose.sphi[k]
            out.append(w - ca.vertcat(a[0] * c + a[1] * s, a[2] * c + a[3] * s, 0, 0, 0, 0))
        return out, None, None

    def hanging_features(self, legs):
        def make(l: HangingLeg):
            X = np.zeros((len(l.t), 6, 4))
            c, s = np.cos(l.phi), np.sin(l.phi)
            X[:, 0, 0], X[:, 0, 1], X[:, 1, 2], X[:, 1, 3] = c, s, c, s
            return X

        return per_leg_face(legs, make, ("x_cos", "x_sin", "y_cos", "y_sin"))

    swing_features = hanging_features


# ----------------------------------------------------------------------------- chassis flex


class ChassisFlexInjector(EffectInjector):
    """The transducer tilts by ``scale`` degrees per 20 N of its own vertical load (axis horizontal in B)."""

    name = "chassis_flex"

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


class ChassisFlex(Effect):
    name = "chassis_flex"
    description = "a transducer's mounting rotation changes with its load"
    explains = "load"
    magnitude = Magnitude("deg of tilt per 20 N of the transducer's vertical load", (0.3, 1.0), 1.0)
    injector_cls = ChassisFlexInjector
    shifts_offsets = True

    def standing_params(self, ctx):
        return ParamBlock.bounded((f"c[{k}].{c} [deg/20N]" for k in ctx.legs for c in "xyz"), 5.0)

    def standing(self, eta, pose, ctx):
        out = []
        for k, (w, nfw) in enumerate(zip(pose.w, pose.nfw)):
            w_o = ctx.w_o[k]
            n = ca.DM(ctx.vertical_axis(k))
            a, a0 = ca.dot(n, w[0:3]), ca.dot(n, w_o[0:3])
            # (n . d_f) d with d = w - w_o, written linear in the features nfw = (n . f) w and w
            ad = nfw - a * w_o - a0 * w + a0 * w_o
            c = (_DEG / REF_FORCE_N) * eta[3 * k : 3 * k + 3]
            out.append(w + ca.vertcat(ca.cross(c, ad[0:3]), ca.cross(c, ad[3:6])))
        return out, None, None

    def hanging_features(self, legs):
        def make(l: HangingLeg):
            wa = l.applied
            s = (_DEG / REF_FORCE_N) * (wa[:, :3] @ l.n_vert)
            X = np.zeros((len(l.t), 6, 3))
            X[:, 0:3, :] = -s[:, None, None] * skew(wa[:, :3])   # delta x f = -[f] delta
            X[:, 3:6, :] = -s[:, None, None] * skew(wa[:, 3:])
            return X

        return per_leg_face(legs, make, tuple(f"c{c}" for c in "xyz"))


__all__ = [
    "AugContext",
    "CasingLoad",
    "CasingLoadInjector",
    "ChassisFlex",
    "ChassisFlexInjector",
    "GainCrosstalk",
    "GainCrosstalkInjector",
    "Hysteresis",
    "HysteresisInjector",
    "OffsetDrift",
    "OffsetDriftInjector",
    "SensorNonlinearity",
    "SensorNonlinearityInjector",
]
