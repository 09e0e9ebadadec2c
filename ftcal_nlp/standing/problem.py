"""The standing balance as a residual linear in per-pose features (report Sec. III-B).

Every balance we fit has, for pose p, a residual in B axes (about the body CoM
for ``exact``, about the fixed point C for ``report``)

    r_p = L(theta) xi_p,      L: 6 x n_xi, polynomial in the unknowns theta,

with data features ``xi_p``. The K-norm of eq. 8, ``||r||_K^2 = r^T K r`` with
``K = diag(1, 1, 1, 10, 10, 10)``, is invariant under the body rotation (it
weights the force and torque blocks uniformly), so residuals in B and in W
(``blockdiag(R_WB, R_WB) r_p``) have the same norm, and the objective of eq. 8
reduces to the moments ``S = sum_p xi_p xi_p^T / P``:

    (1/P) sum_p ||r_p||_K^2 = sum_i K_ii (L S L^T)_ii.

This makes one IPOPT iteration independent of the number of poses and lets
cross-validation folds change only the parameter S.

Efficient weighting (``weighting="fgls"`` of ``fit_standing``): K is not the inverse
noise covariance of r_p (the readings' noise reaches r_p through the Ad_k and
couples force and torque), so two-step feasible GLS refits with a constant
``W = C^-1``, ``C = mean_p r_p r_p^T`` of the K fit (B axes); the objective stays
``tr(W L S L^T)``. W is constant in B, so unlike K it is not invariant under the
body rotation; the poses' residuals are all expressed in B.

Exact balance, physics.py eq. (E), with ``Ad_k = [[R_k, 0], [[p'_k] R_k, R_k]]``,
``z_p = R_WB,p^T e_z`` (up in B), ``M_b g`` the weight of the body without legs:

    r_p = sum_k Ad_k (w_m,pk - w_o,k) - M_b g [z_p; 0]
    xi_p = [w_m,p1 .. w_m,pK, 1, z_p]                                     (6K + 4)

Report balance, eq. 9 (leg weights subtracted with the hanging CoM curves
``r_k(phi)`` about a fixed point C, whole weight ``M g`` balanced there):

    r_p = sum_k Ad_k (w_m,pk - w_o,k) + sum_k m_k g [z_p; (R_k r_k(phi_pk) + p'_k) x z_p] - M g [z_p; 0]
    xi_p = [.. as exact .., r_k(phi_pk) (x) z_p for each k]                (6K + 4 + 9K)

``(R_k r) x z = sum_{a,l} r_a z_l (R_k e_a x e_l)`` is what makes the last
features linear. The numpy twins (:func:`L_numpy`) serve the baseline solver
and the residuals; both are checked against ``physics.py``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..calibration import Calibration
from ..geometry import skew

K_DIAG = np.array([1.0, 1.0, 1.0, 10.0, 10.0, 10.0])  # eq. 8: torques weighted so N and N*m compare
BALANCES = ("exact", "report")


def check_balance(balance: str) -> str:
    if balance not in BALANCES:
        raise ValueError(f"unknown balance {balance!r}; known: {list(BALANCES)}")
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
            raise ValueError("report balance: the prior's leg CoM curves are NaN at some standing shaft angles")
        cols.append((r[:, :, :, None] * z[:, None, None, :]).reshape(P, 9 * K))
    return np.concatenate(cols, axis=1)


def _weights(prior: Calibration, legs) -> tuple[np.ndarray, float, float]:
    """Leg weights m_k g (K,), body-without-legs weight M_b g and whole weight M g (N)."""
    m = np.array([prior.legs[k].leg_weight_N for k in legs])
    Mg = prior.mass_kg * prior.g
    return m, Mg - m.sum(), Mg


# ----------------------------------------------------------------------------- CasADi


def ad_casadi(R: ca.SX, p: ca.SX) -> ca.SX:
    """``[[R, 0], [[p] R, R]]`` (6x6): wrench in ft_k about its origin -> B about the reference point."""
    return ca.blockcat([[R, ca.SX.zeros(3, 3)], [ca.mtimes(skew(p), R), R]])


def L_casadi(R, p_prime, offsets, prior: Calibration, legs, balance: str) -> ca.SX:
    """``L(theta)`` (6 x n_xi) from K rotations, K translations and K offsets (SX or DM)."""
    K = len(legs)
    m, Mb_g, _ = _weights(prior, legs)
    Ads = [ad_casadi(ca.SX(R[k]), ca.SX(p_prime[k])) for k in range(K)]
    const = -sum((ca.mtimes(Ads[k], ca.SX(offsets[k])) for k in range(K)), ca.SX.zeros(6, 1))
    zcol = ca.vertcat(-Mb_g * ca.SX.eye(3), ca.SX.zeros(3, 3))
    blocks = Ads + [const]
    if check_balance(balance) == "report":
        zcol = ca.vertcat(-Mb_g * ca.SX.eye(3), sum((m[k] * skew(ca.SX(p_prime[k])) for k in range(K)), ca.SX.zeros(3, 3)))
        blocks.append(zcol)
        for k in range(K):
            Rk = ca.SX(R[k])
            blocks.append(ca.vertcat(ca.SX.zeros(3, 9), m[k] * ca.horzcat(*[skew(Rk[:, a]) for a in range(3)])))
    else:
        blocks.append(zcol)
    return ca.horzcat(*blocks)


# ----------------------------------------------------------------------------- numpy twins


def ad_numpy(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """numpy twin of :func:`ad_casadi`, batched: R (..., 3, 3), p (..., 3) -> (..., 6, 6)."""
    out = np.zeros(R.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., 3:, :3] = skew(p) @ R
    return out


def L_numpy(R: np.ndarray, p_prime: np.ndarray, offsets: np.ndarray, prior: Calibration, legs, balance: str) -> np.ndarray:
    """numpy twin of :func:`L_casadi`: R (K, 3, 3), p_prime (K, 3), offsets (K, 6) -> (6, n_xi)."""
    K = len(legs)
    m, Mb_g, _ = _weights(prior, legs)
    Ad = ad_numpy(R, p_prime)  # (K, 6, 6)
    L = np.zeros((6, n_features(K, balance)))
    L[:, : 6 * K] = np.concatenate(list(Ad), axis=1)
    L[:, 6 * K] = -np.einsum("kij,kj->i", Ad, offsets)
    L[:3, 6 * K + 1 : 6 * K + 4] = -Mb_g * np.eye(3)
    if check_balance(balance) == "report":
        L[3:, 6 * K + 1 : 6 * K + 4] = np.einsum("k,kij->ij", m, skew(p_prime))
        Sk = m[:, None, None, None] * skew(np.swapaxes(R, 1, 2))  # [k, a] = m_k [R_k e_a]
        L[3:, 6 * K + 4 :] = Sk.transpose(2, 0, 1, 3).reshape(3, 9 * K)
    return L


def residuals_B(L: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Per-pose residuals in B axes, (P, 6)."""
    return xi @ L.T


def to_world(r_B: np.ndarray, R_WB: np.ndarray) -> np.ndarray:
    """``blockdiag(R_WB, R_WB) r`` per pose: residuals (P, 6) from B to W axes."""
    return np.concatenate([np.einsum("pij,pj->pi", R_WB, r_B[:, :3]), np.einsum("pij,pj->pi", R_WB, r_B[:, 3:])], axis=1)


def knorm2(r: np.ndarray) -> np.ndarray:
    """``||r_p||_K^2`` per pose (eq. 8), r (P, 6) -> (P,)."""
    return (r**2) @ K_DIAG


def moments(xi: np.ndarray) -> np.ndarray:
    """``S = xi^T xi / P`` (n_xi, n_xi): all the data eq. 8 needs."""
    return xi.T @ xi / len(xi)


def objective_casadi(L, S, W=None):
    """``tr(W L S L^T)`` (SX or MX): the mean W-norm residual over the poses summarised by S.

    ``W`` (6x6, symmetric) defaults to eq. 8's ``K``; the feasible GLS fit passes the inverse
    residual covariance (a parameter of the compiled solver, like S)."""
    W = ca.DM(np.diag(K_DIAG)) if W is None else W
    return ca.sum1(ca.sum2(ca.mtimes(W, ca.mtimes(L, S)) * L))


def fgls_weight(r_B: np.ndarray, rel_floor: float = 1e-8) -> np.ndarray:
    """``W = C^-1`` with ``C = mean_p r_p r_p^T`` (6x6, B axes), the efficient constant weight.

    Eigenvalues of C below ``rel_floor`` times the largest are raised to it (fewer than 6 poses,
    or a noise-free block), so W stays finite; an all-zero C (noise-free data) gives ``K``."""
    C = r_B.T @ r_B / max(len(r_B), 1)
    lam, V = np.linalg.eigh((C + C.T) / 2)
    if not np.isfinite(lam).all() or lam.max() <= 0:
        return np.diag(K_DIAG)
    lam = np.maximum(lam, rel_floor * lam.max())
    return (V / lam) @ V.T
