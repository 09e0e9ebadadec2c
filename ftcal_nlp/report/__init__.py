"""The run's report: tables (CSV, Markdown, LaTeX), figures (PNG), ``report.md`` and a
self-contained ``report.html`` (figures embedded), rendered from a
:class:`~ftcal_nlp.calibration_run.CalibrationRun` only (its results objects and
its ``settings``).

* ``render.py``: sections and blocks, Markdown and HTML;
* ``tables.py``: the labelled tables (row labels with units, ``value ± se``) and their files;
* ``figures.py``: the calibration's figures; ``diagnosis.py``: the diagnosis' section and figures.

The report opens with a summary, then the notation it uses, then one section
per stage. Figures are drawn with whatever matplotlib backend the entry point
chose (``run.py`` sets Agg).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..core.data import WRENCH_COMPONENTS
from ..core.results import PM, Summary, fmt_pm
from . import figures
from .diagnosis import diagnosis_section
from .render import Bullets, Definitions, Figure, Section, Table, Text, render_html, render_markdown
from .tables import hanging_comparison, parameter_table, stage_times, truth_table, write_table

if TYPE_CHECKING:
    from ..calibration_run import CalibrationRun
    from ..estimate.hanging.result import HangingResult
    from ..estimate.selection import SelectionResult

__all__ = ["Section", "write_report", "build_sections", "summary_paragraph", "notation_section", "diagnosis_section", "legs_as_columns"]

log = logging.getLogger(__name__)

TITLE = "ftcal_nlp calibration report"


def _rms(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.nanmean(np.asarray(a) ** 2, axis=0))


def _model_description(res: "CalibrationRun", name: str) -> str:
    if res.selection is not None:
        for s in res.selection.scores:
            if s.name == name:
                return s.description
    return ""


def summary_paragraph(res: "CalibrationRun") -> str:
    """What was calibrated, how (from ``res.settings``), and what it changed."""
    ds, cal, st = res.dataset, res.calibration, res.settings
    parts = [
        f"Dataset with {len(ds.hanging)} hanging, {len(ds.standing)} standing and {len(ds.walking)} walking recordings of "
        f"a {ds.robot.n_legs}-legged robot of {ds.robot.mass_kg:g} kg."
    ]
    if res.hanging is not None:
        parts.append(f"Hanging stage: method `{res.hanging.method}`, leg CoM curves on {st.hanging.n_grid} shaft angles.")
    else:
        parts.append(f"Offsets only: offsets re-estimated from the standing poses, everything else kept from model `{cal.model}`.")
    if res.poses is not None:
        parts.append("Pose extraction kept " + " -> ".join(f"{v} ({k})" for k, v in res.poses.counts.items()) + " poses.")
    if res.selection is not None:
        sel = res.selection
        desc = _model_description(res, sel.best)
        parts.append(f"Model selection ({sel.folds}-fold CV and BIC over {len(sel.scores)} candidates, {sel.n_poses} poses) "
                     f"chose `{sel.best}`" + (f" ({desc})." if desc else "."))
    elif res.hanging is not None:
        parts.append(f"The model was fixed to `{cal.model}` (no model selection).")
    if res.standing is not None:
        s = res.standing
        parts.append(f"Standing fit: {s.balance} balance, {s.weighting} weighting, solver {s.solver} ({s.solver_status}).")
    if res.standing is not None and res.poses is not None:
        cal_rms = _rms(res.standing.residuals)
        try:
            nv = _rms(res.naive_total_residuals())
            parts.append(
                f"The total-wrench residual RMS (worst component) fell from {nv[:3].max():.3g} N / {nv[3:].max():.3g} N*m with "
                f"naive taring to {cal_rms[:3].max():.3g} N / {cal_rms[3:].max():.3g} N*m calibrated."
            )
        except (ValueError, IndexError) as exc:
            parts.append(f"Calibrated total-wrench residual RMS (worst component) {cal_rms[:3].max():.3g} N / "
                         f"{cal_rms[3:].max():.3g} N*m (naive comparison not available: {exc}).")
    if cal.com_body_m is not None:
        parts.append("CoM of the body without legs in B: (" + ", ".join(f"{1e3 * v:.1f}" for v in cal.com_body_m) + ") mm.")
    if res.standing is not None and res.standing.unidentified:
        parts.append(f"{len(res.standing.unidentified)} direction(s) of the parameters are not determined by these poses "
                     "(standard error inf; listed under Standing calibration).")
    if res.diagnosis is not None:
        parts.append(f"Sim-to-real gap diagnosis: verdict `{res.diagnosis.verdict}`"
                     + (f" (effect `{res.diagnosis.effect}`)." if res.diagnosis.effect else "."))
    elif not st.diagnose.enabled:
        parts.append("The sim-to-real gap diagnosis was not run (`[diagnose] enabled = false`).")
    if res.truth is not None:
        parts.append("The dataset carries its truth (`truth.json`): the estimates are checked against it below.")
    if res.notes:
        parts.append(f"{len(res.notes)} note(s) below.")
    return " ".join(parts)


NOTATION = (
    ("B", "body frame of the robot (its x axis forward, z up when standing level)."),
    ("W", "world frame of the motion capture, z up against gravity; R_WB turns B axes into W axes."),
    ("ft_k", "frame of the transducer of leg k (k in FL, ML, HL, FR, MR, HR): its readings w_m = [f; tau] are in ft_k axes."),
    ("heading frame", "origin at the robot's CoM at that instant, z up against gravity, x the body's x axis projected on the "
                      "horizontal plane; the corrected walking wrenches are in it."),
    ("w_o", "offset of a transducer: the wrench [f_o; tau_o] it reads with no load (N, N*m, ft_k axes)."),
    ("m_k g", "weight of leg k (N)."),
    ("r_k(phi)", "CoM of leg k in ft_k as a function of its shaft angle phi (rad), from the hanging recordings (mm in the figures)."),
    ("R_tilde_k", "mounting rotation error of transducer k: the rotation vector of R_k R_nominal_k^T, R_k the estimated "
                  "rotation from ft_k to B (deg in the tables)."),
    ("p'_k", "origin of ft_k relative to the CoM of the body without legs, in B axes (mm in the tables)."),
    ("K-norm", "||r||_K^2 = |f|^2 + 10 |tau|^2 for a wrench residual r = [f; tau] (report eq. 8; the weight 10 per m^2 "
               "makes N and N*m compare); RSS and CV error are sums / means of it (N²)."),
    ("CV", "k-fold cross-validation: mean K-norm squared residual per held-out pose of a model fitted to the other folds."),
    ("BIC", "Bayesian information criterion P ln(RSS/P) + DOF ln P (P poses); the smallest selects the model."),
    (PM, f"value {PM} one standard error; inf: the data do not determine the quantity; (fixed): kept from an earlier "
         "stage, not estimated here."),
)


def notation_section() -> Section:
    return Section("Notation", [Definitions(list(NOTATION))])


_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
_LIST_CELL = re.compile(r"^\s*([^:;]+):\s*([^;]+?)\s*$")


def _split_list_cell(text: str) -> list[tuple[str, str]] | None:
    """``"a: 1 ± 0.1; b: 2 ± 0.1"`` -> ``[("a", "1 ± 0.1"), ("b", "2 ± 0.1")]``; None if the cell is not such a list."""
    out = []
    for p in str(text).split(";"):
        m = _LIST_CELL.match(p)
        if m is None:
            return None
        out.append((m.group(1).strip(), m.group(2)))
    return out


def legs_as_columns(df: pd.DataFrame) -> pd.DataFrame:
    """A table with one row per leg turned into one column per leg (as Table II), and list cells
    (``"rec: value; rec: value"``) spread over one row per item, so no cell is a paragraph."""
    if df.index.name != "leg":
        return df
    t = df.T
    rows, labels = [], []

    def add(label: str, sub: str, cells: list) -> None:
        head, unit = (label.rsplit(" [", 1) + [""])[:2]
        labels.append(f"{head} {sub}" + (f" [{unit}" if unit else ""))
        rows.append(cells)

    for label, row in t.iterrows():
        label = str(label)
        cells = [_split_list_cell(v) for v in row]
        items = [it for it in cells if it]   # every cell a list, or the row is not spread by name
        names = [n for n, _ in items[0]] if items and len(items) == len(cells) else None
        triples = [str(v).split() for v in row]
        if names and all([n for n, _ in it] == names for it in items):
            for j, n in enumerate(names):
                add(label, n, [it[j][1] for it in items])
        elif all(len(tr) == 3 and all(_NUMBER.fullmatch(x) for x in tr) for tr in triples):
            for j, c in enumerate("xyz"):  # "fx fy fz" in one cell: one row per component
                add(label, c, [tr[j] for tr in triples])
        else:
            labels.append(label)
            rows.append(list(row))
    return pd.DataFrame(rows, index=pd.Index(labels, name="quantity"), columns=list(t.columns))


def _readable(summary: Summary) -> Summary:
    """The stage summary with per-leg tables laid out with legs as columns (``legs_as_columns``)."""
    return Summary(summary.title, list(summary.facts), [(c, legs_as_columns(df)) for c, df in summary.tables], list(summary.notes))


def _try_figure(fn, *args) -> Path | None:
    try:
        return fn(*args)
    except (ValueError, KeyError, AttributeError, IndexError) as exc:  # a missing input must not sink the report
        log.warning("figure %s not drawn: %s", getattr(fn, "__name__", fn), exc)
        return None


def _parameters(res: "CalibrationRun", folder: Path) -> Section:
    sec = Section("Calibration parameters (cf. report Table II)")
    par = parameter_table(res)
    caption = f"Calibration parameters per leg (value {PM} standard error), as in calibration.json"
    write_table(par, folder, "parameters", caption)
    if res.hanging is not None:
        origin = ("Offsets and leg weights come from the hanging stage, R_tilde and p' from the standing fit. The standing "
                  "fit conditions on the hanging estimates; the standard errors shown for R_tilde and p' include what the "
                  f"hanging uncertainty adds (the run's joint covariance, `cov_params()`: {res.joint_covariance()[3]}).")
    else:
        origin = ("Offsets-only run: the offsets are re-estimated from the standing poses; everything else is kept from the "
                  "earlier calibration ((fixed): not estimated here).")
    sec.add(Text(f"The finished calibration, as written to `calibration.json`. {origin}"))
    sec.add(Table(caption, par))
    if res.truth is not None:
        tc = truth_table(res)
        tcap = "Estimate vs truth: largest |estimate - truth| over the components, and largest |error| / se"
        write_table(tc, folder, "truth_check", tcap)
        sec.add(Table(tcap, tc))
    return sec


def _selection(res: "CalibrationRun", sel: SelectionResult, folder: Path) -> Section:
    sec = Section("Model selection (cf. report Table I)")
    view = sel.report_table()
    best = _model_description(res, sel.best)
    caption = (f"Model selection statistics: {sel.n_poses} poses, {sel.folds}-fold CV (seed {sel.seed}), "
               f"{sel.balance} balance, K-norm fits")
    write_table(view, folder, "model_selection", caption, csv=sel.report_table(numeric=True))
    sec.add(Text(f"Every candidate error model is fitted to all poses (RSS, BIC) and in {sel.folds}-fold cross-validation "
                 f"(CV error {PM} its standard error over the folds). The model with the smallest BIC is selected: "
                 f"**{best or sel.best}** (`{sel.best}` in calibration.json). delta BIC is the difference to it."))
    sec.add(Table(caption, view, highlight=best or None))
    return sec


def _hanging(res: "CalibrationRun", hanging: HangingResult, folder: Path) -> Section:
    sec = Section("Hanging calibration")
    summ = hanging.summary()
    ht = hanging.table()
    write_table(ht, folder, "hanging", f"Hanging calibration ({hanging.method}): offsets w_o (ft_k axes) and leg weights, "
                                        f"value {PM} standard error")
    sec.add(Text("Robot hung with its feet in the air in several orientations, legs turning: each transducer reads its "
                 "offset w_o plus its leg's weight m_k g acting at r_k(phi)."))
    sec.add(_readable(summ))
    sec.add(Figure("leg_com.png", _try_figure(figures.fig_leg_com, res, folder / "leg_com.png"),
                   f"Estimated leg CoM r_k(phi) per shaft angle with {PM}1 se and {PM}2 se bands and a fitted sinusoid"
                   + (" beside the truth" if res.truth is not None else "") + "."))
    sec.add(Figure("hanging_residuals.png", _try_figure(figures.fig_hanging_residuals, res, folder / "hanging_residuals.png"),
                   "Distribution of the hanging residuals per leg and component, with and without the estimated "
                   "misalignment of each hanging recording."))
    comp = hanging_comparison(res)
    if comp is not None:
        cap = "Hanging: NLP vs the report's baseline procedure"
        write_table(comp, folder, "hanging_nlp_vs_baseline", cap)
        sec.add(Table(cap, comp))
    return sec


def _standing(res: "CalibrationRun", folder: Path) -> Section:
    sec = Section("Standing calibration")
    if res.standing is not None:
        what = ("how each transducer is mounted (R_tilde_k, p'_k)" if res.hanging is not None
                else "the transducer offsets w_o (the rest of the calibration kept)")
        sec.add(Text(f"Standing poses of the robot on the floor, held still: the balance of forces and torques on the body "
                     f"determines {what}."))
        sec.add(_readable(res.standing.summary()))
        st = res.standing.table()
        write_table(st, folder, "standing", f"Standing calibration (model {res.standing.model}): R_tilde and p', "
                                            f"value {PM} standard error")
    if res.hanging is not None and res.poses is not None:
        sec.add(Figure("naive_total.png", _try_figure(figures.fig_naive_total, res, folder / "naive_total.png"),
                       "What the robot reads with naive taring: the total wrench over the standing poses less its weight "
                       "(zero if the transducers were perfect)."))
    if res.standing is not None and res.poses is not None:
        sec.add(Figure("total_residuals.png", _try_figure(figures.fig_total_residuals, res, folder / "total_residuals.png"),
                       "Total-wrench residual over the standing poses with naive taring, with the hanging stage but nominal "
                       "transducer poses (no transformation error), and calibrated; bottom row: the calibrated residual on "
                       "its own scale."))
    return sec


def _walking(res: "CalibrationRun", folder: Path) -> Section:
    sec = Section("Walking: ground contact wrenches")
    sec.add(Text("Every walking recording corrected with the calibration, one CSV per recording in `corrected/` "
                 f"({', '.join(f'`{n}.csv`' for n in res.corrected)}): per foot the ground force (N) and its torque about "
                 "the robot's CoM (N*m), in the heading frame; then their standard errors (`{leg}_{c}_se`, `total_{c}_se`: "
                 "the calibration's joint covariance and the sensor noise estimated at calibration, by the delta method) "
                 "and each foot's contact state (`{leg}_contact`, 1 stance, 0 swing)."))
    for name, tr in res.tracked_offsets.items():
        sec.add(Table(f"Offsets tracked from the swing phases of {name}: change since calibration (time mean, "
                      f"value {PM} se) and significance (chi^2 on 6 dof, p < 0.001)", _tracked_table(tr)))
    for rec in res.dataset.walking:
        if rec.name not in res.corrected:
            continue
        name = f"walking_{rec.name}.png"
        sec.add(Figure(name, _try_figure(figures.fig_walking, res, rec, folder / name),
                       f"Ground contact forces of {rec.name}, calibrated (solid, with its {PM}1.96 se band) vs naive taring "
                       "(dotted), one colour per leg; bottom row: the normal force near zero, swing phases shaded."))
    return sec


def _tracked_table(tr) -> pd.DataFrame:
    """Per leg: each component's change since calibration as ``value ± se``, then p and significance."""
    tab = tr.change_table()
    rows = {}
    for k, r in tab.iterrows():
        if not r["tracked"]:
            rows[k] = {c: "not tracked" for c in WRENCH_COMPONENTS} | {"p": "", "significant": ""}
            continue
        rows[k] = {c: fmt_pm(r[f"change_{c}"], r[f"change_{c}_se"]) for c in WRENCH_COMPONENTS}
        rows[k] |= {"p": f"{r['p']:.2g}", "significant": "yes" if r["significant"] else "no"}
    df = pd.DataFrame(rows).T
    df.index.name = "leg"
    return df


def build_sections(res: "CalibrationRun", folder: Path) -> list[Section]:
    """Every section of the report, in order; writes the tables and figures into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    secs = [Section("Summary", [Text(summary_paragraph(res))]), notation_section(), _parameters(res, folder)]
    if res.selection is not None:
        secs.append(_selection(res, res.selection, folder))
    if res.hanging is not None:
        secs.append(_hanging(res, res.hanging, folder))
    secs.append(_standing(res, folder))
    if res.corrected:
        secs.append(_walking(res, folder))
    if res.diagnosis is not None:
        secs.append(diagnosis_section(res.diagnosis, folder))
    tim = stage_times(res)
    write_table(tim, folder, "stage_times", "Stage times")
    secs.append(Section("Stage times", [Table("Time per stage", tim)]))
    if res.notes:
        secs.insert(1, Section("Notes", [Bullets(list(res.notes))]))
    return secs


def write_report(res: "CalibrationRun", folder: Path) -> Path:
    """Write tables, figures, ``report.md`` and ``report.html`` into ``folder``; returns the md path."""
    if getattr(res, "free_loads", None) is not None:   # section-5 loads: their own sections (report/loads.py)
        from .loads import write_load_report

        return write_load_report(res, folder)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    secs = build_sections(res, folder)
    (folder / "report.md").write_text(render_markdown(TITLE, secs))
    (folder / "report.html").write_text(render_html(TITLE, secs))
    return folder / "report.md"
