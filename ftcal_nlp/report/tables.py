"""Tables rendered from results: Markdown and LaTeX writers, Table II (value +- se), truth check.

Renderers only format; they never solve anything.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..calibration import Calibration
from ..geometry import rotation_to_rotvec

COMPONENTS = ("x", "y", "z")


def fmt_pm(value: float, se: float | None) -> str:
    """``value +- se`` with as many decimals as the se warrants (two significant digits of se)."""
    if se is None or not np.isfinite(se):
        return f"{value:.4g} (se n/a)" if np.isfinite(value) else "n/a"
    if se <= 0:
        return f"{value:.4g} +- 0"
    dec = max(0, int(-np.floor(np.log10(se))) + 1)
    return f"{value:.{dec}f} +- {se:.{dec}f}"


def to_markdown(df: pd.DataFrame) -> str:
    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for _, row in df.iterrows():
        lines.append("| " + " | ".join(_cell(v) for v in row) + " |")
    return "\n".join(lines) + "\n"


def to_latex(df: pd.DataFrame, caption: str = "", label: str = "") -> str:
    def esc(s: str) -> str:
        return s.replace("\\", "\\textbackslash{}").replace("_", "\\_").replace("%", "\\%").replace("&", "\\&").replace("+-", "$\\pm$")

    cols = [str(c) for c in df.columns]
    out = ["\\begin{table}[t]", "\\centering"]
    if caption:
        out.append(f"\\caption{{{esc(caption)}}}")
    if label:
        out.append(f"\\label{{{label}}}")
    out += ["\\begin{tabular}{l" + "r" * (len(cols) - 1) + "}", "\\hline", " & ".join(esc(c) for c in cols) + " \\\\", "\\hline"]
    for _, row in df.iterrows():
        out.append(" & ".join(esc(_cell(v)) for v in row) + " \\\\")
    out += ["\\hline", "\\end{tabular}", "\\end{table}"]
    return "\n".join(out) + "\n"


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}" if np.isfinite(v) else "n/a"
    return str(v)


def parameter_table(cal: Calibration, nominal_rotations: dict[str, np.ndarray], rotvec_se: dict[str, np.ndarray] | None = None) -> pd.DataFrame:
    """The report's Table II extended: offsets, leg weight, mounting rotation error and p', value +- se.

    Rotation errors are ``R_tilde = R_k R_nominal_k^T`` as rotation vectors in degrees.
    """
    rows: dict[str, dict[str, str]] = {}
    for k, l in cal.legs.items():
        se = l.offset_se if l.offset_se is not None else np.full(6, np.nan)
        col: dict[str, str] = {}
        for j, c in enumerate(COMPONENTS):
            col[f"F_offset {c} [N]"] = fmt_pm(l.offset[j], se[j])
        for j, c in enumerate(COMPONENTS):
            col[f"T_offset {c} [N*m]"] = fmt_pm(l.offset[3 + j], se[3 + j])
        col["m g [N]"] = fmt_pm(l.leg_weight_N, l.leg_weight_se_N)
        rv = np.degrees(rotation_to_rotvec(l.rotation_to_body @ nominal_rotations[k].T))
        rse = np.degrees(rotvec_se[k]) if rotvec_se is not None and k in rotvec_se else np.full(3, np.nan)
        for j, c in enumerate(COMPONENTS):
            col[f"R_tilde {c} [deg]"] = fmt_pm(rv[j], rse[j])
        pse = l.position_from_com_se_m if l.position_from_com_se_m is not None else np.full(3, np.nan)
        for j, c in enumerate(COMPONENTS):
            col[f"p' {c} [mm]"] = fmt_pm(1e3 * l.position_from_com_m[j], 1e3 * pse[j])
        rows[k] = col
    df = pd.DataFrame(rows)
    df.insert(0, "parameter", df.index)
    return df.reset_index(drop=True)


def truth_check(cal: Calibration, truth: Calibration, rotvec_se: dict[str, np.ndarray] | None = None) -> pd.DataFrame:
    """Per leg and parameter group: max |estimate - truth| and max |error| / se (simulated data)."""
    recs = []
    for k, l in cal.legs.items():
        t = truth.legs[k]

        def row(group, err, se):
            err, se = np.atleast_1d(err), np.atleast_1d(se) if se is not None else None
            z = np.nanmax(np.abs(err) / se) if se is not None and np.all(np.isfinite(se)) and np.all(se > 0) else np.nan
            recs.append({"leg": k, "parameter": group, "max abs error": float(np.nanmax(np.abs(err))), "max abs error / se": float(z)})

        row("offset force [N]", l.offset[:3] - t.offset[:3], None if l.offset_se is None else l.offset_se[:3])
        row("offset torque [N*m]", l.offset[3:] - t.offset[3:], None if l.offset_se is None else l.offset_se[3:])
        row("leg weight [N]", l.leg_weight_N - t.leg_weight_N, l.leg_weight_se_N)
        com_t = t.com(l.com_phi)
        row("leg CoM grid [m]", l.com_xyz - com_t, l.com_xyz_se)
        rv = rotation_to_rotvec(l.rotation_to_body @ t.rotation_to_body.T)
        row("rotation [deg]", np.degrees(rv), None if rotvec_se is None else np.degrees(rotvec_se[k]))
        row("p' [m]", l.position_from_com_m - t.position_from_com_m, l.position_from_com_se_m)
    return pd.DataFrame(recs)
