"""The standing noise floor as a variance-component model (issue 13, item 2; ``diagnose/floor.py``).

Numeric twins of the tilt sensitivity ``G_p`` and the physical Jacobian; the pooled readings'
covariance and the REML tilt variance on synthetic residuals with a known truth; then, on
simulated sessions whose per-pose motion-capture error is set (0, 0.05, 0.2, 0.4 deg), floors
that were not estimated from what they are compared with: the fitted ``s_theta`` recovers the
configured value, the floor matches the held-out RMS of the diagnosis' own k-fold refit within
its sampling spread, and it does not rise with an effect (clean twin, same seed). Last, the
sample written by someone else (motion capture 0.05 deg per pose in its simulator)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import require_sample

from ftcal_nlp import calibrate
from ftcal_nlp.core.balance import to_world
from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.diagnose.floor import (
    calibrated_residual_B,
    fit_noise_floor,
    physical_jacobian,
    readings_noise,
    structure_basis,
    tilt_sensitivity,
)
from ftcal_nlp.diagnose.standing_fit import AugmentedProblem
from ftcal_nlp.diagnose.views import standing_view
from ftcal_nlp.core.geometry import rotvec_to_rotation
from ftcal_nlp.models import ModelContext, resolve
from ftcal_nlp.estimate.selection import fold_indices
from ftcal_nlp.core.settings import CalibrationSettings, DiagnoseSettings, StandingSettings
from ftcal_nlp.sim import SimConfig, simulate
from ftcal_nlp.estimate.standing import Poses, extract_poses

SEED = 5
BASE = {"seed": SEED, "n_poses": 150, "hanging_cycles": 2.0, "walk_cycles": 0.5}
FOLDS = 5
SETTINGS = CalibrationSettings(diagnose=DiagnoseSettings(enabled=False),
                               standing=StandingSettings(model="full", compare_baseline=False))

_cache: dict = {}


def _run(mocap_deg: float, effect: str | None = None):
    key = (mocap_deg, effect)
    if key not in _cache:
        spec = {**BASE, "mocap_pose_error_deg": mocap_deg, "effects": [{"name": effect, "seed": 1}] if effect else []}
        sim = simulate(SimConfig.from_dict(spec))
        _cache[key] = (sim, calibrate(sim.dataset, SETTINGS))
    return _cache[key]


def _view(run):
    ds, robot = run.dataset, run.dataset.robot
    legs = tuple(robot.legs)
    prior = run.hanging.to_calibration(robot)
    t_ref = float(np.mean(np.concatenate([r.t for r in ds.hanging])))
    spec = resolve(run.calibration.model).build(ModelContext(legs, robot.nominal_rotations(), robot.nominal_positions(), prior))
    return standing_view(ds, run.poses, run.calibration, prior, robot, t_ref, spec.n_dof, FOLDS, seed=0), prior


def _heldout_rms(run, view, prior) -> np.ndarray:
    """Held-out RMS (6,) of the diagnosis' k-fold K-norm refit (as ``attribute.py`` scores the model alone)."""
    prob = AugmentedProblem(run.calibration.model, prior, run.dataset.robot, run.calibration.meta.get("balance", "exact"))
    Phi = prob.design(view.data)
    P = view.P
    x = prob.fit(Phi, np.full(P, 1.0 / P), run.standing.x)
    held = np.zeros((P, 6))
    for test in fold_indices(P, FOLDS, 0):
        w = np.full(P, 1.0 / (P - len(test)))
        w[test] = 0.0
        held[test] = prob.residuals(prob.fit(Phi, w, x), Phi[test])
    return np.sqrt((to_world(held, view.R_WB) ** 2).mean(axis=0))


def _z_s2(parts: dict, configured_deg: float) -> float:
    """``(s^2 - s_true^2) / se(s^2)``: the fitted tilt variance against the configured one."""
    m = parts["mocap"]
    s, se = np.radians(m["s_theta_deg"]), np.radians(m["se_deg"])
    se_s2 = 2.0 * s * se if m["identified"] else se**2
    return float((s**2 - np.radians(configured_deg) ** 2) / se_s2)


# ----------------------------------------------------------------------------- numeric twins


@pytest.fixture(scope="module")
def small():
    sim = simulate(SimConfig(seed=3, n_poses=12, hanging_cycles=0.5, walk_cycles=0.0))
    ds = sim.dataset
    poses = Poses.concat([extract_poses(r, ds.robot) for r in ds.standing])
    return sim, poses


def _perturbed(cal: Calibration, leg: str, **kw) -> Calibration:
    return replace(cal, legs={**cal.legs, leg: replace(cal.legs[leg], **kw)})


@pytest.mark.parametrize("balance", ["exact", "report"])
def test_tilt_sensitivity_matches_a_rotated_orientation(small, balance):
    """``G_p`` against the residual at a measured orientation rotated by ``exp(-[eps])`` about W x, y."""
    sim, poses = small
    cal, legs = sim.truth, sim.dataset.robot.legs
    G = tilt_sensitivity(poses.w_m, poses.phi, poses.R_WB, cal, legs, balance)
    r0 = to_world(calibrated_residual_B(poses.w_m, poses.phi, poses.R_WB, cal, legs, balance), poses.R_WB)
    h = 1e-6
    for a in range(2):
        eps = np.zeros(3)
        eps[a] = h
        R = rotvec_to_rotation(-eps)[None] @ poses.R_WB   # measured = exp(-[eps]) true
        # (turned into W with the unperturbed orientation: rotating the residual itself is a product of
        # the tilt error and the residual, second order, and left out of G)
        r1 = to_world(calibrated_residual_B(poses.w_m, poses.phi, R, cal, legs, balance), poses.R_WB)
        np.testing.assert_allclose((r1 - r0) / h, G[:, :, a], atol=1e-4 * np.abs(G).max())
    if balance == "exact":  # the weight rotating: horizontal force only, M_b g per rad
        Mb_g = cal.body_weight_N
        GG = np.einsum("pia,pja->pij", G[:, :2], G[:, :2])
        np.testing.assert_allclose(GG, Mb_g**2 * np.broadcast_to(np.eye(2), (poses.n, 2, 2)), atol=1e-6 * Mb_g**2)
        np.testing.assert_allclose(G[:, 2:, :], 0.0, atol=1e-9)


def test_physical_jacobian_matches_finite_differences(small):
    sim, poses = small
    cal, legs = sim.truth, sim.dataset.robot.legs
    J = physical_jacobian(poses.w_m, poses.R_WB, cal, legs)
    r = lambda c: to_world(calibrated_residual_B(poses.w_m, poses.phi, poses.R_WB, c, legs), poses.R_WB)
    r0 = r(cal)
    h = 1e-6
    for k in (0, 4):
        leg, l, c = legs[k], cal.legs[legs[k]], 13 * k
        for i in range(3):
            d = np.eye(3)[i] * h
            fd = (r(_perturbed(cal, leg, rotation_to_body=rotvec_to_rotation(d) @ l.rotation_to_body)) - r0) / h
            np.testing.assert_allclose(fd, J[:, :, c + i], atol=1e-4)
            fd = (r(_perturbed(cal, leg, position_from_com_m=l.position_from_com_m + d)) - r0) / h
            np.testing.assert_allclose(fd, J[:, :, c + 3 + i], atol=1e-4)
        for i in range(6):
            fd = (r(_perturbed(cal, leg, offset=l.offset + np.eye(6)[i] * h)) - r0) / h
            np.testing.assert_allclose(fd, J[:, :, c + 6 + i], atol=1e-5)
        fd = (r(_perturbed(cal, leg, leg_weight_N=l.leg_weight_N + h)) - r0) / h
        np.testing.assert_allclose(fd, J[:, :, c + 12], atol=1e-5)


# ----------------------------------------------------------------------------- synthetic truth


def test_readings_noise_pools_half_run_differences():
    rng = np.random.default_rng(0)
    P = 400
    A = rng.normal(size=(6, 6)) * np.r_[0.05, 0.05, 0.05, 0.003, 0.003, 0.003][:, None]
    S0 = A @ A.T
    n = rng.integers(200, 400, P)
    # d = m_1 - m_2 with var(d) = 4 var(median of n) = 4 S0 / n
    dd = (rng.normal(size=(P, 6)) @ np.linalg.cholesky(S0).T) * 2.0 / np.sqrt(n)[:, None]
    dd[:7] = np.nan  # runs not found
    R = rotvec_to_rotation(rng.normal(0.0, 0.3, (P, 3)))
    rn = readings_noise(dd, n, R)
    assert rn.measured and rn.n_used == P - 7
    np.testing.assert_allclose(np.diag(rn.S0_B), np.diag(S0), rtol=4 * np.sqrt(2 / rn.n_used))
    p = 10
    T = np.zeros((6, 6))
    T[:3, :3] = T[3:, 3:] = R[p]
    np.testing.assert_allclose(rn.sigma_W[p], T @ rn.S0_B @ T.T / n[p], rtol=1e-12)
    assert not readings_noise(np.full((P, 6), np.nan), n, R).measured


@pytest.mark.parametrize("s_deg", [0.0, 0.1])
def test_reml_recovers_a_known_tilt_variance(s_deg):
    """r_p = J_p theta + X_p beta + e_p with Cov(e_p) = S + s^2 G G^T: s recovered within 3 se, the
    floor equals the mean held-out mean square of the K-norm refit (Monte Carlo of the same model)."""
    rng = np.random.default_rng(7)
    P, d = 200, 12
    S = np.diag(np.r_[0.01, 0.01, 0.01, 0.002, 0.002, 0.002] ** 2)
    G = np.zeros((P, 6, 2))
    G[:, 0, 0] = G[:, 1, 1] = 45.0
    J = rng.normal(size=(P, 6, d)) * np.r_[1.0, 1.0, 1.0, 0.1, 0.1, 0.1][None, :, None]
    t = np.sort(rng.uniform(0, 0.5, P))
    X, names = structure_basis(t, rng.uniform(-0.6, 0.6, (P, 6)), rng.normal(0, 5, (P, 6, 3)), rng.normal(0, 2, (P, 6)))
    s = np.radians(s_deg)
    e = rng.normal(size=(P, 6)) @ np.sqrt(S) + s * np.einsum("pia,pa->pi", G, rng.normal(size=(P, 2)))
    r = e + np.einsum("pid,d->pi", J, rng.normal(size=d)) + rng.normal(size=6)   # calibration error and a bias
    # half-run differences of the readings' noise (n = 100 samples per pose)
    n = np.full(P, 100)
    dd = rng.normal(size=(P, 6)) @ np.sqrt(S) * 2.0
    rn = readings_noise(dd, n, np.broadcast_to(np.eye(3), (P, 3, 3)))   # sigma_W ~ S
    nf = fit_noise_floor(r, rn, G, X, J=J, folds=5, names=names, seed=0)
    se_s2 = nf.s2_se
    assert abs(nf.s2 - s**2) < 3 * se_s2, (nf.s2, s**2, se_s2)
    assert nf.identified or s_deg == 0
    assert np.degrees(nf.s_theta_upper_rad) < s_deg + 0.02
    assert np.degrees(nf.s_theta_upper_rad) >= s_deg - 3 * np.degrees(nf.s_theta_se_rad)
    assert not nf.gap, nf.check
    np.testing.assert_allclose(nf.readings, np.sqrt(np.diag(S)), rtol=0.25)
    # the floor is the held-out mean square of the K-norm refit of J: Monte Carlo of the true model
    K = np.r_[1.0, 1.0, 1.0, 10.0, 10.0, 10.0]
    ms = np.zeros(6)
    folds = fold_indices(P, 5, 1)
    draws = 60
    for _ in range(draws):
        e = rng.normal(size=(P, 6)) @ np.sqrt(S) + s * np.einsum("pia,pa->pi", G, rng.normal(size=(P, 2)))
        for test in folds:
            tr = np.setdiff1d(np.arange(P), test)
            Jw, ew = (J[tr] * np.sqrt(K)[None, :, None]).reshape(-1, d), (e[tr] * np.sqrt(K)).ravel()
            th = np.linalg.lstsq(Jw, ew, rcond=None)[0]
            ms += ((e[test] - J[test] @ th) ** 2).sum(axis=0)
    ms /= draws * P
    # (within the floor's own uncertainty: 3 se of s^2 and a fifth of the readings' variance)
    tol = 3.0 * nf.s2_se * np.einsum("pia,pia->i", G, G) / P + 0.2 * ms
    assert np.all(np.abs(nf.floor**2 - ms) <= tol), (nf.floor, np.sqrt(ms))
    # a drift in time (10 x the readings' noise) is structure: a gap, and not taken for tilt noise
    drift = np.outer(X[:, 1] + 0.5 * X[:, 2], 10.0 * np.sqrt(np.diag(S)))
    nf2 = fit_noise_floor(r + drift, rn, G, X, J=J, folds=5, names=names, seed=0)
    assert nf2.gap and nf2.check["structure_cv_ratio"] < 0.5 and "follows time" in nf2.statement
    assert abs(nf2.s2 - nf.s2) < 0.5 * nf.s2_se
    np.testing.assert_allclose(nf2.floor, nf.floor, rtol=1e-2)
    assert nf.statement.startswith("per-pose scatter is measurement noise: motion capture ")
    if s_deg > 0:
        assert f"motion capture ~{np.degrees(nf.s_theta_rad):.2g} deg per pose (+- " in nf.statement


# ----------------------------------------------------------------------------- simulated sessions


@pytest.mark.parametrize("mocap_deg", [0.0, 0.05, 0.2, 0.4])
def test_floor_recovers_mocap_error_and_matches_heldout(mocap_deg):
    sim, run = _run(mocap_deg)
    view, prior = _view(run)
    parts = view.floor_parts["noise_model"]
    z = _z_s2(parts, mocap_deg)
    assert abs(z) <= 3.0, (parts["mocap"], mocap_deg, z)
    assert view.floor_parts["mocap_tilt_deg"] == pytest.approx(parts["mocap"]["s_theta_deg"])
    held = _heldout_rms(run, view, prior)
    ratio = view.floor / held
    spread = np.asarray(parts["spread"])
    # within ~[0.8, 1.25], or within 3 of its own sampling spread where the refit's parameter error
    # dominates (torques under a large tilt error)
    tol = np.maximum(np.log(1.25), 3.0 * spread)
    assert np.all(np.abs(np.log(ratio)) <= tol), (ratio, spread)
    assert not parts["gap"], parts["check"]
    assert parts["statement"].startswith("per-pose scatter is measurement noise")
    for k in ("readings", "mocap", "calibration", "fit", "cv_inflation", "within", "statement"):
        assert k in view.floor_parts


@pytest.mark.parametrize("effect", ["offset_drift", "tether_force"])
def test_floor_does_not_rise_with_an_effect(effect):
    clean_view, _ = _view(_run(0.05)[1])
    view, _ = _view(_run(0.05, effect)[1])
    ratio = view.floor / clean_view.floor
    assert np.all(ratio < 1.3), ratio
    parts = view.floor_parts["noise_model"]
    assert parts["gap"] and "more than measurement noise" in parts["statement"], parts["check"]


def test_sample_mocap_error_and_floor():
    root = require_sample()
    ds = read_dataset(root / "dataset.toml")
    run = calibrate(ds, SETTINGS)
    view, prior = _view(run)
    parts = view.floor_parts["noise_model"]
    assert abs(_z_s2(parts, 0.05)) <= 3.0, parts["mocap"]
    assert not parts["gap"], parts["check"]
    held = _heldout_rms(run, view, prior)
    spread = np.asarray(parts["spread"])
    assert np.all(np.abs(np.log(view.floor / held)) <= np.maximum(np.log(1.3), 3.0 * spread)), (view.floor / held, spread)
