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

Before any fit, :mod:`ftcal_nlp.core.checks` tests the physics of the data (units,
signs, quaternion order, shaft angles in radians); after the standing fit it
bounds the rotations against the design. Optional comparisons (the report's
baselines) and the diagnosis that cannot run on a dataset are skipped with one
warning and a note in ``run.notes`` (the report lists them).

A dataset whose transducers all carry free loads (``DATA_FORMAT.md`` section 5:
rigid payloads, URDF links) takes one stage instead, the free-load estimator
(:func:`ftcal_nlp.estimate.freeload.fit_free_loads`); its standing and walking stages are
skipped (logged), and so is the diagnosis for now (issue 23 extends it).

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
import pandas as pd

from .core.calibration import Calibration
from .calibration_run import CalibrationRun, JointCovariance, joint_covariance
from .core.checks import check_dataset, check_transducer_poses, screen_sensor_faults
from .correct import correct_recording_full
from .core.data import Dataset, Recording
from .diagnose import DiagnosisResult, diagnose_run
from .core.errors import DataFormatError, FtcalError, ImplausibleLoadFit, SolverError
from .estimate.hanging import HangingResult, fit_hanging
from .loads.base import LinearLoad
from .estimate.selection import select_models
from .estimate.sensor_noise import SensorNoise, estimate_sensor_noise
from .core.settings import CalibrationSettings, FreeLoadSettings
from .estimate.standing import Poses, extract_poses, fit_standing
from .correct.tracking import TrackedOffsets
from .estimate.uncertainty import CalibrationCovariance

__all__ = ["calibrate"]

log = logging.getLogger("ftcal_nlp.pipeline")

T = TypeVar("T")

#: per free-load transducer: its recordings cut to the quasi-static samples, the readings' noise sd (6,) and its load
FreeLoadSamples = dict[str, tuple[list[Recording], np.ndarray | None, LinearLoad]]


def optional(what: str, notes: list[str], fn: Callable[[], T]) -> T | None:
    """Run an optional comparison or stage and return its result, or None (the main estimate stands without it).

    A :class:`~ftcal_nlp.core.errors.FtcalError` says why it cannot run on this dataset: one warning
    ``"<what> was skipped: <why>"``, recorded in ``notes`` (the report lists them). Anything else is a
    defect of the package, not of the data; it must not stop the run either, but it is named as one
    (``"... was skipped by a defect (TypeName: msg); please report it"``) and its traceback logged at debug."""
    err: Exception
    try:
        return fn()
    except FtcalError as exc:
        msg, err = f"{what} was skipped: {str(exc) or type(exc).__name__}", exc
    except Exception as exc:  # noqa: BLE001 -- a comparison must not stop the run; named as a defect
        msg, err = f"{what} was skipped by a defect ({type(exc).__name__}: {exc}); please report it", exc
    log.warning("%s", msg)
    log.debug("%s", what, exc_info=err)
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
        hang = fit_hanging(ds.hanging, ds.robot, s.hanging)  # the hexapod legs' load (loads.LegComCurve); logs its own warnings
    base = None
    if s.hanging.compare_baseline and s.hanging.method != "baseline":
        with stage("hanging (baseline)", timings, cpu):
            base = optional("the report's baseline hanging calibration", notes,
                            lambda: fit_hanging(ds.hanging, ds.robot, s.hanging, method="baseline"))
    return hang, base


def _poses(ds: Dataset, s: CalibrationSettings, timings: dict[str, float], cpu: dict[str, float]) -> Poses:
    with stage("poses", timings, cpu):
        if not ds.standing:
            raise DataFormatError(f"{ds.manifest or 'dataset'}: no standing recording; the transformation errors need standing poses",
                                  path=ds.manifest)
        poses = Poses.concat([extract_poses(r, ds.robot, s.standing.poses) for r in ds.standing])
        log.info("poses: %s", " -> ".join(f"{v} {k}" for k, v in poses.counts.items()))
        if poses.n < _MIN_POSES:
            p = s.standing.poses
            raise DataFormatError(
                f"{', '.join(str(r.path or r.name) for r in ds.standing)}: {poses.n} static pose(s) found "
                f"({', '.join(f'{v} {k}' for k, v in poses.counts.items())}); expected at least {_MIN_POSES}: poses where no "
                f"column {{leg}}_phi moves faster than {p.phi_rate_threshold_rad_s:g} rad/s and the forces settle below "
                f"{p.deriv_threshold_N_s:g} N/s for {p.min_steady_s:g} s with the orientation qw..qz tracked; does the robot ever "
                "stand still? ([standing.poses] in the config sets the thresholds)", path=ds.standing[0].path
            )
    return poses


# The full model has 6 x 6 transformation parameters fitted to 6 components per pose: fewer poses
# than this cannot determine it, and a fit on them is no calibration.
_MIN_POSES = 10


def _with_joint_se(cal: Calibration, joint: JointCovariance) -> Calibration:
    """``cal`` with the standing se from the joint covariance (hanging uncertainty propagated,
    ``calibration_run.py``) and the rotations' se beside the contract's keys; se the stage did not
    estimate (NaN: kept from an earlier calibration) stay as they were."""
    bse = joint.bse
    legs = {}
    for k, l in cal.legs.items():
        rot = bse.reindex([f"{k}.R_tilde.{c}" for c in "xyz"]).to_numpy(float)
        pos = bse.reindex([f"{k}.p_prime.{c}" for c in "xyz"]).to_numpy(float)
        kw = {"rotation_se_rad": rot} if not np.all(np.isnan(rot)) else {}
        if not np.all(np.isnan(pos)):
            kw["position_from_com_se_m"] = pos
        legs[k] = replace(l, **kw)
    return replace(cal, legs=legs, meta={**cal.meta, "covariance": joint.how})


def _sensor_noise(ds: Dataset, s: CalibrationSettings, notes: list[str]) -> SensorNoise | None:
    """Per-sample noise of the readings and the motion capture from the standing recordings' steady runs
    (``sensor_noise.py``); None (noted) when they have none."""
    try:
        return estimate_sensor_noise(list(ds.standing), ds.robot, s.standing.poses)
    except DataFormatError as exc:
        log.warning("sensor noise not estimated (the se columns then carry the calibration part only): %s", exc)
        notes.append(f"sensor noise not estimated: {exc}")
        return None


def _free_load_samples(ds: Dataset, s: CalibrationSettings) -> FreeLoadSamples:
    return checked_free_load_samples(ds, s.free_load)


def checked_free_load_samples(ds: Dataset, free_load: FreeLoadSettings | None = None) -> FreeLoadSamples:
    """Per free-load transducer its quasi-static samples (the recordings cut to them), their per-sample noise and its load,
    checked before fitting (``freeload/plausibility.py``: quaternion order, gravity sign, joint angles in degrees, ...);
    ``free_load`` the :class:`~ftcal_nlp.core.settings.FreeLoadSettings` (None: the defaults). ``plan`` checks a pilot so."""
    from .estimate.freeload import free_load_data
    from .estimate.freeload.plausibility import THRESHOLDS, check_free_load_data
    from .loads import load_for

    log.info("plausibility checks: %s", THRESHOLDS)
    from .estimate.freeload.plausibility import as_given, check_pose_list_clock, follows_gravity

    if free_load is None:
        free_load = CalibrationSettings().free_load
    out: FreeLoadSamples = {}
    for leg in ds.free_load_legs:
        load = load_for(ds, leg, free_load.loads.get(leg))
        for r in ds.hanging:   # the clock first: milliseconds make every sample a hold of its own
            if r.hangs_free(leg):
                check_pose_list_clock(r, tuple(getattr(load, "load_joints", ())) + tuple(getattr(load, "base_joints", ())))
        data = free_load_data(ds, leg, free_load, load)
        recs = [r.select(data.masks[r.name]) for r in ds.hanging if r.hangs_free(leg) and r.name in data.masks]
        out[leg] = (recs, data.noise0, load)
    # a transducer on the same recordings whose weight follows gravity as given clears the stream: per-transducer evidence
    given = {leg: as_given(recs, leg, load, ds.robot.g) for leg, (recs, _, load) in out.items()}
    fine = {leg for leg, (recs, _, load) in out.items() if follows_gravity(recs, leg, load, ds.robot.g, given[leg])}
    for leg, (recs, noise, load) in out.items():
        names = {r.name for r in recs}
        siblings = tuple(k for k in fine if k != leg and names & {r.name for r in out[k][0]})
        check_free_load_data(recs, leg, load, ds.robot.g, ds.robot.tree, noise, ds.robot.transducers[leg].load_mass_kg,
                             siblings, given[leg])
    return out


def raise_free_load_causes(ds: Dataset, samples: FreeLoadSamples, exc: SolverError) -> None:
    """After a failed free-load fit: raise :class:`~ftcal_nlp.core.errors.ImplausibleLoadFit` naming the conventions whose
    fix makes a transducer's load plausible, if any (else return: the solver's error stands)."""
    from .estimate.freeload.plausibility import nominal_rotation_source, reference_mass, try_causes

    for leg, (recs, noise, load) in samples.items():
        found = [t for t in try_causes(recs, leg, load, ds.robot.g, ds.robot.tree, noise, nominal_rotation_source(ds, leg),
                                       reference_mass(load, ds.robot.transducers[leg].load_mass_kg)) if t.fixes]
        if found:
            raise ImplausibleLoadFit(f"{', '.join(str(r.path or r.name) for r in recs)}: transducer {leg}: the free-load fit "
                                     f"failed ({exc}); tried in order: {'; '.join(t.text for t in found)}",
                                     leg=leg, causes=tuple(t.name for t in found)) from exc


def check_free_load_fits(ds: Dataset, fits: dict, samples: FreeLoadSamples) -> list[str]:
    """The checks after the free-load fits (``freeload/plausibility.py``: an implausible fit raises, naming the causes
    tried); returns the notes of a weighed mass the fit disagrees with (logged). ``plan`` checks a pilot so."""
    from .estimate.freeload.plausibility import check_free_load_fit, nominal_rotation_source, weighed_mass_note

    notes = []
    for leg, r in fits.items():
        recs, noise, _ = samples[leg]
        weighed = ds.robot.transducers[leg].load_mass_kg
        check_free_load_fit(r, recs, ds.robot.g, ds.robot.tree, noise, nominal_rotation_source(ds, leg), weighed)
        note = weighed_mass_note(r, weighed)
        if note:
            log.warning("%s", note)
            notes.append(note)
    return notes


def _calibrate_free_loads(ds: Dataset, s: CalibrationSettings, timings: dict[str, float], cpu: dict[str, float],
                          notes: list[str]) -> CalibrationRun:
    """Section-5 datasets: every transducer's free load by the free-load estimator; the hexapod stages do not apply."""
    from .estimate.freeload import fit_free_loads, free_load_calibration
    hexapod = [k for k in ds.robot.legs if k not in ds.free_load_legs]
    if hexapod:
        raise DataFormatError(f"{ds.manifest or 'dataset'}: transducers {hexapod} have {{leg}}_phi columns (hexapod legs) and "
                              f"{list(ds.free_load_legs)} carry free loads; one dataset of both kinds is not supported yet")
    for kind in ("standing", "walking"):
        if ds.of_kind(kind):
            msg = f"{kind} recordings skipped: the free-load calibration uses the hanging recordings only"
            log.warning("%s", msg)
            notes.append(msg)
    with stage("plausibility checks", timings, cpu):
        ds, screened = screen_sensor_faults(ds, unit="transducer", every_recording_fatal=False)  # dead / stuck / clipped channels, as the hexapod's
        notes += screened
        samples = _free_load_samples(ds, s)   # quaternion order, gravity sign, joint degrees: before any fit
    with stage("free loads", timings, cpu):
        try:
            res = fit_free_loads(ds, s.free_load)
        except SolverError as exc:   # a convention the checks before could not tell can leave IPOPT lost: try them
            raise_free_load_causes(ds, samples, exc)
            raise
    with stage("plausibility of the fit", timings, cpu):
        notes += check_free_load_fits(ds, res.legs, samples)
    notes += res.identifiability()
    cal = free_load_calibration(res, ds.robot, ds.hanging)
    diagnosis = None
    if s.diagnose.enabled:
        from .diagnose.free import diagnose_free

        with stage("diagnosis", timings, cpu):
            diagnosis = optional("the sim-to-real gap diagnosis", notes, lambda: diagnose_free(ds, res, s.diagnose))
    return CalibrationRun(s, ds, cal, diagnosis=diagnosis, timings=timings, cpu_timings=cpu, notes=tuple(notes), free_loads=res)


def calibrate(dataset: Dataset, settings: CalibrationSettings | None = None, *,
              offsets_only: Calibration | None = None) -> CalibrationRun:
    """Calibrate ``dataset`` (interchange format, ``data.read_dataset``) with ``settings`` (module docstring).

    Builds every part first and the frozen :class:`CalibrationRun` from them (the diagnosis reads the
    run as calibrated; the run returned holds it too). Raises :class:`~ftcal_nlp.core.errors.DataFormatError`
    for data that cannot calibrate (no standing recording, no opposite hanging pair, ...) and
    :class:`~ftcal_nlp.core.errors.SolverError` when a solver of the chosen method fails (a failing baseline
    is logged and recorded in ``notes``).
    """
    s = CalibrationSettings() if settings is None else settings
    ds, robot = dataset, dataset.robot
    timings: dict[str, float] = {}
    cpu: dict[str, float] = {}
    notes: list[str] = []
    if ds.free_load_legs:
        if offsets_only is not None:
            raise DataFormatError(f"{ds.manifest or 'dataset'}: offsets-only re-estimation needs standing poses of a hexapod; "
                                  f"transducers {list(ds.free_load_legs)} carry free loads (calibrate them anew)")
        return _calibrate_free_loads(ds, s, timings, cpu, notes)
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
    joint = joint_covariance(hang, standing)
    cal = _with_joint_se(cal, joint)
    with stage("sensor noise", timings, cpu):
        noise = _sensor_noise(ds, s, notes)
    uncertainty = CalibrationCovariance.from_results(joint, noise)
    if noise is not None:
        cal = replace(cal, meta={**cal.meta, "sensor_noise": noise.to_json_dict()})
    corrected: dict[str, pd.DataFrame] = {}
    tracked: dict[str, TrackedOffsets] = {}
    with stage("correct walking", timings, cpu):
        for rec in ds.walking:
            c = correct_recording_full(cal, rec, uncertainty, s.correct)
            corrected[rec.name] = c.frame
            if c.tracking is not None:
                tracked[rec.name] = c.tracking
            log.info("corrected %s: %d rows", rec.name, len(c.frame))

    def built(diagnosis: DiagnosisResult | None = None) -> CalibrationRun:
        return CalibrationRun(s, ds, cal, hang, hang_base, poses, selection, standing, standing_base, diagnosis,
                              corrected=corrected, tracked_offsets=tracked, uncertainty=uncertainty,
                              timings=dict(timings), cpu_timings=dict(cpu), notes=tuple(notes))

    if not s.diagnose.enabled:
        return built()
    calibrated = built()  # what the diagnosis reads: the run as calibrated
    with stage("diagnosis", timings, cpu):
        diagnosis = optional("the sim-to-real gap diagnosis", notes, lambda: diagnose_run(calibrated))
    return built(diagnosis)  # the same parts with the diagnosis, its stage time and notes
