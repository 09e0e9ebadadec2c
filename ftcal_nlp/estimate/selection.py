"""Model selection among error models (report Sec. IV-2, Table I).

For every candidate model: the fit on all P poses gives the K-norm residual sum
of squares RSS (eq. 8) and

    BIC = P ln(RSS / P) + DOF ln P

(P poses, DOF the model's degrees of freedom), and k-fold cross-validation
(poses shuffled with ``np.random.default_rng(seed)``, split in ``folds`` parts;
fit on the others, mean K-norm squared residual per held-out pose) gives the
CV error, the mean over folds. The selected model has the smallest BIC (the
report's criterion; it also had the smallest CV error). The table keeps the
layout of Table I: Model, DOF, CV error, BIC; renderers give CSV, Markdown and
LaTeX text (writing files is the CLI's job).
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, fields

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from ..core.errors import ConfigError
from ..core.calibration import Calibration
from ..core.results import bic as information_bic
from ..core.results import fmt_pm, latex_escape
from ..core.robot import Robot
from .standing.fit import check_inputs, heldout_mse, make_result, prepare, solve
from ..core.settings import SelectionSettings, StandingSettings, with_overrides
from ..core.solver import SolverError
from .standing.poses import Poses
from .standing.problem import features
from .standing.result import StandingResult

TABLE_COLUMNS = ("Model", "DOF", "CV error", "BIC")


@dataclass(frozen=True)
class CandidateScore:
    """Fit statistics of one candidate; ``status`` is ``"ok"`` or the solver failure."""

    name: str
    description: str
    dof: int
    dof_label: str
    rss: float = float("nan")
    bic: float = float("nan")
    cv_error: float = float("nan")
    cv_fold_errors: tuple[float, ...] = ()
    status: str = "ok"
    time_s: float = float("nan")


@dataclass(frozen=True)
class SelectionResult:
    """Scores of every candidate, the full-data fits, and the selected model (smallest BIC)."""

    scores: tuple[CandidateScore, ...]
    results: dict[str, StandingResult]
    n_poses: int
    folds: int                      # what the selection used (SelectionSettings), recorded
    seed: int
    balance: str
    solver: str

    @property
    def best(self) -> str:
        ok = [s for s in self.scores if s.status == "ok" and np.isfinite(s.bic)]
        if not ok:
            raise SolverError("model selection: no candidate was fitted successfully", "no candidate fitted")
        return min(ok, key=lambda s: s.bic).name

    @property
    def best_result(self) -> StandingResult:
        return self.results[self.best]

    def table(self) -> pd.DataFrame:
        """Every statistic, one row per candidate, for programs: Table I's Model, DOF, CV error, BIC, then
        the candidate's key ``name`` (as ``calibration.json`` names the model), its DOF count ``dof``,
        RSS, the CV error's standard error over folds, status and time (s). The report shows
        :meth:`report_table` instead."""
        rows = []
        for s in self.scores:
            rows.append({
                "Model": s.description, "DOF": s.dof_label, "CV error": s.cv_error, "BIC": s.bic,
                "name": s.name, "dof": s.dof, "RSS": s.rss, "CV error se": _fold_se(s),
                "status": s.status, "time_s": s.time_s,
            })
        return pd.DataFrame(rows)

    def report_table(self, numeric: bool = False) -> pd.DataFrame:
        """Table I as the report shows it: rows labelled by the model, DOF, CV error ``± se`` over the folds,
        BIC and its difference to the selected model, the K-norm RSS (and the status where a fit failed).

        ``numeric``: numbers instead of formatted text (the CSV), the CV error's se in its own column.
        CV error and RSS are K-norm squares (eq. 8), N²."""
        best = self.best
        best_bic = next(s.bic for s in self.scores if s.name == best)
        failed = any(s.status != "ok" for s in self.scores)
        rows = []
        for s in self.scores:
            se = _fold_se(s)
            if numeric:
                row = {"DOF": s.dof_label, "CV error [N²]": s.cv_error, "CV error se [N²]": se, "BIC": s.bic,
                       "delta BIC": s.bic - best_bic, "RSS [N²]": s.rss, "selected": s.name == best}
            elif s.status != "ok":
                row = {"DOF": s.dof_label, "CV error [N²]": "failed", "BIC": "", "delta BIC": "", "RSS [N²]": ""}
            else:
                row = {"DOF": s.dof_label, "CV error [N²]": fmt_pm(s.cv_error, se), "BIC": f"{s.bic:.1f}",
                       "delta BIC": f"{s.bic - best_bic:.1f}", "RSS [N²]": f"{s.rss:.4g}"}
            if failed or numeric:
                row["status"] = s.status
            rows.append(row)
        return pd.DataFrame(rows, index=pd.Index([s.description for s in self.scores], name="Model"))

    def to_csv(self) -> str:
        return to_csv(self)

    def to_markdown(self) -> str:
        return to_markdown(self)

    def to_latex(self) -> str:
        return to_latex(self)


def _fold_se(s: CandidateScore) -> float:
    """Standard error of the mean CV error over the folds."""
    folds = np.asarray(s.cv_fold_errors, float)
    return float(folds.std(ddof=1) / np.sqrt(len(folds))) if len(folds) > 1 else float("nan")


def _report_layout(sel: SelectionResult) -> list[list[str]]:
    rows = []
    for s in sel.scores:
        if s.status != "ok":
            rows.append([s.description, s.dof_label, "failed", s.status])
            continue
        rows.append([s.description, s.dof_label, f"{s.cv_error:.4g}", f"{s.bic:.1f}"])
    return rows


def to_csv(sel: SelectionResult) -> str:
    """The whole table (all columns) as CSV text."""
    buf = io.StringIO()
    sel.table().to_csv(buf, index=False)
    return buf.getvalue()


def to_markdown(sel: SelectionResult) -> str:
    """Table I as a Markdown table (selected model in bold)."""
    best = sel.best
    lines = ["| " + " | ".join(TABLE_COLUMNS) + " |", "|---|---:|---:|---:|"]
    for s, row in zip(sel.scores, _report_layout(sel)):
        if s.name == best:
            row = [f"**{c}**" for c in row]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def to_latex(sel: SelectionResult) -> str:
    """Table I as a LaTeX tabular in a table environment, with the report's caption."""
    best = sel.best
    out = ["\\begin{table}[t]", "\\centering",
           f"\\caption{{Summary of model selection statistics ({sel.n_poses} poses, {sel.folds}-fold CV, {latex_escape(sel.balance)} balance). "
           "(Abbreviations: degree of freedom (DOF), cross-validation (CV), Bayesian information criterion (BIC))}",
           "\\begin{tabular}{lrrr}", "\\hline", " & ".join(TABLE_COLUMNS) + " \\\\", "\\hline"]
    for s, row in zip(sel.scores, _report_layout(sel)):
        cells = [latex_escape(c) for c in row]
        if s.name == best:
            cells = [f"\\textbf{{{c}}}" for c in cells]
        out.append(" & ".join(cells) + " \\\\")
    out += ["\\hline", "\\end{tabular}", "\\end{table}"]
    return "\n".join(out) + "\n"


def fold_indices(n: int, folds: int, seed: int) -> list[np.ndarray]:
    """Seeded shuffle of ``range(n)`` split into ``folds`` nearly equal parts."""
    if folds < 2 or folds > n:
        raise ConfigError(f"cross-validation needs 2 <= folds <= number of poses ({n}), got {folds}", key="selection.folds")
    perm = np.random.default_rng(seed).permutation(n)
    return [np.sort(f) for f in np.array_split(perm, folds)]


def select_models(poses: Poses, prior_calibration: Calibration, robot: Robot, standing: StandingSettings | None = None,
                  selection: SelectionSettings | None = None, *, on_failure: str = "raise", verbose: bool = False,
                  **overrides) -> SelectionResult:
    """CV error and BIC of every candidate model on ``poses`` (module docstring).

    ``standing``: its ``candidates`` (names or ``module:Class`` specs), ``solver``, ``balance``,
    ``covariance`` and ``rel_eig_tol`` are used (the fits here are K-norm, as Table I defines
    them); ``selection``: ``folds`` and ``seed``. Keyword ``overrides`` replace single fields of
    either (``select_models(poses, prior, robot, candidates=["full"], folds=3)``).
    ``on_failure="raise"`` (default) propagates a solver failure; ``"record"`` keeps it as a
    failed row of the table. ``verbose`` prints IPOPT's output. Folds are warm-started from the
    all-pose solution.
    """
    sel_keys = {f.name for f in fields(SelectionSettings)}
    sel = with_overrides(selection, SelectionSettings, {k: v for k, v in overrides.items() if k in sel_keys}, "select_models")
    st = with_overrides(standing, StandingSettings, {k: v for k, v in overrides.items() if k not in sel_keys}, "select_models")
    candidates, solver, balance, covariance = st.candidates, st.solver, st.balance, st.covariance
    folds, seed = sel.folds, sel.seed
    if on_failure not in ("raise", "record"):
        raise ValueError(f"on_failure: expected 'raise' or 'record', got {on_failure!r}")
    check_inputs(poses, prior_calibration, robot)
    parts = fold_indices(poses.n, folds, seed)
    xi = features(poses.w_m, poses.phi, poses.R_WB, prior_calibration, robot.legs, balance)
    P = poses.n
    scores, results = [], {}
    for cand in tqdm(candidates, desc="model selection", unit="model", disable=None, leave=False):
        t0 = time.perf_counter()
        problem = prepare(prior_calibration, robot, cand, balance, verbose=verbose)
        name = problem.name
        desc = problem.model.description or name
        dof, label = problem.spec.n_dof, problem.spec.dof_label or str(problem.spec.n_dof)
        try:
            x, sol = solve(problem, xi, solver)
            res = make_result(problem, poses, xi, x, sol, solver, covariance=covariance, rel_eig_tol=st.rel_eig_tol)
            fold_err = []
            for test in parts:
                train = np.setdiff1d(np.arange(P), test)
                x_tr, _ = solve(problem, xi[train], solver, x0=x)
                fold_err.append(heldout_mse(problem, x_tr, xi[test]))
        except SolverError as exc:
            if on_failure == "raise":
                raise
            scores.append(CandidateScore(name, desc, dof, label, status=f"failed: {exc.status}", time_s=time.perf_counter() - t0))
            continue
        bic = information_bic(res.rss, P, dof)
        results[name] = res
        scores.append(CandidateScore(name, desc, dof, label, res.rss, bic, float(np.mean(fold_err)), tuple(fold_err), "ok",
                                     time.perf_counter() - t0))
    return SelectionResult(tuple(scores), results, P, folds, seed, balance, solver)
