"""Effects outside the transducers: tether force, robot mass, mocap bias, leg inertia, moving CoM.

The model face (augmentations) of each; the injectors (the simulator face, with
their formulas) are in :mod:`ftcal_nlp.sim.injectors` and re-exported here:
:class:`TetherForceInjector` (with :func:`distribute_over_feet`),
:class:`RobotMassInjector`, :class:`MocapBiasInjector`, :class:`LegInertiaInjector`,
:class:`MovingComInjector` (none: exact physics; the gap appears when the
calibration uses the report's fixed-CoM balance, eq. 9).

Augmentations (standing face, eq. (A) of base.py):

* tether_force   e_p = [R_HB^T f; a x R_HB^T f]  (a cable at point a)  6 parameters
* robot_mass     e_p = dM g [z; 0]                                 1
* mocap_bias     z~ = Cay(q) z                                     3 (exactly absorbed by
                 free transducer rotations and translations: then the design face,
                 :func:`design_check`, tests for a common rotation of the fitted frames)
* leg_inertia    standing: only the offset shift (static poses see it through the hanging
                 offsets it biased); hanging and walking swing: a scale ``s``
                 of ``-m a = m phi_dot^2 (-r''(phi))`` from the hanging CoM curves (one for
                 the force rows, one for the torque rows ``r x (-m a)``)
* moving_com     the exact balance (E) instead of eq. 9, no new parameter
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ...geometry import cayley, rotation_to_rotvec, skew
from ...sim.injectors import (  # noqa: F401  (re-exported: the injector face lives in the simulator)
    LegInertiaInjector,
    MocapBiasInjector,
    MovingComInjector,
    RobotMassInjector,
    TetherForceInjector,
    distribute_over_feet,
)
from .base import Effect, LinearFace, ParamBlock, per_leg_face

# ----------------------------------------------------------------------------- tether force


class TetherForce(Effect):
    """Standing face: the cable's wrench. Swing face: with free rotations the standing fit
    takes the cable's horizontal force for tilts ``delta_k`` (B axes) of the transducer
    frames (common in sum, spread over the legs by their loads), which then mispredict
    the direction of each swing leg's weight: ``e = (R_k^T delta_k) x f``, 3 parameters
    per leg (rad)."""

    name = "tether_force"
    description = "a constant external wrench on the body (a cable)"
    explains = None
    magnitude = TetherForceInjector.magnitude
    injector_cls = TetherForceInjector

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


# ----------------------------------------------------------------------------- robot mass


class RobotMass(Effect):
    name = "robot_mass"
    description = "the weighed mass is wrong"
    explains = None
    magnitude = RobotMassInjector.magnitude
    injector_cls = RobotMassInjector

    def standing_params(self, ctx):
        return ParamBlock.bounded(("dM [0.1 kg]",), 20.0)

    def standing(self, eta, pose, ctx):
        return pose.w, None, ca.vertcat(0.1 * eta[0] * ctx.g * pose.z, ca.DM.zeros(3))


# ----------------------------------------------------------------------------- mocap bias


class MocapBias(Effect):
    name = "mocap_bias"
    description = "a constant rotation between the motion-capture body and B"
    explains = "body_tilt"
    magnitude = MocapBiasInjector.magnitude
    injector_cls = MocapBiasInjector

    def standing_params(self, ctx):
        return ParamBlock.bounded(("q.x [~deg/1.15]", "q.y", "q.z"), 20.0)

    def standing(self, eta, pose, ctx):
        return pose.w, cayley(0.01 * eta), None


def design_check(R_fitted: np.ndarray, R_nominal: np.ndarray) -> dict:
    """Design face of mocap_bias: do the fitted transducer frames share a common tilt?

    With free rotations the standing fit absorbs a mocap bias exactly (every
    ``R_k`` turns by ``R_b^T``), so it shows only against the design: the mounting
    errors ``delta_k = log(R_k R_nom,k^T)`` (B axes) are independent per leg, a
    bias adds one common tilt. Likelihood ratio of "common tilt + scatter" against
    "scatter" on the x, y components (heading components are not determined by
    level poses): ``dBIC = n ln(SS_1/SS_0) + 2 ln n``, n = 2K.

    Returns the mean tilt (deg), its se, ``delta_bic``, and ``n``.
    """
    d = np.degrees(rotation_to_rotvec(R_fitted @ np.swapaxes(R_nominal, 1, 2)))[:, :2]  # (K, 2)
    K = len(d)
    mean = d.mean(axis=0)
    ss0 = float((d**2).sum())
    ss1 = float(((d - mean) ** 2).sum())
    n = 2 * K
    sd = np.sqrt(ss1 / max(n - 2, 1))
    dbic = n * np.log(max(ss1, 1e-300) / max(ss0, 1e-300)) + 2 * np.log(n)
    return {"tilt_deg": mean, "tilt_se_deg": sd / np.sqrt(K), "delta_bic": float(dbic), "n": n,
            "scatter_deg": float(sd), "rms_before": float(np.sqrt(ss0 / n)), "rms_after": float(np.sqrt(ss1 / n))}


# ----------------------------------------------------------------------------- leg inertia


class LegInertia(Effect):
    name = "leg_inertia"
    description = "inertial wrench of the turning leg (shaft speed squared)"
    explains = "shaft_speed"
    magnitude = LegInertiaInjector.magnitude
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


# ----------------------------------------------------------------------------- moving CoM


class MovingCom(Effect):
    name = "moving_com"
    description = "the legs' CoM motion that a fixed-CoM balance omits"
    explains = "shaft_angle"
    magnitude = MovingComInjector.magnitude
    injector_cls = MovingComInjector
    needs_report_balance = True

    def standing_params(self, ctx):
        return ParamBlock(())

    def standing_balance(self, balance: str) -> str:
        return "exact"


__all__ = [
    "LegInertia",
    "LegInertiaInjector",
    "MocapBias",
    "MocapBiasInjector",
    "MovingCom",
    "MovingComInjector",
    "RobotMass",
    "RobotMassInjector",
    "TetherForce",
    "TetherForceInjector",
    "design_check",
    "distribute_over_feet",
]
