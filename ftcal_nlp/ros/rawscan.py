"""Message bytes of chosen connections straight from a bag's chunks (ROS 2 MCAP and ROS 1).

Reading a bag message by message through ``rosbags`` costs 3-6 us a message in
Python, most of an ingest. Both formats index their chunks: after each chunk
come, per connection, the receive time and the byte offset of each of its
messages in the uncompressed chunk (MCAP ``MessageIndex`` records, ROS 1
``IndexData`` records). So the file's top-level records are walked once
(seeking over the chunks), then each chunk holding a wanted connection is read
and decompressed once, and its messages' positions are computed from the index
with numpy: :class:`~.wire.Packed` views into the chunk, no object per message.

Record layouts (all little-endian):

* MCAP: magic ``\\x89MCAP0\\r\\n``; record = opcode u8, length u64, content.
  Channel 0x04 = id u16, schema id u16, topic, encoding (strings: u32 length +
  UTF-8); Chunk 0x06 = start u64, end u64, uncompressed size u64, crc u32,
  compression string, records (u64 length + bytes); MessageIndex 0x07 =
  channel u16, u32 length + (log_time u64, offset u64) pairs; Message 0x05 =
  channel u16, sequence u32, log_time u64, publish_time u64, data.
* ROS 1 (``#ROSBAG V2.0``): record = u32 header length, header fields (u32
  length + ``name=value``), u32 data length, data. op 0x05 chunk
  (compression, size), 0x04 index data (ver, conn, count; data: count x (sec
  u32, nsec u32, offset u32)), 0x07 connection (conn, topic; data: fields
  type, md5sum, ...), 0x02 message data (conn, time; data: the message).

Anything unexpected (an unindexed bag, a chunk without an index, an unknown
compression, a position outside its chunk, a record that is not the message
the index says) raises :class:`RawScanError`; the caller then reads the bag
with ``rosbags``.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Iterable, Iterator

import numpy as np

from ..core.errors import DataFormatError
from .wire import Packed

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0\n"


class RawScanError(DataFormatError):
    """The bag cannot be scanned directly (the ``rosbags`` reader may still read it)."""


@dataclass(frozen=True)
class Connection:
    """One connection (MCAP channel, ROS 1 connection): id, topic, ``pkg/msg/Type``, ROS 1 md5sum."""

    id: int
    topic: str
    msgtype: str
    md5sum: str = ""


@dataclass
class Chunk:
    """Where one chunk's bytes are, and its index: connection id -> (receive ns (n,), offset (n,))."""

    file: Path
    pos: int
    size: int
    compression: str
    uncompressed_size: int
    index: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class RawBag:
    """A scanned bag: its connections and chunks, ``cdr`` True for ROS 2."""

    path: Path
    cdr: bool
    connections: dict[int, Connection]
    chunks: list[Chunk]

    def counts(self, ids: Iterable[int]) -> int:
        ids = set(ids)
        return sum(len(t) for c in self.chunks for i, (t, _) in c.index.items() if i in ids)


# ----------------------------------------------------------------------------- helpers


def _read(f: BinaryIO, n: int) -> bytes:
    b = f.read(n)
    if len(b) != n:
        raise RawScanError(f"{f.name}: truncated record")
    return b


def _gather(buf: np.ndarray, at: np.ndarray, dtype: str) -> np.ndarray:
    """Little-endian integers of ``dtype`` at byte offsets ``at`` of ``buf``."""
    size = np.dtype(dtype).itemsize
    if len(at) and (at.min() < 0 or at.max() + size > len(buf)):
        raise RawScanError("an index points outside its chunk")
    return buf[at[:, None] + np.arange(size)].view(dtype)[:, 0].astype(np.int64)


def _decompressor(compression: str):
    if compression in ("", "none"):
        return lambda b, n: b
    if compression == "zstd":
        try:
            from compression import zstd  # Python >= 3.14
        except ImportError:
            try:
                from backports import zstd
            except ImportError:
                raise RawScanError("zstd chunks need backports.zstd") from None
        return lambda b, n: zstd.decompress(b)
    if compression == "lz4":
        import lz4.frame

        return lambda b, n: lz4.frame.decompress(b)
    if compression == "bz2":
        import bz2

        return lambda b, n: bz2.decompress(b)
    raise RawScanError(f"chunk compression {compression!r} not supported here")


def _chunk_bytes(c: Chunk) -> np.ndarray:
    with c.file.open("rb") as f:
        f.seek(c.pos)
        raw = _decompressor(c.compression)(_read(f, c.size), c.uncompressed_size)
    if len(raw) != c.uncompressed_size:
        raise RawScanError(f"{c.file}: chunk at {c.pos} decompresses to {len(raw)} bytes, its record says {c.uncompressed_size}")
    return np.frombuffer(raw, dtype=np.uint8)


# ----------------------------------------------------------------------------- MCAP


def _mcap_string(b: bytes, at: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", b, at)
    return b[at + 4 : at + 4 + n].decode(), at + 4 + n


def _scan_mcap_file(file: Path, connections: dict[int, Connection], chunks: list[Chunk]) -> None:
    with file.open("rb") as f:
        if f.read(8) != MCAP_MAGIC:
            raise RawScanError(f"{file}: not an MCAP file")
        size = file.stat().st_size
        current = None
        while f.tell() < size - 8:
            op, ln = struct.unpack("<BQ", _read(f, 9))
            start = f.tell()
            if op == 0x04:
                b = _read(f, ln)
                cid, _ = struct.unpack_from("<HH", b, 0)
                topic, _ = _mcap_string(b, 4)
                connections.setdefault(cid, Connection(cid, topic, ""))
            elif op == 0x06:
                _, _, usize, _ = struct.unpack("<QQQI", _read(f, 28))
                (n,) = struct.unpack("<I", _read(f, 4))
                compression = _read(f, n).decode()
                (rec_len,) = struct.unpack("<Q", _read(f, 8))
                current = Chunk(file, f.tell(), rec_len, compression, usize)
                chunks.append(current)
            elif op == 0x07:
                b = _read(f, ln)
                (cid,) = struct.unpack_from("<H", b, 0)
                (n,) = struct.unpack_from("<I", b, 2)
                if current is None or n % 16:
                    raise RawScanError(f"{file}: a message index that follows no chunk")
                pairs = np.frombuffer(b, dtype="<u8", count=n // 8, offset=6).reshape(-1, 2).astype(np.int64)
                current.index[cid] = (pairs[:, 0], pairs[:, 1])
            elif op == 0x05:
                raise RawScanError(f"{file}: messages outside chunks (unchunked MCAP)")
            elif op == 0x02:  # footer
                break
            f.seek(start + ln)


def scan_mcap(folder: Path) -> RawBag:
    """A ROS 2 bag folder whose storage is MCAP files (``*.mcap``), or a bare ``.mcap`` file, scanned."""
    connections: dict[int, Connection] = {}
    chunks: list[Chunk] = []
    if folder.is_file():  # a bare file (Foxglove, the mcap CLI): no metadata, one file
        _scan_mcap_file(folder, connections, chunks)
        return _indexed(RawBag(folder, True, connections, chunks), folder)
    meta = (folder / "metadata.yaml").read_text() if (folder / "metadata.yaml").is_file() else ""
    mode = re.search(r"compression_mode:\s*(\S*)", meta)
    if mode and mode.group(1).strip("'\"") not in ("", "none", "NONE"):
        raise RawScanError(f"{folder}: compression_mode {mode.group(1)} (messages or files compressed whole)")
    files = sorted(folder.glob("*.mcap"))
    if not files:
        raise RawScanError(f"{folder}: no .mcap file")
    if len(files) > 1:
        raise RawScanError(f"{folder}: split into several MCAP files (channel ids may differ between them)")
    _scan_mcap_file(files[0], connections, chunks)
    return _indexed(RawBag(folder, True, connections, chunks), files[0])


def _indexed(bag: RawBag, file: Path) -> RawBag:
    if not bag.chunks:
        raise RawScanError(f"{file}: no chunks (unchunked MCAP)")
    for c in bag.chunks:
        if not c.index:
            raise RawScanError(f"{file}: a chunk without message index")
    return bag


def _mcap_messages(buf: np.ndarray, cid: int, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, lengths) of the data of Message records at ``offsets`` of one chunk."""
    if np.any(_gather(buf, offsets, "<u1") != 0x05) or np.any(_gather(buf, offsets + 9, "<u2") != cid):
        raise RawScanError("an MCAP message index does not point at a message of its channel")
    rec_len = _gather(buf, offsets + 1, "<u8")
    return offsets + 31, rec_len - 22


# ----------------------------------------------------------------------------- ROS 1


def _ros1_fields(b: bytes) -> dict[str, bytes]:
    out, at = {}, 0
    while at < len(b):
        (n,) = struct.unpack_from("<I", b, at)
        name, _, value = b[at + 4 : at + 4 + n].partition(b"=")
        out[name.decode()] = value
        at += 4 + n
    return out


def _ros2_name(t: str) -> str:
    pkg, _, name = t.partition("/")
    return f"{pkg}/msg/{name}" if "/msg/" not in t else t


def scan_ros1(file: Path) -> RawBag:
    """A ROS 1 ``.bag`` (format 2.0, indexed), scanned."""
    connections: dict[int, Connection] = {}
    chunks: list[Chunk] = []
    info_counts: dict[int, int] = {}
    with file.open("rb") as f:
        if f.read(13) != ROS1_MAGIC:
            raise RawScanError(f"{file}: not a ROS 1 bag (format 2.0)")
        size = file.stat().st_size
        current = None
        while f.tell() < size:
            (hl,) = struct.unpack("<I", _read(f, 4))
            h = _ros1_fields(_read(f, hl))
            (dl,) = struct.unpack("<I", _read(f, 4))
            op = h.get("op", b"\xff")[0]
            if op == 0x03:
                if struct.unpack("<Q", h["index_pos"])[0] == 0:
                    raise RawScanError(f"{file}: not indexed (still recording, or needs rosbag reindex)")
                f.seek(dl, 1)
            elif op == 0x05:
                current = Chunk(file, f.tell(), dl, h["compression"].decode(), struct.unpack("<I", h["size"])[0])
                chunks.append(current)
                f.seek(dl, 1)
            elif op == 0x04:
                ver, conn, count = (struct.unpack("<I", h[k])[0] for k in ("ver", "conn", "count"))
                if ver != 1 or current is None or dl != 12 * count:
                    raise RawScanError(f"{file}: unexpected index data record (version {ver})")
                a = np.frombuffer(_read(f, dl), dtype="<u4").reshape(-1, 3).astype(np.int64)
                current.index[conn] = (a[:, 0] * 1_000_000_000 + a[:, 1], a[:, 2])
            elif op == 0x07:
                conn = struct.unpack("<I", h["conn"])[0]
                d = _ros1_fields(_read(f, dl))
                connections[conn] = Connection(conn, h["topic"].decode(), _ros2_name(d["type"].decode()), d.get("md5sum", b"").decode())
            elif op == 0x06:  # chunk info: how many messages of each connection a chunk holds
                a = np.frombuffer(_read(f, dl), dtype="<u4").reshape(-1, 2)
                for conn, n in a.tolist():
                    info_counts[conn] = info_counts.get(conn, 0) + n
            elif op == 0x02:
                raise RawScanError(f"{file}: messages outside chunks")
            else:
                f.seek(dl, 1)
    bag = RawBag(file, False, connections, chunks)
    indexed = {i: bag.counts([i]) for i in connections}
    if {i: info_counts.get(i, 0) for i in connections} != indexed:
        raise RawScanError(f"{file}: the chunk indexes and chunk infos count different messages")
    return bag


def _ros1_messages(buf: np.ndarray, cid: int, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, lengths) of the data of message data records at ``offsets`` of one chunk."""
    hl = _gather(buf, offsets, "<u4")
    # Each record header must hold op=2 and this connection; checked on the first of each header length.
    for n in np.unique(hl):
        i = int(np.flatnonzero(hl == n)[0])
        h = _ros1_fields(buf[offsets[i] + 4 : offsets[i] + 4 + n].tobytes())
        if h.get("op") != b"\x02" or struct.unpack("<I", h.get("conn", b"\0\0\0\0\0"))[0] != cid:
            raise RawScanError("a ROS 1 index does not point at a message of its connection")
    dl = _gather(buf, offsets + 4 + hl, "<u4")
    return offsets + 8 + hl, dl


# ----------------------------------------------------------------------------- common


def scan(path: Path) -> RawBag:
    """Scan a ROS 1 ``.bag``, a ROS 2 MCAP bag folder or a bare ``.mcap`` file (else :class:`RawScanError`)."""
    path = Path(path)
    try:
        if path.is_file() and path.suffix == ".bag":
            return scan_ros1(path)
        if path.is_dir() or (path.is_file() and path.suffix == ".mcap"):
            return scan_mcap(path)
    except (struct.error, KeyError, UnicodeDecodeError, ValueError) as exc:
        raise RawScanError(f"{path}: {type(exc).__name__}: {exc}") from exc
    raise RawScanError(f"{path}: neither a .bag file, a .mcap file nor a bag folder")


def batches(bag: RawBag, ids: Iterable[int]) -> Iterator[tuple[int, Packed, np.ndarray, np.ndarray]]:
    """Per chunk (file order) and wanted connection: ``(id, messages, receive ns, tie)``.

    ``tie`` (n,) orders messages of equal receive time as the file does
    (chunk number, then offset), as ``rosbags`` yields them.
    """
    ids = set(ids)
    locate = _ros1_messages if not bag.cdr else _mcap_messages
    for k, c in enumerate(bag.chunks):
        wanted = [i for i in c.index if i in ids]
        if not wanted:
            continue
        buf = _chunk_bytes(c)
        for i in wanted:
            recv, off = c.index[i]
            starts, lengths = locate(buf, i, off)
            if len(lengths) and (lengths.min() < 0 or (starts + lengths).max() > len(buf)):
                raise RawScanError(f"{c.file}: a message runs past the end of its chunk")
            yield i, Packed(buf, starts, lengths), recv, (np.int64(k) << 32) + off
