"""ROS ingestion (issue 9): bags written from the sample dataset, read back as a dataset.

Three seconds of three sample recordings become three bags in the three
storages (ROS 2 sqlite3, ROS 2 MCAP, ROS 1), with the rates and clocks of a
real session: wrenches at 100 Hz (other legs jittered by up to 3 ms, one
message lost), joints at 50 Hz 3 ms late, wrapped to (-pi, pi] and split over
two publishers, mocap at 100 Hz 4 ms late with a 0.3 s tracking loss and two
NaN poses, receive times later than header stamps. The tolerances on the
interpolated channels are the interpolation errors computed from the source
itself (see ``_chord_bound`` and ``_slerp_bound``).
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from scipy.spatial.transform import Rotation, Slerp

from ftcal_nlp.core.data import DataFormatError, read_dataset, read_recording, read_robot
from ftcal_nlp.ros import bagio
from ftcal_nlp.ros.clock import interp_linear, match_nearest, slerp_quat
from ftcal_nlp.ingest import main as cli_main
from ftcal_nlp.ros.bagio import BagError
from ftcal_nlp.ros.ingest import ingest, write_ingested
from ftcal_nlp.ros.urdf import fixed_pose, load_urdf, robot_from_urdf

from conftest import SAMPLE, require_sample, requires_sample
LEGS = ("FL", "ML", "HL", "FR", "MR", "HR")
BASE_NS = 1_700_000_000 * 10**9  # wall-clock epoch of the fake session
H = 0.01  # wrench period, s
JOINT_OFFSET_NS, JOINT_PERIOD_NS = 3_000_000, 20_000_000
POSE_OFFSET_NS = 4_000_000
R_BM = Rotation.from_euler("z", 90, degrees=True).as_matrix()  # mocap marker frame in B


# ----------------------------------------------------------------------------- URDF


def _rpy(r, p, y):
    """URDF convention, written out independently of yourdfpy: R = Rz(y) Ry(p) Rx(r)."""
    cx, sx, cy, sy, cz, sz = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _joint(name, typ, parent, child, xyz=(0, 0, 0), rpy=(0, 0, 0)):
    axis = '<axis xyz="0 1 0"/>' if typ != "fixed" else ""
    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>' if typ == "revolute" else ""
    return (f'<joint name="{name}" type="{typ}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{" ".join(map(repr, map(float, xyz)))}" rpy="{" ".join(map(repr, map(float, rpy)))}"/>{axis}{limit}</joint>')


# Sample robot.toml poses; FL through a two-joint fixed chain, right side yawed by pi.
MOUNT = {"FL": ((0.2, 0.1, 0.0), (0.05, 0.05, 0.0))}
POSE = {"FL": (0.25, 0.15, 0), "ML": (0.0, 0.15, 0), "HL": (-0.25, 0.15, 0), "FR": (0.25, -0.15, 0), "MR": (0.0, -0.15, 0), "HR": (-0.25, -0.15, 0)}


def write_urdf(path: Path, *, tilt_fl=False, movable_on_chain=None) -> Path:
    links = ["base_link", "mocap_marker", "body_cover"]
    joints = [
        _joint("marker_mount", "fixed", "base_link", "mocap_marker", (0, 0, 0.1), (0, 0, np.pi / 2)),
        _joint("cover_hinge", "revolute", "base_link", "body_cover", (0, 0, 0.05)),
    ]
    for k in LEGS:
        links += [f"ft_{k}", f"leg_{k}", f"mount_{k}"]
        yaw = np.pi if k.endswith("R") else 0.0
        if k == "FL":
            a, b = MOUNT["FL"]
            rpy1, rpy2 = ((0.1, 0.2, 0.3), (-0.2, 0.1, 0.5)) if tilt_fl else ((0, 0, 0), (0, 0, 0))
            joints.append(_joint("mount_FL_joint", "fixed", "base_link", "mount_FL", a, rpy1))
            joints.append(_joint("ft_FL_joint", "fixed", "mount_FL", "ft_FL", b, rpy2))
        else:
            typ = "revolute" if movable_on_chain == k else "fixed"
            joints.append(_joint(f"mount_{k}_joint", typ, "base_link", f"mount_{k}", POSE[k], (0, 0, yaw)))
            joints.append(_joint(f"ft_{k}_joint", "fixed", f"mount_{k}", f"ft_{k}"))
        joints.append(_joint(f"leg_{k}_shaft", "continuous", f"ft_{k}", f"leg_{k}", (0, 0, -0.05)))
    body = "".join(f'<link name="{n}"/>' for n in links) + "".join(joints)
    path.write_text(f'<?xml version="1.0"?><robot name="bigant_urdf">{body}</robot>')
    return path


@requires_sample
def test_urdf_poses_equal_the_chain_of_fixed_joints(tmp_path):
    urdf = write_urdf(tmp_path / "r.urdf", tilt_fl=True)
    robot = robot_from_urdf(urdf, base_link="base_link", transducer_links={k: f"ft_{k}" for k in LEGS}, legs=LEGS, mass_kg=8.18, g=9.81)
    (a, b), R1, R2 = MOUNT["FL"], _rpy(0.1, 0.2, 0.3), _rpy(-0.2, 0.1, 0.5)
    np.testing.assert_allclose(robot.transducers["FL"].rotation, R1 @ R2, atol=1e-12)
    np.testing.assert_allclose(robot.transducers["FL"].position_m, np.add(a, R1 @ np.array(b)), atol=1e-12)
    sample = read_robot(SAMPLE / "robot.toml")
    for k in LEGS[1:]:  # the sample's nominal poses, right side rotated 180 deg about z
        np.testing.assert_allclose(robot.transducers[k].rotation, sample.transducers[k].rotation, atol=1e-12)
        np.testing.assert_allclose(robot.transducers[k].position_m, sample.transducers[k].position_m, atol=1e-12)
    # The pose of B seen from a transducer is the inverse: the common ancestor is found either way.
    R, p = fixed_pose(load_urdf(urdf), "ft_MR", "base_link")
    np.testing.assert_allclose(R, sample.transducers["MR"].rotation.T, atol=1e-12)
    np.testing.assert_allclose(p, -sample.transducers["MR"].rotation.T @ sample.transducers["MR"].position_m, atol=1e-12)


def test_urdf_errors_name_the_link_and_joint(tmp_path):
    links = {k: f"ft_{k}" for k in LEGS}
    urdf = write_urdf(tmp_path / "m.urdf", movable_on_chain="HR")
    with pytest.raises(DataFormatError, match=r"\[transducer_links\] HR.*mount_HR_joint.*revolute"):
        robot_from_urdf(urdf, base_link="base_link", transducer_links=links, legs=LEGS, mass_kg=8.18, g=9.81)
    urdf = write_urdf(tmp_path / "ok.urdf")
    with pytest.raises(DataFormatError, match=r"\[transducer_links\] ML = 'ft_ml' is not a link"):
        robot_from_urdf(urdf, base_link="base_link", transducer_links={**links, "ML": "ft_ml"}, legs=LEGS, mass_kg=8.18, g=9.81)
    with pytest.raises(DataFormatError, match=r"base_link = 'chassis' is not a link"):
        robot_from_urdf(urdf, base_link="chassis", transducer_links=links, legs=LEGS, mass_kg=8.18, g=9.81)
    with pytest.raises(DataFormatError, match=r"cover_hinge"):  # a movable joint between B and the link asked for
        fixed_pose(load_urdf(urdf), "base_link", "body_cover")


# ----------------------------------------------------------------------------- bags from the sample


def _source(file: str, kind: str, start: int, n: int = 300):
    robot = read_robot(require_sample() / "robot.toml")
    gb = {"hang_xpos.csv": [1, 0, 0], "hang_xneg.csv": [-1, 0, 0]}.get(file)
    rec = read_recording(SAMPLE / file, robot, kind=kind, gravity_body=gb)
    i = np.arange(rec.n)
    return rec.select((i >= start) & (i < start + n))


def _wrap(x):
    return np.angle(np.exp(1j * x))


def _truth_quat(rec, s):
    """Source orientation at times ``s`` (s), the piecewise geodesic through the source samples."""
    return Slerp(rec.t, Rotation.from_quat(rec.quat[:, [1, 2, 3, 0]]))(s)


def make_bag(path, storage, rec, *, seed, joint_offset_ns=JOINT_OFFSET_NS, drop=None, pose=True, gap=None, nan_poses=(), marker=False, frames=True):
    """Bag of a source recording; returns the stamps written (ns) for the expectations."""
    rng = np.random.default_rng(seed)
    ts = bagio.typestore_for(storage)
    clock = BASE_NS + np.round(rec.t * 1e9).astype(np.int64)
    series, stamps = [], {"wrench": {}, "recv_min": []}
    for i, k in enumerate(LEGS):
        st = clock if i == 0 else clock + rng.integers(-3_000_000, 3_000_001, len(clock))
        rows = np.arange(len(st))
        if drop is not None and drop[0] == k:
            rows = rows[rows != drop[1]]
        msgs = [bagio.wrench_stamped(ts, int(st[r]), f"ft_{k}" if frames else "", rec.wrench[k][r]) for r in rows]
        recv = st[rows] + 2_000_000 + rng.integers(0, 1_000_000, len(rows))
        series.append(bagio.TopicSeries(f"/ft/{k}/wrench", bagio.WRENCH_TYPE, recv, msgs))
        stamps["wrench"][k] = st[rows]
        stamps.setdefault("rows", {})[k] = rows
        stamps["recv_min"].append(int(recv.min()))
        if i == 0:
            stamps["recv0"] = recv
    js = np.arange(clock[0] + joint_offset_ns, clock[-1] + 1, JOINT_PERIOD_NS)
    jt = (js - BASE_NS) * 1e-9
    msgs, recv = [], []
    for s, tj in zip(js, jt):  # two publishers on one topic: left legs, right legs (+ an unrelated joint)
        for side in ("L", "R"):
            legs = [k for k in LEGS if k.endswith(side)]
            names = [f"leg_{k}_shaft" for k in legs] + (["head_pan"] if side == "L" else [])
            pos = [_wrap(np.interp(tj, rec.t, rec.phi[k])) for k in legs] + ([0.3] if side == "L" else [])
            msgs.append(bagio.joint_state(ts, int(s), names, pos))
            recv.append(s + 1_000_000)
    series.append(bagio.TopicSeries("/joint_states", bagio.JOINT_TYPE, np.array(recv), msgs))
    stamps["joints"] = js
    stamps["recv_min"].append(min(recv))
    if pose:
        ps = clock + POSE_OFFSET_NS
        if gap is not None:
            ps = ps[(ps < clock[gap[0]]) | (ps > clock[gap[1]])]
        q = _truth_quat(rec, np.clip((ps - BASE_NS) * 1e-9, rec.t[0], rec.t[-1]))
        if marker:
            q = q * Rotation.from_matrix(R_BM)  # the bridge publishes the marker's pose: R_WM = R_WB R_BM
        wxyz = q.as_quat()[:, [3, 0, 1, 2]] * np.where(rng.random(len(ps)) < 0.5, -1, 1)[:, None]  # either sign
        wxyz[list(nan_poses)] = np.nan
        msgs = [bagio.pose_stamped(ts, int(s), "world", w, (1.0, 2.0, 0.3)) for s, w in zip(ps, wxyz)]
        series.append(bagio.TopicSeries("/mocap/bigant/pose", bagio.POSE_TYPE, ps + 3_000_000, msgs))
        stamps["pose"] = np.delete(ps, list(nan_poses))
        stamps["recv_min"].append(int(np.delete(ps, list(nan_poses)).min()) + 3_000_000)
    bagio.write_bag(path, series, storage=storage)
    return stamps


def base_map(urdf="robot.urdf", recordings=()):
    return {
        "mass_kg": 8.18,
        "g": 9.81,
        "legs": list(LEGS),
        "urdf": urdf,
        "base_link": "base_link",
        "transducer_links": {k: f"ft_{k}" for k in LEGS},
        "wrench_topics": {k: f"/ft/{k}/wrench" for k in LEGS},
        "joints": {"topic": "/joint_states", **{k: f"leg_{k}_shaft" for k in LEGS}},
        "body_pose": {"topic": "/mocap/bigant/pose"},
        "recording": list(recordings),
    }


def write_map(path: Path, d: dict) -> Path:
    path.write_bytes(tomli_w.dumps(d).encode())
    return path


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("ros_session")
    write_urdf(root / "robot.urdf")
    src = {
        "hang_xpos": _source("hang_xpos.csv", "hanging", 1000),
        "hang_xneg": _source("hang_xneg.csv", "hanging", 1000),
        "standing": _source("standing.parquet", "standing", 300),
    }
    stamps = {
        "hang_xpos": make_bag(root / "hang_xpos", "sqlite3", src["hang_xpos"], seed=1, drop=("ML", 57), pose=False, joint_offset_ns=-7_000_000),
        "hang_xneg": make_bag(root / "hang_xneg", "mcap", src["hang_xneg"], seed=2, drop=("FL", 120), pose=False),
        "standing": make_bag(root / "standing.bag", "ros1", src["standing"], seed=3, gap=(150, 180), nan_poses=(60, 61)),
    }
    recs = [
        {"bag": "hang_xpos", "kind": "hanging", "gravity_body": [1, 0, 0]},
        {"bag": "hang_xneg", "kind": "hanging", "gravity_body": [-1, 0, 0]},
        {"bag": "standing.bag", "kind": "standing"},
    ]
    mp = write_map(root / "map.toml", base_map(recordings=recs))
    result = ingest(mp)
    manifest = write_ingested(result, root / "out")
    return {"root": root, "src": src, "stamps": stamps, "map": mp, "result": result, "ds": read_dataset(manifest)}


def _chord_bound(t_rows, t_src, f_src, s_nodes):
    """Largest error of the chord between joint samples ``s_nodes`` against the
    piecewise-linear source: (b - a)/4 times the slope changes of f inside [a, b]."""
    # np.interp holds the end values outside the source: slope 0 there, kinks at both ends
    kinks_t = t_src
    kinks = np.abs(np.diff(np.concatenate([[0.0], np.diff(f_src) / np.diff(t_src), [0.0]])))
    j = np.clip(np.searchsorted(s_nodes, t_rows, side="right"), 1, len(s_nodes) - 1)
    a, b = s_nodes[j - 1], s_nodes[j]
    return np.array([kinks[(kinks_t >= lo) & (kinks_t <= hi)].sum() * (hi - lo) / 4 for lo, hi in zip(a, b)])


def _slerp_bound(src, delta, h):
    """Slerp between the source's orientation at t_(i-1) + delta and t_i + delta, read at
    t_i: to first order in the rotation steps the error is delta (h - delta)/h times the
    change of angular velocity |w_i - w_(i-1)| (rad)."""
    r = Rotation.from_quat(src.quat[:, [1, 2, 3, 0]])
    w = (r[:-1].inv() * r[1:]).as_rotvec() / h
    b = np.full(src.n, np.nan)
    b[1:-1] = delta * (h - delta) / h * np.linalg.norm(w[1:] - w[:-1], axis=1)
    return b


def test_csv_recordings_keep_every_bit_of_time(session, tmp_path):
    """Issue 24: the CSV form of an ingested dataset has the same t (and readings) as the in-memory result."""
    manifest = write_ingested(session["result"], tmp_path / "csv", fmt="csv")
    back = read_dataset(manifest)
    for a, b in zip(session["result"].dataset.recordings, back.recordings):
        assert np.array_equal(a.t, b.t) and all(np.array_equal(a.wrench[k], b.wrench[k]) for k in a.wrench)


def test_session_reads_back_through_read_dataset(session):
    ds, result = session["ds"], session["result"]
    assert [r.name for r in ds.recordings] == ["hang_xpos", "hang_xneg", "standing"]
    assert [r.kind for r in ds.recordings] == ["hanging", "hanging", "standing"]
    np.testing.assert_array_equal(ds.recordings[0].gravity_body, [1, 0, 0])
    sample = read_robot(SAMPLE / "robot.toml")
    assert ds.robot.legs == LEGS and ds.robot.mass_kg == 8.18 and ds.robot.g == 9.81
    for k in LEGS:  # the URDF's fixed chains, written to robot.toml and read back
        np.testing.assert_allclose(ds.robot.transducers[k].rotation, sample.transducers[k].rotation, atol=1e-12)
        np.testing.assert_allclose(ds.robot.transducers[k].position_m, sample.transducers[k].position_m, atol=1e-12)
    # session clock: the earliest stamp written to any used topic of any bag
    epoch = min(int(v.min()) for st in session["stamps"].values() for v in [*st["wrench"].values(), st["joints"], *([st["pose"]] if "pose" in st else [])])
    assert result.epoch_ns == epoch == session["stamps"]["hang_xpos"]["joints"][0]  # joints started first
    for a, b in zip(ds.recordings[:-1], ds.recordings[1:]):
        assert a.t[-1] < b.t[0]
    for rec in ds.recordings:
        src, st = session["src"][rec.name], session["stamps"][rec.name]
        clock = BASE_NS + np.round(src.t * 1e9).astype(np.int64)
        keep = (clock >= st["joints"][0]) & (clock <= st["joints"][-1])
        if rec.name == "hang_xpos":
            keep[57] = False  # ML's lost message
        if rec.name == "hang_xneg":
            keep[120] = False  # a lost message of the clock leaves no row
        assert rec.n == keep.sum()
        np.testing.assert_array_equal(rec.t, (clock[keep] - epoch) * 1e-9)


def test_counts_of_what_was_dropped(session):
    c = {x.name: x for x in session["result"].counts}
    assert c["hang_xpos"].unmatched_wrench == {"ML": 1, "HL": 0, "FR": 0, "MR": 0, "HR": 0}
    assert c["hang_xneg"].unmatched_wrench["ML"] == 0
    assert [x.clock_gaps for x in c.values()] == [0, 1, 0]
    for name, x in c.items():
        st, src = session["stamps"][name], session["src"][name]
        clock = BASE_NS + np.round(src.t * 1e9).astype(np.int64)
        n_out = int(((clock < st["joints"][0]) | (clock > st["joints"][-1])).sum())
        assert n_out > 0 and all(v == n_out for v in x.joint_outside_span.values())
        assert x.n_clock == len(clock) - x.clock_gaps and x.nan_readings == 0 and sum(x.joint_gap.values()) == 0
    assert c["standing"].invalid_pose_samples == 2
    m = read_dataset(session["root"] / "out" / "dataset.toml")  # counts are in the manifest too
    assert m.recordings[2].n == c["standing"].n_rows


def test_wrenches_are_the_source_readings(session):
    for rec in session["ds"].recordings:
        src = session["src"][rec.name]
        rows = np.isin(np.round(src.t * 1e9).astype(np.int64) + BASE_NS - session["result"].epoch_ns, np.round(rec.t * 1e9).astype(np.int64))
        for k in LEGS:  # nearest match within half a period picks each leg's own sample
            np.testing.assert_array_equal(rec.wrench[k], src.wrench[k][rows])


def test_shaft_angles_unwrapped_within_chord_error(session):
    epoch = session["result"].epoch_ns
    worst = {}
    for rec in session["ds"].recordings:
        src, st = session["src"][rec.name], session["stamps"][rec.name]
        s_nodes = (st["joints"] - BASE_NS) * 1e-9
        t_src_rows = rec.t + (epoch - BASE_NS) * 1e-9
        for k in LEGS:
            truth = np.interp(t_src_rows, src.t, src.phi[k])
            bound = _chord_bound(t_src_rows, src.t, src.phi[k], s_nodes)
            # the published angles were wrapped: the turns before the first sample are lost, nothing else
            turns = 2 * np.pi * np.round((rec.phi[k][0] - truth[0]) / (2 * np.pi))
            err = np.abs(rec.phi[k] - turns - truth)
            # plus the rounding of every stamp to 1 ns, times the steepest slope
            floor = np.abs(np.diff(src.phi[k]) / np.diff(src.t)).max() * 1e-9 + 1e-12
            assert np.all(err <= bound + floor), (rec.name, k, np.max(err - bound))
            worst[rec.name] = max(worst.get(rec.name, 0.0), err.max())
    # MR crosses the +-pi seam of the published angle in hang_xpos; unwrapped it is continuous
    src, rec = session["src"]["hang_xpos"], session["ds"].recordings[0]
    published = np.angle(np.exp(1j * np.interp((session["stamps"]["hang_xpos"]["joints"] - BASE_NS) * 1e-9, src.t, src.phi["MR"])))
    assert np.abs(np.diff(published)).max() > np.pi
    assert np.abs(np.diff(rec.phi["MR"])).max() < 0.05 and np.ptp(rec.phi["MR"]) > 0.5
    assert worst["standing"] > 0  # the bound is exercised: the legs move in this window


def test_orientation_slerped_and_gap_is_nan(session):
    epoch = session["result"].epoch_ns
    rec = session["ds"].recordings[2]
    src, st = session["src"]["standing"], session["stamps"]["standing"]
    t_src = rec.t + (epoch - BASE_NS) * 1e-9
    rows = np.searchsorted(src.t, t_src - 1e-7)
    # pose samples bracketing each row: regular where they are one period apart
    ps = st["pose"]
    row_ns = np.round(t_src * 1e9).astype(np.int64) + BASE_NS
    j = np.searchsorted(ps, row_ns, side="right")
    has = (j > 0) & (j < len(ps))
    width = np.full(len(j), np.inf)
    width[has] = (ps[j[has]] - ps[j[has] - 1]) * 1e-9
    expect_nan = ~has | (width > 0.05)
    assert expect_nan.sum() >= 25  # the 0.3 s tracking loss
    np.testing.assert_array_equal(np.isnan(rec.quat[:, 0]), expect_nan)
    assert session["result"].counts[2].nan_orientation == expect_nan.sum()
    regular = ~expect_nan & (np.abs(width - H) < 1e-6)
    bridged = ~expect_nan & ~regular  # the two NaN poses: a 30 ms gap, bridged
    assert bridged.sum() >= 2
    q_in = Rotation.from_quat(rec.quat[~expect_nan][:, [1, 2, 3, 0]])
    q_src = Rotation.from_quat(src.quat[rows[~expect_nan]][:, [1, 2, 3, 0]])
    ang = np.full(rec.n, np.nan)
    ang[~expect_nan] = (q_src.inv() * q_in).magnitude()
    bound = _slerp_bound(src, POSE_OFFSET_NS * 1e-9, H)[rows]
    # first-order bound; the second-order remainder is below 1e-3 of it for mrad steps
    assert np.all(ang[regular] <= 1.001 * bound[regular] + 1e-9), np.max(ang[regular] - bound[regular])
    steps = (Rotation.from_quat(src.quat[:-1][:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(src.quat[1:][:, [1, 2, 3, 0]])).magnitude()
    assert np.all(ang[bridged] <= 4 * steps.max() + 1e-9)
    assert np.nanmax(ang) > 0 and np.all(np.abs(np.linalg.norm(rec.quat[~expect_nan], axis=1) - 1) < 1e-12)


def test_cli_writes_a_dataset_run_takes(session, tmp_path):
    out = tmp_path / "cli_out"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    p = subprocess.run([sys.executable, "-m", "ftcal_nlp.ingest", str(session["map"]), "-o", str(out), "--format", "csv", "-q"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    ds = read_dataset(out / "dataset.toml")
    for a, b in zip(ds.recordings, session["ds"].recordings):
        np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.phi_array(), b.phi_array(), rtol=1e-11, atol=1e-12)  # 12 digits in CSV
        np.testing.assert_allclose(a.wrench_array(), b.wrench_array(), rtol=1e-11, atol=1e-15)
    # written once; a second run does not overwrite without --overwrite
    assert cli_main([str(session["map"]), "-o", str(out), "-q"]) == 2
    assert cli_main([str(session["map"]), "-o", str(out), "-q", "--overwrite"]) == 0


def test_linear_wrench_match_and_receive_clock(session, tmp_path):
    d = tomli_w_roundtrip(session["map"])
    for r in d["recording"]:
        r["bag"] = str(session["root"] / r["bag"])
    d["urdf"] = str(session["root"] / "robot.urdf")
    d["recording"] = d["recording"][:2]
    d["wrench_match"] = "linear"
    lin = ingest(write_map(tmp_path / "lin.toml", d))
    near = session["result"]
    epoch = lin.epoch_ns
    for i, rec in enumerate(lin.dataset.recordings):
        ref = near.dataset.recordings[i]
        st, src = session["stamps"][rec.name], session["src"][rec.name]
        # the rows of "nearest" (same lost-message rule), less those outside a leg's span (no extrapolation)
        ref_ns = np.round(ref.t * 1e9).astype(np.int64) + epoch
        inside = (ref_ns >= max(v[0] for v in st["wrench"].values())) & (ref_ns <= min(v[-1] for v in st["wrench"].values()))
        assert (~inside).sum() < 5
        np.testing.assert_array_equal(rec.t, ref.t[inside])
        np.testing.assert_array_equal(rec.wrench["FL"], ref.wrench["FL"][inside])  # the clock leg is never interpolated
        for k in LEGS[1:]:  # each other leg: the chord between its two samples around the clock row
            s_k = (st["wrench"][k] - epoch) * 1e-9
            expect = np.stack([np.interp(rec.t, s_k, src.wrench[k][st["rows"][k], c]) for c in range(6)], axis=1)
            np.testing.assert_allclose(rec.wrench[k], expect, rtol=0, atol=1e-12)
        assert np.any(rec.wrench["ML"] != ref.wrench["ML"][inside])
        # also counted: rows with a sample within half a period but before the leg's first one (no extrapolation)
        assert lin.counts[i].unmatched_wrench["ML"] >= near.counts[i].unmatched_wrench["ML"]
    d["wrench_match"] = "nearest"
    d["time_source"] = "receive"
    rcv = ingest(write_map(tmp_path / "rcv.toml", d))
    assert rcv.epoch_ns == min(min(session["stamps"][n]["recv_min"]) for n in ("hang_xpos", "hang_xneg"))
    rec, st = rcv.dataset.recordings[1], session["stamps"]["hang_xneg"]
    assert np.all(np.isin(np.round(rec.t * 1e9).astype(np.int64) + rcv.epoch_ns, st["recv0"]))


# ----------------------------------------------------------------------------- bad maps


@pytest.mark.parametrize(
    "edit, pattern",
    [
        (lambda d: d["wrench_topics"].update(HR="/ft/HR/wrnch"), r"'/ft/HR/wrnch' of map key \[wrench_topics\] HR is not in the bag"),
        (lambda d: d["joints"].update(MR="leg_MR_shft"), r"joint 'leg_MR_shft' of map key \[joints\] MR .*leg_MR_shaft"),
        (lambda d: d["joints"].update(topic="/joints"), r"'/joints' of map key \[joints\] topic is not in the bag"),
        (lambda d: d["body_pose"].update(topic="/vicon/pose"), r"'/vicon/pose' of map key \[body_pose\] topic is not in the bag"),
        (lambda d: d["transducer_links"].update(FR="ft_fr"), r"\[transducer_links\] FR = 'ft_fr' is not a link"),
        (lambda d: d["transducer_links"].update(FL="mount_FL"), r"\[wrench_topics\] FL\) is stamped in frame\(s\) \['ft_FL'\].*'mount_FL'"),
        (lambda d: d["wrench_topics"].pop("HL"), r"\[wrench_topics\]: missing entry for leg 'HL'"),
        (lambda d: d.pop("base_link"), r"missing key 'base_link'"),
        (lambda d: d["recording"][2].update(bag="standing_missing.bag"), r"standing_missing.bag: bag not found"),
        (lambda d: d["recording"].pop(1), r"has no opposite recording"),
        (lambda d: d["joints"]["sign"].update(FL=2) if "sign" in d["joints"] else d["joints"].update(sign={"FL": 2}), r"sign: values \{'FL': 2.0\} should be one of"),
        # issue 24: a recording name is a file stem inside -o, never a path out of it
        (lambda d: d["recording"][0].update(name="../../x"), r"#1: key 'name' = '\.\./\.\./x' should be a plain file stem"),
        (lambda d: d["recording"][1].update(name="/tmp/abs"), r"#2: key 'name' = '/tmp/abs' should be a plain file stem"),
        (lambda d: d["recording"][2].update(name=".."), r"#3: key 'name' = '\.\.' should be a plain file stem"),
    ],
)
def test_bad_map_gets_an_error_naming_the_key(session, tmp_path, edit, pattern):
    d = tomli_w_roundtrip(session["map"])
    for r in d["recording"]:
        r["bag"] = str(session["root"] / r["bag"])
    d["urdf"] = str(session["root"] / "robot.urdf")
    edit(d)
    with pytest.raises(DataFormatError, match=pattern):
        ingest(write_map(tmp_path / "bad.toml", d))


def test_example_map_is_a_valid_map(session, tmp_path):
    d = tomli_w_roundtrip(Path(__file__).resolve().parents[1] / "problems" / "ros_map_example.toml")
    assert len(d["recording"]) == 6
    d["urdf"] = str(session["root"] / "robot.urdf")
    d["recording"] = [{**r, "bag": str(session["root"] / r["bag"])} for r in tomli_w_roundtrip(session["map"])["recording"]]
    got = ingest(write_map(tmp_path / "example.toml", d))
    for a, b in zip(got.dataset.recordings, session["result"].dataset.recordings):
        np.testing.assert_array_equal(a.wrench_array(), b.wrench_array())


def tomli_w_roundtrip(path):
    import tomllib

    return tomllib.loads(Path(path).read_text())


def test_signs_zero_and_marker_link(session, tmp_path):
    """wrench_sign, joint zero/sign and a mocap marker that is not B."""
    src = session["src"]["standing"]
    short = src.select(np.arange(src.n) < 60)
    make_bag(tmp_path / "walk_marker", "mcap", short, seed=4, marker=True, frames=False)  # empty frame_id: not checked
    d = base_map(str(session["root"] / "robot.urdf"), [{"bag": "walk_marker", "kind": "walking", "name": "w"}])
    d["body_pose"]["link"] = "mocap_marker"
    d["wrench_sign"] = {"FR": -1}
    d["joints"]["zero_rad"] = {"ML": 0.5}
    d["joints"]["sign"] = {"HL": -1}
    base = ingest(write_map(tmp_path / "plain.toml", base_map(str(session["root"] / "robot.urdf"), [{"bag": "walk_marker", "kind": "walking"}])))
    got = ingest(write_map(tmp_path / "m.toml", d))
    a, b = base.dataset.recordings[0], got.dataset.recordings[0]
    np.testing.assert_array_equal(b.wrench["FR"], -a.wrench["FR"])
    np.testing.assert_array_equal(b.wrench["FL"], a.wrench["FL"])
    np.testing.assert_allclose(b.phi["ML"], a.phi["ML"] - 0.5, atol=1e-15)
    np.testing.assert_array_equal(b.phi["HL"], -a.phi["HL"])
    # without the marker link the orientation is the marker's; with it, B's
    ok = np.isfinite(b.quat[:, 0])
    R_plain = Rotation.from_quat(a.quat[ok][:, [1, 2, 3, 0]]).as_matrix()
    R_body = Rotation.from_quat(b.quat[ok][:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(R_body, R_plain @ R_BM.T, atol=1e-12)
    t_src = b.t + (got.epoch_ns - BASE_NS) * 1e-9
    truth = _truth_quat(short, t_src[ok]).as_matrix()
    assert np.max(np.abs(R_body - truth)) < 1e-2  # B's orientation, not the marker's (90 deg apart)


# ----------------------------------------------------------------------------- clock


def test_clock_never_extrapolates_nor_bridges_gaps():
    s = np.array([0.0, 0.1, 0.2, 0.5, 0.6])
    v = np.array([0.0, 1.0, 2.0, 5.0, 6.0])
    clock = np.array([-0.05, 0.0, 0.15, 0.3, 0.5, 0.55, 0.6, 0.65])
    r = interp_linear(clock, s, v, max_gap_s=0.2)
    np.testing.assert_array_equal(r.outside, [True, False, False, False, False, False, False, True])
    np.testing.assert_array_equal(r.in_gap, [False, False, False, True, False, False, False, False])
    np.testing.assert_allclose(r.values[~r.missing, 0], [0.0, 1.5, 5.0, 5.5, 6.0])
    assert np.all(np.isnan(r.values[r.missing]))
    # a clock row exactly on a sample has its value even at the edge of a gap
    r = interp_linear(np.array([0.6, 0.8, 1.0]), np.append(s, 1.0), np.append(v, 10.0), max_gap_s=0.2)
    np.testing.assert_array_equal(r.in_gap, [False, True, False])
    np.testing.assert_allclose(r.values[[0, 2], 0], [6.0, 10.0])
    idx = match_nearest(np.array([0.0, 0.04, 0.06, 0.33, 0.7]), s, 0.05)
    np.testing.assert_array_equal(idx, [0, 0, 1, -1, -1])


def test_slerp_takes_the_geodesic_whatever_the_quaternion_sign():
    q1 = Rotation.from_euler("z", 0.2).as_quat()[[3, 0, 1, 2]]
    q = np.array([[1.0, 0, 0, 0], -q1, q1])
    r = slerp_quat(np.array([0.05, 0.15, 0.3]), np.array([0.0, 0.1, 0.2]), q, max_gap_s=0.5)
    np.testing.assert_allclose(r.values[0], Rotation.from_euler("z", 0.1).as_quat()[[3, 0, 1, 2]], atol=1e-12)
    np.testing.assert_allclose(r.values[1], q1, atol=1e-12)
    assert np.all(np.isnan(r.values[2])) and r.outside[2]


# ----------------------------------------------------------------------------- ground wrenches out


@pytest.mark.parametrize("storage", [None, "sqlite3"])
def test_ground_wrench_bag_round_trip(tmp_path, storage):
    from rosbags.highlevel import AnyReader

    rng = np.random.default_rng(7)
    t = 973.96 + 0.01 * np.arange(40)
    w = {k: rng.normal(size=(40, 6)) * [5, 5, 20, 0.5, 0.5, 0.1] for k in LEGS}
    path = bagio.write_ground_wrench_bag(tmp_path / "gw", t, w, epoch_ns=BASE_NS, storage=storage)
    expected = {**{f"/ground_wrench/{k}": v for k, v in w.items()}, "/ground_wrench/total": np.sum(list(w.values()), axis=0)}
    got = {}
    with AnyReader([Path(path)]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {k: "geometry_msgs/msg/WrenchStamped" for k in expected}
        for conn, recv, raw in reader.messages():
            m = reader.deserialize(raw, conn.msgtype)
            stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            assert m.header.frame_id == "heading" and recv == stamp
            got.setdefault(conn.topic, []).append((stamp, [m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z]))
    stamps = BASE_NS + np.round(t * 1e9).astype(np.int64)
    for topic, v in expected.items():
        np.testing.assert_array_equal([s for s, _ in got[topic]], stamps)
        np.testing.assert_array_equal(np.array([x for _, x in got[topic]]), v)
    meta = (Path(path) / "metadata.yaml").read_text()
    assert ("storage_identifier: mcap" in meta) == (storage is None and bagio.mcap_supported())
    back = bagio.read_wrench_topics(path)  # the reader used by ingest agrees
    np.testing.assert_array_equal(back["/ground_wrench/total"][1], expected["/ground_wrench/total"])
    # from a corrected-recording table (OUTPUT_FORMAT.md columns), total taken as given
    import pandas as pd

    cols = {"t": t, **{f"{k}_{c}": v[:, j] for k, v in {**w, "total": 2 * expected["/ground_wrench/total"]}.items() for j, c in enumerate(("fx", "fy", "fz", "tx", "ty", "tz"))}}
    p2 = bagio.ground_wrench_bag_from_frame(tmp_path / "gw2", pd.DataFrame(cols), LEGS, topic_prefix="/gw/", storage=storage)
    back = bagio.read_wrench_topics(p2)
    assert sorted(back) == sorted(["/gw/total"] + [f"/gw/{k}" for k in LEGS])
    np.testing.assert_array_equal(back["/gw/total"][1], 2 * expected["/ground_wrench/total"])
    np.testing.assert_array_equal(back["/gw/MR"][1], w["MR"])
    with pytest.raises(DataFormatError, match=r"missing column\(s\) \['total_tz'\]"):
        bagio.ground_wrench_bag_from_frame(tmp_path / "gw3", pd.DataFrame(cols).drop(columns="total_tz"), LEGS)


# ----------------------------------------------------------------------------- fast decoding


def _assert_same_streams(a: bagio.BagStreams, b: bagio.BagStreams):
    assert a.topics == b.topics and sorted(a.wrench) == sorted(b.wrench) and sorted(a.joints) == sorted(b.joints)
    assert a.joint_names_seen == b.joint_names_seen
    pairs = [(a.wrench[t], b.wrench[t]) for t in a.wrench] + [(a.joints[n], b.joints[n]) for n in a.joints]
    assert (a.pose is None) == (b.pose is None)
    if a.pose is not None:
        pairs.append((a.pose, b.pose))
    for x, y in pairs:
        assert x.topic == y.topic and x.frame_ids == y.frame_ids and x.n_invalid == y.n_invalid
        np.testing.assert_array_equal(x.stamp_ns, y.stamp_ns)
        np.testing.assert_array_equal(x.receive_ns, y.receive_ns)
        np.testing.assert_array_equal(x.values, y.values)  # NaN == NaN here


def _forbid_rosbags_reader(mp):
    """Make reading messages through rosbags an error: the direct chunk reader must do it."""
    def fail(*a, **k):
        raise AssertionError("read through rosbags, not chunk by chunk")

    mp.setattr(bagio, "_generic_source", fail)


SESSION_TOPICS = dict(
    wrench_topics=[f"/ft/{k}/wrench" for k in LEGS],
    joint_topic="/joint_states",
    joint_names=[f"leg_{k}_shaft" for k in LEGS] + ["head_pan"],
    pose_topic="/mocap/bigant/pose",
)


def test_fast_decoder_equals_the_rosbags_deserialiser(session, monkeypatch):
    """Every storage, batches of 97 messages (many flushes, several layouts each:
    two joint publishers with different names, NaN poses)."""
    monkeypatch.setattr(bagio, "FLUSH_EVERY", 97)
    for bag, n_fl in (("hang_xpos", 300), ("hang_xneg", 299), ("standing.bag", 300)):  # hang_xneg lost one FL message
        slow = bagio.read_streams(session["root"] / bag, fast=False, **SESSION_TOPICS)
        with monkeypatch.context() as mp:
            if bag != "hang_xpos":  # sqlite3 goes through rosbags; MCAP and ROS 1 chunks are read directly
                _forbid_rosbags_reader(mp)
            fast = bagio.read_streams(session["root"] / bag, **SESSION_TOPICS)
        _assert_same_streams(fast, slow)
        assert len(fast.wrench["/ft/FL/wrench"]) == n_fl


def _odd_layouts_bag(path: Path, storage: str) -> None:
    """One topic of each type whose messages have many layouts."""
    ts = bagio.typestore_for(storage)
    rng = np.random.default_rng(5)
    n = 120
    st = BASE_NS + 10_000_000 * np.arange(n)
    # frame_id of varying length, then 40 distinct ones of equal length (more than MAX_LAYOUTS)
    frames = [["ft_FL", "", "a_much_longer_frame_name_than_usual"][i % 3] if i < 60 else f"f{i:03d}" for i in range(n)]
    w = rng.normal(size=(n, 6))
    w[7] = np.nan
    wmsgs = [bagio.wrench_stamped(ts, int(s), f, x) for s, f, x in zip(st, frames, w)]
    JS = ts.types[bagio.JOINT_TYPE]
    jmsgs = []
    for i, s in enumerate(st):
        names = [["a", "b"], ["b", "c", "long_joint_name"], ["a"]][i % 3]
        if i % 10 == 4:  # velocity only: names, no positions
            jmsgs.append(JS(header=bagio._header(ts, int(s), ""), name=names, position=np.zeros(0),
                            velocity=np.ones(len(names)), effort=np.zeros(0)))
        else:
            jmsgs.append(bagio.joint_state(ts, int(s), names, rng.normal(size=len(names)), "j" * (i % 2)))
    q = rng.normal(size=(n, 4))
    q[3], q[9] = np.nan, 0.0
    pmsgs = [bagio.pose_stamped(ts, int(s), "world" if i % 4 else "map", x, rng.normal(size=3)) for i, (s, x) in enumerate(zip(st, q))]
    bagio.write_bag(path, [
        bagio.TopicSeries("/w", bagio.WRENCH_TYPE, st + 1, wmsgs),
        bagio.TopicSeries("/j", bagio.JOINT_TYPE, st + 2, jmsgs),
        bagio.TopicSeries("/p", bagio.POSE_TYPE, st + 3, pmsgs),
    ], storage=storage)


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_fast_decoder_with_many_layouts(tmp_path, monkeypatch, storage):
    from ftcal_nlp.ros import wire

    path = tmp_path / ("odd.bag" if storage == "ros1" else "odd")
    _odd_layouts_bag(path, storage)
    kw = dict(wrench_topics=["/w"], joint_topic="/j", joint_names=["a", "b", "c", "long_joint_name", "d"], pose_topic="/p")
    slow = bagio.read_streams(path, fast=False, **kw)
    with monkeypatch.context() as mp:
        _forbid_rosbags_reader(mp)
        fast = bagio.read_streams(path, **kw)
    _assert_same_streams(fast, slow)
    assert len(fast.wrench["/w"]) == 120 and np.isnan(fast.wrench["/w"].values[7]).all()
    assert len(fast.wrench["/w"].frame_ids) == 3 + 60
    assert len(fast.joints["a"]) == 80 - 8 and "d" not in fast.joints  # velocity-only messages carry no angle
    assert fast.joint_names_seen == {"a", "b", "c", "long_joint_name"}
    assert fast.pose.n_invalid == 2 and len(fast.pose) == 118 and fast.pose.frame_ids == {"world", "map"}
    # a layout the reference deserialiser disagrees with is not trusted: its rows take the slow path
    calls = []
    real_parse, real_slow = wire.parse_layout, wire.decode_slow

    def wrong(raw, msgtype, cdr):
        lay = real_parse(raw, msgtype, cdr)
        return replace(lay, values_at=lay.values_at - 8) if msgtype == bagio.WRENCH_TYPE else lay

    def counting(raws, rows, *a):
        calls.append(len(rows))
        return real_slow(raws, rows, *a)

    monkeypatch.setattr(wire, "parse_layout", wrong)
    monkeypatch.setattr(wire, "decode_slow", counting)
    _assert_same_streams(bagio.read_streams(path, **kw), slow)
    assert sum(calls) >= 120


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
def test_encoded_messages_are_what_rosbags_deserialises(storage):
    from ftcal_nlp.ros.wire import extract

    ts = bagio.typestore_for(storage)
    de = ts.deserialize_ros1 if storage == "ros1" else ts.deserialize_cdr
    rng = np.random.default_rng(9)
    stamps = BASE_NS + np.cumsum(rng.integers(1, 10**9, 5))
    for typ, vals, names, frame in [
        (bagio.WRENCH_TYPE, rng.normal(size=(5, 6)), None, "ft_FL"),
        (bagio.POSE_TYPE, rng.normal(size=(5, 7)), None, "world"),
        (bagio.JOINT_TYPE, rng.normal(size=(5, 3)), ["x", "yy", "zzz"], ""),
    ]:
        for raw, s, v in zip(bagio.encode_messages(storage, typ, stamps, frame, vals, names), stamps, vals):
            stamp, f, got, nm = extract(de(raw, typ), typ)
            assert stamp == s and f == frame and nm == (None if names is None else tuple(names))
            np.testing.assert_array_equal(got, v)


# ----------------------------------------------------------------------------- bad bags


def _small(kind="hanging", n=60):
    return _source("hang_xpos.csv", "hanging", 1000, n) if kind == "hanging" else _source("standing.parquet", "standing", 300, n)


def _bag_with(tmp_path, edit, *, kind="hanging", storage="mcap", max_backward_s=None):
    """A one-recording session of a short sample window, its topics edited by ``edit(series, rec, storage)``."""
    from ftcal_nlp.ros.simbag import POSE_TOPIC, recording_series, session_map
    from ftcal_nlp.ros.urdf import urdf_text

    rec = _small(kind)
    series = {s.topic: s for s in recording_series(rec, LEGS, storage, epoch_ns=BASE_NS)}
    edit(series, rec, storage)
    bag = tmp_path / ("rec.bag" if storage == "ros1" else "rec")
    bagio.write_bag(bag, list(series.values()), storage=storage)
    (tmp_path / "robot.urdf").write_text(urdf_text(read_robot(SAMPLE / "robot.toml")))
    d = session_map(LEGS, 8.18, 9.81, [(bag.name, rec)])
    if kind == "hanging":  # its opposite: the same bag, said to hang the other way (a map about topics, not physics)
        d["recording"].append({**d["recording"][0], "name": "opposite", "gravity_body": [-1.0, 0.0, 0.0]})
    if max_backward_s is not None:
        d["max_backward_s"] = max_backward_s
    assert POSE_TOPIC == d["body_pose"]["topic"]
    return write_map(tmp_path / "map.toml", d)


def _wrench_series(rec, storage, k, stamps, rows=None, recv=None):
    rows = np.arange(rec.n) if rows is None else rows
    msgs = bagio.encode_messages(storage, bagio.WRENCH_TYPE, stamps[rows], f"ft_{k}", rec.wrench[k][rows])
    return bagio.TopicSeries(f"/ft/{k}/wrench", bagio.WRENCH_TYPE, stamps[rows] + 1_000_000 if recv is None else recv, msgs)


def _clock(rec):
    return BASE_NS + np.round(rec.t * 1e9).astype(np.int64)


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_too_few_messages_name_the_bag_topic_and_key(tmp_path, storage):
    def one_wrench(series, rec, st):
        series["/ft/HL/wrench"] = _wrench_series(rec, st, "HL", _clock(rec), rows=np.array([5]))

    with pytest.raises(BagError, match=r"rec(\.bag)?: topic '/ft/HL/wrench' \(\[wrench_topics\] HL\) has 1 message\(s\); at least 2 are needed"):
        ingest(_bag_with(tmp_path / "w", one_wrench, storage=storage))

    def mr_once(series, rec, st):
        s = series["/joint_states"]
        names = [f"{k}_shaft" for k in LEGS if k != "MR"]
        js = s.receive_ns - 500_000
        pos = np.stack([np.interp((js - BASE_NS) * 1e-9, rec.t, rec.phi[k]) for k in LEGS if k != "MR"], 1)
        msgs = bagio.encode_messages(st, bagio.JOINT_TYPE, js, "", pos, names)
        ts = bagio.typestore_for(st)
        msgs[3] = bagio.joint_state(ts, int(js[3]), [f"{k}_shaft" for k in LEGS], np.zeros(6))  # MR once
        series["/joint_states"] = bagio.TopicSeries("/joint_states", bagio.JOINT_TYPE, s.receive_ns, msgs)

    with pytest.raises(BagError, match=r"joint 'MR_shaft' \(\[joints\] MR\) has fewer than 2 positions"):
        ingest(_bag_with(tmp_path / "j", mr_once, storage=storage))

    def one_pose(series, rec, st):
        s = series["/mocap/body/pose"]
        series["/mocap/body/pose"] = bagio.TopicSeries(s.topic, s.msgtype, s.receive_ns[:1], s.messages[:1])

    with pytest.raises(BagError, match=r"topic '/mocap/body/pose' \(\[body_pose\] topic\) has fewer than 2 valid orientations"):
        ingest(_bag_with(tmp_path / "p", one_pose, kind="standing", storage=storage))


def test_stamps_going_backwards_are_an_error_reordering_is_not(tmp_path):
    def reset(series, rec, st):  # the FR driver's clock jumps back 1 s at row 30
        stamps = _clock(rec)
        stamps[30:] -= 1_000_000_000
        series["/ft/FR/wrench"] = _wrench_series(rec, st, "FR", stamps, recv=_clock(rec) + 1_000_000)

    with pytest.raises(BagError, match=r"rec: topic '/ft/FR/wrench' \(\[wrench_topics\] FR\): header stamps go backwards: "
                                       r"sample 31 of 60 \(bag order\) is stamped 0.99 s before .*max_backward_s = 0.05"):
        ingest(_bag_with(tmp_path / "a", reset))
    # a looser max_backward_s lets it through (the map says the jump is expected)
    ingest(_bag_with(tmp_path / "b", reset, max_backward_s=2.0))

    def joints_back(series, rec, st):
        s = series["/joint_states"]
        js = s.receive_ns - 500_000
        js[10:] -= 200_000_000
        pos = np.stack([np.interp((js - BASE_NS) * 1e-9, rec.t, rec.phi[k]) for k in LEGS], 1)
        msgs = bagio.encode_messages(st, bagio.JOINT_TYPE, js, "", pos, [f"{k}_shaft" for k in LEGS])
        series["/joint_states"] = bagio.TopicSeries("/joint_states", bagio.JOINT_TYPE, s.receive_ns, msgs)

    with pytest.raises(BagError, match=r"'/joint_states' \(\[joints\] FL\): header stamps go backwards: sample 11 of"):
        ingest(_bag_with(tmp_path / "c", joints_back))

    def swapped(series, rec, st):  # ML's message 21 arrives before message 20: stamps step back 10 ms
        recv = _clock(rec) + 1_000_000
        recv[20] = recv[21] + 1
        series["/ft/ML/wrench"] = _wrench_series(rec, st, "ML", _clock(rec), recv=recv)

    ref = ingest(_bag_with(tmp_path / "d", lambda *a: None))
    got = ingest(_bag_with(tmp_path / "e", swapped))
    s = bagio.read_streams(tmp_path / "e" / "rec", wrench_topics=["/ft/ML/wrench"])
    assert np.diff(s.wrench["/ft/ML/wrench"].stamp_ns).min() == -10_000_000  # bag order is receive order
    for a, b in zip(got.dataset.recordings, ref.dataset.recordings):
        np.testing.assert_array_equal(a.wrench_array(), b.wrench_array())

    def unstamped(series, rec, st):
        series["/ft/FL/wrench"] = _wrench_series(rec, st, "FL", np.zeros(rec.n, dtype=np.int64), recv=_clock(rec))

    with pytest.raises(BagError, match=r"'/ft/FL/wrench' \(\[wrench_topics\] FL\) has messages with zero header stamps.*time_source"):
        ingest(_bag_with(tmp_path / "f", unstamped))


def test_output_folder_is_never_written_over_unless_asked(session, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "standing.parquet").write_text("someone else's recording")  # a dataset without its manifest
    with pytest.raises(FileExistsError, match=r"would write over \[.*standing.parquet'\]; pass overwrite=True"):
        write_ingested(session["result"], out)
    assert sorted(p.name for p in out.iterdir()) == ["standing.parquet"]  # nothing written
    assert cli_main([str(session["map"]), "-o", str(out), "-q"]) == 2
    write_ingested(session["result"], out, overwrite=True)
    assert len(read_dataset(out / "dataset.toml").recordings) == 3


def test_unreadable_bag_paths_get_clear_errors(session, tmp_path):
    import shutil

    shutil.copy(session["root"] / "standing.bag", tmp_path / "standing_ros1")
    with pytest.raises(BagError, match=r"standing_ros1: a file not named \*.bag or \*.mcap; a ROS 1 bag must end in .bag"):
        bagio.read_streams(tmp_path / "standing_ros1", wrench_topics=[])
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"empty: folder without metadata.yaml"):
        bagio.read_streams(tmp_path / "empty", wrench_topics=[])


def test_progress_bar_only_when_asked_or_on_a_terminal(session, capsys):
    bag = session["root"] / "hang_xneg"
    bagio.read_streams(bag, wrench_topics=["/ft/FL/wrench"])  # stderr is not a terminal under pytest
    assert capsys.readouterr().err == ""
    bagio.read_streams(bag, wrench_topics=["/ft/FL/wrench"], progress=True)
    err = capsys.readouterr().err
    assert "hang_xneg" in err and "msg" in err


@pytest.mark.parametrize("storage, compression", [("ros1", "bz2"), ("ros1", "lz4"), ("mcap", "zstd"), ("mcap", "message"), ("sqlite3", "message")])
def test_compressed_bags_read_alike(tmp_path, monkeypatch, storage, compression):
    """Compressed chunks are read directly; per-message compression through rosbags."""
    from ftcal_nlp.ros import rawscan
    from ftcal_nlp.ros.simbag import recording_series

    rec = _small("standing", 200)
    path = tmp_path / ("c.bag" if storage == "ros1" else "c")
    bagio.write_bag(path, recording_series(rec, LEGS, storage, epoch_ns=BASE_NS), storage=storage, compression=compression)
    kw = dict(wrench_topics=[f"/ft/{k}/wrench" for k in LEGS], joint_topic="/joint_states", joint_names=[f"{k}_shaft" for k in LEGS], pose_topic="/mocap/body/pose")
    slow = bagio.read_streams(path, fast=False, **kw)
    direct = storage == "ros1" or compression == "zstd"
    with monkeypatch.context() as mp:
        if direct:
            _forbid_rosbags_reader(mp)
        fast = bagio.read_streams(path, **kw)
    _assert_same_streams(fast, slow)
    np.testing.assert_array_equal(fast.wrench["/ft/MR/wrench"].values, rec.wrench["MR"])
    if direct:
        assert rawscan.scan(path).chunks[0].compression == ("zstd" if storage == "mcap" else compression)
    else:
        with pytest.raises(rawscan.RawScanError):
            rawscan.scan(path)
