"""Turn any recording into per-foot ground contact wrenches with a finished calibration.

``python -m ftcal_nlp.correct calibration.json recording.csv -o out.csv [--bag out_bag]``

Each foot's ground wrench is the reading less the offset less the leg's weight
wrench (report eq. 3), moved to the heading frame about the robot's CoM at that
instant (``OUTPUT_FORMAT.md``, corrected recordings); see :mod:`ftcal_nlp.physics`.
Rows without a motion-capture orientation cannot be put in the heading frame and
are dropped with a count in the log.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from .calibration import Calibration
from .data import WRENCH_COMPONENTS, DataFormatError, Recording, ground_wrench_frame, legs_in_frame, read_table, recording_from_frame
from .geometry import quat_to_rotation
from .physics import ground_wrenches
from .robot import Robot, Transducer

log = logging.getLogger(__name__)


def robot_from_calibration(cal: Calibration) -> Robot:
    """A robot description carrying the calibration's legs, mass and (estimated) transducer poses."""
    tr = {k: Transducer(k, l.position_from_com_m, l.rotation_to_body) for k, l in cal.legs.items()}
    return Robot("calibrated", cal.mass_kg, cal.g, cal.leg_names, tr)


def correct_recording(cal: Calibration, rec: Recording) -> pd.DataFrame:
    """Per-foot ground contact wrenches and their total, in the columns of ``OUTPUT_FORMAT.md``.

    Rows whose orientation is NaN are dropped (counted in the log).
    """
    if rec.quat is None:
        raise DataFormatError(f"{rec.path or rec.name}: correction needs the orientation columns qw, qx, qy, qz")
    ok = np.all(np.isfinite(rec.quat), axis=1)
    if not ok.all():
        log.warning("%s: dropped %d of %d rows without motion-capture orientation", rec.path or rec.name, int((~ok).sum()), rec.n)
        rec = rec.select(ok)
    legs = cal.leg_names
    gw = ground_wrenches(rec.wrench_array(legs), rec.phi_array(legs), quat_to_rotation(rec.quat), cal)
    return ground_wrench_frame(rec.t, gw, legs)


def correct_file(cal: Calibration, path: str | Path) -> pd.DataFrame:
    """Read a CSV/Parquet recording in the interchange format and correct it."""
    path = Path(path)
    df = read_table(path)
    uncovered = [k for k in legs_in_frame(df) if k not in cal.legs]
    if uncovered:  # a total without those legs would be silently wrong
        raise DataFormatError(f"{path}: columns of leg(s) {uncovered} ({uncovered[0]}_fx ...) but the calibration covers only "
                              f"{list(cal.leg_names)}; expected a calibration of every leg of the recording")
    rec = recording_from_frame(df, robot_from_calibration(cal), name=path.stem, kind="walking", source=str(path), path=path)
    return correct_recording(cal, rec)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ftcal_nlp.correct", description=__doc__.splitlines()[0])
    ap.add_argument("calibration", help="calibration.json written by a run")
    ap.add_argument("recording", help="recording in the interchange format (CSV or Parquet)")
    ap.add_argument("-o", "--output", required=True, help="output CSV of ground contact wrenches")
    ap.add_argument("--bag", help="also write a ROS 2 MCAP bag with one WrenchStamped topic per foot")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    out = Path(args.output)
    for target in [out] + ([Path(args.bag)] if args.bag else []):
        if target.exists() and not args.force:
            print(f"error: {target} exists; pass --force to overwrite", file=sys.stderr)
            return 2
    try:
        cal = Calibration.load(args.calibration)
        df = correct_file(cal, args.recording)
    except (DataFormatError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(out, index=False, float_format="%.7g")
    log.info("wrote %s (%d rows)", out, len(df))
    if args.bag:
        from .ros.bagio import write_ground_wrench_bag

        legs = cal.leg_names + ("total",)
        wr = {k: df[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy() for k in legs}
        write_ground_wrench_bag(args.bag, df["t"].to_numpy(), wr, overwrite=args.force)
        log.info("wrote bag %s", args.bag)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
