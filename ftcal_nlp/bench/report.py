"""Tables (CSV + Markdown), figures (PNG), ``summary.md`` and ``bench.json`` of a bench run.

Renders the dicts returned by :func:`.accuracy.run_accuracy`, :func:`.speed.run_speed`,
:func:`.scaling.run_scaling` and :func:`.profile.profile_stages`; solves nothing.
``summary.md`` is the section the README shows.
"""

from __future__ import annotations

import json
import subprocess
from datetime import UTC, datetime
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from .accuracy import GROUPS
from .correction import correction_markdown

TARGET_RATIO = 1.2
TARGET_CALIBRATION_S = 5.0
PIPELINE_LABELS = {"nlp": "NLP", "baseline": "baseline (report)", "baseline_exact_balance": "baseline solvers, exact balance",
                   "nlp_report_balance": "NLP, report balance (eq. 9)"}


def md_table(df: pd.DataFrame, floatfmt: str = ".3g") -> str:
    """A plain Markdown table (no index)."""
    def cell(v):
        if isinstance(v, (float, np.floating)):
            return "n/a" if not np.isfinite(v) else format(float(v), floatfmt)
        return str(v)

    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(cell(v) for v in r.values) + " |")
    return "\n".join(lines) + "\n"


def write_table(df: pd.DataFrame, folder: Path, stem: str, floatfmt: str = ".4g") -> None:
    df.to_csv(folder / f"{stem}.csv", index=False)
    (folder / f"{stem}.md").write_text(md_table(df, floatfmt))


def _git_version() -> str:
    """Short commit of the package's checkout (read-only git calls), ``+changes`` when files differ from it."""
    repo = Path(__file__).resolve().parents[2]
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10, cwd=repo,
                             check=False).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True, timeout=10,
                               cwd=repo, check=False).stdout.strip()
        return (rev or "unknown") + ("+changes" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


# ----------------------------------------------------------------------------- accuracy


def accuracy_table(acc: dict) -> pd.DataFrame:
    """Groups as rows; per pipeline the ratio (± se), and the NLP's error scale and reference ratios."""
    s = acc["summary"]
    pipes = [p for p in PIPELINE_LABELS if p in set(s.pipeline)]
    rows = []
    for g in GROUPS:
        d = s[s.group == g].set_index("pipeline")
        if d.empty:
            continue
        row = {"group": g, "unit": d.unit.iloc[0]}
        for p in pipes:
            row[PIPELINE_LABELS[p]] = f"{d.loc[p, 'ratio']:.3g} ± {d.loc[p, 'ratio_se']:.2g}" if p in d.index else "n/a"
        if "nlp" in d.index:
            n = d.loc["nlp"]
            row["NLP mean z (bias)"] = n.mean_z
            row["NLP Mahalanobis"] = n.ratio_mahalanobis
            row["K-norm LS bound"] = n.get("knorm_ls_ratio", np.nan)
            row["two-stage K-norm bound"] = n.get("two_stage_ratio", np.nan)
            row["const-weight GLS bound"] = n.get("gls_const_ratio", np.nan)
            row["NLP RMS error"] = n.rms_error
            row["RMS CRB"] = n.rms_crb
            row[f"NLP <= {TARGET_RATIO}"] = "(reference)" if g == "com_curves_vs_sinusoid" else ("yes" if n.ratio <= TARGET_RATIO else "no")
        rows.append(row)
    return pd.DataFrame(rows)


def fig_accuracy(acc: dict, path: Path) -> Path:
    s = acc["summary"]
    pipes = [p for p in PIPELINE_LABELS if p in set(s.pipeline)]
    groups = [g for g in GROUPS if g in set(s.group)]
    fig, ax = plt.subplots(figsize=(10, 4.5))
    width = 0.8 / max(len(pipes), 1)
    x = np.arange(len(groups))
    for i, p in enumerate(pipes):
        d = s[s.pipeline == p].set_index("group").reindex(groups)
        ax.bar(x + (i - (len(pipes) - 1) / 2) * width, d.ratio, width, yerr=d.ratio_se, label=PIPELINE_LABELS[p], capsize=2)
    n = s[s.pipeline == "nlp"].set_index("group").reindex(groups)
    for col, mk, lab in (("knorm_ls_ratio", "v", "K-norm LS bound (eq. 8 weighting)"), ("gls_const_ratio", "^", "constant GLS weighting bound")):
        if col in n:
            ax.scatter(x - (len(pipes) - 1) / 2 * width, n[col], marker=mk, color="k", zorder=3, label=lab)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(TARGET_RATIO, color="r", ls="--", lw=0.8, label=f"target {TARGET_RATIO}")
    ax.set_yscale("log")
    ax.set_xticks(x, [g.replace("_vs_", "\nvs ") for g in groups], fontsize=8)
    ax.set_ylabel("RMS error / Cramér-Rao bound")
    ax.set_title(f"Accuracy over {int(s.n_datasets.max())} simulated datasets")
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def fig_z(acc: dict, path: Path, pipeline: str = "nlp") -> Path:
    rows = acc["rows"]
    d = rows[rows.pipeline == pipeline]
    groups = [g for g in GROUPS if g in set(d.group)]
    fig, axes = plt.subplots(1, len(groups), figsize=(2.6 * len(groups), 2.8), squeeze=False)
    xs = np.linspace(-5, 5, 200)
    for ax, g in zip(axes[0], groups):
        z = d[d.group == g].z.to_numpy()
        ax.hist(np.clip(z, -5, 5), bins=40, range=(-5, 5), density=True, alpha=0.6)
        ax.plot(xs, np.exp(-xs**2 / 2) / np.sqrt(2 * np.pi), "k", lw=0.8)
        ax.set_title(f"{g}\nmean {z.mean():+.2f}, rms {np.sqrt(np.mean(z**2)):.2f}", fontsize=8)
        ax.set_yticks([])
    fig.suptitle(f"{PIPELINE_LABELS.get(pipeline, pipeline)}: error / CRB sd (black: N(0, 1))", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- speed


def speed_table(sp: dict) -> pd.DataFrame:
    t = sp["times"]
    order = ["load", "poses", "hanging", "model selection", "standing", "calibrate() without diagnosis", "diagnosis",
             "calibrate() with diagnosis", "report", "whole run (python -m ftcal_nlp.run) without diagnosis",
             "whole run (python -m ftcal_nlp.run) with diagnosis"]
    rows = []
    for st in order:
        d = t[t.stage == st].set_index("method")
        if d.empty:
            continue
        if "shared" in d.index:
            r = d.loc["shared"]
            rows.append({"stage": st, "NLP wall [s]": r.wall_s, "baseline wall [s]": r.wall_s, "baseline / NLP": np.nan,
                         "NLP CPU [s]": r.cpu_s, "baseline CPU [s]": r.cpu_s, "note": f"shared {r.note}".strip()})
            continue
        if "baseline" not in d.index:  # NLP only (the run with the diagnosis)
            n = d.loc["nlp"]
            rows.append({"stage": st, "NLP wall [s]": n.wall_s, "baseline wall [s]": np.nan, "baseline / NLP": np.nan,
                         "NLP CPU [s]": n.cpu_s, "baseline CPU [s]": np.nan, "note": n.note})
            continue
        n, b = d.loc["nlp"], d.loc["baseline"]
        rows.append({"stage": st, "NLP wall [s]": n.wall_s, "baseline wall [s]": b.wall_s, "baseline / NLP": b.wall_s / n.wall_s,
                     "NLP CPU [s]": n.cpu_s, "baseline CPU [s]": b.cpu_s, "note": n.note})
    tot = sp["totals"]
    rows.append({"stage": "calibration (hanging + selection + standing)", "NLP wall [s]": tot["nlp"]["calibration_wall_s"],
                 "baseline wall [s]": tot["baseline"]["calibration_wall_s"],
                 "baseline / NLP": tot["baseline"]["calibration_wall_s"] / tot["nlp"]["calibration_wall_s"],
                 "NLP CPU [s]": tot["nlp"]["calibration_cpu_s"], "baseline CPU [s]": tot["baseline"]["calibration_cpu_s"], "note": ""})
    return pd.DataFrame(rows)


def fig_speed(sp: dict, path: Path) -> Path:
    tab = speed_table(sp)
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(tab) + 1.2))
    y = np.arange(len(tab))
    shared = tab.note.astype(str).str.startswith("shared").to_numpy()
    ax.barh(y[~shared] - 0.2, tab["NLP wall [s]"][~shared], 0.4, label="NLP")
    ax.barh(y[~shared] + 0.2, tab["baseline wall [s]"][~shared], 0.4, label="baseline (report)")
    ax.barh(y[shared], tab["NLP wall [s]"][shared], 0.5, color="0.6", label="shared stage")
    ax.axvline(TARGET_CALIBRATION_S, color="r", ls="--", lw=0.8, label=f"{TARGET_CALIBRATION_S:g} s target (calibration)")
    ax.set_yticks(y, tab.stage)
    ax.invert_yaxis()
    ax.set_xlabel("wall time [s] (median)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- scaling


def fig_scaling(sc: dict, path: Path) -> Path:
    pts = sc["points"].dropna(subset=["wall_s"])
    ex = sc["exponents"].set_index("task") if len(sc["exponents"]) else pd.DataFrame()
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    for col, (kind, label) in enumerate((("poses", "standing poses"), ("hanging samples", "hanging samples (4 recordings)"))):
        for row, (y, ylab, ekey) in enumerate((("wall_s", "wall time [s]", "time_exponent"), ("peak_rss_mb", "peak RSS growth [MB]", "memory_exponent"))):
            ax = axes[row, col]
            for task, d in pts.groupby("task", sort=False):
                if task not in ex.index or ex.loc[task, "size"] != kind:
                    continue
                d = d.sort_values("n")
                ax.loglog(d.n, d[y], "o-", label=f"{task} (slope {ex.loc[task, ekey]:.2f}, upper half {ex.loc[task, ekey + '_upper']:.2f})")
            n0 = pts[pts.task.isin([t for t in ex.index if ex.loc[t, "size"] == kind])]
            if len(n0):
                lo, hi = n0.n.min(), n0.n.max()
                ref = n0[y].median()
                ax.loglog([lo, hi], [ref, ref * hi / lo], "k:", lw=0.8, label="slope 1")
            ax.set_xlabel(label)
            ax.set_ylabel(ylab)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- profile


def profile_frames(prof: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
    hs = pd.concat([v["hot_spots"].assign(stage=k) for k, v in prof.items()], ignore_index=True) if prof else pd.DataFrame()
    tops = []
    for k, v in prof.items():
        tops.append(v["top_self"].assign(stage=k, total_s=v["total_s"]))
    top = pd.concat(tops, ignore_index=True) if tops else pd.DataFrame()
    return hs, top


# ----------------------------------------------------------------------------- summary


def export_speed_markdown(corr: dict) -> list[str]:
    """The correction speed section: compiled C per sample and the batched Python throughput."""
    t = corr["table"].copy()
    t["met"] = t["met"].map({True: "yes", False: "no"})
    return [f"### Correction speed ({corr['legs']} legs, {int(t.samples.iloc[0])} samples of the simulated walk, best of "
            f"{corr['settings'].repeats})", "", md_table(t[["path", "us_per_sample", "samples_per_s", "goal", "met"]]), "",
            f"Compiled C and numpy agree to {corr['max_abs_diff_N']:.1e} N / N*m (largest difference).", ""]


def plan_check_markdown(res: dict) -> list[str]:
    """The plan check section: predicted se against the reported se and the spread over seeds."""
    t = res["table"]
    cols = ["protocol", "group", "unit", "predicted_se", "reported_ratio", "spread_ratio", "spread_ratio_sd"]
    (rn, rd), (sn, sd) = res["within"]["reported"], res["within"]["spread"]
    tol = res["tolerance"]
    ref = res["settings"].reference
    return [f"### Plan check: predicted se vs the calibration's ({len(res['settings'].seeds)} seeds; reference protocol "
            f"{ref.hanging_turns:g} turns x 4 hanging, {ref.n_poses} poses)", "", md_table(t[cols]), "",
            f"Reported se within {100 * tol:.0f} % of the prediction: {rn}/{rd}; spread over seeds within "
            f"{100 * tol:.0f} %: {sn}/{sd} (the unsmoothed CoM bound is a reference, not checked).", ""]


def detect_check_markdown(res: dict) -> list[str]:
    """The detection check section: the diagnosis' gap rate at the plan's detection size (predicted 0.8)."""
    t = res["table"].copy()
    p = res["settings"].protocol
    t["gap_rate"] = [f"{r.gap_rate:.2f} ± {r.gap_rate_se:.2f}" for r in t.itertuples()]
    cols = ["effect", "kind", "size", "unit", "runs", "gap_rate", "predicted_rate", "mean_excess", "threshold",
            "verdict_not_none_rate", "named_rate"]
    return [f"### Detection size check: the diagnosis at the plan's predicted size ({p.hanging_turns:g} turns x 4 hanging, "
            f"{p.n_poses} poses; prediction {res['predict_s']:.0f} s)", "", md_table(t[cols]), "",
            "`gap_rate`: share of the datasets whose held-out excess on the predicted kind exceeds the diagnosis' threshold "
            "(± binomial se); `none` rows: clean datasets (false alarms, any kind).", ""]


LOAD_LABELS = {"nlp": "NLP", "ft_calib": "ft_calib (kth)", "calib_force": "calibForce (Robotlib)"}


def loads_table(acc: dict) -> pd.DataFrame:
    """Free-load accuracy: (scenario, group) rows, per estimator the ratio to the bound (± se) and, for the
    payload groups the peers also fit, the ratio to the known-mount bound; the NLP's check against the target."""
    s = acc["summary"]
    if s.empty:
        return pd.DataFrame()
    ests = [e for e in LOAD_LABELS if e in set(s.estimator)]
    rows = []
    for (sc, g), d in s.groupby(["scenario", "group"], sort=False):
        d = d.set_index("estimator")
        row = {"scenario": sc, "group": g, "unit": d.unit.iloc[0]}
        for e in ests:
            row[LOAD_LABELS[e]] = f"{d.loc[e, 'ratio']:.3g} ± {d.loc[e, 'ratio_se']:.2g}" if e in d.index else "n/a"
        for e in ests:
            rk = d.loc[e, "ratio_known_mount"] if e in d.index else np.nan
            row[f"{LOAD_LABELS[e]} / known-mount CRB"] = rk
        ref = d.loc["nlp"] if "nlp" in d.index else d.iloc[0]
        row["RMS CRB"] = ref.rms_crb
        for e in ests:
            row[f"{LOAD_LABELS[e]} RMS error"] = d.loc[e, "rms_error"] if e in d.index else np.nan
        row[f"NLP <= {TARGET_RATIO}"] = _verdict(d.loc["nlp"]) if "nlp" in d.index else "n/a"
        rows.append(row)
    return pd.DataFrame(rows)


def _verdict(r) -> str:
    """``yes`` under the target; ``within 2 se`` when above it by less than twice the ratio's se over datasets (a
    group of one parameter over few datasets: the ratio itself is that noisy); else ``no``."""
    if r.ratio <= TARGET_RATIO:
        return "yes"
    return f"within 2 se ({r.ratio - TARGET_RATIO:.2g} above)" if np.isfinite(r.ratio_se) and r.ratio - 2 * r.ratio_se <= TARGET_RATIO else "no"


def loads_markdown(acc: dict) -> list[str]:
    st, info = acc["settings"], acc["info"]
    out = [f"### Free loads (issue 22): RMS error / Cramér-Rao bound ({len(st.seeds)} datasets per scenario, "
           f"target NLP <= {TARGET_RATIO})", "",
           "Scenarios (`sim.free`): `payload_no_mount` a wrist tool without mounting rotation (the peers' model holds), "
           "`payload_mount` with the drawn ~1 deg mounting rotation, `urdf_leg` the bundled 4-joint leg. Bound "
           "(`crb/free_load.py`): the readings' Fisher information at the truth over the held samples, mounting rotation "
           "unknown; `/ known-mount CRB`: against the bound with the mounting known (ft_calib's assumption). URDF "
           "groups are compared on what the data determine (`Bound.project`; statics see the total mass and the "
           "base first moments). The peers get the simulator's held samples and the nominal ft orientation; the NLP "
           "reads the written dataset and selects its quasi-static samples itself (a few % more than the holds: the "
           "slow ends of the moves, which the simulator writes quasi-static), so it can sit slightly below 1. A group of "
           "one parameter (mass, total mass) over few datasets has a ratio with a relative se near 1/sqrt(2 x datasets); "
           "compare the estimators' RMS errors on the same data.", ""]
    t = loads_table(acc)
    if len(t):
        out += [md_table(t), ""]
    for c in [c for c in info.columns if c.endswith("_failure")]:
        n = int(info[c].notna().sum())
        if n:
            out += [f"{c.replace('_failure', '')} failed on {n} dataset(s): {info[c].dropna().iloc[0]}", ""]
    return out


def load_speed_markdown(ls: dict) -> list[str]:
    t = ls["times"]
    out = [f"### Free-load speed (issue 22, item 9): the estimate alone, median of {ls['settings'].repeats}", ""]
    if len(t):
        t = t.copy()
        t["met"] = [("yes" if w < ts else "NO") if np.isfinite(ts) else "" for w, ts in zip(t.wall_s, t.target_s)]
        out += [md_table(t), ""]
    for k, v in ls["failures"].items():
        out += [f"{k} failed: {v}", ""]
    return out


def diagnosis_ratio_markdown(dr: dict) -> list[str]:
    t = dr["times"]
    out = [f"### The diagnosis' cost (issue 23, item 6): its stage against `calibrate()` without it, median of "
           f"{dr['settings'].repeats}", ""]
    if len(t):
        t = t.copy()
        t["met"] = ["yes" if r <= tg else "NO" for r, tg in zip(t.ratio, t.target)]
        out += [md_table(t), ""]
    return out


def summary_markdown(acc: dict | None, sp: dict | None, sc: dict | None, prof: dict | None, mode: str,
                     corr: dict | None = None, plan: dict | None = None, export: dict | None = None,
                     detect: dict | None = None, loads: dict | None = None, load_speed: dict | None = None,
                     diagnosis_ratio: dict | None = None) -> str:
    now = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    load = f" Machine load average at the speed bench: {sp['load_average']:.1f} on 2 cores." if sp else ""
    out = [f"## Benchmarks (`python -m ftcal_nlp.bench{' --quick' if mode == 'quick' else ''}`)", "",
           f"{now}, version {_git_version()}, {mode} run; one process, BLAS limited to 1 thread.{load}", ""]
    if acc is not None:
        st = acc["settings"]
        info = acc["info"]
        head = f"### Accuracy: RMS error / Cramér-Rao bound ({len(st.seeds)} simulated datasets, target NLP <= {TARGET_RATIO})"
        setup = (f"Datasets: `SimConfig(seed, hanging_cycles={st.hanging_cycles:g}, n_poses={st.n_poses}, walk_cycles=0)` "
                 f"({int(info.hanging_samples.median())} hanging samples, {int(info.n_poses.median())} extracted poses), "
                 f"model `{st.model}`. Ratio = sqrt(mean (error / CRB sd)^2) over the group and the datasets (± its se over "
                 "datasets); 1 is an efficient unbiased estimator.")
        notes = ("How to read it: hanging groups are bounded by the hanging model's Fisher information at the truth "
                 "(configured noise, the recordings' shaft angles, tilts as nuisance). The CoM-curve bound is for unbiased "
                 "grid values: a smoothed curve can go below 1; `com_curves_vs_sinusoid` uses the bound of the simulator's "
                 "own curve family (sinusoid in x, z; constant y) as a reference. Standing groups (rotations, translations "
                 "relative to the body-without-legs CoM) use the errors-in-variables bound of the exact balance with the "
                 "**hanging parameters known** (readings: pose medians, var = pi/2 sigma^2/n; orientation: median jitter plus "
                 "any per-pose mocap error); errors are projected on the identifiable directions (scaled-Fisher eigenvalues "
                 f">= 1e-5 of the largest; dropped per dataset: max {int(info.standing_dropped_dirs.max())}). `com` is the "
                 "total CoM relative to the body-without-legs CoM with every leg at phi = 0 (the body CoM is not identifiable "
                 "with six free translations). `mean z`: the average error in bound units (a bias shows as |mean z| well "
                 "above 1/sqrt(number of values)). `K-norm LS bound`: the best the least squares of eq. 8 "
                 "(K = diag(1,1,1,10,10,10)) can reach; `two-stage K-norm bound`: the same with the hanging bound propagated "
                 "into the standing fit; `const-weight GLS bound`: least squares weighted by W = (mean residual covariance)^-1 "
                 "instead of K. Pose data check (truth residual / modelled noise, 1 = only modelled noise): median "
                 f"{info.pose_residual_check.median():.2f}.")
        out += [head, "", setup, "", md_table(accuracy_table(acc)), "", notes, ""]
        fails = [c for c in info.columns if c.endswith("_failure")]
        for c in fails:
            n = int(info[c].notna().sum())
            if n:
                out += [f"{c.replace('_failure', '')} failed on {n} dataset(s): {info[c].dropna().iloc[0]}", ""]
    if loads is not None:
        out += loads_markdown(loads)
    if load_speed is not None:
        out += load_speed_markdown(load_speed)
    if diagnosis_ratio is not None:
        out += diagnosis_ratio_markdown(diagnosis_ratio)
    if sp is not None:
        tot = sp["totals"]["nlp"]["calibration_wall_s"]
        totb = sp["totals"]["baseline"]["calibration_wall_s"]
        cpu = sp["totals"]["nlp"]["calibration_cpu_s"]
        status = "MET" if tot < TARGET_CALIBRATION_S else "NOT MET"
        sz = sp["sizes"]
        ov = sp["settings"].sim_overrides
        problem = "default problem, SimConfig()" if not ov else "SimConfig(" + ", ".join(f"{k}={v}" for k, v in ov.items()) + ")"
        head = (f"### Speed: {problem}: {sz['poses']} poses, {sz['hanging_samples']} hanging samples; "
                f"wall time, median of {sp['settings'].repeats}")
        verdict = (f"Calibration (hanging + model selection with {sp['settings'].folds}-fold CV + standing): NLP **{tot:.2f} s** "
                   f"wall ({cpu:.2f} s CPU), target < {TARGET_CALIBRATION_S:g} s: **{status}**; baseline {totb:.2f} s "
                   f"(NLP {'no slower' if tot <= totb else 'slower'} than the baseline: ratio baseline/NLP {totb / tot:.2f}).")
        out += [head, "", md_table(speed_table(sp)), "", verdict, ""]
        tn = sp["totals"]["nlp"]
        if "whole_run_with_diagnosis_wall_s" in tn:
            a, b = tn["whole_run_with_diagnosis_wall_s"], tn["whole_run_without_diagnosis_wall_s"]
            out += [f"Whole run (`python -m ftcal_nlp.run`: load, calibrate, files, report) with the diagnosis **{a:.1f} s**, "
                    f"without **{b:.1f} s**: ratio {a / b:.2f} (target <= 3: **{'MET' if a <= 3 * b else 'NOT MET'}**).", ""]
    if export is not None:
        out += export_speed_markdown(export)
    if plan is not None:
        out += plan_check_markdown(plan)
    if detect is not None:
        out += detect_check_markdown(detect)
    if sc is not None and len(sc["exponents"]):
        ex = sc["exponents"].copy()
        ex = ex[["task", "size", "n_min", "n_max", "time_exponent", "time_exponent_upper", "memory_exponent", "time_at_max_s", "peak_rss_at_max_mb"]]
        out += ["### Scaling (log-log slope of wall time and of peak RSS growth; `upper`: upper half of the range)", "",
                md_table(ex), "", "Target: linear or better (slope <= 1).", ""]
        errs = sc["points"][sc["points"]["error"].notna()] if "error" in sc["points"] else None
        if errs is not None and len(errs):
            out += [f"{len(errs)} scaling point(s) failed: " + "; ".join(f"{r.task} n={r.n}: {r.error}" for r in errs.itertuples()), ""]
    if corr is not None:
        out += correction_markdown(corr, md_table)
    if prof:
        out += ["### Where the time goes (cProfile; fraction of each profiled stage, cumulative)", ""]
        for stage, v in prof.items():
            h = v["hot_spots"].sort_values("fraction", ascending=False)
            if len(h):
                out.append(f"- **{stage}** ({v['total_s']:.2f} s profiled): " + "; ".join(f"{r['hot spot']} {100 * r.fraction:.0f} %" for _, r in h.iterrows()))
            else:  # no named hot spots for this stage: its own largest functions
                top = v["top_cumulative_package"]
                top = top[top.cumtime_frac < 0.97].head(5)
                out.append(f"- **{stage}** ({v['total_s']:.2f} s profiled; largest ftcal_nlp functions, cumulative): "
                           + "; ".join(f"`{r.where}` {100 * r.cumtime_frac:.0f} %" for r in top.itertuples()))
        out.append("")
        rec = recommendations(prof, sp)
        if rec:
            out += ["Hot spots and what would remove them (estimators unchanged by the bench; numbers from this profile):", ""]
            out += [f"- {r}" for r in rec]
            out.append("")
    return "\n".join(out)


def _frac(prof: dict, stage: str, label_start: str) -> tuple[float, float]:
    """(fraction, profiled seconds) of the first hot spot of ``stage`` whose label starts with ``label_start``."""
    v = prof.get(stage)
    if v is None:
        return float("nan"), float("nan")
    h = v["hot_spots"]
    m = h[h["hot spot"].str.startswith(label_start)]
    if not len(m):
        return float("nan"), float("nan")
    f = float(m.fraction.iloc[0])
    return f, f * v["total_s"]


def recommendations(prof: dict, sp: dict | None) -> list[str]:
    """Concrete changes, each with the share of its stage it would act on (only those found in the profile)."""
    out = []
    f, t = _frac(prof, "hanging (nlp)", "symbolic NLP build")
    if np.isfinite(f):
        out.append(f"hanging: the CasADi NLP is rebuilt (SX graph, exact Hessian, `nlpsol`) on every `fit_hanging` call: "
                   f"{100 * f:.0f} % of the stage ({t:.2f} s). Cache `HangingNLP` per structure key at module level (the data are "
                   "already parameters) or generate and compile its C code once; repeated fits (CV, benches, re-runs) then skip it.")
    f1, t1 = _frac(prof, "hanging (nlp)", "cvxpy QP solves")
    f2, t2 = _frac(prof, "hanging (nlp)", "cvxpy QP set-up")
    if np.isfinite(f1):
        f2, t2 = (0.0, 0.0) if not np.isfinite(f2) else (f2, t2)
        out.append(f"hanging: the CoM QP has no constraints, so cvxpy/Clarabel (canonicalisation on every solve) returns what "
                   f"`com_qp.solve_closed_form` (one {3 * 72 + 3}x{3 * 72 + 3} solve) gives: {100 * (f1 + f2):.0f} % of the stage ({t1 + t2:.2f} s).")
    f, t = _frac(prof, "hanging (nlp)", "Fisher standard errors")
    if np.isfinite(f):
        out.append(f"hanging: Fisher standard errors {100 * f:.0f} % ({t:.2f} s), mostly evaluating the CasADi Jacobian and "
                   "densifying it (`np.asarray` of a sparse DM); `Jr.sparse()` and a sparse J^T J would keep it cheap.")
    f, t = _frac(prof, "hanging (nlp)", "GCV smoothing")
    if np.isfinite(f):
        out.append(f"hanging: GCV (generalised eigenproblem per leg and round) {100 * f:.0f} % ({t:.2f} s).")
    fb, tb = _frac(prof, "model selection (nlp)", "symbolic build")
    fs, ts = _frac(prof, "model selection (nlp)", "nlpsol construction")
    fi, ti = _frac(prof, "model selection (nlp)", "IPOPT solves")
    if np.isfinite(fb) and np.isfinite(fi):
        fs, ts = (fs, ts) if np.isfinite(fs) else (0.0, 0.0)  # nlpsol is built lazily inside the first solve
        out.append(f"model selection: building the four models and their IPOPT solvers {100 * (fb + fs):.0f} % "
                   f"({tb + ts:.2f} s), the IPOPT iterations {100 * (fi - fs):.0f} % ({ti - ts:.2f} s) over 4 x 6 solves; the compiled "
                   "problems could be cached per (model, balance, legs): the data enter only as the moment-matrix parameter.")
    if sp is not None:
        t = sp["times"]
        st = t[(t.stage == "standing") & (t.method == "nlp")]
        if len(st):
            out.append(f"run.py refits the selected model after the selection (`standing` stage, {st.wall_s.iloc[0]:.2f} s): "
                       "`SelectionResult.best_result` already holds that fit on all poses.")
    f1, t1 = _frac(prof, "diagnosis", "CV fold complements")
    f2, t2 = _frac(prof, "diagnosis", "nlpsol constructions")
    f3, t3 = _frac(prof, "diagnosis", "IPOPT solves")
    if np.isfinite(f1) or np.isfinite(f2):
        parts = []
        if np.isfinite(f1):
            parts.append(f"`np.setdiff1d` building cross-validation fold complements {100 * f1:.0f} % ({t1:.2f} s; a boolean mask per fold "
                         "costs nothing)")
        if np.isfinite(f2):
            parts.append(f"one `nlpsol` construction per candidate effect {100 * f2:.0f} % ({t2:.2f} s; cacheable like the standing models)")
        if np.isfinite(f3):
            parts.append(f"IPOPT calls {100 * f3:.0f} % ({t3:.2f} s)")
        out.append("diagnosis: " + "; ".join(parts) + ".")
    f, t = _frac(prof, "report", "violin plots")
    if np.isfinite(f):
        out.append(f"report: matplotlib violins (a Gaussian KDE over every hanging sample) "
                   f"{100 * f:.0f} % ({t:.2f} s); a seeded subsample of ~2000 points per violin draws the same shape.")
    f, t = _frac(prof, "load", "CSV parsing")
    f2, t2 = _frac(prof, "load", "Parquet reading")
    if np.isfinite(f):
        out.append(f"load: CSV parsing {100 * f:.0f} % of the stage ({t:.2f} s)"
                   + (f", Parquet {100 * f2:.0f} % ({t2:.2f} s) for the larger standing file" if np.isfinite(f2) else "") + ".")
    return out


def write_all(folder: Path, acc: dict | None, sp: dict | None, sc: dict | None, prof: dict | None, mode: str,
              corr: dict | None = None, export: dict | None = None, plan: dict | None = None, detect: dict | None = None,
              loads: dict | None = None, load_speed: dict | None = None, diagnosis_ratio: dict | None = None) -> str:
    """Write every table, figure, ``summary.md`` and ``bench.json`` into ``folder``; returns the summary text."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    js: dict = {"mode": mode, "version": _git_version()}
    if acc is not None:
        acc["rows"].to_csv(folder / "accuracy_params.csv.gz", index=False)
        acc["info"].to_csv(folder / "accuracy_datasets.csv", index=False)
        write_table(acc["summary"], folder, "accuracy_groups")
        write_table(accuracy_table(acc), folder, "accuracy")
        fig_accuracy(acc, folder / "accuracy.png")
        fig_z(acc, folder / "accuracy_z_nlp.png")
        js["accuracy"] = acc["summary"].to_dict(orient="records")
    if sp is not None:
        write_table(sp["times"], folder, "speed_stages")
        write_table(speed_table(sp), folder, "speed")
        fig_speed(sp, folder / "speed.png")
        js["speed"] = {"totals": sp["totals"], "sizes": sp["sizes"], "stages": sp["times"].to_dict(orient="records"),
                       "load_average": sp["load_average"]}
    if sc is not None:
        write_table(sc["points"], folder, "scaling_points")
        write_table(sc["exponents"], folder, "scaling_exponents")
        if len(sc["exponents"]):
            fig_scaling(sc, folder / "scaling.png")
        js["scaling"] = sc["exponents"].to_dict(orient="records")
    if prof:
        hs, top = profile_frames(prof)
        write_table(hs, folder, "profile_hot_spots")
        write_table(top, folder, "profile_top_self")
        for k, v in prof.items():
            stem = k.replace(" ", "_").replace("(", "").replace(")", "").replace(".", "")
            (folder / f"profile_{stem}.txt").write_text(v["text"])
        js["profile"] = hs.to_dict(orient="records")
    if corr is not None:
        write_table(corr["table"], folder, "correction")
        js["correction"] = {"table": corr["table"].to_dict(orient="records"), "accuracy": corr["accuracy"]}
    if export is not None:
        write_table(export["table"], folder, "correction_speed")
        js["export"] = export["table"].to_dict(orient="records")
    if plan is not None:
        write_table(plan["table"], folder, "plan_check")
        js["plan_check"] = {"table": plan["table"].to_dict(orient="records"), "within": plan["within"]}
    if detect is not None:
        write_table(detect["table"], folder, "detect_check")
        detect["runs"].to_csv(folder / "detect_check_runs.csv", index=False)
        js["detect_check"] = detect["table"].to_dict(orient="records")
    if loads is not None:
        loads["rows"].to_csv(folder / "accuracy_loads_params.csv.gz", index=False)
        loads["info"].to_csv(folder / "accuracy_loads_datasets.csv", index=False)
        if len(loads["summary"]):
            write_table(loads["summary"], folder, "accuracy_loads_groups")
            write_table(loads_table(loads), folder, "accuracy_loads")
        js["accuracy_loads"] = loads["summary"].to_dict(orient="records")
    if load_speed is not None:
        write_table(load_speed["times"], folder, "speed_loads")
        js["speed_loads"] = {"times": load_speed["times"].to_dict(orient="records"), "failures": load_speed["failures"]}
    if diagnosis_ratio is not None:
        write_table(diagnosis_ratio["times"], folder, "speed_diagnosis_ratio")
        js["speed_diagnosis_ratio"] = diagnosis_ratio["times"].to_dict(orient="records")
    text = summary_markdown(acc, sp, sc, prof, mode, corr=corr, plan=plan, export=export, detect=detect, loads=loads,
                            load_speed=load_speed, diagnosis_ratio=diagnosis_ratio)
    (folder / "summary.md").write_text(text)
    (folder / "bench.json").write_text(json.dumps(js, indent=1, default=_json_default))
    return text


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
