"""``fit_standing``: the standing stage from poses and a prior calibration (report Sec. III-B).

Input: static poses (:mod:`.poses`), the calibration from hanging (offsets
``w_o``, leg weights, leg CoM curves) and the robot (nominal transducer poses,
weighed mass). Output: a :class:`StandingResult` whose ``calibration`` carries
``rotation_to_body = R_k = R_tilde_k R_nominal_k``, ``position_from_com_m = p'_k``
with standard errors, and ``com_body_m`` where the model determines it.

``balance="exact"`` fits eq. (E) of physics.py (the legs' moving CoMs cancel
exactly); ``balance="report"`` fits the report's eq. 9 (leg weights subtracted
with the hanging CoM curves about a fixed point C). For ``report``, the p'_k
estimated relative to C are moved to the body-without-legs CoM for the
calibration with the mean leg configuration of the poses:
``c_body^C = -sum_k m_k (R_k mean_p r_k(phi_pk) + p'_k) / M_b`` (C taken as the
mean whole-robot CoM); the se are carried over unchanged.

``weighting="fgls"`` (two-step feasible GLS, ``problem.py``): fit with eq. 8's K,
estimate ``C = mean_p r_p r_p^T`` of its residuals (B axes), refit from there with
``W = C^-1`` and take the Gauss-Newton covariance ``(sum_p J_p^T W J_p)^-1``
(``result.py``). The reported RSS, residuals, sigma and BIC stay the K-norm ones
of Table I, evaluated at the GLS estimate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ...core.balance import weights
from ...core.calibration import Calibration
from ...core.data import WRENCH_COMPONENTS
from ...core.errors import ConfigError, DataFormatError
from ...models import ErrorModel, ModelContext, ModelSpec, OffsetsOnly, resolve
from ...core.robot import Robot
from ...core.settings import STANDING_SOLVERS as SOLVERS
from ...core.settings import StandingSettings, with_overrides
from .baseline import BaselineSettings, solve_baseline, to_model_x
from .nlp import CompiledProblem, Solution, compile_problem
from .poses import Poses
from .problem import K_DIAG, L_values, check_balance, features, fgls_weight, knorm2, moments, to_world
from .result import StandingResult, param_label, physical, uncertainty



@dataclass
class StandingProblem:
    """One model and balance prepared for one robot and prior: spec and compiled functions."""

    model: ErrorModel
    ctx: ModelContext
    spec: ModelSpec
    balance: str
    compiled: CompiledProblem

    @property
    def name(self) -> str:
        return self.model.name


def check_inputs(poses: Poses, prior: Calibration, robot: Robot) -> None:
    if tuple(poses.legs) != tuple(robot.legs):
        raise ValueError(f"poses legs {poses.legs} differ from the robot's {robot.legs}")
    missing = [k for k in robot.legs if k not in prior.legs]
    if missing:
        raise DataFormatError(f"prior calibration has no leg(s) {missing}")
    off, w, _, _ = prior.stacked(robot.legs)
    if not np.all(np.isfinite(off)) or not np.all(np.isfinite(w)):
        raise DataFormatError("prior calibration: offsets and leg weights must be finite")
    if poses.n == 0:
        raise DataFormatError("no standing poses to fit")
    if not (np.all(np.isfinite(poses.w_m)) and np.all(np.isfinite(poses.R_WB)) and np.all(np.isfinite(poses.phi))):
        raise ValueError("standing poses: readings, shaft angles and orientations must be finite")


def prepare(prior: Calibration, robot: Robot, model: str | ErrorModel, balance: str, *,
            fit_offsets: bool = False, verbose: bool = False) -> StandingProblem:
    """Resolve the model (``fit_offsets``: the offsets-only model), build and compile it."""
    check_balance(balance)
    m = OffsetsOnly() if fit_offsets else resolve(model)
    ctx = ModelContext(tuple(robot.legs), robot.nominal_rotations(), robot.nominal_positions(), prior)
    spec = m.build(ctx)
    spec.validate(ctx.K, f"error model {m.name!r}")
    cp = compile_problem(spec, prior, ctx.legs, balance, model_name=m.name, verbose=verbose)
    return StandingProblem(m, ctx, spec, balance, cp)


def solve(problem: StandingProblem, xi: np.ndarray, solver: str, x0: np.ndarray | None = None,
          baseline: BaselineSettings = BaselineSettings(), W: np.ndarray | None = None) -> tuple[np.ndarray, Solution]:
    """Minimise eq. 8 on features ``xi`` with ``solver``; returns the model's x and the solver record.

    ``W`` (6x6, ipopt only): weight replacing K (the feasible GLS step)."""
    if solver == "ipopt":
        sol = problem.compiled.solve(moments(xi), x0, W)
        return sol.x, sol
    if W is not None:
        raise ConfigError(f"a weight W other than K needs solver 'ipopt', got {solver!r}", key="standing.solver")
    if solver == "baseline":
        R, p, off, sol = solve_baseline(problem.model, problem.ctx, xi, problem.balance, baseline)
        return to_model_x(problem.spec, problem.model, problem.ctx, R, p, off), sol
    raise ConfigError(f"unknown solver {solver!r}; known: {list(SOLVERS)}", key="standing.solver")


def heldout_mse(problem: StandingProblem, x: np.ndarray, xi: np.ndarray) -> float:
    """Mean K-norm squared residual per pose of ``xi`` at ``x``."""
    return float(knorm2(xi @ problem.compiled.L(x).T).mean())


def _report_to_body_com(prior: Calibration, legs, R: np.ndarray, p: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``c_body`` relative to the fixed point C of eq. 9 (module docstring), B axes."""
    m = np.array([prior.legs[k].leg_weight_N for k in legs])
    r_mean = np.stack([prior.legs[k].com(phi[:, i]).mean(axis=0) for i, k in enumerate(legs)])
    Mb = prior.mass_kg * prior.g - m.sum()
    return -np.einsum("k,ki->i", m, np.einsum("kij,kj->ki", R, r_mean) + p) / Mb


def prior_jacobian(problem: StandingProblem, phys, xi: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """``d r_p / d h`` (P, 6, n_h), B axes, for the prior (hanging) parameters the balance uses:
    each leg's offsets (unless the model fits its own) and leg weights ``m_k g`` (the balance is
    linear in both, so a unit difference of ``L`` is exact)."""
    legs, prior = problem.ctx.legs, problem.ctx.prior
    m, Mg = weights(prior, legs)
    fitted = phys.offsets is not None
    off = phys.offsets if fitted else np.stack([prior.legs[k].offset for k in legs])
    L0 = L_values(phys.R, phys.p_prime, off, m, Mg, problem.balance)[0]
    cols, names = [], []
    for k, leg in enumerate(legs):
        if not fitted:
            for c, comp in enumerate(WRENCH_COMPONENTS):
                d = off.copy()
                d[k, c] += 1.0
                cols.append(L_values(phys.R, phys.p_prime, d, m, Mg, problem.balance)[0] - L0)
                names.append(f"{leg}.w_o.{comp}")
        dm = m.copy()
        dm[k] += 1.0
        cols.append(L_values(phys.R, phys.p_prime, off, dm, Mg, problem.balance)[0] - L0)
        names.append(f"{leg}.mg")
    return np.einsum("pj,hij->pih", xi, np.stack(cols)), names


def make_result(problem: StandingProblem, poses: Poses, xi: np.ndarray, x: np.ndarray, sol: Solution, solver: str, *,
                rel_eig_tol: float, covariance: str, W: np.ndarray | None = None) -> StandingResult:
    """Evaluate the fit at ``x``: residuals, uncertainty, undetermined directions, calibration.

    ``W``: the fit's weight when it is not K (feasible GLS); the covariance uses it, RSS stays K-norm."""
    legs, K, prior = problem.ctx.legs, problem.ctx.K, problem.ctx.prior
    phys = physical(problem.spec, x, legs)
    J_h, h_names = prior_jacobian(problem, phys, xi)
    unc = uncertainty(problem.compiled, x, xi, phys, rel_eig_tol=rel_eig_tol, covariance=covariance, W=W, J_h=J_h)
    se = unc.se
    rot_se = se[: 3 * K].reshape(K, 3)
    p_se = se[3 * K : 6 * K].reshape(K, 3)
    i = 6 * K
    off_se = None
    if phys.offsets is not None:
        off_se = se[i : i + 6 * K].reshape(K, 6)
        i += 6 * K
    com_se = se[i : i + 3] if phys.com_body is not None else None
    r_B = xi @ problem.compiled.L(x).T
    residuals = to_world(r_B, poses.R_WB)
    rss = float(knorm2(r_B).sum())

    p_body, com = phys.p_prime, phys.com_body
    if problem.balance == "report":
        c_b = _report_to_body_com(prior, legs, phys.R, phys.p_prime, poses.phi)
        p_body = phys.p_prime - c_b
        com = None if com is None else com + c_b
    if isinstance(problem.model, OffsetsOnly):
        com = prior.com_body_m
    new_legs = {}
    for k, leg in enumerate(legs):
        l = prior.legs[leg]
        kept = np.all(np.isnan(p_se[k]))  # translations not estimated by this model: the prior's se stays
        kw = dict(rotation_to_body=phys.R[k], position_from_com_m=p_body[k],
                  position_from_com_se_m=l.position_from_com_se_m if kept else p_se[k])
        if phys.offsets is not None and off_se is not None:   # (set together above)
            kw.update(offset=phys.offsets[k], offset_se=off_se[k])
        new_legs[leg] = replace(l, **kw)
    meta = dict(prior.meta)
    meta["standing"] = {
        "model": problem.name, "balance": problem.balance, "solver": solver, "status": sol.status,
        "weighting": "knorm" if W is None else "fgls", "n_poses": int(poses.n), "rss": rss, "dof": problem.spec.n_dof, "sigma": float(np.sqrt(unc.sigma2)),
        "rotation_se_rad": {leg: rot_se[k].tolist() for k, leg in enumerate(legs)},
        "unidentified": list(unc.unidentified),
    }
    cal = replace(prior, legs=new_legs, model=problem.name, com_body_m=None if com is None else np.asarray(com, float), meta=meta)
    return StandingResult(
        calibration=cal, rotations=phys.R, rotvec_se=rot_se, p_prime=phys.p_prime, p_prime_se=p_se,
        com_body_m=None if com is None else np.asarray(com, float), residuals=residuals, rss=rss, dof=problem.spec.n_dof,
        n_poses=int(poses.n), unidentified=unc.unidentified, solver_status=sol.status, solve_time_s=sol.solve_time_s,
        model=problem.name, balance=problem.balance, solver=solver, legs=tuple(legs), R_nominal=problem.ctx.R_nominal,
        com_body_se_m=com_se, offsets=phys.offsets, offsets_se=off_se, unidentified_params=unc.unidentified_params,
        sigma2=unc.sigma2, eig_ratio=unc.eig_ratio, x=x, iterations=sol.iterations,
        weighting="knorm" if W is None else "fgls", weight=None if W is None else np.asarray(W, float),
        param_labels=phys.labels, cov=unc.cov, se=unc.se,
        sensitivity=None if unc.sensitivity is None else pd.DataFrame(
            unc.sensitivity, index=[param_label(l) for l in phys.labels], columns=h_names),
    )


def fit_standing(poses: Poses, prior: Calibration, robot: Robot, settings: StandingSettings | None = None, *,
                 fit_offsets: bool = False, baseline: BaselineSettings = BaselineSettings(), verbose: bool = False,
                 **overrides) -> StandingResult:
    """Fit the transducer-to-CoM transforms (or, ``fit_offsets=True``, the offsets alone) to standing poses.

    ``settings``: :class:`~ftcal_nlp.core.settings.StandingSettings`; keyword ``overrides`` replace
    single fields. Used here: ``model`` (a registered name ``full``, ``rot6_trans1``,
    ``trans6``, ``trans1``, ``module:Class``, ``file.py:Class`` or an ErrorModel; not
    ``"auto"``: choosing among candidates is :func:`~ftcal_nlp.estimate.selection.select_models`'
    job; ignored when ``fit_offsets``), ``solver`` (``ipopt``: exact SO(3); ``baseline``: the
    report's Cayley + alternating least squares), ``balance`` (``exact`` eq. E or ``report``
    eq. 9), ``weighting`` (``knorm``: eq. 8's K; ``fgls``: K fit, then refit with
    W = (mean residual covariance)^-1, IPOPT only), ``covariance`` and ``rel_eig_tol``.
    ``baseline``: the baseline solver's tolerances. Raises :class:`SolverError` when the
    solver does not converge.
    """
    s = with_overrides(settings, StandingSettings, overrides, "fit_standing")
    model, solver, balance, weighting = s.model, s.solver, s.balance, s.weighting
    covariance, rel_eig_tol = s.covariance, s.rel_eig_tol
    if model == "auto" and not fit_offsets:
        raise ConfigError("fit_standing fits one model: pass model='full' (or another name); "
                          "'auto' is resolved by select_models or calibrate", key="standing.model")
    check_inputs(poses, prior, robot)
    t0 = time.perf_counter()
    problem = prepare(prior, robot, model, balance, fit_offsets=fit_offsets, verbose=verbose)
    xi = features(poses.w_m, poses.phi, poses.R_WB, prior, robot.legs, balance)
    x, sol = solve(problem, xi, solver, baseline=baseline)
    W = None
    if weighting == "fgls":
        W = fgls_weight(xi @ problem.compiled.L(x).T)
        # IPOPT's tolerances are absolute: solve with W scaled like K (same minimiser), keep W for the covariance
        t_first = sol.solve_time_s
        x, sol = solve(problem, xi, "ipopt", x0=x, W=W * (K_DIAG.sum() / np.trace(W)))
        sol = replace(sol, solve_time_s=sol.solve_time_s + t_first)
    res = make_result(problem, poses, xi, x, sol, solver, rel_eig_tol=rel_eig_tol, covariance=covariance, W=W)
    return replace(res, total_time_s=time.perf_counter() - t0)
