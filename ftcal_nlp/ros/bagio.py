"""Reading and writing ROS bags with ``rosbags`` (pure Python, no ROS installation).

Reading: any bag ``rosbags.highlevel.AnyReader`` opens (a ROS 2 bag folder with
sqlite3 or MCAP storage, or a ROS 1 ``.bag``) is turned into plain arrays, one
:class:`Stream` per topic (per joint for ``sensor_msgs/JointState``), with both
the header stamps and the bag's receive stamps in integer nanoseconds.

* ``geometry_msgs/WrenchStamped`` -> (N, 6) ``[fx, fy, fz, tx, ty, tz]``, N and N*m,
  in the frame ``header.frame_id``;
* ``sensor_msgs/JointState`` -> per joint name, (N, 1) ``position`` (rad);
* ``geometry_msgs/PoseStamped`` -> (N, 4) ``[qw, qx, qy, qz]`` (ROS stores
  ``x, y, z, w``); the pose of the tracked body in ``header.frame_id``, i.e. a
  quaternion mapping body vectors to world vectors. Samples with a non-finite
  or zero quaternion (some bridges publish these while tracking is lost) are
  left out and counted.

Writing: :func:`write_bag` writes any list of topics to a ROS 2 bag (MCAP or
sqlite3) or a ROS 1 bag; the message builders (:func:`wrench_stamped`,
:func:`joint_state`, :func:`pose_stamped`) build messages of the typestore the
storage needs (ROS 1 headers carry ``seq``). :func:`write_ground_wrench_bag`
writes the corrected ground contact wrenches (``OUTPUT_FORMAT.md``) for Foxglove
or PlotJuggler.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from ..data import DataFormatError

WRENCH_TYPE = "geometry_msgs/msg/WrenchStamped"
JOINT_TYPE = "sensor_msgs/msg/JointState"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
STORAGES = ("mcap", "sqlite3", "ros1")
_COMPONENTS = ("fx", "fy", "fz", "tx", "ty", "tz")


class BagError(DataFormatError):
    """A bag cannot be read, or lacks what the map asks of it; the message names the bag."""


@dataclass(frozen=True)
class Stream:
    """Samples of one topic (or one joint of a JointState topic), in bag order.

    ``stamp_ns`` (N,) header stamps and ``receive_ns`` (N,) bag receive times,
    int64 nanoseconds; ``values`` (N, d); ``frame_ids`` the distinct
    ``header.frame_id`` values seen; ``n_invalid`` samples left out as invalid.
    """

    topic: str
    stamp_ns: np.ndarray
    receive_ns: np.ndarray
    values: np.ndarray
    frame_ids: frozenset[str]
    n_invalid: int = 0

    def __len__(self) -> int:
        return len(self.stamp_ns)


@dataclass(frozen=True)
class BagStreams:
    """What one bag holds for a map: wrench streams by topic, shaft streams by
    joint name, the body pose stream (or None), every topic's type, and every
    joint name seen on the joint topic."""

    path: Path
    topics: dict[str, str]
    wrench: dict[str, Stream]
    joints: dict[str, Stream]
    joint_names_seen: frozenset[str]
    pose: Stream | None


# ----------------------------------------------------------------------------- reading


def _reader(path: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise BagError(f"{path}: bag not found (expected a ROS 2 bag folder or a ROS 1 .bag file)")
    try:
        # Old ROS 2 sqlite3 bags carry no message definitions; the standard ones suffice here.
        return AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
    except Exception as exc:  # rosbags raises several unrelated types for unreadable bags
        raise BagError(f"{path}: cannot open as a ROS bag ({type(exc).__name__}: {exc})") from exc


def bag_topics(path: str | Path) -> dict[str, str]:
    """Topic name -> message type (``pkg/msg/Type``) of every topic in the bag."""
    path = Path(path)
    reader = _reader(path)
    try:
        with reader:
            return {c.topic: c.msgtype for c in reader.connections}
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"{path}: cannot open as a ROS bag ({type(exc).__name__}: {exc})") from exc


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


class _Acc:
    """Accumulates samples of one stream before they become arrays."""

    def __init__(self, topic: str):
        self.topic, self.stamp, self.recv, self.vals, self.frames, self.invalid = topic, [], [], [], set(), 0

    def add(self, stamp: int, recv: int, value, frame: str) -> None:
        self.stamp.append(stamp)
        self.recv.append(recv)
        self.vals.append(value)
        self.frames.add(frame)

    def stream(self, width: int) -> Stream:
        vals = np.asarray(self.vals, dtype=float).reshape(len(self.vals), width)
        return Stream(
            self.topic,
            np.asarray(self.stamp, dtype=np.int64),
            np.asarray(self.recv, dtype=np.int64),
            vals,
            frozenset(self.frames),
            self.invalid,
        )


def read_streams(
    path: str | Path,
    *,
    wrench_topics: Iterable[str],
    joint_topic: str | None = None,
    joint_names: Iterable[str] = (),
    pose_topic: str | None = None,
) -> BagStreams:
    """Read the named topics of one bag into :class:`Stream` arrays in one pass.

    Topics absent from the bag are absent from the result (the caller names the
    map key that asked for them); a topic of the wrong message type raises
    :class:`BagError`.
    """
    path = Path(path)
    wrench_topics = list(wrench_topics)
    joint_names = list(joint_names)
    expected = {t: WRENCH_TYPE for t in wrench_topics}
    if joint_topic:
        expected[joint_topic] = JOINT_TYPE
    if pose_topic:
        expected[pose_topic] = POSE_TYPE
    reader = _reader(path)
    try:
        with reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            for topic, typ in expected.items():
                if topic in topics and topics[topic] != typ:
                    raise BagError(f"{path}: topic '{topic}' has type {topics[topic]}, expected {typ}")
            conns = [c for c in reader.connections if c.topic in expected]
            wr = {t: _Acc(t) for t in wrench_topics if t in topics}
            jn = {n: _Acc(joint_topic) for n in joint_names}
            seen: set[str] = set()
            pose = _Acc(pose_topic) if pose_topic and pose_topic in topics else None
            for conn, recv, raw in reader.messages(connections=conns) if conns else ():
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = _stamp_ns(msg.header)
                frame = msg.header.frame_id
                if conn.topic in wr:
                    f, t = msg.wrench.force, msg.wrench.torque
                    wr[conn.topic].add(stamp, recv, (f.x, f.y, f.z, t.x, t.y, t.z), frame)
                if conn.topic == joint_topic:
                    names = list(msg.name)
                    seen.update(names)
                    pos = np.asarray(msg.position, dtype=float)
                    if len(pos) != len(names):
                        continue  # a velocity- or effort-only message carries no angle
                    where = {n: i for i, n in enumerate(names)}
                    for n, acc in jn.items():
                        if n in where:
                            acc.add(stamp, recv, pos[where[n]], frame)
                if pose is not None and conn.topic == pose_topic:
                    o = msg.pose.orientation
                    q = np.array([o.w, o.x, o.y, o.z], dtype=float)
                    nq = float(np.linalg.norm(q)) if np.all(np.isfinite(q)) else 0.0
                    if nq < 1e-6:
                        pose.invalid += 1
                    else:
                        pose.add(stamp, recv, q / nq, frame)
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"{path}: error while reading ({type(exc).__name__}: {exc})") from exc
    return BagStreams(
        path,
        topics,
        {t: a.stream(6) for t, a in wr.items()},
        {n: a.stream(1) for n, a in jn.items() if a.stamp},
        frozenset(seen),
        None if pose is None else pose.stream(4),
    )


# ----------------------------------------------------------------------------- messages


def typestore_for(storage: str):
    """The typestore whose message classes a bag of ``storage`` needs (ROS 1: Noetic)."""
    from rosbags.typesys import Stores, get_typestore

    if storage not in STORAGES:
        raise ValueError(f"storage must be one of {STORAGES}, got {storage!r}")
    return get_typestore(Stores.ROS1_NOETIC if storage == "ros1" else Stores.LATEST)


def _header(ts, stamp_ns: int, frame_id: str):
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    stamp = Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))
    if "seq" in Header.__dataclass_fields__:
        return Header(seq=0, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def wrench_stamped(ts, stamp_ns: int, frame_id: str, w: Sequence[float]):
    """``geometry_msgs/WrenchStamped`` with ``w = [fx, fy, fz, tx, ty, tz]`` (N, N*m)."""
    V = ts.types["geometry_msgs/msg/Vector3"]
    W = ts.types["geometry_msgs/msg/Wrench"]
    WS = ts.types[WRENCH_TYPE]
    f = V(x=float(w[0]), y=float(w[1]), z=float(w[2]))
    t = V(x=float(w[3]), y=float(w[4]), z=float(w[5]))
    return WS(header=_header(ts, stamp_ns, frame_id), wrench=W(force=f, torque=t))


def joint_state(ts, stamp_ns: int, names: Sequence[str], positions: Sequence[float], frame_id: str = ""):
    """``sensor_msgs/JointState`` with positions only (rad)."""
    JS = ts.types[JOINT_TYPE]
    return JS(
        header=_header(ts, stamp_ns, frame_id),
        name=list(names),
        position=np.asarray(positions, dtype=np.float64),
        velocity=np.zeros(0, dtype=np.float64),
        effort=np.zeros(0, dtype=np.float64),
    )


def pose_stamped(ts, stamp_ns: int, frame_id: str, quat_wxyz: Sequence[float], position: Sequence[float] = (0.0, 0.0, 0.0)):
    """``geometry_msgs/PoseStamped`` from ``[qw, qx, qy, qz]`` and a position (m)."""
    P = ts.types["geometry_msgs/msg/Point"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    Pose = ts.types["geometry_msgs/msg/Pose"]
    PS = ts.types[POSE_TYPE]
    q = [float(x) for x in quat_wxyz]
    return PS(
        header=_header(ts, stamp_ns, frame_id),
        pose=Pose(position=P(x=float(position[0]), y=float(position[1]), z=float(position[2])), orientation=Q(x=q[1], y=q[2], z=q[3], w=q[0])),
    )


# ----------------------------------------------------------------------------- writing


@dataclass(frozen=True)
class TopicSeries:
    """Messages of one topic to write: ``messages`` built with :func:`typestore_for`
    of the target storage, written at ``receive_ns`` (default: their stamps)."""

    topic: str
    msgtype: str
    receive_ns: np.ndarray
    messages: Sequence[object]


def mcap_supported() -> bool:
    """Whether the installed ``rosbags`` writes ROS 2 bags with MCAP storage."""
    from rosbags.rosbag2 import enums

    return hasattr(enums.StoragePlugin, "MCAP")


def write_bag(path: str | Path, series: Sequence[TopicSeries], *, storage: str = "mcap") -> Path:
    """Write ``series`` to a new bag; messages are written in receive-time order.

    ``storage``: ``mcap`` or ``sqlite3`` (a ROS 2 bag folder at ``path``) or
    ``ros1`` (a ``.bag`` file). An existing ``path`` is never overwritten.
    """
    path = Path(path)
    ts = typestore_for(storage)
    if path.exists():
        raise FileExistsError(f"{path} exists; a bag is never written over")
    if storage == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        writer = Writer1(path)
        serialize = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer as Writer2
        from rosbags.rosbag2.enums import StoragePlugin

        kw = {"storage_plugin": StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3}
        if hasattr(Writer2, "VERSION_LATEST"):
            kw["version"] = Writer2.VERSION_LATEST
        writer = Writer2(path, **kw)
        serialize = ts.serialize_cdr
    with writer:
        queue = []
        for s in series:
            conn = writer.add_connection(s.topic, s.msgtype, typestore=ts)
            if len(s.receive_ns) != len(s.messages):
                raise ValueError(f"topic {s.topic}: {len(s.messages)} messages but {len(s.receive_ns)} receive times")
            queue += [(int(r), i, conn, s.msgtype, m) for i, (r, m) in enumerate(zip(s.receive_ns, s.messages))]
        queue.sort(key=lambda x: (x[0], x[2].id, x[1]))
        for recv, _, conn, typ, msg in queue:
            writer.write(conn, recv, bytes(serialize(msg, typ)))
    return path


def write_ground_wrench_bag(
    path: str | Path,
    t: np.ndarray,
    wrenches: Mapping[str, np.ndarray],
    *,
    frame_id: str = "heading",
    topic_prefix: str = "/ground_wrench",
    epoch_ns: int = 0,
    storage: str | None = None,
) -> Path:
    """Write ground contact wrenches as a ROS 2 bag, one ``WrenchStamped`` topic per foot.

    ``t`` (N,) s since the session epoch (stamps are ``epoch_ns + t``, ns);
    ``wrenches[leg]`` (N, 6) ``[fx, fy, fz, tx, ty, tz]``, N and N*m, in the
    heading frame about the robot's CoM (``OUTPUT_FORMAT.md``). Topics are
    ``{topic_prefix}/{leg}`` and ``{topic_prefix}/total`` (the given
    ``wrenches["total"]``, else the sum over the feet). Storage is MCAP when
    the installed ``rosbags`` supports it, else sqlite3 with a warning.
    """
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or not np.all(np.isfinite(t)):
        raise ValueError("t must be a 1-D array of finite seconds")
    ws = {str(k): np.asarray(v, dtype=float) for k, v in wrenches.items()}
    for k, v in ws.items():
        if v.shape != (len(t), 6):
            raise ValueError(f"wrenches[{k!r}] has shape {v.shape}, expected ({len(t)}, 6)")
    if "total" not in ws:
        if not ws:
            raise ValueError("wrenches is empty")
        ws["total"] = np.sum(list(ws.values()), axis=0)
    if storage is None:
        storage = "mcap" if mcap_supported() else "sqlite3"
        if storage == "sqlite3":
            warnings.warn("the installed rosbags cannot write MCAP; writing a sqlite3 ROS 2 bag instead", stacklevel=2)
    if storage == "ros1":
        raise ValueError("write_ground_wrench_bag writes ROS 2 bags (storage 'mcap' or 'sqlite3')")
    ts = typestore_for(storage)
    stamps = int(epoch_ns) + np.round(t * 1e9).astype(np.int64)
    prefix = topic_prefix.rstrip("/")
    series = [
        TopicSeries(f"{prefix}/{k}", WRENCH_TYPE, stamps, [wrench_stamped(ts, int(s), frame_id, row) for s, row in zip(stamps, v)])
        for k, v in ws.items()
    ]
    return write_bag(path, series, storage=storage)


def ground_wrench_bag_from_frame(path: str | Path, df, legs: Sequence[str], **kw) -> Path:
    """:func:`write_ground_wrench_bag` from a corrected-recording table
    (``OUTPUT_FORMAT.md``: ``t``, ``{leg}_fx..tz``, ``total_fx..tz``); ``kw`` as there."""
    missing = [c for c in ["t"] + [f"{k}_{c}" for k in [*legs, "total"] for c in _COMPONENTS] if c not in df.columns]
    if missing:
        raise DataFormatError(f"corrected recording: missing column(s) {missing}")
    w = {k: df[[f"{k}_{c}" for c in _COMPONENTS]].to_numpy(dtype=float) for k in [*legs, "total"]}
    return write_ground_wrench_bag(path, df["t"].to_numpy(dtype=float), w, **kw)


def read_wrench_topics(path: str | Path, topics: Iterable[str] | None = None) -> dict[str, tuple[np.ndarray, np.ndarray, frozenset[str]]]:
    """Every ``WrenchStamped`` topic of a bag (or the named ones): topic ->
    ``(stamp_ns (N,), wrench (N, 6), frame_ids)``, sorted by stamp."""
    types = bag_topics(path)
    names = [t for t, ty in types.items() if ty == WRENCH_TYPE] if topics is None else list(topics)
    s = read_streams(path, wrench_topics=names)
    out = {}
    for t in names:
        if t not in s.wrench:
            raise BagError(f"{path}: no WrenchStamped topic '{t}' (topics: {sorted(types)})")
        st = s.wrench[t]
        o = np.argsort(st.stamp_ns, kind="stable")
        out[t] = (st.stamp_ns[o], st.values[o], st.frame_ids)
    return out
