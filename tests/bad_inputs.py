"""Broken copies of the shared sample (issue 14): each case is one mutation a user could make.

``broken_sample(folder, case)`` copies the sample into ``folder`` (same files and formats)
and applies the mutation of ``case`` (a key of :data:`CASES`) with pandas; it returns the
manifest. The tests in ``test_bad_input.py`` use them.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv

Frames = dict[str, pd.DataFrame]   # file name -> table
LEGS = ("FL", "ML", "HL", "FR", "MR", "HR")
FORCES = [f"{k}_{c}" for k in LEGS for c in ("fx", "fy", "fz")]
READINGS = [f"{k}_{c}" for k in LEGS for c in ("fx", "fy", "fz", "tx", "ty", "tz")]
PHIS = [f"{k}_phi" for k in LEGS]


def read_frame(path: Path) -> pd.DataFrame:
    return pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)


def write_frame(df: pd.DataFrame, path: Path) -> None:
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    elif any(df.dtypes == object):  # a text cell: pandas writes mixed columns
        df.to_csv(path, index=False)
    else:  # pyarrow's writer: full precision, ~10x faster than pandas'
        pacsv.write_csv(pa.Table.from_pandas(df, preserve_index=False), path)


def _every(cols: list[str], fn: Callable[[pd.DataFrame, list[str]], None]) -> Callable[[Path, Frames], None]:
    def mutate(folder: Path, frames: Frames) -> None:
        for df in frames.values():
            present = [c for c in cols if c in df.columns]
            fn(df, present)
    return mutate


def _scale(df, cols, f):
    df[cols] = df[cols] * f


def _xyzw(folder: Path, frames: Frames) -> None:
    for df in frames.values():
        if "qw" in df.columns:  # x, y, z, w stored under the headers qw, qx, qy, qz
            df[["qw", "qx", "qy", "qz"]] = df[["qx", "qy", "qz", "qw"]].to_numpy()


def _robot_edit(old: str, new: str) -> Callable[[Path, Frames], None]:
    def mutate(folder: Path, frames: Frames) -> None:
        p = folder / "robot.toml"
        p.write_text(p.read_text().replace(old, new))
    return mutate


def _manifest_drop(*files: str) -> Callable[[Path, Frames], None]:
    def mutate(folder: Path, frames: Frames) -> None:
        p = folder / "dataset.toml"
        blocks = p.read_text().split("\n[[recording]]\n")
        keep = [b for b in blocks if not any(f'file = "{f}"' in b for f in files)]
        p.write_text("\n[[recording]]\n".join(keep))
    return mutate


def _standing(fn: Callable[[pd.DataFrame], None]) -> Callable[[Path, Frames], None]:
    def mutate(folder: Path, frames: Frames) -> None:
        fn(frames["standing.parquet"])
    return mutate


def _never_still(df: pd.DataFrame) -> None:
    # every shaft creeps at 0.2 rad/s the whole time: no pose is ever static
    df[PHIS] = df[PHIS].to_numpy() + 0.2 * (df["t"].to_numpy() - df["t"].iloc[0])[:, None]


def _text_cell(folder: Path, frames: Frames) -> None:
    df = frames["hang_xpos.csv"]
    df["ML_fy"] = df["ML_fy"].astype(object)
    df.loc[123, "ML_fy"] = "n/a (saturated)"


CASES: dict[str, Callable[[Path, Frames], None]] = {
    "forces_kN": _every(FORCES, lambda df, c: _scale(df, c, 1e-3)),
    "negated": _every(READINGS, lambda df, c: _scale(df, c, -1.0)),
    "quat_xyzw": _xyzw,
    "phi_degrees": _every(PHIS, lambda df, c: _scale(df, c, 180 / np.pi)),
    "mass_grams": _robot_edit("mass_kg = 8.18", "mass_kg = 8180"),
    "quat_all_nan": _standing(lambda df: df.__setitem__(["qw", "qx", "qy", "qz"], np.nan)),
    "never_still": _standing(_never_still),
    "text_cell": _text_cell,
    "one_pair": _manifest_drop("hang_zpos.parquet", "hang_zneg.parquet"),
    "nan_column": lambda folder, frames: frames["hang_zneg.parquet"].__setitem__("HL_tz", np.nan),
}


def broken_sample(sample: Path, folder: Path, case: str | None = None) -> Path:
    """A copy of ``sample`` in ``folder`` with the mutation of ``case`` (None: an intact copy); returns the manifest."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("dataset.toml", "robot.toml"):
        shutil.copy(sample / name, folder / name)
    files = [p for p in sample.iterdir() if p.suffix in (".csv", ".parquet") and p.name != "walk_truth.csv"]
    frames = {p.name: read_frame(p) for p in files}
    before = {name: df.copy() for name, df in frames.items()}
    if case is not None:
        CASES[case](folder, frames)
    for name, df in frames.items():
        if df.equals(before[name]):
            shutil.copy(sample / name, folder / name)
        else:
            write_frame(df, folder / name)
    return folder / "dataset.toml"


def _few_rows(folder: Path, frames: Frames) -> None:
    for name in ("hang_xpos.csv", "hang_xneg.csv", "hang_zpos.parquet", "hang_zneg.parquet"):
        df = frames[name]
        frames[name] = df.iloc[:: len(df) // 60].reset_index(drop=True)  # 60 rows of 4 turns: 1.3 s apart


CASES["few_hanging_rows"] = _few_rows


CASES["right_legs_frame"] = _robot_edit("rotation = [[-1, -0, 0], [0, -1, 0], [0, 0, 1]]", "rotation = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]")
CASES["torques_kNm"] = _every([f"{k}_{c}" for k in LEGS for c in ("tx", "ty", "tz")], lambda df, c: _scale(df, c, 1e-3))
CASES["torques_negated"] = _every([f"{k}_{c}" for k in LEGS for c in ("tx", "ty", "tz")], lambda df, c: _scale(df, c, -1.0))
