"""``correct`` for hexapod legs (the ``leg_com_curve`` load): per foot the ground contact wrench.

Each foot's ground wrench is the reading less the offset less the leg's weight
wrench (report eq. 3), moved to the heading frame about the robot's CoM at that
instant (``OUTPUT_FORMAT.md``, corrected recordings); see :mod:`ftcal_nlp.core.physics`.
Rows without a motion-capture orientation cannot be put in the heading frame and
are dropped with a count in the log. Beside the contract's columns: standard
errors ``{leg}_{c}_se`` / ``total_{c}_se`` (the calibration's covariance, from the
file its ``meta.covariance_file`` names, and the sensor noise in its
``meta.sensor_noise``; ``uncertainty.py``) and each foot's contact state
``{leg}_contact`` (1 stance, 0 swing; ``contact.py``). ``--track-offsets``
re-estimates every leg's offsets over the recording from its swing phases
(``tracking.py``), corrects with them, logs each leg's change since calibration
and its significance, and writes them beside the output (``<out>_offsets.csv``).
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.calibration import Calibration
from ..core.checks import SensorFault, check_calibration, check_recording_to_correct, with_fault_columns
from ..core.csvout import write_csv
from ..core.data import WRENCH_COMPONENTS, DataFormatError, Recording, legs_in_frame, read_table, recording_from_frame
from ..effects.correction import correct_for_effect
from ..core.errors import ConfigError
from ..core.geometry import quat_to_rotation
from ..core.robot import Robot, Transducer
from ..core.settings import CorrectSettings
from .tracking import TrackedOffsets, log_changes
from ..estimate.uncertainty import CalibrationCovariance
from .wrenches import Correction, correct_arrays, noise_of

log = logging.getLogger(__name__)


def robot_from_calibration(cal: Calibration) -> Robot:
    """A robot description carrying the calibration's legs, mass and (estimated) transducer poses."""
    tr = {k: Transducer(k, l.position_from_com_m, l.rotation_to_body) for k, l in cal.legs.items()}
    return Robot("calibrated", cal.mass_kg, cal.g, cal.leg_names, tr)


def correct_recording(cal: Calibration, rec: Recording, cov: CalibrationCovariance | None = None,
                      settings: CorrectSettings = CorrectSettings()) -> pd.DataFrame:
    """Per-foot ground contact wrenches and their total, in the columns of ``OUTPUT_FORMAT.md``, then their
    standard errors and each foot's contact state (module docstring).

    Rows whose orientation is NaN are dropped (counted in the log).
    """
    return correct_recording_full(cal, rec, cov, settings).frame


def correct_recording_full(cal: Calibration, rec: Recording, cov: CalibrationCovariance | None = None,
                           settings: CorrectSettings = CorrectSettings()) -> Correction:
    """:func:`correct_recording` with everything it found (``wrenches.Correction``: uncertainty parts,
    contact state, tracked offsets)."""
    if rec.quat is None:
        raise DataFormatError(f"{rec.path or rec.name}: correction needs the orientation columns qw, qx, qy, qz")
    check_calibration(cal, "the calibration", tuple(rec.wrench))
    faults = check_recording_to_correct(rec, cal, robot_from_calibration(cal))   # conventions: errors; faults: below
    ok = np.all(np.isfinite(rec.quat), axis=1)
    if not ok.all():
        log.warning("%s: dropped %d of %d rows without motion-capture orientation", rec.path or rec.name, int((~ok).sum()), rec.n)
        rec = rec.select(ok)
    legs = cal.leg_names
    # a calibration written with the diagnosis' named effect corrects the readings for it first
    src = str(rec.path or rec.name)
    assert rec.quat is not None   # checked above; select keeps it
    w_raw, phi, R_raw = rec.wrench_array(legs), rec.phi_array(legs), quat_to_rotation(rec.quat)
    w, R, w_cov = correct_for_effect(cal, w_raw, phi, R_raw, rec.t, source=src)
    # ... and its parameters' uncertainty enters the se like reading noise
    try:
        res = correct_arrays(cal, rec.t, w, phi, R, cov, settings, w_cov)
    except DataFormatError as exc:  # the tracking's refusals name no file
        raise DataFormatError(f"{src}: {'offsets tracked (--track-offsets): ' if settings.track_offsets else ''}{exc}") from exc
    return flag_faults(res, faults, ok)


def flag_faults(res: Correction, faults: list[SensorFault], kept: np.ndarray) -> Correction:
    """A warning per sensor fault (leg, columns, rows of the recording) and a column ``{leg}_fault`` (1 on its rows)
    after the others; ``kept`` (N,) the recording's rows the correction kept. No fault: the table as it was."""
    return replace(res, frame=with_fault_columns(res.frame, faults, kept)) if faults else res


def load_covariance(cal: Calibration, calibration_path: str | Path, *, warn: bool = True) -> CalibrationCovariance | None:
    """The covariance file named in ``cal.meta["covariance_file"]`` (relative to the calibration file) with the
    sensor noise of ``cal.meta["sensor_noise"]``; None (logged) when the calibration names none."""
    name = cal.meta.get("covariance_file") if isinstance(cal.meta, dict) else None
    if name is None:
        if warn:
            log.warning("%s names no covariance file (meta.covariance_file): standard errors from the sensor noise alone%s",
                        calibration_path, "" if noise_of(cal) is not None else " (none stored either: se columns NaN)")
        return None
    path = Path(calibration_path).parent / name
    if not path.is_file():
        raise DataFormatError(f"{path}: calibration covariance file not found; {calibration_path} names it in meta.covariance_file "
                              f"(the run writes it beside calibration.json): expected it beside the calibration (copy both "
                              "together) for the se columns", path=path)
    return CalibrationCovariance.load(path, noise_of(cal))


def correct_file(cal: Calibration, path: str | Path, cov: CalibrationCovariance | None = None,
                 settings: CorrectSettings = CorrectSettings()) -> pd.DataFrame:
    """Read a CSV/Parquet recording in the interchange format and correct it (the output table)."""
    return correct_file_full(cal, path, cov, settings).frame


def correct_file_full(cal: Calibration, path: str | Path, cov: CalibrationCovariance | None = None,
                      settings: CorrectSettings = CorrectSettings()) -> Correction:
    """:func:`correct_file` with everything the correction found (``wrenches.Correction``)."""
    path = Path(path)
    return correct_table_full(cal, read_table(path), path, cov, settings)


def correct_table_full(cal: Calibration, df: pd.DataFrame, path: Path, cov: CalibrationCovariance | None = None,
                       settings: CorrectSettings = CorrectSettings()) -> Correction:
    """:func:`correct_file_full` of the table ``df`` read from ``path``."""
    uncovered = [k for k in legs_in_frame(df) if k not in cal.legs]
    if uncovered:  # a total without those legs would be silently wrong
        raise DataFormatError(f"{path}: columns of leg(s) {uncovered} ({uncovered[0]}_fx ...) but the calibration covers only "
                              f"{list(cal.leg_names)}; expected a calibration of every leg of the recording")
    rec = recording_from_frame(df, robot_from_calibration(cal), name=path.stem, kind="walking", source=str(path), path=path)
    return correct_recording_full(cal, rec, cov, settings)


def offsets_frame(t: np.ndarray, tr: TrackedOffsets) -> pd.DataFrame:
    """Tracked offsets and their se per sample: ``t``, ``{leg}_w_o_{c}``, ``{leg}_w_o_{c}_se`` (ft_k, N and N*m)."""
    off, cov = tr.at(t)
    se = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    cols = {"t": t}
    for i, k in enumerate(tr.legs):
        cols.update({f"{k}_w_o_{c}": off[:, i, j] for j, c in enumerate(WRENCH_COMPONENTS)})
        cols.update({f"{k}_w_o_{c}_se": se[:, i, j] for j, c in enumerate(WRENCH_COMPONENTS)})
    return pd.DataFrame(cols)


# ---------------------------------------------------------------------------------------------- the command's hooks
# (the same names in ``free.py``; ``correct/__init__.py`` calls them)

def wrote(cal: Calibration) -> str:
    """What the command's log says it wrote (the table's rows say it)."""
    return ""


def check_options(args: argparse.Namespace) -> None:
    """The options that apply to free loads only are refused."""
    if args.gravity_body is not None:
        raise ConfigError("--gravity-body applies to free-load calibrations (a fixed base's gravity); "
                          f"{args.calibration} holds hexapod legs, whose recordings carry qw..qz", key="--gravity-body")


def prepare(cal: Calibration, args: argparse.Namespace) -> CalibrationCovariance | None:
    """Before the recording is read: the calibration checked, its covariance file (an error when it names one that
    is not there)."""
    check_calibration(cal, args.calibration)
    return load_covariance(cal, args.calibration, warn=False)


def correct_table(cal: Calibration, df: pd.DataFrame, args: argparse.Namespace,
                  cov: CalibrationCovariance | None) -> tuple[pd.DataFrame, TrackedOffsets | None]:
    """The corrected table of the recording ``df`` and the tracked offsets (``--track-offsets``; else None)."""
    res = correct_table_full(cal, df, Path(args.recording), cov, CorrectSettings(track_offsets=args.track_offsets))
    # the missing-covariance warning comes after the correction succeeded: a failure is one line
    if cal.meta.get("covariance_file") is None:
        load_covariance(cal, args.calibration)   # logs what the se then rest on
    return res.frame, res.tracking


def write_extras(cal: Calibration, df: pd.DataFrame, tracking: TrackedOffsets | None, args: argparse.Namespace,
                 off_out: Path | None, bag: Path | None) -> None:
    """Beside the table: the tracked offsets (``<out>_offsets.csv``, their changes printed) and the ROS 2 bag."""
    if tracking is not None:
        assert off_out is not None   # --track-offsets gives both (correct/__init__.py)
        write_csv(offsets_frame(df["t"].to_numpy(), tracking), off_out)
        log.info("wrote %s (tracked offsets)", off_out)
        for line in log_changes(tracking):
            if not args.quiet:
                print(line)
    if bag is not None:
        from ..ros.bagio import write_ground_wrench_bag

        legs = cal.leg_names + ("total",)
        wr = {k: df[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy() for k in legs}
        write_ground_wrench_bag(bag, df["t"].to_numpy(), wr, overwrite=args.force)
        log.info("wrote bag %s", args.bag)
