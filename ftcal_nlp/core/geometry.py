"""Rigid-body geometry shared by every estimator: SO(3), SE(3), wrench maps.

One definition serves numpy arrays and CasADi symbols wherever the algebra is
the same (``skew``, ``unskew``, ``cayley``, ``cayley_inv``, ``transform_wrench``):
the functions look at their argument and pick ``numpy`` or ``casadi``.

Notation of the report (Wu & Revzen, Sec. II-A):

* ``T_A^B = (R_A^B, p_A^B)`` maps coordinates in A to coordinates in B:
  ``x^B = R_A^B x^A + p_A^B``; ``p_A^B`` is the origin of A seen from B.
* Wrenches ``w = [f; tau]`` (N, N*m) move between frames by the transposed
  adjoint, ``w^B = [Ad_{T_B^A}]^T w^A`` (the report's unnumbered equation in
  Sec. II-A), i.e. ``f^B = R^T f^A`` and ``tau^B = R^T (tau^A - p x f^A)`` with
  ``(R, p) = T_B^A``.  ``transform_wrench(R, p, w)`` is the same map written
  with the pose of the *source* frame in the *target* frame, which is how the
  robot description states it (``rotation`` and ``position_m`` of ``ft_k`` in B):
  ``f_t = R f_s``, ``tau_t = R tau_s + p x (R f_s)``.
* Cayley map (report eq. after (8)): ``R = (I - [q])(I + [q])^{-1}``.
"""

from __future__ import annotations

from typing import Any, TypeAlias, overload

import casadi as ca
import numpy as np

# A numpy array or a CasADi SX/MX/DM: the functions below are duck-typed over both
# (indexing and arithmetic mean the same), which no static union expresses; the
# argument's own type picks the branch at run time (``_is_symbolic``).
ArrayLike: TypeAlias = Any

_CASADI_TYPES = (ca.SX, ca.MX, ca.DM)


def _is_symbolic(x: Any) -> bool:
    return isinstance(x, _CASADI_TYPES)


def skew(v: ArrayLike) -> ArrayLike:
    """Skew-symmetric matrix ``[v]`` with ``[v] u = v x u``.

    numpy: ``v`` of shape (..., 3) gives (..., 3, 3). CasADi: a 3-vector gives 3x3.
    """
    if _is_symbolic(v):
        return ca.vertcat(
            ca.horzcat(0, -v[2], v[1]),
            ca.horzcat(v[2], 0, -v[0]),
            ca.horzcat(-v[1], v[0], 0),
        )
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def unskew(m: ArrayLike) -> ArrayLike:
    """Inverse of :func:`skew` applied to the skew part of ``m`` ((..., 3, 3) -> (..., 3))."""
    if _is_symbolic(m):
        return 0.5 * ca.vertcat(m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1])
    m = np.asarray(m, dtype=float)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], axis=-1
    )


def cayley(q: ArrayLike) -> ArrayLike:
    """Cayley map ``R = (I - [q])(I + [q])^{-1}``; a proper rotation for every q in R^3.

    Evaluated in closed form, ``((1 - q.q) I + 2 q q^T - 2 [q]) / (1 + q.q)``, which stays
    orthonormal to rounding for any |q| (a linear solve loses ~|q| eps near 180 degrees).
    """
    if _is_symbolic(q):
        qq = ca.dot(q, q)
        return ((1 - qq) * ca.DM.eye(3) + 2 * ca.mtimes(q, q.T) - 2 * skew(q)) / (1 + qq)
    q = np.asarray(q, dtype=float)
    qq = np.sum(q * q, axis=-1)[..., None, None]
    return ((1 - qq) * np.eye(3) + 2 * q[..., :, None] * q[..., None, :] - 2 * skew(q)) / (1 + qq)


def cayley_inv(R: ArrayLike) -> ArrayLike:
    """Inverse Cayley map, ``[q] = (I - R)(I + R)^{-1}`` (undefined for 180 degree rotations)."""
    if _is_symbolic(R):
        eye = ca.DM.eye(3)
        return unskew(ca.mtimes(eye - R, ca.inv(eye + R)))
    R = np.asarray(R, dtype=float)
    eye_n = np.broadcast_to(np.eye(3), R.shape)
    return unskew(np.swapaxes(np.linalg.solve(np.swapaxes(eye_n + R, -1, -2), np.swapaxes(eye_n - R, -1, -2)), -1, -2))


def se3(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous 4x4 matrix of ``(R, p)``; batched over leading axes."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    out = np.zeros(R.shape[:-2] + (4, 4))
    out[..., :3, :3] = R
    out[..., :3, 3] = p
    out[..., 3, 3] = 1.0
    return out


def se3_inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a homogeneous transform (batched)."""
    R = T[..., :3, :3]
    p = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return se3(Rt, -np.einsum("...ij,...j->...i", Rt, p))


def adjoint_transpose(T: np.ndarray) -> np.ndarray:
    """``[Ad_T]^T`` (6x6) for ``T = T_B^A``: maps a wrench in A to the same wrench in B."""
    R = T[..., :3, :3]
    p = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = Rt
    out[..., 3:, :3] = -Rt @ skew(p)
    out[..., 3:, 3:] = Rt
    return out


def cross(a: ArrayLike, b: ArrayLike) -> ArrayLike:
    """``a x b``: numpy arrays (..., 3) broadcast; CasADi 3-vectors."""
    if _is_symbolic(a) or _is_symbolic(b):
        return ca.cross(ca.reshape(a, 3, 1) if isinstance(a, np.ndarray) else a, ca.reshape(b, 3, 1) if isinstance(b, np.ndarray) else b)
    return np.cross(np.asarray(a, float), np.asarray(b, float))


def stack_wrench(f: ArrayLike, tau: ArrayLike) -> ArrayLike:
    """``[f; tau]``: numpy (..., 3) pairs -> (..., 6); CasADi 3-vectors -> 6-vector."""
    if _is_symbolic(f) or _is_symbolic(tau):
        return ca.vertcat(f, tau)
    f, tau = np.broadcast_arrays(np.asarray(f, float), np.asarray(tau, float))
    return np.concatenate([f, tau], axis=-1)


def transform_wrench(R: ArrayLike, p: ArrayLike, w: ArrayLike) -> ArrayLike:
    """Re-express wrench ``w`` (source frame, about its origin) in a target frame.

    ``(R, p)`` is the pose of the source frame in the target frame. numpy: ``w`` has
    shape (..., 6) and ``R``/``p`` broadcast against it; CasADi: 6-vectors.
    Returns ``[R f; R tau + p x R f]`` (N, N*m), i.e. ``[Ad_{T_t^s}]^T w`` with
    ``T_t^s = (R, p)^{-1}``.
    """
    if _is_symbolic(w) or _is_symbolic(R) or _is_symbolic(p):
        f = ca.mtimes(R, w[0:3])
        return ca.vertcat(f, ca.mtimes(R, w[3:6]) + ca.cross(p, f))
    w = np.asarray(w, dtype=float)
    f = np.einsum("...ij,...j->...i", R, w[..., :3])
    tau = np.einsum("...ij,...j->...i", R, w[..., 3:]) + np.cross(np.asarray(p, dtype=float), f)
    return np.concatenate([f, tau], axis=-1)


@overload
def quat_to_rotation(q: np.ndarray) -> np.ndarray: ...
@overload
def quat_to_rotation(q: ca.MX) -> ca.MX: ...
@overload
def quat_to_rotation(q: ca.SX) -> ca.SX: ...
def quat_to_rotation(q: ArrayLike) -> ArrayLike:
    """Rotation matrices from quaternions ``[qw, qx, qy, qz]`` (..., 4); normalised first.

    NaN quaternions give NaN matrices (motion capture lost). CasADi: a 4-vector gives 3x3.
    """
    if _is_symbolic(q):
        q = q / ca.norm_2(q)
        w, x, y, z = q[0], q[1], q[2], q[3]
        return ca.vertcat(
            ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
        )
    q = np.asarray(q, dtype=float)
    R = np.empty(q.shape[:-1] + (3, 3))
    if q.ndim == 2 and len(q) > _QUAT_BLOCK:  # a long series: blocks keep the ~20 temporaries in cache
        for a in range(0, len(q), _QUAT_BLOCK):
            _quat_to_rotation_into(q[a : a + _QUAT_BLOCK], R[a : a + _QUAT_BLOCK])
    else:
        _quat_to_rotation_into(q, R)
    return R


_QUAT_BLOCK = 4096


def _quat_to_rotation_into(q: np.ndarray, R: np.ndarray) -> None:
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


def rotation_to_quat(R: np.ndarray) -> np.ndarray:
    """Quaternions ``[qw, qx, qy, qz]`` (qw >= 0) of rotation matrices (..., 3, 3)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    wxyz *= np.where(wxyz[:, :1] < 0, -1.0, 1.0)
    return wxyz.reshape(R.shape[:-2] + (4,))


def rotvec_to_rotation(v: np.ndarray) -> np.ndarray:
    """Exponential map so(3) -> SO(3) (Rodrigues), batched over leading axes."""
    v = np.asarray(v, dtype=float)
    th = np.linalg.norm(v, axis=-1)[..., None, None]
    K = skew(v)
    small = th < 1e-12
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * K + b * (K @ K)


def rotation_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Logarithm SO(3) -> so(3) as a rotation vector (rad), batched."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def yaw_of(R_WB: np.ndarray) -> np.ndarray:
    """Heading angle (rad) of the body x axis projected on the horizontal plane."""
    return np.arctan2(R_WB[..., 1, 0], R_WB[..., 0, 0])


def remove_yaw(R_WB: ArrayLike) -> ArrayLike:
    """Rotation from B to the heading frame: ``Rz(-yaw) R_WB``; x of the result's
    frame is the body x axis projected on the horizontal plane, z stays up (numpy or CasADi).

    ``Rz(-yaw)`` from the projected x axis ``(R_00, R_10) / h`` directly, no angle
    (identity when the body x axis is vertical, as ``atan2(0, 0) = 0``).
    """
    if _is_symbolic(R_WB):
        h = ca.sqrt(R_WB[0, 0] ** 2 + R_WB[1, 0] ** 2)
        c = ca.if_else(h > 0, R_WB[0, 0] / h, 1)
        s = ca.if_else(h > 0, R_WB[1, 0] / h, 0)
        return ca.vertcat(c * R_WB[0, :] + s * R_WB[1, :], c * R_WB[1, :] - s * R_WB[0, :], R_WB[2, :])
    R_WB = np.asarray(R_WB, dtype=float)
    x0, x1 = R_WB[..., 0, 0], R_WB[..., 1, 0]
    h = np.hypot(x0, x1)
    flat = h == 0
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(flat, 1.0, x0 / h)[..., None]
        s = np.where(flat, 0.0, x1 / h)[..., None]
    out = np.empty(R_WB.shape)
    out[..., 0, :] = c * R_WB[..., 0, :] + s * R_WB[..., 1, :]
    out[..., 1, :] = c * R_WB[..., 1, :] - s * R_WB[..., 0, :]
    out[..., 2, :] = R_WB[..., 2, :]
    return out


def is_rotation(R: np.ndarray, tol: float = 1e-6) -> bool:
    """True when ``R`` is orthonormal with determinant +1 within ``tol``."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.allclose(R.T @ R, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol)


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest proper rotation (Frobenius) to ``M`` via SVD."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit direction ``a`` to unit direction ``b``."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    v = np.cross(a, b)
    s, c = np.linalg.norm(v), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0])
        return rotvec_to_rotation(np.pi * perp / np.linalg.norm(perp))
    return rotvec_to_rotation(v / s * np.arctan2(s, c))
