"""Effects outside the transducers: tether force, robot mass, mocap bias, leg inertia, moving CoM.

Injectors:

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

Augmentations (standing face, eq. (A) of base.py):

* tether_force   e_p = [R_HB^T f; R_HB^T tau]                      6 parameters
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

from dataclasses import replace

import casadi as ca
import numpy as np

from ...geometry import cayley, remove_yaw, rotation_to_rotvec, rotvec_to_rotation, skew
from .base import (
    Effect,
    EffectInjector,
    LinearFace,
    Magnitude,
    ParamBlock,
    per_leg_face,
    shaft_speed,
)

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
    magnitude = Magnitude("N of cable force", (1.0, 3.0), 2.0)
    injector_cls = TetherForceInjector

    def standing_params(self, ctx):
        return ParamBlock.bounded(("f.x [N]", "f.y [N]", "f.z [N]", "tau.x [N*m]", "tau.y [N*m]", "tau.z [N*m]"), 20.0)

    def standing(self, eta, pose, ctx):
        Rt = pose.R_HB.T
        return pose.w, None, ca.vertcat(ca.mtimes(Rt, eta[0:3]), ca.mtimes(Rt, eta[3:6]))

    def swing_features(self, legs):
        def make(l):
            Xf = -np.einsum("nij,jk->nik", skew(l.f), l.R_cal.T)          # (R^T delta) x f = -[f] R^T delta
            Xt = np.cross(l.r[:, :, None], Xf, axis=1)
            return np.concatenate([Xf, Xt], axis=1)

        return per_leg_face(legs, make, ("tilt.x [rad]", "tilt.y [rad]", "tilt.z [rad]"))


# ----------------------------------------------------------------------------- robot mass


class RobotMassInjector(EffectInjector):
    """The weighed mass in ``robot.toml`` is off by ``scale`` kg (sign drawn from the seed)."""

    name = "robot_mass"

    def robot(self, robot):
        if not hasattr(self, "_sign"):
            self._sign = float(self.rng.choice([-1.0, 1.0]))
        return replace(robot, mass_kg=float(robot.mass_kg + self._sign * self.scale))


class RobotMass(Effect):
    name = "robot_mass"
    description = "the weighed mass is wrong"
    explains = None
    magnitude = Magnitude("kg of weighing error", (0.05, 0.2), 0.15)
    injector_cls = RobotMassInjector

    def standing_params(self, ctx):
        return ParamBlock.bounded(("dM [0.1 kg]",), 20.0)

    def standing(self, eta, pose, ctx):
        return pose.w, None, ca.vertcat(0.1 * eta[0] * ctx.g * pose.z, ca.DM.zeros(3))


# ----------------------------------------------------------------------------- mocap bias


class MocapBiasInjector(EffectInjector):
    """Motion capture reports ``R_WB R_b``: ``R_b`` tilts by ``scale`` degrees about a horizontal axis
    (a heading component would be invisible and harmless: the heading never enters)."""

    name = "mocap_bias"

    def rotation(self) -> np.ndarray:
        if not hasattr(self, "_Rb"):
            ang = self.rng.uniform(0, 2 * np.pi)
            self._Rb = rotvec_to_rotation(np.radians(self.scale) * np.array([np.cos(ang), np.sin(ang), 0.0]))
        return self._Rb

    def orientation(self, ctx, R_meas):
        return R_meas @ self.rotation()


class MocapBias(Effect):
    name = "mocap_bias"
    description = "a constant rotation between the motion-capture body and B"
    explains = "body_tilt"
    magnitude = Magnitude("deg of tilt between the mocap body and B", (2.0, 3.0), 3.0)
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


class LegInertiaInjector(EffectInjector):
    """``scale`` times the leg's centripetal inertial wrench (1 = physical for these slow legs;
    ``scale = s`` is the physical value of legs turning ``sqrt(s)`` times faster)."""

    name = "leg_inertia"

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
    magnitude = Magnitude("x the physical centripetal wrench (legs sqrt(x) times faster)", (30.0, 100.0), 100.0)
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


class MovingComInjector(EffectInjector):
    """Exact physics (nothing added): the legs' CoMs move, as they always do."""

    name = "moving_com"

    def __init__(self, scale: float | None = None, seed: int = 0):
        super().__init__(1.0 if scale is None else scale, seed)


class MovingCom(Effect):
    name = "moving_com"
    description = "the legs' CoM motion that a fixed-CoM balance omits"
    explains = "shaft_angle"
    magnitude = Magnitude("(none: exact physics; a calibration with balance = 'report')", (1.0, 1.0), 1.0)
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
