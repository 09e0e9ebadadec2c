"""Ingest of section-5 sessions (issue 22, item 7): a JointState topic into ``q_{joint}`` columns and an IMU
(orientation -> ``qw..qz``, or the accelerometer at rest -> ``gx..gz``) on the recording's clock, from bags
written by ``ros/simbag.write_free_session`` out of the free-load simulator; and the map's errors."""

from __future__ import annotations

import numpy as np
import pytest
import tomli_w

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.core.errors import DataFormatError
from ftcal_nlp.core.geometry import quat_to_rotation, rotvec_to_rotation
from ftcal_nlp.ros import ingest, read_map, write_ingested
from ftcal_nlp.ros.simbag import write_free_session
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_payload, simulate_urdf_leg


@pytest.fixture(scope="module")
def leg():
    return simulate_urdf_leg(UrdfLegConfig(seed=1, n_orientations=2, poses_per_orientation=2, hold_s=1.0, move_s=0.5))


@pytest.fixture(scope="module")
def payload():
    return simulate_payload(PayloadConfig(seed=1, n_orientations=3, hold_s=1.0, move_s=0.5))


def _frame(result):
    from ftcal_nlp.core.data import recording_to_frame

    rec = result.dataset.recordings[0]
    return recording_to_frame(rec, result.dataset.robot.legs)


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_joint_states_and_imu_orientation_onto_the_wrench_clock(tmp_path, leg, storage) -> None:
    R_B_imu = rotvec_to_rotation(np.array([0.1, -0.2, 0.3]))
    mp = write_free_session(leg, tmp_path, storage, imu="orientation", R_B_imu=R_B_imu)
    res = ingest(mp, progress=False)
    src, got = leg.frame, _frame(res)
    X = leg.config.transducer
    # the joint stream starts 3 ms late and ends before the last reading: those rows are dropped and counted
    c = res.counts[0]
    assert c.n_clock == len(src) and c.n_rows == len(got) == len(src) - 2
    assert set(c.joint_columns_dropped) == set(leg.q) and all(v == 2 for v in c.joint_columns_dropped.values())
    h = leg.held
    # held samples whose chords stay within the hold (3 samples either side held too)
    held = np.array([h[max(i - 3, 0):i + 4].all() for i in range(len(h))])[1:-1]
    src = src.iloc[1:-1].reset_index(drop=True)
    np.testing.assert_allclose(got.t, src.t - leg.frame.t.iloc[0], atol=1e-9)
    np.testing.assert_array_equal(got[f"{X}_fx"], src[f"{X}_fx"])                 # readings pass through
    assert f"{X}_phi" not in got
    # q: the bag holds chords of the recorded angles at every 2nd sample, 3 ms late, and the ingest takes chords
    # of those: a chord over at most three recorded steps misses the recorded value by less than the largest
    # second difference of the recorded angles; the holds exactly
    for j in leg.q:
        a, b = got[f"q_{j}"].to_numpy(), src[f"q_{j}"].to_numpy()
        assert np.abs(a - b).max() <= np.abs(np.diff(leg.frame[f"q_{j}"].to_numpy(), 2)).max() + 1e-12, j
        assert np.abs(a - b)[held].max() < 1e-9
    # orientation of B from the IMU's through its mounting: the recorded one (slerp at the sample times)
    R_got = quat_to_rotation(got[["qw", "qx", "qy", "qz"]].to_numpy())
    R_src = quat_to_rotation(src[["qw", "qx", "qy", "qz"]].to_numpy())
    assert np.abs(R_got - R_src).max() < 1e-9
    rec = res.dataset.recordings[0]
    assert rec.gravity is not None and rec.gravity_body is None and set(rec.q) == set(leg.q)


def test_accelerometer_gives_gravity_columns_and_the_dataset_reads_back(tmp_path, payload) -> None:
    R_B_imu = rotvec_to_rotation(np.array([0.0, 0.5, 0.0]))
    mp = write_free_session(payload, tmp_path / "bags", imu="acceleration", R_B_imu=R_B_imu)
    res = ingest(mp, progress=False)
    got = _frame(res)
    assert {"gx", "gy", "gz"} <= set(got.columns) and "qw" not in got.columns
    R_src = quat_to_rotation(payload.frame[["qw", "qx", "qy", "qz"]].to_numpy())
    g_true = -R_src[:, 2, :]                                                         # R_WB^T [0, 0, -1]
    np.testing.assert_allclose(got[["gx", "gy", "gz"]].to_numpy(), g_true, atol=1e-9)
    manifest = write_ingested(res, tmp_path / "ds")
    ds = read_dataset(manifest)
    rec = ds.recordings[0]
    assert ds.robot.legs == (payload.config.transducer,) and rec.gravity_body is None
    np.testing.assert_allclose(rec.gravity, g_true, atol=1e-9)
    assert ds.load_kind(payload.config.transducer) == "rigid_payload"


def _write_map(tmp_path, leg, **changes):
    mp = write_free_session(leg, tmp_path)
    import tomllib

    d = tomllib.loads(mp.read_text())
    for k, v in changes.items():
        if v is None:
            d.pop(k.split(".")[0]) if "." not in k else d[k.split(".")[0]].pop(k.split(".")[1])
        elif "." in k:
            d[k.split(".")[0]][k.split(".")[1]] = v
        else:
            d[k] = v
    mp.write_bytes(tomli_w.dumps(d).encode())
    return mp


@pytest.mark.parametrize("change, message", [
    ({"joint_columns.names": ["r_knee", "no_such_joint"]}, r"\[joint_columns\]: \['no_such_joint'\] are not movable joints"),
    ({"imu.use": "gyro"}, r"\[imu\]: key 'use' = 'gyro'"),
    ({"imu.rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}, r"\[imu\]: key 'rotation' should be a proper 3x3 rotation"),
    ({"imu.link": "r_thigh"}, r"\[imu\]: give 'link' or 'rotation', not both"),
    ({"body_pose": {"topic": "/mocap"}}, r"\[imu\] and \[body_pose\] both give the orientation"),
])
def test_bad_section5_map_keys_are_named(tmp_path, leg, change, message) -> None:
    with pytest.raises(DataFormatError, match=message):
        read_map(_write_map(tmp_path, leg, **change))


def test_imu_link_that_moves_with_a_joint_is_an_error(tmp_path, leg) -> None:
    mp = _write_map(tmp_path, leg, **{"imu.rotation": None})
    import tomllib

    d = tomllib.loads(mp.read_text())
    d["imu"]["link"] = "r_thigh"
    mp.write_bytes(tomli_w.dumps(d).encode())
    with pytest.raises(DataFormatError, match=r"link 'r_thigh' moves with joint\(s\)"):
        read_map(mp)
    d["imu"]["link"] = "base"
    mp.write_bytes(tomli_w.dumps(d).encode())
    assert np.allclose(read_map(mp).free_keys.imu.R_B_imu, np.eye(3))


def test_missing_imu_topic_names_the_map_key(tmp_path, leg) -> None:
    mp = _write_map(tmp_path, leg, **{"imu.topic": "/imu/other"})
    with pytest.raises(DataFormatError, match=r"topic '/imu/other' of map key \[imu\] topic is not in the bag"):
        ingest(mp, progress=False)
