"""The ingest command: ``python -m ftcal_nlp.ingest MAP.toml -o DATASET_DIR`` (ROS bags -> interchange dataset; needs
the ``ros`` extra: ``rosbags``, ``yourdfpy``).

Reads the map's bags (an ``[arm]`` map: :mod:`ftcal_nlp.ros.arm`; any other: :mod:`ftcal_nlp.ros.mapfile`), writes the interchange
dataset (with a URDF: copied beside ``robot.toml``), then reads it back with
:func:`ftcal_nlp.core.data.read_dataset` (what ``ftcal_nlp.run`` does) so that a
dataset the run would reject is reported here. Exit status 2 on a bad map,
bag or dataset, with the message naming the file and key. The files it writes
over must be ones the tool wrote (the folder's ``.ftcal_manifest.json`` lists
them, ``outdir.guard_files``), and only with ``--force``; anything else in the
folder (the bags, a user's notes) is left as it is.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

from .core.data import read_dataset
from .core.outdir import check_files_apart, output_path, robot_inputs, write_guarded
from .ros.ingest import ingest, write_ingested


def main(argv: Sequence[str] | None = None, prog: str | None = None) -> int:
    from .cli import add_common, guarded, parse, setup

    ap = argparse.ArgumentParser(prog=prog or "python -m ftcal_nlp.ingest", description="ROS bags -> ftcal_nlp interchange dataset")
    ap.add_argument("map", help="ingest map (TOML); see ftcal_nlp/ros/mapfile.py and problems/ros_map_example.toml; "
                                "an arm's map (an [arm] table: JointState + WrenchStamped + URDF): ftcal_nlp/ros/arm.py")
    add_common(ap, output_help="dataset folder to write (dataset.toml, robot.toml, recordings)", output_required=True,
               old_force=("--overwrite",), force_help="replace an existing dataset.toml in the output folder")
    ap.add_argument("--format", choices=("parquet", "csv"), default=None, help="recording file type (default: the map's 'format', else parquet)")
    args = parse(ap, argv)
    setup(args)
    return guarded(lambda: _main(args))


def map_inputs(path: Path) -> dict[str, Path]:
    """What an ingest map names (parsed as TOML only): the map, its bags, its URDF or robot.toml (and that one's URDF)."""
    import tomllib

    try:
        d = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        d = {}
    out: dict[str, Path] = {"ingest map": path}
    if isinstance(d.get("urdf"), str):
        out["URDF"] = path.parent / d["urdf"]         # a hexapod's or an [arm] map's
    if isinstance(d.get("robot"), str):
        out.update(robot_inputs(path.parent / d["robot"]))
    recs = d.get("recording")
    for r in recs if isinstance(recs, list) else []:
        if isinstance(r, dict) and isinstance(r.get("bag"), str):
            out[f"bag {r['bag']}"] = path.parent / r["bag"]
    return out


def _main(args) -> int:
    result = ingest(args.map, progress=False if (args.quiet or args.no_progress) else None)
    fmt = args.format or result.map.fmt
    names = ["dataset.toml", "robot.toml", *(f"{rec.name}.{fmt}" for rec in result.dataset.recordings)]
    if result.dataset.robot.urdf is not None:     # section 5: the URDF is copied beside robot.toml
        names.append(result.dataset.robot.urdf.name)
    check_files_apart(args.output, names, map_inputs(Path(args.map)))
    out = output_path(args.output)
    manifest = write_guarded(out, names, lambda: write_ingested(result, out, fmt=args.format, overwrite=True), force=args.force)
    ds = read_dataset(manifest)
    n = sum(r.n for r in ds.recordings)
    if not args.quiet:
        print(f"wrote {manifest}: {len(ds.recordings)} recording(s), {n} rows, session epoch {result.epoch_ns} ns")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
