"""Turn any recording into contact wrenches with a finished calibration: per foot (legged robot) or per transducer (free load).

``python -m ftcal_nlp.correct calibration.json recording.csv -o out.csv [--bag out_bag] [--track-offsets]``
(free loads: ``[--gravity-body X Y Z]`` for a fixed base's recording without orientation columns)

One command for every load. The flow is written here once: the output's rules (``outdir.py``: a CSV, never an
input; the offsets file and the bag likewise), the calibration read and checked by the one reader
(:func:`ftcal_nlp.correct.calibrated.read_calibration` over ``calibration.read_calibration_json``), the recording read
(``data.read_table``), corrected, and written to the last bit (``csvout.py``). What differs by load is a module of
the same functions, chosen by what the reader gave:

* ``legs.py``: hexapod legs (a :class:`~ftcal_nlp.core.calibration.Calibration`): per foot the ground contact wrench in the
  heading frame about the robot's CoM, its se, the contact state, ``--track-offsets`` and ``--bag``;
* ``free.py``: free loads (a rigid payload, URDF links below a sensor; per transducer a calibrated load of
  ``loads.calibrated``): the contact wrench in each ft frame and its se, the fixed base's ``--gravity-body``;
  ``recording.py`` reads and checks their recording.

Each has ``check_options`` (the options of the other kind refused), ``prepare`` (what comes before the recording is
read), ``correct_table`` (the corrected table, and tracked offsets), ``write_extras`` (beside the table) and
``wrote`` (the log's words). The named effects of a ``calibration_with_effect.json`` are corrected first by the one
effect correction (``effects/correction.py``).
"""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

from ..core.calibration import Calibration
from ..core.csvout import write_csv
from ..core.data import read_table
from ..core.errors import OutputError
from .calibrated import read_calibration
from . import free, legs
from .free import contact_frame, contact_wrench
from .legs import (correct_file, correct_file_full, correct_recording, correct_recording_full, flag_faults, load_covariance,
                   offsets_frame, robot_from_calibration)

log = logging.getLogger(__name__)

__all__ = ["main", "read_calibration", "correct_recording", "correct_recording_full", "correct_file", "correct_file_full",
           "robot_from_calibration", "load_covariance", "offsets_frame", "flag_faults", "contact_frame", "contact_wrench",
           "kind_of"]


def kind_of(cal):
    """The module of the load-specific functions for a calibration as :func:`read_calibration` gives it."""
    return legs if isinstance(cal, Calibration) else free


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    from ..cli import add_common, guarded, parse, setup

    ap = argparse.ArgumentParser(prog=prog or "python -m ftcal_nlp.correct", description=__doc__.splitlines()[0],
                                 epilog="The calibration's covariance file (meta.covariance_file, calibration_cov.npz written "
                                        "beside calibration.json by a run) gives the se columns; without it the se rest on the "
                                        "sensor noise alone (logged).")
    ap.add_argument("calibration", help="calibration.json written by a run")
    ap.add_argument("recording", help="recording in the interchange format (CSV or Parquet)")
    add_common(ap, output_help="output CSV of ground contact wrenches", output_required=True, old_force=("--overwrite",))
    ap.add_argument("--bag", help="also write a ROS 2 MCAP bag with one WrenchStamped topic per foot")
    ap.add_argument("--track-offsets", action="store_true",
                    help="re-estimate each leg's offsets over the recording from its swing phases and correct with them")
    ap.add_argument("--gravity-body", nargs=3, type=float, metavar=("X", "Y", "Z"),
                    help="free loads on a fixed base (an arm logging joints only): gravity's direction in B for a recording "
                         "without qw..qz / gx..gz (default: the calibration's gravity_body, kept by the run)")
    args = parse(ap, argv)
    setup(args)
    return guarded(lambda: _main(args), extra=(ValueError,))


def _main(args) -> int:
    from ..core.outdir import calibration_inputs, check_apart, check_file_output, output_path

    given = Path(os.path.expanduser(args.output))
    cal_path = Path(os.path.expanduser(args.calibration))
    inputs = {"recording": Path(os.path.expanduser(args.recording)), **calibration_inputs(cal_path)}
    # the output's format is CSV (every value to the last bit, csvout.py): a .parquet name is refused, not given CSV bytes
    out = check_file_output(given, inputs, force=args.force, suffixes=(".csv",))
    off_out = check_file_output(given.with_name(given.stem + "_offsets.csv"), inputs, force=args.force) if args.track_offsets else None
    bag = None
    if args.bag:
        bag = Path(os.path.expanduser(args.bag))
        check_apart(bag, inputs)   # a ROS 2 bag is a folder, replaced whole with --force
        if bag.exists() and not args.force:
            raise OutputError(f"{bag} exists; pass --force to replace it", path=bag)
        bag = output_path(bag)
    args.calibration, args.recording = str(cal_path), str(inputs["recording"])

    cal = read_calibration(args.calibration)   # checked as read; free loads (DATA_FORMAT.md section 5) or legs
    kind = kind_of(cal)
    kind.check_options(args)
    prepared = kind.prepare(cal, args)
    df, tracking = kind.correct_table(cal, read_table(Path(args.recording)), args, prepared)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_csv(df, out)  # t and every value to the last bit, whatever the epoch (csvout.py)
    log.info("wrote %s (%d rows)%s", out, len(df), kind.wrote(cal))
    kind.write_extras(cal, df, tracking, args, off_out, bag)
    return 0
