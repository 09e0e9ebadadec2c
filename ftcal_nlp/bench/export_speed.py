"""Speed of the correction (readings -> per-foot ground wrenches), on the robot and in Python.

* compiled: the C that ``python -m ftcal_nlp.export`` writes, built with the
  system compiler (``-O2``) and run over a walking recording by its batch entry
  point (one call per sample inside C, so ctypes' per-call cost is paid once);
  time per sample, all legs (goal < 5 us).
* Python, batched: :func:`ftcal_nlp.core.physics.ground_wrenches` from arrays
  (quaternions to rotations included), and ``correct_recording`` (a Recording in,
  the ``OUTPUT_FORMAT.md`` table out); samples per second (goal >= 1 M/s).

The recording is the simulator's walk (true calibration of ``SimConfig(seed)``),
tiled to ``n_samples``; the best of ``repeats`` is reported (shared machine).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ..correct import correct_recording
from ..core.calibration import Calibration
from ..core.data import Recording
from ..export import compile_shared, load_compiled, write_c
from ..core.geometry import quat_to_rotation
from ..core.physics import ground_wrenches
from ..sim import SimConfig, simulate

GOAL_COMPILED_US = 5.0
GOAL_PYTHON_PER_S = 1e6


@dataclass(frozen=True)
class ExportSpeedSettings:
    n_samples: int = 1_000_000
    repeats: int = 5
    seed: int = 0


def _best(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _tiled_walk(cfg: SimConfig, n: int) -> tuple[Recording, Calibration]:
    sim = simulate(cfg)
    walk = sim.dataset.walking[0]
    assert walk.quat is not None  # a walking recording has qw..qz
    walk = walk.select(np.all(np.isfinite(walk.quat), axis=1))
    reps = int(np.ceil(n / walk.n))
    idx = np.tile(np.arange(walk.n), reps)[:n]
    dt = float(np.median(np.diff(walk.t)))
    rec = walk.select(idx)
    return replace(rec, t=np.arange(n) * dt), sim.truth


def run_export_speed(settings: ExportSpeedSettings = ExportSpeedSettings()) -> dict:
    """Time the compiled and the batched Python correction; returns a table and the totals."""
    rec, cal = _tiled_walk(SimConfig(seed=settings.seed, hanging_cycles=0.25, n_poses=1, walk_cycles=2.0), settings.n_samples)
    legs = cal.leg_names
    w, phi, q = rec.wrench_array(legs), rec.phi_array(legs), rec.quat
    assert q is not None  # (as _tiled_walk's)
    n = len(phi)
    with tempfile.TemporaryDirectory(prefix="ftcal_export_") as tmp:
        fn = load_compiled(compile_shared(write_c(cal, Path(tmp))), cal)
        t_c = _best(lambda: fn(w, phi, q), settings.repeats)
        err = np.abs(fn(w[:10000], phi[:10000], q[:10000]) - ground_wrenches(w[:10000], phi[:10000], quat_to_rotation(q[:10000]), cal)).max()
    t_gw = _best(lambda: ground_wrenches(w, phi, quat_to_rotation(q), cal), settings.repeats)
    t_rec = _best(lambda: correct_recording(cal, rec), settings.repeats)
    rows = [
        {"path": "compiled C (export), batch entry", "samples": n, "time_s": t_c, "us_per_sample": 1e6 * t_c / n,
         "samples_per_s": n / t_c, "goal": f"< {GOAL_COMPILED_US:g} us/sample", "met": 1e6 * t_c / n < GOAL_COMPILED_US},
        {"path": "numpy ground_wrenches (arrays, quaternions included)", "samples": n, "time_s": t_gw, "us_per_sample": 1e6 * t_gw / n,
         "samples_per_s": n / t_gw, "goal": f">= {GOAL_PYTHON_PER_S / 1e6:g} M samples/s", "met": n / t_gw >= GOAL_PYTHON_PER_S},
        {"path": "correct_recording (Recording -> table)", "samples": n, "time_s": t_rec, "us_per_sample": 1e6 * t_rec / n,
         "samples_per_s": n / t_rec, "goal": f">= {GOAL_PYTHON_PER_S / 1e6:g} M samples/s", "met": n / t_rec >= GOAL_PYTHON_PER_S},
    ]
    return {"settings": settings, "legs": len(legs), "table": pd.DataFrame(rows), "max_abs_diff_N": float(err)}


__all__ = ["ExportSpeedSettings", "run_export_speed"]
