"""An arm's ROS bags + its URDF -> a section-5 dataset (``DATA_FORMAT.md`` section 5; issue 32 item 5).

The commonest user: a six-axis sensor at the wrist of an arm (UR, Franka, KUKA) carrying a tool, logging
``sensor_msgs/JointState``, ``geometry_msgs/WrenchStamped`` and perhaps ``sensor_msgs/Temperature``, the base
fixed. The dataset written has the shape of ``shared/sample_arm``: ``robot.toml`` (``urdf``, ``legs = [X]``,
``[transducers.X] link``, no ``mass_kg``), the URDF beside it, one ``hanging`` recording per bag with
``gravity_body`` (the base's gravity, default ``[0, 0, -1]``: level), and columns ``t``, ``{X}_fx..tz``,
``q_{joint}``, optionally ``{X}_temp_C``.

Map (TOML; paths relative to it; only ``urdf``, ``[arm] link``, ``wrench_topic``, ``joint_states`` and one
``[[recording]] bag`` are required)::

    urdf = "ur5e.urdf"                  # the arm's URDF: frame B is its root link
    g = 9.81                            # m/s^2
    name = "ur5e"                       # default: the URDF's robot name
    format = "parquet"                  # or "csv"
    max_backward_s = 0.05               # header stamps may step back in bag order by this much (transport)

    [arm]
    transducer = "wrist"                # X of the columns {X}_fx..{X}_tz
    link = "ft_sensor"                  # URDF link whose frame is the sensor's (its load: every link below)
    wrench_topic = "/ft_sensor/wrench"  # geometry_msgs/WrenchStamped: the wrench the load exerts on the sensor
    frame_id = "ft_sensor"              # header.frame_id the readings must carry (default: link; "" allowed)
    wrench_sign = 1                     # -1 for a driver that publishes the opposite wrench
    joint_states = "/joint_states"      # sensor_msgs/JointState topic, or a list of them
    joint_prefix = ""                   # topic joint name = joint_prefix + URDF joint name (a tf prefix)
    max_gap_s = 0.1                     # longest gap of a joint's samples the wrench stamps may fall in
    temperature_topic = "/ft_sensor/temperature"   # optional sensor_msgs/Temperature (degC) -> {X}_temp_C
    temperature_max_gap_s = 10.0
    gravity_body = [0, 0, -1]           # gravity (pointing down) in gravity_link's frame
    gravity_link = "base_link"          # default: the root link (B); reached through fixed joints only
    load_mass_kg = 0.95                 # optional: the tool as weighed (robot.toml's load_mass_kg)

    [[recording]]
    bag = "bags/cal_0"                  # ROS 2 bag folder (sqlite3 or MCAP), a bare .mcap, or a ROS 1 .bag
    name = "wrist"                      # output file stem (default: the bag's name)
    gravity_body = [0, 0, -1]           # this bag's, when the base was tilted differently

Rules (every stamp is a header stamp, int64 ns; ``t`` and the epoch below):

* **clock**: the WrenchStamped header stamps, sorted, one row per distinct stamp (repeats: the first kept,
  counted). ``t = (stamp - epoch_ns) * 1e-9`` with ``epoch_ns`` the earliest header stamp of any stream used
  in any bag of the map, written to ``dataset.toml [ingest] epoch_ns``: ``epoch_ns + round(t * 1e9)`` gives
  each row's header stamp back to the nanosecond (float64 resolves 1 ns for sessions under ~50 days).
* **joints**: the columns are the movable joints that move the sensor (root to ``link``) or its load (below
  ``link``), in URDF order. A JointState's positions are taken by name (the order may change between
  messages; a message naming only some joints gives samples to those). With several topics, or several
  publishers on one, a joint's samples are the union over them, sorted by header stamp, a repeated stamp
  keeping the first. Names that are no URDF joint (a gripper's, another description's) are left out (logged). ``continuous`` joints are unwrapped in stamp order (their column keeps growing over full
  turns); revolute and prismatic positions are taken as published. Positions are interpolated linearly in
  the header stamps onto the clock; clock rows before a joint's first or after its last sample are dropped
  (counted); a gap between two samples longer than ``max_gap_s`` with a clock row inside it is an error
  naming the topic, the joint and the time, never bridged.
* **temperature**: linear in the header stamps between samples; rows up to ``temperature_max_gap_s`` before
  the first or after the last sample take that sample's value, rows farther out are dropped (counted); a gap
  longer than ``temperature_max_gap_s`` with a clock row inside is an error.
* **readings**: ``wrench_sign * [fx, fy, fz, tx, ty, tz]`` as published, offset included; rows with a NaN
  or infinite value are dropped (counted).

Errors name the bag, the topic, the map key or message field, and what was expected: a missing topic, an
empty bag, a topic of another type, a needed joint never published (with the names seen), a map key naming a
link or joint the URDF lacks, zero stamps, stamps stepping back more than ``max_backward_s`` (out of order),
frames other than ``frame_id``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.data import JOINT_PREFIX, TEMP_SUFFIX, WRENCH_COMPONENTS, Dataset, read_urdf_tree, recording_from_frame
from ..core.errors import DataFormatError
from ..core.robot import Robot, Transducer
from .bagio import BagError, BagStreams, Stream, read_streams
from .clock import interp_linear, median_period, sort_unique
from .freeload import link_rotation
from .counts import IngestCounts, IngestResult, check_not_backwards, seconds, summary
from .mapfile import RecordingSpec, _get, output_name, recording_tables
from .wire import TEMPERATURE_TYPE

log = logging.getLogger(__name__)

TOP_KEYS = ("urdf", "g", "name", "format", "max_backward_s", "arm", "recording")
ARM_KEYS = ("transducer", "link", "wrench_topic", "frame_id", "wrench_sign", "joint_states", "joint_prefix", "max_gap_s",
            "temperature_topic", "temperature_max_gap_s", "gravity_body", "gravity_link", "load_mass_kg")
RECORDING_KEYS = ("bag", "name", "kind", "gravity_body")


@dataclass(frozen=True)
class ArmSpec:
    """The ``[arm]`` table, validated: ``joints`` the URDF joints written as ``q_{joint}``, ``continuous`` those
    unwrapped; ``gravity_body`` in B (the root link)."""

    transducer: str
    link: str
    wrench_topic: str
    frame_id: str
    wrench_sign: float
    joint_topics: tuple[str, ...]
    joint_prefix: str
    joints: tuple[str, ...]
    continuous: frozenset[str]
    max_gap_s: float
    temperature_topic: str | None
    temperature_max_gap_s: float
    gravity_body: np.ndarray


@dataclass(frozen=True)
class ArmMap:
    """An arm's ingest map (module docstring). ``fmt`` and ``time_source`` as :class:`.mapfile.IngestMap`'s."""

    path: Path
    robot: Robot
    arm: ArmSpec
    recordings: tuple[RecordingSpec, ...]
    fmt: str = "parquet"
    max_backward_s: float = 0.05
    time_source: str = "header"

    @property
    def legs(self) -> tuple[str, ...]:
        return self.robot.legs


# ----------------------------------------------------------------------------- the map


def _seconds_key(d: dict, key: str, where: str, default: float, *, allow_zero: bool = False) -> float:
    v = _get(d, key, where, (int, float), default)
    if not (v >= 0 if allow_zero else v > 0) or not np.isfinite(v):
        raise DataFormatError(f"{where}: key '{key}' = {v!r} should be a {'non-negative' if allow_zero else 'positive'} number of seconds")
    return float(v)


def _gravity(v, where: str, key: str) -> np.ndarray:
    g = np.asarray(v, dtype=float) if isinstance(v, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v) else None
    if g is None or g.shape != (3,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-9:
        raise DataFormatError(f"{where}: key '{key}' should be 3 finite numbers, not all zero (gravity, pointing down), got {v!r}")
    return g / np.linalg.norm(g)


def moving_joints(tree, link: str) -> tuple[str, ...]:
    """The movable joints that move ``link`` relative to the root or move links below it, in URDF order."""
    above = {j.name for j in tree.path_to_root(link)}
    below = {tree.joints[c].name for c in tree.below(link) if c in tree.joints}
    wanted = above | below
    return tuple(n for n in tree.movable if n in wanted)


def read_arm_map(d: dict, path: Path) -> ArmMap:
    """Validate a parsed arm map ``d`` (the file ``path``); errors name the map and the key."""
    where, root = str(path), path.parent
    other = sorted(set(d) - set(TOP_KEYS))
    if other:
        raise DataFormatError(f"{where}: key(s) {other} do not belong in an [arm] map (the arm's sensor is named in [arm]); "
                              f"an [arm] map takes {list(TOP_KEYS)}")
    a = _get(d, "arm", where, dict)
    wa = f"{where} [arm]"
    unknown = sorted(set(a) - set(ARM_KEYS))
    if unknown:
        raise DataFormatError(f"{wa}: unknown key(s) {unknown}; known: {list(ARM_KEYS)}")
    urdf_path = root / _get(d, "urdf", where, str)
    tree = read_urdf_tree(urdf_path, f"{where} key 'urdf'")
    g = float(_get(d, "g", where, (int, float), 9.81))
    if not 1.0 < g < 30.0:
        raise DataFormatError(f"{where}: 'g' = {g} is not a plausible m/s^2 value")
    X = _get(a, "transducer", wa, str, "wrist")
    if not X or any(c in X for c in "/\\\0") or X.startswith("."):
        raise DataFormatError(f"{wa}: key 'transducer' = {X!r} should be a plain name (it names the columns {X}_fx..{X}_tz)")
    link = _get(a, "link", wa, str)
    if link not in tree.links:
        raise DataFormatError(f"{wa}: key 'link' = '{link}' is not a link of {urdf_path.name} (links: {list(tree.links)})")
    joints = moving_joints(tree, link)
    topics = a.get("joint_states")
    topics = [topics] if isinstance(topics, str) else topics
    if not isinstance(topics, list) or not topics or not all(isinstance(t, str) and t for t in topics) or len(set(topics)) != len(topics):
        raise DataFormatError(f"{wa}: key 'joint_states' should be a sensor_msgs/JointState topic or a list of distinct ones, "
                              f"got {a.get('joint_states')!r}")
    wt = _get(a, "wrench_topic", wa, str)
    temp = _get(a, "temperature_topic", wa, str, None)
    named = [wt, *topics] + ([temp] if temp else [])
    if len(set(named)) != len(named):
        raise DataFormatError(f"{wa}: topics {named} name one topic twice; wrench, joint states and temperature are three topics")
    sign = _get(a, "wrench_sign", wa, (int, float), 1)
    if sign not in (1, -1):
        raise DataFormatError(f"{wa}: key 'wrench_sign' = {sign!r} should be 1 or -1")
    gl = _get(a, "gravity_link", wa, str, tree.root)
    R = link_rotation(tree, gl, f"{wa} gravity_link", "the link gravity_body is given in")
    gb = R @ _gravity(a.get("gravity_body", [0.0, 0.0, -1.0]), wa, "gravity_body")
    weighed = _get(a, "load_mass_kg", wa, (int, float), None)
    if weighed is not None and not 0 < weighed < 1e4:
        raise DataFormatError(f"{wa}: key 'load_mass_kg' = {weighed!r}; expected the load's mass as weighed, in kg")
    spec = ArmSpec(X, link, wt, _get(a, "frame_id", wa, str, link), float(sign), tuple(topics), _get(a, "joint_prefix", wa, str, ""),
                   joints, frozenset(n for n in joints if tree.joint(n).type == "continuous"), _seconds_key(a, "max_gap_s", wa, 0.1),
                   temp, _seconds_key(a, "temperature_max_gap_s", wa, 10.0), gb)
    robot = Robot(str(_get(d, "name", where, str, tree.name or urdf_path.stem)), None, g, (X,),
                  {X: Transducer(X, None, None, None, link, None if weighed is None else float(weighed))}, None, urdf_path, tree)
    fmt = _get(d, "format", where, str, "parquet")
    if fmt not in ("parquet", "csv"):
        raise DataFormatError(f"{where}: key 'format' = {fmt!r} should be one of ('parquet', 'csv')")
    return ArmMap(path, robot, spec, _arm_recordings(d, where, root, gb), fmt, _seconds_key(d, "max_backward_s", where, 0.05, allow_zero=True))


def _arm_recordings(d: dict, where: str, root: Path, gravity_body: np.ndarray) -> tuple[RecordingSpec, ...]:
    out: list[RecordingSpec] = []
    names: dict[str, str] = {}
    for e, w in recording_tables(d, where):
        unknown = sorted(set(e) - set(RECORDING_KEYS))
        if unknown:
            raise DataFormatError(f"{w}: unknown key(s) {unknown}; known: {list(RECORDING_KEYS)}")
        bag = root / _get(e, "bag", w, str)
        if _get(e, "kind", w, str, "hanging") != "hanging":
            raise DataFormatError(f"{w}: kind = {e['kind']!r}; an arm's recordings are 'hanging' (the load hangs free below the sensor)")
        gb = _gravity(e["gravity_body"], w, "gravity_body") if "gravity_body" in e else gravity_body
        out.append(RecordingSpec(bag, "hanging", output_name(e, w, bag, names), gb))
    return tuple(out)


# ----------------------------------------------------------------------------- reading and checks


def _check_topics(m: ArmMap, bag: Path, topics: dict[str, str]) -> None:
    a = m.arm
    if not topics:
        raise BagError(f"{bag}: empty bag (no topics); expected [arm] wrench_topic '{a.wrench_topic}' and joint_states {list(a.joint_topics)}")
    listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items()))
    wanted = [("wrench_topic", a.wrench_topic)] + [("joint_states", t) for t in a.joint_topics]
    wanted += [("temperature_topic", a.temperature_topic)] if a.temperature_topic else []
    for key, t in wanted:
        if t not in topics:
            raise BagError(f"{bag}: topic '{t}' of map key [arm] {key} is not in the bag (topics: {listing})")


def _read(m: ArmMap, spec: RecordingSpec, progress: bool | None) -> BagStreams:
    a = m.arm
    return read_streams(spec.bag, wrench_topics=[a.wrench_topic], joint_topics=a.joint_topics,
                        joint_names=[a.joint_prefix + j for j in a.joints],
                        extra_topics={a.temperature_topic: TEMPERATURE_TYPE} if a.temperature_topic else None,
                        check_topics=lambda topics: _check_topics(m, spec.bag, topics), progress=progress)


def _check(m: ArmMap, spec: RecordingSpec, s: BagStreams) -> None:
    a, bag = m.arm, spec.bag
    w = s.wrench[a.wrench_topic]
    if len(w) < 2:
        raise BagError(f"{bag}: topic '{a.wrench_topic}' ([arm] wrench_topic) has {len(w)} message(s); at least 2 are needed")
    other = sorted(f for f in w.frame_ids if f != a.frame_id)
    if other:
        raise BagError(f"{bag}: topic '{a.wrench_topic}' field header.frame_id is {other}, expected '{a.frame_id}' ([arm] "
                       f"{'frame_id' if a.frame_id != a.link else 'link'}): the readings must be in the sensor frame, the frame of URDF "
                       f"link '{a.link}'. If '{other[0]}' names that frame, set [arm] frame_id = '{other[0]}'; if it is another "
                       "frame, fix [arm] link or the driver")
    named: list[tuple[str, Stream]] = [("[arm] wrench_topic", w)]
    prefixed = {a.joint_prefix + x for x in m.robot.tree.movable}
    for j in a.joints:
        n = a.joint_prefix + j
        if n not in s.joints or len(s.joints[n]) < 2:
            seen = sorted(s.joint_names_seen)
            k = len(s.joints[n]) if n in s.joints else 0
            raise BagError(f"{bag}: URDF joint '{j}' (it moves the sensor or its load) has {k} position(s) on {list(a.joint_topics)} "
                           f"(field name; expected '{n}' in at least 2 messages with positions; names seen: {seen}"
                           f"{', none of them a URDF joint: set [arm] joint_prefix?' if seen and not set(seen) & prefixed else ''})")
        for t, by in s.joints_by_topic.items():
            if n in by:
                named.append((f"[arm] joint_states, joint '{n}'", by[n]))
    foreign = sorted(s.joint_names_seen - prefixed)
    if foreign:
        log.info("%s: JointState names %s are not joints of the URDF (with joint_prefix '%s'); not used", bag, foreign, a.joint_prefix)
    if a.temperature_topic:
        tp = s.extra.get(a.temperature_topic)
        if tp is None or len(tp) < 1:
            raise BagError(f"{bag}: topic '{a.temperature_topic}' ([arm] temperature_topic) has no message; expected sensor_msgs/Temperature in degC")
        named.append(("[arm] temperature_topic", tp))
    for key, st in named:
        if np.any(st.stamp_ns <= 0):
            raise BagError(f"{bag}: topic '{st.topic}' ({key}) field header.stamp is zero in {int(np.sum(st.stamp_ns <= 0))} message(s); "
                           "expected the publisher's stamps (the dataset keeps header stamps)")
        check_not_backwards(spec, key, st, m.max_backward_s)


# ----------------------------------------------------------------------------- resampling


def _stamp_text(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d} s"


def _refuse_gaps(bag: Path, st: Stream, what: str, key: str, s_ns: np.ndarray, clock_ns: np.ndarray, max_gap_s: float) -> None:
    """A gap of the sorted stamps ``s_ns`` longer than ``max_gap_s`` with a clock stamp strictly inside: an error."""
    if len(s_ns) < 2:
        return
    width = np.diff(s_ns)
    for i in np.flatnonzero(width > max_gap_s * 1e9):
        lo, hi = s_ns[i], s_ns[i + 1]
        inside = int(np.sum((clock_ns > lo) & (clock_ns < hi)))
        if inside:
            raise BagError(f"{bag}: topic '{st.topic}' ({what}): no sample for {(hi - lo) * 1e-9:.6g} s, from header stamp {_stamp_text(int(lo))} "
                           f"to {_stamp_text(int(hi))}, while {inside} wrench reading(s) fall inside; expected gaps of at most {key} = "
                           f"{max_gap_s:g} s (values are interpolated onto the wrench stamps, never across a longer gap). Raise {key} "
                           "if the arm was still, or cut the bag there")


def resample_arm(m: ArmMap, spec: RecordingSpec, s: BagStreams, epoch_ns: int) -> tuple[pd.DataFrame, IngestCounts]:
    """One bag's streams on its wrench clock as a table with the format's columns, and its :class:`.counts.IngestCounts`."""
    a, bag = m.arm, spec.bag
    w = s.wrench[a.wrench_topic]
    clock_ns, vals, n_dup = sort_unique(w.stamp_ns, w.values)
    t = seconds(clock_ns, epoch_ns)
    period = median_period(t) if len(t) > 1 else 0.0
    dt = np.diff(t)
    clock_gaps = int(np.sum(np.round(dt[dt > 1.5 * period] / period) - 1)) if period > 0 else 0
    keep = np.ones(len(t), dtype=bool)
    cols: dict[str, np.ndarray] = {"t": t}
    for i, c in enumerate(WRENCH_COMPONENTS):
        cols[f"{a.transducer}_{c}"] = a.wrench_sign * vals[:, i]
    outside: dict[str, int] = {}
    for j in a.joints:
        st = s.joints[a.joint_prefix + j]
        sj, pj, _ = sort_unique(st.stamp_ns, st.values[:, 0])
        ok = np.isfinite(pj)                                    # a NaN position is no sample
        sj, pj = sj[ok], pj[ok]
        _refuse_gaps(bag, st, f"field position of joint '{j}'", "[arm] max_gap_s", sj, clock_ns, a.max_gap_s)
        if j in a.continuous:       # a continuous joint published wrapped: the shorter way between samples
            pj = np.unwrap(pj)
        r = interp_linear(t, seconds(sj, epoch_ns), pj)
        cols[JOINT_PREFIX + j] = r.values[:, 0]
        outside[j] = int(r.outside.sum())
        keep &= ~r.outside
    temp_out = 0
    if a.temperature_topic:
        st = s.extra[a.temperature_topic]
        sT, vT, _ = sort_unique(st.stamp_ns, st.values[:, 0])
        ok = np.isfinite(vT)
        sT, vT = sT[ok], vT[ok]
        if not len(sT):
            raise BagError(f"{bag}: topic '{st.topic}' field temperature holds no finite value; expected degC")
        _refuse_gaps(bag, st, "field temperature", "[arm] temperature_max_gap_s", sT, clock_ns, a.temperature_max_gap_s)
        tT = seconds(sT, epoch_ns)
        far = (t < tT[0] - a.temperature_max_gap_s) | (t > tT[-1] + a.temperature_max_gap_s)
        cols[f"{a.transducer}{TEMP_SUFFIX}"] = np.interp(t, tT, vT)      # the edge samples held up to the bound
        temp_out = int((far & keep).sum())
        keep &= ~far
    table = np.stack(list(cols.values()), axis=1)
    bad = keep & ~np.all(np.isfinite(table), axis=1)
    keep &= ~bad
    df = pd.DataFrame({c: v[keep] for c, v in cols.items()})
    counts = IngestCounts(name=spec.name, bag=str(bag), n_clock=len(t), n_rows=int(keep.sum()), duplicate_stamps=n_dup,
                          clock_gaps=clock_gaps, joint_outside_span=outside, nan_readings=int(bad.sum()),
                          temperature_outside_span=temp_out)
    return df, counts


def ingest_arm(m: ArmMap, *, progress: bool | None = None) -> IngestResult:
    """Read an arm map's bags into a validated :class:`~ftcal_nlp.core.data.Dataset` (nothing written)."""
    streams = []
    for spec in m.recordings:
        s = _read(m, spec, progress)
        _check(m, spec, s)
        streams.append(s)
    used = [st for s in streams for st in [*s.wrench.values(), *s.joints.values(), *s.extra.values()] if len(st)]
    epoch = int(min(int(st.stamp_ns.min()) for st in used))
    recs, counts = [], []
    for spec, s in zip(m.recordings, streams):
        df, c = resample_arm(m, spec, s, epoch)
        if len(df) < 2:
            raise DataFormatError(f"{spec.bag}: only {len(df)} row(s) left on the wrench clock after alignment ({summary(c)})")
        recs.append(recording_from_frame(df, m.robot, name=spec.name, kind="hanging", gravity_body=spec.gravity_body, source=str(spec.bag)))
        log.info("%s -> %s: %s", spec.bag, spec.name, summary(c))
        counts.append(c)
    return IngestResult(Dataset(m.robot, tuple(recs), None), tuple(counts), epoch, m)
