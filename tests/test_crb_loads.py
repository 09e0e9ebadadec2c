"""Cramer-Rao bounds of the free loads (crb/free_load.py): the Jacobian against the simulator's forward model, the
bound against the Monte-Carlo spread of least squares where the model is linear (kth ft_calib for a payload,
the weighted LS of the joint groups for a URDF leg), and orientations that cannot determine the load flagged.

Monte-Carlo tolerance: with R replicates the sample sd of an efficient estimator is the bound within a
relative error of about 1/sqrt(2 (R - 1)); the tests allow 4 of those, and the mean error 4 sd/sqrt(R).
"""

from __future__ import annotations

import numpy as np
import pytest

from ftcal_nlp import crb as cl
from ftcal_nlp.core.geometry import rotation_to_rotvec, rotvec_to_rotation
from ftcal_nlp.bench.peers import calib_force, ft_calib
from ftcal_nlp.sim.free import (PayloadConfig, UrdfLegConfig, gravity_in_body, gravity_in_ft, load_tree, payload_readings,
                                simulate_payload, simulate_urdf_leg, urdf_load_readings)
from ftcal_nlp.sim.free.simulate import rpy_to_rotation

R_MC = 300
REL = 4.0 / np.sqrt(2 * (R_MC - 1))


def _payload_design(stride: int = 20, **kw):
    cfg = PayloadConfig(seed=5, **kw)
    res = simulate_payload(cfg)
    R_WB = res.R_WB[res.held][::stride]
    R_true = rpy_to_rotation(cfg.rotation_rpy) @ rotvec_to_rotation(np.asarray(res.truth["mount_rotvec"]))
    return cfg, res, R_WB, R_true


def test_payload_jacobian_matches_forward_model() -> None:
    rng = np.random.default_rng(1)
    R_WB = rotvec_to_rotation(rng.normal(size=(30, 3)))
    R0 = rotvec_to_rotation(np.array([0.3, -0.2, 1.0]))
    m, c, off = 1.3, np.array([0.01, -0.02, 0.07]), rng.normal(size=6)
    g = gravity_in_ft(R_WB, R0, 9.81)
    J = cl.payload_jacobian(g, m, c, mount=True)
    theta = np.concatenate([off, [m], c])
    eps = 1e-6
    for k in range(13):
        d = np.zeros(13)
        d[k] = eps

        def w(x):
            th = theta + x[:10]
            return payload_readings(gravity_in_ft(R_WB, R0 @ rotvec_to_rotation(x[10:]), 9.81), th[6], th[7:10], th[:6])

        fd = (w(d) - w(-d)) / (2 * eps)
        assert np.allclose(fd, J[:, :, k], atol=1e-6), cl.payload_names()[k]


def test_payload_bound_matches_ft_calib_monte_carlo() -> None:
    """No mounting rotation, known orientations: ft_calib's LS is efficient, its MC sd is the bound."""
    cfg, res, R_WB, R_true = _payload_design(mount_rotvec=(0.0, 0.0, 0.0))
    g = gravity_in_ft(R_WB, R_true, cfg.g)
    truth = np.concatenate([res.truth["offset"], [cfg.mass_kg], cfg.com_m])
    clean = payload_readings(g, cfg.mass_kg, np.asarray(cfg.com_m), np.asarray(res.truth["offset"]))
    sigma = np.asarray(res.truth["noise"])
    b = cl.payload_bound(g, cfg.mass_kg, np.asarray(cfg.com_m), sigma, mount=False)
    assert b.identifiable and b.unidentified == ()
    rng = np.random.default_rng(7)
    est = []
    for _ in range(R_MC):
        fit = ft_calib(g, clean + rng.standard_normal(clean.shape) * sigma)
        est.append(np.concatenate([fit.offset, [fit.mass_kg], fit.com_m]))
    err = np.array(est) - truth
    mc_sd = err.std(axis=0, ddof=1)
    ratio = mc_sd / b.bound.sd
    assert np.all(np.abs(ratio - 1) < REL), dict(zip(b.names, ratio.round(3)))
    assert np.all(np.abs(err.mean(0)) < 4 * mc_sd / np.sqrt(R_MC))
    # the peer's own se (residual variance x (H^T H)^-1) agrees with the bound too
    assert np.allclose(fit.com_se_m, b.sd(["com_x", "com_y", "com_z"]), rtol=0.15)


def test_payload_bound_with_mount_rotation_is_larger_and_calib_force_above_it() -> None:
    """With the mounting rotation free the bound grows; the calibForce-style fit (rotation from forces only,
    unweighted) has an MC spread at or above the bound."""
    rv = np.radians(1.0) * np.array([1.0, -2.0, 1.5]) / np.linalg.norm([1.0, -2.0, 1.5])
    cfg, res, R_WB, R_true = _payload_design(mount_rotvec=tuple(rv))
    g_true = gravity_in_ft(R_WB, R_true, cfg.g)
    g_nom = gravity_in_ft(R_WB, rpy_to_rotation(cfg.rotation_rpy), cfg.g)
    sigma = np.asarray(res.truth["noise"])
    b0 = cl.payload_bound(g_true, cfg.mass_kg, np.asarray(cfg.com_m), sigma, mount=False)
    b1 = cl.payload_bound(g_true, cfg.mass_kg, np.asarray(cfg.com_m), sigma, mount=True)
    assert b1.identifiable
    assert np.all(b1.sd(b0.names) >= b0.bound.sd * (1 - 1e-9))
    clean = payload_readings(g_true, cfg.mass_kg, np.asarray(cfg.com_m), np.asarray(res.truth["offset"]))
    rng = np.random.default_rng(8)
    est = []
    for _ in range(R_MC):
        fit = calib_force(g_nom, clean + rng.standard_normal(clean.shape) * sigma)
        est.append(np.concatenate([fit.offset, [fit.mass_kg], fit.com_m, fit.mount_rotvec]))
    err = np.array(est) - np.concatenate([res.truth["offset"], [cfg.mass_kg], cfg.com_m, rv])
    rmse = np.sqrt((err**2).mean(0))
    assert np.all(rmse >= b1.bound.sd * (1 - REL)), dict(zip(b1.names, (rmse / b1.bound.sd).round(3)))


def test_orientation_jitter_raises_the_bound() -> None:
    cfg, res, R_WB, R_true = _payload_design()
    g = gravity_in_ft(R_WB, R_true, cfg.g)
    sigma = np.asarray(res.truth["noise"])
    b0 = cl.payload_bound(g, cfg.mass_kg, np.asarray(cfg.com_m), sigma)
    b1 = cl.payload_bound(g, cfg.mass_kg, np.asarray(cfg.com_m), sigma, orientation_sd_rad=np.radians(0.5))
    assert np.all(b1.bound.sd >= b0.bound.sd) and b1.se["mount_rx"] > 2 * b0.se["mount_rx"]


def test_orientations_about_the_vertical_are_flagged() -> None:
    """Turning the tool only about gravity leaves gravity fixed in ft: mass against the force offset, the CoM
    and the mounting rotation against the offsets are not determined; the bound names them."""
    n = 400
    R_WB = rotvec_to_rotation(np.linspace(0, 2 * np.pi, n)[:, None] * np.array([0.0, 0.0, 1.0])) @ rotvec_to_rotation(np.array([0.7, 0.2, 0.0]))
    g = gravity_in_ft(R_WB, np.eye(3), 9.81)
    b = cl.payload_bound(g, 1.5, np.array([0.006, -0.004, 0.08]), np.array([0.02] * 3 + [6e-4] * 3))
    assert b.bound.n_dropped == 7 and not b.identifiable
    text = " ".join(b.unidentified)
    assert "mass_kg" in text and "com_" in text and "mount_r" in text


def test_turning_about_one_horizontal_axis_determines_everything() -> None:
    """The contrast: about a horizontal axis gravity sweeps a plane in ft; the force's harmonics give mass, offset
    and the rotation (phase and tilt of the circle), the torque's the CoM: nothing is flagged."""
    R_WB = rotvec_to_rotation(np.linspace(0, np.pi / 2, 400)[:, None] * np.array([1.0, 0.0, 0.0]))
    g = gravity_in_ft(R_WB, np.eye(3), 9.81)
    b = cl.payload_bound(g, 1.5, np.array([0.006, -0.004, 0.08]), np.array([0.02] * 3 + [6e-4] * 3))
    assert b.identifiable and b.unidentified == ()


def test_two_gravity_directions_leave_one_com_component() -> None:
    g = np.repeat(np.array([[0, 0, -9.81], [0, -9.81, 0]]), 200, axis=0)
    b = cl.payload_bound(g, 1.5, np.array([0.006, -0.004, 0.08]), np.array([0.02] * 3 + [6e-4] * 3), mount=False)
    assert b.bound.n_dropped == 1
    # the first moment along g1 - g2 = (0, 1, -1) is what torques never see
    assert "com_y" in b.unidentified[0] and "com_z" in b.unidentified[0]


# ----------------------------------------------------------------------------- URDF leg


@pytest.fixture(scope="module")
def leg():
    cfg = UrdfLegConfig(seed=3)
    res = simulate_urdf_leg(cfg)
    tree = load_tree(cfg.urdf_path)
    sel = np.flatnonzero(res.held)[::10]
    q = {j: v[sel] for j, v in res.q.items()}
    g_B = gravity_in_body(res.R_WB[sel], cfg.g)
    bodies = {l: (b["mass_kg"], np.asarray(b["com_m"])) for l, b in res.truth["bodies"].items()}
    return cfg, res, tree, q, g_B, bodies


def test_joint_groups_of_leg4(leg) -> None:
    _, _, tree, *_ = leg
    groups = cl.joint_groups(tree, "r_leg_ft")
    assert [g.name for g in groups] == ["r_hip_pitch", "r_knee", "r_ankle_pitch", "r_ankle_roll"]
    assert [g.links for g in groups] == [("r_thigh",), ("r_shank",), ("r_ankle",), ("r_foot",)]


def test_urdf_model_and_jacobian_match_forward_model(leg) -> None:
    cfg, res, tree, q, g_B, bodies = leg
    rv = np.asarray(res.truth["mount_rotvec"])
    off = np.asarray(res.truth["offset"])
    g_ft = cl.urdf_gravity_in_ft(tree, cfg.ft_link, q, g_B, rv)
    b, groups = cl.urdf_bound(tree, cfg.ft_link, q, g_ft, bodies, np.ones(6), offset=off)
    R, p = cl.group_poses(tree, cfg.ft_link, groups, q, len(g_ft))
    m, s = cl.group_truth(tree, groups, bodies)
    J = cl.urdf_jacobian(g_ft, R, p, m, s, mount=True)
    w = urdf_load_readings(tree, cfg.ft_link, q, g_B, bodies, off, rv)
    # linear in (offsets, m_k, s_k): J theta is the reading
    assert np.allclose(np.einsum("nij,j->ni", J[:, :, :-3], b.theta[:-3]), w, atol=1e-10)
    eps = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        # a perturbation in the true ft axes: exp(rv) exp(d) ~ exp(rv + d) to O(|rv| eps)
        fd = (urdf_load_readings(tree, cfg.ft_link, q, g_B, bodies, off, rotation_to_rotvec(rotvec_to_rotation(rv) @ rotvec_to_rotation(d)))
              - urdf_load_readings(tree, cfg.ft_link, q, g_B, bodies, off, rotation_to_rotvec(rotvec_to_rotation(rv) @ rotvec_to_rotation(-d)))) / (2 * eps)
        assert np.allclose(fd, J[:, :, -3 + k], atol=1e-6)


def test_urdf_bound_matches_weighted_ls_monte_carlo(leg) -> None:
    """Known mounting: the model is linear in the group parameters; the weighted LS (minimum norm on what the
    data leave undetermined) is efficient and unbiased on the identifiable subspace."""
    cfg, res, tree, q, g_B, bodies = leg
    rv = np.asarray(res.truth["mount_rotvec"])
    g_ft = cl.urdf_gravity_in_ft(tree, cfg.ft_link, q, g_B, rv)
    sigma = np.asarray(res.truth["noise"])
    off = np.asarray(res.truth["offset"])
    b, groups = cl.urdf_bound(tree, cfg.ft_link, q, g_ft, bodies, sigma, mount=False, offset=off)
    # statics see the total mass only, a child group's mass at its joint lumps into its parent's first moment,
    # and the first moment along parallel joint axes (hip pitch, knee, ankle pitch) is one sum: 6 base directions
    assert b.bound.n_dropped == 6
    R, p = cl.group_poses(tree, cfg.ft_link, groups, q, len(g_ft))
    m, s = cl.group_truth(tree, groups, bodies)
    H = (cl.urdf_jacobian(g_ft, R, p, m, s, mount=False) / sigma[None, :, None]).reshape(-1, len(b.names)) / b.bound.scale
    clean = urdf_load_readings(tree, cfg.ft_link, q, g_B, bodies, off, rv)
    rng = np.random.default_rng(9)
    est = np.array([np.linalg.lstsq(H, ((clean + rng.standard_normal(clean.shape) * sigma) / sigma).ravel(), rcond=1e-7)[0]
                    for _ in range(R_MC)]) / b.bound.scale
    err = b.bound.project(est - b.theta)
    mc_sd = err.std(0, ddof=1)
    ratio = mc_sd / b.bound.sd
    assert np.all(np.abs(ratio - 1) < REL), dict(zip(b.names, ratio.round(3)))
    assert np.all(np.abs(err.mean(0)) < 4 * mc_sd / np.sqrt(R_MC))
    # the total mass is identifiable: its bound from the full covariance
    idx = [b.names.index(f"{g.name}.mass_kg") for g in groups]
    sd_total = b.sd_of({f"{g.name}.mass_kg": 1.0 for g in groups})
    assert abs(err[:, idx].sum(1).std(ddof=1) / sd_total - 1) < REL


def test_urdf_joint_that_never_moves_is_flagged(leg) -> None:
    """Hold the ankle roll at 0: the foot's first moment merges with the ankle's (y and z; x already did)."""
    cfg, res, tree, q, g_B, bodies = leg
    sigma = np.asarray(res.truth["noise"])
    moving, _ = cl.urdf_bound(tree, cfg.ft_link, q, cl.urdf_gravity_in_ft(tree, cfg.ft_link, q, g_B), bodies, sigma)
    q = dict(q, r_ankle_roll=np.zeros_like(q["r_ankle_roll"]))
    held, _ = cl.urdf_bound(tree, cfg.ft_link, q, cl.urdf_gravity_in_ft(tree, cfg.ft_link, q, g_B), bodies, sigma)
    assert held.bound.n_dropped == moving.bound.n_dropped + 2
    before, after = " ".join(moving.unidentified), " ".join(held.unidentified)
    for name in ("r_ankle_roll.moment_y", "r_ankle_roll.moment_z"):
        assert name not in before and name in after


def test_free_load_bound_of_simulations(leg) -> None:
    cfg, res, *_ = leg
    b = cl.free_load_bound(res)
    assert b.bound.n_dropped == 6 and len(b.names) == 6 + 4 * 4 + 3
    total = b.sd_of({f"{g}.mass_kg": 1.0 for g in ("r_hip_pitch", "r_knee", "r_ankle_pitch", "r_ankle_roll")})
    # the total mass from the forces alone: about s_f / (g sqrt(N)) at the least
    n = int(res.held.sum())
    assert res.truth["noise"][0] / (9.81 * np.sqrt(n)) < total < 10 * res.truth["noise"][0] / (9.81 * np.sqrt(n))
    p = simulate_payload(PayloadConfig(seed=2, n_orientations=6))
    bp = cl.free_load_bound(p)
    assert bp.identifiable and bp.names == cl.payload_names(True)
    assert np.isclose(bp.theta[6], p.truth["mass_kg"])


def test_tilt_columns_match_the_forward_model_of_a_tilted_stream() -> None:
    """The world tilt's columns (``tilt_dirs``): the stream reports ``R_t R_WB``, true gravity in B is then
    ``g R_WB'^T u(tilt)`` (``freeload.problem.tilt_gravity``); central differences at tilt 0 of the simulator's
    payload readings equal them, and the bound with the tilt is wider than without (it is a nuisance)."""
    from ftcal_nlp.estimate.freeload.problem import tilt_gravity

    rng = np.random.default_rng(2)
    R_WB = rotvec_to_rotation(rng.normal(size=(30, 3)))
    R0 = rotvec_to_rotation(np.array([0.3, -0.2, 1.0]))
    m, c, off = 1.3, np.array([0.01, -0.02, 0.07]), rng.normal(size=6)
    dg = np.einsum("ji,njt->nit", R0, cl.tilt_directions(R_WB, 9.81))
    J = cl.free_load._with_tilt(cl.payload_jacobian(gravity_in_ft(R_WB, R0, 9.81), m, c, mount=True), dg, m, m * c, True)
    assert J.shape == (30, 6, 15) and cl.payload_names(True, True)[10:12] == cl.TILT_NAMES
    eps = 1e-6
    for k in range(2):
        d = np.zeros(2)
        d[k] = eps

        def w(t):
            g_B = 9.81 * np.einsum("nkj,k->nj", R_WB, tilt_gravity(t))
            return payload_readings(g_B @ R0, m, c, off)

        np.testing.assert_allclose((w(d) - w(-d)) / (2 * eps), J[:, :, 10 + k], atol=1e-6)
    sigma = np.array([0.02] * 3 + [6e-4] * 3)
    b0 = cl.payload_bound(gravity_in_ft(R_WB, R0, 9.81), m, c, sigma)
    b1 = cl.payload_bound(gravity_in_ft(R_WB, R0, 9.81), m, c, sigma, tilt_dirs=dg)
    assert b1.identifiable and b1.names[10:12] == cl.TILT_NAMES
    assert np.all(b1.sd(b0.names) >= b0.bound.sd * (1 - 1e-9)) and np.any(b1.sd(b0.names) > 1.01 * b0.bound.sd)
