"""leg_inertia: the inertial wrench of the turning leg (shaft speed squared).

Injected (``LegInertiaInjector``): the leg's inertial force ``-m_k a_k``, ``a_k = r_k''(phi) phi_dot^2``
(centripetal), times ``scale`` (1 = physical; ``scale = s`` is the physical value of legs turning
``sqrt(s)`` times faster).

Model faces: standing, only the offset shift (static poses see it through the hanging offsets it
biased); hanging and walking swing, a scale of ``-m a = m phi_dot^2 (-r''(phi))`` from the hanging
CoM curves (one for the force rows, one for the torque rows ``r x (-m a)``).

Correction: none per foot (a body effect: static in the standing poses).
"""

from __future__ import annotations

import numpy as np

from .faces import LinearFace, ParamBlock
from .injection import EffectInjector, Magnitude, shaft_speed
from .unit import Effect


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


class LegInertia(Effect):
    name = "leg_inertia"
    description = "inertial wrench of the turning leg (shaft speed squared)"
    explains = "shaft_speed"
    kind = "body"
    injector_cls = LegInertiaInjector
    shifts_offsets = True  # static poses see it only through the hanging offsets it shifted

    def standing_params(self, ctx):
        return ParamBlock(())

    def _features(self, legs):
        # Force and torque rows get their own scale: the hanging fit's CoM curve absorbs part of
        # the inertial torque r x (-m a) (it is periodic in phi like r x m g u), not of the force.
        out = []
        for l in legs:
            f = -(l.mg / l.g) * l.r_dd * (l.omega**2)[:, None]
            X = np.zeros((len(f), 6, 2))
            X[:, :3, 0] = f
            X[:, 3:, 1] = np.cross(l.r, f)
            out.append(X)
        return LinearFace(out, ("s_force (x physical)", "s_torque (x physical)"), False)

    def hanging_features(self, legs):
        return self._features(legs)

    def swing_features(self, legs):
        return self._features(legs)


EFFECT = LegInertia()
