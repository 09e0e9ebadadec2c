"""``calibrate(dataset, settings) -> CalibrationRun``: the whole method as one function.

Stages (report Wu & Revzen): the hanging calibration (Sec. III-A: offsets
``w_o``, leg weights ``m_k g``, leg CoM curves ``r_k(phi)``, hanging tilts), the
steady standing poses (Sec. I-B), model selection over the candidate error
models by cross-validation and BIC (Sec. IV-2, Table I), the standing fit of the
selected model (Sec. III-B: mounting rotations ``R_tilde_k``, translations
``p'_k``, the body CoM where identifiable), the report's own baselines beside
them when asked, the per-foot ground wrenches of every walking recording
(``OUTPUT_FORMAT.md``), and the sim-to-real gap diagnosis when enabled.

``calibrate`` writes no file and prints nothing: it logs each stage with counts
and wall time (``logging``, logger ``ftcal_nlp.pipeline``) and shows progress
bars (tqdm, off when not on a terminal). ``run.py`` is the command line around
it (config, files, printing); the diagnosis' validation and every benchmark call
it too, so what they measure is what a run does.

With ``offsets_only=<earlier Calibration>`` only the offsets are re-estimated
from the standing poses and everything else of the earlier calibration is kept
(report Sec. V); no hanging stage runs.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import replace
from typing import Iterator

import numpy as np

from .calibration import Calibration
from .calibration_run import CalibrationRun
from .correct import correct_recording_full
from .data import DataFormatError, Dataset
from .diagnose import diagnose_run
from .hanging import HangingResult, fit_hanging
from .selection import select_models
from .sensor_noise import SensorNoise, estimate_sensor_noise
from .settings import CalibrationSettings
from .solver import SolverError
from .standing import Poses, extract_poses, fit_standing
from .uncertainty import CalibrationCovariance

__all__ = ["calibrate"]

log = logging.getLogger("ftcal_nlp.pipeline")


@contextmanager
def stage(name: str, timings: dict[str, float], cpu: dict[str, float] | None = None) -> Iterator[None]:
    """Log the start and the wall time of stage ``name``; store it in ``timings`` (and the CPU time in ``cpu``)."""
    log.info("[%s] ...", name)
    t0, c0 = time.perf_counter(), time.process_time()
    yield
    timings[name] = time.perf_counter() - t0
    if cpu is not None:
        cpu[name] = time.process_time() - c0
    log.info("[%s] done in %.2f s", name, timings[name])


def _hanging(ds: Dataset, s: CalibrationSettings, timings: dict[str, float], cpu: dict[str, float], notes: list[str]) -> tuple[HangingResult, HangingResult | None]:
    with stage("hanging", timings, cpu):
        hang = fit_hanging(ds.hanging, ds.robot, s.hanging)
        for leg in hang.legs.values():
            for w in leg.warnings:
                log.warning("%s", w)
    base = None
    if s.hanging.compare_baseline and s.hanging.method != "baseline":
        with stage("hanging (baseline)", timings, cpu):
            try:
                base = fit_hanging(ds.hanging, ds.robot, s.hanging, method="baseline")
            except (DataFormatError, SolverError) as exc:  # a comparison that cannot run is skipped, not fatal
                log.warning("the report's baseline hanging calibration was skipped: %s", exc)
                notes.append(f"the report's baseline hanging calibration was skipped: {exc}")
    return hang, base


def _poses(ds: Dataset, s: CalibrationSettings, timings: dict[str, float], cpu: dict[str, float]) -> Poses:
    with stage("poses", timings, cpu):
        if not ds.standing:
            raise DataFormatError(f"{ds.manifest or 'dataset'}: no standing recording; the transformation errors need standing poses")
        poses = Poses.concat([extract_poses(r, ds.robot, s.standing.poses) for r in ds.standing])
        log.info("poses: %s", " -> ".join(f"{v} {k}" for k, v in poses.counts.items()))
    return poses


def _with_joint_se(run: CalibrationRun) -> Calibration:
    """The calibration with the standing se from the joint covariance (hanging uncertainty propagated,
    ``calibration_run.py``) and the rotations' se beside the contract's keys; se the stage did not
    estimate (NaN: kept from an earlier calibration) stay as they were."""
    bse = run.bse
    legs = {}
    for k, l in run.calibration.legs.items():
        rot = bse.reindex([f"{k}.R_tilde.{c}" for c in "xyz"]).to_numpy(float)
        pos = bse.reindex([f"{k}.p_prime.{c}" for c in "xyz"]).to_numpy(float)
        kw = {"rotation_se_rad": rot} if not np.all(np.isnan(rot)) else {}
        if not np.all(np.isnan(pos)):
            kw["position_from_com_se_m"] = pos
        legs[k] = replace(l, **kw)
    meta = {**run.calibration.meta, "covariance": run.joint_covariance()[3]}
    return replace(run.calibration, legs=legs, meta=meta)


def _sensor_noise(ds: Dataset, s: CalibrationSettings, notes: list[str]) -> SensorNoise | None:
    """Per-sample noise of the readings and the motion capture from the standing recordings' steady runs
    (``sensor_noise.py``); None (noted) when they have none."""
    try:
        return estimate_sensor_noise(list(ds.standing), ds.robot, s.standing.poses)
    except ValueError as exc:
        log.warning("sensor noise not estimated (the se columns then carry the calibration part only): %s", exc)
        notes.append(f"sensor noise not estimated: {exc}")
        return None


def calibrate(dataset: Dataset, settings: CalibrationSettings | None = None, *,
              offsets_only: Calibration | None = None) -> CalibrationRun:
    """Calibrate ``dataset`` (interchange format, ``data.read_dataset``) with ``settings`` (module docstring).

    Raises :class:`~ftcal_nlp.data.DataFormatError` for data that cannot calibrate (no standing
    recording, no opposite hanging pair, ...) and :class:`~ftcal_nlp.solver.SolverError` when a
    solver of the chosen method fails (a failing baseline is logged and recorded in ``notes``).
    """
    s = CalibrationSettings() if settings is None else settings
    ds, robot = dataset, dataset.robot
    timings: dict[str, float] = {}
    cpu: dict[str, float] = {}
    notes: list[str] = []
    hang = hang_base = None
    if offsets_only is not None:
        prior = offsets_only
        log.info("offsets-only re-estimation from an earlier calibration (model %s)", prior.model)
    else:
        hang, hang_base = _hanging(ds, s, timings, cpu, notes)
        prior = hang.to_calibration(robot)
    poses = _poses(ds, s, timings, cpu)

    st = s.standing
    selection = standing_base = None
    if offsets_only is not None:
        with stage("standing (offsets only)", timings, cpu):
            standing = fit_standing(poses, prior, robot, st, fit_offsets=True, model=prior.model or "full")
        model_name = prior.model
    else:
        model_name = st.model
        if model_name == "auto":
            with stage("model selection", timings, cpu):
                selection = select_models(poses, prior, robot, st, s.selection)
                model_name = selection.best
                log.info("model selection:\n%s", selection.table().to_string(index=False))
        with stage("standing", timings, cpu):
            if selection is not None and model_name in selection.results and st.weighting == "knorm":
                standing = selection.results[model_name]  # selection already fitted it to all poses with K
            else:
                standing = fit_standing(poses, prior, robot, st, model=model_name)
        if st.compare_baseline and st.solver != "baseline":
            with stage("standing (baseline)", timings, cpu):
                try:
                    standing_base = fit_standing(poses, prior, robot, st, model=model_name, solver="baseline", weighting="knorm")
                except SolverError as exc:  # a failed baseline is a finding, not a reason to stop
                    log.warning("baseline standing solver failed: %s", exc)
                    notes.append(f"the report's baseline standing solver failed: {exc}")
    meta = {"solver": st.solver, "balance": st.balance, "weighting": standing.weighting,
            # null standard errors in calibration.json are these: directions the poses do not determine
            "unidentified": list(standing.unidentified_params)}
    cal = replace(standing.calibration, model=str(model_name), meta={**standing.calibration.meta, **meta})
    run = CalibrationRun(s, ds, cal, hang, hang_base, poses, selection, standing, standing_base, timings=timings, cpu_timings=cpu, notes=notes)
    run.calibration = _with_joint_se(run)
    with stage("sensor noise", timings, cpu):
        noise = _sensor_noise(ds, s, notes)
    run.uncertainty = CalibrationCovariance.from_results(run, noise)
    if noise is not None:
        run.calibration = replace(run.calibration, meta={**run.calibration.meta, "sensor_noise": noise.to_json_dict()})
    with stage("correct walking", timings, cpu):
        for rec in ds.walking:
            c = correct_recording_full(run.calibration, rec, run.uncertainty, s.correct)
            run.corrected[rec.name] = c.frame
            if c.tracking is not None:
                run.tracked_offsets[rec.name] = c.tracking
            log.info("corrected %s: %d rows", rec.name, len(run.corrected[rec.name]))
    if s.diagnose.enabled:
        with stage("diagnosis", timings, cpu):
            run.diagnosis = diagnose_run(run)
    return run
