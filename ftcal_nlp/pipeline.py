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

Before any fit, :mod:`ftcal_nlp.checks` tests the physics of the data (units,
signs, quaternion order, shaft angles in radians); after the standing fit it
bounds the rotations against the design. Optional comparisons (the report's
baselines) and the diagnosis that cannot run on a dataset are skipped with one
warning and a note in ``run.notes`` (the report lists them).

With ``offsets_only=<earlier Calibration>`` only the offsets are re-estimated
from the standing poses and everything else of the earlier calibration is kept
(report Sec. V); no hanging stage runs.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import replace
from typing import Callable, Iterator, TypeVar

import numpy as np

from .calibration import Calibration
from .calibration_run import CalibrationRun
from .checks import check_dataset, check_transducer_poses, screen_sensor_faults
from .correct import correct_recording_full
from .data import DataFormatError, Dataset
from .diagnose import diagnose_run
from .hanging import HangingResult, fit_hanging
from .selection import select_models
from .sensor_noise import SensorNoise, estimate_sensor_noise
from .settings import CalibrationSettings
from .standing import Poses, extract_poses, fit_standing
from .uncertainty import CalibrationCovariance

__all__ = ["calibrate"]

log = logging.getLogger("ftcal_nlp.pipeline")

T = TypeVar("T")


def optional(what: str, notes: list[str], fn: Callable[[], T]) -> T | None:
    """Run an optional comparison or stage; if it cannot run on this dataset, log one warning saying why,
    record it in ``notes`` (the report lists them) and return None: the main estimate stands without it."""
    try:
        return fn()
    except Exception as exc:  # noqa: BLE001 -- whatever stops a comparison must not stop the run
        why = str(exc) if isinstance(exc, (ValueError, RuntimeError)) and str(exc) else f"{type(exc).__name__}: {exc}"
        msg = f"{what} was skipped: {why}"
        log.warning("%s", msg)
        log.debug("%s", what, exc_info=True)
        notes.append(msg)
        return None


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
        hang = fit_hanging(ds.hanging, ds.robot, s.hanging)  # logs its own warnings
    base = None
    if s.hanging.compare_baseline and s.hanging.method != "baseline":
        with stage("hanging (baseline)", timings, cpu):
            base = optional("the report's baseline hanging calibration", notes,
                            lambda: fit_hanging(ds.hanging, ds.robot, s.hanging, method="baseline"))
    return hang, base


def _poses(ds: Dataset, s: CalibrationSettings, timings: dict[str, float], cpu: dict[str, float]) -> Poses:
    with stage("poses", timings, cpu):
        if not ds.standing:
            raise DataFormatError(f"{ds.manifest or 'dataset'}: no standing recording; the transformation errors need standing poses")
        poses = Poses.concat([extract_poses(r, ds.robot, s.standing.poses) for r in ds.standing])
        log.info("poses: %s", " -> ".join(f"{v} {k}" for k, v in poses.counts.items()))
        if poses.n < _MIN_POSES:
            p = s.standing.poses
            raise DataFormatError(
                f"{', '.join(str(r.path or r.name) for r in ds.standing)}: {poses.n} static pose(s) found "
                f"({', '.join(f'{v} {k}' for k, v in poses.counts.items())}); expected at least {_MIN_POSES}: poses where no "
                f"column {{leg}}_phi moves faster than {p.phi_rate_threshold_rad_s:g} rad/s and the forces settle below "
                f"{p.deriv_threshold_N_s:g} N/s for {p.min_steady_s:g} s with the orientation qw..qz tracked; does the robot ever "
                "stand still? ([standing.poses] in the config sets the thresholds)"
            )
    return poses


# The full model has 6 x 6 transformation parameters fitted to 6 components per pose: fewer poses
# than this cannot determine it, and a fit on them is no calibration.
_MIN_POSES = 10


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
    with stage("plausibility checks", timings, cpu):
        ds, screened = screen_sensor_faults(ds)  # dead / stuck / clipped channels: named, their rows left out
        notes += screened
        check_dataset(ds, offsets_only)
    poses = _poses(ds, s, timings, cpu)  # before hanging: a dataset without poses fails fast
    if offsets_only is not None:
        prior = offsets_only
        log.info("offsets-only re-estimation from an earlier calibration (model %s)", prior.model)
    else:
        hang, hang_base = _hanging(ds, s, timings, cpu, notes)
        prior = hang.to_calibration(robot)

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
                standing_base = optional("the report's baseline standing solver", notes, lambda: fit_standing(
                    poses, prior, robot, st, model=model_name, solver="baseline", weighting="knorm"))
        notes += check_transducer_poses(standing.calibration, robot, str(ds.manifest or "dataset"))
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
            run.diagnosis = optional("the sim-to-real gap diagnosis", notes, lambda: diagnose_run(run))
    return run
