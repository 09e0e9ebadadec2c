"""The report's tables, built from the results objects, and their files (CSV, Markdown, LaTeX).

Every table is a ``DataFrame`` whose index holds the row labels (named: the
first column of every file) and whose labels carry units; estimates are
``value ± se`` (:func:`ftcal_nlp.core.results.fmt_pm`). Renderers only format; they
never solve anything.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..core.calibration import Calibration
from ..core.geometry import rotation_to_rotvec
from ..core.results import fmt_pm, latex_table
from .render import bold_md, md_table

if TYPE_CHECKING:
    from ..calibration_run import CalibrationRun

__all__ = ["write_table", "parameter_table", "truth_table", "hanging_comparison", "stage_times", "rotvec_se"]

XYZ = ("x", "y", "z")


def write_table(df: pd.DataFrame, folder: Path, stem: str, caption: str, csv: pd.DataFrame | None = None) -> None:
    """``stem.csv`` (``csv`` if given, else ``df``; the index as a labelled first column), ``stem.md`` and ``stem.tex``."""
    for t in (df, csv):
        if t is not None and not t.index.name:
            raise ValueError(f"table {stem}: the index (row labels) needs a name")
    c = df if csv is None else csv
    c.to_csv(folder / f"{stem}.csv", index=True, index_label=c.index.name)
    (folder / f"{stem}.md").write_text(bold_md(caption) + "\n\n" + md_table(df))
    (folder / f"{stem}.tex").write_text(latex_table(df, caption=caption, label=f"tab:{stem}") + "\n")


def rotvec_se(res: "CalibrationRun") -> dict[str, np.ndarray] | None:
    """Per leg the standard errors (rad) of the mounting rotation error's rotation vector: the calibration's
    (joint covariance, hanging uncertainty included) or else the standing stage's own."""
    cal = res.calibration.legs
    if all(cal[k].rotation_se_rad is not None for k in res.dataset.robot.legs):
        return {k: np.asarray(cal[k].rotation_se_rad, float) for k in res.dataset.robot.legs}
    if res.standing is None or getattr(res.standing, "rotvec_se", None) is None:
        return None
    return {k: np.asarray(res.standing.rotvec_se)[i] for i, k in enumerate(res.dataset.robot.legs)}


def parameter_table(res: "CalibrationRun") -> pd.DataFrame:
    """The report's Table II extended: per leg offsets, leg weight, mounting rotation error and p', ``value ± se``.

    Values and standard errors are those of the calibration (``calibration.json``);
    rotation errors ``R_tilde_k = R_k R_nominal_k^T`` as rotation vectors in degrees.
    """
    cal, robot = res.calibration, res.dataset.robot
    rse = rotvec_se(res)
    cols: dict[str, list[str]] = {}
    for k in robot.legs:
        l = cal.legs[k]
        se = l.offset_se if l.offset_se is not None else np.full(6, np.nan)
        rv = rotation_to_rotvec(l.rotation_to_body @ robot.transducers[k].given_rotation().T)
        rs = rse[k] if rse is not None else np.full(3, np.nan)
        pse = l.position_from_com_se_m if l.position_from_com_se_m is not None else np.full(3, np.nan)
        cols[k] = ([fmt_pm(l.offset[j], se[j]) for j in range(6)]
                   + [fmt_pm(l.leg_weight_N, l.leg_weight_se_N)]
                   + [fmt_pm(rv[j], rs[j], scale=180 / np.pi) for j in range(3)]
                   + [fmt_pm(l.position_from_com_m[j], pse[j], scale=1e3) for j in range(3)])
    rows = ([f"force offset {c} [N]" for c in XYZ] + [f"torque offset {c} [N*m]" for c in XYZ] + ["leg weight m g [N]"]
            + [f"R_tilde {c} [deg]" for c in XYZ] + [f"p' {c} [mm]" for c in XYZ])
    return pd.DataFrame(cols, index=pd.Index(rows, name="parameter"))


def hexapod_truth(res: "CalibrationRun") -> Calibration | None:
    """The dataset's truth when it is a hexapod's calibration (a free load's, a ``LoadTruth``, is ``report/loads.py``'s)."""
    return res.truth if isinstance(res.truth, Calibration) else None


def truth_table(res: "CalibrationRun") -> pd.DataFrame:
    """Simulated data: per parameter group and leg, the largest |estimate - truth| and, in brackets, the largest |error| / se."""
    cal, truth = res.calibration, hexapod_truth(res)
    if truth is None:
        raise ValueError("truth_table compares the calibration with the dataset's truth.json: the run has no hexapod's truth")
    rse = rotvec_se(res)
    groups = (("force offset [mN]", 1e3), ("torque offset [mN*m]", 1e3), ("leg weight m g [mN]", 1e3),
              ("leg CoM r_k(phi), grid [mm]", 1e3), ("R_tilde [deg]", 180 / np.pi), ("p' [mm]", 1e3))
    cols: dict[str, list[str]] = {}
    for k, l in cal.legs.items():
        t = truth.legs[k]
        osd = l.offset_se if l.offset_se is not None else np.full(6, np.nan)
        errs = (
            (l.offset[:3] - t.offset[:3], osd[:3]),
            (l.offset[3:] - t.offset[3:], osd[3:]),
            (np.atleast_1d(l.leg_weight_N - t.leg_weight_N), np.atleast_1d(np.nan if l.leg_weight_se_N is None else l.leg_weight_se_N)),
            (l.com_xyz - t.com(l.com_phi), l.com_xyz_se),
            (rotation_to_rotvec(l.rotation_to_body @ t.rotation_to_body.T), None if rse is None else rse[k]),
            (l.position_from_com_m - t.position_from_com_m, l.position_from_com_se_m),
        )
        col = []
        for (_, scale), (err, se) in zip(groups, errs):
            err = np.abs(np.asarray(err, float))
            if not np.isfinite(err).any():
                col.append("n/a")
                continue
            cell = f"{np.nanmax(err) * scale:.3g}"
            if se is not None:
                se = np.asarray(se, float)
                ok = np.isfinite(se) & (se > 0) & np.isfinite(err)
                if ok.any():
                    cell += f" ({np.max(err[ok] / se[ok]):.2g} se)"
            col.append(cell)
        cols[k] = col
    return pd.DataFrame(cols, index=pd.Index([g for g, _ in groups], name="parameter (max |error|)"))


def hanging_comparison(res: "CalibrationRun") -> pd.DataFrame | None:
    """Per leg: the leg weight of the NLP and of the report's baseline, and how far their offsets differ (and miss the truth)."""
    if res.hanging is None or res.hanging_baseline is None:
        return None
    rows = {}
    for k in res.dataset.robot.legs:
        a, b = res.hanging.legs[k], res.hanging_baseline.legs[k]
        row = {"m g NLP [N]": fmt_pm(a.leg_weight_N, a.leg_weight_se_N),
               "m g baseline [N]": fmt_pm(b.leg_weight_N, b.leg_weight_se_N),
               "force offset, |NLP - baseline| [mN]": f"{1e3 * np.linalg.norm(np.asarray(a.offset[:3]) - b.offset[:3]):.3g}",
               "torque offset, |NLP - baseline| [mN*m]": f"{1e3 * np.linalg.norm(np.asarray(a.offset[3:]) - b.offset[3:]):.3g}"}
        truth = hexapod_truth(res)
        if truth is not None:
            t = truth.legs[k]
            row["force offset, |NLP - truth| [mN]"] = f"{1e3 * np.linalg.norm(np.asarray(a.offset[:3]) - t.offset[:3]):.3g}"
            row["force offset, |baseline - truth| [mN]"] = f"{1e3 * np.linalg.norm(np.asarray(b.offset[:3]) - t.offset[:3]):.3g}"
        rows[k] = row
    df = pd.DataFrame(rows).T
    df.index.name = "leg"
    return df


def stage_times(res: "CalibrationRun") -> pd.DataFrame:
    """Wall (and CPU, where recorded) seconds per stage."""
    cpu = getattr(res, "cpu_timings", None) or {}
    data = {"wall time [s]": [f"{v:.2f}" for v in res.timings.values()]}
    if cpu:
        data["CPU time [s]"] = [f"{cpu[k]:.2f}" if k in cpu else "" for k in res.timings]
    return pd.DataFrame(data, index=pd.Index(list(res.timings), name="stage"))
