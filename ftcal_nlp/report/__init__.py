"""The run's report: tables (CSV, Markdown, LaTeX), figures (PNG), ``report.md`` and a
self-contained ``report.html`` (figures embedded), rendered from a :class:`RunResult` only."""

from __future__ import annotations

import base64
import html
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from . import figures
from .tables import parameter_table, to_latex, to_markdown, truth_check

if TYPE_CHECKING:
    from ..run import RunResult

log = logging.getLogger(__name__)


@dataclass
class Section:
    title: str
    text: list[str] = field(default_factory=list)
    tables: list[tuple[str, pd.DataFrame]] = field(default_factory=list)
    figures: list[tuple[str, Path]] = field(default_factory=list)


def write_table(df: pd.DataFrame, folder: Path, stem: str, caption: str) -> None:
    df.to_csv(folder / f"{stem}.csv", index=False)
    (folder / f"{stem}.md").write_text(to_markdown(df))
    (folder / f"{stem}.tex").write_text(to_latex(df, caption=caption, label=f"tab:{stem}"))


def _rms(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.nanmean(np.asarray(a) ** 2, axis=0))


def summary_paragraph(res: "RunResult") -> str:
    ds, cal = res.dataset, res.calibration
    parts = [
        f"Dataset with {len(ds.hanging)} hanging, {len(ds.standing)} standing and {len(ds.walking)} walking recordings of "
        f"a {ds.robot.n_legs}-legged robot of {ds.robot.mass_kg:g} kg."
    ]
    if res.poses is not None:
        parts.append("Pose extraction kept " + " -> ".join(f"{v} ({k})" for k, v in res.poses.counts.items()) + " poses.")
    if res.selection is not None:
        parts.append(f"Model selection (5-fold CV and BIC) chose `{res.selection.best}`.")
    else:
        parts.append(f"The model was fixed to `{cal.model}`.")
    if res.standing is not None and res.poses is not None:
        try:
            nv = _rms(figures.naive_total_residuals(res))
            parts.append(
                f"The total-wrench residual RMS fell from {nv[:3].max():.3g} N / {nv[3:].max():.3g} N*m with naive taring "
                f"to {_rms(res.standing.residuals)[:3].max():.3g} N / {_rms(res.standing.residuals)[3:].max():.3g} N*m calibrated (worst component)."
            )
        except (ValueError, IndexError) as exc:
            parts.append(f"(Naive comparison not available: {exc}.)")
    if res.standing is not None and getattr(res.standing, "unidentified", ()):
        parts.append("Not identifiable from these poses: " + "; ".join(res.standing.unidentified) + ".")
    if res.diagnosis is not None:
        parts.append(f"Sim-to-real gap diagnosis: verdict `{res.diagnosis.verdict}`" + (f" (effect `{res.diagnosis.effect}`)." if res.diagnosis.effect else "."))
    parts += res.notes
    return " ".join(parts)


def build_sections(res: "RunResult", folder: Path) -> list[Section]:
    robot = res.dataset.robot
    secs: list[Section] = [Section("Summary", [summary_paragraph(res)])]
    nominal = {k: robot.transducers[k].rotation for k in robot.legs}
    rv_se = None
    if res.standing is not None and getattr(res.standing, "rotvec_se", None) is not None:
        rv_se = {k: np.asarray(res.standing.rotvec_se)[i] for i, k in enumerate(robot.legs)}
    par = parameter_table(res.calibration, nominal, rv_se)
    write_table(par, folder, "parameters", "Estimated calibration parameters (value +- standard error), cf. report Table II")
    s = Section("Calibration parameters (cf. Table II)", ["Value +- standard error; rotation errors as rotation vectors of R_k R_nominal^T."], [("parameters", par)])
    if res.truth is not None:
        tc = truth_check(res.calibration, res.truth, rv_se)
        write_table(tc, folder, "truth_check", "Estimate vs simulated truth")
        s.tables.append(("truth check (simulated data: error and error/se)", tc))
    secs.append(s)
    if res.selection is not None:
        sel = res.selection.table()
        write_table(sel, folder, "model_selection", "Model selection statistics (cf. report Table I)")
        secs.append(Section("Model selection (cf. Table I)", [f"Selected: `{res.selection.best}`."], [("model selection", sel)]))
    if res.hanging is not None:
        ht = res.hanging.table()
        ht = ht.reset_index() if ht.index.name is not None else ht
        write_table(ht, folder, "hanging", "Hanging calibration (value +- se)")
        hs = Section("Hanging calibration", [f"Method: `{res.hanging.method}`."], [("hanging", ht)])
        for name, fn in (("leg_com.png", figures.fig_leg_com), ("hanging_residuals.png", figures.fig_hanging_residuals)):
            hs.figures.append((name, _try_figure(fn, res, folder / name)))
        if res.hanging_baseline is not None:
            comp = _hanging_comparison(res)
            if comp is not None:
                write_table(comp, folder, "hanging_nlp_vs_baseline", "Hanging: NLP vs report baseline")
                hs.tables.append(("NLP vs baseline", comp))
        secs.append(hs)
    st = Section("Standing calibration")
    if res.standing is not None:
        st.text.append("```\n" + res.standing.summary() + "\n```")
    if res.hanging is not None:
        st.figures.append(("naive_total.png", _try_figure(figures.fig_naive_total, res, folder / "naive_total.png")))
    st.figures.append(("total_residuals.png", _try_figure(figures.fig_total_residuals, res, folder / "total_residuals.png")))
    secs.append(st)
    if res.corrected:
        ws = Section("Walking: ground contact wrenches", [f"Corrected recordings in `corrected/`: {', '.join(res.corrected)}."])
        for rec in res.dataset.walking:
            name = f"walking_{rec.name}.png"
            ws.figures.append((name, _try_figure(figures.fig_walking, res, rec, folder / name)))
        secs.append(ws)
    if res.diagnosis is not None and hasattr(res.diagnosis, "report_section"):
        secs.append(res.diagnosis.report_section(folder))
    tim = pd.DataFrame({"stage": list(res.timings), "seconds": [round(v, 3) for v in res.timings.values()]})
    secs.append(Section("Stage times", tables=[("times", tim)]))
    return secs


def _try_figure(fn, *args) -> Path | None:
    try:
        return fn(*args)
    except (ValueError, KeyError, AttributeError, IndexError) as exc:  # a missing input must not sink the report
        log.warning("figure %s not drawn: %s", getattr(fn, "__name__", fn), exc)
        return None


def _hanging_comparison(res: "RunResult") -> pd.DataFrame | None:
    rows = []
    for k in res.dataset.robot.legs:
        a, b = res.hanging.legs[k], res.hanging_baseline.legs[k]
        row = {"leg": k, "m g NLP [N]": a.leg_weight_N, "m g baseline [N]": b.leg_weight_N,
               "offset F diff norm [N]": float(np.linalg.norm(np.asarray(a.offset[:3]) - b.offset[:3])),
               "offset T diff norm [N*m]": float(np.linalg.norm(np.asarray(a.offset[3:]) - b.offset[3:]))}
        if res.truth is not None:
            t = res.truth.legs[k]
            row["offset F error norm NLP [N]"] = float(np.linalg.norm(np.asarray(a.offset[:3]) - t.offset[:3]))
            row["offset F error norm baseline [N]"] = float(np.linalg.norm(np.asarray(b.offset[:3]) - t.offset[:3]))
        rows.append(row)
    return pd.DataFrame(rows)


def write_report(res: "RunResult", folder: Path) -> Path:
    """Write tables, figures, ``report.md`` and ``report.html`` into ``folder``; returns the md path."""
    folder = Path(folder)
    secs = build_sections(res, folder)
    md = ["# ftcal_nlp calibration report", ""]
    body = ["<h1>ftcal_nlp calibration report</h1>"]
    for s in secs:
        md += [f"## {s.title}", ""]
        body.append(f"<h2>{html.escape(s.title)}</h2>")
        for t in s.text:
            md += [t, ""]
            if t.startswith("```"):
                body.append(f"<pre>{html.escape(t.strip('`').strip())}</pre>")
            else:
                body.append(f"<p>{html.escape(t)}</p>")
        for name, df in s.tables:
            md += [f"**{name}**", "", to_markdown(df), ""]
            body.append(f"<h3>{html.escape(name)}</h3>" + df.to_html(index=False, border=0, classes="tbl", na_rep="n/a"))
        for name, path in s.figures:
            if path is None:
                md += [f"*(figure {name} not drawn: see the log)*", ""]
                continue
            md += [f"![{name}]({path.name})", ""]
            b64 = base64.b64encode(path.read_bytes()).decode()
            body.append(f'<figure><img alt="{html.escape(name)}" src="data:image/png;base64,{b64}" style="max-width:100%"></figure>')
    (folder / "report.md").write_text("\n".join(md))
    css = "body{font-family:sans-serif;max-width:1100px;margin:2em auto}table.tbl{border-collapse:collapse;font-size:12px}table.tbl td,table.tbl th{padding:2px 6px;border-bottom:1px solid #ddd}"
    (folder / "report.html").write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>ftcal_nlp report</title><style>{css}</style></head><body>{''.join(body)}</body></html>")
    return folder / "report.md"
