"""The standing problem of eq. 8: the balance as ``r_p = L(theta) xi_p`` and its moments.

The balance itself (exact (E) or the report's eq. 9, features ``xi_p``) is
defined once in ``balance.py``; here ``L(theta)`` is read off it, as the
Jacobian in ``xi`` of the CasADi residual (:func:`L_casadi`) and as the residual
of the identity rows in numpy (:func:`L_numpy`, for the baseline solver and the
residuals). Both are exact because the residual is linear in ``xi``.

The K-norm objective of eq. 8 reduces to the moments ``S = sum_p xi_p xi_p^T / P``:

    (1/P) sum_p ||r_p||_K^2 = sum_i K_ii (L S L^T)_ii,

which makes one IPOPT iteration independent of the number of poses and lets
cross-validation folds change only the parameter S.

Efficient weighting (``weighting="fgls"`` of ``fit_standing``): K is not the inverse
noise covariance of r_p (the readings' noise reaches r_p through the Ad_k and
couples force and torque), so two-step feasible GLS refits with a constant
``W = C^-1``, ``C = mean_p r_p r_p^T`` of the K fit (B axes); the objective stays
``tr(W L S L^T)``. W is constant in B, so unlike K it is not invariant under the
body rotation; the poses' residuals are all expressed in B.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca
import numpy as np

from ...core.balance import BALANCES, K_DIAG, check_balance, features, knorm2, n_features, residual, to_world, weights
from ...core.calibration import Calibration

__all__ = ["BALANCES", "K_DIAG", "check_balance", "features", "knorm2", "n_features", "to_world", "L_casadi", "L_numpy",
           "L_numpy_jacobian", "residuals_B", "moments", "objective_casadi", "fgls_weight"]


def L_casadi(R, p_prime, offsets, prior: Calibration, legs, balance: str) -> ca.SX:
    """``L(theta)`` (6 x n_xi) from K rotations, K translations and K offsets (SX or DM)."""
    m, Mg = weights(prior, legs)
    xi = ca.SX.sym("xi", n_features(len(legs), balance))
    r = residual(xi, [ca.SX(Rk) for Rk in R], [ca.SX(pk) for pk in p_prime], [ca.SX(o) for o in offsets], m, Mg, balance)
    return ca.jacobian(r, xi)


@lru_cache(maxsize=None)
def _L_function(K: int, balance: str) -> ca.Function:
    """``L`` and its Jacobians in the rotations, translations and offsets, compiled as functions of
    (rotations, translations, offsets, leg weights, M g): the numeric twins evaluate the same
    symbolic definition (one call each; the baseline solver calls them every iteration)."""
    R = [ca.SX.sym(f"R{k}", 3, 3) for k in range(K)]
    p = [ca.SX.sym(f"p{k}", 3) for k in range(K)]
    off = [ca.SX.sym(f"o{k}", 6) for k in range(K)]
    m = ca.SX.sym("m", K)
    Mg = ca.SX.sym("Mg")
    xi = ca.SX.sym("xi", n_features(K, balance))
    L = ca.jacobian(residual(xi, R, p, off, [m[k] for k in range(K)], Mg, balance), xi)
    Rv, pv, ov = ca.vertcat(*[ca.vec(Rk) for Rk in R]), ca.vertcat(*p), ca.vertcat(*off)
    vL = ca.vec(L)
    outs = [L, ca.jacobian(vL, Rv), ca.jacobian(vL, pv), ca.jacobian(vL, ov)]
    return ca.Function("L_num", [Rv, pv, ov, m, Mg], [ca.densify(o) for o in outs])


def _call(R, p_prime, offsets, prior: Calibration, legs, balance: str) -> list[np.ndarray]:
    m, Mg = weights(prior, legs)
    return L_values(R, p_prime, offsets, m, Mg, balance)


def L_values(R, p_prime, offsets, leg_weights_N, weight_N: float, balance: str) -> list[np.ndarray]:
    """``[L, dvecL/dR, dvecL/dp', dvecL/dw_o]`` at given leg weights and whole weight, numpy: :func:`_L_function`
    evaluated straight into numpy arrays (CasADi's function buffer: converting large DM outputs
    element by element would cost more than the evaluation)."""
    m, Mg = leg_weights_N, weight_N
    f = _L_function(len(R), check_balance(balance))
    args = [np.ascontiguousarray(np.swapaxes(np.asarray(R, float), 1, 2).ravel()), np.asarray(p_prime, float).ravel().copy(),
            np.asarray(offsets, float).ravel().copy(), np.asarray(m, float).copy(), np.array([float(Mg)])]
    flat = [np.zeros(f.nnz_out(i)) for i in range(f.n_out())]  # dense outputs, column-major
    buf, trigger = f.buffer()
    for i, a in enumerate(args):
        buf.set_arg(i, memoryview(a))  # type: ignore[call-arg, arg-type]  # stubs: CasADi's wants the byte size SWIG reads off the buffer; numpy's ndarray is a buffer
    for i, o in enumerate(flat):
        buf.set_res(i, memoryview(o))  # type: ignore[call-arg, arg-type]  # (as set_arg)
    trigger()
    return [o.reshape(f.size_out(i), order="F") for i, o in enumerate(flat)]


def L_numpy(R: np.ndarray, p_prime: np.ndarray, offsets: np.ndarray, prior: Calibration, legs, balance: str) -> np.ndarray:
    """numpy twin of :func:`L_casadi`: R (K, 3, 3), p_prime (K, 3), offsets (K, 6) -> (6, n_xi)."""
    return _call(R, p_prime, offsets, prior, legs, balance)[0]


def L_numpy_jacobian(R: np.ndarray, p_prime: np.ndarray, offsets: np.ndarray, prior: Calibration, legs, balance: str,
                     which: str) -> np.ndarray:
    """``dL / d(entries of R, p' or offsets)``, (n, 6, n_xi), entries in C order of ``R`` (K, 3, 3),
    ``p_prime`` (K, 3) or ``offsets`` (K, 6); ``which`` is ``"R"``, ``"p"`` or ``"o"``."""
    out = _call(R, p_prime, offsets, prior, legs, balance)
    J = {"R": out[1], "p": out[2], "o": out[3]}[which]
    n_xi = out[0].shape[1]
    J = J.reshape(n_xi, 6, -1).transpose(2, 1, 0)  # vec(L) is column-major: row i + 6 j
    if which == "R":  # vec(R_k) is column-major too: entry (k, i, j) at 9 k + i + 3 j
        K = len(legs)
        J = J[[9 * k + i + 3 * j for k in range(K) for i in range(3) for j in range(3)]]
    return J


def residuals_B(L: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Per-pose residuals in B axes, (P, 6)."""
    return xi @ L.T


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
