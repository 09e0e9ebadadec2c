"""Speed: wall and CPU time per pipeline stage on the default problem, NLP and baseline in one process.

The default problem is ``SimConfig()`` (the full 3^6 pose grid, four hanging
recordings of 10 leg turns at 100 Hz), written to a temporary folder in the
interchange format so that loading is timed as a user meets it. Stages, as in
``ftcal_nlp.run``:

* ``load``: ``read_dataset`` of the manifest;
* ``poses``: ``extract_poses`` of every standing recording;
* ``hanging``: ``fit_hanging`` (``nlp`` | ``baseline``);
* ``model selection``: ``select_models`` over the report's four candidates with
  5-fold CV (``ipopt`` + exact balance | ``baseline`` solver + report balance,
  i.e. the report's method);
* ``standing``: ``fit_standing`` of the selected model (as ``run.py`` does after
  the selection);
* ``diagnosis``: ``ftcal_nlp.diagnose.diagnose_run`` when that package provides it;
* ``report``: ``ftcal_nlp.report.write_report`` (tables and figures).

"Calibration" is hanging + model selection + standing (the 5 s target). Each
stage runs ``repeats`` times and the median is reported (the machine is shared:
CPU time, ``time.process_time``, is reported beside wall time). BLAS must be
limited to one thread by the caller (``__main__`` does).
"""

from __future__ import annotations

import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

CALIBRATION_STAGES = ("hanging", "model selection", "standing")
METHODS = {
    "nlp": {"hanging": "nlp", "solver": "ipopt", "balance": "exact"},
    "baseline": {"hanging": "baseline", "solver": "baseline", "balance": "report"},
}


@dataclass(frozen=True)
class SpeedSettings:
    repeats: int = 3
    sim_overrides: dict = field(default_factory=dict)   # SimConfig fields; empty: the default problem
    folds: int = 5
    diagnosis: bool = True                               # time ftcal_nlp.diagnose when it is available


def timed(fn: Callable, repeats: int) -> tuple[object, list[float], list[float]]:
    """Call ``fn`` ``repeats`` times; returns the last result, wall and CPU seconds of each call."""
    walls, cpus, out = [], [], None
    for _ in range(max(1, repeats)):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return out, walls, cpus


def _row(stage: str, method: str, walls: list[float], cpus: list[float], note: str = "") -> dict:
    return {"stage": stage, "method": method, "wall_s": float(np.median(walls)), "wall_min_s": float(np.min(walls)),
            "cpu_s": float(np.median(cpus)), "repeats": len(walls), "note": note}


def run_speed(settings: SpeedSettings = SpeedSettings(), progress: bool = True) -> dict:
    """Time every stage (module docstring). Returns ``times`` (DataFrame: stage, method, wall_s,
    wall_min_s, cpu_s, repeats, note), ``totals`` and the problem's sizes."""
    from tqdm import tqdm

    from ..data import read_dataset
    from ..hanging import fit_hanging
    from ..selection import select_models
    from ..sim import SimConfig, simulate, write_simulation
    from ..standing import extract_poses, fit_standing
    from ..standing.poses import Poses

    R = settings.repeats
    rows: list[dict] = []
    steps = 7
    bar = tqdm(total=steps, desc="speed (stages)", disable=not progress)
    sim = simulate(SimConfig(**settings.sim_overrides))
    with tempfile.TemporaryDirectory(prefix="ftcal_bench_") as tmp:
        manifest = write_simulation(sim, Path(tmp) / "data")
        ds, w, c = timed(lambda: read_dataset(manifest), R)
        rows.append(_row("load", "shared", w, c))
        bar.update()
        robot = ds.robot
        poses, w, c = timed(lambda: Poses.concat([extract_poses(r, robot) for r in ds.standing]), R)
        rows.append(_row("poses", "shared", w, c))
        bar.update()
        results = {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for method, spec in METHODS.items():
                hang, w, c = timed(lambda spec=spec: fit_hanging(ds.hanging, robot, method=spec["hanging"]), R)
                rows.append(_row("hanging", method, w, c))
                prior = hang.to_calibration(robot)
                sel, w, c = timed(lambda spec=spec, prior=prior: select_models(poses, prior, robot, solver=spec["solver"],
                                                                                balance=spec["balance"], folds=settings.folds,
                                                                                on_failure="record"), R)
                rows.append(_row("model selection", method, w, c, f"selected {sel.best}"))
                stand, w, c = timed(lambda spec=spec, prior=prior, best=sel.best: fit_standing(
                    poses, prior, robot, model=best, solver=spec["solver"], balance=spec["balance"]), R)
                rows.append(_row("standing", method, w, c, f"model {sel.best}"))
                results[method] = (hang, sel, stand)
                bar.update()
        run_res = _run_result(ds, manifest, Path(tmp), results, poses, sim)
        if settings.diagnosis:
            rows.append(_diagnosis_row(run_res, R))
        bar.update()
        out_dir = Path(tmp) / "report"
        out_dir.mkdir()
        from ..report import write_report

        _, w, c = timed(lambda: write_report(run_res, out_dir), 1)
        rows.append(_row("report", "shared", w, c))
        bar.update()
    bar.update(steps - bar.n)
    bar.close()
    times = pd.DataFrame(rows)
    totals = {}
    for method in METHODS:
        t = times[(times.method == method) & times.stage.isin(CALIBRATION_STAGES)]
        totals[method] = {"calibration_wall_s": float(t.wall_s.sum()), "calibration_cpu_s": float(t.cpu_s.sum())}
        totals[method]["with_poses_wall_s"] = totals[method]["calibration_wall_s"] + float(times[times.stage == "poses"].wall_s.iloc[0])
    sizes = {"hanging_samples": int(sum(r.n for r in ds.hanging)), "standing_samples": int(sum(r.n for r in ds.standing)),
             "poses": int(poses.n), "selected_nlp": results["nlp"][1].best, "selected_baseline": results["baseline"][1].best}
    context = {"sim": sim, "dataset": ds, "poses": poses, "results": results, "run_result": run_res}
    return {"times": times, "totals": totals, "sizes": sizes, "settings": settings, "load_average": _load_average(),
            "context": context}


def _load_average() -> float:
    """1-minute load average of the machine (other processes compete for the 2 cores)."""
    try:
        import os

        return float(os.getloadavg()[0])
    except OSError:
        return float("nan")


def profile_targets(context: dict, workdir: Path, names: list[str] | None = None, methods: tuple[str, ...] = ("nlp",)) -> dict:
    """Callables re-running stages of the speed bench's problem, for :mod:`.profile`.

    ``names``: which to build (all by default): ``load``, ``poses``, ``hanging (nlp)``,
    ``model selection (nlp)``, ``standing (nlp)``, ``diagnosis`` (when available), ``report``.
    The dataset for ``load`` is written into ``workdir`` here, outside what is profiled.
    """
    from ..data import read_dataset
    from ..hanging import fit_hanging
    from ..report import write_report
    from ..selection import select_models
    from ..sim import write_simulation
    from ..standing import extract_poses, fit_standing
    from ..standing.poses import Poses

    ds, poses, robot = context["dataset"], context["poses"], context["dataset"].robot
    out = {}
    if names is None or "load" in names:
        manifest = write_simulation(context["sim"], Path(workdir) / "data", overwrite=True)
        out["load"] = lambda: read_dataset(manifest)
    out["poses"] = lambda: Poses.concat([extract_poses(r, robot) for r in ds.standing])
    for m in methods:
        spec = METHODS[m]
        hang, sel, _ = context["results"][m]
        prior = hang.to_calibration(robot)
        out[f"hanging ({m})"] = lambda spec=spec: fit_hanging(ds.hanging, robot, method=spec["hanging"])
        out[f"model selection ({m})"] = lambda spec=spec, prior=prior: select_models(poses, prior, robot, solver=spec["solver"], balance=spec["balance"])
        out[f"standing ({m})"] = lambda spec=spec, prior=prior, best=sel.best: fit_standing(poses, prior, robot, model=best, solver=spec["solver"], balance=spec["balance"])
    try:
        from ..diagnose import diagnose_run

        out["diagnosis"] = lambda: diagnose_run(context["run_result"])
    except ImportError:
        pass
    report_dir = Path(workdir) / "report"
    report_dir.mkdir(parents=True, exist_ok=True)
    out["report"] = lambda: write_report(context["run_result"], report_dir)
    return out if names is None else {k: v for k, v in out.items() if k in names}


def _run_result(ds, manifest: Path, tmp: Path, results: dict, poses, sim):
    """A RunResult of the NLP pipeline (baselines attached) for the diagnosis and report stages."""
    from dataclasses import replace

    from ..config import RunConfig
    from ..run import RunResult

    hang, sel, stand = results["nlp"]
    hang_b, _, stand_b = results["baseline"]
    cfg = RunConfig(path=tmp / "bench.toml", manifest=manifest, simulate=None, simulate_dir=None, output_dir=tmp / "report")
    cal = replace(stand.calibration, model=sel.best)
    return RunResult(cfg, ds, cal, hang, hang_b, poses, sel, stand, stand_b, truth=sim.truth)


def _diagnosis_row(run_res, repeats: int) -> dict:
    """Time the diagnosis if ``ftcal_nlp.diagnose`` provides ``diagnose_run`` and it works; else a note."""
    try:
        from ..diagnose import diagnose_run
    except ImportError as exc:
        return {"stage": "diagnosis", "method": "shared", "wall_s": float("nan"), "wall_min_s": float("nan"),
                "cpu_s": float("nan"), "repeats": 0, "note": f"not available ({exc})"}
    try:
        out, w, c = timed(lambda: diagnose_run(run_res), repeats)
    except Exception as exc:  # noqa: BLE001 - a module under construction; its failure is reported, not raised
        return {"stage": "diagnosis", "method": "shared", "wall_s": float("nan"), "wall_min_s": float("nan"),
                "cpu_s": float("nan"), "repeats": 0, "note": f"failed: {type(exc).__name__}: {exc}"[:200]}
    run_res.diagnosis = out
    return _row("diagnosis", "shared", w, c, f"verdict {getattr(out, 'verdict', '?')}")
