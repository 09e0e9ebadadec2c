"""Bags of interchange recordings: what a ROS session of a (simulated) dataset would have recorded.

For the ingest's tests and benchmark (issue 9; an arm's session: :func:`write_arm_session`, issue 32).
Each recording becomes one bag:

* one ``WrenchStamped`` topic per leg, in ``ft_{leg}``, at the recording's
  sample times ``epoch_ns + t``;
* ``JointState`` of every shaft at ``1/joint_every`` of that rate and
  ``joint_delay_ns`` late, the angle being the chord of the recording's
  ``phi`` at those instants (the recording is the truth at its own times);
* ``PoseStamped`` of B at the sample times where the recording has an
  orientation: motion-capture dropouts leave no message, as with a real bridge.

Receive times trail the stamps by a transport delay. Messages are serialised
by :func:`.bagio.encode_messages` (``encode=True``) or built as ``rosbags``
message objects (``encode=False``, ~20x slower, independent of :mod:`.wire`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from ..core.data import Dataset, Recording
from ..core.errors import DataFormatError, OutputExistsError
from . import bagio
from .urdf import urdf_text

WRENCH_TOPIC = "/ft/{leg}/wrench"
JOINT_TOPIC = "/joint_states"
JOINT_NAME = "{leg}_shaft"
POSE_TOPIC = "/mocap/body/pose"


def stamps_ns(t: np.ndarray, epoch_ns: int) -> np.ndarray:
    """Integer ns stamps of session times ``t`` (s)."""
    return int(epoch_ns) + np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def recording_series(
    rec: Recording,
    legs: Sequence[str],
    storage: str,
    *,
    epoch_ns: int,
    joint_every: int = 2,
    joint_delay_ns: int = 3_000_000,
    encode: bool = True,
) -> list[bagio.TopicSeries]:
    """The topics of one recording's bag (see the module docstring)."""
    ts = bagio.typestore_for(storage)
    clock = stamps_ns(rec.t, epoch_ns)
    series = []
    for k in legs:
        frame = f"ft_{k}"
        if encode:
            msgs = bagio.encode_messages(storage, bagio.WRENCH_TYPE, clock, frame, rec.wrench[k])
        else:
            msgs = [bagio.wrench_stamped(ts, int(s), frame, w) for s, w in zip(clock, rec.wrench[k])]
        series.append(bagio.TopicSeries(WRENCH_TOPIC.format(leg=k), bagio.WRENCH_TYPE, clock + 1_000_000, msgs))
    js = clock[::joint_every] + int(joint_delay_ns)
    js = js[js <= clock[-1]]
    tj = rec.t[0] + (js - clock[0]) * 1e-9
    pos = np.stack([np.interp(tj, rec.t, rec.phi[k]) for k in legs], axis=1)
    names = [JOINT_NAME.format(leg=k) for k in legs]
    if encode:
        msgs = bagio.encode_messages(storage, bagio.JOINT_TYPE, js, "", pos, names)
    else:
        msgs = [bagio.joint_state(ts, int(s), names, p) for s, p in zip(js, pos)]
    series.append(bagio.TopicSeries(JOINT_TOPIC, bagio.JOINT_TYPE, js + 500_000, msgs))
    if rec.quat is not None:
        ok = np.all(np.isfinite(rec.quat), axis=1)
        ps, q = clock[ok], rec.quat[ok]
        if encode:
            vals = np.concatenate([np.zeros((len(q), 3)), q[:, [1, 2, 3, 0]]], axis=1)
            msgs = bagio.encode_messages(storage, bagio.POSE_TYPE, ps, "world", vals)
        else:
            msgs = [bagio.pose_stamped(ts, int(s), "world", w) for s, w in zip(ps, q)]
        series.append(bagio.TopicSeries(POSE_TOPIC, bagio.POSE_TYPE, ps + 2_000_000, msgs))
    return series


def bag_name(rec: Recording, storage: str) -> str:
    """``{name}.bag`` for ROS 1, the bag folder ``{name}`` for ROS 2."""
    return f"{rec.name}.bag" if storage == "ros1" else rec.name


def session_map(legs: Sequence[str], mass_kg: float, g: float, recordings: Sequence[tuple[str, Recording]], *, urdf: str = "robot.urdf") -> dict:
    """An ingest map (as a dict for ``tomli_w``) of bags ``(path, recording)`` written by :func:`write_session`."""
    entries = []
    for bag, rec in recordings:
        e: dict = {"bag": bag, "kind": rec.kind, "name": rec.name}
        if rec.gravity_body is not None:
            e["gravity_body"] = [float(x) for x in rec.gravity_body]
        entries.append(e)
    return {
        "mass_kg": float(mass_kg),
        "g": float(g),
        "legs": list(legs),
        "urdf": urdf,
        "base_link": "base_link",
        "transducer_links": {k: f"ft_{k}" for k in legs},
        "wrench_topics": {k: WRENCH_TOPIC.format(leg=k) for k in legs},
        "joints": {"topic": JOINT_TOPIC, **{k: JOINT_NAME.format(leg=k) for k in legs}},
        "body_pose": {"topic": POSE_TOPIC},
        "recording": entries,
    }


def write_session(
    ds: Dataset,
    folder: str | Path,
    storage: str | Mapping[str, str] = "mcap",
    *,
    epoch_ns: int = 1_700_000_000 * 10**9,
    names: Sequence[str] | None = None,
    **kw,
) -> Path:
    """Write ``ds`` as ROS bags (one per recording), a URDF of its robot and an ingest map; returns the map.

    ``storage``: one storage for all, or per recording name (``mcap``,
    ``sqlite3``, ``ros1``); ``names``: the recordings to write (default all);
    ``kw``: :func:`recording_series` settings. Nothing is written over.
    """
    import tomli_w

    mass_kg = ds.robot.mass_kg
    if mass_kg is None:  # the map written is of the 'urdf' form, which needs it (DATA_FORMAT section 2)
        raise DataFormatError(f"robot '{ds.robot.name}': no 'mass_kg'; the ingest map written for the bags needs it",
                              column="mass_kg")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    recs = [r for r in ds.recordings if names is None or r.name in names]
    legs = ds.robot.legs
    urdf, mp = folder / "robot.urdf", folder / "map.toml"
    st_of = {r.name: storage if isinstance(storage, str) else storage[r.name] for r in recs}
    for p in [urdf, mp] + [folder / bag_name(r, st_of[r.name]) for r in recs]:
        if p.exists():
            raise OutputExistsError(f"{p} exists; not written over", path=p)
    written = []
    for rec in recs:
        path = folder / bag_name(rec, st_of[rec.name])
        bagio.write_bag(path, recording_series(rec, legs, st_of[rec.name], epoch_ns=epoch_ns, **kw), storage=st_of[rec.name])
        written.append((path.name, rec))
    urdf.write_text(urdf_text(ds.robot))
    mp.write_bytes(tomli_w.dumps(session_map(legs, mass_kg, ds.robot.g, written)).encode())
    return mp


# ----------------------------------------------------------------------------- section 5 (issue 22)

IMU_TOPIC = "/imu/data"


def write_free_session(res, folder: str | Path, storage: str = "mcap", *, imu: str = "orientation",
                       R_B_imu: np.ndarray | None = None, epoch_ns: int = 1_700_000_000 * 10**9, joint_every: int = 2,
                       joint_delay_ns: int = 3_000_000) -> Path:
    """Bags of a free-load simulation (``sim.free.simulate_free`` result) with its robot files and an ingest map;
    returns the map.

    Topics: the transducer's ``WrenchStamped`` at the sample times; ``JointState`` of every ``q_{joint}`` at
    ``1/joint_every`` of that rate, ``joint_delay_ns`` late (chords of the recorded angles); ``sensor_msgs/Imu``
    at the sample times from the recorded orientation ``R_WB``: orientation ``R_W,imu = R_WB R_B,imu`` and the
    specific force at rest ``a = R_W,imu^T [0, 0, g]`` (``R_B_imu`` default identity). The map asks for ``imu``
    (``"orientation"`` or ``"acceleration"``), ``[joint_columns]`` when there are joints, one hanging recording
    without ``gravity_body``.
    """
    import tomli_w

    from ..core.geometry import quat_to_rotation, rotation_to_quat
    from .freeload import IMU_TYPE, imu_message

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cfg, df = res.config, res.frame
    X = cfg.transducer
    R_B_imu = np.eye(3) if R_B_imu is None else np.asarray(R_B_imu, float)
    t = df["t"].to_numpy()
    clock = stamps_ns(t - t[0], epoch_ns)
    ts = bagio.typestore_for(storage)
    w = df[[f"{X}_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy()
    series = [bagio.TopicSeries(f"/ft/{X}/wrench", bagio.WRENCH_TYPE, clock + 1_000_000,
                                bagio.encode_messages(storage, bagio.WRENCH_TYPE, clock, f"ft_{X}", w))]
    joints = [c[2:] for c in df.columns if c.startswith("q_")]
    if joints:
        js = clock[::joint_every] + int(joint_delay_ns)
        js = js[js <= clock[-1]]
        tj = (js - clock[0]) * 1e-9
        pos = np.stack([np.interp(tj, t - t[0], df[f"q_{j}"].to_numpy()) for j in joints], axis=1)
        series.append(bagio.TopicSeries(JOINT_TOPIC, bagio.JOINT_TYPE, js + 500_000,
                                        bagio.encode_messages(storage, bagio.JOINT_TYPE, js, "", pos, joints)))
    R_WB = quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy())
    R_Wi = R_WB @ R_B_imu
    q_imu = rotation_to_quat(R_Wi)
    acc = np.einsum("nji,j->ni", R_Wi, np.array([0.0, 0.0, cfg.g]))
    msgs = [imu_message(ts, int(s), "imu", q, a) for s, q, a in zip(clock, q_imu, acc)]
    series.append(bagio.TopicSeries(IMU_TOPIC, IMU_TYPE, clock + 2_000_000, msgs))
    bag = folder / ("hang.bag" if storage == "ros1" else "hang")
    bagio.write_bag(bag, series, storage=storage)
    robot = dict(res.robot)
    (folder / "robot.toml").write_bytes(tomli_w.dumps(robot).encode())
    if res.urdf_text is not None:
        (folder / robot["urdf"]).write_text(res.urdf_text)
    m: dict = {"robot": "robot.toml", "wrench_topics": {X: f"/ft/{X}/wrench"},
               "imu": {"topic": IMU_TOPIC, "use": imu, "rotation": [[float(x) for x in row] for row in R_B_imu]},
               "recording": [{"bag": bag.name, "kind": "hanging", "name": cfg.recording}], "format": "csv"}
    if joints:
        m["joint_columns"] = {"topic": JOINT_TOPIC, "names": joints}
    mp = folder / "map.toml"
    mp.write_bytes(tomli_w.dumps(m).encode())
    return mp


# ----------------------------------------------------------------------------- an arm (issue 32 item 5)

#: A UR-like six-joint arm on a fixed base, a sensor link at its flange and a tool link without an <inertial> (the
#: tool left out, as in most arm URDFs: a rigid payload). ``wrist_3`` is continuous (published wrapped).
ARM_URDF = """<?xml version="1.0"?>
<robot name="arm6">
  <link name="base_link"/><link name="shoulder"/><link name="upper_arm"/><link name="forearm"/>
  <link name="wrist1"/><link name="wrist2"/><link name="flange"/><link name="ft_sensor"/><link name="tool"/>
  <joint name="shoulder_pan" type="revolute"><parent link="base_link"/><child link="shoulder"/><origin xyz="0 0 0.1625"/><axis xyz="0 0 1"/><limit lower="-3.14" upper="3.14" effort="150" velocity="3.14"/></joint>
  <joint name="shoulder_lift" type="revolute"><parent link="shoulder"/><child link="upper_arm"/><origin xyz="0 0 0" rpy="1.5707963267948966 0 0"/><axis xyz="0 0 1"/><limit lower="-3.14" upper="0" effort="150" velocity="3.14"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper_arm"/><child link="forearm"/><origin xyz="-0.425 0 0"/><axis xyz="0 0 1"/><limit lower="-2.8" upper="2.8" effort="150" velocity="3.14"/></joint>
  <joint name="wrist_1" type="revolute"><parent link="forearm"/><child link="wrist1"/><origin xyz="-0.3922 0 0.1333"/><axis xyz="0 0 1"/><limit lower="-3.14" upper="3.14" effort="28" velocity="3.14"/></joint>
  <joint name="wrist_2" type="revolute"><parent link="wrist1"/><child link="wrist2"/><origin xyz="0 -0.0997 0" rpy="1.5707963267948966 0 0"/><axis xyz="0 0 1"/><limit lower="-3.14" upper="3.14" effort="28" velocity="3.14"/></joint>
  <joint name="wrist_3" type="continuous"><parent link="wrist2"/><child link="flange"/><origin xyz="0 0.0996 0" rpy="-1.5707963267948966 0 0"/><axis xyz="0 0 1"/></joint>
  <joint name="ft_mount" type="fixed"><parent link="flange"/><child link="ft_sensor"/><origin xyz="0 0 0.01" rpy="0 0 0.3"/></joint>
  <joint name="tool_mount" type="fixed"><parent link="ft_sensor"/><child link="tool"/><origin xyz="0 0 0.03"/></joint>
</robot>
"""


@dataclass(frozen=True)
class ArmSession:
    """A simulated arm session written as a bag: what was written and the truth.

    ``wrench_stamp_ns`` (N,) the WrenchStamped header stamps; ``wrench`` (N, 6) the readings published;
    ``q(t_s)`` the true joint positions (dict of (n,) rad, unwrapped) at seconds ``t_s`` since ``t0_ns``;
    ``temperature(t_s)`` the true temperature; ``truth`` mass, CoM (ft), offset, mounting rotation vector
    (true ft relative to the URDF's, rad, in its axes), noise; ``map`` the ingest map written.
    """

    map: Path
    t0_ns: int
    wrench_stamp_ns: np.ndarray
    wrench: np.ndarray
    joints: tuple[str, ...]
    q: Callable[[np.ndarray], dict]
    temperature: Callable[[np.ndarray], np.ndarray]
    truth: dict


ARM_TRUTH = {"mass_kg": 0.84, "com_m": [0.008, -0.006, 0.085], "offset": [3.4, -3.2, 1.6, -0.036, -0.15, -0.011],
             "mount_rotvec": [0.004, -0.006, -0.035], "noise": [0.04, 0.04, 0.04, 0.002, 0.002, 0.002]}


def _min_jerk_path(poses: np.ndarray, hold_s: float, move_s: float) -> Callable[[np.ndarray], np.ndarray]:
    """``q(t)`` (n, J) of holds ``poses`` (H, J) of ``hold_s`` joined by minimum-jerk moves of ``move_s``."""
    period = hold_s + move_s

    def q(t: np.ndarray) -> np.ndarray:
        t = np.clip(np.asarray(t, dtype=float), 0.0, None)
        i = np.minimum((t // period).astype(int), len(poses) - 1)
        u = np.clip((t - i * period - hold_s) / move_s, 0.0, 1.0) if move_s > 0 else np.zeros_like(t)
        u[i == len(poses) - 1] = 0.0
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        nxt = np.minimum(i + 1, len(poses) - 1)
        return poses[i] + (poses[nxt] - poses[i]) * s[:, None]

    return q


def write_arm_session(folder: str | Path, storage: str = "mcap", *, seed: int = 0, holds: int = 14, hold_s: float = 2.0,
                      move_s: float = 1.5, rate_hz: float = 100.0, joint_rate_hz: float = 250.0, truth: dict | None = None,
                      t0_ns: int = 1_700_000_000_123_456_789, temperature_hz: float | None = 2.0, split_joints: str | None = "topics",
                      frame_id: str = "ft_sensor", name: str = "wrist") -> ArmSession:
    """An arm's session (``ARM_URDF``, the tool ``truth``, default ``ARM_TRUTH``) as one ROS bag, the URDF and an
    ``[arm]`` ingest map (``ros/arm.py``) in ``folder``.

    Motion: ``holds`` joint-space holds drawn uniformly within 80 % of each joint's limits (``wrist_3``, continuous,
    over 0..5.5 rad: it crosses +-pi) joined by minimum-jerk moves. Topics, every stamp an arbitrary nanosecond:

    * ``/ft_sensor/wrench`` WrenchStamped in ``frame_id`` at ``rate_hz`` (stamps jittered by up to 50 us): the
      quasi-static payload ``[m g_ft, c x m g_ft]`` in the true sensor frame (URDF's turned by ``mount_rotvec``)
      plus offset plus white noise;
    * JointState at ``joint_rate_hz`` on its own clock, positions exact at their stamps, ``wrist_3`` wrapped to
      (-pi, pi]; the name order alternates between two permutations; ``split_joints = "topics"``: the first three
      joints on ``/arm/joint_states``, the other three on ``/wrist/joint_states``; ``"messages"``: both halves on
      ``/joint_states`` as two messages of one stamp; None: all six in one message on ``/joint_states``;
    * ``/ft_sensor/temperature`` Temperature at ``temperature_hz`` (None: no topic), 24 degC + a slow drift (no
      effect on the readings).

    Receive times trail the stamps by 0.5-2 ms, so topics interleave in the bag as recorded.
    """
    import tomli_w

    from ..core.kinematics import load_tree
    from ..sim.free import gravity_in_ft, payload_readings, true_rotation

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    truth = dict(ARM_TRUTH if truth is None else truth)
    urdf = folder / "arm6.urdf"
    bag = folder / (f"{name}.bag" if storage == "ros1" else name)
    mp = folder / "map.toml"
    for p in (urdf, bag, mp):
        if p.exists():
            raise OutputExistsError(f"{p} exists; not written over", path=p)
    urdf.write_text(ARM_URDF)
    tree = load_tree(urdf)
    joints = tree.movable
    rng = np.random.default_rng(seed)
    lo = np.array([tree.joint(j).lower if tree.joint(j).lower is not None else 0.0 for j in joints])
    hi = np.array([tree.joint(j).upper if tree.joint(j).upper is not None else 5.5 for j in joints])
    mid, half = (lo + hi) / 2, 0.4 * (hi - lo)
    poses = rng.uniform(mid - half, mid + half, (holds, len(joints)))
    poses[0, joints.index("wrist_3")] = 0.5               # starts within (-pi, pi]: unwrapping gives the truth back
    path = _min_jerk_path(poses, hold_s, move_s)
    duration = holds * (hold_s + move_s) - move_s
    # wrench stamps: the nominal period with up to 50 us of jitter, every one an arbitrary ns
    n = int(duration * rate_hz)
    w_ns = t0_ns + np.round(np.arange(n) * 1e9 / rate_hz).astype(np.int64) + rng.integers(0, 50_000, n)
    tw = (w_ns - t0_ns) * 1e-9
    qw = path(tw)
    R_nom = tree.pose(tree.root, "ft_sensor", {j: qw[:, i] for i, j in enumerate(joints)}, n)[0]
    g_ft = gravity_in_ft(np.broadcast_to(np.eye(3), (n, 3, 3)), true_rotation(R_nom, np.asarray(truth["mount_rotvec"])), 9.81)
    w = payload_readings(g_ft, truth["mass_kg"], np.asarray(truth["com_m"]), np.asarray(truth["offset"]))
    w = w + rng.normal(size=(n, 6)) * np.asarray(truth["noise"])
    series = [bagio.TopicSeries("/ft_sensor/wrench", bagio.WRENCH_TYPE, w_ns + rng.integers(500_000, 2_000_000, n),
                                bagio.encode_messages(storage, bagio.WRENCH_TYPE, w_ns, frame_id, w))]
    # joint states on their own clock, 1.3 ms after the first wrench stamp
    nj = int((duration - 0.01) * joint_rate_hz)
    j_ns = t0_ns + 1_300_017 + np.round(np.arange(nj) * 1e9 / joint_rate_hz).astype(np.int64)
    qj = path((j_ns - t0_ns) * 1e-9)
    k3 = joints.index("wrist_3")
    qj[:, k3] = (qj[:, k3] + np.pi) % (2 * np.pi) - np.pi
    splits: dict[str | None, list[tuple[str, list[int]]]] = {
        "topics": [("/arm/joint_states", [0, 1, 2]), ("/wrist/joint_states", [3, 4, 5])],
        "messages": [("/joint_states", [0, 1, 2]), ("/joint_states", [3, 4, 5])]}
    groups = splits.get(split_joints, [("/joint_states", list(range(6)))])
    by_topic: dict[str, tuple[list, list]] = {}
    for topic, idx in groups:
        msgs, recv = by_topic.setdefault(topic, ([], []))
        for parity, order in ((0, idx), (1, idx[::-1])):        # two name orders, alternating
            sel = np.arange(parity, nj, 2)
            msgs += bagio.encode_messages(storage, bagio.JOINT_TYPE, j_ns[sel], "", qj[np.ix_(sel, np.asarray(order))], [joints[i] for i in order])
            recv.append(j_ns[sel] + 700_000 + idx[0] * 1000)
    for topic, (msgs, recv) in by_topic.items():
        series.append(bagio.TopicSeries(topic, bagio.JOINT_TYPE, np.concatenate(recv), msgs))

    def temp(t_s: np.ndarray) -> np.ndarray:
        return 24.0 + 1.5 * (1 - np.exp(-np.asarray(t_s) / 30.0))

    topics = {"wrench_topic": "/ft_sensor/wrench", "joint_states": list(by_topic), "link": "ft_sensor", "transducer": "wrist"}
    if frame_id != "ft_sensor":
        topics["frame_id"] = frame_id
    if temperature_hz:
        nt = int(duration * temperature_hz) + 1
        t_ns = t0_ns + 250_000_003 + np.round(np.arange(nt) * 1e9 / temperature_hz).astype(np.int64)
        vals = np.c_[temp((t_ns - t0_ns) * 1e-9), np.full(nt, 0.01)]
        series.append(bagio.TopicSeries("/ft_sensor/temperature", bagio.TEMPERATURE_TYPE, t_ns + 1_000_000,
                                        bagio.encode_messages(storage, bagio.TEMPERATURE_TYPE, t_ns, "ft_sensor", vals)))
        topics["temperature_topic"] = "/ft_sensor/temperature"
    bagio.write_bag(bag, series, storage=storage)
    m = {"urdf": urdf.name, "format": "csv", "arm": topics, "recording": [{"bag": bag.name, "name": name}]}
    mp.write_bytes(tomli_w.dumps(m).encode())

    def q_of(t_s: np.ndarray) -> dict:
        v = path(t_s)
        return {j: v[:, i] for i, j in enumerate(joints)}

    return ArmSession(mp, t0_ns, w_ns, w, joints, q_of, temp, truth)
