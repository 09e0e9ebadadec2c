"""Reading and writing ROS bags with ``rosbags`` (pure Python, no ROS installation).

Reading: any bag ``rosbags.highlevel.AnyReader`` opens (a ROS 2 bag folder with
sqlite3 or MCAP storage, a bare ROS 2 ``.mcap`` file as Foxglove or the mcap CLI
write it (rosbags >= 0.11), or a ROS 1 ``.bag``) is turned into plain arrays, one
:class:`Stream` per topic (per joint for ``sensor_msgs/JointState``), with both
the header stamps and the bag's receive stamps in integer nanoseconds.

* ``geometry_msgs/WrenchStamped`` -> (N, 6) ``[fx, fy, fz, tx, ty, tz]``, N and N*m,
  in the frame ``header.frame_id``;
* ``sensor_msgs/JointState`` -> per joint name, (N, 1) ``position`` (rad), found by name in every message
  that names it (the order of names may change between messages; a message naming some joints only, or
  positions for none, adds samples to the joints it gives positions for); with several JointState topics a
  joint's samples are the union over the topics that name it, in bag order (:func:`merge_streams`);
* ``sensor_msgs/Temperature`` (and any type of :data:`.wire.N_VALUES`, asked for by ``extra_topics``) ->
  (N, d) values, e.g. ``[temperature, variance]``;
* ``geometry_msgs/PoseStamped`` -> (N, 4) ``[qw, qx, qy, qz]`` (ROS stores
  ``x, y, z, w``); the pose of the tracked body in ``header.frame_id``, i.e. a
  quaternion mapping body vectors to world vectors. Samples with a non-finite
  or zero quaternion (some bridges publish these while tracking is lost) are
  left out and counted.

Each bag is read once for all topics; messages are decoded in batches with
numpy at the byte offsets of their layout (:mod:`.wire`, checked against the
``rosbags`` deserialiser), with a progress bar over messages.

Writing: :func:`write_bag` writes any list of topics to a ROS 2 bag (MCAP or
sqlite3) or a ROS 1 bag; the message builders (:func:`wrench_stamped`,
:func:`joint_state`, :func:`pose_stamped`) build messages of the typestore the
storage needs (ROS 1 headers carry ``seq``). :func:`write_ground_wrench_bag`
writes the corrected ground contact wrenches (``OUTPUT_FORMAT.md``) for Foxglove
or PlotJuggler.
"""

from __future__ import annotations

import logging
import shutil
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ..core.data import DataFormatError
from ..core.errors import ConfigError, OutputExistsError
from . import rawscan
from .wire import JOINT_TYPE, N_VALUES, POSE_TYPE, TEMPERATURE_TYPE, WRENCH_TYPE, Group, Packed, decode_batch, encode_batch

STORAGES = ("mcap", "sqlite3", "ros1")
FLUSH_EVERY = 1 << 15  # messages held as raw bytes before a batch is decoded
_COMPONENTS = ("fx", "fy", "fz", "tx", "ty", "tz")


log = logging.getLogger(__name__)


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
    extra: dict = field(default_factory=dict)      # section 5: e.g. "imu" (ros/freeload.py); extra_topics by topic
    joints_by_topic: dict = field(default_factory=dict)   # topic -> joint name -> Stream (before merging)


# ----------------------------------------------------------------------------- reading


def _reader_checks(path: Path) -> None:
    if not path.exists():
        raise BagError(f"{path}: bag not found (expected a ROS 2 bag folder, a bare ROS 2 .mcap file or a ROS 1 .bag file)")
    if path.is_file() and path.suffix not in (".bag", ".mcap"):
        raise BagError(f"{path}: a file not named *.bag or *.mcap; a ROS 1 bag must end in .bag, a bare ROS 2 MCAP file "
                       "(Foxglove, the mcap CLI) in .mcap, a ROS 2 bag is the folder holding metadata.yaml")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise BagError(f"{path}: folder without metadata.yaml; expected a ROS 2 bag folder")


def _reader(path: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    _reader_checks(path)
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


class _TopicBatches:
    """Decoded groups of one topic's messages, with their receive times and a
    tie-break that orders equal receive times as the bag does."""

    def __init__(self, topic: str, msgtype: str, cdr: bool, deserialize, fast: bool):
        self.topic, self.msgtype, self.cdr, self.deserialize, self.fast = topic, msgtype, cdr, deserialize, fast
        self.groups: list[Group] = []
        self.recv_parts: list[np.ndarray] = []
        self.tie_parts: list[np.ndarray] = []
        self.n = 0

    def add(self, raws: Packed | list[bytes], recv: np.ndarray, tie: np.ndarray) -> None:
        if not len(raws):
            return
        for g in decode_batch(raws, self.msgtype, cdr=self.cdr, deserialize=self.deserialize, fast=self.fast):
            self.groups.append(replace(g, rows=g.rows + self.n))
        self.recv_parts.append(np.asarray(recv, dtype=np.int64))
        self.tie_parts.append(np.asarray(tie, dtype=np.int64))
        self.n += len(raws)

    def _stream(self, groups: list[Group], column: str | None, width: int) -> tuple[Stream, np.ndarray]:
        """Samples of ``groups`` in bag order (receive time; ``column``: one joint's position)."""
        if not groups:
            e = np.zeros(0, dtype=np.int64)
            return Stream(self.topic, e, e, np.zeros((0, width)), frozenset()), np.zeros((0, width))
        recv, tie = np.concatenate(self.recv_parts), np.concatenate(self.tie_parts)
        rows = np.concatenate([g.rows for g in groups])
        o = np.lexsort((tie[rows], recv[rows]))
        stamp = np.concatenate([g.stamp_ns for g in groups])[o]
        if column is None:
            vals = np.concatenate([g.values for g in groups])[o]
        else:
            # the groups given with a column are those naming it (joint())
            vals = np.concatenate([g.values[:, (g.names or ()).index(column)] for g in groups])[o][:, None]
        return Stream(self.topic, stamp, recv[rows[o]], vals, frozenset(g.frame_id for g in groups)), vals

    def wrench(self) -> Stream:
        return self._stream(self.groups, None, 6)[0]

    def values(self) -> Stream:
        """Every message's values (N, d) in bag order (a type of :data:`.wire.N_VALUES`)."""
        return self._stream(self.groups, None, N_VALUES[self.msgtype])[0]

    def pose(self) -> Stream:
        """Orientation ``[qw, qx, qy, qz]``, normalised; non-finite or zero ones left out and counted."""
        st, v = self._stream(self.groups, None, 7)
        q = v[:, [6, 3, 4, 5]]
        nq = np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1)
        ok = np.all(np.isfinite(q), axis=1) & (nq >= 1e-6)
        return Stream(self.topic, st.stamp_ns[ok], st.receive_ns[ok], q[ok] / nq[ok, None], st.frame_ids, int((~ok).sum()))

    def names_seen(self) -> frozenset[str]:
        return frozenset(n for g in self.groups for n in g.names or ())

    def joint(self, name: str) -> Stream:
        return self._stream([g for g in self.groups if g.usable and name in (g.names or ())], name, 1)[0]


@dataclass(frozen=True)
class _Source:
    """An open bag: every topic's type, the connections of the wanted topics
    (id -> topic), their message count, and a function yielding batches
    ``(connection id, messages, receive ns, tie)`` in bag order or chunk by chunk."""

    topics: dict[str, str]
    conn_topic: dict[int, str]
    total: int
    cdr: bool
    deserialize: Callable[[bytes, str], object]
    batches: Callable[[], Iterable[tuple[int, Packed | list[bytes], np.ndarray, np.ndarray]]]


def _generic_batches(reader, conns) -> Iterator[tuple[int, list[bytes], np.ndarray, np.ndarray]]:
    """Messages through ``rosbags`` in bag order, handed on every ``FLUSH_EVERY``
    messages so that no more raw byte strings are held at a time; the tie is the
    message's place in the bag."""
    pending: dict[int, tuple[list, list, list]] = {c.id: ([], [], []) for c in conns}

    def drain():
        for cid, (raws, recv, place) in pending.items():
            if raws:
                yield cid, list(raws), np.asarray(recv, dtype=np.int64), np.asarray(place, dtype=np.int64)
                for x in (raws, recv, place):
                    x.clear()

    n = 0
    for conn, recv, raw in reader.messages(connections=conns) if conns else ():
        raws, rcv, place = pending[conn.id]
        raws.append(raw)
        rcv.append(recv)
        place.append(n)
        n += 1
        if n % FLUSH_EVERY == 0:
            yield from drain()
    yield from drain()


def _raw_source(path: Path, wanted: set[str], stack: ExitStack) -> _Source | None:
    """Chunks read directly (:mod:`.rawscan`); None when the bag needs the ``rosbags`` reader."""
    from rosbags.typesys import Stores, get_typestore

    try:
        raw = rawscan.scan(path)
    except rawscan.RawScanError as exc:
        log.debug("%s: read with rosbags (%s)", path, exc)
        return None
    if raw.cdr:
        # Types and message definitions from rosbags (it reads only the summary of an MCAP bag).
        reader = stack.enter_context(_reader(path))
        topics = {c.topic: c.msgtype for c in reader.connections}
        deserialize = reader.deserialize
        counts = {t: raw.counts(i for i, c in raw.connections.items() if c.topic == t) for t in topics}
        if set(c.topic for c in raw.connections.values()) != set(topics) or any(
                counts[c.topic] != sum(x.msgcount for x in reader.connections if x.topic == c.topic) for c in reader.connections):
            log.debug("%s: channels or message counts differ from the bag's summary; read with rosbags", path)
            return None
    else:
        # ROS 1 carries an md5sum per connection: the standard definitions decode only their own.
        ts = get_typestore(Stores.ROS1_NOETIC)
        topics = {c.topic: c.msgtype for c in raw.connections.values()}
        for c in raw.connections.values():
            if c.topic in wanted and c.msgtype in ts.types and ts.generate_msgdef(c.msgtype, ros_version=1)[1] != c.md5sum:
                log.debug("%s: topic %s has a non-standard %s definition; read with rosbags", path, c.topic, c.msgtype)
                return None
        deserialize = ts.deserialize_ros1
    ids = {i: c.topic for i, c in raw.connections.items() if c.topic in wanted}

    def batches():
        try:
            yield from rawscan.batches(raw, ids)
        except rawscan.RawScanError as exc:
            raise BagError(f"{path}: {exc}") from exc

    return _Source(topics, ids, raw.counts(ids), raw.cdr, deserialize, batches)


def _generic_source(path: Path, wanted: set[str], stack: ExitStack) -> _Source:
    reader = stack.enter_context(_reader(path))
    conns = [c for c in reader.connections if c.topic in wanted]
    topics = {c.topic: c.msgtype for c in reader.connections}
    return _Source(topics, {c.id: c.topic for c in conns}, sum(int(c.msgcount) for c in conns), reader.is2,
                   reader.deserialize, lambda: _generic_batches(reader, conns))


def read_streams(
    path: str | Path,
    *,
    wrench_topics: Iterable[str],
    joint_topic: str | None = None,
    joint_names: Iterable[str] = (),
    pose_topic: str | None = None,
    check_topics: Callable[[dict[str, str]], None] | None = None,
    progress: bool | None = None,
    fast: bool = True,
    joint_topics: Sequence[str] = (),
    extra_topics: Mapping[str, str] | None = None,
) -> BagStreams:
    """Read the named topics of one bag into :class:`Stream` arrays in one pass.

    Topics absent from the bag are absent from the result (the caller names the
    map key that asked for them, e.g. in ``check_topics(topics)``, called with
    every topic's type once the bag is open and before any message is read); a
    topic of the wrong message type raises :class:`BagError`.

    ``fast``: ROS 1 and MCAP bags are read chunk by chunk (:mod:`.rawscan`) and
    decoded with numpy (:mod:`.wire`); sqlite3 bags, and bags those cannot
    read, through the ``rosbags`` reader. ``fast=False`` reads and deserialises
    every message with ``rosbags`` (same result, ~10x slower). ``progress``: a
    progress bar over messages on stderr (None: only when stderr is a terminal).

    ``joint_topics``: more JointState topics besides ``joint_topic`` (a joint's samples are merged over them,
    :func:`merge_streams`; ``joints_by_topic`` keeps them apart). ``extra_topics``: topic -> message type (one
    of :data:`.wire.N_VALUES`, e.g. ``sensor_msgs/msg/Temperature``), returned in ``extra`` by topic.
    """
    from tqdm import tqdm

    path = Path(path)
    wrench_topics = list(wrench_topics)
    expected = {t: WRENCH_TYPE for t in wrench_topics}
    all_joint_topics = list(dict.fromkeys(([joint_topic] if joint_topic else []) + list(joint_topics)))
    for t in all_joint_topics:
        expected[t] = JOINT_TYPE
    if pose_topic:
        expected[pose_topic] = POSE_TYPE
    for t, typ in (extra_topics or {}).items():
        if typ not in N_VALUES or expected.get(t, typ) != typ:
            raise ValueError(f"extra topic {t}: type {typ} (one of {sorted(N_VALUES)}, once per topic)")
        expected[t] = typ
    _reader_checks(path)
    try:
        with ExitStack() as stack:
            src = (_raw_source(path, set(expected), stack) if fast else None) or _generic_source(path, set(expected), stack)
            for t, typ in src.topics.items():
                if t in expected and typ != expected[t]:
                    raise BagError(f"{path}: topic '{t}' has type {typ}, expected {expected[t]}")
            if check_topics is not None:
                check_topics(src.topics)
            acc = {t: _TopicBatches(t, typ, src.cdr, (lambda raw, typ=typ: src.deserialize(raw, typ)), fast) for t, typ in expected.items() if t in src.topics}
            with tqdm(total=src.total, unit="msg", unit_scale=True, desc=path.name, disable=None if progress is None else not progress,
                      mininterval=0.5, leave=False) as bar:
                for cid, raws, recv, tie in src.batches():
                    acc[src.conn_topic[cid]].add(raws, recv, tie)
                    bar.update(len(recv))
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"{path}: error while reading ({type(exc).__name__}: {exc})") from exc
    joint_names = list(joint_names)
    seen: frozenset[str] = frozenset()
    by_topic: dict[str, dict[str, Stream]] = {}
    for t in all_joint_topics:
        if t in acc:
            seen |= acc[t].names_seen()
            by_topic[t] = {n: s for n in joint_names if len(s := acc[t].joint(n))}
    joints = {n: merge_streams([by_topic[t][n] for t in by_topic if n in by_topic[t]]) for n in joint_names
              if any(n in d for d in by_topic.values())}
    return BagStreams(
        path,
        src.topics,
        {t: acc[t].wrench() for t in wrench_topics if t in acc},
        joints,
        seen,
        acc[pose_topic].pose() if pose_topic in acc else None,
        {t: acc[t].values() for t in (extra_topics or {}) if t in acc},
        by_topic,
    )


def merge_streams(parts: Sequence[Stream]) -> Stream:
    """One joint's samples from several topics as one stream in bag order (receive time; ties by header stamp).

    Samples are kept as they are: equal header stamps from two topics are two samples here, and the resampling
    keeps the first in stamp order (``clock.sort_unique``). The topic reads ``"/a + /b"``."""
    if len(parts) == 1:
        return parts[0]
    recv = np.concatenate([p.receive_ns for p in parts])
    stamp = np.concatenate([p.stamp_ns for p in parts])
    o = np.lexsort((stamp, recv))
    return Stream(" + ".join(p.topic for p in parts), stamp[o], recv[o], np.concatenate([p.values for p in parts])[o],
                  frozenset().union(*(p.frame_ids for p in parts)), sum(p.n_invalid for p in parts))


# ----------------------------------------------------------------------------- messages


def typestore_for(storage: str):
    """The typestore whose message classes a bag of ``storage`` needs (ROS 1: Noetic)."""
    from rosbags.typesys import Stores, get_typestore

    if storage not in STORAGES:
        raise ConfigError(f"storage must be one of {STORAGES}, got {storage!r}", key="storage")
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


def temperature(ts, stamp_ns: int, frame_id: str, temp_C: float, variance: float = 0.0):
    """``sensor_msgs/Temperature`` (degC; ``variance`` 0: unknown)."""
    return ts.types[TEMPERATURE_TYPE](header=_header(ts, stamp_ns, frame_id), temperature=float(temp_C), variance=float(variance))


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


def encode_messages(storage: str, msgtype: str, stamp_ns: np.ndarray, frame_id: str, values: np.ndarray,
                    names: Sequence[str] | None = None) -> list[bytes]:
    """Serialised messages of one topic, all with ``frame_id`` (and joint ``names``), fast.

    ``values`` (n, d): wrench ``[fx..tz]``; pose ``[px, py, pz, qx, qy, qz, qw]``;
    joint positions (n, len(names)); temperature ``[degC, variance]``. The first message is serialised by
    ``rosbags`` and the rest copied from it with their own stamps and values
    (:func:`.wire.encode_batch`): ~1 us instead of ~20 us a message.
    """
    ts = typestore_for(storage)
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    values = np.asarray(values, dtype=float)
    if len(stamp_ns) == 0:
        return []
    v0 = values[0]
    if msgtype == WRENCH_TYPE:
        msg = wrench_stamped(ts, int(stamp_ns[0]), frame_id, v0)
    elif msgtype == POSE_TYPE:
        msg = pose_stamped(ts, int(stamp_ns[0]), frame_id, [v0[6], v0[3], v0[4], v0[5]], v0[:3])
    elif msgtype == JOINT_TYPE:
        msg = joint_state(ts, int(stamp_ns[0]), list(names or ()), v0, frame_id)
    elif msgtype == TEMPERATURE_TYPE:
        msg = temperature(ts, int(stamp_ns[0]), frame_id, v0[0], v0[1])
    else:
        raise ValueError(f"no encoder for {msgtype}")
    template = bytes(ts.serialize_ros1(msg, msgtype) if storage == "ros1" else ts.serialize_cdr(msg, msgtype))
    return encode_batch(template, msgtype, cdr=storage != "ros1", stamp_ns=stamp_ns, values=values)


COMPRESSIONS = {"ros1": (None, "bz2", "lz4"), "mcap": (None, "zstd", "message"), "sqlite3": (None, "message")}


def write_bag(path: str | Path, series: Sequence[TopicSeries], *, storage: str = "mcap", overwrite: bool = False,
              compression: str | None = None) -> Path:
    """Write ``series`` to a new bag; messages are written in receive-time order.

    ``storage``: ``mcap`` or ``sqlite3`` (a ROS 2 bag folder at ``path``) or
    ``ros1`` (a ``.bag`` file). Messages are message objects of
    :func:`typestore_for` ``(storage)`` or already serialised bytes
    (:func:`encode_messages`). An existing ``path`` is written over only with
    ``overwrite``. ``compression``: ROS 1 chunks ``bz2`` or ``lz4``; MCAP chunks
    ``zstd``; ROS 2 ``message`` (each message zstd-compressed).
    """
    if storage in COMPRESSIONS and compression not in COMPRESSIONS[storage]:
        raise ConfigError(f"compression for {storage} must be one of {COMPRESSIONS[storage]}, got {compression!r}", key="compression")
    path = Path(path)
    ts = typestore_for(storage)
    if path.exists():
        if not overwrite:
            raise OutputExistsError(f"{path} exists; a bag is never written over unless asked (overwrite)", path=path)
        if path.is_dir():
            if not (path / "metadata.yaml").is_file():
                raise OutputExistsError(f"{path} is a folder but not a ROS 2 bag; not written over", path=path)
            shutil.rmtree(path)
        else:
            path.unlink()
    for s in series:
        if len(s.receive_ns) != len(s.messages):
            raise ValueError(f"topic {s.topic}: {len(s.messages)} messages but {len(s.receive_ns)} receive times")
    path.parent.mkdir(parents=True, exist_ok=True)
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

    writer: Writer1 | Writer2
    if storage == "ros1":
        writer1 = Writer1(path)
        if compression:
            writer1.set_compression(getattr(Writer1.CompressionFormat, compression.upper()))
        writer = writer1
        serialize = ts.serialize_ros1
    else:
        from rosbags.rosbag2.enums import StoragePlugin

        # Any: 'version' exists (and is required) only in newer rosbags, hence the hasattr below
        kw: dict[str, Any] = {"storage_plugin": StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3}
        if hasattr(Writer2, "VERSION_LATEST"):
            kw["version"] = Writer2.VERSION_LATEST
        writer2 = Writer2(path, **kw)
        if compression:
            from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

            writer2.set_compression(CompressionMode.STORAGE if compression == "zstd" else CompressionMode.MESSAGE, CompressionFormat.ZSTD)
        serialize = ts.serialize_cdr
        writer = writer2
    with writer:
        conns = [writer.add_connection(s.topic, s.msgtype, typestore=ts) for s in series]
        # receive time, then series, then position: one stable order over all topics
        recv = np.concatenate([np.asarray(s.receive_ns, dtype=np.int64) for s in series]) if series else np.zeros(0, dtype=np.int64)
        which = np.concatenate([np.full(len(s.messages), j) for j, s in enumerate(series)]) if series else np.zeros(0, dtype=int)
        index = np.concatenate([np.arange(len(s.messages)) for s in series]) if series else np.zeros(0, dtype=int)
        for q in np.lexsort((index, which, recv)):
            s, msg = series[which[q]], series[which[q]].messages[index[q]]
            data: bytes | memoryview  # the writers' declared type; a bytearray is passed as a view of the same bytes
            if isinstance(msg, (bytes, memoryview)):
                data = msg
            elif isinstance(msg, bytearray):
                data = memoryview(msg)
            else:
                data = bytes(serialize(msg, s.msgtype))
            writer.write(conns[which[q]], int(recv[q]), data)
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
    overwrite: bool = False,
) -> Path:
    """Write ground contact wrenches as a ROS 2 bag, one ``WrenchStamped`` topic per foot.

    ``t`` (N,) s since the session epoch (stamps are ``epoch_ns + t``, ns);
    ``wrenches[leg]`` (N, 6) ``[fx, fy, fz, tx, ty, tz]``, N and N*m, in the
    heading frame about the robot's CoM (``OUTPUT_FORMAT.md``). Topics are
    ``{topic_prefix}/{leg}`` and ``{topic_prefix}/total`` (the given
    ``wrenches["total"]``, else the sum over the feet). Storage is MCAP when
    the installed ``rosbags`` supports it, else sqlite3 with a warning. An
    existing bag at ``path`` is replaced only with ``overwrite``.
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
            log.warning("%s: the installed rosbags cannot write MCAP; writing a sqlite3 ROS 2 bag instead", path)
    if storage == "ros1":
        raise ValueError("write_ground_wrench_bag writes ROS 2 bags (storage 'mcap' or 'sqlite3')")
    # whole seconds and the fraction apart: t * 1e9 at t ~ 1.6e9 s (Unix time) would round to 256 ns steps
    sec = np.floor(t)
    stamps = int(epoch_ns) + sec.astype(np.int64) * 1_000_000_000 + np.round((t - sec) * 1e9).astype(np.int64)
    if len(stamps) and stamps.min() < 0:
        raise ValueError("stamps epoch_ns + t must not be negative")
    prefix = topic_prefix.rstrip("/")
    series = [TopicSeries(f"{prefix}/{k}", WRENCH_TYPE, stamps, encode_messages(storage, WRENCH_TYPE, stamps, frame_id, v)) for k, v in ws.items()]
    return write_bag(path, series, storage=storage, overwrite=overwrite)


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
