"""The BigAnt simulator: determinism, files, shapes, statics (tipping, equilibrium), walking truth, hooks."""

import json
import logging
from dataclasses import replace

import numpy as np
import pytest

from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.core.data import hanging_pairs, read_dataset
from ftcal_nlp.sim import EFFECTS, NoEffect, SimConfig, draw_true_robot, simulate, write_simulation
from ftcal_nlp.sim.recordings import pose_grid, solve_poses, transition_profile

from conftest import SAMPLE, constant_phi_windows, require_sample, requires_sample

SMALL = SimConfig(seed=3, n_poses=40, hanging_cycles=2, walk_cycles=1.0)
COMPONENTS = ("fx", "fy", "fz", "tx", "ty", "tz")


@pytest.fixture(scope="module")
def res():
    return simulate(SMALL)


def _arrays(r):
    out = []
    for rec in r.dataset.recordings:
        out += [rec.t, rec.phi_array(), rec.wrench_array()] + ([] if rec.quat is None else [rec.quat])
    return out + [r.walk_truth.to_numpy(), r.pose_windows]


def test_same_seed_same_arrays(res):
    again = simulate(SMALL)
    for a, b in zip(_arrays(res), _arrays(again), strict=True):
        np.testing.assert_array_equal(a, b)
    assert json.dumps(res.truth_json_dict()) == json.dumps(again.truth_json_dict())


def test_other_seed_differs(res):
    other = simulate(replace(SMALL, seed=4))
    assert not np.allclose(res.dataset.recordings[0].wrench_array(), other.dataset.recordings[0].wrench_array())
    assert not np.allclose(res.true_robot.R, other.true_robot.R)


def test_shapes_durations_and_session_clock(res):
    cfg = SMALL
    names = [r.name for r in res.dataset.recordings]
    assert names == ["hang_xpos", "hang_xneg", "hang_zpos", "hang_zneg", "standing", "walk"]
    kinds = [r.kind for r in res.dataset.recordings]
    assert kinds == ["hanging"] * 4 + ["standing", "walking"]
    dt = 1 / cfg.rate_hz
    for rec in res.dataset.hanging:
        assert rec.n == round(cfg.hanging_cycles * cfg.hanging_cycle_s * cfg.rate_hz)
        assert rec.quat is None
        turns = (rec.phi_array()[-1] - rec.phi_array()[0]) / (2 * np.pi)
        # each leg at its own speed, within the configured spread
        assert np.all(np.abs(turns / cfg.hanging_cycles - 1) <= cfg.hanging_speed_spread + 1e-3)
        assert np.ptp(turns) > 0
    st = res.dataset.standing[0]
    P = len(res.pose_phi)
    assert P + len(res.skipped_pose_phi) == cfg.n_poses
    assert st.n == P * round(cfg.pose_s * cfg.rate_hz)
    assert res.pose_windows.shape == (P, 2)
    walk = res.dataset.walking[0]
    assert walk.n == round(cfg.walk_cycles / cfg.walk_freq_hz * cfg.rate_hz) == len(res.walk_truth)
    t_all = np.concatenate([r.t for r in res.dataset.recordings])
    assert np.all(np.diff(t_all) > 0), "recordings follow each other on one session clock"
    for rec in res.dataset.recordings:
        np.testing.assert_allclose(np.diff(rec.t), dt, atol=2e-6)


def test_hanging_opposites(res):
    pairs = hanging_pairs(res.dataset.hanging)
    assert len(pairs) == 2
    for a, b in pairs:
        np.testing.assert_array_equal(a.gravity_body, -b.gravity_body)
    # the robot hangs ~2 deg off the nominal direction, about a random axis per recording
    tilts = [np.degrees(np.arccos((np.trace(R) - 1) / 2)) for R in res.hanging_tilt.values()]
    lo, hi = 0.75 * SMALL.hanging_tilt_deg, 1.25 * SMALL.hanging_tilt_deg
    assert all(lo - 1e-9 <= x <= hi + 1e-9 for x in tilts) and len(set(np.round(tilts, 6))) == 4


def test_noise_level_in_readings(res):
    """First differences of the steady readings carry sqrt(2) times the sensor noise."""
    st = res.dataset.standing[0]
    W = st.wrench_array()
    d = []
    for a, b in res.pose_windows:
        m = (st.t >= a) & (st.t <= b)
        d.append(np.diff(W[m], axis=0))
    sd = np.concatenate(d).std(axis=0) / np.sqrt(2)   # (K, 6)
    n = sum(len(x) for x in d)
    rel = 5 / np.sqrt(2 * n)                          # 5 standard errors of a standard deviation
    np.testing.assert_allclose(sd[:, :3], SMALL.noise_force_N, rtol=rel)
    np.testing.assert_allclose(sd[:, 3:], SMALL.noise_torque_Nm, rtol=rel)


def test_steady_windows_hold_the_pose(res):
    st = res.dataset.standing[0]
    phi = st.phi_array()
    for p, (a, b) in enumerate(res.pose_windows):
        m = (st.t >= a) & (st.t <= b)
        assert m.sum() == round((SMALL.pose_s - SMALL.settle_s) * SMALL.rate_hz)
        np.testing.assert_array_equal(phi[m], np.broadcast_to(res.pose_phi[p], phi[m].shape))
    grid = np.radians(SMALL.pose_angles_deg)
    assert np.all(np.min(np.abs(res.pose_phi[..., None] - grid), axis=-1) < 1e-12)


def test_transition_overshoots_then_settles():
    s, y = transition_profile(SMALL)
    i_settle = round(SMALL.settle_s * SMALL.rate_hz)
    assert s[0] == 0 and s[-1] == 1 and y[0] == 0
    assert y.max() > 1.1, "the response overshoots the new pose"
    assert np.abs(y[i_settle:] - 1).max() < 1e-3, "and has settled when the steady part starts"


def test_mocap_dropouts(res):
    cfg = replace(SMALL, mocap_dropout_rate=0.3, mocap_blip_rate_hz=0.05)
    r = simulate(cfg)
    st = r.dataset.standing[0]
    lost = np.isnan(st.quat[:, 0])
    whole = [np.all(lost[(st.t >= a) & (st.t <= b)]) for a, b in r.pose_windows]
    assert 0 < sum(whole) < len(whole)
    assert np.all(np.isnan(st.quat[lost])) and np.all(np.isfinite(st.quat[~lost]))
    np.testing.assert_allclose(np.linalg.norm(st.quat[~lost], axis=1), 1, atol=1e-12)


def test_written_files_read_back(res, tmp_path, caplog):
    manifest = write_simulation(res, tmp_path)
    with caplog.at_level(logging.WARNING):
        ds = read_dataset(manifest)
    assert not [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]  # no extra columns, no dropped rows
    assert [r.name for r in ds.recordings] == [r.name for r in res.dataset.recordings]
    for a, b in zip(res.dataset.recordings, ds.recordings, strict=True):
        csv = b.path.suffix == ".csv"
        tol = dict(rtol=1e-9, atol=1e-12) if csv else dict(rtol=0, atol=0)
        assert a.kind == b.kind and b.n_dropped == 0
        np.testing.assert_allclose(b.t, a.t, **tol)
        np.testing.assert_allclose(b.phi_array(), a.phi_array(), **tol)
        np.testing.assert_allclose(b.wrench_array(), a.wrench_array(), **tol)
        if a.quat is not None:
            np.testing.assert_allclose(b.quat, a.quat, **tol)  # NaN rows stay NaN
        if a.gravity_body is not None:
            np.testing.assert_array_equal(b.gravity_body, a.gravity_body)
    assert {r.path.suffix for r in ds.hanging} == {".csv"} and ds.standing[0].path.suffix == ".parquet"
    with pytest.raises(FileExistsError, match="dataset.toml exists"):
        write_simulation(res, tmp_path)
    import pandas as pd

    wt = pd.read_csv(tmp_path / "walk_truth.csv")
    assert list(wt.columns) == list(res.walk_truth.columns)
    np.testing.assert_allclose(wt.to_numpy(), res.walk_truth.to_numpy(), rtol=1e-9, atol=1e-12)


@requires_sample
def test_truth_json_layout_matches_sample(res, tmp_path):
    write_simulation(res, tmp_path)
    ours = json.loads((tmp_path / "truth.json").read_text())
    theirs = json.loads((SAMPLE / "truth.json").read_text())
    assert list(ours) == list(theirs)
    assert ours["effect"] == "none" and ours["seed"] == SMALL.seed
    assert list(ours["legs"]) == list(theirs["legs"])
    for k in ours["legs"]:
        assert set(ours["legs"][k]) == set(theirs["legs"]["FL"])
        assert set(ours["legs"][k]["leg_com_grid"]) == set(theirs["legs"]["FL"]["leg_com_grid"])
        assert len(ours["legs"][k]["leg_com_grid"]["phi"]) == 72
    cal = Calibration.load(tmp_path / "truth.json", g=9.81)
    assert cal.mass_kg == SMALL.mass_kg
    for k, leg in cal.legs.items():
        t = res.truth.legs[k]
        np.testing.assert_allclose(leg.offset, t.offset)
        np.testing.assert_allclose(leg.rotation_to_body, t.rotation_to_body)
        np.testing.assert_allclose(leg.position_from_com_m, t.position_from_com_m)
        np.testing.assert_allclose(leg.com(np.linspace(0, 7, 50)), t.com(np.linspace(0, 7, 50)))
        np.testing.assert_allclose(ours["legs"][k]["position_m"], res.truth_positions_m[k])
        np.testing.assert_allclose(np.array(ours["legs"][k]["position_m"]) - ours["com_body_m"], leg.position_from_com_m, atol=1e-15)


def test_truth_is_bigant_like(res):
    tr = res.true_robot
    frac = tr.weights_N.sum() / tr.weight_N
    assert 0.43 < frac < 0.49, "legs carry ~46 % of the mass"
    R_err = np.einsum("kij,klj->kil", tr.R, tr.robot.nominal_rotations())
    ang = np.degrees(np.arccos(np.clip((np.trace(R_err, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert np.all(ang < 4 * SMALL.mounting_rot_deg) and ang.mean() > 0.2 * SMALL.mounting_rot_deg
    dp = np.linalg.norm(tr.p - tr.robot.nominal_positions(), axis=1) * 1e3
    assert np.all(dp < 4 * SMALL.mounting_trans_mm) and dp.mean() > 0.2 * SMALL.mounting_trans_mm
    # toe straight down at phi = 0, ~0.17 m below the hip; lifted near phi = pi
    down = tr.ft_to_body(tr.foot_ft(np.zeros(6))) - tr.p
    assert np.all(np.abs(down[:, 2] + SMALL.toe_depth_m) < 0.01) and np.all(np.abs(down[:, 0]) < 0.01)
    up = tr.ft_to_body(tr.foot_ft(np.full(6, np.pi))) - tr.p
    assert np.all(up[:, 2] - down[:, 2] > 0.05)
    # the four-bar's flat-ish stance arc: lowest at 0, a few mm up at +-36 deg (as configured), then rising to pi
    for a in (-36.0, 36.0):
        rise = tr.toe_height(np.full(6, np.radians(a))) * 1e3
        assert np.all(np.abs(rise - SMALL.toe_stance_rise_mm) <= SMALL.toe_rise_spread_mm + 1e-9), rise
    h = tr.toe_height(np.linspace(0, np.pi, 181)[:, None] * np.ones(6))
    assert np.all(h[0] == 0) and np.all(np.diff(h, axis=0) > 0)
    np.testing.assert_allclose(h[-1], tr.toe_lift, rtol=1e-12)


def test_standing_equilibrium_is_exact(res):
    """Per pose, on level ground and on the board: the ground forces (foot springs, the slope's
    friction share, internal forces) hold the whole robot, inside the friction cones."""
    tr = res.true_robot
    board_dir = np.where(np.arange(len(res.pose_phi)) % 3 == 0, np.random.default_rng(1).uniform(0, 2 * np.pi, len(res.pose_phi)), np.nan)
    poses = solve_poses(tr, SMALL, res.pose_phi, np.random.default_rng(0), board_dir)
    assert len(poses.skipped) == 0
    np.testing.assert_array_equal(poses.on_board, np.isfinite(board_dir))
    feet_W = np.einsum("pij,pkj->pki", poses.R_tilt, tr.ft_to_body(tr.foot_ft(poses.phi)))
    c_W = np.einsum("pij,pj->pi", poses.R_tilt, tr.total_com_B(poses.phi))
    F = poses.ground_W0
    np.testing.assert_allclose(F.sum(1), np.broadcast_to([0, 0, tr.weight_N], (len(F), 3)), atol=1e-7)
    np.testing.assert_allclose(np.cross(feet_W - c_W[:, None], F).sum(1), 0, atol=1e-8)
    # friction: in the ground's frame (z its normal) the tangential force stays inside the cone
    F_G = np.einsum("pji,pkj->pki", poses.R_ground, F)
    normal, tangential = F_G[..., 2], np.linalg.norm(F_G[..., :2], axis=-1)
    assert np.all(normal >= 0)
    level, board = ~poses.on_board, poses.on_board
    assert np.all(tangential[level] <= 0.5 * SMALL.friction_mu * normal[level] + 1e-12), "inside the friction cones"
    assert tangential[level].max() > 0.3 * SMALL.internal_force_N, "internal forces are present"
    assert np.all(tangential[board] <= SMALL.board_friction_mu * normal[board] + 1e-12)
    tan = np.tan(np.radians(SMALL.board_tilt_deg))
    # the board carries the slope's share, tan(theta) N, on every loaded foot (internal forces aside)
    np.testing.assert_allclose(tangential[board].sum(1) / normal[board].sum(1), tan, rtol=0.1)
    slope = np.degrees(np.arccos(poses.R_ground[:, 2, 2]))
    np.testing.assert_allclose(slope[board], SMALL.board_tilt_deg, atol=1e-9)
    np.testing.assert_allclose(slope[level], 0, atol=1e-9)
    # the body lies on the board within the compliance tilt
    rel = np.degrees(np.arccos(np.einsum("pi,pi->p", poses.R_ground[:, :, 2], poses.R_tilt[:, :, 2])))
    assert np.all(rel <= SMALL.max_tilt_deg)


def test_potential_derivatives_match_finite_differences():
    """The equilibrium solver's analytic gradient and Hessian of the potential energy, and
    the gradient's zero is the documented equilibrium (force and moments about the CoM)."""
    from ftcal_nlp.sim.statics import _potential, _residual

    tr = draw_true_robot(SMALL, np.random.default_rng(5))
    phi = np.radians([[0, 36, -36, 0, 36, -36], [36, 36, 36, -36, -36, -36], [0, 0, 0, 0, 0, 0]])
    feet, com = tr.ft_to_body(tr.foot_ft(phi)), tr.total_com_B(phi)
    q = np.array([[0.163, 0.004, -0.003], [0.160, -0.006, 0.002], [0.1675, 0.0, 0.0]])
    W, k = tr.weight_N, SMALL.foot_stiffness_N_per_m
    bumps = np.random.default_rng(6).normal(0.0, 1e-3, (3, 6))  # an uneven floor
    V, g, H = _potential(q, feet, com, W, k, bumps)
    assert np.all(((bumps - (tr.ft_to_body(tr.foot_ft(phi))[..., 2] + q[:, :1])) > 0).sum(1) >= 3), "several feet in contact"
    h = 1e-6
    for j, e in enumerate(np.eye(3) * h):
        Vp, gp, _ = _potential(q + e, feet, com, W, k, bumps)
        Vm, gm, _ = _potential(q - e, feet, com, W, k, bumps)
        np.testing.assert_allclose((Vp - Vm) / (2 * h), g[:, j], atol=1e-6 * W)
        np.testing.assert_allclose((gp - gm) / (2 * h), H[:, :, j], rtol=1e-5, atol=1e-4 * W)
    # the force equation is the z-gradient; level (a = b = 0), the moment equations about the CoM are
    # -dV/da and +dV/db up to the force residual's moment: -dV/da = r_1 + r_0 c_y, dV/db = r_2 + r_0 c_x
    r = _residual(q, feet, com, W, k, None, bumps)[0]
    np.testing.assert_allclose(r[:, 0], -g[:, 0], atol=1e-9)
    np.testing.assert_allclose(r[2, 1] + r[2, 0] * com[2, 1], -g[2, 1], atol=1e-9)
    np.testing.assert_allclose(r[2, 2] + r[2, 0] * com[2, 0], g[2, 2], atol=1e-9)


def test_tipping_pose_is_skipped():
    """Legs at 180 deg hold their feet 8 cm up: a pose tips when the CoM leaves the support of the rest."""
    cfg = replace(SMALL, pose_angles_deg=(0.0, 180.0), n_poses=None)
    tr = draw_true_robot(cfg, np.random.default_rng(1))
    grid = pose_grid(cfg.pose_angles_deg, 6)
    poses = solve_poses(tr, cfg, grid, np.random.default_rng(2))
    kept = {tuple(p) for p in np.round(poses.phi, 9)}
    skipped = {tuple(p) for p in np.round(poses.skipped, 9)}
    assert len(kept) + len(skipped) == 64 and skipped and kept
    # Independent check with the level robot: support polygon of the lowest feet (those at 0 deg,
    # or all six at 180 deg); feet 8 cm higher cannot reach the ground within the 5 deg tilt limit.
    for phi in grid:
        feet = tr.ft_to_body(tr.foot_ft(phi))
        down = feet[:, 2] < feet[:, 2].min() + 0.02
        feet = feet[down, :2]
        com = tr.total_com_B(phi)[:2]
        margin = _polygon_margin(com, feet)
        key = tuple(np.round(phi, 9))
        if margin > 0.005:
            assert key in kept, f"pose {np.degrees(phi)} is well supported (margin {margin:.3f} m) but was skipped"
        elif margin < -0.005:
            assert key in skipped, f"pose {np.degrees(phi)} has its CoM {-margin:.3f} m outside the support but was kept"
    r = simulate(replace(cfg, seed=1, hanging_cycles=0.2, walk_cycles=0.3))
    assert len(r.skipped_pose_phi) > 0 and len(r.pose_phi) + len(r.skipped_pose_phi) == 64


def _polygon_margin(pt, pts):
    """Signed distance of ``pt`` inside the convex hull of ``pts`` (negative outside; -inf if < 3 points)."""
    if len(pts) < 3:
        return -np.inf
    from scipy.spatial import ConvexHull

    hull = ConvexHull(pts)
    # hull.equations: n . x + d <= 0 inside, n unit
    return float(-(hull.equations[:, :2] @ pt + hull.equations[:, 2]).max())


def test_walk_truth(res):
    wt = res.walk_truth
    legs = res.dataset.robot.legs
    G = np.stack([wt[[f"{k}_{c}" for c in COMPONENTS]].to_numpy() for k in legs], axis=1)
    total = wt[[f"total_{c}" for c in COMPONENTS]].to_numpy()
    np.testing.assert_allclose(G.sum(1), total, atol=1e-9)
    mg = SMALL.mass_kg * SMALL.g
    np.testing.assert_allclose(total, np.broadcast_to([0, 0, mg, 0, 0, 0], total.shape), atol=1e-6)
    # Feet well into the swing read exactly zero: lifted on their toe loop by more than the largest
    # foot compression (max load / stiffness), plus what the body tilt lowers a foot 0.4 m from the
    # support, plus 5 mm for the legs' height differences (mounting, toe depth and rise).
    tr = res.true_robot
    walk = res.dataset.walking[0]
    phi = walk.phi_array(legs)
    lift = tr.toe_height(phi)
    from ftcal_nlp.core.geometry import quat_to_rotation

    ok = np.isfinite(walk.quat[:, 0])
    tilt = np.arccos(quat_to_rotation(walk.quat[ok])[:, 2, 2]).max()
    clear = G[..., 2].max() / SMALL.foot_stiffness_N_per_m + 0.4 * np.sin(tilt) + 0.005
    assert clear < 0.03
    swing = lift > clear
    assert swing.any(axis=0).all()
    assert np.all(G[swing] == 0.0)
    # a tripod or more carries the robot, each loaded foot pushes up
    loaded = G[..., 2] > 0
    assert np.all(loaded.sum(1) >= 3) and np.all(G[..., 2] >= 0)
    # both tripods take turns
    assert loaded[:, [0, 2, 4]].all(1).any() and loaded[:, [1, 3, 5]].all(1).any()
    # it turns at the configured rate (the heading of the mocap quaternion)
    from ftcal_nlp.core.geometry import quat_to_rotation, yaw_of

    q = res.dataset.walking[0].quat
    ok = np.isfinite(q[:, 0])
    yaw = np.unwrap(yaw_of(quat_to_rotation(q[ok])))
    rate = np.polyfit(res.dataset.walking[0].t[ok], yaw, 1)[0]
    np.testing.assert_allclose(np.degrees(rate) / SMALL.walk_freq_hz, SMALL.walk_turn_deg_per_cycle, rtol=0.02)


def test_config_from_dict():
    cfg = SimConfig.from_dict({"seed": 7, "pose_angles_deg": [-30, 0, 30], "n_poses": 12, "noise_force_N": 0.1})
    assert cfg.seed == 7 and cfg.pose_angles_deg == (-30.0, 0.0, 30.0) and cfg.n_poses == 12 and cfg.noise_force_N == 0.1
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['hanging_cyles'\].*hanging_cycles"):
        SimConfig.from_dict({"hanging_cyles": 3})
    with pytest.raises(ValueError, match="'seed' should be an integer"):
        SimConfig.from_dict({"seed": "x"})
    with pytest.raises(ValueError, match="unknown effect 'tether'"):
        SimConfig.from_dict({"effects": ["tether"]})
    with pytest.raises(ValueError, match="pose_s"):
        SimConfig(pose_s=1.0)
    with pytest.raises(ValueError, match="rate_hz must be > 0"):
        SimConfig.from_dict({"rate_hz": 0})


class _AddToReadings(NoEffect):
    """A stand-in effect: adds a known wrench to one leg's readings while standing, tilts mocap."""

    name = "casing_load"
    scale = 2.0

    def readings(self, ctx, w):
        out = w.copy()
        if ctx.kind == "standing":
            assert ctx.applied.shape == w.shape and ctx.pose_index.shape == ctx.t.shape
            out[:, 0, 0] += self.scale
        return out

    def orientation(self, ctx, R):
        return R

    def robot(self, robot):
        return replace(robot, mass_kg=robot.mass_kg + 0.5)


def test_effect_hook(res, tmp_path):
    base = replace(SMALL, walk_cycles=0.3, hanging_cycles=0.2, n_poses=5)
    plain = simulate(base)
    hooked = simulate(replace(base, effects=(_AddToReadings(),)))
    d = hooked.dataset.standing[0].wrench_array() - plain.dataset.standing[0].wrench_array()
    np.testing.assert_allclose(d[:, 0, 0], 2.0, atol=1e-9)
    np.testing.assert_allclose(np.delete(d.reshape(len(d), -1), 0, axis=1), 0, atol=1e-9)
    np.testing.assert_array_equal(hooked.dataset.hanging[0].wrench_array(), plain.dataset.hanging[0].wrench_array())
    assert hooked.dataset.robot.mass_kg == SMALL.mass_kg + 0.5 and hooked.truth.mass_kg == SMALL.mass_kg
    write_simulation(hooked, tmp_path)
    assert read_dataset(tmp_path / "dataset.toml").robot.mass_kg == SMALL.mass_kg + 0.5
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["effect"] == "casing_load" and truth["scale"] == 2.0 and truth["in_library"] is True
    assert EFFECTS == {} or all(callable(f) for f in EFFECTS.values())


# ----------------------------------------------------------------------------- realism against the shared sample

LEVEL = np.cos(np.radians(10.0))   # pose whose body z is within 10 deg of up: level ground
LOADED_N = 1.0                     # a foot carries load when the ground pushes it up by more than this


def _ground_from_readings(rec, legs, windows, cal, min_rows=100):
    """Per pose (median of its steady rows with motion capture): ground force on each foot in W,
    reading less offset less leg weight turned into W with ``cal``, (P, K, 3); shaft angles (P, K);
    R_WB (P, 3, 3); rows used (P,); index of the window (P,)."""
    from ftcal_nlp.core import physics
    from ftcal_nlp.core.geometry import quat_to_rotation

    offsets, weights, rotations, _ = cal.stacked(legs)
    W, PHI = rec.wrench_array(legs), rec.phi_array(legs)
    out = {"F": [], "phi": [], "R": [], "n": [], "i": []}
    for i, rows in enumerate(windows):
        rows = rows[np.isfinite(rec.quat[rows, 0])]
        if len(rows) < min_rows:
            continue
        q = rec.quat[rows] * np.sign(rec.quat[rows] @ rec.quat[rows[0]])[:, None]
        qm = np.median(q, axis=0)
        R = quat_to_rotation(qm / np.linalg.norm(qm))
        phi = np.median(PHI[rows], axis=0)
        u = physics.gravity_dir_in_ft(R, rotations)
        r = np.stack([cal.legs[k].com(phi[j : j + 1])[0] for j, k in enumerate(legs)])
        w = np.median(W[rows], axis=0) - offsets - physics.leg_gravity_wrench(u, r, weights)
        for key, v in zip(out, (np.einsum("ij,kjl,kl->ki", R, rotations, w[:, :3]), phi, R, len(rows), i)):
            out[key].append(v)
    return {k: np.array(v) for k, v in out.items()}


def _load_stats(g):
    """Loading and tilt statistics of level poses: P(loaded | leg at 0), P(loaded | leg at +-36 deg),
    per-leg loaded fraction (K,), mean number of loaded feet, median tilt (deg)."""
    level = g["R"][:, 2, 2] > LEVEL
    loaded = g["F"][level][..., 2] > LOADED_N
    at0 = np.isclose(g["phi"][level], 0.0, atol=1e-6)
    tilt = np.degrees(np.arccos(g["R"][level][:, 2, 2]))
    return dict(p0=loaded[at0].mean(), p36=loaded[~at0].mean(), frac=loaded.mean(0), feet=loaded.sum(1).mean(), tilt=np.median(tilt))


@pytest.fixture(scope="module")
def sample_loads():
    ds = read_dataset(require_sample() / "dataset.toml", kinds=("standing",))
    st, legs = ds.standing[0], ds.robot.legs
    g = _ground_from_readings(st, legs, constant_phi_windows(st, legs), Calibration.load(SAMPLE / "truth.json", g=9.81))
    return g, _load_stats(g)


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_every_leg_carries_load_like_the_sample(seed, sample_loads):
    """Each leg's mounting is identifiable only where its foot carries ground load. Over the whole
    3^6 grid, read off the readings with the truth as on the sample: every leg is loaded in at least
    20 % of the level poses, and the loading resembles the sample's (a leg at 0 deg nearly always
    loaded, at +-36 deg in ~70 % of poses; ~5 feet loaded; the body tilted ~0.8 deg)."""
    r = simulate(SimConfig(seed=seed, hanging_cycles=0.1, walk_cycles=0.0))
    st, legs = r.dataset.standing[0], r.dataset.robot.legs
    g = _ground_from_readings(st, legs, [np.flatnonzero((st.t >= a) & (st.t <= b)) for a, b in r.pose_windows], r.truth)
    # The readings give the true vertical ground forces to the noise: the median's reading noise and
    # the motion-capture error (held through the pose) turning the reading's force into W.
    true_fz = r.pose_ground_N[g["i"]][..., 2]
    f_ft = np.linalg.norm(g["F"], axis=-1)
    sd = np.sqrt(np.pi / 2 * r.config.noise_force_N**2 / g["n"][:, None]
                 + 2 * (np.radians(r.config.mocap_pose_error_deg) * f_ft) ** 2 + 1e-12)
    z = (g["F"][..., 2] - true_fz) / sd
    assert np.abs(z).max() < 5, np.abs(z).max()

    ours, (_, theirs) = _load_stats(g), sample_loads
    print(f"\nseed {seed}: loaded fraction per leg {ours['frac'].round(2)} (sample {theirs['frac'].round(2)}); "
          f"P(loaded | 0 deg) {ours['p0']:.2f} ({theirs['p0']:.2f}), P(loaded | +-36 deg) {ours['p36']:.2f} ({theirs['p36']:.2f}); "
          f"feet loaded {ours['feet']:.2f} ({theirs['feet']:.2f}); median tilt {ours['tilt']:.2f} deg ({theirs['tilt']:.2f})")
    assert ours["frac"].min() >= 0.2
    assert theirs["frac"].min() >= 0.2, "the sample, the reference: every leg loaded"
    # Resemblance, not equality (other robots, other seeds): within 0.15 in the fractions, half a
    # foot in the count, a factor 1.6 in the tilt.
    assert abs(ours["p0"] - theirs["p0"]) < 0.15 and abs(ours["p36"] - theirs["p36"]) < 0.15
    assert abs(ours["feet"] - theirs["feet"]) < 0.5
    assert 1 / 1.6 < ours["tilt"] / theirs["tilt"] < 1.6


def test_board_poses_like_the_sample(sample_loads):
    """A share of the poses stand on a 38 deg board (the sample: 9 of 108 at 38-39 deg), downhill in a
    random direction per pose: gravity then has a large component in the body's xy plane, which makes
    the turn of all transducers about z identifiable. The robot stays on the board (friction) and
    only the uphill feet may lift."""
    cfg = replace(SMALL, n_poses=150, hanging_cycles=0.1, walk_cycles=0.0)
    r = simulate(cfg)
    n_board = round(cfg.board_pose_fraction * cfg.n_poses)
    assert r.pose_on_board.sum() == n_board and len(r.skipped_pose_phi) == 0
    g = _ground_from_readings(r.dataset.standing[0], r.dataset.robot.legs,
                              [np.flatnonzero((r.dataset.standing[0].t >= a) & (r.dataset.standing[0].t <= b)) for a, b in r.pose_windows],
                              r.truth)
    on = r.pose_on_board[g["i"]]
    tilt = np.degrees(np.arccos(g["R"][:, 2, 2]))
    assert np.all(np.abs(tilt[on] - cfg.board_tilt_deg) < 2.0), tilt[on]      # board plus compliance
    assert np.all(tilt[~on] < 3.0)
    sample_g, _ = sample_loads
    sample_tilt = np.degrees(np.arccos(sample_g["R"][:, 2, 2]))
    assert np.all(np.abs(sample_tilt[sample_tilt > 10] - cfg.board_tilt_deg) < 2.0) and (sample_tilt > 10).sum() == 9
    # downhill directions in B spread around (gravity's horizontal part in the body frame)
    up_B = g["R"][on, 2, :]
    az = np.arctan2(up_B[:, 1], up_B[:, 0])
    assert np.abs(np.mean(np.exp(1j * az))) < 0.6, "not all in one direction"
    # the readings hold the robot: vertical loads carry the weight, ground forces nearly vertical
    # (the slope's friction share turns each normal load vertical; internal forces aside)
    F = g["F"][on]
    np.testing.assert_allclose(F[..., 2].sum(1), r.truth.mass_kg * r.truth.g, rtol=0.01)
    assert np.all((F[..., 2] > LOADED_N).sum(1) >= 2)


def test_board_poses_slip_without_enough_friction():
    """Below tan(38 deg) = 0.78 no friction holds the robot on the board: those poses are skipped."""
    base = replace(SMALL, n_poses=60, hanging_cycles=0.1, walk_cycles=0.0, board_pose_fraction=0.2)
    held = simulate(base)
    slid = simulate(replace(base, board_friction_mu=0.75))
    assert held.pose_on_board.sum() == 12 and slid.pose_on_board.sum() == 0
    assert len(slid.skipped_pose_phi) == len(held.skipped_pose_phi) + 12
    flat = simulate(replace(base, board_pose_fraction=0.0))
    assert flat.pose_on_board.sum() == 0 and len(flat.pose_phi) == 60


def test_mocap_error_is_held_through_each_pose():
    """Motion capture: an orientation error constant through each standing pose (not averaged by
    the pose median) plus white jitter; walking has the white jitter only. With the jitter off, the
    measured orientation differs from the error-free one by exactly the pose's held error."""
    base = replace(SMALL, n_poses=20, hanging_cycles=0.1, walk_cycles=0.3, mocap_jitter_deg=0.0,
                   mocap_dropout_rate=0.0, mocap_blip_rate_hz=0.0)
    from ftcal_nlp.core.geometry import quat_to_rotation, rotation_to_rotvec

    clean = simulate(replace(base, mocap_pose_error_deg=0.0))
    held = simulate(base)
    err = held.pose_mocap_error
    assert err.shape == (len(held.pose_phi), 3)
    # its size: per-axis sd of the configured value (5 standard errors of an sd over 3P draws)
    assert abs(np.degrees(err.std()) / base.mocap_pose_error_deg - 1) < 5 / np.sqrt(2 * err.size)
    a, b = clean.dataset.standing[0], held.dataset.standing[0]
    np.testing.assert_array_equal(a.wrench_array(), b.wrench_array())  # readings untouched
    rv = rotation_to_rotvec(np.swapaxes(quat_to_rotation(a.quat), 1, 2) @ quat_to_rotation(b.quat))
    pose = np.repeat(np.arange(len(held.pose_phi)), round(base.pose_s * base.rate_hz))
    np.testing.assert_allclose(rv, err[pose], atol=1e-12)
    np.testing.assert_array_equal(clean.dataset.walking[0].quat, held.dataset.walking[0].quat)
    # white jitter on top: a pose's rows scatter by it about their (held) median
    jit = simulate(replace(base, mocap_jitter_deg=0.05)).dataset.standing[0]
    R = quat_to_rotation(jit.quat)
    lo, hi = held.pose_windows[0]
    m = (jit.t >= lo) & (jit.t <= hi)
    d = np.degrees(rotation_to_rotvec(np.swapaxes(R[m][:1], 1, 2) @ R[m]))
    assert abs(np.diff(d, axis=0).std() / np.sqrt(2) / 0.05 - 1) < 5 / np.sqrt(2 * d[1:].size)
