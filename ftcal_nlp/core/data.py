"""Interchange format of ``shared/DATA_FORMAT.md``: read, validate, write.

A dataset is a ``dataset.toml`` manifest, a ``robot.toml`` and one CSV or Parquet
file per recording. Conventions (section 1 of the format page): a reading is the
wrench the leg exerts on the transducer, in ``ft_k`` about its origin, plus the
transducer offset ``w_o`` and noise (report eq. 1); SI units; ``qw..qz`` map
body vectors to world vectors; ``{leg}_phi`` is unwrapped, 0 = leg straight down.

Section 5 (any robot): a transducer whose ``{leg}_phi`` column no hanging
recording has carries a rigid payload; ``robot.toml`` ``urdf`` with
``[transducers.X].link`` gives a load of URDF links (with no ``<inertial>`` below
the link: a rigid payload oriented by the joints), moved by the ``q_{joint}``
columns (``Recording.q``; movable joints without a column are held at 0 and
named in a warning); ``gx..gz`` or ``qw..qz`` in a ``hanging`` recording give the
gravity direction per sample (``Recording.gravity``, unit, in B) and make
``gravity_body`` optional (then no opposite partner is needed); a hanging
recording's ``free = [...]`` names the transducers whose loads hang free in it;
``mass_kg`` is needed only with standing or walking recordings.

Only this module and the command-line modules touch files.
"""

from __future__ import annotations

import logging
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, TypeVar, overload

import numpy as np
import pandas as pd

from .errors import ConfigError, DataFormatError, OutputExistsError
from .geometry import is_rotation, quat_to_rotation
from .robot import Robot, Transducer

log = logging.getLogger(__name__)

WRENCH_COMPONENTS = ("fx", "fy", "fz", "tx", "ty", "tz")
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")
GRAVITY_COLUMNS = ("gx", "gy", "gz")
JOINT_PREFIX = "q_"
TEMP_SUFFIX = "_temp_C"       # optional ``{leg}_temp_C``: that transducer's temperature, degC (docs/proposals/temperature.md)
TEMP_COMMON = "temp_C"        # optional ``temp_C``: one temperature for the transducers without their own
TEMP_RANGE_C = (-60.0, 150.0)  # a plausible transducer temperature in degC (outside: kelvin or degF?)
RECORDING_KINDS = ("hanging", "standing", "walking")

# A torque column in N*mm or a force column in mN is ~1000x too large. Forces on a
# transducer cannot exceed a few robot weights; torques in N*m cannot exceed the
# force times a lever arm of a few metres.
_MAX_FORCE_IN_WEIGHTS = 20.0
_MAX_LEVER_ARM_M = 3.0
_MAX_POSITION_M = 5.0
# Joint angles in degrees: a revolute joint's 99th percentile |q| beyond its URDF limit by more than this
# (rad), or beyond 2 turns without limits, is not an angle in radians.
_JOINT_LIMIT_SLACK_RAD = 0.5
_MAX_TURNS = 2.0




@dataclass(frozen=True)
class Recording:
    """One recording in the interchange format.

    ``t``: (N,) s, strictly increasing, session clock. ``phi[leg]``: (N,) rad,
    unwrapped shaft angle. ``wrench[leg]``: (N, 6) raw reading in ft_leg, N and
    N*m. ``quat``: (N, 4) ``[qw, qx, qy, qz]`` of B in the world, NaN where the
    motion capture was lost, or None (hanging with ``gravity_body``). ``gravity_body``: (3,) nominal
    gravity direction in B for hanging recordings. ``n_dropped``: rows with NaN
    readings that were dropped at load.

    Section 5: ``phi`` holds only the transducers with a ``{leg}_phi`` column
    (the others carry a rigid payload or URDF links); ``q[joint]`` (N,) rad or m
    from the ``q_{joint}`` columns; ``gravity`` (N, 3) unit gravity direction
    (pointing down) in B per sample of a hanging recording, from ``gx..gz`` or
    ``qw..qz`` (NaN where not tracked), or None; ``free`` the transducers whose
    loads hang free (None: all). ``temperature[leg]`` (N,) degC from the optional
    ``{leg}_temp_C`` column (or ``temp_C`` for every leg without its own; empty without either).
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
    q: dict[str, np.ndarray] = field(default_factory=dict)
    gravity: np.ndarray | None = None
    free: tuple[str, ...] | None = None
    temperature: dict[str, np.ndarray] = field(default_factory=dict)

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
            q={k: v[mask] for k, v in self.q.items()},
            gravity=None if self.gravity is None else self.gravity[mask],
        )

    def gravity_directions(self) -> np.ndarray:
        """Unit gravity direction in B per sample (N, 3): ``gravity`` when the recording has it, else
        ``gravity_body`` for every sample (NaN where the orientation was not tracked)."""
        if self.gravity is not None:
            return self.gravity
        if self.gravity_body is None:
            raise DataFormatError(f"{self.path or self.name}: no gravity direction (neither gravity_body nor qw..qz / gx..gz)")
        gb = np.asarray(self.gravity_body, float)
        return np.broadcast_to(gb / np.linalg.norm(gb), (self.n, 3)).copy()

    def hangs_free(self, leg: str) -> bool:
        """Whether transducer ``leg``'s load hangs free in this (hanging) recording (``free``; default all)."""
        return self.kind == "hanging" and (self.free is None or leg in self.free)


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

    def load_kind(self, leg: str) -> str:
        """The kind of transducer ``leg``'s load (section 5): ``"leg_com_curve"`` (a ``{leg}_phi`` column:
        a hexapod leg), ``"urdf_subtree"`` (a URDF ``link`` with links of mass below it) or ``"rigid_payload"``
        (no ``link``, or a ``link`` with no mass below it: an arm's tool the URDF leaves out, oriented by the joints)."""
        link = self.robot.transducers[leg].link
        if link is not None:
            return "urdf_subtree" if has_mass_below(self.robot.tree, link) else "rigid_payload"
        if any(leg in r.phi for r in self.recordings):
            return "leg_com_curve"
        return "rigid_payload"

    @property
    def free_load_legs(self) -> tuple[str, ...]:
        """Transducers whose load is not a hexapod leg (section 5): they go to the free-load estimator."""
        return tuple(k for k in self.robot.legs if self.load_kind(k) != "leg_com_curve")


# ----------------------------------------------------------------------------- reading


def _load_toml(path: Path) -> dict:
    if not path.is_file():
        raise DataFormatError(f"{path}: file not found", path=path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise DataFormatError(f"{path}: not valid TOML ({exc})", path=path) from exc


_T = TypeVar("_T")
_U = TypeVar("_U")


@overload
def _require(d: dict, key: str, where: str, typ: type[_T]) -> _T: ...
@overload
def _require(d: dict, key: str, where: str, typ: tuple[type[_T], type[_U]]) -> _T | _U: ...
def _require(d: dict, key: str, where: str, typ: type | tuple[type, ...]) -> Any:
    """``d[key]``, an instance of ``typ`` (its type as the return type), or a DataFormatError naming ``where``."""
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


#: a plausible gravity (m/s^2) in robot.toml and calibration.json: outside it, another unit or a typo
G_RANGE = (1.0, 30.0)


def read_robot(path: str | Path) -> Robot:
    """Read and validate ``robot.toml`` (format page sections 2 and 5)."""
    path = Path(path)
    d = _load_toml(path)
    where = str(path)
    mass = None
    if "mass_kg" in d:  # section 5: only needed with standing or walking recordings (read_dataset checks)
        mass = float(_require(d, "mass_kg", where, (int, float)))
        if not (0 < mass < 1e4):
            raise DataFormatError(f"{where}: 'mass_kg' = {mass} is not a plausible mass in kg", path=path, column="mass_kg")
    g = float(_require(d, "g", where, (int, float)))
    if not (G_RANGE[0] < g < G_RANGE[1]):
        raise DataFormatError(f"{where}: 'g' = {g} is not a plausible m/s^2 value")
    legs = _require(d, "legs", where, list)
    if not legs or not all(isinstance(k, str) for k in legs) or len(set(legs)) != len(legs):
        raise DataFormatError(f"{where}: 'legs' must be a non-empty list of distinct names")
    # a transducer's name becomes a file name (report tables, corrected recordings): no path in it
    for k in legs:
        if "/" in k or "\\" in k or k.startswith(".") or "\0" in k:
            raise DataFormatError(f"{where}: 'legs': {k!r} is not a plain name (it names files of the results as well as the "
                                  f"columns {k}_fx..{k}_tz); expected no '/' or '\\' and no leading '.'", path=path, column="legs")
    urdf_path, tree = None, None
    if "urdf" in d:
        urdf_path = path.parent / str(_require(d, "urdf", where, str))
        tree = read_urdf_tree(urdf_path, f"{where} key 'urdf'")
    tables = _require(d, "transducers", where, dict)
    transducers = {}
    for k in legs:
        if k not in tables:
            raise DataFormatError(f"{where}: missing table [transducers.{k}]")
        t = tables[k]
        w = f"{where} [transducers.{k}]"
        link = t.get("link")
        if link is not None:
            link = _transducer_link(link, tree, w)
        pos = rot = None
        if link is None or "position_m" in t:
            pos = _vec3(_require(t, "position_m", w, list), f"{w} position_m")
            if np.linalg.norm(pos) > _MAX_POSITION_M:
                raise DataFormatError(f"{w} position_m = {pos.tolist()}: more than {_MAX_POSITION_M} m from B; expected metres (is it in mm?)")
        if link is None or "rotation" in t:
            rot = np.asarray(_require(t, "rotation", w, list), dtype=float)
            if not is_rotation(rot, tol=1e-4):
                raise DataFormatError(f"{w} rotation: not a proper rotation matrix (R^T R = I, det R = +1): {rot.tolist()}")
        if link is not None and (pos is not None or rot is not None):
            log.info("%s: link '%s' given: the URDF gives the nominal pose for each sample's joint angles; position_m / rotation "
                     "are not used for it", w, link)
        weighed = None
        if "load_mass_kg" in t:
            weighed = float(_require(t, "load_mass_kg", w, (int, float)))
            if not (0 < weighed < 1e4):
                raise DataFormatError(f"{w}: 'load_mass_kg' = {weighed}; expected the load's mass as weighed, a positive "
                                      "number of kg", path=path, column="load_mass_kg")
        transducers[k] = Transducer(k, pos, rot, t.get("model"), link, weighed)
    lm = d.get("leg_mass_kg")
    leg_mass = None
    if lm is not None:
        if isinstance(lm, (int, float)):
            leg_mass = {k: float(lm) for k in legs}
        elif isinstance(lm, dict):
            leg_mass = {k: float(lm[k]) for k in legs if k in lm}
        else:
            raise DataFormatError(f"{where}: 'leg_mass_kg' should be a number or a table per leg")
    return Robot(str(d.get("name", path.parent.name)), mass, g, tuple(legs), transducers, leg_mass, urdf_path, tree)


def read_urdf_tree(path: Path, where: str):
    """The :class:`~ftcal_nlp.core.kinematics.KinematicTree` of a URDF file; a missing file or one that does
    not parse is a :class:`DataFormatError` naming it and ``where`` it was named."""
    from .kinematics import load_tree

    if not path.is_file():
        raise DataFormatError(f"{where}: URDF file {path} not found", path=path)
    import xml.etree.ElementTree as ET

    try:  # yourdfpy repairs malformed XML silently: a truncated file is an error here, not a guess
        ET.parse(path)
    except ET.ParseError as exc:
        raise DataFormatError(f"{where}: {path} cannot be parsed as a URDF (malformed XML: {exc}); expected a URDF file", path=path) from exc
    try:
        return load_tree(path)
    except DataFormatError as exc:
        raise DataFormatError(f"{where}: {exc}", path=path) from exc
    except Exception as exc:  # yourdfpy / lxml raise many types for a malformed file
        raise DataFormatError(f"{where}: {path} cannot be parsed as a URDF ({type(exc).__name__}: {exc})", path=path) from exc


def _transducer_link(link: object, tree, where: str) -> str:
    """A transducer's ``link`` key: a link of the URDF, the child of a fixed joint (the sensor), with a load below it."""
    if tree is None:
        raise DataFormatError(f"{where}: key 'link' needs a URDF: add 'urdf = \"robot.urdf\"' to the robot.toml", column="link")
    if not isinstance(link, str) or link not in tree.links:
        raise DataFormatError(f"{where}: key 'link' = {link!r} is not a link of the URDF {tree.name!r} (links: {list(tree.links)})",
                              column="link")
    j = tree.joints.get(link)
    if j is None or j.type != "fixed":
        what = "the root link" if j is None else f"the child of {j.type} joint '{j.name}'"
        raise DataFormatError(f"{where}: key 'link' = '{link}' is {what}; expected a sensor link, the child link of a fixed joint",
                              column="link")
    if not has_mass_below(tree, link):
        log.info("%s: no link with mass below '%s' in the URDF %r: its load is a rigid payload (mass and CoM from the "
                 "readings), oriented by the joints through the URDF (DATA_FORMAT.md section 5)", where, link, tree.name)
    return link


def has_mass_below(tree, link: str) -> bool:
    """Whether a link of ``tree`` below ``link`` carries an ``<inertial>`` (else the load is a rigid payload)."""
    return any(l in tree.bodies for l in tree.below(link))


def read_table(path: Path) -> pd.DataFrame:
    """The raw table of a CSV or Parquet recording (no validation: see :func:`recording_from_frame`)."""
    if not path.is_file():
        raise DataFormatError(f"{path}: recording file not found", path=path)
    suffix = path.suffix.lower()
    if suffix not in (".parquet", ".csv", ".txt"):
        raise DataFormatError(f"{path}: unknown recording type '{suffix}' (expected .csv or .parquet)", path=path)
    try:
        if suffix == ".parquet":
            return pd.read_parquet(path)
        try:
            return pd.read_csv(path, engine="pyarrow")
        except Exception:  # the C engine gives the clearer message on malformed CSV
            return pd.read_csv(path, engine="c")
    except Exception as exc:  # pyarrow, pandas and OS errors alike: the file cannot be read as a table
        kind = "Parquet" if suffix == ".parquet" else "CSV"
        raise DataFormatError(f"{path}: cannot be read as {kind} ({type(exc).__name__}: {exc}); truncated or not a {kind} file?", path=path) from exc


def numeric_values(df: pd.DataFrame, cols: list[str], where: str) -> np.ndarray:
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
                raise DataFormatError(f"{where}: column '{c}' row {i + 1} holds {col.iloc[i]!r}; expected a number", column=c)
            col = num
        out[:, j] = col.to_numpy(dtype=float)
    empty = [c for j, c in enumerate(cols) if len(df) and not np.isfinite(out[:, j]).any()]
    if empty:
        what = ("the motion-capture orientation of B, empty only where tracking was lost" if set(empty) <= set(QUAT_COLUMNS)
                else "numbers")
        raise DataFormatError(f"{where}: column(s) {empty} hold no finite value; expected {what}", column=empty[0])
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
    payload_legs: Iterable[str] = (),
    free: Iterable[str] | None = None,
) -> Recording:
    """Validate a table with the columns of the format page and build a :class:`Recording`.

    ``payload_legs``: transducers whose ``{leg}_phi`` column is not expected in a hanging recording (rigid
    payloads, section 5; a transducer with a URDF ``link`` never has one). ``free``: the manifest's ``free``.
    """
    where = source or name
    if kind not in RECORDING_KINDS:
        raise DataFormatError(f"{where}: kind '{kind}' is not one of {RECORDING_KINDS}")
    no_phi = {k for k in robot.legs if robot.transducers[k].link is not None}
    if kind == "hanging":
        no_phi |= set(payload_legs)
    phi_legs = [k for k in robot.legs if k not in no_phi]
    reading_cols = ["t"] + [f"{k}_{c}" for k in robot.legs for c in (("phi",) if k in phi_legs else ()) + WRENCH_COMPONENTS]
    expected = list(reading_cols)
    needs_quat = kind in ("standing", "walking")
    if needs_quat:
        expected += list(QUAT_COLUMNS)
    missing = [c for c in expected if c not in df.columns]
    if missing:
        raise DataFormatError(f"{where}: missing column(s) {missing}", path=path, column=missing[0])
    cols_in = [str(c) for c in df.columns]
    quat_cols = complete_group(cols_in, QUAT_COLUMNS, where) if kind == "hanging" else []
    g_cols = complete_group(cols_in, GRAVITY_COLUMNS, where) if kind == "hanging" else []
    joint_cols = [c for c in cols_in if c.startswith(JOINT_PREFIX)] if robot.tree is not None else []
    urdf_joints = [jt.name for jt in robot.tree.joints.values()] if robot.tree is not None else []
    for c in joint_cols:
        if c[len(JOINT_PREFIX):] not in urdf_joints:
            raise DataFormatError(f"{where}: column '{c}': the URDF {robot.urdf} has no joint '{c[len(JOINT_PREFIX):]}' "
                                  f"(joints: {urdf_joints})", path=path, column=c)
    temp_cols = [c for c in [f"{k}{TEMP_SUFFIX}" for k in robot.legs] + [TEMP_COMMON] if c in cols_in]
    known = set(expected) | set(QUAT_COLUMNS) | set(g_cols) | set(joint_cols) | set(temp_cols)
    extra = [c for c in df.columns if c not in known]
    if extra:
        log.warning("%s: extra column(s) ignored: %s", where, extra)
    use_quat = needs_quat or (bool(quat_cols) and gravity_body is None)
    orient_cols = (list(QUAT_COLUMNS) if use_quat else []) + g_cols + (quat_cols if not use_quat and not g_cols else [])
    cols = reading_cols + joint_cols + orient_cols
    values = numeric_values(df, cols, where)
    n_read = len(reading_cols) + len(joint_cols)
    bad = ~np.all(np.isfinite(values[:, :n_read]), axis=1)
    n_bad = int(bad.sum())
    if n_bad:
        what = "readings or joint angles" if joint_cols else "readings"
        log.warning("%s: dropped %d of %d rows with NaN or infinite %s", where, n_bad, len(df), what)
        values = values[~bad]
    if len(values) < 2:
        raise DataFormatError(f"{where}: fewer than 2 rows with finite readings ({len(values)} of {len(df)}); expected a recording")
    t = values[:, 0]
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise DataFormatError(f"{where}: column 't' is not strictly increasing (row {i + 1}: {t[i]} -> {t[i + 1]})", path=path, column="t")
    temps = temperatures(df, temp_cols, ~bad, t, robot.legs, where, path)
    phi, wrench = {}, {}
    j = 1
    for k in robot.legs:
        if k in phi_legs:
            phi[k] = values[:, j].copy()
            j += 1
        wrench[k] = values[:, j: j + 6].copy()
        j += 6
        _check_units(wrench[k], robot, where, k)
    q = {c[len(JOINT_PREFIX):]: values[:, len(reading_cols) + i].copy() for i, c in enumerate(joint_cols)}
    if robot.tree is not None and kind == "hanging":
        check_joint_units(q, robot.tree, where)
        held = [jn for jn in robot.tree.movable if jn not in q]
        if held:
            log.warning("%s: no column for URDF joint(s) %s: held at 0 (expected columns %s)", where, held,
                        [JOINT_PREFIX + jn for jn in held])
    ov = values[:, n_read:]
    quat = None
    if use_quat:
        quat = ov[:, :4].copy()
        ok = np.all(np.isfinite(quat), axis=1)
        norms = np.linalg.norm(quat[ok], axis=1)
        if ok.any() and np.any(np.abs(norms - 1.0) > 1e-2):
            raise DataFormatError(f"{where}: columns qw, qx, qy, qz are not unit quaternions (norms {norms.min():.3g}..{norms.max():.3g}); "
                                  "expected norm 1 within 0.01", path=path, column="qw")
        quat[~ok] = np.nan
    gravity = None
    if kind == "hanging":
        if g_cols:
            gravity = _unit_rows(ov[:, -3:], where, "gx, gy, gz")
        elif quat_cols:
            qq = quat if quat is not None else _unit_quats(ov[:, :4], where)
            gravity = -quat_to_rotation(np.nan_to_num(qq, nan=1.0))[:, 2, :]   # R_WB^T [0, 0, -1]
            gravity[~np.all(np.isfinite(qq), axis=1)] = np.nan
        if gravity_body is None and gravity is None:
            raise DataFormatError(f"{where}: hanging recording needs 'gravity_body' in the manifest or the gravity per sample "
                                  "(columns qw, qx, qy, qz or gx, gy, gz)")
    free_t = None
    if free is not None:
        free_t = tuple(free)
        bad_free = [k for k in free_t if k not in robot.legs]
        if bad_free:
            raise DataFormatError(f"{where}: free = {list(free_t)} names {bad_free}, not transducers of the robot (legs: {list(robot.legs)})")
    return Recording(name, kind, t, phi, wrench, quat, gravity_body, path, n_bad, q=q, gravity=gravity, free=free_t,
                     temperature=temps)


def temperatures(df: pd.DataFrame, cols: list[str], keep: np.ndarray, t: np.ndarray, legs, where: str,
                  path: Path | None) -> dict[str, np.ndarray]:
    """``{leg: (N,) degC}`` from the optional temperature columns ``cols`` (rows ``keep``): ``{leg}_temp_C``, else
    ``temp_C``. A temperature sampled slower than the readings (NaN between its samples) is interpolated
    linearly in ``t`` (a warning counts the rows); a column without any number, or values outside
    ``TEMP_RANGE_C``, is an error naming it."""
    if not cols:
        return {}
    vals = numeric_values(df, cols, where)[keep]
    by_col = {}
    for j, c in enumerate(cols):
        v = vals[:, j]
        ok = np.isfinite(v)
        if not ok.any():
            raise DataFormatError(f"{where}: column '{c}' holds no temperature; expected degC", path=path, column=c)
        lo, hi = TEMP_RANGE_C
        if np.any((v[ok] < lo) | (v[ok] > hi)):
            raise DataFormatError(f"{where}: column '{c}' ranges {v[ok].min():.4g}..{v[ok].max():.4g}; expected degC "
                                  f"within {lo:g}..{hi:g}", path=path, column=c)
        if not ok.all():
            log.warning("%s: column '%s': %d of %d rows without a temperature, interpolated in t", where, c, int((~ok).sum()), len(v))
            v = np.interp(t, t[ok], v[ok])
        by_col[c] = v
    out = {}
    for k in legs:
        c = f"{k}{TEMP_SUFFIX}"
        if c in by_col or TEMP_COMMON in by_col:
            out[k] = (by_col[c] if c in by_col else by_col[TEMP_COMMON]).copy()
    return out


def complete_group(columns: list[str], group: tuple[str, ...], where: str) -> list[str]:
    """``group`` when the table has all of its columns, [] when none; some but not all is an error naming the missing."""
    have = [c for c in group if c in columns]
    if have and len(have) < len(group):
        raise DataFormatError(f"{where}: column(s) {have} without {[c for c in group if c not in have]}; expected all of {list(group)}")
    return list(group) if have else []


def _unit_quats(q: np.ndarray, where: str) -> np.ndarray:
    ok = np.all(np.isfinite(q), axis=1)
    norms = np.linalg.norm(q[ok], axis=1)
    if ok.any() and np.any(np.abs(norms - 1.0) > 1e-2):
        raise DataFormatError(f"{where}: columns qw, qx, qy, qz are not unit quaternions (norms {norms.min():.3g}..{norms.max():.3g}); "
                              "expected norm 1 within 0.01")
    out = q.copy()
    out[~ok] = np.nan
    return out


def _unit_rows(g: np.ndarray, where: str, what: str) -> np.ndarray:
    """Rows of ``g`` normalised (the gravity direction: any scale); zero or non-finite rows become NaN."""
    n = np.linalg.norm(g, axis=1)
    ok = np.isfinite(n) & (n > 0)
    if not ok.any():
        raise DataFormatError(f"{where}: columns {what} hold no nonzero finite row; expected the direction of gravity in B")
    out = np.full_like(g, np.nan)
    out[ok] = g[ok] / n[ok, None]
    return out


def check_joint_units(q: dict[str, np.ndarray], tree: Any, where: str) -> None:
    """``tree`` a :class:`~ftcal_nlp.core.kinematics.KinematicTree` (a robot's, or a free load's URDF). Revolute joint angles in radians: the 99th percentile of |q| beyond the URDF limits by more than
    ``_JOINT_LIMIT_SLACK_RAD`` (or beyond ``_MAX_TURNS`` turns) is an error suspecting degrees."""
    for name, v in q.items():
        jt = tree.joint(name)
        if jt.type != "revolute":  # prismatic: metres; continuous: may turn without bound (unwrapped)
            continue
        lo_q, hi_q = np.percentile(v, [1, 99])
        big = max(abs(lo_q), abs(hi_q))
        if jt.type == "revolute" and jt.lower is not None and jt.upper is not None and jt.upper > jt.lower:
            over = max(jt.lower - lo_q, hi_q - jt.upper)
            if over > _JOINT_LIMIT_SLACK_RAD:
                raise DataFormatError(
                    f"{where}: column '{JOINT_PREFIX}{name}' reaches {lo_q:.4g}..{hi_q:.4g}, beyond the URDF limits "
                    f"[{jt.lower:g}, {jt.upper:g}] rad by {over:.3g}; expected radians (degrees?)", column=JOINT_PREFIX + name)
        elif big > _MAX_TURNS * 2 * np.pi:
            raise DataFormatError(f"{where}: column '{JOINT_PREFIX}{name}' reaches |q| = {big:.4g}, over {_MAX_TURNS:g} turns; "
                                  "expected radians (degrees?)", column=JOINT_PREFIX + name)


def legs_in_frame(df: pd.DataFrame) -> tuple[str, ...]:
    """Names ``X`` for which the table holds every reading column ``X_phi``, ``X_fx`` .. ``X_tz``, in column order."""
    legs = [c[: -len("_fx")] for c in df.columns if str(c).endswith("_fx")]
    return tuple(k for k in legs if all(f"{k}_{c}" in df.columns for c in ("phi",) + WRENCH_COMPONENTS))


def _weight_scale_N(robot: Robot) -> float | None:
    """The weight that bounds a reading's force: the robot's, else the URDF's total mass (section 5), else None."""
    if robot.mass_kg is not None:
        return robot.weight_N
    if robot.tree is not None and robot.tree.bodies:
        return robot.g * sum(b.mass_kg for b in robot.tree.bodies.values())
    return None


def _check_units(w: np.ndarray, robot: Robot, where: str, leg: str) -> None:
    fmax = np.percentile(np.linalg.norm(w[:, :3], axis=1), 99)
    weight = _weight_scale_N(robot)
    if weight is not None and fmax > _MAX_FORCE_IN_WEIGHTS * weight:
        what = "the robot's weight" if robot.mass_kg is not None else "the URDF's total weight"
        raise DataFormatError(
            f"{where}: columns {leg}_fx..{leg}_fz reach {fmax:.4g}, over {_MAX_FORCE_IN_WEIGHTS:.0f}x {what} "
            f"({weight:.4g} N); expected N (off by a unit factor such as 1000?)", column=f"{leg}_fx"
        )
    check_torque_units(w, weight, where, leg, fmax)


#: forces whose 99th percentile stays below this (N) while the torques look large: likely kN, not N
_KN_FORCE_MAX_N = 1.0


def check_torque_units(w: np.ndarray, weight_N: float | None, where: str, leg: str, fmax: float | None = None) -> None:
    """Torques in N*m: the 99th percentile of their norm above ``_MAX_LEVER_ARM_M`` times the larger of the forces'
    (99th percentile) and ``weight_N`` is an error suspecting N*mm. ``w`` (N, 6) one transducer's readings."""
    if fmax is None:   # the forces' 99th percentile norm, where the caller has not taken it
        fmax = np.percentile(np.linalg.norm(w[:, :3], axis=1), 99)
    tmax = np.percentile(np.linalg.norm(w[:, 3:], axis=1), 99)
    if tmax > _MAX_LEVER_ARM_M * max(fmax, weight_N or 0.0):
        # the ratio cannot tell torques in N*mm from forces in kN; forces that never reach a newton point at the latter
        guess = ("are the forces in kN, or the torques in N*mm?" if fmax < _KN_FORCE_MAX_N
                 else "are the torques in N*mm, or the forces in kN?")
        raise DataFormatError(
            f"{where}: columns {leg}_tx..{leg}_tz reach {tmax:.4g}, more than {_MAX_LEVER_ARM_M} m times the forces "
            f"({leg}_fx..{leg}_fz reach {fmax:.4g}); expected N*m and N: {guess}", column=f"{leg}_tx"
        )


def read_recording(path: str | Path, robot: Robot, *, kind: str, gravity_body=None, name: str | None = None,
                   payload_legs: Iterable[str] = (), free: Iterable[str] | None = None) -> Recording:
    """Read one CSV or Parquet recording and validate it against ``robot`` (``payload_legs``, ``free``:
    :func:`recording_from_frame`)."""
    path = Path(path)
    df = read_table(path)
    gb = None if gravity_body is None else _vec3(list(gravity_body), f"{path} gravity_body")
    return recording_from_frame(df, robot, name=name or path.stem, kind=kind, gravity_body=gb, source=str(path), path=path,
                                payload_legs=payload_legs, free=free)


def read_dataset(manifest: str | Path, *, kinds: Iterable[str] | None = None) -> Dataset:
    """Read a dataset manifest (format page sections 4 and 5) and every recording in it.

    ``kinds`` restricts which recordings are loaded (e.g. only ``walking``). A transducer without a URDF
    ``link`` whose ``{leg}_phi`` column no hanging recording has carries a rigid payload (section 5).
    Hanging recordings must come in opposite pairs only where a hexapod leg (a ``{leg}_phi`` column) needs them.
    """
    manifest = Path(manifest)
    d = _load_toml(manifest)
    where = str(manifest)
    robot_path = manifest.parent / str(_require(d, "robot", where, str))
    robot = read_robot(robot_path)
    entries = d.get("recording", [])
    if not isinstance(entries, list) or not entries:
        raise DataFormatError(f"{where}: no [[recording]] entries", path=manifest)
    todo = []
    for i, e in enumerate(entries):
        w = f"{where} [[recording]] #{i + 1}"
        file = str(_require(e, "file", w, str))
        kind = str(_require(e, "kind", w, str))
        if kind not in RECORDING_KINDS:
            raise DataFormatError(f"{w}: kind '{kind}' is not one of {RECORDING_KINDS}")
        gb = free = None
        if kind == "hanging":
            if "gravity_body" in e:
                gb = _vec3(_require(e, "gravity_body", w, list), f"{w} gravity_body")
                if abs(np.linalg.norm(gb) - 1.0) > 1e-3:
                    gb = gb / np.linalg.norm(gb)
            if "free" in e:
                free = _require(e, "free", w, list)
                if not all(isinstance(k, str) for k in free):
                    raise DataFormatError(f"{w}: key 'free' should be a list of transducer names, got {free!r}")
        if kind in ("standing", "walking") and robot.mass_kg is None:
            raise DataFormatError(f"{robot_path}: missing key 'mass_kg'; a dataset with {kind} recordings ({file}) needs the "
                                  "robot's weighed total mass", path=robot_path, column="mass_kg")
        if kinds is not None and kind not in kinds:
            continue
        todo.append((manifest.parent / file, kind, gb, free))
    tables = [read_table(f) for f, *_ in todo]
    hanging_cols = [set(map(str, df.columns)) for df, (_, kind, _, _) in zip(tables, todo) if kind == "hanging"]
    payload = tuple(k for k in robot.legs if robot.transducers[k].link is None and hanging_cols
                    and not any(f"{k}_phi" in c for c in hanging_cols))
    recs = [recording_from_frame(df, robot, name=f.stem, kind=kind, gravity_body=gb, source=str(f), path=f,
                                 payload_legs=payload, free=free)
            for df, (f, kind, gb, free) in zip(tables, todo)]
    ds = Dataset(robot, tuple(recs), manifest.parent, manifest, robot_path)
    if payload:
        log.info("%s: transducer(s) %s have no {leg}_phi column: rigid payloads (DATA_FORMAT.md section 5)", where, list(payload))
    check_distinct_recordings(ds)  # before pairing: a file listed twice is named as such
    if any(ds.load_kind(k) == "leg_com_curve" for k in robot.legs) and ds.hanging:
        ds = _nominal_gravity_body(ds)
        if kinds is None or "hanging" in kinds:
            hanging_pairs(ds.hanging)
    return ds


def _nominal_gravity_body(ds: Dataset) -> Dataset:
    """Hexapod legs' hanging fit needs each hanging recording's nominal ``gravity_body``: where the manifest gives
    none, the mean of the per-sample gravity (it must stay within 10 deg of it: one held orientation)."""
    recs = []
    for r in ds.recordings:
        if r.kind == "hanging" and r.gravity_body is None:
            g = r.gravity_directions()  # without gravity_body: the per-sample gravity (recording_from_frame requires one of them)
            gm = np.nanmean(g, axis=0)
            gb = gm / np.linalg.norm(gm)
            spread = np.degrees(np.arccos(np.clip(g[np.all(np.isfinite(g), axis=1)] @ gb, -1, 1))).max()
            if spread > 10.0:
                raise DataFormatError(f"{r.path or r.name}: the hexapod legs' hanging fit needs one held orientation per recording "
                                      f"(gravity_body); the per-sample gravity spreads {spread:.0f} deg; expected within 10 deg")
            log.info("%s: gravity_body %s from the per-sample gravity", r.path or r.name, np.round(gb, 4).tolist())
            r = replace(r, gravity_body=gb)
        recs.append(r)
    return replace(ds, recordings=tuple(recs))


def check_distinct_recordings(ds: Dataset) -> None:
    """No recording listed twice (the same file, or the same samples under another name): each would count twice
    and shrink every standard error by sqrt 2."""
    seen: dict[tuple, Recording] = {}
    for rec in ds.recordings:
        key = (rec.n, float(rec.t[0]) if rec.n else 0.0, float(rec.t[-1]) if rec.n else 0.0)
        other = seen.get(key)
        same_file = other is not None and other.path is not None and rec.path is not None and Path(other.path).resolve() == Path(rec.path).resolve()
        if other is not None and (same_file or (np.array_equal(other.t, rec.t) and all(
                np.array_equal(other.wrench[k], rec.wrench[k], equal_nan=True) for k in rec.wrench))):
            raise DataFormatError(
                f"{ds.manifest or 'dataset'}: recordings {str(other.path or other.name)} and {str(rec.path or rec.name)} are the same "
                f"{'file' if same_file else 'samples'} listed twice; expected each recording once (twice, it would count "
                "twice and every standard error would shrink by sqrt 2)"
            )
        seen[key] = rec



def held_gravity_body(r: Recording) -> np.ndarray:
    """``r.gravity_body``, which every hanging recording of hexapod legs has once read (``_nominal_gravity_body``)."""
    if r.gravity_body is None:
        raise DataFormatError(f"{r.path or r.name}: hanging recording without gravity_body; expected one held orientation "
                              "per recording to pair opposite recordings")
    return r.gravity_body


def hanging_pairs(recs: Iterable[Recording], tol_deg: float = 10.0) -> list[tuple[Recording, Recording]]:
    """Match hanging recordings into opposite pairs by ``gravity_body``.

    Raises :class:`DataFormatError` naming a recording that has no opposite.
    """
    recs = list(recs)
    gbs = [held_gravity_body(r) for r in recs]
    used: set[int] = set()
    pairs = []
    cos_tol = np.cos(np.radians(tol_deg))
    for i, a in enumerate(recs):
        if i in used:
            continue
        match = None
        for j in range(i + 1, len(recs)):
            if j not in used and float(gbs[i] @ gbs[j]) < -cos_tol:
                match = j
                break
        if match is None:
            src = a.path or a.name
            raise DataFormatError(
                f"{src}: hanging recording with gravity_body {gbs[i].tolist()} has no opposite recording "
                f"(expected one with gravity_body {(-gbs[i]).tolist()})"
            )
        used |= {i, match}
        pairs.append((a, recs[match]))
    return pairs


# ----------------------------------------------------------------------------- writing


def recording_to_frame(rec: Recording, legs: Iterable[str]) -> pd.DataFrame:
    """The table of ``rec`` in the interchange format, readable back into the same recording: ``t``, per leg
    ``{leg}_phi`` (where it has one: section 5 loads have none) and ``{leg}_fx..tz``; ``q_{joint}`` columns;
    ``qw..qz`` when the recording keeps its orientation, else ``gx..gz`` when it has gravity per sample (a
    hanging recording with both ``gravity_body`` and orientation columns keeps only the gravity they give)."""
    cols: dict[str, np.ndarray] = {"t": rec.t}
    for k in legs:
        if k in rec.phi:
            cols[f"{k}_phi"] = rec.phi[k]
        for j, c in enumerate(WRENCH_COMPONENTS):
            cols[f"{k}_{c}"] = rec.wrench[k][:, j]
    for jn, v in rec.q.items():
        cols[f"{JOINT_PREFIX}{jn}"] = v
    if rec.quat is not None:
        for j, c in enumerate(QUAT_COLUMNS):
            cols[c] = rec.quat[:, j]
    elif rec.gravity is not None:
        for j, c in enumerate(GRAVITY_COLUMNS):
            cols[c] = rec.gravity[:, j]
    for k, v in rec.temperature.items():
        cols[f"{k}{TEMP_SUFFIX}"] = v
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
    unless ``overwrite`` is true. Section 5: the robot's URDF is copied beside
    ``robot.toml``, recordings keep their ``q_{joint}`` and orientation or gravity
    columns (:func:`recording_to_frame`), hanging entries their ``free`` list.
    """
    import tomli_w

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest = folder / "dataset.toml"
    if manifest.exists() and not overwrite:
        raise OutputExistsError(f"{manifest} exists; pass overwrite=True to replace it", path=manifest)
    write_robot(ds.robot, folder / "robot.toml")
    if ds.robot.urdf is not None:  # robot.toml names it by file name, beside itself
        import shutil

        target = folder / Path(ds.robot.urdf).name
        if not target.exists() or not target.samefile(ds.robot.urdf):
            shutil.copyfile(ds.robot.urdf, target)
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
            raise ConfigError(f"fmt must be 'csv' or 'parquet', got {fmt!r}", key="fmt")
        e: dict = {"file": fname, "kind": rec.kind}
        if rec.gravity_body is not None:
            e["gravity_body"] = [float(x) for x in rec.gravity_body]
        if rec.free is not None:
            e["free"] = list(rec.free)
        entries.append(e)
    manifest.write_bytes(tomli_w.dumps({"robot": "robot.toml", "recording": entries}).encode())
    return manifest
