"""The hanging fit of one leg: CoM QP and exact-rotation NLP on one joint objective.

Joint objective (noise-standardised least squares of report eqs. 4-7 over every
sample of the leg, plus the CoM smoothness penalty and a prior, com_qp.py):

    J(R, m g, w_o, r) = 1/2 sum_i sum_c W_c e_ic^2 + lam/2 ||D2 r||^2 + 1/2 sum_g r_g^T Pi r_g,  W_c = 1/sigma_c^2,

``Pi = I / (1 m)^2`` (weak), plus a stiff gauge along the gravity axis when all
pairs share one axis (problem.py, ``prior_precision``); the NLP then also
fixes each pair's common tilt (``pins_common_tilt``).

Combined, not alternated. Block coordinate descent (QP for ``(r, tau_o)`` with
the rotations fixed, NLP for ``(R, m g, w_o)`` with ``r`` fixed) does lower
``J`` at every step, but on the sample it needs ~30 rounds: the common tilt of
a pair, the force offset and the CoM component along gravity move together
along a narrow valley (the tilt is seen only through ``r(phi) x m g dR a``), and
each block only slides a little along it. So each round is

1. the QP (com_qp.py) at the current rotations and weight: it gives the CoM
   curve for the start and, by GCV in that linear setting, the smoothing
   weight ``lam``;
2. the NLP (nlp.py) over all unknowns, CoM grid included, at that ``lam``:
   IPOPT with the exact Hessian crosses the valley in a few iterations.

For fixed ``(W, lam)`` step 2 ends at the joint minimum, so ``J`` cannot fall
further by another QP; rounds repeat only because the noise variances
(re-estimated from the residuals, starting from the model-free pure error of
the compression) and the GCV choice of ``lam`` (which depends on the
rotations) change. ``lam`` is chosen at the start (rotations from the pair
means) and once more after the first NLP, then held (a change below 10 %
shifts the CoM by far less than its standard error, and the eigenproblem
behind GCV is the costliest step). Rounds stop when the noise sd moved by
< 2 %, ``lam`` did not move, and the last NLP lowered ``J`` by less than 1e-6
standardised squared residuals (a further decrease of ``dJ`` moves estimates
by ``~sqrt(2 dJ)`` standard errors).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ...core.errors import ConfigError
from ...core.geometry import rotation_between
from .com_qp import ComQP, choose_smoothing, penalty, prior, torque_design
from .model import LegState, rss
from .nlp import HangingNLP, structure_key
from .problem import LegProblem
from .result import LegHangingResult
from .uncertainty import leg_covariance

OBJECTIVE_TOL = 1e-6
SIGMA_RTOL = 0.02
LAM_RTOL = 0.10
MAX_ROUNDS = 6
GCV_ROUNDS = 2


def initial_state(problem: LegProblem) -> LegState:
    """Start from the pair means: ``f_o = (f_down + f_up)/2``, ``R_j a_j`` along the mean weight vector."""
    means = problem.means
    f_o = np.mean([(means[d, :3] + means[u, :3]) / 2 for d, u in problem.pairs], axis=0)
    t_o = np.mean([(means[d, 3:] + means[u, 3:]) / 2 for d, u in problem.pairs], axis=0)
    f = means[:, :3] - f_o
    mg = float(np.mean(np.linalg.norm(f, axis=1)))
    R = np.stack([rotation_between(a, fj) for a, fj in zip(problem.a, f)])
    return LegState(R, mg, np.concatenate([f_o, t_o]), np.zeros((problem.n_grid, 3)))


def pure_error_weights(problem: LegProblem) -> np.ndarray:
    """``1/sigma_c^2`` from the pure error of the compressed recordings (model free)."""
    pure = sum(st.pure_rss for st in problem.stats)
    dof = sum(st.n - st.k for st in problem.stats)
    return dof / np.maximum(pure, 1e-300)


def joint_objective(problem: LegProblem, s: LegState, W: np.ndarray, lam: float) -> float:
    """``J`` of the module docstring."""
    r = s.r.T.ravel()
    n = len(r)
    P = penalty(problem.n_grid)[:n, :n] * lam + prior(problem.n_grid, problem.prior_precision)[:n, :n]
    return 0.5 * float(W @ rss(problem, s)) + 0.5 * float(r @ P @ r)


def _smoothing(problem: LegProblem, s: LegState, W: np.ndarray, smoothing) -> tuple[float, tuple]:
    """``lam`` at the current rotations: GCV (``smoothing == "auto"``) or as given; and the QP's data."""
    design = torque_design(problem, s.forces(problem.a), W[3:])
    if smoothing != "auto":
        return float(smoothing), design
    A, b, pure = design
    return choose_smoothing(A, b, pure, 3 * problem.n_samples, problem.n_grid, problem.prior_precision).lam, design


def _qp_step(problem: LegProblem, qp: ComQP, s: LegState, design: tuple, lam: float) -> LegState:
    """CoM grid and torque offset from the QP at the current rotations and weight."""
    G = problem.n_grid
    A, b, _ = design
    z = qp.solve(A, b, lam)
    return replace(s, r=z[: 3 * G].reshape(3, G).T, w_o=np.concatenate([s.w_o[:3], z[3 * G :]]))


def noise_weights(problem: LegProblem, s: LegState) -> np.ndarray:
    """``1/sigma_c^2`` from the residuals of the fit (dof-corrected, pooled over recordings)."""
    n_par = 2 * problem.n_rec + 7 + 3 * problem.n_grid
    return (problem.n_samples - n_par / 6) / rss(problem, s)


def fit_leg_nlp(problem: LegProblem, *, smoothing: float | str, nlp_cache: dict | None = None) -> LegHangingResult:
    """Calibrate one leg from its hanging recordings (see module docstring).

    ``nlp_cache`` (structure key -> HangingNLP) lets legs with the same data
    structure share one symbolic NLP; pass the same dict for every leg of a fit.
    """
    t0 = time.perf_counter()
    if not (smoothing == "auto" or (isinstance(smoothing, (int, float)) and smoothing >= 0)):
        raise ConfigError(f"smoothing must be 'auto' or a non-negative number, got {smoothing!r}", key="hanging.smoothing")
    G = problem.n_grid
    nlp_cache = {} if nlp_cache is None else nlp_cache
    key = structure_key(problem)
    if key not in nlp_cache:
        nlp_cache[key] = HangingNLP.build(problem)
    nlp = nlp_cache[key]
    qp = ComQP(problem.leg, G, problem.prior_precision)
    W = pure_error_weights(problem)
    s = initial_state(problem)
    lam, converged = None, False
    for rounds in range(1, MAX_ROUNDS + 1):
        lam_moved = False
        if rounds <= GCV_ROUNDS:
            lam_new, design = _smoothing(problem, s, W, smoothing)
            lam_moved = lam is None or abs(lam_new - lam) >= LAM_RTOL * abs(lam)  # lam may be 0 (no smoothing)
            if lam_moved:  # otherwise keep lam, so that J stays one function between rounds
                lam = lam_new
                s = _qp_step(problem, qp, s, design, lam)
        assert lam is not None  # set in round 1 (GCV_ROUNDS >= 1)
        J_start = joint_objective(problem, s, W, lam)
        s = nlp.solve(problem, s, W, lam)
        J_drop = J_start - joint_objective(problem, s, W, lam)
        W_new = noise_weights(problem, s)
        sigma_moved = np.any(np.abs(np.sqrt(W / W_new) - 1.0) >= SIGMA_RTOL)
        W = W_new
        if not lam_moved and not sigma_moved and J_drop < OBJECTIVE_TOL:
            converged = True
            break
    assert lam is not None  # MAX_ROUNDS >= 1 rounds ran
    Jval = joint_objective(problem, s, W, lam)
    cov = leg_covariance(problem, nlp, s, W, lam)
    mask = problem.com_mask
    com_se = cov.se(cov.r).reshape(3, G).T
    res_rms = np.sqrt(rss(problem, s) / problem.n_samples)
    return LegHangingResult(
        leg=problem.leg,
        offset=np.where(problem.offset_mask, s.w_o, np.nan),
        offset_se=np.where(problem.offset_mask, cov.se(cov.w_o), np.nan),
        leg_weight_N=s.mg,
        leg_weight_se_N=float(cov.se(cov.mg)),
        com_phi=problem.grid.copy(),
        com_xyz=np.where(mask, s.r, np.nan),
        com_xyz_se=np.where(mask, com_se, np.nan),
        misalignment={n: s.R[j].copy() for j, n in enumerate(problem.names)},
        misalignment_se={n: cov.rotvec_se(j) for j, n in enumerate(problem.names)},
        residual_rms=res_rms,
        warnings=problem.warnings,
        solve_time_s=time.perf_counter() - t0,
        converged=bool(converged),
        com_mask=mask.copy(),
        com_xyz_fit=s.r.copy(),
        offset_fit=s.w_o.copy(),
        noise_sd=1.0 / np.sqrt(W),
        smoothing=float(lam),
        n_rounds=rounds,
        objective=Jval,
        cov=cov.physical(G),
    )
