"""Figures a reader of the report expects, rendered from a finished run.

Fig. 2: naive-tare total wrench; Figs. 4/7: leg CoM vs phase with fitted
sinusoid and bands; Fig. 5: hanging residuals with and without misalignment;
Fig. 6: total-wrench residual naive / without transformation error /
calibrated; Figs. 8/9: walking ground wrenches naive vs calibrated.

Naive taring (Sec. I-B): the bias of each transducer is its mean reading with
all feet in the air, upright (the hanging recording whose gravity is closest to
-z of B), and readings less that bias are rotated with the nominal transducer
poses; the total is compared with the robot's weight and zero torque about B.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..geometry import remove_yaw, skew, transform_wrench  # noqa: E402
from ..physics import balance_residual_exact  # noqa: E402

if TYPE_CHECKING:
    from ..run import RunResult

LABELS = ("Fx [N]", "Fy [N]", "Fz [N]", "Tx [N*m]", "Ty [N*m]", "Tz [N*m]")


def naive_bias(res: "RunResult") -> np.ndarray:
    """(K, 6) mean reading of the upright feet-in-the-air recording."""
    hang = res.dataset.hanging
    if not hang:
        raise ValueError("naive taring needs a hanging recording with the feet in the air")
    up = max(hang, key=lambda r: float(r.gravity_body @ np.array([0.0, 0.0, -1.0])))
    return up.wrench_array(res.dataset.robot.legs).mean(axis=0)


def naive_total_residuals(res: "RunResult") -> np.ndarray:
    """(P, 6) naive-tare total wrench less ``[0, 0, m g, 0, 0, 0]`` at the extracted poses, W axes about B."""
    robot = res.dataset.robot
    p = res.poses
    R = np.einsum("pij,kjl->pkil", p.R_WB, robot.nominal_rotations())
    pos = np.einsum("pij,kj->pki", p.R_WB, robot.nominal_positions())
    total = transform_wrench(R, pos, p.w_m - naive_bias(res)).sum(axis=1)
    total[:, 2] -= robot.weight_N
    return total


def no_transformation_error_residuals(res: "RunResult") -> np.ndarray:
    """(P, 6) exact-balance residual with the hanging offsets and weights but nominal transducer
    poses and only a single CoM translation, fitted by linear least squares (the report's model 4)."""
    robot, p, cal = res.dataset.robot, res.poses, res.calibration
    offsets, weights, _, _ = cal.stacked(robot.legs)
    Mb_g = robot.weight_N - weights.sum()
    R0 = robot.nominal_rotations()
    p0 = robot.nominal_positions()
    r0 = balance_residual_exact(p.w_m, p.R_WB, offsets, R0, p0, Mb_g)
    # Moving the reference point by c (B axes) changes torques by -(R_WB c) x F_W, linear in c.
    F = r0[:, :3] + np.array([0.0, 0.0, Mb_g])
    # d tau = -(R c) x F = F x (R c) = [F] R c
    A = np.einsum("pij,pjk->pik", skew(F), p.R_WB)
    c, *_ = np.linalg.lstsq(A.reshape(-1, 3), -r0[:, 3:].reshape(-1), rcond=None)
    out = r0.copy()
    out[:, 3:] += (A @ c)
    return out


_VIOLIN_MAX_POINTS = 4000


def _thin(d: np.ndarray) -> np.ndarray:
    if len(d) <= _VIOLIN_MAX_POINTS:
        return d
    return np.concatenate([d[:: len(d) // _VIOLIN_MAX_POINTS], [d.min(), d.max()]])


def _violins(ax, data: list[np.ndarray], positions, color: str, label: str | None = None) -> None:
    # a 100-point kernel density barely changes past a few thousand samples: an even stride (plus
    # the extremes, which the violin's bars show) halves the report's time on 80 000-sample recordings
    data = [_thin(np.asarray(d)) for d in data]
    parts = ax.violinplot(data, positions=positions, widths=0.8, showmedians=True, points=100)
    for b in parts["bodies"]:
        b.set_facecolor(color)
        b.set_alpha(0.55)
    for key in ("cbars", "cmins", "cmaxes", "cmedians"):
        if key in parts:
            parts[key].set_color(color)
    if label:
        ax.plot([], [], color=color, lw=6, alpha=0.55, label=label)


def fig_naive_total(res: "RunResult", path: Path) -> Path:
    r = naive_total_residuals(res)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    _violins(axes[0], [r[:, j] for j in range(3)], [1, 2, 3], "tab:blue")
    _violins(axes[1], [r[:, j] for j in range(3, 6)], [1, 2, 3], "tab:blue")
    axes[0].set_xticks([1, 2, 3], LABELS[:3])
    axes[1].set_xticks([1, 2, 3], LABELS[3:])
    axes[0].set_ylabel("total wrench - [0,0,mg,0,0,0]")
    fig.suptitle(f"Naive taring: sum of wrenches over {len(r)} standing poses (cf. report Fig. 2)")
    return _save(fig, path)


def fig_total_residuals(res: "RunResult", path: Path) -> Path:
    naive = naive_total_residuals(res)
    no_tf = no_transformation_error_residuals(res)
    cal = np.asarray(res.standing.residuals)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, sl, labs in ((axes[0], slice(0, 3), LABELS[:3]), (axes[1], slice(3, 6), LABELS[3:])):
        js = range(sl.start, sl.stop)
        for off, data, color, lab in ((-0.27, naive, "lightblue", "naive taring"), (0.0, no_tf, "tab:orange", "no transformation error"), (0.27, cal, "tab:green", f"calibrated ({res.calibration.model})")):
            _violins(ax, [data[:, j] for j in js], [i + 1 + off for i in range(3)], color, lab if ax is axes[0] else None)
        ax.set_xticks([1, 2, 3], labs)
        ax.axhline(0, color="k", lw=0.5)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle("Total wrench residual at the CoM, floating-base frame (cf. report Fig. 6)")
    return _save(fig, path)


def _sinusoid_fit(phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares ``A sin(phi + C) + D`` (as a sin + b cos + D) evaluated on ``phi``."""
    ok = np.isfinite(y)
    X = np.column_stack([np.sin(phi), np.cos(phi), np.ones_like(phi)])
    if ok.sum() < 3:
        return np.full_like(phi, np.nan)
    coef, *_ = np.linalg.lstsq(X[ok], y[ok], rcond=None)
    return X @ coef


def fig_leg_com(res: "RunResult", path: Path) -> Path:
    legs = res.dataset.robot.legs
    fig, axes = plt.subplots(2, (len(legs) + 1) // 2, figsize=(12, 6), sharex=True, sharey=True, squeeze=False)
    colors = ("tab:blue", "tab:orange", "tab:green")
    for ax, k in zip(axes.flat, legs):
        lg = res.hanging.legs[k]
        phi = np.asarray(lg.com_phi)
        for j, (c, name) in enumerate(zip(colors, "xyz")):
            y = 1e3 * np.asarray(lg.com_xyz)[:, j]
            se = 1e3 * np.asarray(lg.com_xyz_se)[:, j] if lg.com_xyz_se is not None else np.zeros_like(y)
            ax.fill_between(phi, y - 2 * se, y + 2 * se, color=c, alpha=0.25, lw=0)
            ax.fill_between(phi, y - se, y + se, color=c, alpha=0.45, lw=0)
            ax.plot(phi, y, ".", color=c, ms=3, label=name)
            fit = _sinusoid_fit(phi, y) if name != "y" else np.full_like(y, np.nanmean(y))
            ax.plot(phi, fit, "--", color="red", lw=0.8)
            if res.truth is not None:
                ax.plot(phi, 1e3 * res.truth.legs[k].com(phi)[:, j], "-", color="k", lw=0.6, alpha=0.6)
        ax.set_title(k)
        ax.set_xlabel("phi [rad]")
    axes[0, 0].set_ylabel("leg CoM in ft [mm]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Leg CoM vs shaft angle: estimate, +-1 se / +-2 se bands, sinusoid fit (red)" + (", truth (black)" if res.truth is not None else "") + " (cf. Figs. 4, 7)")
    return _save(fig, path)


def fig_hanging_residuals(res: "RunResult", path: Path) -> Path:
    from ..hanging import hanging_residuals

    robot = res.dataset.robot
    with_s = hanging_residuals(res.hanging, res.dataset.hanging, robot, with_misalignment=True)
    without = hanging_residuals(res.hanging, res.dataset.hanging, robot, with_misalignment=False)
    fig, axes = plt.subplots(2, 3, figsize=(13, 6))
    for j, ax in enumerate(axes.flat):
        pos = np.arange(len(robot.legs))
        _violins(ax, [without[k][:, j] for k in robot.legs], pos - 0.2, "tab:blue", "without misalignment" if j == 0 else None)
        _violins(ax, [with_s[k][:, j] for k in robot.legs], pos + 0.2, "tab:orange", "with misalignment" if j == 0 else None)
        ax.set_xticks(pos, robot.legs)
        ax.set_title(LABELS[j])
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Hanging residuals after offsets and leg gravity, with / without the hanging misalignment (cf. Fig. 5)")
    return _save(fig, path)


def naive_ground_wrenches(res: "RunResult", rec) -> np.ndarray:
    """(N, K, 6) naive-tare per-foot wrench in the heading frame about B's origin."""
    from ..geometry import quat_to_rotation

    robot = res.dataset.robot
    ok = np.all(np.isfinite(rec.quat), axis=1)
    R_HB = remove_yaw(quat_to_rotation(rec.quat[ok]))
    R = np.einsum("nij,kjl->nkil", R_HB, robot.nominal_rotations())
    pos = np.einsum("nij,kj->nki", R_HB, robot.nominal_positions())
    return transform_wrench(R, pos, rec.wrench_array(robot.legs)[ok] - naive_bias(res))


def fig_walking(res: "RunResult", rec, path: Path) -> Path:
    legs = list(res.dataset.robot.legs)
    naive = naive_ground_wrenches(res, rec)
    df = res.corrected[rec.name]
    t = df["t"].to_numpy()
    tripods = (("FL", "MR", "HL"), ("FR", "ML", "HR"))
    tripods = tuple(tuple(k for k in tp if k in legs) for tp in tripods)
    if not all(tripods):
        tripods = (tuple(legs[::2]), tuple(legs[1::2]))
    fig, axes = plt.subplots(3, 2, figsize=(13, 8), sharex=True)
    for col, tp in enumerate(tripods):
        for row, (j, comp) in enumerate(((0, "fx"), (1, "fy"), (2, "fz"))):
            ax = axes[row, col]
            for k in tp:
                i = legs.index(k)
                (line,) = ax.plot(t, df[f"{k}_{comp}"], lw=1, label=f"{k} calibrated")
                ax.plot(t, naive[:, i, j], lw=0.8, ls=":", color=line.get_color(), label=f"{k} naive")
            ax.set_ylabel(LABELS[j])
        axes[0, col].set_title(("Left tripod: " if col == 0 else "Right tripod: ") + ", ".join(tp))
        axes[0, col].legend(fontsize=6, ncol=2)
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("t [s]")
    fig.suptitle(f"Ground contact forces while walking ({rec.name}): calibrated (solid) vs naive taring (dotted) (cf. Figs. 8, 9)")
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
