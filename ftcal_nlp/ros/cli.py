"""Command line: ``python -m ftcal_nlp.ingest MAP.toml -o DATASET_DIR``.

Reads the map's bags, writes the interchange dataset, then reads it back with
:func:`ftcal_nlp.data.read_dataset` (what ``ftcal_nlp.run`` does) so that a
dataset the run would reject is reported here. Exit status 2 on a bad map,
bag or dataset, with the message naming the file and key.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Sequence

from ..data import DataFormatError, read_dataset
from .ingest import ingest, write_ingested


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ftcal_nlp.ingest", description="ROS bags -> ftcal_nlp interchange dataset")
    ap.add_argument("map", help="ingest map (TOML); see ftcal_nlp/ros/mapfile.py and problems/ros_map_example.toml")
    ap.add_argument("-o", "--output", required=True, help="dataset folder to write (dataset.toml, robot.toml, recordings)")
    ap.add_argument("--format", choices=("parquet", "csv"), default=None, help="recording file type (default: the map's 'format', else parquet)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing dataset.toml in the output folder")
    ap.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors, no progress bar")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar (it is shown only on a terminal anyway)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        result = ingest(args.map, progress=False if (args.quiet or args.no_progress) else None)
        manifest = write_ingested(result, args.output, fmt=args.format, overwrite=args.overwrite)
        ds = read_dataset(manifest)
    except (DataFormatError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    n = sum(r.n for r in ds.recordings)
    print(f"wrote {manifest}: {len(ds.recordings)} recording(s), {n} rows, session epoch {result.epoch_ns} ns")
    return 0
