"""Withheld-effect validation (issue 7): simulate datasets with one hidden effect each (or none),
calibrate, diagnose without being told, and score the verdicts.

``python -m ftcal_nlp.diagnose.validate problems/diagnose_validation.toml`` (and
``python -m ftcal_nlp.run`` on a config with a ``[validation]`` table, once the
run dispatches to :func:`main`). Config::

    [validation]
    n_datasets = 24            # datasets simulated
    seed = 0                   # dataset i uses simulator seed seed * 1000 + i
    effects = [...]            # effects to withhold (default: the whole library)
    clean_share = 0.15         # share of datasets without any effect (false-alarm check)
    magnitude = "realistic"    # "realistic": uniform in each effect's realistic range; "test": its test size
    model = "full"             # calibration error model (no model selection, for speed)
    folds = 5
    workers = 1                # parallel processes (the machine's cores are shared: keep 1-2)

    [validation.simulate]      # SimConfig overrides: reduced sizes keep a run near 10 minutes
    n_poses = 200
    hanging_cycles = 3.0
    walk_cycles = 1.0

    [output]
    dir = "../reports/diagnose_validation"

``moving_com`` datasets are exact physics calibrated with the report's fixed-CoM
balance (eq. 9); every other dataset uses the exact balance. Datasets cycle
through ``[none] + effects`` (clean ones as ``clean_share`` asks), so every
effect is withheld about equally often. Outputs: ``confusion.csv`` and
``confusion.md`` (rows: withheld, columns: verdict), ``datasets.csv`` (one row
per dataset) and ``summary.json`` (accuracy, false-alarm rate on clean data,
shrinkage error, runtime).

Shrinkage error of a correctly named effect: how far the held-out RMS with the
effect added stays above the noise floor, ``mean_c (after_c / floor_c) - 1``
(0: the gap is closed to the noise).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from ..pipeline import calibrate
from ..settings import CalibrationSettings, DiagnoseSettings, HangingSettings, StandingSettings
from ..sim import SimConfig, simulate
from .effects import LIBRARY

log = logging.getLogger("ftcal_nlp.diagnose.validate")

DEFAULTS = {"n_datasets": 24, "seed": 0, "effects": None, "clean_share": 0.15, "magnitude": "realistic", "model": "full",
            "folds": 5, "workers": 1}
SIM_DEFAULTS = {"n_poses": 200, "hanging_cycles": 3.0, "walk_cycles": 1.0}


def plan(cfg: dict) -> list[dict]:
    """The datasets of a validation: ``index``, ``seed``, ``effect`` (or "none"), ``scale``."""
    effects = list(cfg["effects"]) if cfg["effects"] is not None else list(LIBRARY)
    unknown = [e for e in effects if e not in LIBRARY]
    if unknown:
        raise ValueError(f"[validation].effects: unknown effect(s) {unknown}; known effects: {sorted(LIBRARY)}")
    n = int(cfg["n_datasets"])
    rng = np.random.default_rng(int(cfg["seed"]))
    n_clean = int(round(cfg["clean_share"] * n))
    labels = ["none"] * n_clean + [effects[i % len(effects)] for i in range(n - n_clean)]
    labels = [labels[i] for i in rng.permutation(n)]
    out = []
    for i, lab in enumerate(labels):
        scale = None
        if lab != "none":
            mag = LIBRARY[lab].magnitude
            scale = float(mag.test) if cfg["magnitude"] == "test" else float(rng.uniform(*mag.realistic))
        out.append({"index": i, "seed": int(cfg["seed"]) * 1000 + i, "effect": lab, "scale": scale})
    return out


def run_one(item: dict, cfg: dict, sim_over: dict) -> dict:
    """Simulate one dataset and put it through :func:`ftcal_nlp.calibrate` with the diagnosis on; returns its row."""
    t0 = time.perf_counter()
    lab = item["effect"]
    spec = [] if lab in ("none", "moving_com") else [{"name": lab, "scale": item["scale"], "seed": item["seed"]}]
    balance = "report" if lab == "moving_com" else "exact"
    row = {**item, "balance": balance}
    settings = CalibrationSettings(
        hanging=HangingSettings(compare_baseline=False),
        standing=StandingSettings(model=cfg["model"], balance=balance, compare_baseline=False),
        diagnose=DiagnoseSettings(folds=int(cfg["folds"]), seed=0))
    try:
        sim = simulate(SimConfig.from_dict({**sim_over, "seed": item["seed"], "effects": spec}))
        run = calibrate(sim.dataset, settings)
        d = run.diagnosis
        t1 = t0 + sum(v for k, v in run.timings.items() if k != "diagnosis")
        sh = d.shrinkage
        b, a, f = (np.asarray(sh[k], float) for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"))
        row.update(verdict=d.verdict, named=d.effect or d.verdict, kind=sh["kind"], gaps=";".join(d.gaps),
                   explains=d.where.get("explains"), legs=" ".join(d.where.get("legs", [])),
                   rms_ratio_before=float(np.mean(b / f)), rms_ratio_after=float(np.mean(a / f)),
                   shrinkage_error=float(np.mean(a / f) - 1.0), best=d.ranking[0]["effect"] if d.ranking else "",
                   second=d.ranking[1]["effect"] if len(d.ranking) > 1 else "",
                   calib_s=t1 - t0, diag_s=d.time_s)
    except Exception as exc:  # one failed dataset is a finding of the validation, not a reason to stop it
        log.exception("dataset %s (%s) failed", item["index"], lab)
        row.update(verdict="error", named="error", error=f"{type(exc).__name__}: {exc}")
    row["time_s"] = time.perf_counter() - t0
    return row


def confusion(rows: pd.DataFrame, labels: list[str]) -> pd.DataFrame:
    cols = ["none"] + [l for l in labels if l != "none"] + ["unexplained", "error"]
    M = pd.DataFrame(0, index=["none"] + [l for l in labels if l != "none"], columns=cols)
    for _, r in rows.iterrows():
        M.loc[r["effect"], r["named"] if r["named"] in cols else "error"] += 1
    M = M.loc[:, (M.sum(axis=0) > 0) | M.columns.isin(["none", "unexplained"] + labels)]
    M.index.name = "withheld"
    return M


def summarise(rows: pd.DataFrame, wall_s: float) -> dict:
    ok = rows[rows["named"] != "error"]
    correct = ok["named"] == ok["effect"]
    clean = ok[ok["effect"] == "none"]
    eff = ok[(ok["effect"] != "none") & correct]
    per = {}
    for lab, g in ok.groupby("effect"):
        per[lab] = {"n": len(g), "correct": int((g["named"] == lab).sum()),
                    "named": {k: int(v) for k, v in g["named"].value_counts().items()}}
    return {
        "n_datasets": len(rows), "n_errors": int((rows["named"] == "error").sum()),
        "accuracy": float(correct.mean()) if len(ok) else float("nan"),
        "accuracy_effects": float(correct[ok["effect"] != "none"].mean()) if (ok["effect"] != "none").any() else float("nan"),
        "false_alarm_rate_clean": float((clean["named"] != "none").mean()) if len(clean) else float("nan"),
        "n_clean": len(clean),
        "shrinkage_error_median": float(eff["shrinkage_error"].median()) if len(eff) else float("nan"),
        "shrinkage_error_max": float(eff["shrinkage_error"].max()) if len(eff) else float("nan"),
        "per_effect": per, "wall_time_s": float(wall_s),
        "mean_time_per_dataset_s": float(rows["time_s"].mean()) if len(rows) else float("nan"),
    }


def _markdown(M: pd.DataFrame, summary: dict) -> str:
    cols = [M.index.name or "withheld"] + [str(c) for c in M.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join(["---"] + ["---:"] * len(M.columns)) + "|"]
    for idx, r in M.iterrows():
        lines.append("| " + " | ".join([str(idx)] + [(f"**{v}**" if c == idx and v else str(v)) for c, v in r.items()]) + " |")
    lines += ["", f"accuracy {summary['accuracy']:.2f} ({summary['n_datasets']} datasets, {summary['n_errors']} errors); "
              f"false-alarm rate on clean data {summary['false_alarm_rate_clean']:.2f} ({summary['n_clean']} clean); "
              f"shrinkage error (mean held-out RMS / floor - 1, correctly named) median {summary['shrinkage_error_median']:.2f}, "
              f"max {summary['shrinkage_error_max']:.2f}; wall time {summary['wall_time_s']:.0f} s"]
    return "\n".join(lines) + "\n"


def run_validation(cfg: dict, out_dir: str | Path) -> dict:
    """Run the validation of ``cfg`` (the ``[validation]`` table, optionally with a ``simulate``
    sub-table) and write its outputs into ``out_dir``; returns the summary."""
    unknown = sorted(set(cfg) - set(DEFAULTS) - {"simulate"})
    if unknown:
        raise ValueError(f"[validation]: unknown key(s) {unknown}; known keys: {sorted(DEFAULTS) + ['simulate']}")
    c = {**DEFAULTS, **{k: v for k, v in cfg.items() if k != "simulate"}}
    if c["magnitude"] not in ("realistic", "test"):
        raise ValueError(f"[validation].magnitude: expected 'realistic' or 'test', got {c['magnitude']!r}")
    sim_over = {**SIM_DEFAULTS, **cfg.get("simulate", {})}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    items = plan(c)
    t0 = time.perf_counter()
    rows = []
    if int(c["workers"]) > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(int(c["workers"])) as ex:
            for row in ex.map(run_one, items, [c] * len(items), [sim_over] * len(items)):
                rows.append(row)
                log.info("dataset %d: withheld %s -> %s (%.0f s)", row["index"], row["effect"], row["named"], row["time_s"])
    else:
        for it in items:
            row = run_one(it, c, sim_over)
            rows.append(row)
            log.info("dataset %d: withheld %s (scale %s) -> %s (%.0f s)", row["index"], row["effect"], row.get("scale"), row["named"], row["time_s"])
    df = pd.DataFrame(rows)
    labels = ["none"] + (list(c["effects"]) if c["effects"] is not None else list(LIBRARY))
    M = confusion(df, labels)
    summary = summarise(df, time.perf_counter() - t0)
    df.to_csv(out / "datasets.csv", index=False)
    M.to_csv(out / "confusion.csv")
    (out / "confusion.md").write_text(_markdown(M, summary))
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(_markdown(M, summary))
    return summary


def main(config_path: str | Path) -> int:
    """Read a config with a ``[validation]`` table and run it (output folder from ``[output] dir``)."""
    path = Path(config_path)
    d = tomllib.loads(path.read_text())
    if "validation" not in d:
        raise ValueError(f"{path}: no [validation] table")
    out = d.get("output", {}).get("dir")
    if not isinstance(out, str):
        raise ValueError(f"{path} [output].dir: expected a path string for the output folder")
    run_validation(d["validation"], path.parent / out)
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(prog="python -m ftcal_nlp.diagnose.validate", description="Withheld-effect validation of the diagnosis.")
    ap.add_argument("config")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    sys.exit(main(args.config))
