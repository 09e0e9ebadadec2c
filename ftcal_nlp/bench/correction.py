"""Correction bench (issue 15): throughput of the per-foot ground wrenches with standard errors, and the
time and accuracy of tracking offsets from the swing phases on a long walk.

A calibration session is simulated and calibrated (``calibrate``, model ``full``,
no diagnosis); then a later walk of ``walk_minutes`` at the simulator's rate
(default 10 min at 100 Hz, 60 000 samples) of the same robot, with its offsets
moved by up to 10 N / 0.2 N*m and drifting during the walk (``sim/later.py``),
and its drift-free twin (same motion and noise). Timed (wall and CPU, median of
``repeats``): the ground wrenches alone (``physics.ground_wrenches``), with
standard errors and contact state (``wrenches.correct_arrays``), and with the
offsets tracked (``track_offsets``). Measured beside: per-foot RMS error with
tracking over the drift-free twin's (the noise-only reference; issue 15 goal
<= 1.5), without tracking (N), and the coverage of the +-1.96 se bands.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from ..core.data import WRENCH_COMPONENTS
from ..core.geometry import quat_to_rotation
from ..core.physics import ground_wrenches
from ..pipeline import calibrate
from ..core.settings import CalibrationSettings, CorrectSettings, DiagnoseSettings, HangingSettings, StandingSettings
from ..sim import SimConfig, simulate
from ..sim.later import simulate_later_walk
from ..correct.wrenches import correct_arrays

CALIBRATE = CalibrationSettings(hanging=HangingSettings(compare_baseline=False),
                                standing=StandingSettings(compare_baseline=False, model="full"),
                                diagnose=DiagnoseSettings(enabled=False))


@dataclass(frozen=True)
class CorrectionBenchSettings:
    walk_minutes: float = 10.0
    repeats: int = 1
    seed: int = 0
    sim_overrides: dict = field(default_factory=lambda: {"n_poses": 150, "hanging_cycles": 3.0, "walk_cycles": 0.0})


def _arrays(rec, legs):
    ok = np.all(np.isfinite(rec.quat), axis=1)
    return rec.t[ok], rec.wrench_array(legs)[ok], rec.phi_array(legs)[ok], quat_to_rotation(rec.quat[ok])


def _timed(fn, repeats: int):
    walls, cpus, out = [], [], None
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return out, float(np.median(walls)), float(np.median(cpus))


def _errors(frame: pd.DataFrame, truth: pd.DataFrame, legs) -> tuple[np.ndarray, np.ndarray]:
    """Errors (n, K, 6) against the truth and the se (n, K, 6), rows matched on t."""
    m = frame.merge(truth, on="t", suffixes=("", "_true"))
    e = np.stack([m[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy() - m[[f"{k}_{c}_true" for c in WRENCH_COMPONENTS]].to_numpy()
                  for k in legs], 1)
    se = np.stack([m[[f"{k}_{c}_se" for c in WRENCH_COMPONENTS]].to_numpy() for k in legs], 1)
    return e, se


def run_correction(settings: CorrectionBenchSettings = CorrectionBenchSettings(), progress: bool = True) -> dict:
    """Times and accuracies of the module docstring; ``table`` one row per task."""
    s = settings
    sim = simulate(replace(SimConfig(seed=s.seed), **s.sim_overrides))
    run = calibrate(sim.dataset, CALIBRATE)
    cal, cov = run.calibration, run.uncertainty
    assert cov is not None  # a hexapod's run has its covariance
    legs = cal.leg_names
    cycles = s.walk_minutes * 60.0 * sim.config.walk_freq_hz
    moved = simulate_later_walk(sim, cycles=cycles)
    ref = simulate_later_walk(sim, cycles=cycles, shift_N=0.0, shift_Nm=0.0, drift_N=0.0, drift_Nm=0.0)
    t, w, phi, R = _arrays(moved.recording, legs)
    n = len(t)
    rows = []
    _, wall, cpu = _timed(lambda: ground_wrenches(w, phi, R, cal), s.repeats)
    rows.append({"task": "ground wrenches only", "samples": n, "wall_s": wall, "cpu_s": cpu})
    plain, wall, cpu = _timed(lambda: correct_arrays(cal, t, w, phi, R, cov), s.repeats)
    rows.append({"task": "with se and contact state", "samples": n, "wall_s": wall, "cpu_s": cpu})
    tracked, wall, cpu = _timed(lambda: correct_arrays(cal, t, w, phi, R, cov, CorrectSettings(track_offsets=True)), s.repeats)
    rows.append({"task": "with se, contact and tracked offsets", "samples": n, "wall_s": wall, "cpu_s": cpu})
    table = pd.DataFrame(rows)
    table["samples_per_s"] = table.samples / table.wall_s
    tr_, wr, pr, Rr = _arrays(ref.recording, legs)
    reference = correct_arrays(cal, tr_, wr, pr, Rr, cov)
    e_ref, _ = _errors(reference.frame, ref.truth, legs)
    e_tr, se_tr = _errors(tracked.frame, moved.truth, legs)
    e_no, se_no = _errors(plain.frame, moved.truth, legs)
    rms = lambda e: np.sqrt(np.mean(e**2, axis=0))  # noqa: E731  (K, 6)
    acc = {
        "ratio_tracked_over_reference_max": float(np.max(rms(e_tr) / rms(e_ref))),
        "ratio_tracked_over_reference_median": float(np.median(rms(e_tr) / rms(e_ref))),
        "reference_rms_force_N": float(np.sqrt(np.mean(e_ref[..., :3] ** 2))),
        "reference_rms_torque_Nm": float(np.sqrt(np.mean(e_ref[..., 3:] ** 2))),
        "untracked_rms_force_N_per_foot": rms(e_no)[:, :3].max(axis=1).round(2).tolist(),
        "coverage_tracked": float(np.mean(np.abs(e_tr / se_tr) < 1.96)),
        "coverage_reference": float(np.mean(np.abs(e_ref / _errors(reference.frame, ref.truth, legs)[1]) < 1.96)),
        "max_offset_shift_N": float(np.abs(moved.offset_change[..., :3]).max()),
        "n_params": len(cov.names),
    }
    return {"settings": s, "table": table, "accuracy": acc, "samples": n}


def correction_markdown(res: dict, md_table) -> list[str]:
    """The bench summary's section."""
    s, a, n = res["settings"], res["accuracy"], res["samples"]
    tab = res["table"].copy()
    head = (f"### Correction: a later walk of {s.walk_minutes:g} min at 100 Hz ({n} samples), offsets moved "
            f"(max {a['max_offset_shift_N']:.1f} N) and drifting; calibration with {a['n_params']} parameters")
    tr = tab[tab.task.str.contains("tracked")].iloc[0]
    se = tab[tab.task == "with se and contact state"].iloc[0]
    text = (f"Throughput with se (all legs, totals, contact state): **{se.samples_per_s:,.0f} samples/s**; "
            f"with offsets tracked from the swing phases: **{tr.wall_s:.1f} s** for the walk. Per-foot RMS error with tracking "
            f"over the drift-free twin's (noise-only reference {a['reference_rms_force_N']:.3f} N, "
            f"{a['reference_rms_torque_Nm']:.4f} N*m): max **{a['ratio_tracked_over_reference_max']:.2f}x** (median "
            f"{a['ratio_tracked_over_reference_median']:.2f}x; goal <= 1.5x); without tracking the worst force component "
            f"per foot is {', '.join(f'{v:.1f}' for v in a['untracked_rms_force_N_per_foot'])} N. Coverage of the +-1.96 se "
            f"bands: {100 * a['coverage_tracked']:.1f} % tracked, {100 * a['coverage_reference']:.1f} % on the drift-free twin.")
    return [head, "", md_table(tab), "", text, ""]
