"""The leg CoM curve ``r(phi)`` as a smoothness-penalised QP (cvxpy + Clarabel).

With the misalignments ``R_j`` and the weight ``m g`` fixed, the torques of
every recording of the leg (report eqs. 6, 7) are linear in the CoM grid
``r_1..r_G`` and the torque offset ``tau_o``:

    tau_m,i = (1 - t_i) r_b x f_j + t_i r_{b+1} x f_j + tau_o + omega_i,  f_j = m g R_j a_j.

The report subtracts (6) - (7) per pair to drop ``tau_o``, solves each pair
by a Kalman smoother (leaving a line per sample unidentified), and fills the
line afterwards from the other pair. Here all recordings enter one problem
with ``tau_o`` free, which is the same as fitting the differences when the
two recordings of a pair share their shaft angles and is exact when they do
not; the line that one pair leaves open is filled by the other pair inside
the same problem. The QP is

    min_{r, tau_o} 1/2 sum_j sum_c W_c ||tau-residual||^2 + lam/2 sum_g ||r_{g+1} - 2 r_g + r_{g-1}||^2
                   + 1/(2 s_p^2) sum_g ||r_g||^2

with periodic second differences (``r`` is periodic in phi) and a weak prior
``s_p = 1 m`` that keeps the problem strictly convex where the data leave a
direction free (unsupported grid angles); it is ~1e-8 of the data's
curvature elsewhere. With a single gravity axis the prior also pins the CoM
component along that axis (``LegProblem.prior_precision``), which the data
cannot fix.

Smoothing weight. ``lam`` is chosen by generalised cross-validation
(Craven & Wahba 1979): ``GCV(lam) = n RSS(lam) / (n - edf(lam))^2`` with
``edf = tr((H + lam P + I/s_p^2)^-1 H)``, ``H`` the data's Gram matrix. RSS and
edf are exact from the compressed recordings, so the search is cheap (a
simultaneous diagonalisation of ``H`` and ``P`` makes every trial ``O(m^2)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cvxpy as cp
import numpy as np
import scipy.linalg as sla
from scipy import sparse

from ...core.geometry import skew
from ...core.solver import SolverError
from .problem import PRIOR_SD_M, LegProblem


def second_difference(n_grid: int) -> np.ndarray:
    """Periodic second-difference operator (G, G): ``(D r)_g = r_{g-1} - 2 r_g + r_{g+1}``."""
    D = -2.0 * np.eye(n_grid)
    idx = np.arange(n_grid)
    D[idx, (idx + 1) % n_grid] += 1.0
    D[idx, (idx - 1) % n_grid] += 1.0
    return D


def torque_design(problem: LegProblem, f: np.ndarray, W_tau: np.ndarray) -> tuple[sparse.csr_matrix, np.ndarray, float]:
    """Weighted linear model of the torques: ``A z ~ b`` with ``z = [vec(r) (3G, x then y then z); tau_o]``.

    ``f`` (J, 3) leg weight vectors in ft_k; ``W_tau`` (3,) inverse noise
    variances. Returns ``A`` (sparse: the pseudo-features keep the band
    structure), ``b`` and the weighted pure error (the part of the RSS that no
    parameter can explain).
    """
    rows_A, rows_b = [], []
    pure = 0.0
    for st, fj in zip(problem.stats, f):
        XG = sparse.csr_matrix(st.X)
        F = skew(fj)  # row form: (r x f)^T = r^T [f]
        for c in range(3):
            w = np.sqrt(W_tau[c])
            tau = np.zeros((st.k, 3))
            tau[:, c] = st.x1
            rows_A.append(w * sparse.hstack([F[0, c] * XG, F[1, c] * XG, F[2, c] * XG, sparse.csr_matrix(tau)]))
            rows_b.append(w * st.Y[:, 3 + c])
        pure += float(W_tau @ st.pure_rss[3:])
    return sparse.vstack(rows_A).tocsr(), np.concatenate(rows_b), pure


def penalty(n_grid: int) -> np.ndarray:
    """``P`` with ``z^T P z = sum_g ||(second difference of r)_g||^2`` (zero on tau_o)."""
    D = second_difference(n_grid)
    P = np.zeros((3 * n_grid + 3, 3 * n_grid + 3))
    P[: 3 * n_grid, : 3 * n_grid] = np.kron(np.eye(3), D.T @ D)
    return P


def prior(n_grid: int, precision: np.ndarray | None = None) -> np.ndarray:
    """Prior precision matrix (3G+3, 3G+3): ``precision`` (3, 3) per grid point (default ``I/s_p^2``), 0 on tau_o."""
    precision = np.eye(3) / PRIOR_SD_M**2 if precision is None else precision
    P = np.zeros((3 * n_grid + 3, 3 * n_grid + 3))
    P[: 3 * n_grid, : 3 * n_grid] = np.kron(precision, np.eye(n_grid))
    return P


@dataclass(frozen=True)
class GCVResult:
    lam: float
    log10_lams: np.ndarray
    scores: np.ndarray
    edf: float


def choose_smoothing(A: sparse.spmatrix, b: np.ndarray, pure: float, n_obs: int, n_grid: int, precision: np.ndarray | None = None) -> GCVResult:
    """Smoothing weight minimising GCV over a log grid (then refined), see module docstring."""
    H = (A.T @ A).toarray()
    g = A.T @ b
    P = penalty(n_grid)
    Pr = prior(n_grid, precision)
    # tau_o has neither penalty nor prior: a tiny ridge keeps M definite without
    # changing anything that is estimable.
    Pr[-3:, -3:] += 1e-12 * np.trace(H) * np.eye(3)
    M = H + Pr
    # one generalised eigenproblem P V = M V diag(sig), V^T M V = I, serves every lam:
    # (M + lam P)^-1 = V diag(1/(1 + lam sig)) V^T
    sig, V = sla.eigh(P, M)
    sig = np.maximum(sig, 0.0)
    Vg = V.T @ g
    q = np.einsum("ki,ki->i", V, Pr @ V)  # diag(V^T Pr V); diag(V^T H V) = 1 - q
    bb = float(b @ b)
    scale = np.trace(H[: 3 * n_grid, : 3 * n_grid]) / np.trace(P)

    def score(log_lam: float) -> tuple[float, float]:
        d = 1.0 / (1.0 + 10.0**log_lam * scale * sig)
        v = d * Vg
        z = V @ v
        rss = bb - 2 * float(Vg @ v) + float(v @ v) - float(z @ Pr @ z) + pure  # z^T H z = z^T M z - z^T Pr z
        edf = float((1.0 - q) @ d)
        return n_obs * rss / (n_obs - edf) ** 2, edf

    logs = np.linspace(-12.0, 2.0, 57)
    sc = np.array([score(x)[0] for x in logs])
    i = int(np.argmin(sc))
    lo, hi = logs[max(i - 1, 0)], logs[min(i + 1, len(logs) - 1)]
    from scipy.optimize import minimize_scalar

    best = minimize_scalar(lambda x: score(x)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    x = float(best.x) if best.fun <= sc[i] else float(logs[i])
    return GCVResult(10.0**x * scale, logs + np.log10(scale), sc, score(x)[1])


def solve_closed_form(A: sparse.spmatrix, b: np.ndarray, lam: float, n_grid: int, precision: np.ndarray | None = None) -> np.ndarray:
    """Numpy twin of :class:`ComQP`: ``(H + lam P + prior) z = A^T b``."""
    M = (A.T @ A).toarray() + lam * penalty(n_grid) + prior(n_grid, precision)
    return np.linalg.solve(M, A.T @ b)


class ComQP:
    """The CoM QP of one leg in cvxpy (Clarabel), parametrised so repeated solves reuse the canonicalisation.

    The data and the prior enter through the Cholesky factor ``L`` of
    ``M = A^T A + prior`` (``||A z - b||^2 + z^T prior z = ||L^T z - L^-1 A^T b||^2 +
    const``), which keeps the parameter small (m x m, m = 3G + 3).
    """

    def __init__(self, leg: str, n_grid: int, precision: np.ndarray | None = None):
        m = 3 * n_grid + 3
        self.leg = leg
        self.n_grid = n_grid
        self.prior = prior(n_grid, precision)
        self.z = cp.Variable(m)
        self.Rf = cp.Parameter((m, m))
        self.c = cp.Parameter(m)
        self.sqrt_lam = cp.Parameter(nonneg=True)
        Dfull = np.zeros((3 * n_grid, m))
        Dfull[:, : 3 * n_grid] = np.kron(np.eye(3), second_difference(n_grid))
        obj = cp.sum_squares(self.Rf @ self.z - self.c) + cp.sum_squares(self.sqrt_lam * (Dfull @ self.z))
        self.prob = cp.Problem(cp.Minimize(0.5 * obj))

    def solve(self, A: sparse.spmatrix, b: np.ndarray, lam: float) -> np.ndarray:
        """Minimiser ``z`` (3G + 3,); raises SolverError if Clarabel does not report optimal."""
        L = np.linalg.cholesky((A.T @ A).toarray() + self.prior)
        c = sla.solve_triangular(L, A.T @ b, lower=True)
        # Scale every term by s^2 so the data are O(1) for the interior-point solver;
        # the minimiser is unchanged.
        s = 1.0 / max(np.abs(L).max(), 1.0)
        self.Rf.value = L.T * s
        self.c.value = c * s
        self.sqrt_lam.value = np.sqrt(lam) * s
        try:
            self.prob.solve(solver=cp.CLARABEL)
        except cp.error.SolverError as exc:
            raise SolverError(f"leg {self.leg}: Clarabel failed on the CoM QP ({exc})", "solver_error") from exc
        if self.prob.status != cp.OPTIMAL:
            raise SolverError(f"leg {self.leg}: CoM QP status '{self.prob.status}' (expected 'optimal')", str(self.prob.status))
        return np.asarray(self.z.value, float)
