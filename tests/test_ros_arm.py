"""An arm's ROS bag + URDF -> a section-5 dataset (issue 32 item 5; ``ftcal_nlp/ros/arm.py``).

Bags are written with ``rosbags`` (``ros/simbag.write_arm_session``) from a simulated six-joint arm whose truth is
known: the ingested dataset has the shape of ``shared/sample_arm``, keeps every header stamp to the nanosecond,
carries the temperature when the topic is there, and ``run`` on it recovers the tool's mass, CoM, the offsets and
the sensor's mounting rotation within the reported se. Bad inputs get errors naming the topic, field or key.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.core.errors import DataFormatError
from ftcal_nlp.ros import bagio
from ftcal_nlp.ros.arm import read_arm_map
from ftcal_nlp.ingest import main as cli_main
from ftcal_nlp.ros.ingest import ingest, read_any_map
from ftcal_nlp.ros.mapfile import read_map
from ftcal_nlp.ros.simbag import ARM_URDF, write_arm_session
from ftcal_nlp.run import main as run_main

SHARED = Path("/work/shared")
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
Z_MAX = 4.0    # |est - truth| / se over 15 numbers: a 4-sigma bound fails by chance ~1e-3 of the time


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 14-hold session written as an MCAP bag (joints split over two topics, temperature at 2 Hz), ingested by
    the command line into a CSV dataset, and calibrated by ``run`` (diagnosis off)."""
    root = tmp_path_factory.mktemp("arm_bag")
    s = write_arm_session(root / "bags", "mcap", seed=3, holds=14)
    ds = root / "ds"
    assert cli_main([str(s.map), "-o", str(ds), "-q"]) == 0
    (ds / "run.toml").write_bytes(tomli_w.dumps({"data": {"manifest": "dataset.toml"}, "output": {"dir": str(root / "out")},
                                                 "diagnose": {"enabled": False}}).encode())
    assert run_main([str(ds / "run.toml"), "-q"]) == 0
    return {"sim": s, "ds": ds, "out": root / "out"}


def test_run_on_the_ingested_bag_recovers_the_truth(session) -> None:
    d = json.loads((session["out"] / "calibration.json").read_text())["legs"]["wrist"]
    truth = session["sim"].truth
    assert d["load_kind"] == "rigid_payload" and d["link"] == "ft_sensor"
    z = {"mass": (d["load_mass_kg"] - truth["mass_kg"]) / d["load_mass_se_kg"]}
    z.update({f"com_{i}": (d["load_com_m"][i] - truth["com_m"][i]) / d["load_com_se_m"][i] for i in range(3)})
    z.update({f"offset_{c}": (d["offset"][i] - truth["offset"][i]) / d["offset_se"][i] for i, c in enumerate(WRENCH)})
    z.update({f"mount_{i}": (d["mount_rotvec"][i] - truth["mount_rotvec"][i]) / d["mount_rotvec_se"][i] for i in range(3)})
    assert max(abs(v) for v in z.values()) < Z_MAX, z
    assert d["gravity_body_nominal"] == [0.0, 0.0, -1.0]


def test_dataset_has_the_shape_of_sample_arm(session) -> None:
    ds = session["ds"]
    assert {"dataset.toml", "robot.toml", "arm6.urdf", "wrist.csv"} <= {p.name for p in ds.iterdir()}
    assert (ds / "arm6.urdf").read_text() == ARM_URDF
    robot = tomllib.loads((ds / "robot.toml").read_text())
    assert robot == {"name": "arm6", "g": 9.81, "legs": ["wrist"], "urdf": "arm6.urdf", "transducers": {"wrist": {"link": "ft_sensor"}}}
    man = tomllib.loads((ds / "dataset.toml").read_text())
    rec = man["recording"][0]
    assert man["robot"] == "robot.toml" and len(man["recording"]) == 1
    assert rec["file"] == "wrist.csv" and rec["kind"] == "hanging" and rec["gravity_body"] == [0.0, 0.0, -1.0]
    cols = list(pd.read_csv(ds / "wrist.csv", nrows=1).columns)
    assert cols == ["t", *(f"wrist_{c}" for c in WRENCH), *(f"q_{j}" for j in JOINTS), "wrist_temp_C"]
    sample = SHARED / "sample_arm"
    if (sample / "wrist.csv").is_file():          # the shared reference: its columns, manifest and robot keys
        assert cols[:-1] == list(pd.read_csv(sample / "wrist.csv", nrows=1).columns)
        ref_robot = tomllib.loads((sample / "robot.toml").read_text())
        assert set(ref_robot) == set(robot) and ref_robot["transducers"] == robot["transducers"]
        ref = tomllib.loads((sample / "dataset.toml").read_text())["recording"][0]
        assert {k: rec[k] for k in ref if k != "file"} == {k: v for k, v in ref.items() if k != "file"}
    got = read_dataset(ds / "dataset.toml")
    assert got.load_kind("wrist") == "rigid_payload" and set(got.recordings[0].q) == set(JOINTS)


def test_header_stamps_kept_to_the_nanosecond_and_columns_true(session) -> None:
    s, ds = session["sim"], session["ds"]
    epoch = tomllib.loads((ds / "dataset.toml").read_text())["ingest"]["epoch_ns"]
    rec = read_dataset(ds / "dataset.toml").recordings[0]          # the CSV as the run reads it
    stamps = epoch + np.round(rec.t * 1e9).astype(np.int64)
    # every row is a WrenchStamped header stamp, exactly; only the rows outside the joint streams are left out
    idx = np.searchsorted(s.wrench_stamp_ns, stamps)
    assert np.array_equal(s.wrench_stamp_ns[idx], stamps) and epoch == s.wrench_stamp_ns[0]
    assert len(stamps) == len(s.wrench_stamp_ns) - 2 and stamps[0] == s.wrench_stamp_ns[1]
    np.testing.assert_array_equal(rec.wrench["wrist"], s.wrench[idx])     # readings as published
    # joints: chords of the true path between 250 Hz samples (exact in holds); wrist_3, published wrapped, unwrapped
    ts = (stamps - s.t0_ns) * 1e-9
    q = s.q(ts)
    for j in JOINTS:
        assert np.abs(rec.q[j] - q[j]).max() < 2e-5, j
    assert rec.q["wrist_3"].max() > np.pi + 0.5
    # temperature: linear between the 2 Hz samples, the first sample held before it
    assert np.abs(rec.temperature["wrist"] - s.temperature(np.maximum(ts, 0.25))).max() < 1e-3


@pytest.mark.parametrize("storage, split", [("sqlite3", "messages"), ("mcap", None), ("ros1", "topics")])
def test_storages_give_one_table_and_no_temperature_without_its_topic(tmp_path, storage, split) -> None:
    """sqlite3 (read by rosbags) and MCAP (read chunk by chunk) bags of one session give the same table, the joints on
    one topic in one message per stamp or split over two messages of each stamp; no temperature topic: no
    temperature column."""
    s = write_arm_session(tmp_path / storage, storage, seed=5, holds=3, temperature_hz=None, split_joints=split)
    res = ingest(s.map, progress=False)
    rec = res.dataset.recordings[0]
    assert rec.temperature == {} and set(rec.q) == set(JOINTS) and res.counts[0].n_rows == len(s.wrench_stamp_ns) - 2
    stamps = res.epoch_ns + np.round(rec.t * 1e9).astype(np.int64)
    assert np.array_equal(stamps, s.wrench_stamp_ns[1:-1])
    np.testing.assert_array_equal(rec.wrench["wrist"], s.wrench[1:-1])
    q = s.q((stamps - s.t0_ns) * 1e-9)
    assert max(np.abs(rec.q[j] - q[j]).max() for j in JOINTS) < 2e-5


# ----------------------------------------------------------------------------- bad input


def _small(tmp_path: Path, **kw):
    return write_arm_session(tmp_path / "bags", "mcap", seed=7, holds=2, hold_s=1.0, move_s=1.0, **kw)


def _edit(mp: Path, **arm) -> Path:
    d = tomllib.loads(mp.read_text())
    for k, v in arm.items():
        if k.startswith("top_"):
            d[k[4:]] = v
        elif v is None:
            d["arm"].pop(k)
        else:
            d["arm"][k] = v
    mp.write_bytes(tomli_w.dumps(d).encode())
    return mp


@pytest.mark.parametrize("edit, message", [
    ({"wrench_topic": "/ft/other"}, r"topic '/ft/other' of map key \[arm\] wrench_topic is not in the bag \(topics: "),
    ({"joint_states": ["/arm/joint_states", "/gripper/joint_states"]}, r"topic '/gripper/joint_states' of map key \[arm\] joint_states is not in the bag"),
    ({"temperature_topic": "/ft/temp"}, r"topic '/ft/temp' of map key \[arm\] temperature_topic is not in the bag"),
    ({"joint_prefix": "ur5e_"}, r"URDF joint 'shoulder_pan' .* has 0 position\(s\) on \['/arm/joint_states', '/wrist/joint_states'\] "
                                r"\(field name; expected 'ur5e_shoulder_pan' .* none of them a URDF joint: set \[arm\] joint_prefix\?"),
    ({"frame_id": "tool0"}, r"topic '/ft_sensor/wrench' field header.frame_id is \['ft_sensor'\], expected 'tool0' \(\[arm\] frame_id\)"),
    ({"joint_states": "/ft_sensor/wrench"}, r"topics .* name one topic twice"),
])
def test_bag_and_map_mismatches_name_topic_and_key(tmp_path, edit, message) -> None:
    s = _small(tmp_path)
    with pytest.raises(DataFormatError, match=message):
        ingest(_edit(s.map, **edit), progress=False)


@pytest.mark.parametrize("edit, message", [
    ({"link": "ft_link"}, r"\[arm\]: key 'link' = 'ft_link' is not a link of arm6.urdf \(links: "),
    ({"gravity_link": "flange"}, r"link 'flange' moves with joint\(s\) .* the link gravity_body is given in must be fixed to B"),
    ({"gravity_body": [0, 0, 0]}, r"key 'gravity_body' should be 3 finite numbers, not all zero"),
    ({"wrench_topics": "/x"}, r"\[arm\]: unknown key\(s\) \['wrench_topics'\]; known: "),
    ({"top_legs": ["wrist"]}, r"key\(s\) \['legs'\] do not belong in an \[arm\] map"),
    ({"top_recording": [{"bag": "wrist", "kind": "standing"}]}, r"kind = 'standing'; an arm's recordings are 'hanging'"),
    ({"max_gap_s": 0}, r"key 'max_gap_s' = 0 should be a positive number of seconds"),
])
def test_bad_arm_map_keys_are_named(tmp_path, edit, message) -> None:
    s = _small(tmp_path)
    with pytest.raises(DataFormatError, match=message):
        read_any_map(_edit(s.map, **edit))


def test_map_readers_tell_arm_maps_apart(tmp_path) -> None:
    s = _small(tmp_path)
    with pytest.raises(DataFormatError, match=r"an \[arm\] map"):
        read_map(s.map)
    m = read_arm_map(tomllib.loads(s.map.read_text()), s.map)
    assert m.arm.joints == JOINTS and m.arm.continuous == {"wrist_3"} and m.robot.mass_kg is None


def _bag(path: Path, wrench_ns, joint_ns, *, temp_ns=None, storage: str = "mcap") -> Path:
    """A bag of the arm with the given WrenchStamped, JointState (and Temperature) header stamps (bag order = list
    order); arm at rest, 30 degC."""
    w_ns, j_ns = np.asarray(wrench_ns, dtype=np.int64), np.asarray(joint_ns, dtype=np.int64)
    w = np.tile([1.0, 2.0, -8.0, 0.1, 0.2, 0.0], (len(w_ns), 1))
    series = [bagio.TopicSeries("/ft_sensor/wrench", bagio.WRENCH_TYPE, np.arange(len(w_ns)) + 10**18,
                                bagio.encode_messages(storage, bagio.WRENCH_TYPE, w_ns, "ft_sensor", w))]
    series.append(bagio.TopicSeries("/joint_states", bagio.JOINT_TYPE, np.arange(len(j_ns)) + 10**18,
                                    bagio.encode_messages(storage, bagio.JOINT_TYPE, j_ns, "", np.full((len(j_ns), 6), 0.3), JOINTS)))
    if temp_ns is not None:
        T = np.asarray(temp_ns, dtype=np.int64)
        series.append(bagio.TopicSeries("/temp", bagio.TEMPERATURE_TYPE, np.arange(len(T)) + 10**18,
                                        bagio.encode_messages(storage, bagio.TEMPERATURE_TYPE, T, "ft_sensor", np.tile([30.0, 0.0], (len(T), 1)))))
    return bagio.write_bag(path, series, storage=storage, overwrite=True)


def _map(tmp_path: Path) -> Path:
    (tmp_path / "arm6.urdf").write_text(ARM_URDF)
    mp = tmp_path / "map.toml"
    mp.write_bytes(tomli_w.dumps({"urdf": "arm6.urdf", "arm": {"link": "ft_sensor", "wrench_topic": "/ft_sensor/wrench",
                                                               "joint_states": "/joint_states"},
                                  "recording": [{"bag": "b"}]}).encode())
    return mp


T0 = 1_700_000_000_000_000_007


def test_joint_gap_longer_than_the_bound_is_refused_with_topic_and_time(tmp_path) -> None:
    w = T0 + np.arange(300) * 10_000_000                   # 3 s at 100 Hz
    j = T0 + np.arange(0, 3000, 4) * 1_000_000             # 250 Hz ...
    j = j[(j < T0 + 1_200_000_000) | (j > T0 + 1_500_000_000)]     # ... silent for 0.3 s
    _bag(tmp_path / "b", w, j)
    with pytest.raises(DataFormatError, match=r"topic '/joint_states' \(field position of joint 'shoulder_pan'\): no sample for 0.308 s, "
                                              r"from header stamp 1700000001.196000007 s to 1700000001.504000007 s, while 31 wrench "
                                              r"reading\(s\) fall inside; expected gaps of at most \[arm\] max_gap_s = 0.1 s"):
        ingest(_map(tmp_path), progress=False)
    mp = _edit(_map(tmp_path), max_gap_s=0.5)              # a bound that allows it: interpolated (the arm was still)
    assert ingest(mp, progress=False).counts[0].n_rows == 300
    # temperature: a gap longer than its bound is refused; rows beyond its ends by more than the bound dropped, counted
    _bag(tmp_path / "b", w, T0 + np.arange(0, 3000, 4) * 1_000_000, temp_ns=T0 + np.array([5, 10, 25]) * 100_000_000)
    mp = _edit(_map(tmp_path), temperature_topic="/temp", temperature_max_gap_s=1.0)
    with pytest.raises(DataFormatError, match=r"topic '/temp' \(field temperature\): no sample for 1.5 s, .* \[arm\] temperature_max_gap_s = 1 s"):
        ingest(mp, progress=False)
    res = ingest(_edit(mp, temperature_max_gap_s=2.0), progress=False)
    c, rec = res.counts[0], res.dataset.recordings[0]
    assert c.temperature_outside_span == 0 and np.all(rec.temperature["wrist"] == 30.0)
    _bag(tmp_path / "b", w, T0 + np.arange(0, 3000, 4) * 1_000_000, temp_ns=T0 + np.arange(5, 26) * 100_000_000)
    res = ingest(_edit(mp, temperature_max_gap_s=0.2 + 1e-9), progress=False)          # 0.5 s .. 2.5 s every 0.1 s:
    assert res.counts[0].temperature_outside_span == 59 == 300 - res.counts[0].n_rows   # rows before 0.3 s, after 2.7 s


def test_out_of_order_stamps_and_empty_bags_are_named(tmp_path) -> None:
    w = T0 + np.arange(200) * 10_000_000
    w[100:] -= 1_500_000_000                               # a clock reset halfway (bag order)
    _bag(tmp_path / "b", w, T0 - 2 * 10**9 + np.arange(0, 4000, 4) * 1_000_000)
    with pytest.raises(DataFormatError, match=r"topic '/ft_sensor/wrench' \(\[arm\] wrench_topic\): header stamps go backwards: sample 101 of 200"):
        ingest(_map(tmp_path), progress=False)
    bagio.write_bag(tmp_path / "b", [], storage="sqlite3", overwrite=True)
    with pytest.raises(DataFormatError, match=r"/b: empty bag \(no topics\); expected \[arm\] wrench_topic '/ft_sensor/wrench'"):
        ingest(_map(tmp_path), progress=False)
    # a topic of another type
    bagio.write_bag(tmp_path / "b", [bagio.TopicSeries("/joint_states", bagio.WRENCH_TYPE, np.array([1]),
                                                       bagio.encode_messages("mcap", bagio.WRENCH_TYPE, [T0], "x", np.zeros((1, 6))))],
                    storage="mcap", overwrite=True)
    with pytest.raises(DataFormatError, match=r"topic '/joint_states' has type geometry_msgs/msg/WrenchStamped, expected sensor_msgs/msg/JointState"):
        ingest(_map(tmp_path), progress=False)
