"""ROS ingest end to end (issue 9, item 4): a simulated session as bags, ingested, calibrated.

The simulator's session is written in the interchange format (CSV/Parquet) and
read back; the same recordings become ROS bags (ROS 1 for the x pair and the
walk, ROS 2 MCAP for the z pair and standing) with joint states at half rate
and 3 ms late and no mocap message during tracking losses, plus a URDF of the
nominal robot. Ingested, they must give the CSV recordings (wrenches exactly,
shaft angles within the chord error of the half-rate joint stream, orientation
exactly where mocap saw the robot), the nominal robot, and a calibration
within its standard errors of the CSV one. Last, ``python -m ftcal_nlp.correct
... --bag`` writes a ground-wrench bag that reads back as its CSV.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.ros import bagio
from ftcal_nlp.ros.ingest import ingest, write_ingested
from ftcal_nlp.ros.simbag import bag_name, recording_series, session_map, stamps_ns
from ftcal_nlp.ros.urdf import urdf_text
from ftcal_nlp.sim import SimConfig, simulate, write_simulation

EPOCH_NS = 1_700_000_000 * 10**9
JOINT_DELAY_NS = 3_000_000
STORAGE = {"hang_xpos": "ros1", "hang_xneg": "ros1", "hang_zpos": "mcap", "hang_zneg": "mcap", "standing": "mcap", "walk": "ros1"}
MAX_POSE_GAP_S = 0.05  # the map's default [body_pose] max_gap_s


def _chord_bound(t_rows, t_src, f_src, s_nodes):
    """Largest error of the chord between joint samples ``s_nodes`` against the
    piecewise-linear source at ``t_rows``: (b - a)/4 times the sum of the slope
    changes of the source inside the bracketing [a, b] (as ``test_ros._chord_bound``, vectorised)."""
    kinks = np.abs(np.diff(np.concatenate([[0.0], np.diff(f_src) / np.diff(t_src), [0.0]])))
    csum = np.concatenate([[0.0], np.cumsum(kinks)])
    j = np.clip(np.searchsorted(s_nodes, t_rows, side="right"), 1, len(s_nodes) - 1)
    a, b = s_nodes[j - 1], s_nodes[j]
    inside = csum[np.searchsorted(t_src, b, side="right")] - csum[np.searchsorted(t_src, a, side="left")]
    return inside * (b - a) / 4


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("ros_pipeline")
    res = simulate(SimConfig(seed=1, n_poses=60, hanging_cycles=2, walk_cycles=0.5))
    csv = read_dataset(write_simulation(res, root / "csv"))
    legs = csv.robot.legs
    bags = root / "bags"
    bags.mkdir()
    written = []
    for rec in csv.recordings:
        st = STORAGE[rec.name]
        path = bags / bag_name(rec, st)
        # the walk's messages are rosbags objects, the rest copies of one serialised template
        series = recording_series(rec, legs, st, epoch_ns=EPOCH_NS, joint_every=2, joint_delay_ns=JOINT_DELAY_NS, encode=rec.name != "walk")
        bagio.write_bag(path, series, storage=st)
        written.append((path.name, rec))
    (bags / "robot.urdf").write_text(urdf_text(csv.robot))
    mp = bags / "map.toml"
    mp.write_bytes(tomli_w.dumps(session_map(legs, csv.robot.mass_kg, csv.robot.g, written)).encode())
    result = ingest(mp, progress=False)
    ing = read_dataset(write_ingested(result, root / "ingested"))
    return {"root": root, "res": res, "csv": csv, "ing": ing, "result": result}


def _rows(session, rec):
    """Source rows of an ingested recording, and the clock rows the joint stream spans."""
    src = next(r for r in session["csv"].recordings if r.name == rec.name)
    t_src = rec.t + (session["result"].epoch_ns - EPOCH_NS) * 1e-9
    rows = np.searchsorted(src.t, t_src - 1e-7)
    clock = stamps_ns(src.t, EPOCH_NS)
    js = clock[::2] + JOINT_DELAY_NS
    js = js[js <= clock[-1]]
    return src, rows, t_src, (clock >= js[0]) & (clock <= js[-1]), (js - EPOCH_NS) * 1e-9


def test_robot_is_the_nominal_robot_from_the_urdf(session):
    ing, csv = session["ing"].robot, session["csv"].robot
    assert ing.legs == csv.legs and ing.mass_kg == csv.mass_kg and ing.g == csv.g
    for k in csv.legs:
        np.testing.assert_allclose(ing.transducers[k].rotation, csv.transducers[k].rotation, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ing.transducers[k].position_m, csv.transducers[k].position_m, rtol=0, atol=1e-12)


def test_recordings_match_the_csvs_within_interpolation_error(session):
    ing, counts = session["ing"], {c.name: c for c in session["result"].counts}
    assert [r.name for r in ing.recordings] == [r.name for r in session["csv"].recordings]
    worst_phi, n_lost = 0.0, 0
    for rec in ing.recordings:
        src, rows, t_src, spanned, s_nodes = _rows(session, rec)
        assert rec.kind == src.kind
        if rec.gravity_body is not None:
            np.testing.assert_array_equal(rec.gravity_body, src.gravity_body)
        # rows: every source row the joint stream spans (the first is before the first joint sample)
        np.testing.assert_array_equal(rows, np.flatnonzero(spanned))
        np.testing.assert_allclose(t_src, src.t[rows], rtol=0, atol=1e-9)
        assert counts[rec.name].n_clock == src.n and sum(counts[rec.name].joint_gap.values()) == 0
        for k in src.legs:
            np.testing.assert_array_equal(rec.wrench[k], src.wrench[k][rows])
            # shaft angle: the chord between joint samples 20 ms apart, against the piecewise-linear source
            err = np.abs(rec.phi[k] - src.phi[k][rows])
            bound = _chord_bound(src.t[rows], src.t, src.phi[k], s_nodes)
            floor = np.abs(np.diff(src.phi[k]) / np.diff(src.t)).max() * 1e-9 + 1e-12
            assert np.all(err <= bound + floor), (rec.name, k, np.max(err - bound))
            worst_phi = max(worst_phi, float(err.max()))
        if src.quat is None:
            assert rec.quat is None or np.all(np.isnan(rec.quat))
            continue
        # orientation: the mocap sample itself where there was one; NaN inside losses longer than max_gap_s
        q_src = src.quat[rows] / np.linalg.norm(src.quat[rows], axis=1, keepdims=True)  # 10 digits in the CSV; ingest normalises
        lost = np.isnan(src.quat[:, 0])
        idx = np.arange(src.n)
        prev = np.maximum.accumulate(np.where(~lost, idx, -1))
        nxt = np.minimum.accumulate(np.where(~lost, idx, src.n)[::-1])[::-1]
        inside = (prev >= 0) & (nxt < src.n)
        width = np.where(inside, src.t[np.minimum(nxt, src.n - 1)] - src.t[np.maximum(prev, 0)], np.inf)
        expect_nan = (lost & (width > MAX_POSE_GAP_S))[rows]
        n_lost += int(expect_nan.sum())
        np.testing.assert_array_equal(np.isnan(rec.quat[:, 0]), expect_nan)
        seen = ~lost[rows]
        sign = np.sign(np.sum(rec.quat[seen] * q_src[seen], axis=1))
        np.testing.assert_allclose(rec.quat[seen] * sign[:, None], q_src[seen], rtol=0, atol=1e-12)
    assert n_lost >= 100  # the standing recording has tracking losses (~1000 rows with seed 1)
    assert 0 < worst_phi < 1e-2  # the half-rate joint stream is exercised, its error small


def _hanging(ds):
    from ftcal_nlp.estimate.hanging import fit_hanging

    return fit_hanging(ds.hanging, ds.robot)


@pytest.fixture(scope="module")
def calibrations(session):
    return _hanging(session["csv"]), _hanging(session["ing"])


def test_hanging_calibration_matches_the_csv_one_within_its_standard_errors(calibrations):
    a, b = calibrations
    worst = 0.0
    for k, la in a.legs.items():
        lb = b.legs[k]
        assert la.converged and lb.converged
        assert np.all(np.abs(la.offset - lb.offset) < la.offset_se), (k, (la.offset - lb.offset) / la.offset_se)
        assert abs(la.leg_weight_N - lb.leg_weight_N) < la.leg_weight_se_N
        ok = la.com_mask & lb.com_mask
        assert ok.sum() >= 0.9 * ok.size
        assert np.all(np.abs(la.com_xyz[ok] - lb.com_xyz[ok]) < la.com_xyz_se[ok])
        for name, R in la.misalignment.items():
            d = np.linalg.norm(R.T @ lb.misalignment[name] - np.eye(3))
            assert d < np.linalg.norm(la.misalignment_se[name])
        worst = max(worst, np.max(np.abs(la.offset - lb.offset) / la.offset_se), abs(la.leg_weight_N - lb.leg_weight_N) / la.leg_weight_se_N)
    assert worst < 1.0


def test_standing_calibration_matches_the_csv_one_within_its_standard_errors(session, calibrations):
    from ftcal_nlp.estimate.standing import extract_poses, fit_standing

    fits = []
    for ds, h in zip((session["csv"], session["ing"]), calibrations):
        stand = next(r for r in ds.recordings if r.kind == "standing")
        poses = extract_poses(stand, ds.robot)
        # rot6_trans1 is identified by these poses (every se finite); "full" is not, with 60 poses
        fits.append(fit_standing(poses, h.to_calibration(ds.robot), ds.robot, model="rot6_trans1"))
    a, b = fits
    assert a.n_poses == b.n_poses >= 40
    assert np.all(np.isfinite(a.rotvec_se)) and np.all(np.isfinite(a.p_prime_se))
    drot = np.abs(a.rotation_errors - b.rotation_errors)
    assert np.all(drot < a.rotvec_se), drot / a.rotvec_se
    assert np.all(np.abs(a.p_prime - b.p_prime) < a.p_prime_se), (a.p_prime - b.p_prime) / a.p_prime_se
    assert np.all(np.abs(a.com_body_m - b.com_body_m) < a.com_body_se_m)


def test_correct_cli_writes_a_ground_wrench_bag_that_reads_back(session, tmp_path):
    res = session["res"]
    cal = tmp_path / "cal.json"
    res.truth.save(cal)
    walk = session["root"] / "csv" / "walk.csv"
    out, bag = tmp_path / "out.csv", tmp_path / "out_bag"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    cmd = [sys.executable, "-m", "ftcal_nlp.correct", str(cal), str(walk), "-o", str(out), "--bag", str(bag)]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    import pandas as pd

    df = pd.read_csv(out)
    src = next(r for r in session["csv"].recordings if r.name == "walk")
    legs = res.dataset.robot.legs
    got = bagio.read_wrench_topics(bag)
    assert sorted(got) == sorted([f"/ground_wrench/{k}" for k in legs] + ["/ground_wrench/total"])
    for k in [*legs, "total"]:
        stamp, w, frames = got[f"/ground_wrench/{k}"]
        assert frames == frozenset({"heading"})
        np.testing.assert_allclose(stamp * 1e-9, src.t, rtol=0, atol=1e-9)  # every walk row has an orientation
        # the CSV holds 7 significant digits of what the bag holds in full
        csv_w = df[[f"{k}_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy()
        np.testing.assert_allclose(w, csv_w, rtol=5e-7, atol=1e-9)
    # the walk's ground wrench is that of the simulator's truth (the calibration is the truth)
    truth = res.walk_truth
    np.testing.assert_allclose(got["/ground_wrench/total"][1][:, 2], truth["total_fz"].to_numpy(), rtol=0, atol=0.5)
    # not written over without --force
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 2 and "exists" in p.stderr
