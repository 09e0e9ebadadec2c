"""Section-5 streams of a bag (issue 22, ``DATA_FORMAT.md`` section 5): URDF joint positions into ``q_{joint}``
columns, an IMU into ``qw..qz`` or ``gx..gz``, on the recording's clock (the first transducer's wrench stamps).

Map keys (read by :func:`read_free_keys` from :mod:`.mapfile`; all optional)::

    [joint_columns]                  sensor_msgs/JointState -> q_{joint} (rad, m for prismatic)
    topic = "/joint_states"          default: [joints] topic (one joint topic per map)
    names = ["knee", ...]            URDF joints; default: every movable joint of the robot file's URDF
    max_gap_s = 0.25                 rows in a longer gap of a joint's stream are dropped (counted)

    [imu]                            sensor_msgs/Imu of a body-fixed IMU
    topic = "/imu/data"
    use = "orientation"              "orientation": qw..qz; "acceleration": gx..gz (the load must be at rest or
                                     slow: the tool keeps the quasi-static samples only)
    link = "imu_link"                URDF link of the IMU frame, reached from B through fixed joints; or
    rotation = [[1,0,0],[0,1,0],[0,0,1]]   R_B,imu (IMU vectors to B vectors); default: the identity
    max_gap_s = 0.05

Equations (``R_B,imu`` the IMU's mounting in B):

* orientation: ``R_WB = R_W,imu R_B,imu^T``, slerped onto the clock; outside the IMU stream or in a longer gap
  NaN (tracking lost, as the format allows), never bridged;
* acceleration: an accelerometer at rest reads the specific force ``-g`` (pointing up), so the direction of
  gravity (pointing down) in B is ``g_B = -R_B,imu a / |a|``; ``a`` is interpolated linearly onto the clock and
  rows outside the stream or in a longer gap are dropped (a hanging recording needs its gravity), counted;
* ``q_{joint}``: the JointState positions (unwrapped in stream order, so that a continuous joint does not sweep
  the circle between two samples across the +-pi seam), linear in time; rows outside or in a gap dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..core.data import GRAVITY_COLUMNS, JOINT_PREFIX, QUAT_COLUMNS
from ..core.errors import DataFormatError
from .bagio import BagError, Stream
from .clock import interp_linear, slerp_quat, sort_unique

IMU_TYPE = "sensor_msgs/msg/Imu"
IMU_USES = ("orientation", "acceleration")


@dataclass(frozen=True)
class JointColumnsSpec:
    topic: str
    names: tuple[str, ...]
    max_gap_s: float = 0.25


@dataclass(frozen=True)
class ImuSpec:
    topic: str
    use: str
    R_B_imu: np.ndarray
    max_gap_s: float = 0.05


@dataclass(frozen=True)
class FreeKeys:
    """The section-5 tables of a map (None where absent)."""

    joint_columns: JointColumnsSpec | None = None
    imu: ImuSpec | None = None

    @property
    def any(self) -> bool:
        return self.joint_columns is not None or self.imu is not None


# ----------------------------------------------------------------------------- map keys


def _num(v, where: str, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
        raise DataFormatError(f"{where}: key '{key}' should be a positive number of seconds, got {v!r}")
    return float(v)


def read_free_keys(d: dict, where: str, robot, joint_topic: str | None) -> FreeKeys:
    """``[joint_columns]`` and ``[imu]`` of a parsed map ``d`` (module docstring); ``robot`` the map's robot (its
    ``tree`` gives the URDF joints and links), ``joint_topic`` the ``[joints] topic`` if any."""
    jc = imu = None
    tree = getattr(robot, "tree", None)
    if "joint_columns" in d:
        t = d["joint_columns"]
        w = f"{where} [joint_columns]"
        if not isinstance(t, dict):
            raise DataFormatError(f"{w}: should be a table")
        unknown = sorted(set(t) - {"topic", "names", "max_gap_s"})
        if unknown:
            raise DataFormatError(f"{w}: unknown key(s) {unknown}; known: ['max_gap_s', 'names', 'topic']")
        if tree is None:
            raise DataFormatError(f"{w}: q_{{joint}} columns need a URDF: give robot = \"robot.toml\" with urdf = ...")
        topic = t.get("topic", joint_topic)
        if not isinstance(topic, str) or not topic:
            raise DataFormatError(f"{w}: missing key 'topic' (a sensor_msgs/JointState topic; or [joints] topic)")
        if joint_topic and topic != joint_topic:
            raise DataFormatError(f"{w}: topic '{topic}' differs from [joints] topic '{joint_topic}'; one JointState topic per map")
        names = t.get("names", list(tree.movable))
        if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names):
            raise DataFormatError(f"{w}: key 'names' should be a list of distinct URDF joint names, got {names!r}")
        bad = [n for n in names if n not in tree.movable]
        if bad:
            raise DataFormatError(f"{w}: {bad} are not movable joints of the URDF (movable: {list(tree.movable)})")
        jc = JointColumnsSpec(topic, tuple(names), _num(t.get("max_gap_s", 0.25), w, "max_gap_s"))
    if "imu" in d:
        t = d["imu"]
        w = f"{where} [imu]"
        if not isinstance(t, dict):
            raise DataFormatError(f"{w}: should be a table")
        unknown = sorted(set(t) - {"topic", "use", "link", "rotation", "max_gap_s"})
        if unknown:
            raise DataFormatError(f"{w}: unknown key(s) {unknown}; known: ['link', 'max_gap_s', 'rotation', 'topic', 'use']")
        topic = t.get("topic")
        if not isinstance(topic, str) or not topic:
            raise DataFormatError(f"{w}: missing key 'topic' (a sensor_msgs/Imu topic)")
        use = t.get("use", "orientation")
        if use not in IMU_USES:
            raise DataFormatError(f"{w}: key 'use' = {use!r} should be one of {IMU_USES}")
        if "link" in t and "rotation" in t:
            raise DataFormatError(f"{w}: give 'link' or 'rotation', not both")
        if "link" in t:
            R = link_rotation(tree, t["link"], w)
        else:
            R = np.asarray(t.get("rotation", np.eye(3)), dtype=float)
            if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                raise DataFormatError(f"{w}: key 'rotation' should be a proper 3x3 rotation matrix (rows), got {t['rotation']!r}")
        imu = ImuSpec(topic, use, R, _num(t.get("max_gap_s", 0.05), w, "max_gap_s"))
    return FreeKeys(jc, imu)


def link_rotation(tree, link, where: str, what: str = "an IMU giving B's orientation") -> np.ndarray:
    """``R`` (3, 3) mapping ``link`` vectors to B (the URDF's root) vectors; ``link`` must be fixed to B (``what``
    it is, for the error)."""
    if tree is None:
        raise DataFormatError(f"{where}: key 'link' needs a URDF: give robot = \"robot.toml\" with urdf = ...")
    if not isinstance(link, str) or link not in tree.links:
        raise DataFormatError(f"{where}: link {link!r} is not a link of the URDF (links: {list(tree.links)})")
    moving = [j.name for j in tree.path_to_root(link) if j.type != "fixed"]
    if moving:
        raise DataFormatError(f"{where}: link '{link}' moves with joint(s) {moving} relative to B; {what} must be fixed "
                              "to B (fixed joints only)")
    R, _ = tree.pose(tree.root, link, {}, 1)
    return R[0]


# ----------------------------------------------------------------------------- reading


def read_imu(path: str | Path, topic: str) -> Stream:
    """The IMU topic of one bag: ``values`` (N, 7) ``[qw, qx, qy, qz, ax, ay, az]`` in bag order (rosbags reader;
    IMU rates are low enough). A topic of another type is a BagError; an absent one gives an empty stream."""
    from .bagio import _reader

    path = Path(path)
    reader = _reader(path)
    stamps, recv, vals, frames = [], [], [], set()
    try:
        with reader:
            conns = [c for c in reader.connections if c.topic == topic]
            for c in conns:
                if c.msgtype != IMU_TYPE:
                    raise BagError(f"{path}: topic '{topic}' ([imu] topic) has type {c.msgtype}, expected {IMU_TYPE}")
            for conn, t_recv, raw in reader.messages(connections=conns) if conns else ():
                msg = reader.deserialize(raw, conn.msgtype)
                h, q, a = msg.header, msg.orientation, msg.linear_acceleration
                stamps.append(int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec))
                recv.append(int(t_recv))
                vals.append((q.w, q.x, q.y, q.z, a.x, a.y, a.z))
                frames.add(h.frame_id)
    except BagError:
        raise
    except Exception as exc:
        raise BagError(f"{path}: error while reading topic '{topic}' ({type(exc).__name__}: {exc})") from exc
    return Stream(topic, np.asarray(stamps, dtype=np.int64), np.asarray(recv, dtype=np.int64),
                  np.asarray(vals, dtype=float).reshape(-1, 7), frozenset(frames))


def imu_message(ts, stamp_ns: int, frame_id: str, quat_wxyz: Sequence[float], acc: Sequence[float]):
    """``sensor_msgs/Imu`` with an orientation and a linear acceleration (m/s^2); no angular rate, unknown covariances."""
    from .bagio import _header

    V = ts.types["geometry_msgs/msg/Vector3"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    Imu = ts.types[IMU_TYPE]
    q = [float(x) for x in quat_wxyz]
    cov = np.zeros(9, dtype=np.float64)
    return Imu(header=_header(ts, stamp_ns, frame_id), orientation=Q(x=q[1], y=q[2], z=q[3], w=q[0]),
               orientation_covariance=cov.copy(), angular_velocity=V(x=0.0, y=0.0, z=0.0),
               angular_velocity_covariance=cov.copy(),
               linear_acceleration=V(x=float(acc[0]), y=float(acc[1]), z=float(acc[2])),
               linear_acceleration_covariance=cov.copy())


# ----------------------------------------------------------------------------- resampling


@dataclass(frozen=True)
class FreeColumns:
    """Columns (on the whole clock), the rows they keep, and what was dropped or left NaN."""

    columns: dict[str, np.ndarray]
    keep: np.ndarray
    joint_dropped: dict[str, int] = field(default_factory=dict)
    imu_dropped: int = 0
    imu_nan: int = 0


def _quat_mul_R(q_wxyz: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Quaternions of ``R(q) R`` (a constant right factor commutes with slerp)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]]) * Rotation.from_matrix(R)
    return r.as_quat()[:, [3, 0, 1, 2]]


def free_columns(keys: FreeKeys, joints: Mapping[str, Stream], imu: Stream | None, t: np.ndarray,
                 seconds, stamps) -> FreeColumns:
    """``q_{joint}`` and IMU columns on clock ``t`` (s); ``seconds(stamp_ns)`` -> session s, ``stamps(stream)`` the
    map's time source of a stream (header or receive)."""
    keep = np.ones(len(t), dtype=bool)
    cols: dict[str, np.ndarray] = {}
    dropped: dict[str, int] = {}
    if keys.joint_columns is not None:
        for name in keys.joint_columns.names:
            st = joints[name]
            sj, pj, _ = sort_unique(seconds(stamps(st)), st.values[:, 0])
            r = interp_linear(t, sj, np.unwrap(pj), keys.joint_columns.max_gap_s)
            cols[JOINT_PREFIX + name] = r.values[:, 0]
            dropped[name] = int(r.missing.sum())
            keep &= ~r.missing
    n_drop = n_nan = 0
    if keys.imu is not None and imu is not None:
        si, vi, _ = sort_unique(seconds(stamps(imu)), imu.values)
        if keys.imu.use == "orientation":
            q = vi[:, :4]
            nq = np.linalg.norm(q, axis=1)
            ok = np.all(np.isfinite(q), axis=1) & (nq > 1e-6)      # an IMU without orientation sends zeros
            q = _quat_mul_R(q[ok] / nq[ok, None], keys.imu.R_B_imu.T)
            r = slerp_quat(t, si[ok], q, keys.imu.max_gap_s)
            for j, c in enumerate(QUAT_COLUMNS):
                cols[c] = r.values[:, j]
            n_nan = int(r.missing.sum())
        else:
            a = vi[:, 4:7]
            r = interp_linear(t, si, a, keys.imu.max_gap_s)
            g = -(r.values @ keys.imu.R_B_imu.T)
            norm = np.linalg.norm(g, axis=1)
            bad = r.missing | ~np.isfinite(norm) | (norm < 1e-6)
            g = g / np.where(bad, 1.0, norm)[:, None]
            for j, c in enumerate(GRAVITY_COLUMNS):
                cols[c] = g[:, j]
            n_drop = int(bad.sum())
            keep &= ~bad
    return FreeColumns(cols, keep, dropped, n_drop, n_nan)
