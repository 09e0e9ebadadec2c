"""Scaling: time and peak memory against the number of standing poses and of hanging samples.

Every point runs in its own subprocess (``python -m ftcal_nlp.bench.scaling
--worker ...``, BLAS limited to one thread) so that memory peaks do not mix:
the worker prepares its data, resets the kernel's peak-RSS counter (writing 5
to ``/proc/self/clear_refs``) after handing freed memory back to the OS
(``malloc_trim``: otherwise the task reuses what the data preparation freed
and its peak hides), runs the task and reports the wall/CPU time (the
minimum of two runs when a run is short), the growth of the peak RSS over the
RSS before the task (``VmHWM - VmRSS``: everything, CasADi and IPOPT included)
and, from one more run with ``tracemalloc`` on (tracing slows allocations, so
never while timing), the peak of numpy and Python allocations.

Standing poses (100 to 20 000): the poses extracted from one simulated 3^6
grid, replicated with fresh noise at the level of a pose median (readings:
``sigma sqrt(pi / 2n)``, n = 300 samples) and concatenated (``Poses.concat``);
the prior is that dataset's NLP hanging fit. Tasks: the stages as
``calibrate`` runs them (the settings objects of ``speed.METHODS``, which the
speed bench passes to ``calibrate``): ``fit_standing`` (full model, the run's
defaults: IPOPT, exact balance, feasible GLS), ``select_models`` (four
candidates, 5-fold CV) and the report's baseline (``fit_standing`` with the
baseline solver and the report balance). ``calibrate`` itself cannot be scaled
in poses without simulating recordings of 20 000 poses; its whole-call time on
the default problem is the speed bench's. Hanging samples (10^4 to 10^6 in all four recordings): the
simulator with ``hanging_cycles`` chosen for the count; tasks ``fit_hanging``
NLP and baseline.

Exponents: least squares of log(time) on log(size) over all points and over
the upper half of the range (the asymptotic regime; fixed costs such as
CasADi's symbolic build dominate small problems).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import re
import subprocess
import sys
import tempfile
import time
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

STANDING_TASKS = ("standing_nlp", "selection_nlp", "standing_baseline")
HANGING_TASKS = ("hanging_nlp", "hanging_baseline")
SAMPLES_PER_CYCLE = 2000  # hanging_cycle_s 20 s at 100 Hz
POSE_MEDIAN_SAMPLES = 300


@dataclass(frozen=True)
class ScalingSettings:
    poses: tuple[int, ...] = (100, 300, 1000, 3000, 10000, 20000)
    hanging_samples: tuple[int, ...] = (10_000, 30_000, 100_000, 300_000, 1_000_000)
    standing_tasks: tuple[str, ...] = STANDING_TASKS
    hanging_tasks: tuple[str, ...] = HANGING_TASKS
    timeout_s: float = 600.0
    base_sim: dict = field(default_factory=lambda: {"hanging_cycles": 2.0})  # SimConfig of the replicated poses
    tracemalloc: bool = True          # one more run per point for the numpy/Python allocation peak


# ----------------------------------------------------------------------------- worker side


def _status_kb(key: str) -> float:
    m = re.search(rf"{key}:\s+(\d+)", Path("/proc/self/status").read_text())
    return float(m.group(1)) if m else float("nan")


def _release_free_memory() -> None:
    """Hand memory freed while preparing the data back to the OS (glibc), so that the task's own
    allocations show in the peak RSS instead of silently reusing it."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def replicate_poses(base, n: int, sigma: np.ndarray, seed: int = 0):
    """``n`` poses: copies of ``base`` (cycled) with fresh pose-median noise on the readings."""
    from ..estimate.standing.poses import Poses

    rng = np.random.default_rng(seed)
    reps = int(np.ceil(n / base.n))
    parts = []
    for i in range(reps):
        w = base.w_m + rng.standard_normal(base.w_m.shape) * sigma
        parts.append(Poses(w, base.phi, base.R_WB, base.t + i * 1e5, base.legs, dict(base.counts)))
    allp = Poses.concat(parts)
    return allp.subset(np.arange(n))


def _standing_task(task: str, n: int, data_path: Path):
    """The stage as ``calibrate`` runs it (the speed bench's settings objects), at ``n`` replicated poses."""
    from ..estimate.selection import select_models
    from ..estimate.standing import fit_standing
    from .speed import METHODS

    with open(data_path, "rb") as fh:
        d = pickle.load(fh)
    poses = replicate_poses(d["poses"], n, d["sigma_median"])
    prior, robot = d["prior"], d["robot"]
    nlp, base = METHODS["nlp"], METHODS["baseline"]
    if task == "standing_nlp":
        return lambda: fit_standing(poses, prior, robot, nlp.standing, model="full")
    if task == "selection_nlp":
        return lambda: select_models(poses, prior, robot, nlp.standing, nlp.selection)
    if task == "standing_baseline":
        return lambda: fit_standing(poses, prior, robot, base.standing, model="full")
    raise ValueError(f"unknown standing task {task!r}; known: {list(STANDING_TASKS)}")


def _hanging_task(task: str, n: int):
    from ..estimate.hanging import fit_hanging
    from ..sim import SimConfig, simulate

    cycles = n / (4 * SAMPLES_PER_CYCLE)
    sim = simulate(SimConfig(seed=0, hanging_cycles=cycles, n_poses=5, walk_cycles=0.0))
    recs, robot = sim.dataset.hanging, sim.dataset.robot
    del sim
    from .speed import METHODS

    method = {"hanging_nlp": "nlp", "hanging_baseline": "baseline"}.get(task)
    if method is None:
        raise ValueError(f"unknown hanging task {task!r}; known: {list(HANGING_TASKS)}")
    return lambda: fit_hanging(recs, robot, METHODS[method].hanging)


def worker(task: str, n: int, data_path: Path | None, trace: bool = True) -> dict:
    """Run one point in this process (module docstring); returns the measurements."""
    import warnings

    from threadpoolctl import threadpool_limits

    warnings.simplefilter("ignore")
    with threadpool_limits(1):
        if task in HANGING_TASKS:
            fn = _hanging_task(task, n)
        elif data_path is None:
            raise ValueError(f"scaling task {task!r} reads the standing dataset: give --data")
        else:
            fn = _standing_task(task, n, data_path)
        _release_free_memory()
        rss0 = _status_kb("VmRSS")
        reset = _reset_peak()
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        hwm = _status_kb("VmHWM")
        if wall < 2.0:  # short: a second run, keep the faster
            w0, c0 = time.perf_counter(), time.process_time()
            fn()
            w2, c2 = time.perf_counter() - w0, time.process_time() - c0
            if w2 < wall:
                wall, cpu = w2, c2
        tm_peak = float("nan")
        if trace:
            tracemalloc.start()  # after the timing: tracing slows every allocation
            fn()
            _, tm_peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
    return {"task": task, "n": n, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": (hwm - rss0) / 1024 if reset else float("nan"),
            "tracemalloc_peak_mb": tm_peak / 2**20, "rss_before_mb": rss0 / 1024}


# ----------------------------------------------------------------------------- driver side


def prepare_standing_data(folder: Path, base_sim: dict | None = None, seed: int = 0) -> Path:
    """Simulate one 3^6 grid (``base_sim``: SimConfig overrides), extract its poses, fit the hanging prior;
    pickle what the workers need."""
    import warnings

    from ..estimate.hanging import fit_hanging
    from ..sim import SimConfig, simulate
    from ..estimate.standing import extract_poses

    cfg = SimConfig(**{"seed": seed, "hanging_cycles": 2.0, **(base_sim or {}), "walk_cycles": 0.0})
    sim = simulate(cfg)
    robot = sim.dataset.robot
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prior = fit_hanging(sim.dataset.hanging, robot).to_calibration(robot)
    poses = extract_poses(sim.dataset.standing[0], robot)
    sigma = np.array([cfg.noise_force_N] * 3 + [cfg.noise_torque_Nm] * 3) * np.sqrt(np.pi / (2 * POSE_MEDIAN_SAMPLES))
    path = folder / "standing_base.pkl"
    with open(path, "wb") as fh:
        pickle.dump({"poses": poses, "prior": prior, "robot": robot, "sigma_median": sigma}, fh)
    return path


def run_point(task: str, n: int, data_path: Path | None, timeout_s: float, trace: bool = True) -> dict:
    """One point in a fresh subprocess; a failure becomes a row with its message."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "ftcal_nlp.bench.scaling", "--worker", task, str(n)]
    if data_path is not None:
        cmd += ["--data", str(data_path)]
    if not trace:
        cmd.append("--no-tracemalloc")
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env, check=False)
    except subprocess.TimeoutExpired:
        return {"task": task, "n": n, "error": f"timeout after {timeout_s:.0f} s"}
    lines = [l for l in out.stdout.splitlines() if l.startswith("{")]
    if out.returncode != 0 or not lines:
        return {"task": task, "n": n, "error": (out.stderr.strip().splitlines() or ["no output"])[-1][:300]}
    return json.loads(lines[-1])


def fit_exponent(n: np.ndarray, y: np.ndarray) -> float:
    """Slope of log y on log n (NaN with fewer than two positive points)."""
    n, y = np.asarray(n, float), np.asarray(y, float)
    ok = (n > 0) & (y > 0) & np.isfinite(y)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(n[ok]), np.log(y[ok]), 1)[0])


def exponents(points: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for task, d in points.dropna(subset=["wall_s"]).groupby("task", sort=False):
        d = d.sort_values("n")
        upper = d[d.n >= np.sqrt(d.n.min() * d.n.max())]
        rows.append({"task": task, "size": "poses" if task in STANDING_TASKS else "hanging samples",
                     "n_min": int(d.n.min()), "n_max": int(d.n.max()),
                     "time_exponent": fit_exponent(d.n, d.wall_s), "time_exponent_upper": fit_exponent(upper.n, upper.wall_s),
                     "memory_exponent": fit_exponent(d.n, d.peak_rss_mb), "memory_exponent_upper": fit_exponent(upper.n, upper.peak_rss_mb),
                     "time_at_max_s": float(d.wall_s.iloc[-1]), "peak_rss_at_max_mb": float(d.peak_rss_mb.iloc[-1])})
    return pd.DataFrame(rows)


def run_scaling(settings: ScalingSettings = ScalingSettings(), progress: bool = True) -> dict:
    """Every point of ``settings`` in its own subprocess; returns ``points`` and ``exponents``."""
    from tqdm import tqdm

    jobs = [(t, n) for t in settings.standing_tasks for n in settings.poses] + [(t, n) for t in settings.hanging_tasks for n in settings.hanging_samples]
    rows = []
    with tempfile.TemporaryDirectory(prefix="ftcal_scaling_") as tmp:
        data = prepare_standing_data(Path(tmp), settings.base_sim) if settings.standing_tasks else None
        for task, n in tqdm(jobs, desc="scaling (points)", disable=not progress):
            rows.append(run_point(task, n, data if task in STANDING_TASKS else None, settings.timeout_s, settings.tracemalloc))
    points = pd.DataFrame(rows)
    for col in ("wall_s", "cpu_s", "peak_rss_mb", "tracemalloc_peak_mb", "error"):
        if col not in points:
            points[col] = np.nan
    return {"points": points, "exponents": exponents(points), "settings": settings}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ftcal_nlp.bench.scaling", description="One scaling point (used by the bench).")
    ap.add_argument("--worker", nargs=2, metavar=("TASK", "N"), required=True)
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--no-tracemalloc", action="store_true")
    a = ap.parse_args(argv)
    print(json.dumps(worker(a.worker[0], int(a.worker[1]), a.data, trace=not a.no_tracemalloc)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
