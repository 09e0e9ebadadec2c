"""Report of a run on free loads (``DATA_FORMAT.md`` section 5, issue 22): a wrist tool, URDF links below a sensor.

Sections: summary; notes; per transducer the load table (offsets, mass, CoM or the URDF groups' masses and
first moments, mounting rotation; estimate ± se, the truth beside it when ``truth.json`` came with the
dataset); the measured and the predicted reading per component over time of every recording in which the
load hangs free, and the residual (measured - predicted) below them, quasi-static samples marked (the fit
uses those; the moves show what a static model leaves out); the residual RMS per component over the
quasi-static samples and over all, beside the noise sd the fit weighted with; the fit's facts (samples kept
and dropped per recording, IPOPT); what the data leave
undetermined and the determined combinations; stage times. Predictions come from
``FreeLoadResult.predict_recording`` (the fitted model:
``f = M E^T b + f_o``, ``t = s x E^T b + t_o``); the quasi-static selection is the estimator's own
(``freeload.quasistatic``). Files: ``load_{leg}.csv/.md/.tex``, ``load_readings_{leg}.png``,
``load_residuals.csv``, ``report.md``, ``report.html``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..core.data import WRENCH_COMPONENTS
from ..core.results import fmt_pm
from .render import Bullets, Figure, Section, Table, Text, render_html, render_markdown
from .tables import stage_times, write_table

if TYPE_CHECKING:
    from ..calibration_run import CalibrationRun
    from ..core.data import Recording
    from ..estimate.freeload.result import FreeLoadResult

log = logging.getLogger(__name__)

TITLE = "Calibration report: free loads"
UNITS = ("N", "N", "N", "N*m", "N*m", "N*m")


def _fits(res: "CalibrationRun") -> dict[str, FreeLoadResult]:
    """The run's free-load fits per transducer: every function here reads a run on free loads (``write_report`` sends
    only those here)."""
    assert res.free_loads is not None, "a run on free loads"
    return res.free_loads.legs


def _truth_for(res: "CalibrationRun", leg: str):
    from ..truth import LoadTruth

    t = res.truth
    return t if isinstance(t, LoadTruth) and (t.transducer in (None, leg)) else None


def load_table(res: "CalibrationRun", leg: str) -> pd.DataFrame:
    """One row per reported quantity of ``leg``'s load: estimate ± se (and truth, when known), in SI units
    (mounting rotation in deg)."""
    fit = _fits(res)[leg]
    rep = fit.load_report()
    truth = _truth_for(res, leg)
    rows: list[tuple[str, str, float | None]] = []
    for i, c in enumerate(WRENCH_COMPONENTS):
        rows.append((f"offset {c} [{UNITS[i]}]", fmt_pm(fit.offset[i], fit.se[i]), None if truth is None else truth.offset[i]))
    rows.append(("load mass [kg]", fmt_pm(rep["load_mass_kg"], rep["load_mass_se_kg"]), None if truth is None else truth.mass_kg))
    if "load_com_m" in rep:
        for i, ax in enumerate("xyz"):
            rows.append((f"CoM {ax} [mm] (ft)", fmt_pm(1e3 * rep["load_com_m"][i], 1e3 * rep["load_com_se_m"][i]),
                         None if truth is None or truth.com_m is None else 1e3 * truth.com_m[i]))
    gt = _group_truth(truth, fit.load) if rep.get("urdf_groups") else None
    for k, (g, d) in enumerate(rep.get("urdf_groups", {}).items()):
        rows.append((f"group {g}: mass [kg] ({', '.join(d['links'])})", fmt_pm(d["mass_kg"], d["mass_se_kg"]),
                     None if gt is None else gt[0][k]))
        for i, ax in enumerate("xyz"):
            rows.append((f"group {g}: first moment {ax} [kg mm] ({d['frame']})",
                         fmt_pm(1e3 * d["first_moment_kgm"][i], 1e3 * d["first_moment_se_kgm"][i]),
                         None if gt is None else 1e3 * gt[1][k][i]))
    if "gravity_tilt_rad" in rep:   # the world tilt of the orientation stream
        tv, tv_se = np.degrees(rep["gravity_tilt_rad"]), np.degrees(rep["gravity_tilt_se_rad"])
        for i, ax in enumerate("xy"):
            rows.append((f"world tilt of the orientation stream {ax} [deg]", fmt_pm(tv[i], tv_se[i]), None))
    for rec, tv in rep.get("recording_tilt_rad", {}).items():   # a tilt per gravity_body-only recording
        for i, ax in enumerate("xy"):
            rows.append((f"tilt of recording {rec} {ax} [deg]",
                         fmt_pm(np.degrees(tv[i]), np.degrees(rep["recording_tilt_se_rad"][rec][i])), None))
    rv, rv_se = np.degrees(rep["mount_rotvec"]), np.degrees(rep["mount_rotvec_se"])
    for i, ax in enumerate("xyz"):
        rows.append((f"mounting rotation {ax} [deg]", fmt_pm(rv[i], rv_se[i]),
                     None if truth is None or truth.mount_rotvec is None else float(np.degrees(truth.mount_rotvec[i]))))
    df = pd.DataFrame({"estimate ± se": [r[1] for r in rows]}, index=pd.Index([r[0] for r in rows], name="quantity"))
    if truth is not None:
        df["truth"] = ["" if r[2] is None else f"{r[2]:.5g}" for r in rows]
    return df


def _group_truth(truth, load) -> tuple[np.ndarray, np.ndarray] | None:
    """True masses and first moments of the load's joint groups (``crb.group_truth``), or None."""
    from ..crb import group_truth

    groups = getattr(load, "groups", ())
    if truth is None or not truth.bodies or not all(l in truth.bodies for g in groups for l in g.links):
        return None
    return group_truth(load.tree, groups, truth.body_tuples())


def predicted_readings(res: "CalibrationRun", leg: str) -> list[tuple[Recording, np.ndarray, np.ndarray]]:
    """Per hanging recording in which ``leg``'s load hangs free: (recording, predicted (N, 6), quasi-static mask: the
    samples the fit used, ``FreeLoadResult.used``, else the estimator's selection recomputed)."""
    from ..estimate.freeload.quasistatic import select_quasi_static

    fit = _fits(res)[leg]
    s = res.settings.free_load
    joints = tuple(getattr(fit.load, "load_joints", ())) + tuple(getattr(fit.load, "base_joints", ()))
    out = []
    for rec in res.dataset.hanging:
        if not rec.hangs_free(leg):
            continue
        pred = fit.predict_recording(rec, res.dataset.robot.g)
        mask = getattr(fit, "used", {}).get(rec.name)          # the samples the fit used
        if mask is None or len(mask) != rec.n:
            q = {j: rec.q[j] for j in joints if j in rec.q}
            mask = select_quasi_static(rec.t, rec.wrench[leg][:, :3], rec.quat, rec.gravity, q, s, str(rec.path or rec.name)).mask
        out.append((rec, pred, mask))
    return out


def residual_table(res: "CalibrationRun") -> pd.DataFrame:
    """Residual RMS (measured - predicted) per transducer and component over the quasi-static samples and over
    all samples with a gravity direction, with the noise sd the fit weighted with."""
    rows = {}
    for leg, fit in _fits(res).items():
        parts = predicted_readings(res, leg)
        r = np.concatenate([rec.wrench[leg] - pred for rec, pred, _ in parts])
        m = np.concatenate([mask for *_, mask in parts])
        ok = np.all(np.isfinite(r), axis=1)
        rq, ra = r[ok & m], r[ok]
        for i, c in enumerate(WRENCH_COMPONENTS):
            rows[f"{leg} {c}"] = {"unit": UNITS[i], "rms quasi-static": float(np.sqrt(np.mean(rq[:, i] ** 2))),
                              "rms all samples": float(np.sqrt(np.mean(ra[:, i] ** 2))), "noise sd (fit)": float(fit.sigma[i]),
                              "n quasi-static": int(len(rq)), "n all": int(len(ra))}
    df = pd.DataFrame(rows).T
    df.index.name = "transducer component"
    return df


def fig_readings(res: "CalibrationRun", leg: str, path: Path, max_points: int = 20000) -> Path:
    """Measured and predicted reading per component over time (left), the residual (right), quasi-static samples
    darker; recordings one after another on the session clock."""
    import matplotlib.pyplot as plt

    parts = predicted_readings(res, leg)
    t = np.concatenate([rec.t for rec, *_ in parts])
    meas = np.concatenate([rec.wrench[leg] for rec, *_ in parts])
    pred = np.concatenate([p for _, p, _ in parts])
    mask = np.concatenate([m for *_, m in parts])
    step = max(1, len(t) // max_points)
    t, meas, pred, mask = t[::step], meas[::step], pred[::step], mask[::step]
    t = t - t[0]
    fig, axes = plt.subplots(6, 2, figsize=(12, 11), sharex=True, constrained_layout=True)
    for i, c in enumerate(WRENCH_COMPONENTS):
        a, b = axes[i, 0], axes[i, 1]
        a.plot(t, meas[:, i], ".", ms=1.0, color="0.6", label="measured")
        a.plot(t, pred[:, i], "-", lw=0.8, color="C0", label="predicted (fit)")
        a.set_ylabel(f"{c} [{UNITS[i]}]")
        r = meas[:, i] - pred[:, i]
        b.plot(t[~mask], r[~mask], ".", ms=1.0, color="C1", alpha=0.5, label="moving (not fitted)")
        b.plot(t[mask], r[mask], ".", ms=1.0, color="k", label="quasi-static (fitted)")
        b.axhline(0.0, color="C0", lw=0.6)
        b.set_ylabel(f"residual {c}")
    axes[0, 0].legend(loc="upper right", fontsize=7, markerscale=6)
    axes[0, 1].legend(loc="upper right", fontsize=7, markerscale=6)
    axes[-1, 0].set_xlabel("time since the first sample [s]")
    axes[-1, 1].set_xlabel("time since the first sample [s]")
    fig.suptitle(f"Transducer {leg}: reading measured and predicted by the fitted load, and the residual")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _facts(fit) -> Table:
    """The fit's summary facts (``FreeLoadResult.summary``) as a two-column table."""
    facts = fit.summary().facts
    df = pd.DataFrame({"value": [str(v) for _, v in facts]}, index=pd.Index([str(k) for k, _ in facts], name="fact"))
    return Table(f"Free-load fit of {fit.leg}", df)


def _figure(fn, *args) -> Path | None:
    try:
        return fn(*args)
    except Exception as exc:  # a figure that cannot be drawn is named in the log, the report goes on
        log.warning("figure %s not drawn: %s: %s", args[-1], type(exc).__name__, exc)
        return None


def load_sections(res: "CalibrationRun", folder: Path) -> list[Section]:
    """The report's sections for a run on free loads; writes their tables and figures into ``folder``."""
    fits = _fits(res)
    summ = []
    for leg, fit in fits.items():
        rep = fit.load_report()
        summ.append(f"Transducer **{leg}** ({fit.load.kind}): load mass {fmt_pm(rep['load_mass_kg'], rep['load_mass_se_kg'])} kg, "
                    f"mounting rotation {np.degrees(np.linalg.norm(fit.mount_rotvec)):.3g} deg, "
                    f"{fit.n_used} quasi-static samples used"
                    + (f"; {len(fit.undetermined)} direction(s) not determined by the data" if fit.undetermined else "") + ".")
    if res.diagnosis is not None:
        d = res.diagnosis
        summ.append(f"Sim-to-real gap diagnosis: verdict `{d.verdict}`"
                    + (" (effects " + ", ".join(f"`{e['name']}`" for e in d.effects) + ")." if d.effects else "."))
    if res.truth is not None:
        summ.append("The dataset carries its truth (`truth.json`): it is shown beside the estimates.")
    secs = [Section("Summary", [Text(" ".join(summ))])]
    shown = {n for fit in fits.values() for n in fit.identifiability()}     # listed with their load below
    notes = [n for n in res.notes if n not in shown]
    if notes:
        secs.append(Section("Notes", [Bullets(notes)]))
    for leg, fit in fits.items():
        sec = Section(f"Load of {leg}")
        tab = load_table(res, leg)
        cap = f"Load of {leg} ({fit.load.kind}): estimate ± standard error" + (", truth beside it" if "truth" in tab else "")
        write_table(tab, folder, f"load_{leg}", cap)
        sec.add(Text("Offsets in the transducer frame; CoM and first moments in the (estimated) transducer frame or "
                     "the frame of each group's joint; mounting rotation: R_true = R_nominal expm(r). se inf: not "
                     "determined by the data (see below)."))
        sec.add(Table(cap, tab))
        name = f"load_readings_{leg}.png"
        sec.add(Figure(name, _figure(fig_readings, res, leg, folder / name),
                       f"Transducer {leg}: measured (grey) and predicted (blue) reading per component over time, and the "
                       "residual (black: the quasi-static samples the fit uses; orange: moves)."))
        sec.add(Text("The estimator's own summary (quasi-static samples kept and dropped per recording, residual RMS "
                     "against the noise sd it weighted with, IPOPT):"))
        sec.add(_facts(fit))
        ident = fit.identifiability()
        sec.add(Text("What the data determine: " + ("every parameter." if not ident else "")))
        if ident:
            sec.add(Bullets(ident))
        secs.append(sec)
    rt = residual_table(res)
    cap = "Residual RMS (measured - predicted) per component: quasi-static samples, all samples, and the fit's noise sd"
    write_table(rt, folder, "load_residuals", cap)
    secs.append(Section("Residuals", [Text("A residual at the noise sd on the quasi-static samples is a model that "
                                            "explains the readings; larger on the moves is what a static model leaves out "
                                            "(accelerations, lags)."), Table(cap, rt)]))
    if res.diagnosis is not None:   # the free-load diagnosis (diagnose/free.py): the chain of effects, where the gap lies
        from .diagnosis import diagnosis_section

        secs.append(diagnosis_section(res.diagnosis, folder))
    tim = stage_times(res)
    write_table(tim, folder, "stage_times", "Stage times")
    secs.append(Section("Stage times", [Table("Time per stage", tim)]))
    return secs


def write_load_report(res: "CalibrationRun", folder: Path) -> Path:
    """Write the free-load report (tables, figures, ``report.md``, ``report.html``) into ``folder``; returns the md."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    secs = load_sections(res, folder)
    (folder / "report.md").write_text(render_markdown(TITLE, secs))
    (folder / "report.html").write_text(render_html(TITLE, secs))
    return folder / "report.md"
