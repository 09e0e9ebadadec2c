"""The hanging measurement model (report eqs. 4-7, exact rotation), numpy and CasADi twins.

For leg k and hanging recording j with nominal gravity axis ``a_j`` in ft_k
(``a_j = R_k,nom^T gravity_body_j``) and misalignment ``R_j`` in SO(3):

    f_m,i = m_k g R_j a_j + f_o + nu_i                       (4), (5)
    tau_m,i = r(phi_i) x (m_k g R_j a_j) + tau_o + omega_i   (6), (7)

The report writes ``R_j ~ I + [s_j]`` (infinitesimal) and the up-recording
with ``-a``; here the sign sits in ``a_j`` and ``R_j`` is exact. ``r(phi)`` is
periodic linear interpolation of the grid ``r_1..r_G`` (see binning.py), so
each recording is compared through its compressed pseudo-samples:

    Y~_j - X~_j M_j^T,   M_j[:, g] = [f_j + f_o; r_g x f_j + tau_o],  f_j = m_k g R_j a_j.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ...core.geometry import skew
from .problem import LegProblem


@dataclass(frozen=True)
class LegState:
    """Parameters of one leg: ``R`` (J, 3, 3) misalignments, ``mg`` N, ``w_o`` (6,)
    offset (N, N*m), ``r`` (G, 3) CoM grid in ft_k, m."""

    R: np.ndarray
    mg: float
    w_o: np.ndarray
    r: np.ndarray

    def forces(self, a: np.ndarray) -> np.ndarray:
        """Leg weight vectors ``f_j = m g R_j a_j`` (J, 3), N."""
        return self.mg * np.einsum("jab,jb->ja", self.R, a)


def pseudo_residuals(problem: LegProblem, s: LegState) -> list[np.ndarray]:
    """Residuals of the compressed recordings, one (K_j, 6) array per recording."""
    out = []
    for st, f in zip(problem.stats, s.forces(problem.a)):
        XG, x1 = st.X, st.x1
        pred_f = np.outer(x1, f + s.w_o[:3])
        pred_t = (XG @ s.r) @ skew(f) + np.outer(x1, s.w_o[3:])  # rows: (r x f)^T = r^T [f]
        out.append(st.Y - np.hstack([pred_f, pred_t]))
    return out


def rss(problem: LegProblem, s: LegState) -> np.ndarray:
    """Residual sum of squares per component over every sample of the leg (6,), exact."""
    res = pseudo_residuals(problem, s)
    return sum(np.einsum("kc,kc->c", e, e) for e in res) + sum(st.pure_rss for st in problem.stats)


def sample_prediction(phi: np.ndarray, a: np.ndarray, R: np.ndarray, mg: float, w_o: np.ndarray, com_phi: np.ndarray, com_xyz: np.ndarray) -> np.ndarray:
    """Modelled readings (N, 6) of one recording: ``[f; r(phi) x f] + w_o``, ``f = mg R a``."""
    from ...core.calibration import periodic_interp

    f = mg * (R @ a)
    r = periodic_interp(phi, com_phi, com_xyz)
    return np.hstack([np.broadcast_to(f, r.shape), np.cross(r, f)]) + w_o


def pseudo_residuals_sx(Y: list, x1: list, forces: list, w_o, r_interp: list) -> list:
    """CasADi twin of :func:`pseudo_residuals`: one (6, K_j) expression per recording.

    ``Y``: (6, K_j) pseudo-readings and ``x1``: (1, K_j) constant features per
    recording (DM, or SX parameters); ``forces``: the leg weight vector
    ``f_j = m g R_j a_j`` (3-vector) per recording; ``r_interp``: (3, K_j), the
    CoM grid interpolated at the pseudo-samples, ``r_grid^T X~_j^T``.
    """
    out = []
    for Yj, x1j, f, rj in zip(Y, x1, forces, r_interp):
        pred_f = ca.mtimes(f + w_o[0:3], x1j)
        pred_t = -ca.mtimes(skew(f), rj) + ca.mtimes(w_o[3:6], x1j)  # r x f = -[f] r
        out.append(Yj - ca.vertcat(pred_f, pred_t))
    return out


def weighted_sumsq_sx(res: list, W) -> ca.SX:
    """``sum_j sum_c W_c ||res_j[c, :]||^2`` for (6, K_j) residual expressions."""
    return sum(ca.dot(W, ca.sum2(e * e)) for e in res)
