"""tether_force: a constant external wrench on the body (a cable).

Injected (``TetherForceInjector``, standing and walking): a force of ``scale`` N in the heading
frame H (z up, x the body's heading: a cable that trails the robot) at a point ``a`` on the body.
The feet carry it (``injection.distribute_over_feet``): the least-norm change of the contact
forces with ``sum_k dF_k = -f`` and ``sum_k (foot_k - c) x dF_k = -(a - c) x f``.

Model faces:

* standing   e_p = [R_HB^T f; a x R_HB^T f]      6 parameters
* walking swing: the tilts ``delta_k`` a free-rotation fit takes the cable's horizontal force
  for, ``e = (R_k^T delta_k) x f``, 3 per leg
* design: a common tilt of the fitted frames

Correction: none per foot (a body effect: the feet carry what they carry).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..core.geometry import remove_yaw, skew
from .faces import ParamBlock, per_leg_face
from .injection import EffectInjector, Magnitude, distribute_over_feet
from .unit import Effect


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


class TetherForce(Effect):
    """Standing face: the cable's wrench. Swing face: with free rotations the standing fit
    takes the cable's horizontal force for tilts ``delta_k`` (B axes) of the transducer
    frames (common in sum, spread over the legs by their loads), which then mispredict
    the direction of each swing leg's weight: ``e = (R_k^T delta_k) x f``, 3 parameters
    per leg (rad)."""

    name = "tether_force"
    description = "a constant external wrench on the body (a cable)"
    explains = None
    kind = "body"
    injector_cls = TetherForceInjector
    design_face = True

    def standing_params(self, ctx):
        names = ("f.x [N]", "f.y [N]", "f.z [N]", "a.x [cm]", "a.y [cm]", "a.z [cm]")
        return ParamBlock(names, np.zeros(6), np.r_[np.full(3, -20.0), np.full(3, -50.0)], np.r_[np.full(3, 20.0), np.full(3, 50.0)])

    def standing(self, eta, pose, ctx):
        # A cable pulls with a force fixed in the heading frame at a point a of the body: its
        # torque about the reference point, a x f, turns with the body (a constant torque would not)
        f_B = ca.mtimes(pose.R_HB.T, eta[0:3])
        return pose.w, None, ca.vertcat(f_B, ca.cross(0.01 * eta[3:6], f_B))

    def swing_features(self, legs):
        def make(l):
            Xf = -np.einsum("nij,jk->nik", skew(l.f), l.R_cal.T)          # (R^T delta) x f = -[f] R^T delta
            Xt = np.cross(l.r[:, :, None], Xf, axis=1)
            return np.concatenate([Xf, Xt], axis=1)

        return per_leg_face(legs, make, ("tilt.x [rad]", "tilt.y [rad]", "tilt.z [rad]"))


EFFECT = TetherForce()
