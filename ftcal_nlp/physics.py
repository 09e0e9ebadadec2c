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
from .geometry import remove_yaw, transform_wrench

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
    r = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(cal.leg_names)], axis=1)
    w_gc = w_m - offsets - leg_gravity_wrench(u, r, weights)
    total = transform_wrench(R, p, w_gc).sum(axis=1)
    total[:, 2] -= cal.mass_kg * cal.g
    return total


def total_com_from_body_com(phi: np.ndarray, cal: Calibration) -> np.ndarray:
    """CoM of the whole robot relative to the body-without-legs CoM, in B axes, (N, 3) m.

    ``phi`` (N, K) shaft angles in the calibration's leg order.
    """
    _, weights, rotations, p_prime = cal.stacked()
    r = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(cal.leg_names)], axis=1)  # (N, K, 3)
    r_B = np.einsum("kij,nkj->nki", rotations, r) + p_prime
    return np.einsum("k,nki->ni", weights, r_B) / (cal.mass_kg * cal.g)


def ground_wrenches(w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, cal: Calibration) -> np.ndarray:
    """Ground contact wrench on each foot, (N, K, 6), in the heading frame.

    Heading frame (``OUTPUT_FORMAT.md``): origin at the robot's CoM at that
    instant, z up, x the body x axis projected on the horizontal plane. Torques
    are about that CoM. ``w_m`` (N, K, 6), ``phi`` (N, K), ``R_WB`` (N, 3, 3).
    """
    offsets, weights, rotations, p_prime = cal.stacked()
    R_HB = remove_yaw(R_WB)
    u = gravity_dir_in_ft(R_WB[:, None], rotations[None])
    r = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(cal.leg_names)], axis=1)
    w_gc = w_m - offsets - leg_gravity_wrench(u, r, weights)
    c_tot = total_com_from_body_com(phi, cal)  # (N, 3) in B
    R = np.einsum("nij,kjl->nkil", R_HB, rotations)
    p = np.einsum("nij,nkj->nki", R_HB, p_prime[None] - c_tot[:, None])
    return transform_wrench(R, p, w_gc)
