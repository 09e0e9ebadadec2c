"""Cramer-Rao bounds of the hexapod: the legs' hanging model (a CoM curve over the shaft angle) and the standing balance.

The generic bound (``F``, directions it does not determine dropped) is :mod:`ftcal_nlp.crb.bound`'s.

Hanging (report eqs. 4-7, exact rotation), leg k, recording j with true unit
gravity direction ``u_j`` in ft_k (``R_k^T R_tilt,j gravity_body_j``): with the
periodic linear-interpolation features ``x_i`` of the CoM grid (binning.py),

    w_m,i = M_j x_i + n_i,   M_j[:, g] = [m g u_j + f_o; r_g x m g u_j + tau_o],   n_i ~ N(0, diag(s_f^2, s_t^2)),

so ``F = sum_j sum_c W_c (dM_j,c/dtheta) S_xx,j (dM_j,c/dtheta)^T`` with
``S_xx,j = sum_i x_i x_i^T`` and ``W_c = 1 / s_c^2`` (the simulator's configured
noise). ``theta = (eta_j (2 per recording: tilt of u_j in its tangent plane),
m g, w_o (6), r (G x 3))``; the tilts are nuisance parameters. This is the
bound for *unbiased* estimates of the grid values: a smoothed curve (the NLP's
GCV penalty) or a sinusoid fitted to the curve (the baseline) may beat it by
being biased towards the truth's smoothness.

Standing (exact balance, physics.py eq. (E)), with the hanging parameters
(offsets, leg weights) *known* (the CRB is conditional on them: the estimators'
standing se ignore the hanging uncertainty too), pose p:

    r_p = sum_k Ad(R_k, p'_k) (w_m,pk - w_o,k) - M_b g [z_p; 0] = 0 at the truth,   z_p = R_WB,p^T e_z,

an implicit model with noisy readings and noisy orientation: its bound is the
errors-in-variables one, ``F = sum_p J_p^T Sigma_p^-1 J_p`` with
``J_p = dr_p/dtheta`` and the residual's covariance

    Sigma_p = sum_k Ad_k Sigma_w,p Ad_k^T + (M_b g)^2 blockdiag(s_z,p^2 (I - z_p z_p^T), 0),

``Sigma_w,p = pi/(2 n_p) diag(s_f^2 I, s_t^2 I)`` the variance of a median of
``n_p`` samples, ``s_z,p^2`` that of the pose's orientation (median of white
jitter, plus any per-pose error). ``theta = (delta_k, p'_k)``, ``R_k =
exp([delta_k]) R_k,true`` (B axes, rad), ``p'_k`` in m, B axes.

Two reference points that explain where an estimator lands relative to the
bound: :func:`ls_covariance` (asymptotic covariance of the K-norm least
squares of eq. 8, which weights with ``K = diag(1,1,1,10,10,10)`` instead of
``Sigma_p^-1``) and the same with the hanging bound propagated through the
two-stage fit (``G C_h G^T``, ``G = -A^-1 sum_p J_p^T K J_h,p``), and the least squares
weighted by the fixed ``W = (mean_p Sigma_p)^-1`` (what a constant re-weighting of eq. 8 would reach).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import skew
from ..estimate.hanging.binning import interp_weights, periodic_grid
from ..estimate.standing.problem import K_DIAG
from ..core.settings import HangingSettings
from ..core.solver import REL_EIG_TOL
from .bound import Bound, crb, fisher_information, marginal

MEDIAN_EFFICIENCY = np.pi / 2  # var(median of n Gaussian samples) ~ (pi/2) sigma^2 / n


# ----------------------------------------------------------------------------- hanging


def interp_gram(phi: np.ndarray, n_grid: int) -> np.ndarray:
    """``S_xx = sum_i x_i x_i^T`` (G, G) of the periodic linear-interpolation features at ``phi``."""
    b, t = interp_weights(phi, n_grid)
    b1 = np.mod(b + 1, n_grid)
    u = 1.0 - t
    g = np.arange(n_grid)
    S = np.zeros((n_grid, n_grid))
    S[g, g] = np.bincount(b, u * u, n_grid) + np.bincount(b1, t * t, n_grid)
    off = np.bincount(b, u * t, n_grid)
    S[g, (g + 1) % n_grid] += off
    S[(g + 1) % n_grid, g] += off
    return S


def interp_cross(phi: np.ndarray, y: np.ndarray, n_grid: int) -> np.ndarray:
    """``sum_i x_i y_i^T`` (G, d) for values ``y`` (N, d) at ``phi``."""
    b, t = interp_weights(phi, n_grid)
    b1 = np.mod(b + 1, n_grid)
    return np.stack([np.bincount(b, (1 - t) * y[:, c], n_grid) + np.bincount(b1, t * y[:, c], n_grid) for c in range(y.shape[1])], 1)


def tangent_plane(u: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3, 2) of the plane perpendicular to ``u``."""
    _, _, Vt = np.linalg.svd(np.asarray(u, float)[None, :])
    return Vt[1:].T


@dataclass(frozen=True)
class HangingLayout:
    """Indices into the hanging parameter vector of one leg."""

    n_rec: int
    n_grid: int

    @property
    def mg(self) -> int:
        return 2 * self.n_rec

    @property
    def w_o(self) -> np.ndarray:
        return np.arange(2 * self.n_rec + 1, 2 * self.n_rec + 7)

    def r(self, g: int | np.ndarray, d: int | np.ndarray) -> np.ndarray:
        """Index of CoM grid point ``g``, component ``d`` (x, y, z = 0, 1, 2)."""
        return 2 * self.n_rec + 7 + 3 * np.asarray(g) + np.asarray(d)

    @property
    def n(self) -> int:
        return 2 * self.n_rec + 7 + 3 * self.n_grid


def hanging_derivatives(u: np.ndarray, mg: float, r: np.ndarray, j: int, n_rec: int) -> np.ndarray:
    """``dM_j / dtheta`` (n, 6, G) for recording ``j`` of ``n_rec`` (layout :class:`HangingLayout`).

    ``u`` (3,) true unit gravity direction in ft_k; ``r`` (G, 3) CoM grid, m.
    """
    G = len(r)
    lay = HangingLayout(n_rec, G)
    D = np.zeros((lay.n, 6, G))
    B = tangent_plane(u)
    f = mg * u
    for l in range(2):
        D[2 * j + l, :3, :] = mg * B[:, l][:, None]
        D[2 * j + l, 3:, :] = mg * np.cross(r, B[:, l]).T
    D[lay.mg, :3, :] = u[:, None]
    D[lay.mg, 3:, :] = np.cross(r, u).T
    for c in range(6):
        D[lay.w_o[c], c, :] = 1.0
    g = np.arange(G)
    for d in range(3):
        D[lay.r(g, d), 3:, g] = np.cross(np.eye(3)[d], f)  # d(r_g x f)/d r_g,d = e_d x f
    return D


def hanging_leg_fisher(phis: list[np.ndarray], us: list[np.ndarray], mg: float, r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Fisher information of one leg's hanging recordings (module docstring).

    ``phis``: shaft angles (N_j,) per recording; ``us``: true gravity direction
    (3,) in ft_k per recording; ``mg`` N; ``r`` (G, 3) the true CoM grid (m);
    ``sigma`` (6,) noise sd per reading component.
    """
    G = len(r)
    J = len(phis)
    W = 1.0 / np.asarray(sigma, float) ** 2
    F = np.zeros((HangingLayout(J, G).n,) * 2)
    for j, (phi, u) in enumerate(zip(phis, us)):
        S = interp_gram(phi, G)
        D = hanging_derivatives(np.asarray(u, float), mg, r, j, J)
        for c in range(6):
            Dc = D[:, c, :]
            F += W[c] * Dc @ S @ Dc.T
    return F


def true_gravity_directions(sim, leg: str, names: list[str]) -> list[np.ndarray]:
    """True unit gravity direction in ft_leg of each hanging recording of a :class:`~ftcal_nlp.sim.SimResult`."""
    i = list(sim.dataset.robot.legs).index(leg)
    R_k = sim.true_robot.R[i]
    recs = {r.name: r for r in sim.dataset.hanging}
    out = []
    for n in names:
        g_B = sim.hanging_tilt[n] @ (recs[n].gravity_body / np.linalg.norm(recs[n].gravity_body))
        out.append(R_k.T @ g_B)
    return out


def sensor_sigma(cfg) -> np.ndarray:
    """Per-sample noise sd (6,) of a reading: the simulator's configured ATI noise."""
    return np.array([cfg.noise_force_N] * 3 + [cfg.noise_torque_Nm] * 3, float)


@dataclass(frozen=True)
class HangingBound:
    """Hanging CRB of every leg: per leg the bound and its layout; and the CoM truth the grid model can reach."""

    legs: tuple[str, ...]
    bounds: dict[str, Bound]
    layouts: dict[str, HangingLayout]
    fisher: dict[str, np.ndarray]

    def offset_cov(self, leg: str) -> np.ndarray:
        return marginal(self.bounds[leg], self.layouts[leg].w_o)

    def weight_var(self, leg: str) -> float:
        i = self.layouts[leg].mg
        return float(self.bounds[leg].cov[i, i])

    def com_sd(self, leg: str) -> np.ndarray:
        """(G, 3) bound on the sd of each CoM grid value."""
        lay = self.layouts[leg]
        G = lay.n_grid
        idx = lay.r(np.arange(G)[:, None], np.arange(3)[None, :])
        return self.bounds[leg].sd[idx]

    def com_sd_sinusoid(self, leg: str) -> np.ndarray:
        """(G, 3) bound on the sd of each CoM grid value if the curve were known to be the simulator's
        family, ``x, z = a sin(phi) + b cos(phi) + d``, ``y`` constant (7 parameters instead of 3G)."""
        lay = self.layouts[leg]
        G = lay.n_grid
        T = sinusoid_map(lay)
        b = crb(T.T @ self.fisher[leg] @ T)
        idx = lay.r(np.arange(G)[:, None], np.arange(3)[None, :])
        C = T[idx.ravel()] @ b.cov @ T[idx.ravel()].T
        return np.sqrt(np.maximum(np.diag(C), 0.0)).reshape(G, 3)


def sinusoid_map(lay: HangingLayout) -> np.ndarray:
    """Linear map (n, n - 3G + 7) from (tilts, m g, w_o, sinusoid coefficients) to the grid layout."""
    G = lay.n_grid
    n0 = 2 * lay.n_rec + 7
    phi = periodic_grid(G)
    T = np.zeros((lay.n, n0 + 7))
    T[:n0, :n0] = np.eye(n0)
    basis = np.stack([np.sin(phi), np.cos(phi), np.ones(G)], axis=1)
    g = np.arange(G)
    T[lay.r(g, 0), n0 : n0 + 3] = basis
    T[lay.r(g, 1), n0 + 3] = 1.0
    T[lay.r(g, 2), n0 + 4 : n0 + 7] = basis
    return T


def hanging_bound(sim, n_grid: int = HangingSettings.n_grid, rel_tol: float = REL_EIG_TOL) -> HangingBound:
    """Hanging CRB of a simulation at its truth (configured noise, the recordings' own shaft angles)."""
    legs = tuple(sim.dataset.robot.legs)
    sigma = sensor_sigma(sim.config)
    names = [r.name for r in sim.dataset.hanging]
    grid = periodic_grid(n_grid)
    bounds, layouts, fishers = {}, {}, {}
    for i, leg in enumerate(legs):
        us = true_gravity_directions(sim, leg, names)
        phis = [r.phi[leg] for r in sim.dataset.hanging]
        r_true = sim.true_robot.leg_com_ft(np.repeat(grid[:, None], len(legs), axis=1))[:, i]
        F = hanging_leg_fisher(phis, us, float(sim.true_robot.weights_N[i]), r_true, sigma)
        fishers[leg] = F
        bounds[leg] = crb(F, rel_tol)
        layouts[leg] = HangingLayout(len(names), n_grid)
    return HangingBound(legs, bounds, layouts, fishers)


def interpolation_bias(sim, leg: str, n_grid: int = HangingSettings.n_grid) -> np.ndarray:
    """Pseudo-true CoM grid minus the truth's grid values, (G, 3) m.

    The grid model (linear interpolation) cannot follow the true curve exactly;
    an unbiased estimator of the grid model converges to the least-squares
    projection of the true torques onto it (the other parameters at their truth),
    which differs from the true curve sampled at the grid points by ~h^2/12 r''.
    """
    i = list(sim.dataset.robot.legs).index(leg)
    names = [r.name for r in sim.dataset.hanging]
    us = true_gravity_directions(sim, leg, names)
    mg = float(sim.true_robot.weights_N[i])
    W_t = 1.0 / sensor_sigma(sim.config)[3:] ** 2
    G = n_grid
    A = np.zeros((3 * G, 3 * G))
    b = np.zeros(3 * G)
    for rec, u in zip(sim.dataset.hanging, us):
        phi = rec.phi[leg]
        S = interp_gram(phi, G)
        r_true = sim.true_robot.leg_com_ft(np.repeat(phi[:, None], len(sim.dataset.robot.legs), axis=1))[:, i]
        T = interp_cross(phi, r_true, G)  # X^T r_true (G, 3)
        Fm = -skew(mg * u)  # r x f = -[f] r, rows c: torque component c = Fm[c] . r
        # sum_i (Fm[c] (X r_grid)_i - Fm[c] r_true,i)^2 with r_grid stacked [x over grid, y, z]:
        for c in range(3):
            A += W_t[c] * np.kron(np.outer(Fm[c], Fm[c]), S)
            b += W_t[c] * np.outer(Fm[c], T @ Fm[c]).ravel()
    r_star = np.linalg.solve(A + 1e-12 * np.trace(A) / (3 * G) * np.eye(3 * G), b).reshape(3, G).T
    grid = periodic_grid(G)
    r_grid = sim.true_robot.leg_com_ft(np.repeat(grid[:, None], len(sim.dataset.robot.legs), axis=1))[:, i]
    return r_star - r_grid


# ----------------------------------------------------------------------------- standing


def ad(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``[[R, 0], [[p] R, R]]`` (..., 6, 6): wrench in ft_k about its origin -> B about the reference point."""
    out = np.zeros(np.shape(R)[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., 3:, :3] = skew(p) @ R
    return out


def standing_jacobians(w_m: np.ndarray, R_WB: np.ndarray, R: np.ndarray, p_prime: np.ndarray,
                       offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of the exact-balance residual (B axes) per pose.

    Returns ``J_s`` (P, 6, 6K) w.r.t. ``(delta_1..delta_K, p'_1..p'_K)`` and
    ``J_h`` (P, 6, 7K) w.r.t. the hanging parameters ``(w_o,1..w_o,K, m_1 g..m_K g)``.
    ``w_m`` (P, K, 6) readings; ``R_WB`` (P, 3, 3); ``R`` (K, 3, 3); ``p_prime``
    (K, 3) m; ``offsets`` (K, 6).
    """
    P, K = w_m.shape[:2]
    v = w_m - offsets
    a = np.einsum("kij,pkj->pki", R, v[..., :3])  # R_k f
    b = np.einsum("kij,pkj->pki", R, v[..., 3:])  # R_k tau
    Sa, Sb, Sp = skew(a), skew(b), skew(p_prime)
    J_s = np.zeros((P, 6, 6 * K))
    J_h = np.zeros((P, 6, 7 * K))
    z = R_WB[:, 2, :]
    Ad = ad(R, p_prime)
    for k in range(K):
        J_s[:, :3, 3 * k : 3 * k + 3] = -Sa[:, k]
        J_s[:, 3:, 3 * k : 3 * k + 3] = -Sb[:, k] - Sp[k] @ Sa[:, k]
        J_s[:, 3:, 3 * K + 3 * k : 3 * K + 3 * k + 3] = -Sa[:, k]
        J_h[:, :, 6 * k : 6 * k + 6] = -Ad[k]
        J_h[:, :3, 6 * K + k] = z  # -M_b g z with M_b g = M g - sum_k m_k g
    return J_s, J_h


def pose_noise_cov(R: np.ndarray, p_prime: np.ndarray, R_WB: np.ndarray, Mb_g: float, sigma: np.ndarray,
                   n_samples: np.ndarray, sigma_z: np.ndarray) -> np.ndarray:
    """``Sigma_p`` (P, 6, 6) of the balance residual at the truth (module docstring).

    ``sigma`` (6,) per-sample reading noise; ``n_samples`` (P,) samples in each
    pose's median; ``sigma_z`` (P,) sd (rad) of each pose's orientation per axis.
    """
    Ad = ad(R, p_prime)  # (K, 6, 6)
    base = np.einsum("kij,j,klj->il", Ad, np.asarray(sigma, float) ** 2, Ad)
    Sig = MEDIAN_EFFICIENCY * base[None] / np.asarray(n_samples, float)[:, None, None]
    z = R_WB[:, 2, :]
    Pz = np.eye(3) - np.einsum("pi,pj->pij", z, z)
    Sig[:, :3, :3] += (Mb_g * np.asarray(sigma_z, float))[:, None, None] ** 2 * Pz
    return Sig


def ls_covariance(J_s: np.ndarray, Sigma: np.ndarray, W: np.ndarray | None = None, J_h: np.ndarray | None = None,
                  C_h: np.ndarray | None = None) -> np.ndarray:
    """Asymptotic covariance of the least squares ``min sum_p r_p^T W r_p`` (sandwich), optionally plus the
    hanging covariance ``C_h`` propagated through the two-stage fit (module docstring).

    ``W`` (6, 6) a fixed weight, by default eq. 8's ``K = diag(1, 1, 1, 10, 10, 10)``. Pseudo-inverse on
    the directions the weighted information determines (same tolerance as :func:`crb`).
    """
    Kd = np.diag(K_DIAG) if W is None else np.asarray(W, float)
    A = np.einsum("pmi,mn,pnj->ij", J_s, Kd, J_s)
    Bm = np.einsum("pmi,mn,pnq,qr,prj->ij", J_s, Kd, Sigma, Kd, J_s)
    Ainv = crb(A).cov
    C = Ainv @ Bm @ Ainv
    if J_h is not None and C_h is not None:
        G = -Ainv @ np.einsum("pmi,mn,pnj->ij", J_s, Kd, J_h)
        C = C + G @ C_h @ G.T
    return C


def pose_sample_counts(t_mid: np.ndarray, windows: np.ndarray, rate_hz: float) -> np.ndarray:
    """Samples in each extracted pose's median, from its mid time and the simulator's pose windows.

    A steady run ends where the pose ends (the next pose's shaft motion starts),
    so a run centred at ``t_mid`` spans ``2 (t_end - t_mid)``; poses matched to
    no window get the window length.
    """
    i = np.clip(np.searchsorted(windows[:, 1], t_mid), 0, len(windows) - 1)
    span = 2.0 * (windows[i, 1] - t_mid)
    default = windows[i, 1] - windows[i, 0]
    span = np.where((t_mid >= windows[i, 0] - 5.0) & (span > 0), span, default)
    return np.maximum(np.round(span * rate_hz) + 1, 1.0)


@dataclass(frozen=True)
class StandingBound:
    """Standing CRB (hanging parameters known) and the K-norm LS reference covariances.

    Parameters: ``(delta_1..delta_K (rad, B axes), p'_1..p'_K (m))``.
    ``bound`` the CRB; ``ls_cov`` the K-norm LS covariance (hanging known);
    ``two_stage_cov`` with the hanging CRB propagated; ``gls_const_cov`` the least squares
    weighted by the inverse mean residual covariance ``(mean_p Sigma_p)^-1`` instead of K
    (hanging known); ``residual_check``: RMS
    over poses of the standardised truth residual ``|L_p^-1 r_p|/sqrt(6)`` (1 when
    the poses carry only the modelled noise).
    """

    bound: Bound
    ls_cov: np.ndarray | None
    two_stage_cov: np.ndarray | None
    gls_const_cov: np.ndarray | None
    fisher: np.ndarray
    residual_check: float
    n_samples_median: float
    sigma_z_median: float

    def reference_covs(self) -> dict[str, np.ndarray]:
        """The reference covariances by the name of their ratio to the bound (``references=True`` computes them)."""
        if self.ls_cov is None or self.two_stage_cov is None or self.gls_const_cov is None:
            raise ValueError("standing bound computed without its references: standing_bound(..., references=True)")
        return {"ls_ratio": self.ls_cov, "two_stage_ratio": self.two_stage_cov, "gls_const_ratio": self.gls_const_cov}


def pose_orientation_sd(n_samples: np.ndarray, jitter_rad: float, per_pose_rad: float) -> np.ndarray:
    """sd (rad, per axis) of each pose's orientation: the median of white jitter plus the per-pose error."""
    return np.sqrt(MEDIAN_EFFICIENCY * jitter_rad**2 / np.asarray(n_samples, float) + per_pose_rad**2)


def standing_bound_at(poses, R: np.ndarray, p_prime: np.ndarray, offsets: np.ndarray, Mb_g: float, sigma: np.ndarray,
                      n_samples: np.ndarray, sigma_z: np.ndarray, rel_tol: float = REL_EIG_TOL) -> Bound:
    """The standing CRB (module docstring) at given transforms (``R`` (K, 3, 3), ``p_prime`` (K, 3), ``offsets``
    (K, 6)) for ``poses``: e.g. a pilot dataset's poses with its calibration standing in for the truth."""
    Sig = pose_noise_cov(R, p_prime, poses.R_WB, Mb_g, sigma, n_samples, sigma_z)
    J_s, _ = standing_jacobians(poses.w_m, poses.R_WB, R, p_prime, offsets)
    return crb(fisher_information(J_s, Sig), rel_tol)


def standing_bound(sim, poses, hbound: HangingBound | None = None, rel_tol: float = REL_EIG_TOL,
                   references: bool = True) -> StandingBound:
    """CRB of the full model's transforms at the truth of ``sim`` for the extracted ``poses``.

    ``references=False`` skips the least-squares reference covariances (most of the time; left None)."""
    from ..core.physics import balance_residual_exact

    tr = sim.true_robot
    cfg = sim.config
    K = len(tr.legs)
    Mb_g = tr.body_weight_N
    n = pose_sample_counts(poses.t, sim.pose_windows, cfg.rate_hz)
    jit = np.radians(getattr(cfg, "mocap_jitter_deg", 0.0))
    per_pose = np.radians(getattr(cfg, "mocap_pose_error_deg", 0.0))
    sigma_z = pose_orientation_sd(n, jit, per_pose)
    Sig = pose_noise_cov(tr.R, tr.p_prime, poses.R_WB, Mb_g, sensor_sigma(cfg), n, sigma_z)
    J_s, J_h = standing_jacobians(poses.w_m, poses.R_WB, tr.R, tr.p_prime, tr.offsets)
    F = fisher_information(J_s, Sig)
    b = crb(F, rel_tol)
    ls = ls_covariance(J_s, Sig) if references else None
    gls = ls_covariance(J_s, Sig, np.linalg.inv(Sig.mean(axis=0))) if references else None
    C_h = np.zeros((7 * K, 7 * K))
    if hbound is not None and references:
        for k, leg in enumerate(tr.legs):
            C_h[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = hbound.offset_cov(leg)
            C_h[6 * K + k, 6 * K + k] = hbound.weight_var(leg)
            lay = hbound.layouts[leg]
            C_h[6 * k : 6 * k + 6, 6 * K + k] = hbound.bounds[leg].cov[lay.w_o, lay.mg]
            C_h[6 * K + k, 6 * k : 6 * k + 6] = hbound.bounds[leg].cov[lay.mg, lay.w_o]
    two = ls_covariance(J_s, Sig, None, J_h, C_h) if references else None
    r = balance_residual_exact(poses.w_m, np.eye(3)[None].repeat(poses.n, 0), tr.offsets, tr.R, tr.p_prime, 0.0)
    r[:, :3] -= Mb_g * poses.R_WB[:, 2, :]  # residual in B: sum_k Ad_k v - M_b g [z; 0]
    L = np.linalg.cholesky(Sig)
    std = np.linalg.solve(L, r[..., None])[..., 0]
    check = float(np.sqrt(np.mean(std**2)))
    return StandingBound(b, ls, two, gls, F, check, float(np.median(n)), float(np.median(sigma_z)))


def total_com_jacobian(weights: np.ndarray, R: np.ndarray, p_prime: np.ndarray, r0: np.ndarray, weight_total: float):
    """Jacobians of ``c = sum_k m_k g (R_k r_k + p'_k) / (M g)`` (physics.total_com_from_body_com).

    Returns ``(G_h (3, 4K): w.r.t. (m_k g, r_k (3)) per leg, G_s (3, 6K): w.r.t. (delta_k, p'_k))``;
    ``r0`` (K, 3) the leg CoMs in ft_k at the configuration evaluated.
    """
    K = len(weights)
    Rr = np.einsum("kij,kj->ki", R, r0)
    G_h = np.zeros((3, 4 * K))
    G_s = np.zeros((3, 6 * K))
    for k in range(K):
        G_h[:, 4 * k] = (Rr[k] + p_prime[k]) / weight_total
        G_h[:, 4 * k + 1 : 4 * k + 4] = weights[k] * R[k] / weight_total
        G_s[:, 3 * k : 3 * k + 3] = -weights[k] * skew(Rr[k]) / weight_total  # d(R r) = delta x (R r)
        G_s[:, 3 * K + 3 * k : 3 * K + 3 * k + 3] = weights[k] * np.eye(3) / weight_total
    return G_h, G_s


def total_com_cov(sim, hbound: HangingBound, C_s: np.ndarray, grid_index: int = 0) -> np.ndarray:
    """Covariance (3, 3) of the total CoM relative to the body CoM at the leg configuration of grid point
    ``grid_index`` (0: phi = 0, every leg straight down): the hanging CRB of the leg weights and CoMs plus
    ``C_s`` (6K, 6K), a covariance of the standing parameters (the conditional CRB for the bound)."""
    tr = sim.true_robot
    K = len(tr.legs)
    G = hbound.layouts[tr.legs[0]].n_grid
    phi = np.full((1, K), periodic_grid(G)[grid_index])
    r0 = tr.leg_com_ft(phi)[0]
    G_h, G_s = total_com_jacobian(tr.weights_N, tr.R, tr.p_prime, r0, tr.weight_N)
    C = G_s @ C_s @ G_s.T
    for k, leg in enumerate(tr.legs):
        lay = hbound.layouts[leg]
        idx = np.concatenate([[lay.mg], lay.r(grid_index, np.arange(3))])
        Gk = G_h[:, 4 * k : 4 * k + 4]
        C += Gk @ marginal(hbound.bounds[leg], idx) @ Gk.T
    return C


# ----------------------------------------------------------------------------- one dataset


@dataclass(frozen=True)
class DatasetBounds:
    """The bounds of one simulated dataset: hanging, standing (with its reference covariances), the total CoM
    (bound and references), the grid model's interpolation bias and the CoM bound of the sinusoid family."""

    hanging: HangingBound
    standing: StandingBound
    com_cov: np.ndarray
    com_ref: dict
    interp_bias: dict
    com_sd_sin: dict


def dataset_bounds(sim, poses) -> DatasetBounds:
    """Every bound of one simulated dataset at its truth, for the extracted ``poses``."""
    hb = hanging_bound(sim)
    sb = standing_bound(sim, poses, hb)
    com_ref = {k: total_com_cov(sim, hb, C) for k, C in sb.reference_covs().items()}
    return DatasetBounds(hb, sb, total_com_cov(sim, hb, sb.bound.cov), com_ref,
                         {leg: interpolation_bias(sim, leg) for leg in hb.legs}, {leg: hb.com_sd_sinusoid(leg) for leg in hb.legs})
