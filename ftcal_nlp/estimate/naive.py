"""What the robot reads without this calibration: naive taring, and the fit without transformation errors.

Naive taring (report Sec. I-B, Fig. 2): the bias of each transducer is its mean
reading with all feet in the air, upright (the hanging recording whose gravity
is closest to -z of B); readings less that bias are moved to B with the nominal
transducer poses, and their total is compared with the robot's weight and zero
torque about B's origin. What is left is the up-to-20 N imbalance that motivates
the method.

No transformation error (Fig. 6, the report's model 4): the exact balance (E)
with the hanging offsets and leg weights but nominal transducer poses, and only
one CoM translation ``c`` (B axes) fitted by linear least squares. Moving the
reference point by ``c`` changes the torque by ``-(R_WB c) x F = [F] R_WB c``.

Pure functions on arrays; reports plot them, run summaries print their RMS.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..core.data import Recording
from ..core.errors import DataFormatError
from ..core.geometry import quat_to_rotation, remove_yaw, skew, transform_wrench
from ..core.physics import balance_residual_exact
from ..core.robot import Robot

__all__ = ["naive_bias", "naive_total_residuals", "no_transformation_error_residuals", "naive_ground_wrenches"]


def naive_bias(hanging: Sequence[Recording], robot: Robot) -> np.ndarray:
    """(K, 6) mean reading of the upright feet-in-the-air recording, ft_k axes (N, N*m)."""
    if not hanging:
        raise DataFormatError("naive taring needs a hanging recording with the feet in the air")
    up = max(hanging, key=lambda r: float(r.gravity_body @ np.array([0.0, 0.0, -1.0])))
    return up.wrench_array(robot.legs).mean(axis=0)


def naive_total_residuals(w_m: np.ndarray, R_WB: np.ndarray, bias: np.ndarray, robot: Robot) -> np.ndarray:
    """(P, 6) naive-tare total wrench less ``[0, 0, m g, 0, 0, 0]``, W axes about B's origin.

    ``w_m`` (P, K, 6) readings; ``R_WB`` (P, 3, 3); ``bias`` (K, 6) from :func:`naive_bias`."""
    R = np.einsum("pij,kjl->pkil", R_WB, robot.nominal_rotations())
    pos = np.einsum("pij,kj->pki", R_WB, robot.nominal_positions())
    total = transform_wrench(R, pos, w_m - bias).sum(axis=1)
    total[:, 2] -= robot.weight_N
    return total


def no_transformation_error_residuals(w_m: np.ndarray, R_WB: np.ndarray, offsets: np.ndarray, leg_weights_N: np.ndarray,
                                      robot: Robot) -> np.ndarray:
    """(P, 6) exact-balance residual (W axes) with nominal transducer poses and one fitted CoM shift."""
    Mb_g = robot.weight_N - float(np.sum(leg_weights_N))
    r0 = balance_residual_exact(w_m, R_WB, offsets, robot.nominal_rotations(), robot.nominal_positions(), Mb_g)
    F = r0[:, :3] + np.array([0.0, 0.0, Mb_g])
    A = np.einsum("pij,pjk->pik", skew(F), R_WB)
    c, *_ = np.linalg.lstsq(A.reshape(-1, 3), -r0[:, 3:].reshape(-1), rcond=None)
    out = r0.copy()
    out[:, 3:] += A @ c
    return out


def naive_ground_wrenches(rec: Recording, bias: np.ndarray, robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Naive-tare per-foot wrench (N_ok, K, 6) in the heading frame about B's origin, and the row mask
    of rows with a motion-capture orientation (N,)."""
    q = rec.quat
    if q is None:
        raise DataFormatError(f"{rec.path or rec.name}: no columns qw, qx, qy, qz; the naive ground wrenches need the body's orientation")
    ok = np.all(np.isfinite(q), axis=1)
    R_HB = remove_yaw(quat_to_rotation(q[ok]))
    R = np.einsum("nij,kjl->nkil", R_HB, robot.nominal_rotations())
    pos = np.einsum("nij,kj->nki", R_HB, robot.nominal_positions())
    return transform_wrench(R, pos, rec.wrench_array(robot.legs)[ok] - bias), ok
