"""The ingest map: which bag topics, joints and URDF links make a dataset.

A map (TOML) states, once per session, where each quantity of
``DATA_FORMAT.md`` lives in the user's ROS graph. Keys (paths are relative to
the map; ``*`` marks keys beyond the issue's contract, all optional)::

    mass_kg, g, legs                  robot mass as weighed (kg), m/s^2, leg order
    urdf = "robot.urdf"               or: robot = "robot.toml" (then mass_kg/g/legs may be omitted)
    base_link = "base_link"           URDF link whose frame is B
    [transducer_links] FL = "ft_FL"   URDF link whose frame is ft_FL
    [wrench_topics] FL = "/ft/FL/wrench"      geometry_msgs/WrenchStamped in ft_FL
    [joints] topic = "/joint_states", FL = "leg_FL_shaft"
    [body_pose] topic = "/mocap/pose"         geometry_msgs/PoseStamped of B in the world
    [[recording]] bag, kind, gravity_body (hanging)

    * name, leg_mass_kg (number or per-leg table): passed to robot.toml
    * wrench_sign = 1 | -1 | {FL = -1, ...}: multiplies a reading, for drivers that
      publish the wrench the transducer exerts on the leg (the format wants the reverse)
    * wrench_match = "nearest" | "linear": how other legs meet the first leg's clock
    * check_frame_ids = true: a WrenchStamped frame_id other than its transducer link is an error
    * time_source = "header" | "receive": header stamps (default) or bag receive times
    * max_backward_s = 0.05: header stamps of a stream may step back (bag order) by this
      much (transport reordering); more is an error (a clock reset, a looped playback)
    * format = "parquet" | "csv": recording files written
    * [joints] max_gap_s = 0.25; [joints.zero_rad] FL = 0.0; [joints.sign] FL = 1:
      phi = sign * (unwrap(position) - zero_rad), so that phi = 0 is the leg straight down
    * [body_pose] max_gap_s = 0.05: longer mocap gaps give NaN orientation
    * [body_pose] link = "mocap_marker": URDF link the mocap rigid body tracks, when not B
    * [[recording]] name: output file stem (default: the bag's stem)

Section 5 (any robot; :mod:`.freeload`): ``[joint_columns]`` (JointState -> ``q_{joint}``) and ``[imu]``
(``sensor_msgs/Imu`` -> ``qw..qz`` or ``gx..gz``). In a section-5 map (one of those tables, or a robot file
with a ``urdf``) a leg without a ``[joints]`` entry has no ``{leg}_phi`` column (its load is a payload or URDF
links), ``[joints]`` may be absent, and a hanging recording needs no ``gravity_body`` when ``[imu]`` or
``[body_pose]`` gives the orientation per sample.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.data import RECORDING_KINDS, DataFormatError, read_robot
from ..core.robot import Robot

if TYPE_CHECKING:
    from .freeload import FreeKeys

_MISSING = object()


@dataclass(frozen=True)
class RecordingSpec:
    """One ``[[recording]]`` of the map."""

    bag: Path
    kind: str
    name: str
    gravity_body: np.ndarray | None


@dataclass(frozen=True)
class IngestMap:
    """A validated map. Per-leg tables are complete (defaults filled in)."""

    path: Path
    robot: Robot
    transducer_links: dict[str, str] | None
    wrench_topics: dict[str, str]
    wrench_sign: dict[str, float]
    wrench_match: str
    check_frame_ids: bool
    joint_topic: str | None          # None: no [joints] table (section 5 maps may do without)
    joint_names: dict[str, str]
    joint_zero_rad: dict[str, float]
    joint_sign: dict[str, float]
    joint_max_gap_s: float
    pose_topic: str | None
    pose_max_gap_s: float
    R_marker_to_body: np.ndarray | None
    time_source: str
    fmt: str
    recordings: tuple[RecordingSpec, ...]
    max_backward_s: float = 0.05
    free_keys: "FreeKeys | None" = None        # section 5: [joint_columns], [imu] (ros/freeload.py)
    payload_legs: tuple[str, ...] = ()          # legs without a [joints] entry in a section-5 map: no {leg}_phi

    @property
    def legs(self) -> tuple[str, ...]:
        return self.robot.legs


def _get(d: dict, key: str, where: str, typ, default=_MISSING):
    if key not in d:
        if default is _MISSING:
            raise DataFormatError(f"{where}: missing key '{key}'")
        return default
    v = d[key]
    if isinstance(v, bool) and typ is not bool and bool not in (typ if isinstance(typ, tuple) else (typ,)):
        raise DataFormatError(f"{where}: key '{key}' should be {typ}, got a boolean")
    if not isinstance(v, typ):
        names = " or ".join(t.__name__ for t in (typ if isinstance(typ, tuple) else (typ,)))
        raise DataFormatError(f"{where}: key '{key}' should be {names}, got {type(v).__name__} {v!r}")
    return v


def _per_leg_str(table: dict, legs, where: str, reserved=()) -> dict[str, str]:
    out = {}
    for k in legs:
        if k not in table:
            raise DataFormatError(f"{where}: missing entry for leg '{k}'")
        if not isinstance(table[k], str) or not table[k]:
            raise DataFormatError(f"{where}: {k} should be a non-empty string, got {table[k]!r}")
        out[k] = table[k]
    unknown = [x for x in table if x not in legs and x not in reserved]
    if unknown:
        raise DataFormatError(f"{where}: entries {unknown} are not legs of {list(legs)}")
    return out


def _per_leg_num(v, legs, where: str, default: float, allowed: tuple[float, ...] | None = None) -> dict[str, float]:
    if v is None:
        out = {k: default for k in legs}
    elif isinstance(v, (int, float)) and not isinstance(v, bool):
        out = {k: float(v) for k in legs}
    elif isinstance(v, dict):
        unknown = [x for x in v if x not in legs]
        if unknown:
            raise DataFormatError(f"{where}: entries {unknown} are not legs of {list(legs)}")
        out = {}
        for k in legs:
            x = v.get(k, default)
            if not isinstance(x, (int, float)) or isinstance(x, bool):
                raise DataFormatError(f"{where}: {k} should be a number, got {x!r}")
            out[k] = float(x)
    else:
        raise DataFormatError(f"{where}: should be a number or a table per leg, got {v!r}")
    if allowed is not None:
        bad = {k: x for k, x in out.items() if x not in allowed}
        if bad:
            raise DataFormatError(f"{where}: values {bad} should be one of {allowed}")
    return out


def _choice(d: dict, key: str, where: str, choices: tuple[str, ...]) -> str:
    v = _get(d, key, where, str, choices[0])
    if v not in choices:
        raise DataFormatError(f"{where}: key '{key}' = {v!r} should be one of {choices}")
    return v


def _robot(d: dict, where: str, root: Path) -> tuple[Robot, dict[str, str] | None, str | None, object]:
    """Robot description from ``urdf`` or ``robot``; also the transducer links,
    the base link and the parsed URDF (None without one)."""
    from .urdf import load_urdf, robot_from_urdf

    has_urdf, has_robot = "urdf" in d, "robot" in d
    if has_urdf == has_robot:
        raise DataFormatError(f"{where}: give exactly one of 'urdf' (a URDF file) or 'robot' (a robot.toml)")
    links = d.get("transducer_links")
    if links is not None and not isinstance(links, dict):
        raise DataFormatError(f"{where}: [transducer_links] should be a table")
    if has_robot:
        robot = read_robot(root / _get(d, "robot", where, str))
        for key, val in (("mass_kg", robot.mass_kg), ("g", robot.g)):
            if key in d and val is None:
                raise DataFormatError(f"{where}: '{key}' = {d[key]} is given but the robot file has no '{key}'; "
                                      "give it in the robot file")
            if key in d and val is not None and abs(float(_get(d, key, where, (int, float))) - val) > 1e-9 * max(1.0, abs(val)):
                raise DataFormatError(f"{where}: '{key}' = {d[key]} disagrees with the robot file ({val})")
        if "legs" in d and list(d["legs"]) != list(robot.legs):
            raise DataFormatError(f"{where}: 'legs' = {d['legs']} disagrees with the robot file ({list(robot.legs)})")
        tl = None if links is None else _per_leg_str(links, robot.legs, f"{where} [transducer_links]")
        return robot, tl, d.get("base_link"), None
    legs = _get(d, "legs", where, list)
    if not legs or not all(isinstance(k, str) and k for k in legs) or len(set(legs)) != len(legs):
        raise DataFormatError(f"{where}: 'legs' must be a non-empty list of distinct names, got {legs!r}")
    mass = float(_get(d, "mass_kg", where, (int, float)))
    g = float(_get(d, "g", where, (int, float)))
    if not (0 < mass < 1e4):
        raise DataFormatError(f"{where}: 'mass_kg' = {mass} is not a plausible mass in kg")
    if not (1.0 < g < 30.0):
        raise DataFormatError(f"{where}: 'g' = {g} is not a plausible m/s^2 value")
    if links is None:
        raise DataFormatError(f"{where}: missing table [transducer_links] (URDF link of each ft_{{leg}})")
    tl = _per_leg_str(links, legs, f"{where} [transducer_links]")
    base = _get(d, "base_link", where, str)
    lm = d.get("leg_mass_kg")
    leg_mass = None if lm is None else _per_leg_num(lm, legs, f"{where} leg_mass_kg", 0.0)
    urdf_path = root / _get(d, "urdf", where, str)
    robot = robot_from_urdf(urdf_path, base_link=base, transducer_links=tl, legs=legs, mass_kg=mass, g=g, name=d.get("name"), leg_mass_kg=leg_mass)
    return robot, tl, base, load_urdf(urdf_path)


def recording_tables(d: dict, where: str) -> list[tuple[dict, str]]:
    """The map's ``[[recording]]`` tables, each with its place for messages (``<map> [[recording]] #i``)."""
    entries = d.get("recording")
    if not isinstance(entries, list) or not entries:
        raise DataFormatError(f"{where}: no [[recording]] entries")
    return [(e, f"{where} [[recording]] #{i + 1}") for i, e in enumerate(entries)]


def output_name(e: dict, w: str, bag: Path, names: dict[str, str]) -> str:
    """A recording's output file stem (key ``name``, default the bag's stem): plain, and not that of an earlier
    recording (``names``: stem -> its place, filled in here)."""
    name = _get(e, "name", w, str, Path(bag).stem)
    if not _plain_name(name):  # the recording's file is written as <-o>/<name>.<fmt>: never outside -o
        raise DataFormatError(f"{w}: key 'name' = {name!r} should be a plain file stem (letters, digits, '_', '-', '.'; no "
                              "path separator, no '..', not absolute): the recording is written as <output>/<name>.parquet")
    if name in names:
        raise DataFormatError(f"{w}: output name '{name}' is also that of recording #{names[name]}; set 'name' on one of them")
    names[name] = w.rsplit("#", 1)[-1]
    return name


def _recordings(d: dict, where: str, root: Path, orientation_per_sample: bool = False) -> tuple[RecordingSpec, ...]:
    specs: list[RecordingSpec] = []
    names: dict[str, str] = {}
    for e, w in recording_tables(d, where):
        bag = root / _get(e, "bag", w, str)
        kind = _get(e, "kind", w, str)
        if kind not in RECORDING_KINDS:
            raise DataFormatError(f"{w}: kind '{kind}' is not one of {RECORDING_KINDS}")
        gb = None
        if kind == "hanging" and orientation_per_sample and "gravity_body" not in e:
            pass                              # section 5: gravity per sample from [imu] or [body_pose]
        elif kind == "hanging":
            gb = np.asarray(_get(e, "gravity_body", w, list), dtype=float)
            if gb.shape != (3,) or not np.all(np.isfinite(gb)) or np.linalg.norm(gb) < 1e-9:
                raise DataFormatError(f"{w}: gravity_body should be 3 finite numbers, not all zero, got {e['gravity_body']!r}")
            gb = gb / np.linalg.norm(gb)
        specs.append(RecordingSpec(bag, kind, output_name(e, w, bag, names), gb))
    return tuple(specs)


def _plain_name(name: str) -> bool:
    """A recording name that stays inside the output folder as a file stem."""
    return (bool(name) and name not in (".", "..") and not name.startswith(".") and "/" not in name and "\\" not in name
            and "\0" not in name and ":" not in name and not Path(name).is_absolute() and name == name.strip())


def load_map(path: str | Path) -> dict:
    """The parsed TOML of a map file; a missing file or bad TOML is an error naming it."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: map file not found")
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise DataFormatError(f"{path}: not valid TOML ({exc})") from exc


def read_map(path: str | Path) -> IngestMap:
    """Read and validate an ingest map; errors name the map file and the key. An ``[arm]`` map is
    :func:`.arm.read_arm_map`'s (:func:`.ingest.read_any_map` tells them apart)."""
    path = Path(path)
    d = load_map(path)
    if "arm" in d:
        raise DataFormatError(f"{path}: an [arm] map (ros/arm.py); read it with ftcal_nlp.ros.read_any_map or ingest it")
    where, root = str(path), path.parent
    robot, links, base, urdf = _robot(d, where, root)
    legs = robot.legs
    wt = _per_leg_str(_get(d, "wrench_topics", where, dict), legs, f"{where} [wrench_topics]")
    dup = {t for t in wt.values() if list(wt.values()).count(t) > 1}
    if dup:
        raise DataFormatError(f"{where} [wrench_topics]: topic(s) {sorted(dup)} given for more than one leg")
    section5 = "joint_columns" in d or "imu" in d or getattr(robot, "tree", None) is not None
    jt = _get(d, "joints", where, dict, {} if section5 else _MISSING)
    wj = f"{where} [joints]"
    reserved = ("topic", "max_gap_s", "zero_rad", "sign")
    shaft_legs = tuple(k for k in legs if k in jt) if section5 else legs
    joint_topic = _get(jt, "topic", wj, str) if (jt or not section5) else None
    joint_names = _per_leg_str(jt, shaft_legs, wj, reserved + tuple(k for k in legs if k not in shaft_legs))
    joint_gap = float(_get(jt, "max_gap_s", wj, (int, float), 0.25))
    bp = _get(d, "body_pose", where, dict, {})
    wp = f"{where} [body_pose]"
    pose_topic = _get(bp, "topic", wp, str) if bp else None
    pose_gap = float(_get(bp, "max_gap_s", wp, (int, float), 0.05))
    R_mb = None
    if "link" in bp:
        if urdf is None:
            raise DataFormatError(f"{wp}: 'link' needs a URDF ('urdf' key) to place the tracked link in B")
        assert base is not None  # _robot: the 'urdf' branch requires 'base_link' and is the only one with a URDF
        from .urdf import fixed_pose

        R_bm, _ = fixed_pose(urdf, base, _get(bp, "link", wp, str), key="[body_pose] link", source=where)
        R_mb = R_bm.T
    max_back = float(_get(d, "max_backward_s", where, (int, float), 0.05))
    for key, val in (("joints.max_gap_s", joint_gap), ("body_pose.max_gap_s", pose_gap)):
        if not val > 0:
            raise DataFormatError(f"{where}: '{key}' = {val} should be a positive number of seconds")
    if not max_back >= 0:
        raise DataFormatError(f"{where}: 'max_backward_s' = {max_back} should be a number of seconds >= 0")
    from .freeload import read_free_keys

    free_keys = read_free_keys(d, where, robot, joint_topic)
    if free_keys.imu is not None and pose_topic is not None:
        raise DataFormatError(f"{where}: [imu] and [body_pose] both give the orientation of B; keep one")
    if free_keys.joint_columns is not None:
        joint_topic = free_keys.joint_columns.topic
    recs = _recordings(d, where, root, section5 and (free_keys.imu is not None or pose_topic is not None))
    if pose_topic is None:
        needing = [r.name for r in recs if r.kind != "hanging"]
        if needing:
            raise DataFormatError(f"{where}: recordings {needing} are standing/walking and need [body_pose] topic")
    return IngestMap(
        path=path,
        robot=robot,
        transducer_links=links,
        wrench_topics=wt,
        wrench_sign=_per_leg_num(d.get("wrench_sign"), legs, f"{where} wrench_sign", 1.0, (1.0, -1.0)),
        wrench_match=_choice(d, "wrench_match", where, ("nearest", "linear")),
        check_frame_ids=bool(_get(d, "check_frame_ids", where, bool, True)),
        joint_topic=joint_topic,
        joint_names=joint_names,
        joint_zero_rad=_per_leg_num(jt.get("zero_rad"), shaft_legs, f"{wj} zero_rad", 0.0),
        joint_sign=_per_leg_num(jt.get("sign"), shaft_legs, f"{wj} sign", 1.0, (1.0, -1.0)),
        joint_max_gap_s=joint_gap,
        pose_topic=pose_topic,
        pose_max_gap_s=pose_gap,
        R_marker_to_body=R_mb,
        time_source=_choice(d, "time_source", where, ("header", "receive")),
        fmt=_choice(d, "format", where, ("parquet", "csv")),
        recordings=recs,
        max_backward_s=max_back,
        free_keys=free_keys if free_keys.any else None,
        payload_legs=tuple(k for k in legs if k not in shaft_legs),
    )
