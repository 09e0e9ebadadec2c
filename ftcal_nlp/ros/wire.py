"""Byte layouts of ``WrenchStamped``, ``PoseStamped``, ``JointState`` and ``Temperature``: vectorised decoding and encoding.

A standing bag of a few hundred poses holds about a million messages;
deserialising each into Python objects costs ~20 us a message. Messages of one
topic almost always share one *layout*: the same frame_id, the same joint
names, the same number of values, hence the same byte offsets. So the raw bytes
of a batch are stacked into an (n, L) byte matrix per message length L, the
first message's layout is parsed by hand (:func:`parse_layout`), and every row
whose *layout bytes* (string lengths and characters, sequence counts, the CDR
representation id; never the stamp, values or padding) equal the template's is
decoded at once with numpy at the template's offsets. The remaining rows repeat
this with their own first row.

Each template is checked against the reference deserialiser (``rosbags``, the
bag's own message definitions): a layout that does not decode to the same
stamp, frame and values (a non-standard definition, XCDR2, ...) sends its rows
to the per-message path (:func:`decode_slow`), as does a block with more than
:data:`MAX_LAYOUTS` layouts. The results are the same either way; only the time
differs.

Wire formats (little- or big-endian per the CDR header; ROS 1 is little-endian):

* ROS 2 CDR: 4-byte encapsulation header, then fields aligned to their size
  relative to the end of that header; ``Header = int32 sec, uint32 nanosec,
  string frame_id`` (uint32 length counting a trailing NUL); sequences are a
  uint32 count then elements, aligned to the element size when there are any.
* ROS 1: no header, no alignment; ``Header = uint32 seq, uint32 secs, uint32
  nsecs, string`` (uint32 length, no NUL).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

WRENCH_TYPE = "geometry_msgs/msg/WrenchStamped"
JOINT_TYPE = "sensor_msgs/msg/JointState"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
TEMPERATURE_TYPE = "sensor_msgs/msg/Temperature"
MAX_LAYOUTS = 32  # per block of one message length; more means the slow path is as fast

#: values per message type: wrench [fx fy fz tx ty tz]; pose [px py pz qx qy qz qw] (ROS order);
#: temperature [temperature (degC), variance]
N_VALUES = {WRENCH_TYPE: 6, POSE_TYPE: 7, TEMPERATURE_TYPE: 2}


@dataclass(frozen=True)
class Layout:
    """Byte layout of one message, parsed from a template.

    ``fixed``: byte ranges that must equal the template's for a message to share
    this layout. ``sec_at``: offset of the stamp's seconds (``nanosec`` follows).
    ``values_at``/``n_values``: the float64 values (wrench, pose, or the joint
    positions). ``names``: joint names (JointState), else None.
    """

    fixed: tuple[tuple[int, int], ...]
    sec_at: int
    sec_signed: bool
    byteorder: str
    values_at: int
    n_values: int
    frame_id: str
    names: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Group:
    """Messages of one layout: ``rows`` (m,) their positions in the batch,
    ``stamp_ns`` (m,), ``values`` (m, d) float64; one ``frame_id`` (and joint
    ``names``, with ``values`` the positions, for JointState). ``usable`` is
    False for a JointState whose positions do not match its names one to one
    (a velocity- or effort-only message: it names joints but carries no angle)."""

    rows: np.ndarray
    stamp_ns: np.ndarray
    values: np.ndarray
    frame_id: str
    names: tuple[str, ...] | None = None
    usable: bool = True


class _Cursor:
    """Reads one message's fields in order, tracking offsets; raises on truncation."""

    def __init__(self, raw: bytes, cdr: bool):
        self.raw, self.cdr, self.fixed = raw, cdr, []
        if cdr:
            if len(raw) < 4 or raw[0] != 0 or raw[1] not in (0, 1):
                raise ValueError("not plain CDR (XCDR1) with representation id 0x0000 or 0x0001")
            self.order, self.pos = ("<" if raw[1] == 1 else ">"), 4
            self.fixed.append((0, 2))
        else:
            self.order, self.pos = "<", 0

    def align(self, n: int) -> None:
        if self.cdr:
            self.pos += -(self.pos - 4) % n

    def take(self, n: int) -> int:
        at = self.pos
        if at + n > len(self.raw):
            raise ValueError("message shorter than its fields")
        self.pos += n
        return at

    def u32(self, fixed: bool = True) -> int:
        self.align(4)
        at = self.take(4)
        if fixed:
            self.fixed.append((at, at + 4))
        return struct.unpack_from(self.order + "I", self.raw, at)[0]

    def string(self) -> str:
        n = self.u32()
        at = self.take(n)
        self.fixed.append((at, at + n))
        s = self.raw[at : at + n]
        return (s[:-1] if self.cdr and s.endswith(b"\0") else s).decode("utf-8", errors="replace")

    def f64s(self, n: int) -> int:
        if n:
            self.align(8)
        return self.take(8 * n)


def parse_layout(raw: bytes, msgtype: str, cdr: bool) -> Layout:
    """Layout of one message of ``msgtype`` (raises ``ValueError`` when it does not parse)."""
    c = _Cursor(bytes(raw), cdr)
    if not cdr:
        c.u32(fixed=False)  # seq
    sec_at = c.take(8)
    frame = c.string()
    names = None
    if msgtype in N_VALUES:
        n = N_VALUES[msgtype]
        at = c.f64s(n)
    elif msgtype == JOINT_TYPE:
        names = tuple(c.string() for _ in range(c.u32()))
        n = c.u32()
        at = c.f64s(n)
    else:
        raise ValueError(f"no fast decoder for {msgtype}")
    return Layout(tuple(c.fixed), sec_at, cdr, c.order, at, n, frame, names)


def _columns(fixed: Sequence[tuple[int, int]]) -> np.ndarray:
    return np.concatenate([np.arange(a, b) for a, b in fixed]) if fixed else np.zeros(0, dtype=np.intp)


def _decode_rows(block: np.ndarray, lay: Layout) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (m,) ns and values (m, n_values) of the rows of ``block`` (m, L) with layout ``lay``."""
    o = lay.byteorder
    raw_t = np.ascontiguousarray(block[:, lay.sec_at : lay.sec_at + 8])
    sec = raw_t[:, :4].copy().view(o + ("i4" if lay.sec_signed else "u4"))[:, 0].astype(np.int64)
    nsec = raw_t[:, 4:].copy().view(o + "u4")[:, 0].astype(np.int64)
    vals = np.ascontiguousarray(block[:, lay.values_at : lay.values_at + 8 * lay.n_values]).view(o + "f8")
    return sec * 1_000_000_000 + nsec, vals.astype(np.float64).reshape(len(block), lay.n_values)


def extract(msg, msgtype: str) -> tuple[int, str, np.ndarray, tuple[str, ...] | None]:
    """(stamp ns, frame_id, values, names) of a deserialised message, as :class:`Group` holds them."""
    h = msg.header
    stamp = int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)
    if msgtype == WRENCH_TYPE:
        f, t = msg.wrench.force, msg.wrench.torque
        return stamp, h.frame_id, np.array([f.x, f.y, f.z, t.x, t.y, t.z], dtype=float), None
    if msgtype == POSE_TYPE:
        p, q = msg.pose.position, msg.pose.orientation
        return stamp, h.frame_id, np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=float), None
    if msgtype == JOINT_TYPE:
        return stamp, h.frame_id, np.asarray(msg.position, dtype=float), tuple(msg.name)
    if msgtype == TEMPERATURE_TYPE:
        return stamp, h.frame_id, np.array([msg.temperature, msg.variance], dtype=float), None
    raise ValueError(f"no decoder for {msgtype}")


def _same(a: Group, stamp: int, frame: str, values: np.ndarray, names) -> bool:
    v = a.values[0]
    return (int(a.stamp_ns[0]) == stamp and a.frame_id == frame and a.names == names and v.shape == values.shape
            and bool(np.all((v == values) | (np.isnan(v) & np.isnan(values)))))


class Packed:
    """Messages stored in one byte buffer: message ``i`` is ``buf[starts[i] : starts[i] + lengths[i]]``.

    Built from a list of byte strings (:meth:`from_list`) or pointing into a
    decompressed chunk of a bag (:mod:`.rawscan`), so that no Python object is
    made per message on the fast path.
    """

    def __init__(self, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray):
        self.buf = buf
        self.starts = np.asarray(starts, dtype=np.int64)
        self.lengths = np.asarray(lengths, dtype=np.int64)
        if len(self.starts) and (self.starts.min() < 0 or (self.starts + self.lengths).max() > len(buf)):
            raise ValueError("message positions outside the buffer")

    @classmethod
    def from_list(cls, raws: Sequence[bytes]) -> "Packed":
        lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]) if len(raws) else np.zeros(0, dtype=np.int64)
        return cls(np.frombuffer(b"".join(raws), dtype=np.uint8), starts, lengths)

    def __len__(self) -> int:
        return len(self.starts)

    def __getitem__(self, i) -> bytes:
        a = int(self.starts[i])
        return self.buf[a : a + int(self.lengths[i])].tobytes()

    def block(self, rows: np.ndarray, L: int) -> np.ndarray:
        """(len(rows), L) bytes of messages ``rows``, all of length ``L``."""
        s = self.starts[rows]
        if len(s) > 1 and np.all(np.diff(s) == L):  # back to back: a view
            return self.buf[s[0] : s[0] + len(s) * L].reshape(len(s), L)
        return self.buf[s[:, None] + np.arange(L)]


def decode_slow(raws: Packed, rows: np.ndarray, msgtype: str, deserialize: Callable) -> list[Group]:
    """Per-message decoding with the reference deserialiser; one group per message."""
    out = []
    for r in rows:
        stamp, frame, vals, names = extract(deserialize(raws[r]), msgtype)
        usable = names is None or len(vals) == len(names)
        out.append(Group(np.array([r]), np.array([stamp], dtype=np.int64), vals[None, :], frame, names, usable))
    return out


def decode_batch(raws: Packed | Sequence[bytes], msgtype: str, *, cdr: bool, deserialize: Callable, fast: bool = True) -> list[Group]:
    """Decode a batch of raw messages of one type into :class:`Group` s (rows index ``raws``).

    ``raws``: :class:`Packed` messages or a list of byte strings. ``cdr``: ROS 2
    CDR (True) or ROS 1 (False) bytes; ``deserialize(raw)`` the reference
    deserialiser of this connection; ``fast=False`` decodes every message with it.
    """
    if not isinstance(raws, Packed):
        raws = Packed.from_list(raws)
    n = len(raws)
    if n == 0:
        return []
    if not fast:
        return decode_slow(raws, np.arange(n), msgtype, deserialize)
    order = np.argsort(raws.lengths, kind="stable")
    sorted_len = raws.lengths[order]
    bounds = np.flatnonzero(np.diff(sorted_len)) + 1
    groups: list[Group] = []
    for lo, hi in zip(np.r_[0, bounds], np.r_[bounds, n]):
        L = int(sorted_len[lo])
        groups += _decode_block(raws.block(order[lo:hi], L), order[lo:hi], raws, msgtype, cdr, deserialize)
    return groups


def _decode_block(block: np.ndarray, rows: np.ndarray, raws, msgtype: str, cdr: bool, deserialize: Callable) -> list[Group]:
    """Decode a block of equal-length messages (``rows`` their batch indices)."""
    groups: list[Group] = []
    left = np.arange(len(block))
    for _ in range(MAX_LAYOUTS):
        if not left.size:
            return groups
        try:
            lay = parse_layout(block[left[0]].tobytes(), msgtype, cdr)
        except ValueError:
            groups += decode_slow(raws, rows[left[:1]], msgtype, deserialize)
            left = left[1:]
            continue
        cols = _columns(lay.fixed)
        sub = block[left]
        match = np.all(sub[:, cols] == sub[0, cols], axis=1)
        stamp, vals = _decode_rows(sub[match], lay)
        g = Group(rows[left[match]], stamp, vals, lay.frame_id, lay.names, lay.names is None or lay.n_values == len(lay.names))
        # The template is checked against the reference deserialiser before its rows are trusted.
        ref = extract(deserialize(raws[int(g.rows[0])]), msgtype)
        if _same(g, *ref):
            groups.append(g)
        else:
            groups += decode_slow(raws, g.rows, msgtype, deserialize)
        left = left[~match]
    return groups + decode_slow(raws, rows[left], msgtype, deserialize)


def encode_batch(template: bytes, msgtype: str, *, cdr: bool, stamp_ns: np.ndarray, values: np.ndarray) -> list[bytes]:
    """Raw messages that equal ``template`` but for the stamps (n,) ns and values (n, d).

    ``template``: one message of ``msgtype`` serialised by the reference
    serialiser, whose frame_id (and joint names, and number of values) all
    messages share; ``values`` as :class:`Group` holds them (pose: ``[px py pz
    qx qy qz qw]``).
    """
    lay = parse_layout(template, msgtype, cdr)
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    values = np.asarray(values, dtype=np.float64).reshape(len(stamp_ns), -1)
    if values.shape[1] != lay.n_values:
        raise ValueError(f"{msgtype}: the template holds {lay.n_values} values, got {values.shape[1]} per message")
    if np.any(stamp_ns < 0):
        raise ValueError("stamps must be >= 0 ns")
    o = lay.byteorder
    block = np.empty((len(stamp_ns), len(template)), dtype=np.uint8)
    block[:] = np.frombuffer(template, dtype=np.uint8)
    sec_t = o + ("i4" if lay.sec_signed else "u4")
    block[:, lay.sec_at : lay.sec_at + 4] = (stamp_ns // 1_000_000_000).astype(sec_t).reshape(-1, 1).view(np.uint8)
    block[:, lay.sec_at + 4 : lay.sec_at + 8] = (stamp_ns % 1_000_000_000).astype(o + "u4").reshape(-1, 1).view(np.uint8)
    block[:, lay.values_at : lay.values_at + 8 * lay.n_values] = np.ascontiguousarray(values, dtype=o + "f8").view(np.uint8)
    return [r.tobytes() for r in block]
