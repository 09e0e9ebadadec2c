"""The standing balance, one definition for numpy and CasADi (report Sec. III-B, eqs. 8-9).

For pose p the residual of the balance, in B axes (about the body-without-legs
CoM for ``exact``, about the fixed point C for ``report``), is linear in
per-pose features ``xi_p``:

    r_p = L(theta) xi_p.

Exact balance, physics.py eq. (E), with ``Ad_k w = [R_k f; R_k tau + p'_k x R_k f]``
(``geometry.transform_wrench``), ``z_p = R_WB,p^T e_z`` (up in B), ``M_b g`` the
weight of the body without legs (``M g - sum_k m_k g``):

    r_p = sum_k Ad_k (w_m,pk - w_o,k) - M_b g [z_p; 0]
    xi_p = [w_m,p1 .. w_m,pK, 1, z_p]                                       (6K + 4)

Report balance, eq. 9 (each leg's weight subtracted with its hanging CoM curve
``r_k(phi)`` about C, the whole weight ``M g`` balanced there):

    r_p = sum_k Ad_k (w_m,pk - w_o,k) + sum_k m_k g [z_p; (R_k r_k(phi_pk) + p'_k) x z_p] - M g [z_p; 0]
    xi_p = [.. as exact .., r_k(phi_pk) (x) z_p for each k]                 (6K + 4 + 9K)

``(R_k r) x z = sum_{a,l} r_a z_l (R_k e_a x e_l)`` keeps the last features
linear. :func:`residual` is written once with the dual helpers of
``geometry.py``: numpy features ``(P, n_xi)`` give ``(P, 6)`` residuals, a CasADi
column gives a 6-vector. Everything else is derived from it: ``L`` as the
Jacobian of the CasADi residual in ``xi`` (exact, the residual is linear), its
numpy twin as the residual of the identity rows (``standing/problem.py``), and
the diagnosis' augmented balances (corrected readings, corrected up vector).
``physics.py`` keeps an independently written numpy form in W axes as the test
oracle.

The K-norm of eq. 8, ``||r||_K^2 = r^T K r`` with ``K = diag(1, 1, 1, 10, 10, 10)``,
is invariant under the body rotation, so residuals in B and in W have the same norm.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .calibration import Calibration
from .errors import ConfigError, DataFormatError
from .geometry import ArrayLike, _is_symbolic, cross, stack_wrench, transform_wrench
from .settings import BALANCES  # the names live with the settings that choose them

__all__ = ["BALANCES", "K_DIAG", "check_balance", "n_features", "features", "residual", "weights", "knorm2", "to_world"]

K_DIAG = np.array([1.0, 1.0, 1.0, 10.0, 10.0, 10.0])  # eq. 8: torques weighted so N and N*m compare


def check_balance(balance: str) -> str:
    if balance not in BALANCES:
        raise ConfigError(f"unknown balance {balance!r}; known: {list(BALANCES)}", key="standing.balance")
    return balance


def n_features(K: int, balance: str) -> int:
    return 6 * K + 4 + (9 * K if check_balance(balance) == "report" else 0)


def features(w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, prior: Calibration, legs, balance: str) -> np.ndarray:
    """Per-pose features ``xi`` (P, n_xi) of the balance (module docstring).

    ``w_m`` (P, K, 6) raw readings in ft_k; ``phi`` (P, K) rad; ``R_WB`` (P, 3, 3).
    """
    P, K = w_m.shape[:2]
    z = R_WB[:, 2, :]  # R_WB^T e_z: up in B
    cols = [w_m.reshape(P, 6 * K), np.ones((P, 1)), z]
    if check_balance(balance) == "report":
        r = np.stack([prior.legs[k].com(phi[:, i]) for i, k in enumerate(legs)], axis=1)  # (P, K, 3)
        if not np.all(np.isfinite(r)):
            raise DataFormatError("report balance: the prior's leg CoM curves are NaN at some standing shaft angles "
                                  "(the hanging recordings do not cover them)")
        cols.append((r[:, :, :, None] * z[:, None, None, :]).reshape(P, 9 * K))
    return np.concatenate(cols, axis=1)


def weights(prior: Calibration, legs) -> tuple[np.ndarray, float]:
    """Leg weights ``m_k g`` (K,) and the whole weight ``M g`` (N) of a calibration."""
    return np.array([prior.legs[k].leg_weight_N for k in legs], float), float(prior.mass_kg * prior.g)


def _seg(xi: ArrayLike, a: int, b: int) -> ArrayLike:
    """Features ``a:b`` of every pose: numpy (P, b-a), CasADi (b-a, 1)."""
    return xi[a:b] if _is_symbolic(xi) else xi[:, a:b]


def residual(xi: ArrayLike, R, p_prime, offsets, leg_weights_N, weight_N: ArrayLike, balance: str) -> ArrayLike:
    """``r_p = L(theta) xi_p`` of the module docstring, B axes (N, N*m).

    ``xi``: numpy (P, n_xi) or a CasADi column (n_xi,); ``R``: K rotations ft_k -> B
    (numpy (K, 3, 3) or a list of 3x3 CasADi matrices); ``p_prime``: K translations (m);
    ``offsets``: K offsets ``w_o,k`` (6,); ``leg_weights_N`` (K,) ``m_k g``; ``weight_N``
    the whole robot's ``M g``. Linear in ``xi``.
    """
    check_balance(balance)
    K = len(R)
    sym = _is_symbolic(xi)
    one = _seg(xi, 6 * K, 6 * K + 1)
    z = _seg(xi, 6 * K + 1, 6 * K + 4)
    zero3 = ca.SX.zeros(3, 1) if sym else np.zeros_like(z)
    total = 0
    for k in range(K):
        w_o = ca.reshape(offsets[k], 6, 1) if sym and isinstance(offsets[k], np.ndarray) else offsets[k]
        total = total + transform_wrench(R[k], p_prime[k], _seg(xi, 6 * k, 6 * k + 6) - one * w_o)
    m = [leg_weights_N[k] for k in range(K)]
    if balance == "exact":
        Mb_g = weight_N - sum(m)
        return total - stack_wrench(Mb_g * z, zero3)
    base = 6 * K + 4
    for k in range(K):
        Rk = R[k]
        lever = zero3
        for a in range(3):
            col = Rk[:, a]
            for l in range(3):
                e_l = np.eye(3)[l]
                lever = lever + _seg(xi, base + 9 * k + 3 * a + l, base + 9 * k + 3 * a + l + 1) * cross(col, e_l)
        total = total + m[k] * stack_wrench(z, lever + cross(p_prime[k], z))
    return total - stack_wrench(weight_N * z, zero3)


def to_world(r_B: np.ndarray, R_WB: np.ndarray) -> np.ndarray:
    """``blockdiag(R_WB, R_WB) r`` per pose: residuals (P, 6) from B to W axes."""
    return np.concatenate([np.einsum("pij,pj->pi", R_WB, r_B[:, :3]), np.einsum("pij,pj->pi", R_WB, r_B[:, 3:])], axis=1)


def knorm2(r: np.ndarray) -> np.ndarray:
    """``||r_p||_K^2`` per pose (eq. 8), r (P, 6) -> (P,)."""
    return (r**2) @ K_DIAG
