"""Standard errors of the hanging fit: Fisher information at the optimum.

Local coordinates around the optimum: for each recording the tilt
``eta_j`` in R^2 with ``R_j = R_j* exp([B_j eta_j])`` (``B_j`` spans the plane
perpendicular to ``a_j``: rotations about ``a_j`` are the gauge fixed in the
NLP), then ``m g``, ``w_o`` (6) and the CoM grid ``r`` (3G). With the residuals
standardised by the per-component noise variances ``sigma_c^2`` estimated from
the fit, the Gauss-Newton Hessian of the joint objective

    J = 1/2 sum_i sum_c (e_ic / sigma_c)^2 + lam/2 ||D2 r||^2 + 1/(2 s_p^2) ||r||^2

is ``H = Jac^T Jac + lam P + I/s_p^2`` and the covariance is ``H^-1``. For the
offsets, weight and tilts (unpenalised) this is the usual Fisher information
with the CoM curve profiled out; for the penalised CoM grid it is the Bayesian
posterior covariance of a smoothing spline (Wahba 1983), whose intervals
account on average for the smoothing bias as well as the noise.
The Jacobian is exact (CasADi, built with the NLP in nlp.py) and evaluated on the compressed recordings,
which give the same ``Jac^T Jac`` as the raw samples (binning.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ...core.solver import identifiability
from .com_qp import penalty, prior

# Only numerically singular directions are dropped: the penalised CoM grid and the weak prior make H
# regular wherever the data leave a direction open (those come out with large, honest se).
PINV_REL_TOL = 1e-13
from .model import LegState
from .nlp import HangingNLP
from .problem import LegProblem, tangent_basis


@dataclass(frozen=True)
class LegCovariance:
    """Covariance of the local parameters and the slices that address it."""

    cov: np.ndarray
    eta: list[slice]
    mg: int
    w_o: slice
    r: slice
    bases: list[np.ndarray]

    def se(self, sl) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov)[sl], 0.0))

    def physical(self, n_grid: int) -> np.ndarray:
        """Covariance of the physical parameters in the order of ``result.leg_param_names``:
        ``w_o`` (6), ``m g``, the CoM grid point by point (x, y, z per angle), then each
        recording's tilt as a rotation vector ``B_j eta_j`` (3), rad."""
        n_loc = self.cov.shape[0]
        J = len(self.eta)
        G = n_grid
        D = np.zeros((7 + 3 * G + 3 * J, n_loc))
        D[:6, self.w_o] = np.eye(6)
        D[6, self.mg] = 1.0
        r0 = self.r.start
        for i in range(G):
            for c in range(3):
                D[7 + 3 * i + c, r0 + c * G + i] = 1.0  # r is stored component-major: x_0..x_G-1, y.., z..
        for j in range(J):
            D[7 + 3 * G + 3 * j : 10 + 3 * G + 3 * j, self.eta[j]] = self.bases[j]
        return D @ self.cov @ D.T

    def rotvec_se(self, j: int) -> np.ndarray:
        """Standard error (3,) of the misalignment rotation vector of recording ``j``, rad."""
        B = self.bases[j]
        C = B @ self.cov[self.eta[j], self.eta[j]] @ B.T
        return np.sqrt(np.maximum(np.diag(C), 0.0))


def leg_covariance(problem: LegProblem, nlp: HangingNLP, state: LegState, W: np.ndarray, lam: float) -> LegCovariance:
    """``H^-1`` of the joint objective at ``state`` (see module docstring)."""
    J, G = problem.n_rec, problem.n_grid
    bases = [tangent_basis(a) for a in problem.a]
    Jac, C = nlp.jacobian(problem, state, W, bases)
    H = Jac.T @ Jac
    n0 = 2 * J + 7
    n = 3 * G
    H[n0:, n0:] += lam * penalty(G)[:n, :n] + prior(G, problem.prior_precision)[:n, :n]
    if len(C):  # gauge constraints (single gravity axis): covariance on their null space
        Z = sla.null_space(C)
        cov = Z @ identifiability(Z.T @ H @ Z, PINV_REL_TOL).pinv() @ Z.T
    else:
        cov = identifiability(H, PINV_REL_TOL).pinv()
    return LegCovariance(cov, [slice(2 * j, 2 * j + 2) for j in range(J)], 2 * J, slice(2 * J + 1, 2 * J + 7), slice(n0, n0 + 3 * G), bases)
