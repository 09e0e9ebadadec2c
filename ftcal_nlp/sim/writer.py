"""Write a simulated session in the interchange format (``shared/DATA_FORMAT.md``), with its truth.

Files, as in ``shared/sample``: ``dataset.toml``, ``robot.toml``, one file per
recording (CSV or Parquet per kind), ``truth.json`` (layout of the sample's) and
``walk_truth.csv`` (columns of ``OUTPUT_FORMAT.md``'s corrected recordings plus
totals). Tables are built by ``data.recording_to_frame`` so that the reader's
columns and the writer's cannot drift apart.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..core.data import recording_to_frame, write_robot
from ..core.errors import OutputExistsError
from .simulate import SimResult

_FORMATS = ("csv", "parquet")


def _write_table(df, path: Path) -> None:
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    else:
        df.to_csv(path, index=False, float_format="%.10g")


def simulation_files(res: SimResult, *, fmt_hanging: str = "csv", fmt_standing: str = "parquet",
                     fmt_walking: str = "csv") -> list[str]:
    """The names :func:`write_simulation` writes into its folder (same defaults)."""
    fmts = {"hanging": fmt_hanging, "standing": fmt_standing, "walking": fmt_walking}
    return ["dataset.toml", "robot.toml", *(f"{r.name}.{fmts[r.kind]}" for r in res.dataset.recordings),
            "truth.json", "walk_truth.csv"]


def write_simulation(
    res: SimResult,
    folder: str | Path,
    *,
    fmt_hanging: str = "csv",
    fmt_standing: str = "parquet",
    fmt_walking: str = "csv",
    overwrite: bool = False,
) -> Path:
    """Write ``res`` into ``folder``; returns the manifest path.

    An existing ``dataset.toml`` is not replaced unless ``overwrite`` is true
    (nothing is written in that case).
    """
    import tomli_w

    fmts = {"hanging": fmt_hanging, "standing": fmt_standing, "walking": fmt_walking}
    for kind, f in fmts.items():
        if f not in _FORMATS:
            raise ValueError(f"write_simulation: fmt_{kind} must be one of {_FORMATS}, got {f!r}")
    folder = Path(folder)
    manifest = folder / "dataset.toml"
    if manifest.exists() and not overwrite:
        raise OutputExistsError(f"{manifest} exists; pass overwrite=True to replace it", path=manifest)
    folder.mkdir(parents=True, exist_ok=True)
    ds = res.dataset
    write_robot(ds.robot, folder / "robot.toml")
    entries = []
    for rec in ds.recordings:
        fname = f"{rec.name}.{fmts[rec.kind]}"
        _write_table(recording_to_frame(rec, ds.robot.legs), folder / fname)
        e: dict = {"file": fname, "kind": rec.kind}
        if rec.gravity_body is not None:
            e["gravity_body"] = [float(x) for x in rec.gravity_body]
        entries.append(e)
    (folder / "truth.json").write_text(json.dumps(res.truth_json_dict(), indent=1))
    _write_table(res.walk_truth, folder / "walk_truth.csv")
    manifest.write_bytes(tomli_w.dumps({"robot": "robot.toml", "recording": entries}).encode())
    return manifest
