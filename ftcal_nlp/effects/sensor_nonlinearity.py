"""sensor_nonlinearity: a small quadratic term per axis.

Injected (``SensorNonlinearityInjector``): ``w = w_o + w_a + q_k (.) w_a^2``,
``q_kj = s_j scale (1 +- 0.2) / ref_j`` (ref 20 N, 2 N*m; ``scale`` the relative error there).

Model faces:

* standing   c_k = w - q_k (.) (w - w_o)^2      K + 6 (vertical axis per leg, others shared)
* hanging    q (.) w_a^2 on the modelled applied wrench, 6 shared

Correction: the standing face on each sample. Acts while hanging (offset shift).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .faces import WRENCH, LinearFace, ParamBlock
from .injection import REF_FORCE_N, REF_TORQUE_NM, EffectInjector, Magnitude
from .unit import Effect

_REF = np.array([REF_FORCE_N] * 3 + [REF_TORQUE_NM] * 3)


class SensorNonlinearityInjector(EffectInjector):
    """``q_kj w_a,j^2``: ``scale`` is the relative error at the reference load (20 N, 2 N*m)."""

    name = "sensor_nonlinearity"
    magnitude = Magnitude("relative error at 20 N / 2 N*m", (0.003, 0.01), 0.01)

    def coefficients(self, K: int) -> np.ndarray:
        def draw(K):
            sign = self.rng.choice([-1.0, 1.0], 6)
            return sign * self.rng.uniform(0.8, 1.2, (K, 6)) / _REF

        return self.scale * self.drawn("_q", K, draw)

    def readings(self, ctx, w):
        return w + self.coefficients(w.shape[1])[None] * ctx.applied**2


class SensorNonlinearity(Effect):
    name = "sensor_nonlinearity"
    description = "a small quadratic term per axis"
    explains = "load"
    kind = "sensor"
    injector_cls = SensorNonlinearityInjector
    applies_to = frozenset({"hexapod", "free"})   # it needs nothing of a hexapod
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


EFFECT = SensorNonlinearity()
