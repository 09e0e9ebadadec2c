"""The report's hanging method (Sec. III-A), kept as ``baseline`` for comparisons only.

Per opposite pair, in a frame where the down recording's nominal gravity axis
is the report's ``e_1`` (``Q a_down = e_1``, ``Q`` the smallest rotation; the
report's pairs are the transducer axes, ours come from ``gravity_body`` and the
nominal rotations), with ``g_x = [g, 0, 0]``:

    f_m,i^down =  ([s^down] + I) m g_x + f_o + nu          (4)
    f_m,i^up   = -([s^up]   + I) m g_x + f_o + nu          (5)
    tau_m,i^down =  [r(phi_i)] ([s^down] + I) m g_x + tau_o + omega   (6)
    tau_m,i^up   = -[r(phi_i)] ([s^up]   + I) m g_x + tau_o + omega   (7)

and ``x^- = (x^down - x^up)/2``, ``x^+ = (x^down + x^up)/2``:

* ``s^+ = ([s^down] + [s^up])/2`` minimises
  ``1/sqrt(N) sum_{j=2,3} sqrt(sum_i (((I + [s^+])^-1 f_i^-) . e_j)^2) + std_i(((I + [s^+])^-1 f_i^-) . e_1)``
  by ``scipy.optimize.least_squares`` (TRF, ``ftol = 1e-3``, the scalar cost as
  a one-element residual); ``m g = mean_i ((I + [s^+])^-1 f_i^-) . e_1``.
* ``tau_i^- = [r(phi_i)] f_i^-``: ``r`` by a Kalman smoother over the samples with
  a random-walk state and diagonal transition and observation covariances
  0.01 (the report's values), observation matrix ``-[f_i^-]``. The smoother
  is computed as the equivalent MAP problem, a symmetric block-tridiagonal
  system (``solveh_banded``), which gives the RTS smoother's means exactly.
* The line ``r + p f^-`` left open per pair is closed per shaft angle by least
  squares over both pairs (``r + p n = r' + p' n'``, then the average), and
  the average is fitted by ``A sin(phi + C) + D`` in x and z and a constant in y.
* ``s^- = ([s^down] - [s^up])/2`` minimises the standard deviation of
  ``tau_i^+ - [r(phi_i)] [s^-] m g_x`` (least_squares, TRF, ftol 1e-3), and

      f_o = mean_i (f_i^+ - [s^-] m g_x),   tau_o = mean_i (tau_i^+ - [r(phi_i)] [s^-] m g_x).

Offsets and weight are averaged over the pairs. The report's two recordings
of a pair share their shaft angles ``phi_i``; ours need not, so the up
recording is averaged on a 1-degree phase grid and interpolated at the down
recording's ``phi_i``. Standard errors are the naive ones of sample means
(``std / sqrt(N)``, CoM from the OLS fit of the sinusoid); no rotation se.
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np
import scipy.linalg as sla
from scipy.optimize import least_squares

from ...core.data import Recording, held_gravity_body
from ...core.geometry import rotation_between, rotvec_to_rotation, skew
from ...core.robot import Robot
from .binning import TWO_PI, periodic_grid
from .model import sample_prediction
from .problem import HangingDataError, _identified_components
from .result import LegHangingResult

KALMAN_Q = 0.01  # transition covariance (diagonal), report Sec. III-A.3
KALMAN_R = 0.01  # observation covariance (diagonal)
KALMAN_P0 = 1.0  # initial state covariance (diffuse)
N_PHASE_BINS = 360
E1 = np.array([1.0, 0.0, 0.0])


def kalman_smoother_random_walk(y: np.ndarray, H: np.ndarray, q: float = KALMAN_Q, r: float = KALMAN_R, p0: float = KALMAN_P0) -> np.ndarray:
    """Smoothed means (N, 3) of ``x_i = x_{i-1} + w``, ``y_i = H_i x_i + v``, ``x_0 ~ N(0, p0 I)``.

    ``y`` (N, 3), ``H`` (N, 3, 3); ``w ~ N(0, q I)``, ``v ~ N(0, r I)``. The
    RTS smoother's means are the minimiser of
    ``sum |y_i - H_i x_i|^2 / r + sum |x_i - x_{i-1}|^2 / q + |x_0|^2 / p0``,
    a block-tridiagonal SPD system solved in banded form.
    """
    N = len(y)
    A = np.einsum("nki,nkj->nij", H, H) / r
    A += np.eye(3) * (2.0 / q)
    A[0] += np.eye(3) * (1.0 / p0 - 1.0 / q)
    A[-1] -= np.eye(3) * (1.0 / q)
    b = np.einsum("nki,nk->ni", H, y) / r
    u = 5
    ab = np.zeros((u + 1, 3 * N))
    for i in range(3):
        for j in range(i, 3):  # upper triangle of the diagonal blocks
            ab[u + i - j, np.arange(N) * 3 + j] = A[:, i, j]
    for i in range(3):  # off-diagonal blocks -I/q between samples n and n+1
        ab[u - 3, np.arange(1, N) * 3 + i] = -1.0 / q
    return sla.solveh_banded(ab, b.ravel()).reshape(N, 3)


def _phase_profile(phi: np.ndarray, x: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``x`` (N, d) per 1-degree phase bin, periodic-interpolated at ``at``; and a validity mask."""
    nb = N_PHASE_BINS
    b = np.floor(np.mod(phi, TWO_PI) / TWO_PI * nb).astype(int) % nb
    cnt = np.bincount(b, minlength=nb)
    mean = np.stack([np.bincount(b, weights=x[:, c], minlength=nb) for c in range(x.shape[1])], 1) / np.maximum(cnt, 1)[:, None]
    centres = (np.arange(nb) + 0.5) * TWO_PI / nb
    xa = np.mod(at - centres[0], TWO_PI) / (TWO_PI / nb)
    i0 = np.floor(xa).astype(int) % nb
    i1 = (i0 + 1) % nb
    t = xa - np.floor(xa)
    ok = (cnt[i0] > 0) & (cnt[i1] > 0)
    return (1 - t)[:, None] * mean[i0] + t[:, None] * mean[i1], ok


def _splus_cost(s: np.ndarray, fm: np.ndarray) -> np.ndarray:
    g = np.linalg.solve(np.eye(3) + skew(s), fm.T).T
    N = len(fm)
    cost = (np.sqrt(np.sum(g[:, 1] ** 2)) + np.sqrt(np.sum(g[:, 2] ** 2))) / np.sqrt(N) + np.std(g[:, 0])
    return np.array([cost])


def _pair_step(leg: str, down: Recording, up: Recording, a_down: np.ndarray) -> dict:
    """s^+, m g and the smoothed CoM of one pair (rotated frame: Q a_down = e_1)."""
    Q = rotation_between(a_down, E1)
    phi = down.phi[leg]
    wd = down.wrench[leg]
    wu_prof, ok = _phase_profile(up.phi[leg], up.wrench[leg], phi)
    if ok.sum() < 10:
        raise HangingDataError(f"leg {leg}: recordings {down.name} and {up.name} share almost no shaft angles; the baseline pairs samples by phase")
    phi, wd, wu = phi[ok], wd[ok], wu_prof[ok]
    f_minus = (wd[:, :3] - wu[:, :3]) @ Q.T / 2
    f_plus = (wd[:, :3] + wu[:, :3]) @ Q.T / 2
    t_minus = (wd[:, 3:] - wu[:, 3:]) @ Q.T / 2
    t_plus = (wd[:, 3:] + wu[:, 3:]) @ Q.T / 2
    s_plus = least_squares(_splus_cost, np.zeros(3), args=(f_minus,), method="trf", ftol=1e-3).x
    g = np.linalg.solve(np.eye(3) + skew(s_plus), f_minus.T).T
    mg = float(g[:, 0].mean())
    r_rot = kalman_smoother_random_walk(t_minus, -skew(f_minus))
    n_rot = f_minus / np.linalg.norm(f_minus, axis=1, keepdims=True)
    return dict(Q=Q, phi=phi, f_plus=f_plus, t_plus=t_plus, s_plus=s_plus, mg=mg, mg_se=float(g[:, 0].std() / np.sqrt(len(g))),
                r=r_rot @ Q, n=n_rot @ Q)  # back to ft_k: x_ft = Q^T x_rot


def _resolve_null_space(leg: str, steps: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per phase bin: r = argmin sum_p |(I - n_p n_p^T)(r - r_p)|^2 (report: r + p n = r' + p' n', averaged)."""
    nb = N_PHASE_BINS
    M = np.zeros((nb, 3, 3))
    v = np.zeros((nb, 3))
    seen = np.zeros((len(steps), nb), bool)
    for k, st in enumerate(steps):
        b = np.floor(np.mod(st["phi"], TWO_PI) / TWO_PI * nb).astype(int) % nb
        cnt = np.bincount(b, minlength=nb)
        rb = np.stack([np.bincount(b, weights=st["r"][:, c], minlength=nb) for c in range(3)], 1) / np.maximum(cnt, 1)[:, None]
        nbv: np.ndarray = np.stack([np.bincount(b, weights=st["n"][:, c], minlength=nb) for c in range(3)], 1)  # float (weights)
        nbv /= np.maximum(np.linalg.norm(nbv, axis=1, keepdims=True), 1e-300)
        P = np.eye(3) - np.einsum("bi,bj->bij", nbv, nbv)
        P[cnt == 0] = 0.0
        M += P
        v += np.einsum("bij,bj->bi", P, rb)
        seen[k] = cnt > 0
    good = seen.all(axis=0) & (np.linalg.matrix_rank(M, tol=0.5) == 3)
    if good.sum() < 4:
        raise HangingDataError(f"leg {leg}: the baseline needs two non-parallel opposite pairs covering common shaft angles")
    r = np.linalg.solve(M[good], v[good][..., None])[..., 0]
    centres = (np.arange(nb) + 0.5) * TWO_PI / nb
    return centres[good], r, seen[:, good].sum(axis=0).astype(float)


def _fit_sinusoid(phi: np.ndarray, r: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A sin(phi + C) + D`` (as ``a sin + b cos + D``) in x and z, a constant in y; values and OLS se on ``grid``."""
    X = np.stack([np.sin(phi), np.cos(phi), np.ones_like(phi)], 1)
    Xg = np.stack([np.sin(grid), np.cos(grid), np.ones_like(grid)], 1)
    out, se = np.zeros((len(grid), 3)), np.zeros((len(grid), 3))
    for c in range(3):
        Xc, Xgc = (X, Xg) if c != 1 else (X[:, 2:], Xg[:, 2:])
        coef, *_ = np.linalg.lstsq(Xc, r[:, c], rcond=None)
        res = r[:, c] - Xc @ coef
        cov = np.linalg.inv(Xc.T @ Xc) * (res @ res) / max(len(res) - Xc.shape[1], 1)
        out[:, c] = Xgc @ coef
        se[:, c] = np.sqrt(np.einsum("gi,ij,gj->g", Xgc, cov, Xgc))
    return out, se


def fit_leg_baseline(leg: str, recordings: Sequence[Recording], robot: Robot, pairs: Sequence[tuple[int, int]], n_grid: int) -> LegHangingResult:
    """The report's hanging method for one leg (see module docstring)."""
    t0 = time.perf_counter()
    recordings = list(recordings)
    R_nom = robot.transducers[leg].given_rotation()
    a = np.stack([R_nom.T @ (gb / np.linalg.norm(gb)) for gb in map(held_gravity_body, recordings)])
    _, null = _identified_components(np.stack([a[d] for d, _ in pairs]))
    if null is not None:
        raise HangingDataError(f"leg {leg}: the baseline (report Sec. III-A.3) needs two non-parallel opposite pairs; all pairs have gravity along one axis")
    steps = [_pair_step(leg, recordings[d], recordings[u], a[d]) for d, u in pairs]
    grid = periodic_grid(n_grid)
    phi_b, r_b, _ = _resolve_null_space(leg, steps)
    com, com_se = _fit_sinusoid(phi_b, r_b, grid)

    offsets, off_se, weights, mis = [], [], [], {}
    for (d, u), st in zip(pairs, steps):
        Q, mg = st["Q"], st["mg"]
        r_rot = np.stack([np.interp(np.mod(st["phi"], TWO_PI), np.append(grid, TWO_PI), np.append(com[:, c], com[0, c])) for c in range(3)], 1) @ Q.T
        g_x = mg * E1

        def tau_o_samples(s):
            return st["t_plus"] - np.cross(r_rot, np.cross(s, g_x))

        def res(s):
            x = tau_o_samples(s)
            return ((x - x.mean(axis=0)) / np.sqrt(len(x))).ravel()

        s_minus = least_squares(res, np.zeros(3), method="trf", ftol=1e-3).x
        f_o = st["f_plus"] - np.cross(s_minus, g_x)
        t_o = tau_o_samples(s_minus)
        w = np.hstack([f_o, t_o]) @ np.kron(np.eye(2), Q)  # back to ft_k
        offsets.append(w.mean(axis=0))
        off_se.append(w.std(axis=0) / np.sqrt(len(w)))
        weights.append((mg, st["mg_se"]))
        mis[recordings[d].name] = rotvec_to_rotation(Q.T @ (st["s_plus"] + s_minus))
        mis[recordings[u].name] = rotvec_to_rotation(Q.T @ (st["s_plus"] - s_minus))
    P = len(pairs)
    offset = np.mean(offsets, axis=0)
    offset_se = np.sqrt(np.sum(np.square(off_se), axis=0)) / P
    mg = float(np.mean([w for w, _ in weights]))
    mg_se = float(np.sqrt(np.sum([s**2 for _, s in weights])) / P)

    res2, n = np.zeros(6), 0
    for j, rec in enumerate(recordings):
        pred = sample_prediction(rec.phi[leg], a[j], mis[rec.name], mg, offset, grid, com)
        res2 += np.sum((rec.wrench[leg] - pred) ** 2, axis=0)
        n += rec.n
    return LegHangingResult(
        leg=leg, offset=offset, offset_se=offset_se, leg_weight_N=mg, leg_weight_se_N=mg_se,
        com_phi=grid, com_xyz=com, com_xyz_se=com_se,
        misalignment=mis, misalignment_se={k: np.full(3, np.nan) for k in mis},
        residual_rms=np.sqrt(res2 / n), warnings=(), solve_time_s=time.perf_counter() - t0, converged=True,
        com_mask=np.ones((n_grid, 3), bool), com_xyz_fit=com.copy(), offset_fit=offset.copy(),
    )
