"""chassis_flex: a transducer's mounting rotation changes with its load.

Injected (``ChassisFlexInjector``): ``w = w_o + Rot(-delta_k) w_a``, ``delta_k = c_k (n_k . f_a) / 20 N``,
``c_k`` horizontal in B (``scale`` degrees per 20 N).

Model faces: ``c_k = w + [delta x f; delta x tau]``, ``delta = c_k (n_k . f) / 20 N``, 3K; the
hanging face the same on the modelled applied wrench.

Correction: the standing face on each sample. Acts while hanging (offset shift).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..core.geometry import skew
from .faces import HangingLeg, ParamBlock, per_leg_face
from .injection import REF_FORCE_N, EffectInjector, Magnitude, rotvec_rotate
from .unit import Effect

_DEG = np.pi / 180.0


class ChassisFlexInjector(EffectInjector):
    """The transducer tilts by ``scale`` degrees per 20 N of its own vertical load (axis horizontal in B)."""

    name = "chassis_flex"
    magnitude = Magnitude("deg of tilt per 20 N of the transducer's vertical load", (0.3, 1.0), 1.0)

    def axes(self, truth) -> np.ndarray:
        """Rotation per newton of vertical load, rad/N, in ft_k (K, 3)."""
        def draw(K):
            ang = self.rng.uniform(0, 2 * np.pi, K)
            amp = self.rng.uniform(0.7, 1.3, K)
            c_B = np.stack([np.cos(ang), np.sin(ang), np.zeros(K)], axis=1) * amp[:, None]
            return np.einsum("kji,kj->ki", truth.R, c_B)  # R_k^T c_B

        return self.scale * _DEG / REF_FORCE_N * self.drawn("_c", len(truth.legs), draw)

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
    kind = "sensor"
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


EFFECT = ChassisFlex()
