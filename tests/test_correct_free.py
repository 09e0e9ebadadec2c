"""``correct`` for a wrist sensor (correct/free.py, loads/calibrated.py, issue 22 item 5): contact wrench = reading - offset - payload
wrench, with se per sample; the Jacobian against finite differences, contacts recovered within their se on
simulated data, the se from the run's full covariance file against a Monte-Carlo of refits, the CLI dispatch and
its errors."""

from __future__ import annotations

import json
import logging
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import correct
from ftcal_nlp.config import load_config
from ftcal_nlp.correct import contact_frame
from ftcal_nlp.loads.base import calibration_variance
from ftcal_nlp.correct.calibrated import (PayloadCalibration, payload_calibrations, payload_from_fit, payload_from_json,
                                        predicted_load)
from ftcal_nlp.core.geometry import rotvec_to_rotation
from ftcal_nlp.run import run


def test_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(0)
    g_B = rng.normal(size=(20, 3))
    g_B *= 9.81 / np.linalg.norm(g_B, axis=1, keepdims=True)
    R = rotvec_to_rotation(np.array([0.2, -0.1, 1.3]))
    p = PayloadCalibration("w", rng.normal(size=6), 1.3, np.array([0.01, -0.02, 0.1]), R, np.eye(13), np.ones(6), 9.81)
    _, J = predicted_load(p, g_B)
    eps = 1e-6
    for k in range(13):
        def model(s):
            x = np.zeros(13)
            x[k] = s
            q = PayloadCalibration("w", p.offset + x[:6], p.mass_kg + x[6], p.h + x[7:10], R @ rotvec_to_rotation(x[10:]),
                                   p.cov, p.sigma, p.g)
            return predicted_load(q, g_B)[0]
        np.testing.assert_allclose((model(eps) - model(-eps)) / (2 * eps), J[:, :, k], atol=1e-6)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wrist")
    (tmp / "c.toml").write_text('[simulate]\nkind = "payload"\ndir = "data"\nseed = 5\nn_orientations = 8\nhold_s = 5.0\n'
                                '[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    res = run(load_config(tmp / "c.toml"))
    return tmp, res


def _with_contact(tmp, seed: int = 1):
    """The recording again, fresh noise-free copy plus new noise, and a push of (3, -2, 5) N at (0, 0, 0.12) m
    (in the true ft frame) on the second quarter of the samples."""
    df = pd.read_csv(tmp / "data" / "wrist.csv")
    n = len(df)
    push = np.zeros((n, 6))
    sl = slice(n // 4, n // 2)
    f = np.array([3.0, -2.0, 5.0])
    push[sl] = np.r_[f, np.cross([0.0, 0.0, 0.12], f)]
    cols = [f"wrist_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]
    df[cols] = df[cols].to_numpy() + push
    return df, push


def test_contact_recovered_within_its_se_in_process(calibrated) -> None:
    tmp, res = calibrated
    fit = res.free_loads.legs["wrist"]
    p = payload_from_fit(fit, res.dataset.robot.transducers["wrist"].rotation, res.dataset.robot.g)
    df, push = _with_contact(tmp)
    out = contact_frame({"wrist": p}, df, "wrist.csv")
    w = out[[f"wrist_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy()
    se = out[[f"wrist_{c}_se" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy()
    z = (w - push) / se
    # the readings carry the simulator's noise: z ~ N(0, 1) per component (sd within 5 %), never beyond ~5
    assert np.allclose(z.std(axis=0), 1.0, atol=0.05) and np.abs(z).max() < 5.5
    assert np.allclose(z.mean(axis=0), 0.0, atol=4 / np.sqrt(len(z)) + 0.05)
    # se: the noise plus the calibration's (full covariance) part, which is small here but positive
    assert np.all(se > np.asarray(fit.sigma)) and p.full_cov


def test_correct_cli_dispatches_to_the_payload_correction(calibrated, tmp_path, capsys) -> None:
    tmp, _ = calibrated
    df, push = _with_contact(tmp)
    rec = tmp_path / "push.csv"
    df.to_csv(rec, index=False)
    out = tmp_path / "contact.csv"
    cal = str(tmp / "out" / "calibration.json")
    assert correct.main([cal, str(rec), "-o", str(out)]) == 0
    got = pd.read_csv(out)
    assert list(got.columns[:7]) == ["t", "wrist_fx", "wrist_fy", "wrist_fz", "wrist_tx", "wrist_ty", "wrist_tz"]
    z = (got["wrist_fz"].to_numpy() - push[:, 2]) / got["wrist_fz_se"].to_numpy()
    assert abs(z.std() - 1.0) < 0.1 and np.abs(z).max() < 5.5
    assert correct.main([cal, str(rec), "-o", str(out)]) == 2                     # exists, no --force
    assert "exists" in capsys.readouterr().err
    assert correct.main([cal, str(rec), "-o", str(out), "--force", "--track-offsets"]) == 2
    assert "--track-offsets applies to hexapod" in capsys.readouterr().err
    df.drop(columns=["qw", "qx", "qy", "qz"]).to_csv(rec, index=False)
    assert correct.main([cal, str(rec), "-o", str(out), "--force"]) == 2
    err = capsys.readouterr().err       # neither orientation columns nor a fixed base's gravity: both ways named
    assert "no orientation columns (qw, qx, qy, qz or gx, gy, gz)" in err and "--gravity-body X Y Z" in err


def test_a_urdf_calibration_without_its_urdf_is_named(tmp_path, capsys) -> None:
    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps({"model": "free_load", "g": 9.81, "legs": {"r_leg": {"load_kind": "urdf_subtree", "offset": [0] * 6}}}))
    (tmp_path / "r.csv").write_text("t,r_leg_fx\n0,1\n")
    assert correct.main([str(cal), str(tmp_path / "r.csv"), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "calibration.json legs.r_leg.load_mass_kg: missing key(s) ['load_mass_kg', 'urdf', 'link', 'urdf_groups'] of a urdf_subtree calibration" in err
    assert not (tmp_path / "o.csv").exists()


# ----------------------------------------------------------------------------- URDF loads (a leg below its sensor)

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


@pytest.fixture(scope="module")
def leg_calibrated(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("leg4")
    (tmp / "c.toml").write_text('[simulate]\nkind = "urdf_leg"\ndir = "data"\nseed = 5\nn_orientations = 8\n'
                                'poses_per_orientation = 3\nhold_s = 4.0\nmove_s = 2.0\n'
                                '[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    return tmp, run(load_config(tmp / "c.toml"))


def _true_urdf_calibration(tmp, res):
    """The calibration the data would give without noise: the simulator's truth in a UrdfLoadCalibration."""
    from ftcal_nlp.correct.calibrated import UrdfLoadCalibration
    from ftcal_nlp.loads import UrdfSubtree

    truth = json.loads((tmp / "data" / "truth.json").read_text())
    load = UrdfSubtree(res.dataset.robot.tree, truth["ft_link"])
    th = []
    for gr in load.groups:
        M, H = 0.0, np.zeros(3)
        for link in gr.links:
            m, c = truth["bodies"][link]["mass_kg"], np.asarray(truth["bodies"][link]["com_m"])
            R, p = load._link_in_group(gr, link)
            M, H = M + m, H + m * (p + R @ c)
        th += [M, *H]
    n = 6 + len(th) + 3
    return UrdfLoadCalibration("r_leg", load, np.asarray(truth["offset"], float), np.array(th),
                               rotvec_to_rotation(np.asarray(truth["mount_rotvec"], float)), np.zeros((n, n)),
                               np.zeros(6), 9.81)


def test_urdf_load_model_is_the_simulators_and_its_jacobian_exact(leg_calibrated) -> None:
    """With the true parameters, the predicted reading at each sample's joint angles and orientation is the
    simulator's noise-free reading (the kinematics agree); the derivative matches central differences."""
    from ftcal_nlp.correct.recording import gravity_of_frame, joint_angles
    from ftcal_nlp.sim.free import UrdfLegConfig, simulate_urdf_leg

    tmp, res = leg_calibrated
    p = _true_urdf_calibration(tmp, res)
    sim = simulate_urdf_leg(UrdfLegConfig(seed=5, n_orientations=8, poses_per_orientation=3, hold_s=4.0, move_s=2.0))
    df = pd.read_csv(tmp / "data" / "leg.csv")
    q = joint_angles(df, p.joints, p.load.tree, "leg.csv")
    model, J = p.predict(gravity_of_frame(df, 9.81, "leg.csv"), q)
    np.testing.assert_allclose(model, sim.clean, atol=1e-9 * np.abs(sim.clean).max())
    sub = np.arange(0, len(df), 97)
    g_B, qs = gravity_of_frame(df, 9.81, "leg.csv")[sub], {j: v[sub] for j, v in q.items()}
    _, J = p.predict(g_B, qs)
    eps, P = 1e-6, J.shape[-1]
    for k in range(P):
        def f(h):
            x = np.zeros(P)
            x[k] = h
            pp = replace(p, offset=p.offset + x[:6], theta=p.theta + x[6:P - 3], E=p.E @ rotvec_to_rotation(x[P - 3:]))
            return pp.predict(g_B, qs)[0]
        np.testing.assert_allclose((f(eps) - f(-eps)) / (2 * eps), J[:, :, k], atol=1e-6)


def test_urdf_contact_recovered_within_its_se(leg_calibrated, tmp_path, capsys, caplog) -> None:
    """A push of (3, -2, 5) N at (0, 0, -0.3) m (the foot, in the true ft frame) on the second quarter of the leg's
    recording, through ``python -m ftcal_nlp.correct``: the contact wrench is the push within its se, the se
    finite although six directions of the links' split are undetermined (the wrench at any joint angles does
    not depend on them), and the calibration's covariance file used."""
    tmp, res = leg_calibrated
    df = pd.read_csv(tmp / "data" / "leg.csv")
    n = len(df)
    push = np.zeros((n, 6))
    f = np.array([3.0, -2.0, 5.0])
    push[n // 4: n // 2] = np.r_[f, np.cross([0.0, 0.0, -0.3], f)]
    cols = [f"r_leg_{c}" for c in WRENCH]
    df[cols] = df[cols].to_numpy() + push
    rec, out = tmp_path / "push.csv", tmp_path / "contact.csv"
    df.to_csv(rec, index=False)
    cal = tmp / "out" / "calibration.json"
    assert len(json.loads(cal.read_text())["legs"]["r_leg"]["undetermined"]) > 0
    with caplog.at_level(logging.INFO, logger="ftcal_nlp.correct.calibrated"):
        assert correct.main([str(cal), str(rec), "-o", str(out)]) == 0
    assert "from the full covariance of calibration_cov.npz" in caplog.text
    got = pd.read_csv(out)
    assert len(got) == n
    w, se = got[cols].to_numpy(), got[[c + "_se" for c in cols]].to_numpy()
    assert np.all(np.isfinite(se))
    z = (w - push) / se
    assert np.allclose(z.std(axis=0), 1.0, atol=0.05) and np.abs(z).max() < 5.5
    assert np.allclose(z.mean(axis=0), 0.0, atol=4 / np.sqrt(n) + 0.05)
    # joint angles in degrees: an error naming the column, nothing written
    df["q_r_knee"] = np.degrees(df["q_r_knee"])
    df.to_csv(rec, index=False)
    assert correct.main([str(cal), str(rec), "-o", str(tmp_path / "deg.csv")]) == 2
    assert "column 'q_r_knee' reaches" in capsys.readouterr().err and not (tmp_path / "deg.csv").exists()


def test_se_from_the_covariance_file_matches_refits(calibrated, caplog) -> None:
    """The calibration part of the se per sample, from calibration.json and its covariance file (what ``correct``
    uses), against the sd of the predicted load wrench over refits to fresh noise on the same motion (Monte-Carlo
    error of an sd from K refits: 1/sqrt(2(K-1)) relative; 4 of those). The diagonal of the stored se (the
    fallback) misses the offset-load correlations: it falls outside that band. With the world tilt (the default):
    gravity from orientations ``R_WB`` goes through each refit's tilt, and the se from the file with them too."""
    from ftcal_nlp.estimate.freeload import fit_free_load
    from ftcal_nlp.sim.free import PayloadConfig, simulate_payload

    tmp, res = calibrated
    cal = tmp / "out" / "calibration.json"
    d = json.loads(cal.read_text())
    assert d["meta"]["covariance_file"] == "calibration_cov.npz" and (tmp / "out" / "calibration_cov.npz").is_file()
    with caplog.at_level(logging.INFO, logger="ftcal_nlp.correct.calibrated"):
        p = payload_calibrations(cal)["wrist"]
    assert p.full_cov and "from the full covariance of calibration_cov.npz" in caplog.text
    p_diag = payload_from_json(d["legs"]["wrist"], "wrist", d["g"])
    rng = np.random.default_rng(11)
    g_B = rng.normal(size=(12, 3))
    g_B *= 9.81 / np.linalg.norm(g_B, axis=1, keepdims=True)
    _, J = predicted_load(p, g_B)
    se_full, se_diag = np.sqrt(calibration_variance(p, J)), np.sqrt(calibration_variance(p_diag, J))
    from ftcal_nlp.estimate.freeload.problem import tilt_gravity

    assert p.tilt is not None and J.shape[-1] == 15
    R_WB = rotvec_to_rotation(rng.normal(size=(12, 3)))
    se_tilt = np.sqrt(calibration_variance(p, p.predict(-9.81 * R_WB[:, 2, :], {}, R_WB)[1]))
    # the same motion and truth as the run's simulation (seed 5): fresh white noise of the simulator's sd per refit
    sim = simulate_payload(PayloadConfig(seed=5, n_orientations=8, hold_s=5.0))
    rec = res.dataset.hanging[0]
    np.testing.assert_allclose(rec.wrench["wrist"], sim.frame[[f"wrist_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]])
    sd = np.asarray(sim.truth["noise"])
    K = 300
    preds, preds_t = [], []
    logging.disable(logging.WARNING)
    try:
        for _ in range(K):
            w = sim.clean + rng.normal(size=sim.clean.shape) * sd
            fit = fit_free_load(replace(res.dataset, recordings=(replace(rec, wrench={"wrist": w}),)), "wrist")
            preds.append(fit.predict(g_B, {}))
            preds_t.append(fit.predict(9.81 * np.einsum("nkj,k->nj", R_WB, tilt_gravity(fit.tilt)), {}))
    finally:
        logging.disable(logging.NOTSET)
    mc = np.std(preds, axis=0, ddof=1)
    band = 4.0 / np.sqrt(2 * (K - 1))
    assert np.abs(mc / se_full - 1).max() < band
    assert np.abs(np.std(preds_t, axis=0, ddof=1) / se_tilt - 1).max() < band
    assert np.abs(mc / se_diag - 1).max() > band          # the test can tell the two apart


def test_fallback_without_the_covariance_file_and_undetermined_parameters(calibrated, tmp_path, caplog) -> None:
    tmp, _ = calibrated
    d = json.loads((tmp / "out" / "calibration.json").read_text())
    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps(d))                                  # names calibration_cov.npz, which is not beside it
    with caplog.at_level(logging.INFO, logger="ftcal_nlp.correct.calibrated"):
        p = payload_calibrations(cal)["wrist"]
    assert not p.full_cov and "is not there" in caplog.text and "from the stored standard errors" in caplog.text
    assert np.allclose(np.sqrt(np.diag(p.cov))[:6], d["legs"]["wrist"]["offset_se"])
    # an undetermined mass: the forces (which carry m g) get se inf, the torques do not
    d["legs"]["wrist"]["load_mass_se_kg"] = float("inf")
    p = payload_from_json(d["legs"]["wrist"], "wrist", 9.81)
    _, J = predicted_load(p, np.array([[0.0, 0.0, -9.81], [0.0, 9.81, 0.0]]))
    var = calibration_variance(p, J)
    assert np.isinf(var[:, :3]).all() and np.all(np.isinf(var[:, 3:]) == (np.abs(J[:, 3:, 7:10]).max(axis=-1) > 0))


def test_a_urdf_calibration_moved_away_from_its_urdf(leg_calibrated, tmp_path, capsys) -> None:
    """calibration.json names its URDF by absolute path: moved elsewhere with the URDF beside it, it is found
    there; without it, one error line naming the key legs.r_leg.urdf and the file."""
    tmp, _ = leg_calibrated
    d = json.loads((tmp / "out" / "calibration.json").read_text())
    d["legs"]["r_leg"]["urdf"] = str(tmp_path / "gone" / "robot.urdf")
    cal = tmp_path / "calibration.json"
    cal.write_text(json.dumps(d))
    rec = tmp / "data" / "leg.csv"
    assert correct.main([str(cal), str(rec), "-o", str(tmp_path / "a.csv")]) == 2
    err = capsys.readouterr().err
    assert "legs.r_leg.urdf: URDF file" in err and "gone/robot.urdf not found" in err and not (tmp_path / "a.csv").exists()
    (tmp_path / "robot.urdf").write_text((tmp / "data" / "robot.urdf").read_text())
    assert correct.main([str(cal), str(rec), "-o", str(tmp_path / "a.csv")]) == 0


def test_urdf_se_at_new_joint_angles_matches_refits() -> None:
    """The URDF load's calibration se (covariance file's block and undetermined directions) at 20 new joint
    angles and orientations against the sd of 60 refits to fresh noise (Monte-Carlo error 1/sqrt(2 * 59) = 9 %
    relative; 4 of those): finite everywhere although six directions are undetermined (they are kinematic
    invariants: no wrench at any angles depends on them), and of the refits' size."""
    from ftcal_nlp.correct.calibrated import UrdfLoadCalibration, param_names
    from ftcal_nlp.core.data import read_dataset
    from ftcal_nlp.estimate.freeload import FreeLoadResults, fit_free_load
    from ftcal_nlp.sim.free import UrdfLegConfig, simulate_urdf_leg, write_free_load
    from ftcal_nlp.estimate.uncertainty import free_load_covariance
    import tempfile
    from pathlib import Path

    sim = simulate_urdf_leg(UrdfLegConfig(seed=5, n_orientations=6, poses_per_orientation=2, hold_s=3.0, move_s=2.0))
    with tempfile.TemporaryDirectory() as d:
        ds = read_dataset(write_free_load(sim, Path(d)))
    logging.disable(logging.WARNING)
    try:
        fit = fit_free_load(ds, "r_leg")
        assert len(fit.undetermined) > 0
        C, und, null = free_load_covariance(FreeLoadResults({"r_leg": fit})).block(param_names("r_leg", fit.load.param_names))
        p = UrdfLoadCalibration("r_leg", fit.load, fit.offset, fit.theta, fit.rotation, C, fit.sigma, 9.81, True, und, null)
        rng = np.random.default_rng(3)
        g_B = rng.normal(size=(20, 3))
        g_B *= 9.81 / np.linalg.norm(g_B, axis=1, keepdims=True)
        tree = fit.load.tree
        q = {j: rng.uniform(0.9 * tree.joint(j).lower, 0.9 * tree.joint(j).upper, 20) for j in tree.movable}
        se = np.sqrt(calibration_variance(p, p.predict(g_B, q)[1]))
        assert np.all(np.isfinite(se))
        rec, sd, K = ds.hanging[0], np.asarray(sim.truth["noise"]), 60
        preds = [fit_free_load(replace(ds, recordings=(replace(rec, wrench={"r_leg": sim.clean + rng.normal(size=sim.clean.shape) * sd}),)),
                               "r_leg").predict(g_B, q) for _ in range(K)]
    finally:
        logging.disable(logging.NOTSET)
    ratio = np.std(preds, axis=0, ddof=1) / se
    assert np.abs(ratio - 1).max() < 4.0 / np.sqrt(2 * (K - 1))


def test_tilt_jacobian_matches_finite_differences() -> None:
    """With a world tilt (``gravity_tilt_rad``) gravity comes from the orientations, ``g R_WB^T u(tilt)``; the 15
    columns ``(w_o, m, h, tilt, delta)`` against central differences; without the orientations (``gx..gz``) the
    tilt's columns are zero."""
    rng = np.random.default_rng(4)
    R_WB = rotvec_to_rotation(rng.normal(size=(20, 3)))
    g_B = -9.81 * R_WB[:, 2, :]
    R = rotvec_to_rotation(np.array([0.2, -0.1, 1.3]))
    tilt = np.array([0.012, -0.02])
    p = PayloadCalibration("w", rng.normal(size=6), 1.3, np.array([0.01, -0.02, 0.1]), R, np.eye(15), np.ones(6), 9.81,
                           tilt=tilt)
    _, J = p.predict(g_B, {}, R_WB)
    assert J.shape == (20, 6, 15)
    eps = 1e-6
    for k in range(15):
        def model(s):
            x = np.zeros(15)
            x[k] = s
            q = replace(p, offset=p.offset + x[:6], mass_kg=p.mass_kg + x[6], h=p.h + x[7:10], tilt=tilt + x[10:12],
                        R_B_ft=R @ rotvec_to_rotation(x[12:]))
            return q.predict(g_B, {}, R_WB)[0]
        np.testing.assert_allclose((model(eps) - model(-eps)) / (2 * eps), J[:, :, k], atol=1e-6)
    _, J0 = p.predict(g_B, {})
    assert J0.shape == (20, 6, 15) and not J0[:, :, 10:12].any()
