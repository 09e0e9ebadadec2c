"""Figures a reader of the report expects, rendered from a finished run.

Fig. 2: naive-tare total wrench; Figs. 4/7: leg CoM vs shaft angle with fitted
sinusoid and bands; Fig. 5: hanging residuals with and without the hanging
misalignment; Fig. 6: total-wrench residual naive / without transformation
error / calibrated; Figs. 8/9: walking ground forces naive vs calibrated.

The naive and no-transformation-error residuals are computed in ``naive.py``.
Legends are built from proxies of exactly what is drawn (violin bodies as
patches of their face colour and alpha). The backend is the entry point's
choice (``run.py`` sets Agg); without a display matplotlib picks Agg itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.artist import Artist
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from .tables import hexapod_truth

if TYPE_CHECKING:
    from ..calibration_run import CalibrationRun

_S = TypeVar("_S")


def _stage(result: _S | None, what: str) -> _S:
    """A stage's result the figure needs; a run without it is a ValueError (the report leaves the figure out)."""
    if result is None:
        raise ValueError(f"the run has no {what} result")
    return result

FORCE = ("Fx [N]", "Fy [N]", "Fz [N]")
TORQUE = ("Tx [N*m]", "Ty [N*m]", "Tz [N*m]")
LABELS = FORCE + TORQUE
VIOLIN_ALPHA = 0.6

_VIOLIN_MAX_POINTS = 4000


def _thin(d: np.ndarray) -> np.ndarray:
    d = np.asarray(d, float)
    d = d[np.isfinite(d)]
    if len(d) <= _VIOLIN_MAX_POINTS:
        return d
    return np.concatenate([d[:: len(d) // _VIOLIN_MAX_POINTS], [d.min(), d.max()]])


def _violins(ax, data: list[np.ndarray], positions, color: str, width: float = 0.8) -> Patch:
    """Violins of ``data`` at ``positions`` in one colour; returns the legend proxy of what is drawn."""
    # a 100-point kernel density barely changes past a few thousand samples: an even stride (plus
    # the extremes, which the violin's bars show) halves the report's time on 80 000-sample recordings
    data = [_thin(d) for d in data]
    parts = ax.violinplot(data, positions=positions, widths=width, showmedians=True, points=100)
    for b in parts["bodies"]:
        b.set_facecolor(color)
        b.set_edgecolor(color)
        b.set_alpha(VIOLIN_ALPHA)
    for key in ("cbars", "cmins", "cmaxes", "cmedians"):
        if key in parts:
            parts[key].set_color(color)
            parts[key].set_linewidth(1.0)
    return Patch(facecolor=color, edgecolor=color, alpha=VIOLIN_ALPHA)


def fig_naive_total(res: "CalibrationRun", path: Path) -> Path:
    r = res.naive_total_residuals()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    _violins(axes[0], [r[:, j] for j in range(3)], [1, 2, 3], "tab:blue")
    _violins(axes[1], [r[:, j] for j in range(3, 6)], [1, 2, 3], "tab:blue")
    axes[0].set_xticks([1, 2, 3], ["Fx", "Fy", "Fz"])
    axes[1].set_xticks([1, 2, 3], ["Tx", "Ty", "Tz"])
    axes[0].set_ylabel("total force - weight [N]")
    axes[1].set_ylabel("total torque about B's origin [N*m]")
    for ax in axes:
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"Naive taring: sum of the six wrenches less [0, 0, m g, 0, 0, 0] over {len(r)} standing poses, "
                 "W axes (cf. report Fig. 2)", fontsize=10)
    return _save(fig, path)


def fig_total_residuals(res: "CalibrationRun", path: Path) -> Path:
    """Top: the three models on one scale (Fig. 6); bottom: the calibrated residual alone, on its own scale."""
    naive = res.naive_total_residuals()
    no_tf = res.no_transformation_error_residuals()
    cal = np.asarray(_stage(res.standing, "standing").residuals)
    series = ((-0.27, naive, "tab:blue", "naive taring"),
              (0.0, no_tf, "tab:orange", "no transformation error (nominal poses, one CoM shift)"),
              (0.27, cal, "tab:green", f"calibrated (model {res.calibration.model})"))
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), gridspec_kw={"height_ratios": [3, 2]})
    handles = []
    for col, (js, labs, unit) in enumerate(((range(0, 3), ["Fx", "Fy", "Fz"], "N"), (range(3, 6), ["Tx", "Ty", "Tz"], "N*m"))):
        ax = axes[0, col]
        for off, data, color, lab in series:
            h = _violins(ax, [data[:, j] for j in js], [i + 1 + off for i in range(3)], color, width=0.26)
            if col == 0:
                handles.append((h, lab))
        ax.set_xticks([1, 2, 3], labs)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"residual [{unit}]")
        ax.grid(axis="y", alpha=0.3)
        ax = axes[1, col]
        _violins(ax, [cal[:, j] for j in js], [1, 2, 3], "tab:green", width=0.6)
        ax.set_xticks([1, 2, 3], labs)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"calibrated residual [{unit}]")
        ax.grid(axis="y", alpha=0.3)
    axes[1, 0].set_title("calibrated only (zoomed)", fontsize=9)
    axes[1, 1].set_title("calibrated only (zoomed)", fontsize=9)
    fig.legend([h for h, _ in handles], [l for _, l in handles], loc="upper center", ncol=3, fontsize=8,
               bbox_to_anchor=(0.5, 0.955), frameon=False)
    fig.suptitle(f"Total-wrench residual over {len(cal)} standing poses, W axes (cf. report Fig. 6)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return _save(fig, path, tight=False)


def _sinusoid_fit(phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares ``A sin(phi + C) + D`` (as a sin + b cos + D) evaluated on ``phi``."""
    ok = np.isfinite(y)
    X = np.column_stack([np.sin(phi), np.cos(phi), np.ones_like(phi)])
    if ok.sum() < 3:
        return np.full_like(phi, np.nan)
    coef, *_ = np.linalg.lstsq(X[ok], y[ok], rcond=None)
    return X @ coef


def fig_leg_com(res: "CalibrationRun", path: Path) -> Path:
    legs = res.dataset.robot.legs
    ncol = (len(legs) + 1) // 2
    fig, axes = plt.subplots(2, ncol, figsize=(4 * ncol, 6.4), sharex=True, sharey=True, squeeze=False)
    colors = ("tab:blue", "tab:orange", "tab:green")
    hanging, truth = _stage(res.hanging, "hanging"), hexapod_truth(res)
    for ax, k in zip(axes.flat, legs):
        lg = hanging.legs[k]
        phi = np.asarray(lg.com_phi)
        for j, (c, name) in enumerate(zip(colors, "xyz")):
            y = 1e3 * np.asarray(lg.com_xyz)[:, j]
            se = 1e3 * np.asarray(lg.com_xyz_se)[:, j] if lg.com_xyz_se is not None else np.zeros_like(y)
            ax.fill_between(phi, y - 2 * se, y + 2 * se, color=c, alpha=0.2, lw=0)
            ax.fill_between(phi, y - se, y + se, color=c, alpha=0.4, lw=0)
            ax.plot(phi, y, ".", color=c, ms=3)
            fit = _sinusoid_fit(phi, y) if name != "y" else np.full_like(y, np.nanmean(y))
            ax.plot(phi, fit, "--", color="red", lw=0.8)
            if truth is not None:
                ax.plot(phi, 1e3 * truth.legs[k].com(phi)[:, j], "-", color="k", lw=0.6, alpha=0.6)
        ax.set_title(k)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("shaft angle phi [rad]")
    for ax in axes[:, 0]:
        ax.set_ylabel("r_k(phi) in ft_k [mm]")
    for ax in list(axes.flat)[len(legs):]:
        ax.set_visible(False)
    handles: list[Artist] = [Line2D([], [], ls="", marker=".", ms=8, color=c, label=f"{n} estimate") for c, n in zip(colors, "xyz")]
    handles += [Patch(facecolor="0.5", alpha=0.4, label="± 1 se band"), Patch(facecolor="0.5", alpha=0.2, label="± 2 se band"),
                Line2D([], [], ls="--", color="red", lw=0.8, label="sinusoid fit (y: mean)")]
    if truth is not None:
        handles.append(Line2D([], [], ls="-", color="k", lw=0.6, alpha=0.6, label="truth"))
    fig.legend(handles=handles, loc="upper center", ncol=len(handles), fontsize=8, bbox_to_anchor=(0.5, 0.95), frameon=False)
    fig.suptitle("Leg CoM r_k(phi) in ft_k vs shaft angle, from the hanging recordings (cf. report Figs. 4, 7)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    return _save(fig, path, tight=False)


def fig_hanging_residuals(res: "CalibrationRun", path: Path) -> Path:
    from ..estimate.hanging import hanging_residuals

    robot, hanging = res.dataset.robot, _stage(res.hanging, "hanging")
    with_s = hanging_residuals(hanging, res.dataset.hanging, robot, with_misalignment=True)
    without = hanging_residuals(hanging, res.dataset.hanging, robot, with_misalignment=False)
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.4))
    pos = np.arange(len(robot.legs))
    for j, ax in enumerate(axes.flat):
        h0 = _violins(ax, [without[k][:, j] for k in robot.legs], pos - 0.2, "tab:blue", width=0.38)
        h1 = _violins(ax, [with_s[k][:, j] for k in robot.legs], pos + 0.2, "tab:orange", width=0.38)
        ax.set_xticks(pos, robot.legs)
        ax.set_ylabel(f"residual {LABELS[j]}")
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(axis="y", alpha=0.3)
    fig.legend([h0, h1], ["without the hanging misalignment", "with the hanging misalignment"], loc="upper center", ncol=2,
               fontsize=8, bbox_to_anchor=(0.5, 0.955), frameon=False)
    fig.suptitle("Hanging residuals per leg after offsets and leg gravity, ft_k axes (cf. report Fig. 5)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return _save(fig, path, tight=False)


def fig_walking(res: "CalibrationRun", rec, path: Path) -> Path:
    """Per tripod: ground forces, calibrated (with their +-1.96 se bands) and naive; the last row zooms on the
    normal force near zero, where the swing phases (shaded: contact state 0) and the bands can be seen."""
    legs = list(res.dataset.robot.legs)
    naive, _ = res.naive_ground_wrenches(rec)
    df = res.corrected[rec.name]
    t = df["t"].to_numpy()
    tripods: tuple[tuple[str, ...], ...] = (("FL", "MR", "HL"), ("FR", "ML", "HR"))
    tripods = tuple(tuple(k for k in tp if k in legs) for tp in tripods)
    if not all(tripods):
        tripods = (tuple(legs[::2]), tuple(legs[1::2]))
    colors = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
    has_se = f"{legs[0]}_fz_se" in df.columns
    fig, axes = plt.subplots(4, 2, figsize=(13, 10.5), sharex=True)
    for col, tp in enumerate(tripods):
        for j in range(3):
            ax = axes[j, col]
            for c, k in zip(colors, tp):
                i = legs.index(k)
                y = df[f"{k}_{('fx', 'fy', 'fz')[j]}"].to_numpy()
                ax.plot(t, y, lw=1, color=c)
                if has_se:
                    band = 1.96 * df[f"{k}_{('fx', 'fy', 'fz')[j]}_se"].to_numpy()
                    ax.fill_between(t, y - band, y + band, color=c, alpha=0.3, lw=0)
                ax.plot(t, naive[:, i, j], lw=0.8, ls=":", color=c)
            ax.set_ylabel(f"ground force {FORCE[j]}")
            ax.grid(alpha=0.3)
        ax = axes[3, col]
        for c, k in zip(colors, tp):
            y = df[f"{k}_fz"].to_numpy()
            ax.plot(t, y, lw=0.4, color=c)
            if has_se:
                band = 1.96 * df[f"{k}_fz_se"].to_numpy()
                ax.fill_between(t, y - band, y + band, color=c, alpha=0.35, lw=0)
            if f"{k}_contact" in df.columns:
                ax.fill_between(t, -0.5, 0.5, where=df[f"{k}_contact"].to_numpy() == 0, color=c, alpha=0.07, lw=0)
        ax.set_ylim(-0.5, 0.5)
        ax.set_ylabel("normal force near 0 [N]")
        ax.grid(alpha=0.3)
        handles: list[Artist] = [Line2D([], [], color=c, lw=2, label=k) for c, k in zip(colors, tp)]
        handles += [Line2D([], [], color="0.3", lw=1.5, label="calibrated"), Line2D([], [], color="0.3", lw=1.5, ls=":", label="naive taring")]
        if has_se:
            handles.append(Patch(color="0.3", alpha=0.3, label="± 1.96 se"))
        axes[0, col].legend(handles=handles, fontsize=7, ncol=len(handles), loc="lower left", bbox_to_anchor=(0, 1.0), frameon=False)
        axes[-1, col].set_xlabel("t [s]")
    fig.suptitle(f"Ground contact forces while walking ({rec.name}), heading frame: left column tripod {', '.join(tripods[0])}, "
                 f"right column tripod {', '.join(tripods[1])} (cf. report Figs. 8, 9); bottom: swing (shaded) and se bands", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    return _save(fig, path, tight=False)


def _save(fig, path: Path, tight: bool = True) -> Path:
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
