"""The free-load simulator (DATA_FORMAT.md section 5) checked against the page and against someone else's data.

The key checks feed the truth of the independent samples ``shared/sample_payload``
and ``shared/sample_urdf`` (and their orientation / joint columns) through this
simulator's noise-free reading functions: the residual of the recorded readings
must be the samples' noise on held samples, and the plausible wrong conventions
(the mounting rotation's sign, a CoM in the ft frame instead of the link's own,
the URDF's nominal bodies) must not fit. Frames and units are read from the
sample's files with tomllib / pandas, not with the project's reader.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.geometry import quat_to_rotation, rotvec_to_rotation
from ftcal_nlp.sim.free import (
    LEG4_URDF, PayloadConfig, UrdfLegConfig, config_from_dict, gravity_in_body, gravity_in_ft, load_tree,
    payload_readings, simulate_payload, simulate_to_folder, simulate_urdf_leg, true_rotation, urdf_load_readings,
    write_free_load,
)

SHARED = Path("/work/shared")
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
needs_samples = pytest.mark.skipif(not (SHARED / "sample_urdf" / "truth.json").is_file(), reason="shared samples absent")


def _sample(name: str):
    d = SHARED / name
    manifest = tomllib.loads((d / "dataset.toml").read_text())
    robot = tomllib.loads((d / manifest["robot"]).read_text())
    (rec,) = manifest["recording"]
    df = pd.read_csv(d / rec["file"])
    truth = json.loads((d / "truth.json").read_text())
    return d, robot, df, truth


def _held(df: pd.DataFrame, cols: list[str]) -> np.ndarray:
    """Rows whose orientation and joint columns equal the previous row's (a hold; the first row counts)."""
    x = df[cols].to_numpy()
    return np.r_[True, np.all(x[1:] == x[:-1], axis=1)]


def _noise_level(res: np.ndarray, sd: np.ndarray) -> None:
    """Residual (n, 6) is white noise of sd ``sd``: per-channel sd within 10 %, mean within 5 se."""
    n = len(res)
    assert np.all(np.abs(res.std(0) / sd - 1) < 0.1), (res.std(0), sd)
    assert np.all(np.abs(res.mean(0)) < 5 * sd / np.sqrt(n)), (res.mean(0), sd / np.sqrt(n))


# ----------------------------------------------------------------------------- the independent samples


@needs_samples
def test_sample_payload_matches_the_page_and_the_mount_convention() -> None:
    _, robot, df, truth = _sample("sample_payload")
    (leg,) = robot["legs"]
    assert f"{leg}_phi" not in df.columns                                    # a rigid payload
    R_nom = np.asarray(robot["transducers"][leg]["rotation"], dtype=float)
    R_WB = quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy())
    w = df[[f"{leg}_{c}" for c in WRENCH]].to_numpy()
    held = _held(df, ["qw", "qx", "qy", "qz"])
    assert 0.5 < held.mean() < 0.9                                            # moves between holds
    sd = np.asarray(truth["noise"])
    rv = np.asarray(truth["mount_rotvec"])

    def residual(R_ft):
        g_ft = gravity_in_ft(R_WB, R_ft, robot["g"])
        return w - payload_readings(g_ft, truth["mass_kg"], truth["com_m"], truth["offset"])

    res = residual(true_rotation(R_nom, rv))                                  # R_true = R_nom @ expm(rv)
    _noise_level(res[held], sd)
    _noise_level(res[~held], sd)                                              # their moves are quasi-static too
    # the rotation vector is the true frame relative to the nominal one, not the inverse, and it matters
    for wrong in (R_nom @ rotvec_to_rotation(-rv), R_nom):
        assert np.all(np.sqrt((residual(wrong)[held, :2] ** 2).mean(0)) > 3 * sd[:2])
    # R_nom = I in this sample, so R_nom @ expm(rv) and expm(rv) @ R_nom coincide: it cannot tell them apart
    assert np.allclose(R_nom, np.eye(3))


@needs_samples
def test_sample_urdf_matches_with_coms_in_each_link_frame() -> None:
    d, robot, df, truth = _sample("sample_urdf")
    tree = load_tree(d / robot["urdf"])
    (leg,) = robot["legs"]
    ft_link = robot["transducers"][leg]["link"]
    qcols = [c for c in df.columns if c.startswith("q_")]
    assert sorted(c[2:] for c in qcols) == sorted(tree.movable)
    q = {c[2:]: df[c].to_numpy() for c in qcols}
    g_B = gravity_in_body(quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy()), robot["g"])
    w = df[[f"{leg}_{c}" for c in WRENCH]].to_numpy()
    held = _held(df, ["qw", "qx", "qy", "qz"] + qcols)
    sd = np.asarray(truth["noise"])
    bodies = {k: (v["mass_kg"], np.asarray(v["com_m"])) for k, v in truth["bodies"].items()}
    assert set(bodies) == set(tree.below(ft_link)) & set(tree.bodies)
    rv = np.asarray(truth.get("mount_rotvec", np.zeros(3)))                   # this sample has none
    res = w - urdf_load_readings(tree, ft_link, q, g_B, bodies, truth["offset"], rv)
    _noise_level(res[held], sd)
    assert abs(sum(m for m, _ in bodies.values()) - truth["load_mass_kg"]) < 1e-12

    def torque_rms(res_):
        return np.sqrt((res_[held, 3:] ** 2).mean(0))

    # the URDF's nominal bodies do not fit (the truth differs from the CAD) ...
    nominal = {k: (v["mass_kg"], np.asarray(v["com_m"])) for k, v in truth["nominal_bodies"].items()}
    assert np.all(torque_rms(w - urdf_load_readings(tree, ft_link, q, g_B, nominal, truth["offset"])) > 10 * sd[3:])
    # ... nor do the true CoMs read in the ft frame instead of each link's own
    n = len(df)
    R_B_ft, _ = tree.pose(tree.root, ft_link, q, n)
    g_ft = np.einsum("nji,nj->ni", R_B_ft, g_B)
    f = sum(m for m, _ in bodies.values()) * g_ft
    t = sum(np.cross(c, m * g_ft) for m, c in bodies.values())
    assert np.all(torque_rms(w - (np.concatenate([f, t], axis=1) + truth["offset"])) > 10 * sd[3:])


# ----------------------------------------------------------------------------- this simulator


@pytest.fixture(scope="module")
def payload():
    return simulate_payload(PayloadConfig(seed=11))


@pytest.fixture(scope="module")
def leg():
    return simulate_urdf_leg(UrdfLegConfig(seed=12, n_orientations=8, poses_per_orientation=2))


def test_payload_readings_are_truth_plus_noise_through_written_files(payload, tmp_path) -> None:
    manifest = write_free_load(payload, tmp_path)
    m = tomllib.loads(manifest.read_text())
    robot = tomllib.loads((tmp_path / m["robot"]).read_text())
    (rec,) = m["recording"]
    assert rec["kind"] == "hanging" and "gravity_body" not in rec
    assert "mass_kg" not in robot and robot["legs"] == ["wrist"]
    tr = robot["transducers"]["wrist"]
    truth = json.loads((tmp_path / "truth.json").read_text())
    df = pd.read_csv(tmp_path / rec["file"])
    assert list(df.columns) == ["t", *(f"wrist_{c}" for c in WRENCH), "qw", "qx", "qy", "qz"]
    assert np.array_equal(df.to_numpy(), payload.frame.to_numpy())          # full precision on disk
    assert np.all(np.diff(df["t"]) > 0)
    R_ft = true_rotation(np.asarray(tr["rotation"]), truth["mount_rotvec"])
    g_ft = gravity_in_ft(quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy()), R_ft, robot["g"])
    res = df[[f"wrist_{c}" for c in WRENCH]].to_numpy() - payload_readings(g_ft, truth["mass_kg"], truth["com_m"], truth["offset"])
    _noise_level(res, np.asarray(truth["noise"]))
    assert not np.allclose(tr["rotation"], np.eye(3))                         # a nominal rotation that tells conventions apart
    with pytest.raises(FileExistsError):
        write_free_load(payload, tmp_path)


def test_payload_moves_between_holds(payload) -> None:
    held = payload.held
    assert 0.6 < held.mean() < 0.8 and payload.truth["n_held"] == held.sum()
    q = payload.frame[["qw", "qx", "qy", "qz"]].to_numpy()
    # held: constant; moving: smooth (no sample-to-sample jump above 1 deg) and not constant
    same = np.all(q[1:] == q[:-1], axis=1)
    assert np.all(same[held[1:] & held[:-1]]) and not np.all(same)
    R = payload.R_WB
    step = np.arccos(np.clip((np.einsum("nij,nij->n", R[1:], R[:-1]) - 1) / 2, -1, 1))
    assert step.max() < np.radians(1.0)
    # gravity directions of the holds spread over the sphere: no axis is unseen
    g = gravity_in_body(R[held], 1.0)
    assert np.all(g.min(0) < -0.5) and np.all(g.max(0) > 0.5)


def test_urdf_leg_asset_and_dataset_follow_section_5(leg, tmp_path) -> None:
    tree = load_tree(LEG4_URDF)
    cfg = leg.config
    mount = tree.joints[cfg.ft_link]
    assert mount.type == "fixed"                                              # sensor = a fixed joint's child link
    below = [j for j in tree.joints.values() if j.type != "fixed" and j.child in tree.below(cfg.ft_link)]
    above = [j for j in tree.path_to_root(cfg.ft_link) if j.type != "fixed"]
    assert len(below) >= 4 and len(above) >= 1
    q0 = {j: np.zeros(2) for j in tree.movable}
    q1 = {**q0, above[0].name: np.array([0.0, 0.4])}
    R0, p0 = tree.pose(tree.root, cfg.ft_link, q1, 2)
    assert not np.allclose(R0[0], R0[1]) or not np.allclose(p0[0], p0[1])   # ft pose in B depends on q
    write_free_load(leg, tmp_path)
    robot = tomllib.loads((tmp_path / "robot.toml").read_text())
    assert robot["urdf"] == "robot.urdf" and robot["transducers"]["r_leg"] == {"link": "r_leg_ft"}
    assert (tmp_path / "robot.urdf").read_text() == LEG4_URDF.read_text()
    df = pd.read_csv(tmp_path / "leg.csv")
    assert [c for c in df.columns if c.startswith("q_")] == [f"q_{j}" for j in tree.movable]
    assert "r_leg_phi" not in df.columns and {"qw", "qx", "qy", "qz"} <= set(df.columns)
    truth = json.loads((tmp_path / "truth.json").read_text())
    bodies = {k: (v["mass_kg"], np.asarray(v["com_m"])) for k, v in truth["bodies"].items()}
    q = {c[2:]: df[c].to_numpy() for c in df.columns if c.startswith("q_")}
    g_B = gravity_in_body(quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy()), robot["g"])
    res = df[[f"r_leg_{c}" for c in WRENCH]].to_numpy() - urdf_load_readings(
        tree, "r_leg_ft", q, g_B, bodies, truth["offset"], truth["mount_rotvec"])
    _noise_level(res, np.asarray(truth["noise"]))
    # the truth is not the CAD: ~10 % in mass, several mm in CoM
    nom = truth["nominal_bodies"]
    dm = np.array([bodies[k][0] / nom[k]["mass_kg"] - 1 for k in nom])
    dc = np.array([np.linalg.norm(bodies[k][1] - nom[k]["com_m"]) for k in nom])
    assert np.all(np.abs(dm) < 0.5) and np.abs(dm).max() > 0.03
    assert np.all(dc > 1e-3) and np.all(dc < 0.05)
    assert 1e-4 < np.linalg.norm(truth["mount_rotvec"]) < 0.1


def test_urdf_kinematics_agree_with_yourdfpy() -> None:
    import yourdfpy

    tree = load_tree(LEG4_URDF)
    u = yourdfpy.URDF.load(str(LEG4_URDF), load_meshes=False, build_collision_scene_graph=False)
    rng = np.random.default_rng(0)
    for _ in range(3):
        cfg = {j: rng.uniform(-0.5, 0.5) for j in tree.movable}
        u.update_cfg(cfg)
        for link in ("r_leg_ft", "r_foot", "r_shank"):
            R, p = tree.pose("base", link, {k: np.array([v]) for k, v in cfg.items()}, 1)
            T = u.get_transform(link, "base")
            assert np.allclose(R[0], T[:3, :3], atol=1e-12) and np.allclose(p[0], T[:3, 3], atol=1e-12)
        R, p = tree.pose("r_leg_ft", "r_foot", {k: np.array([v]) for k, v in cfg.items()}, 1)
        T = np.linalg.solve(u.get_transform("r_leg_ft", "base"), u.get_transform("r_foot", "base"))
        assert np.allclose(R[0], T[:3, :3], atol=1e-12) and np.allclose(p[0], T[:3, 3], atol=1e-12)


def test_gravity_columns_variant() -> None:
    r = simulate_urdf_leg(UrdfLegConfig(seed=12, n_orientations=8, poses_per_orientation=2, orientation="gravity"))
    g = r.frame[["gx", "gy", "gz"]].to_numpy()
    assert "qw" not in r.frame.columns and np.allclose(np.linalg.norm(g, axis=1), 1.0)
    assert np.allclose(g, gravity_in_body(r.R_WB, 1.0))
    assert np.all(np.abs(g[:, 2]) > np.cos(np.radians(60.0)) - 1e-9)       # tilts up to 60 deg: B's z stays near vertical


def test_deterministic_and_configured_from_toml(leg) -> None:
    a = simulate_urdf_leg(UrdfLegConfig(seed=12, n_orientations=8, poses_per_orientation=2))
    assert a.frame.equals(leg.frame) and a.truth == leg.truth
    b = simulate_urdf_leg(UrdfLegConfig(seed=13, n_orientations=8, poses_per_orientation=2))
    assert not np.allclose(b.frame["r_leg_fx"], leg.frame["r_leg_fx"])
    cfg = config_from_dict({"kind": "payload", "seed": 4, "n_orientations": 6, "mount_rotvec": [0, 0, 0.01], "effects": ["offset_drift"]})
    assert isinstance(cfg, PayloadConfig) and cfg.mount_rotvec == (0.0, 0.0, 0.01) and cfg.effects[0].name == "offset_drift"
    with pytest.raises(ValueError, match="unknown key.*hold_sec"):
        config_from_dict({"kind": "urdf_leg", "hold_sec": 3})
    with pytest.raises(ValueError, match="free-load kinds"):
        config_from_dict({"kind": "arm"})
    with pytest.raises(ValueError, match="casing_load.*need a hexapod"):
        config_from_dict({"kind": "payload", "effects": ["casing_load"]})


def test_effects_act_on_readings_and_orientation() -> None:
    base = simulate_payload(PayloadConfig(seed=5, n_orientations=4))
    drift = simulate_payload(PayloadConfig(seed=5, n_orientations=4, effects=("offset_drift",)))
    dw = (drift.frame["wrist_fx"] - base.frame["wrist_fx"]).to_numpy()
    assert np.all(np.diff(dw) > -1e-12) or np.all(np.diff(dw) < 1e-12)    # a monotone warm-up on the same noise
    assert abs(dw[-1] - dw[0]) > 1e-3
    bias = simulate_payload(PayloadConfig(seed=5, n_orientations=4, effects=("mocap_bias",)))
    assert np.array_equal(bias.frame["wrist_fx"], base.frame["wrist_fx"])
    assert not np.allclose(bias.frame["qx"], base.frame["qx"])
    assert bias.truth["effects"][0]["name"] == "mocap_bias"


def test_simulate_table_hook(tmp_path) -> None:
    from ftcal_nlp.sim import simulate_to_folder as hook

    assert hook is simulate_to_folder
    m = hook({"kind": "payload", "seed": 1, "n_orientations": 3, "hold_s": 2.0, "move_s": 1.0}, tmp_path / "p")
    assert (m.parent / "wrist.csv").is_file() and json.loads((m.parent / "truth.json").read_text())["kind"] == "payload"
    with pytest.raises(ValueError, match="known kinds"):
        hook({"kind": "quadruped"}, tmp_path / "q")


def test_hexapod_config_accepts_its_kind_and_refers_free_kinds() -> None:
    from ftcal_nlp.sim import SimConfig

    assert SimConfig.from_dict({"kind": "hexapod", "seed": 3}).seed == 3
    with pytest.raises(ValueError, match="simulate_to_folder"):
        SimConfig.from_dict({"kind": "payload"})


def test_inertial_wrench_of_a_spinning_body_is_analytic() -> None:
    from ftcal_nlp.sim.free.physics import inertial_wrench

    t = np.arange(0.0, 2.0, 1e-3)
    alpha, omega0, m, rho, Izz = 0.7, 1.3, 2.0, 0.1, 0.05
    angle = omega0 * t + 0.5 * alpha * t**2
    R_WB = rotvec_to_rotation(angle[:, None] * np.array([0.0, 0.0, 1.0]))     # B spins about W's z, origin fixed
    body = (m, np.broadcast_to([rho, 0.0, 0.0], (len(t), 3)), np.broadcast_to(np.eye(3), (len(t), 3, 3)), np.diag([0.0, 0.0, Izz]))
    w = inertial_wrench(t, R_WB, np.zeros(3), np.eye(3), [body])[5:-5]        # ft = B; interior samples
    om = (omega0 + alpha * t)[5:-5]
    # the load pulls the sensor outward (centripetal reaction) and backward (tangential reaction)
    assert np.allclose(w[:, 0], m * om**2 * rho, rtol=1e-4) and np.allclose(w[:, 1], -m * alpha * rho, rtol=1e-4)
    assert np.allclose(w[:, 5], -(m * rho**2 + Izz) * alpha, rtol=1e-4) and np.allclose(w[:, [2, 3, 4]], 0.0, atol=1e-9)


def test_inertial_load_only_in_moves() -> None:
    a = simulate_payload(PayloadConfig(seed=2, n_orientations=5))
    b = simulate_payload(PayloadConfig(seed=2, n_orientations=5, inertial_load=1.0))
    d = b.clean - a.clean
    assert np.array_equal(d[a.held], np.zeros_like(d[a.held]))               # held: at rest, the static wrench
    assert np.abs(d[~a.held, :3]).max() > 5 * a.config.noise_force_N         # moves: not quasi-static
    assert b.truth["effects"] == [{"name": "inertial_load", "scale": 1.0}]


def test_truth_files_know_the_simulators_kinds():
    from ftcal_nlp.sim.free.config import FREE_SIM_KINDS as simulated
    from ftcal_nlp.truth import FREE_SIM_KINDS as read

    assert tuple(simulated) == tuple(read)
