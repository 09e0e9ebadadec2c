"""Rigid-body statics of a legged robot with hip transducers (numpy).

Symbols (report Sec. II): reading ``w_m`` = applied ``w_a`` + offset ``w_o`` + noise
(eq. 1). The applied wrench is what the leg exerts on the transducer: the leg's
weight ``[m_k g u; r_k(phi) x m_k g u]`` (``u`` the unit gravity direction in
ft_k) plus the ground contact wrench on its foot, both about the ft_k origin.

Balance, physically exact (our default): the body without legs is acted on only
by its own weight and by the legs through the transducers, so for every static
pose p

    sum_k Ad^T(R_WB R_k, R_WB p'_k) (w_m,k - w_o,k) = [0, 0, M_b g, 0, 0, 0]     (E)

about the body's CoM, where ``p'_k`` is the ft_k origin relative to that CoM in
B axes, ``M_b g = m_total g - sum_k m_k g``. The leg CoMs do not enter (E).

Report variant (eq. 9): subtract each leg's gravity wrench about a fixed point C
and balance the whole robot's weight there:

    sum_k [Ad^T (w_m,k - w_o,k) - w_leg,k^C(phi_k)] = [0, 0, M g, 0, 0, 0].     (9)

(9) is exact only if the total CoM sits at C in every pose; with legs that carry
~46 % of the mass and CoMs that move with phi, it leaves a pose-dependent torque
``(c_tot(p) - C) x M g z``.
"""

from __future__ import annotations

import numpy as np

from .calibration import Calibration
from .geometry import remove_yaw, skew, transform_wrench

Z_UP = np.array([0.0, 0.0, 1.0])


def gravity_dir_in_ft(R_WB: np.ndarray, R_k: np.ndarray) -> np.ndarray:
    """Unit gravity direction (pointing down) in ft_k: ``R_k^T R_WB^T (-z)``.

    ``R_WB`` (..., 3, 3), ``R_k`` (3, 3) or broadcastable; returns (..., 3).
    """
    u_B = -R_WB[..., 2, :]  # R_WB^T (-z) is minus the third row of R_WB
    return np.einsum("...ji,...j->...i", R_k, u_B)


def leg_gravity_wrench(u_ft: np.ndarray, r_ft: np.ndarray, leg_weight_N: float | np.ndarray) -> np.ndarray:
    """Wrench of the leg's weight on its transducer, in ft_k about its origin.

    ``u_ft`` (..., 3) unit gravity direction, ``r_ft`` (..., 3) leg CoM (m), both
    in ft_k; returns (..., 6) = ``[m g u; r x m g u]``.
    """
    f = np.asarray(leg_weight_N)[..., None] * u_ft
    return np.concatenate([f, np.cross(r_ft, f)], axis=-1)


def balance_residual_exact(
    w_m: np.ndarray, R_WB: np.ndarray, offsets: np.ndarray, rotations: np.ndarray, p_prime: np.ndarray, body_weight_N: float
) -> np.ndarray:
    """Residual of (E) per pose, in W axes about the body CoM, shape (P, 6).

    ``w_m`` (P, K, 6) readings; ``R_WB`` (P, 3, 3); ``offsets`` (K, 6);
    ``rotations`` (K, 3, 3) ft_k -> B; ``p_prime`` (K, 3) m.
    """
    R = np.einsum("pij,kjl->pkil", R_WB, rotations)
    p = np.einsum("pij,kj->pki", R_WB, p_prime)
    total = transform_wrench(R, p, w_m - offsets).sum(axis=1)
    total[:, 2] -= body_weight_N
    return total


def balance_residual_report(
    w_m: np.ndarray,
    phi: np.ndarray,
    R_WB: np.ndarray,
    cal: Calibration,
    p_prime_C: np.ndarray | None = None,
) -> np.ndarray:
    """Residual of the report's eq. 9, in W axes about a fixed point C, shape (P, 6).

    ``p_prime_C`` (K, 3) are the ft_k origins relative to C in B axes; by default
    C is the body-without-legs CoM (``cal.legs[k].position_from_com_m``).
    """
    offsets, weights, rotations, p_prime = cal.stacked()
    if p_prime_C is not None:
        p_prime = p_prime_C
    R = np.einsum("pij,kjl->pkil", R_WB, rotations)
    p = np.einsum("pij,kj->pki", R_WB, p_prime)
    u = gravity_dir_in_ft(R_WB[:, None], rotations[None])  # (P, K, 3)
    r = cal.leg_coms(phi)
    w_gc = w_m - offsets - leg_gravity_wrench(u, r, weights)
    total = transform_wrench(R, p, w_gc).sum(axis=1)
    total[:, 2] -= cal.mass_kg * cal.g
    return total


def total_com_from_body_com(phi: np.ndarray, cal: Calibration) -> np.ndarray:
    """CoM of the whole robot relative to the body-without-legs CoM, in B axes, (N, 3) m.

    ``phi`` (N, K) shaft angles in the calibration's leg order.
    """
    _, weights, rotations, p_prime = cal.stacked()
    r = cal.leg_coms(phi)  # (N, K, 3)
    r_B = np.einsum("kij,nkj->nki", rotations, r) + p_prime
    return np.einsum("k,nki->ni", weights, r_B) / (cal.mass_kg * cal.g)


# samples per block of ground_wrenches: small enough that the intermediates stay in cache
_BLOCK = 2048


def _sub_cross(out: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """``out -= a x b`` over the last axis (3), in place, by components (np.cross copies and is slow on 3-vectors)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out[..., 0] -= a1 * b2 - a2 * b1
    out[..., 1] -= a2 * b0 - a0 * b2
    out[..., 2] -= a0 * b1 - a1 * b0


def ground_wrenches(w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, cal: Calibration, out: np.ndarray | None = None) -> np.ndarray:
    """Ground contact wrench on each foot, (N, K, 6), in the heading frame (written into ``out`` when given).

    Heading frame (``OUTPUT_FORMAT.md``): origin at the robot's CoM at that
    instant, z up, x the body x axis projected on the horizontal plane. Torques
    are about that CoM. ``w_m`` (N, K, 6), ``phi`` (N, K), ``R_WB`` (N, 3, 3).

    Per leg ``w_gc = w_m - w_o - [m_k g u_k; r_k(phi) x m_k g u_k]`` (eq. 3),
    moved to B about the total CoM ``c`` and turned by ``R_HB = Rz(-yaw) R_WB``.
    Evaluated in cache-sized blocks of samples and rearranged for speed: with
    ``F, T = Ad^T(R_k, p'_k) (w_m - w_o)`` (one constant matrix per leg), the
    leg's CoM in B ``s_k = R_k r_k + p'_k`` and ``a_k = R_HB (s_k - c)``, the
    leg weight's share is exact in the heading frame, where gravity is ``-z``:

        f_H = R_HB F + m_k g z,   tau_H = R_HB (T - c x F) + m_k g [a_y, -a_x, 0].
    """
    offsets, weights, rotations, p_prime = cal.stacked()
    N, K = np.shape(phi)
    ad = np.zeros((K, 6, 6))
    ad[:, :3, :3] = ad[:, 3:, 3:] = rotations
    ad[:, 3:, :3] = skew(p_prime) @ rotations
    ad_T = ad.transpose(0, 2, 1)
    share = np.kron(weights[:, None] / (cal.mass_kg * cal.g), np.eye(3))  # c = s (flat, n x 3K) @ share
    leg_com_B = cal.leg_com_interpolator(in_body=True)  # s_k(phi), the grids turned into B once
    if out is None:
        out = np.empty((N, K, 6))
    elif out.shape != (N, K, 6):
        raise ValueError(f"ground_wrenches: out must have shape {(N, K, 6)}, got {out.shape}")
    for a in range(0, N, _BLOCK):
        b = min(a + _BLOCK, N)
        n = b - a
        s = leg_com_B(phi[a:b])
        c = s.reshape(n, 3 * K) @ share
        v = np.empty((n, K, 9))  # F, T about c, s - c: every vector the heading rotation turns
        v[..., :6] = np.matmul((w_m[a:b] - offsets).transpose(1, 0, 2), ad_T).transpose(1, 0, 2)
        _sub_cross(v[..., 3:6], c[:, None, :], v[..., :3])
        np.subtract(s, c[:, None, :], out=v[..., 6:])
        v = (v.reshape(n, 3 * K, 3) @ remove_yaw(R_WB[a:b]).transpose(0, 2, 1)).reshape(n, K, 9)
        o = out[a:b]
        o[:] = v[..., :6]
        o[..., 2] += weights
        o[..., 3] += weights * v[..., 7]
        o[..., 4] -= weights * v[..., 6]
    return out
