"""Bags of interchange recordings: what a ROS session of a (simulated) dataset would have recorded.

For the ingest's tests and benchmark (issue 9). Each recording becomes one bag:

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

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..data import Dataset, Recording
from ..errors import OutputExistsError
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
    mp.write_bytes(tomli_w.dumps(session_map(legs, ds.robot.mass_kg, ds.robot.g, written)).encode())
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

    from ..geometry import quat_to_rotation, rotation_to_quat
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
