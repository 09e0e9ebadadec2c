"""Interchange format of ``shared/DATA_FORMAT.md``: read, validate, write.

A dataset is a ``dataset.toml`` manifest, a ``robot.toml`` and one CSV or Parquet
file per recording. Conventions (section 1 of the format page): a reading is the
wrench the leg exerts on the transducer, in ``ft_k`` about its origin, plus the
transducer offset ``w_o`` and noise (report eq. 1); SI units; ``qw..qz`` map
body vectors to world vectors; ``{leg}_phi`` is unwrapped, 0 = leg straight down.

Only this module and the command-line modules touch files.
"""

from __future__ import annotations

import logging
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable

import numpy as np
import pandas as pd

from .errors import DataFormatError
from .geometry import is_rotation
from .robot import Robot, Transducer

log = logging.getLogger(__name__)

WRENCH_COMPONENTS = ("fx", "fy", "fz", "tx", "ty", "tz")
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")
KINDS = ("hanging", "standing", "walking")

# A torque column in N*mm or a force column in mN is ~1000x too large. Forces on a
# transducer cannot exceed a few robot weights; torques in N*m cannot exceed the
# force times a lever arm of a few metres.
_MAX_FORCE_IN_WEIGHTS = 20.0
_MAX_LEVER_ARM_M = 3.0
_MAX_POSITION_M = 5.0




@dataclass(frozen=True)
class Recording:
    """One recording in the interchange format.

    ``t``: (N,) s, strictly increasing, session clock. ``phi[leg]``: (N,) rad,
    unwrapped shaft angle. ``wrench[leg]``: (N, 6) raw reading in ft_leg, N and
    N*m. ``quat``: (N, 4) ``[qw, qx, qy, qz]`` of B in the world, NaN where the
    motion capture was lost, or None (hanging). ``gravity_body``: (3,) nominal
    gravity direction in B for hanging recordings. ``n_dropped``: rows with NaN
    readings that were dropped at load.
    """

    name: str
    kind: str
    t: np.ndarray
    phi: dict[str, np.ndarray]
    wrench: dict[str, np.ndarray]
    quat: np.ndarray | None = None
    gravity_body: np.ndarray | None = None
    path: Path | None = None
    n_dropped: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def legs(self) -> tuple[str, ...]:
        return tuple(self.wrench)

    def wrench_array(self, legs: Iterable[str] | None = None) -> np.ndarray:
        """Readings stacked as (N, K, 6) in the order of ``legs``."""
        legs = self.legs if legs is None else tuple(legs)
        return np.stack([self.wrench[k] for k in legs], axis=1)

    def phi_array(self, legs: Iterable[str] | None = None) -> np.ndarray:
        """Shaft angles stacked as (N, K)."""
        legs = self.legs if legs is None else tuple(legs)
        return np.stack([self.phi[k] for k in legs], axis=1)

    def select(self, mask: np.ndarray) -> "Recording":
        """A copy restricted to the rows where ``mask`` is true."""
        return replace(
            self,
            t=self.t[mask],
            phi={k: v[mask] for k, v in self.phi.items()},
            wrench={k: v[mask] for k, v in self.wrench.items()},
            quat=None if self.quat is None else self.quat[mask],
        )


@dataclass(frozen=True)
class Dataset:
    """A robot and its recordings, as listed by a manifest."""

    robot: Robot
    recordings: tuple[Recording, ...]
    root: Path | None = None
    manifest: Path | None = None
    robot_path: Path | None = None

    def of_kind(self, kind: str) -> tuple[Recording, ...]:
        return tuple(r for r in self.recordings if r.kind == kind)

    @property
    def hanging(self) -> tuple[Recording, ...]:
        return self.of_kind("hanging")

    @property
    def standing(self) -> tuple[Recording, ...]:
        return self.of_kind("standing")

    @property
    def walking(self) -> tuple[Recording, ...]:
        return self.of_kind("walking")


# ----------------------------------------------------------------------------- reading


def _load_toml(path: Path) -> dict:
    if not path.is_file():
        raise DataFormatError(f"{path}: file not found")
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise DataFormatError(f"{path}: not valid TOML ({exc})") from exc


def _require(d: dict, key: str, where: str, typ: type | tuple[type, ...]) -> object:
    if key not in d:
        raise DataFormatError(f"{where}: missing key '{key}'")
    v = d[key]
    if not isinstance(v, typ):
        raise DataFormatError(f"{where}: key '{key}' should be {typ}, got {type(v).__name__}")
    return v


def _vec3(v: object, where: str) -> np.ndarray:
    a = np.asarray(v, dtype=float) if isinstance(v, list) else None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        raise DataFormatError(f"{where}: expected a list of 3 finite numbers, got {v!r}")
    return a


def read_robot(path: str | Path) -> Robot:
    """Read and validate ``robot.toml`` (format page section 2)."""
    path = Path(path)
    d = _load_toml(path)
    where = str(path)
    mass = float(_require(d, "mass_kg", where, (int, float)))
    g = float(_require(d, "g", where, (int, float)))
    if not (0 < mass < 1e4):
        raise DataFormatError(f"{where}: 'mass_kg' = {mass} is not a plausible mass in kg")
    if not (1.0 < g < 30.0):
        raise DataFormatError(f"{where}: 'g' = {g} is not a plausible m/s^2 value")
    legs = _require(d, "legs", where, list)
    if not legs or not all(isinstance(k, str) for k in legs) or len(set(legs)) != len(legs):
        raise DataFormatError(f"{where}: 'legs' must be a non-empty list of distinct names")
    tables = _require(d, "transducers", where, dict)
    transducers = {}
    for k in legs:
        if k not in tables:
            raise DataFormatError(f"{where}: missing table [transducers.{k}]")
        t = tables[k]
        w = f"{where} [transducers.{k}]"
        pos = _vec3(_require(t, "position_m", w, list), f"{w} position_m")
        if np.linalg.norm(pos) > _MAX_POSITION_M:
            raise DataFormatError(f"{w} position_m = {pos.tolist()}: more than {_MAX_POSITION_M} m from B; expected metres (is it in mm?)")
        rot = np.asarray(_require(t, "rotation", w, list), dtype=float)
        if not is_rotation(rot, tol=1e-4):
            raise DataFormatError(f"{w} rotation: not a proper rotation matrix (R^T R = I, det R = +1): {rot.tolist()}")
        transducers[k] = Transducer(k, pos, rot, t.get("model"))
    lm = d.get("leg_mass_kg")
    leg_mass = None
    if lm is not None:
        if isinstance(lm, (int, float)):
            leg_mass = {k: float(lm) for k in legs}
        elif isinstance(lm, dict):
            leg_mass = {k: float(lm[k]) for k in legs if k in lm}
        else:
            raise DataFormatError(f"{where}: 'leg_mass_kg' should be a number or a table per leg")
    return Robot(str(d.get("name", path.parent.name)), mass, g, tuple(legs), transducers, leg_mass)


def read_table(path: Path) -> pd.DataFrame:
    """The raw table of a CSV or Parquet recording (no validation: see :func:`recording_from_frame`)."""
    if not path.is_file():
        raise DataFormatError(f"{path}: recording file not found")
    suffix = path.suffix.lower()
    if suffix not in (".parquet", ".csv", ".txt"):
        raise DataFormatError(f"{path}: unknown recording type '{suffix}' (expected .csv or .parquet)")
    try:
        if suffix == ".parquet":
            return pd.read_parquet(path)
        try:
            return pd.read_csv(path, engine="pyarrow")
        except Exception:  # the C engine gives the clearer message on malformed CSV
            return pd.read_csv(path, engine="c")
    except Exception as exc:  # pyarrow, pandas and OS errors alike: the file cannot be read as a table
        kind = "Parquet" if suffix == ".parquet" else "CSV"
        raise DataFormatError(f"{path}: cannot be read as {kind} ({type(exc).__name__}: {exc}); truncated or not a {kind} file?") from exc


def _numeric(df: pd.DataFrame, cols: list[str], where: str) -> np.ndarray:
    """The columns ``cols`` as floats (N, len(cols)); a cell that is not a number, or a column without
    any number, is an error naming the column."""
    out = np.empty((len(df), len(cols)))
    for j, c in enumerate(cols):
        col = df[c]
        if not pd.api.types.is_numeric_dtype(col):
            num = pd.to_numeric(col, errors="coerce")
            bad = num.isna() & col.notna()
            if bad.any():
                i = int(np.flatnonzero(bad.to_numpy())[0])
                raise DataFormatError(f"{where}: column '{c}' row {i + 1} holds {col.iloc[i]!r}; expected a number")
            col = num
        out[:, j] = col.to_numpy(dtype=float)
    empty = [c for j, c in enumerate(cols) if len(df) and not np.isfinite(out[:, j]).any()]
    if empty:
        what = ("the motion-capture orientation of B, empty only where tracking was lost" if set(empty) <= set(QUAT_COLUMNS)
                else "numbers")
        raise DataFormatError(f"{where}: column(s) {empty} hold no finite value; expected {what}")
    return out


def recording_from_frame(
    df: pd.DataFrame,
    robot: Robot,
    *,
    name: str,
    kind: str,
    gravity_body: np.ndarray | None = None,
    source: str | None = None,
    path: Path | None = None,
) -> Recording:
    """Validate a table with the columns of the format page and build a :class:`Recording`."""
    where = source or name
    if kind not in KINDS:
        raise DataFormatError(f"{where}: kind '{kind}' is not one of {KINDS}")
    expected = ["t"] + [f"{k}_{c}" for k in robot.legs for c in ("phi",) + WRENCH_COMPONENTS]
    needs_quat = kind in ("standing", "walking")
    if needs_quat:
        expected += list(QUAT_COLUMNS)
    missing = [c for c in expected if c not in df.columns]
    if missing:
        raise DataFormatError(f"{where}: missing column(s) {missing}")
    extra = [c for c in df.columns if c not in expected and not (c in QUAT_COLUMNS)]
    if extra:
        log.warning("%s: extra column(s) ignored: %s", where, extra)
    reading_cols = ["t"] + [f"{k}_{c}" for k in robot.legs for c in ("phi",) + WRENCH_COMPONENTS]
    cols = reading_cols + (list(QUAT_COLUMNS) if needs_quat else [])
    values = _numeric(df, cols, where)
    bad = ~np.all(np.isfinite(values[:, : len(reading_cols)]), axis=1)
    n_bad = int(bad.sum())
    if n_bad:
        log.warning("%s: dropped %d of %d rows with NaN or infinite readings", where, n_bad, len(df))
        values = values[~bad]
    if len(values) < 2:
        raise DataFormatError(f"{where}: fewer than 2 rows with finite readings ({len(values)} of {len(df)}); expected a recording")
    t = values[:, 0]
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise DataFormatError(f"{where}: column 't' is not strictly increasing (row {i + 1}: {t[i]} -> {t[i + 1]})")
    phi, wrench = {}, {}
    for i, k in enumerate(robot.legs):
        phi[k] = values[:, 1 + 7 * i].copy()
        wrench[k] = values[:, 2 + 7 * i: 8 + 7 * i].copy()
        _check_units(wrench[k], robot, where, k)
    quat = None
    if needs_quat:
        quat = values[:, len(reading_cols):].copy()
        ok = np.all(np.isfinite(quat), axis=1)
        norms = np.linalg.norm(quat[ok], axis=1)
        if ok.any() and np.any(np.abs(norms - 1.0) > 1e-2):
            raise DataFormatError(f"{where}: columns qw, qx, qy, qz are not unit quaternions (norms {norms.min():.3g}..{norms.max():.3g}); "
                                  "expected norm 1 within 0.01")
        quat[~ok] = np.nan
    if kind == "hanging":
        if gravity_body is None:
            raise DataFormatError(f"{where}: hanging recording needs 'gravity_body' in the manifest")
    return Recording(name, kind, t, phi, wrench, quat, gravity_body, path, n_bad)


def legs_in_frame(df: pd.DataFrame) -> tuple[str, ...]:
    """Names ``X`` for which the table holds every reading column ``X_phi``, ``X_fx`` .. ``X_tz``, in column order."""
    legs = [c[: -len("_fx")] for c in df.columns if str(c).endswith("_fx")]
    return tuple(k for k in legs if all(f"{k}_{c}" in df.columns for c in ("phi",) + WRENCH_COMPONENTS))


def _check_units(w: np.ndarray, robot: Robot, where: str, leg: str) -> None:
    fmax = np.percentile(np.linalg.norm(w[:, :3], axis=1), 99)
    tmax = np.percentile(np.linalg.norm(w[:, 3:], axis=1), 99)
    if fmax > _MAX_FORCE_IN_WEIGHTS * robot.weight_N:
        raise DataFormatError(
            f"{where}: columns {leg}_fx..{leg}_fz reach {fmax:.4g}, over {_MAX_FORCE_IN_WEIGHTS:.0f}x the robot's weight "
            f"({robot.weight_N:.4g} N); expected N (off by a unit factor such as 1000?)"
        )
    if tmax > _MAX_LEVER_ARM_M * max(fmax, robot.weight_N):
        raise DataFormatError(
            f"{where}: columns {leg}_tx..{leg}_tz reach {tmax:.4g}, more than {_MAX_LEVER_ARM_M} m times the forces; "
            "expected N*m (are they in N*mm?)"
        )


def read_recording(path: str | Path, robot: Robot, *, kind: str, gravity_body=None, name: str | None = None) -> Recording:
    """Read one CSV or Parquet recording and validate it against ``robot``."""
    path = Path(path)
    df = read_table(path)
    gb = None if gravity_body is None else _vec3(list(gravity_body), f"{path} gravity_body")
    return recording_from_frame(df, robot, name=name or path.stem, kind=kind, gravity_body=gb, source=str(path), path=path)


def read_dataset(manifest: str | Path, *, kinds: Iterable[str] | None = None) -> Dataset:
    """Read a dataset manifest (format page section 4) and every recording in it.

    ``kinds`` restricts which recordings are loaded (e.g. only ``walking``).
    """
    manifest = Path(manifest)
    d = _load_toml(manifest)
    where = str(manifest)
    robot_path = manifest.parent / str(_require(d, "robot", where, str))
    robot = read_robot(robot_path)
    entries = d.get("recording", [])
    if not isinstance(entries, list) or not entries:
        raise DataFormatError(f"{where}: no [[recording]] entries")
    recs = []
    for i, e in enumerate(entries):
        w = f"{where} [[recording]] #{i + 1}"
        file = str(_require(e, "file", w, str))
        kind = str(_require(e, "kind", w, str))
        if kind not in KINDS:
            raise DataFormatError(f"{w}: kind '{kind}' is not one of {KINDS}")
        gb = None
        if kind == "hanging":
            gb = _vec3(_require(e, "gravity_body", w, list), f"{w} gravity_body")
            if abs(np.linalg.norm(gb) - 1.0) > 1e-3:
                gb = gb / np.linalg.norm(gb)
        if kinds is not None and kind not in kinds:
            continue
        recs.append(read_recording(manifest.parent / file, robot, kind=kind, gravity_body=gb, name=Path(file).stem))
    ds = Dataset(robot, tuple(recs), manifest.parent, manifest, robot_path)
    from .checks import check_distinct_recordings  # (checks imports this module)

    check_distinct_recordings(ds)  # before pairing: a file listed twice is named as such
    if kinds is None or "hanging" in kinds:
        hanging_pairs(ds.hanging)
    return ds


def hanging_pairs(recs: Iterable[Recording], tol_deg: float = 10.0) -> list[tuple[Recording, Recording]]:
    """Match hanging recordings into opposite pairs by ``gravity_body``.

    Raises :class:`DataFormatError` naming a recording that has no opposite.
    """
    recs = list(recs)
    used: set[int] = set()
    pairs = []
    cos_tol = np.cos(np.radians(tol_deg))
    for i, a in enumerate(recs):
        if i in used:
            continue
        match = None
        for j in range(i + 1, len(recs)):
            if j not in used and float(a.gravity_body @ recs[j].gravity_body) < -cos_tol:
                match = j
                break
        if match is None:
            src = a.path or a.name
            raise DataFormatError(
                f"{src}: hanging recording with gravity_body {a.gravity_body.tolist()} has no opposite recording "
                f"(expected one with gravity_body {(-a.gravity_body).tolist()})"
            )
        used |= {i, match}
        pairs.append((a, recs[match]))
    return pairs


# ----------------------------------------------------------------------------- writing


def recording_to_frame(rec: Recording, legs: Iterable[str]) -> pd.DataFrame:
    cols: dict[str, np.ndarray] = {"t": rec.t}
    for k in legs:
        cols[f"{k}_phi"] = rec.phi[k]
        for j, c in enumerate(WRENCH_COMPONENTS):
            cols[f"{k}_{c}"] = rec.wrench[k][:, j]
    if rec.quat is not None:
        for j, c in enumerate(QUAT_COLUMNS):
            cols[c] = rec.quat[:, j]
    return pd.DataFrame(cols)


def ground_wrench_table(N: int, K: int) -> tuple[np.ndarray, np.ndarray]:
    """An empty block for :func:`ground_wrench_frame` (N, 1 + 6 (K + 1)) and its per-foot part as an (N, K, 6)
    view, for a caller that computes the wrenches in place (``physics.ground_wrenches(..., out=view)``)."""
    table = np.empty((N, 1 + 6 * (K + 1)))
    return table, table[:, 1 : 1 + 6 * K].reshape(N, K, 6)


def ground_wrench_frame(t: np.ndarray, ground: np.ndarray, legs: Iterable[str], table: np.ndarray | None = None) -> pd.DataFrame:
    """Table of a corrected recording (``OUTPUT_FORMAT.md``): ``t``, ``{leg}_fx..tz`` per foot and
    ``total_fx..tz``, from per-foot wrenches ``ground`` (N, K, 6) in the heading frame. ``table``: the block
    of :func:`ground_wrench_table` whose view ``ground`` is (the frame is built on it, nothing copied)."""
    legs = tuple(legs)
    N, K = ground.shape[:2]
    # one float block filled in place: pandas keeps it as is (a dict of strided columns costs a copy each)
    if table is None:
        table, view = ground_wrench_table(N, K)
        view[:] = ground
    elif not (table.shape == (N, 1 + 6 * (K + 1)) and np.shares_memory(table, ground)):
        raise ValueError("ground_wrench_frame: table must be the block of ground_wrench_table whose view is ground")
    table[:, 0] = t
    np.einsum("nkj->nj", ground, out=table[:, 1 + 6 * K :])  # the total; far faster than ground.sum(axis=1)
    cols = ["t"] + [f"{k}_{c}" for k in legs + ("total",) for c in WRENCH_COMPONENTS]
    return pd.DataFrame(table, columns=cols, copy=False)


def write_robot(robot: Robot, path: str | Path) -> None:
    import tomli_w

    Path(path).write_bytes(tomli_w.dumps(robot.to_toml_dict()).encode())


def write_dataset(ds: Dataset, folder: str | Path, *, fmt: str = "csv", overwrite: bool = False) -> Path:
    """Write ``ds`` in the interchange format; returns the manifest path.

    ``fmt`` is ``csv`` or ``parquet``. An existing manifest is not overwritten
    unless ``overwrite`` is true.
    """
    import tomli_w

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest = folder / "dataset.toml"
    if manifest.exists() and not overwrite:
        raise FileExistsError(f"{manifest} exists; pass overwrite=True to replace it")
    write_robot(ds.robot, folder / "robot.toml")
    entries = []
    for rec in ds.recordings:
        fname = f"{rec.name}.{fmt}"
        df = recording_to_frame(rec, ds.robot.legs)
        if fmt == "parquet":
            df.to_parquet(folder / fname, index=False)
        elif fmt == "csv":
            from .csvout import write_csv

            write_csv(df, folder / fname)  # every float at full precision (csvout.py)
        else:
            raise ValueError(f"fmt must be 'csv' or 'parquet', got {fmt!r}")
        e: dict = {"file": fname, "kind": rec.kind}
        if rec.gravity_body is not None:
            e["gravity_body"] = [float(x) for x in rec.gravity_body]
        entries.append(e)
    manifest.write_bytes(tomli_w.dumps({"robot": "robot.toml", "recording": entries}).encode())
    return manifest
