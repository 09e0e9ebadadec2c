"""The peers' baselines (kth ft_calib, Robotlib.jl calibForce-style) on simulated payload data.

Without a mounting rotation both recover the truth within a few standard errors
(the noise level); with a ~1 deg mounting rotation ft_calib, which takes the
nominal ft orientation as true, is biased far beyond its noise-only standard
errors and leaves a residual several times the noise, while the calibForce-style
fit recovers the rotation.
"""

from __future__ import annotations

import numpy as np
import pytest

from ftcal_nlp.core.geometry import quat_to_rotation, rotvec_to_rotation
from ftcal_nlp.bench.peers import calib_force, ft_calib
from ftcal_nlp.sim.free import PayloadConfig, gravity_in_ft, payload_readings, simulate_payload
from ftcal_nlp.sim.free.simulate import rpy_to_rotation

ONE_DEG = np.radians(1.0) * np.array([1.0, -2.0, 1.5]) / np.linalg.norm([1.0, -2.0, 1.5])


def _held_data(rotvec):
    cfg = PayloadConfig(seed=21, mount_rotvec=tuple(rotvec))
    res = simulate_payload(cfg)
    df = res.frame[res.held]
    g_nom = gravity_in_ft(quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy()), rpy_to_rotation(cfg.rotation_rpy), cfg.g)
    w = df[[f"wrist_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy()
    return cfg, res.truth, g_nom, w


def _errors(fit, cfg, truth):
    return (fit.mass_kg - cfg.mass_kg, fit.com_m - np.asarray(cfg.com_m), fit.offset - np.asarray(truth["offset"]))


@pytest.fixture(scope="module")
def no_rotation():
    return _held_data((0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def one_degree():
    return _held_data(tuple(ONE_DEG))


def test_exact_on_noise_free_readings() -> None:
    rng = np.random.default_rng(0)
    g = rng.normal(size=(40, 3))
    g *= 9.81 / np.linalg.norm(g, axis=1, keepdims=True)
    m, c, off = 1.2, np.array([0.01, -0.02, 0.07]), rng.normal(size=6)
    fit = ft_calib(g, payload_readings(g, m, c, off))
    assert abs(fit.mass_kg - m) < 1e-10 and np.allclose(fit.com_m, c, atol=1e-10) and np.allclose(fit.offset, off, atol=1e-9)
    E = rotvec_to_rotation(ONE_DEG * 3)
    fit = calib_force(g, payload_readings(g @ E, m, c, off))                   # true g_ft = E^T g_nom
    assert np.allclose(fit.rotation, E, atol=1e-10) and abs(fit.mass_kg - m) < 1e-10
    assert np.allclose(fit.com_m, c, atol=1e-10) and np.allclose(fit.offset, off, atol=1e-9)


@pytest.mark.parametrize("method", [ft_calib, calib_force])
def test_recover_truth_without_mounting_rotation(no_rotation, method) -> None:
    cfg, truth, g_nom, w = no_rotation
    fit = method(g_nom, w)
    dm, dc, doff = _errors(fit, cfg, truth)
    assert abs(dm) < 4 * fit.mass_se_kg and np.all(np.abs(dc) < 4 * fit.com_se_m) and np.all(np.abs(doff) < 4 * fit.offset_se)
    assert np.all(np.abs(fit.rms / np.asarray(truth["noise"]) - 1) < 0.05)    # the residual is the noise
    assert np.linalg.norm(fit.mount_rotvec) < 1e-4


def test_mounting_rotation_biases_ft_calib_not_calib_force(no_rotation, one_degree) -> None:
    cfg, truth, g_nom, w = one_degree
    ref = ft_calib(*no_rotation[2:])                                           # noise-only standard errors
    plain, rot = ft_calib(g_nom, w), calib_force(g_nom, w)
    _, dc, doff = _errors(plain, cfg, truth)
    assert np.linalg.norm(dc) > 50 * np.linalg.norm(ref.com_se_m)             # CoM biased far beyond the noise
    assert np.max(np.abs(doff[:3]) / ref.offset_se[:3]) > 20
    assert np.max(plain.rms[:3] / np.asarray(truth["noise"][:3])) > 3         # and the residual shows it
    dm, dc, doff = _errors(rot, cfg, truth)
    assert abs(dm) < 4 * rot.mass_se_kg and np.all(np.abs(dc) < 4 * rot.com_se_m) and np.all(np.abs(doff) < 4 * rot.offset_se)
    assert np.linalg.norm(rot.mount_rotvec - ONE_DEG) < 1e-4
