"""``calibration_with_effect.json`` of free loads and what ``correct`` applies (issue 23 item 3;
effects/correction.py, diagnose/free_effect_file.py): a payload and a URDF leg with a clock offset and creep injected are run with the
diagnosis; a fresh recording of the same rig (another seed: other orientations, other noise) corrected with that file
lands on the simulator's truth (no contact: zero) within the noise, and clearly closer than with calibration.json
(paired block-wise z); the se carry the noise; a saved and reloaded file corrects bit-identically; a face that needs
the session's reference keeps the calibration's; bad blocks and missing columns give clear errors."""

from __future__ import annotations

import json
import logging
import shutil
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.correct import contact_frame, contact_wrench, main as correct_main
from ftcal_nlp.effects.correction import FreeEffects, Member
from ftcal_nlp.effects.faces import legendre_time
from ftcal_nlp.core.errors import DataFormatError
from ftcal_nlp.correct.calibrated import PayloadCalibration, payload_calibrations
from ftcal_nlp.run import main as run_main
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_payload, simulate_urdf_leg, write_free_load

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
EFFECTS = ({"name": "clock_offset", "scale": 0.02}, {"name": "creep"})
RIG = dict(offset=(1.0, -2.0, 0.5, 0.05, -0.03, 0.02), mount_rotvec=(0.01, -0.02, 0.015), effects=EFFECTS)


def _payload(seed: int):
    return simulate_payload(PayloadConfig(seed=seed, n_orientations=12, hold_s=6.0, move_s=3.0, **RIG))


def _urdf(seed: int):
    # the true bodies drawn from the seed: none drawn (the URDF's), so that another seed is the same rig
    return simulate_urdf_leg(UrdfLegConfig(seed=seed, n_orientations=6, poses_per_orientation=3, hold_s=4.0, move_s=2.0,
                                           mass_spread=0.0, com_spread_mm=0.0, **RIG))


def _run(tmp, sim, fresh):
    """Calibrate ``sim`` with the diagnosis (the run's command line), write ``fresh``'s recording and correct it with
    both files: ``(folder, {file: corrected frame})``."""
    man = write_free_load(sim, tmp / "data")
    (tmp / "run.toml").write_text(f'[data]\nmanifest = "{man}"\n[output]\ndir = "{tmp / "out"}"\n[diagnose]\nenabled = true\n')
    assert run_main([str(tmp / "run.toml")]) == 0
    fresh.frame.to_csv(tmp / "fresh.csv", index=False)
    out = {}
    for name in ("calibration.json", "calibration_with_effect.json"):
        assert correct_main([str(tmp / "out" / name), str(tmp / "fresh.csv"), "-o", str(tmp / f"c_{name}.csv")]) == 0
        out[name] = pd.read_csv(tmp / f"c_{name}.csv")
    return tmp, out


@pytest.fixture(scope="module")
def payload(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("payload_fx"), _payload(11), _payload(12))


@pytest.fixture(scope="module")
def urdf(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("urdf_fx"), _urdf(21), _urdf(22))


def _paired_z(e0: np.ndarray, e1: np.ndarray, noise: np.ndarray, size: int = 100) -> float:
    """Paired block-wise z of ``log(SSE_0 / SSE_1)`` over blocks of ``size`` consecutive samples (channels in units
    of the noise sd)."""
    nb = len(e0) // size
    s0 = ((e0[: nb * size] / noise) ** 2).reshape(nb, size, 6).sum(axis=(1, 2))
    s1 = ((e1[: nb * size] / noise) ** 2).reshape(nb, size, 6).sum(axis=(1, 2))
    d = np.log(s0 / s1)
    return float(d.mean() / (d.std(ddof=1) / np.sqrt(nb)))


def _check(folder, out, leg: str, noise: np.ndarray):
    cols = [f"{leg}_{c}" for c in WRENCH]
    e_fx = out["calibration_with_effect.json"][cols].to_numpy()
    e_0 = out["calibration.json"][cols].to_numpy()
    se = out["calibration_with_effect.json"][[f"{c}_se" for c in cols]].to_numpy()
    rms_fx, rms_0 = np.sqrt((e_fx**2).mean(0)) / noise, np.sqrt((e_0**2).mean(0)) / noise
    # truth: the load hangs free, the contact wrench is zero; with the effects corrected what is left is the noise
    assert np.all(rms_fx < 1.5), rms_fx
    assert np.max(rms_0) > 3.0, rms_0                                       # calibration.json alone: far above it
    assert _paired_z(e_0, e_fx, noise) >= 4.0
    z_sd = (e_fx / se).std(0)
    assert np.all((z_sd > 0.8) & (z_sd < 1.3)), z_sd                        # the se carry the noise (within 30 %)
    meta = json.loads((folder / "out" / "calibration_with_effect.json").read_text())["meta"]
    eff = meta["effect"]
    assert eff["kind"] == "free_load" and eff["name"] == "clock_offset+creep"
    assert [m["name"] for m in eff["legs"][leg]["members"]] == ["clock_offset", "creep"]
    assert meta["covariance_file"] == "calibration_with_effect_cov.npz"
    assert (folder / "out" / meta["covariance_file"]).is_file()
    return rms_fx, rms_0


def _in_sample(folder, leg: str, recording: str) -> np.ndarray:
    """The calibration's own recording corrected with calibration_with_effect.json: its RMS per channel over the
    diagnosis' held-out RMS after the chain (what the joint refit leaves; in-sample vs held-out agree within 10 %
    when the correction rebuilds the faces the diagnosis fitted)."""
    out = folder / f"in_sample_{leg}.csv"
    assert correct_main([str(folder / "out" / "calibration_with_effect.json"), str(folder / "data" / recording), "-o",
                         str(out), "--force"]) == 0
    e = pd.read_csv(out)[[f"{leg}_{c}" for c in WRENCH]].to_numpy()
    after = json.loads((folder / "out" / "diagnosis.json").read_text())["free_loads"][leg]["heldout_rms_after"]
    return np.sqrt((e**2).mean(0)) / np.asarray(after)


def test_payload_fresh_recording_corrected_to_the_noise(payload):
    folder, out = payload
    _check(folder, out, "wrist", np.array([0.02] * 3 + [0.0006] * 3))
    ratio = _in_sample(folder, "wrist", "wrist.csv")
    assert np.all((ratio > 0.9) & (ratio < 1.1)), ratio
    # the reference clock of the session: the span of the calibration's recording
    t = pd.read_csv(folder / "data" / "wrist.csv")["t"].to_numpy()
    ref = json.loads((folder / "out" / "calibration_with_effect.json").read_text())["meta"]["effect"]["legs"]["wrist"]["reference"]
    assert ref["t_span_s"] == [float(t.min()), float(t.max())]


def test_urdf_leg_fresh_recording_corrected_to_the_noise(urdf):
    folder, out = urdf
    _check(folder, out, "r_leg", np.array([0.05] * 3 + [0.003] * 3))
    ratio = _in_sample(folder, "r_leg", "leg.csv")
    assert np.all((ratio > 0.9) & (ratio < 1.1)), ratio


@pytest.mark.parametrize("kind,effects,name", [
    ("payload", ({"name": "offset_drift_ramp", "scale": 20.0},), "offset_drift"),   # a time polynomial: the session's span
    ("payload", ({"name": "temperature"},), "temperature"),                          # the lagged temperature's session mean
    ("payload", ({"name": "inertial_load"},), "inertial_load"),                      # the lever from robot.toml's position_m
    ("urdf", ({"name": "joint_limit_contact"},), "joint_limit_contact"),             # the joint and its URDF limits
    ("payload", ({"name": "gain_crosstalk"},), "gain_crosstalk"),                    # the sensor matrix on the load's wrench
])
def test_other_effects_correct_a_fresh_recording(kind, effects, name, tmp_path):
    rig = {**RIG, "effects": effects}
    if kind == "payload":
        sim = lambda seed: simulate_payload(PayloadConfig(seed=seed, n_orientations=12, hold_s=6.0, move_s=3.0, **rig))  # noqa: E731
        leg, recording, noise = "wrist", "wrist.csv", np.array([0.02] * 3 + [0.0006] * 3)
    else:
        sim = lambda seed: simulate_urdf_leg(UrdfLegConfig(seed=seed, n_orientations=6, poses_per_orientation=3, hold_s=4.0,  # noqa: E731
                                                           move_s=2.0, mass_spread=0.0, com_spread_mm=0.0, **rig))
        leg, recording, noise = "r_leg", "leg.csv", np.array([0.05] * 3 + [0.003] * 3)
    folder, out = _run(tmp_path, sim(31), sim(32))
    cols = [f"{leg}_{c}" for c in WRENCH]
    e_fx, e_0 = out["calibration_with_effect.json"][cols].to_numpy(), out["calibration.json"][cols].to_numpy()
    eff = json.loads((folder / "out" / "calibration_with_effect.json").read_text())["meta"]["effect"]
    assert eff["name"] == name
    assert np.all(np.sqrt((e_fx**2).mean(0)) / noise < 1.5) and _paired_z(e_0, e_fx, noise) >= 4.0
    ratio = _in_sample(folder, leg, recording)
    assert np.all((ratio > 0.9) & (ratio < 1.1)), ratio


def test_saved_and_reloaded_file_corrects_bit_identically(payload, tmp_path):
    folder, out = payload
    cal = Calibration.load(folder / "out" / "calibration_with_effect.json")
    cal.save(tmp_path / "calibration_with_effect.json")
    shutil.copy(folder / "out" / "calibration_with_effect_cov.npz", tmp_path)
    assert correct_main([str(tmp_path / "calibration_with_effect.json"), str(folder / "fresh.csv"), "-o", str(tmp_path / "c.csv")]) == 0
    again = pd.read_csv(tmp_path / "c.csv")
    ref = out["calibration_with_effect.json"]
    assert list(again.columns) == list(ref.columns)
    assert np.array_equal(again.to_numpy(), ref.to_numpy())


def _edited(folder, tmp_path, edit):
    d = json.loads((folder / "out" / "calibration_with_effect.json").read_text())
    edit(d)
    (tmp_path / "calibration_with_effect.json").write_text(json.dumps(d))
    shutil.copy(folder / "out" / "calibration_with_effect_cov.npz", tmp_path)
    return tmp_path / "calibration_with_effect.json"


def _member(d, i=0):
    return d["meta"]["effect"]["legs"]["wrist"]["members"][i]


@pytest.mark.parametrize("edit,key", [
    (lambda d: _member(d).update(name="no_such_effect"), "meta.effect.legs.wrist.members[0].name"),
    (lambda d: _member(d).update(name="casing_load"), "meta.effect.legs.wrist.members[0].name"),   # no free face
    (lambda d: _member(d, 1).update(beta=_member(d, 1)["beta"][:-1]), "meta.effect.legs.wrist.members[1].beta"),
    (lambda d: _member(d, 1).update(beta=["a"] * len(_member(d, 1)["labels"])), "meta.effect.legs.wrist.members[1].beta"),
    (lambda d: _member(d).update(shape="all"), "meta.effect.legs.wrist.members[0].shape"),
    (lambda d: d["meta"]["effect"]["legs"]["wrist"].update(members=[]), "meta.effect.legs.wrist.members"),
    (lambda d: d["meta"]["effect"]["legs"].update(elbow=d["meta"]["effect"]["legs"]["wrist"]), "meta.effect.legs"),
])
def test_bad_effect_blocks_are_named(payload, tmp_path, edit, key):
    folder, _ = payload
    path = _edited(folder, tmp_path, edit)
    with pytest.raises(DataFormatError) as exc:
        payload_calibrations(path)
    assert key in str(exc.value) and str(path) in str(exc.value)


def test_an_effect_without_its_column_is_an_error(payload, tmp_path):
    folder, _ = payload
    temp = {"name": "temperature", "shape": {"degree": 1, "lag_s": 0.0},
            "labels": [f"{c}.dT [{'N' if i < 3 else 'N*m'}/degC]" for i, c in enumerate(WRENCH)], "beta": [0.01] * 6}
    path = _edited(folder, tmp_path, lambda d: d["meta"]["effect"]["legs"]["wrist"]["members"].append(temp))
    cal = payload_calibrations(path)
    rec = pd.read_csv(folder / "fresh.csv")
    with pytest.raises(DataFormatError) as exc:
        contact_frame(cal, rec, "fresh.csv")
    assert "wrist_temp_C" in str(exc.value) and "temperature" in str(exc.value)
    # with the column it applies: (T - the calibration's mean) x beta more is taken off every force and torque
    rec["temp_C"] = 30.0 + np.linspace(0.0, 2.0, len(rec))
    path = _edited(folder, tmp_path, lambda d: (d["meta"]["effect"]["legs"]["wrist"]["members"].append(temp),
                                                 d["meta"]["effect"]["legs"]["wrist"]["reference"].update(temperature_mean_C=29.0)))
    with_t = contact_frame(payload_calibrations(path), rec, "fresh.csv")
    base = contact_frame(payload_calibrations(folder / "out" / "calibration_with_effect.json"), rec, "fresh.csv")
    dT = rec["temp_C"].to_numpy() - 29.0
    for c in WRENCH:
        np.testing.assert_allclose(base[f"wrist_{c}"] - with_t[f"wrist_{c}"], 0.01 * dT, rtol=0, atol=1e-12)
    # a recording held at one temperature: still (T - the calibration's mean) x beta, an offset
    rec["temp_C"] = 31.5
    with_t = contact_frame(payload_calibrations(path), rec, "fresh.csv")
    for c in WRENCH:
        np.testing.assert_allclose(base[f"wrist_{c}"] - with_t[f"wrist_{c}"], 0.01 * 2.5, rtol=0, atol=1e-12)


def test_joint_limit_contact_needs_its_joint_column(urdf, tmp_path):
    folder, _ = urdf
    d = json.loads((folder / "out" / "calibration_with_effect.json").read_text())
    lim = {"name": "joint_limit_contact", "shape": {"joint": "r_knee", "side": 1, "onset": 0.7},
           "labels": [f"{c}.at_limit [{'N' if i < 3 else 'N*m'}]" for i, c in enumerate(WRENCH)], "beta": [0.1] * 6}
    d["meta"]["effect"]["legs"]["r_leg"]["members"].append(lim)
    (tmp_path / "c.json").write_text(json.dumps(d))
    shutil.copy(folder / "out" / "calibration_with_effect_cov.npz", tmp_path)
    rec = pd.read_csv(folder / "fresh.csv").drop(columns=["q_r_knee"])
    with pytest.raises(DataFormatError) as exc:
        contact_frame(payload_calibrations(tmp_path / "c.json"), rec, "fresh.csv")
    assert "q_r_knee" in str(exc.value) and "joint_limit_contact" in str(exc.value)


def test_a_time_polynomial_keeps_the_calibration_session_span(caplog):
    # offset_drift's Legendre P1 over the calibration's span, not the new recording's own: exact
    n = 200
    t = np.linspace(1100.0, 1150.0, n)
    rng = np.random.default_rng(3)
    g_B = rng.normal(size=(n, 3))
    g_B *= 9.81 / np.linalg.norm(g_B, axis=1, keepdims=True)
    p = PayloadCalibration("w", np.zeros(6), 1.0, np.array([0.0, 0.0, 0.05]), np.eye(3), np.zeros((13, 13)),
                           np.full(6, 0.01), 9.81, undetermined=np.zeros(13, bool))
    beta = np.array([0.3, -0.2, 0.1, 0.01, 0.02, -0.01])
    m = Member("offset_drift", {"degree": 1}, tuple(f"{c}.P1 [N]" for c in WRENCH), beta, np.full(6, 0.01))
    fx = FreeEffects("w", (m,), {"t_span_s": [1000.0, 1200.0]}, np.eye(3), None, np.zeros((19, 19)), np.zeros(19, bool))
    w = rng.normal(size=(n, 6))
    plain, _ = contact_wrench(p, w, g_B, t=t)
    corrected, se = contact_wrench(replace(p, effects=fx), w, g_B, t=t)
    P1 = legendre_time(t, 1000.0, 1200.0, [1])[:, 0]
    np.testing.assert_allclose(plain - corrected, P1[:, None] * beta[None], rtol=0, atol=1e-12)
    np.testing.assert_allclose(se, 0.01, rtol=1e-12)   # no parameter uncertainty given: the noise alone
    # a recording on another clock (outside the session's span): extrapolated, and said so
    with caplog.at_level(logging.WARNING):
        contact_wrench(replace(p, effects=fx), w, g_B, t=t - 1100.0, where="other_clock.csv")
    assert "outside the calibration session's span" in caplog.text and "other_clock.csv" in caplog.text


def test_export_of_a_calibration_with_effects_is_an_error(payload, tmp_path):
    # the C function is the per-sample load model: the effects would be dropped silently
    from ftcal_nlp.export import write_c

    folder, _ = payload
    with pytest.raises(DataFormatError) as exc:
        write_c(payload_calibrations(folder / "out" / "calibration_with_effect.json"), tmp_path, "ftc",
                "calibration_with_effect.json")
    assert "meta.effect" in str(exc.value) and "clock_offset" in str(exc.value) and "calibration.json" in str(exc.value)


def test_se_of_the_corrected_wrench_match_the_spread_of_refits(tmp_path):
    # 20 calibrations of one rig (a linear drift: on the face) correct one noise-free probe recording; the sd of the
    # corrected wrench over them matches the se's calibration part sqrt(se^2 - sigma^2), which carries the joint
    # covariance of the load parameters and beta (pooled per channel; 1 +- 3 / sqrt(2 (R - 1)) for R refits)
    from ftcal_nlp.core.data import read_dataset
    from ftcal_nlp.diagnose.free_effect_file import COVARIANCE_FILE, free_effect_calibration
    from ftcal_nlp.pipeline import calibrate
    from ftcal_nlp.core.settings import CalibrationSettings, DiagnoseSettings

    rig = {**RIG, "effects": ({"name": "offset_drift_ramp", "scale": 20.0},)}
    probe = simulate_payload(PayloadConfig(seed=999, n_orientations=6, hold_s=6.0, move_s=3.0, noise_force_N=0.0,
                                           noise_torque_Nm=0.0, **rig)).frame
    settings = replace(CalibrationSettings(), diagnose=DiagnoseSettings(enabled=True))
    err, se_cal = [], []
    R = 20
    for s in range(100, 100 + R):
        sim = simulate_payload(PayloadConfig(seed=s, n_orientations=12, hold_s=6.0, move_s=3.0, **rig))
        res = calibrate(read_dataset(write_free_load(sim, tmp_path / f"d{s}")), settings)
        cal, cc = free_effect_calibration(res)
        cal.save(tmp_path / f"c{s}.json")
        cc.save(tmp_path / COVARIANCE_FILE)
        df = contact_frame(payload_calibrations(tmp_path / f"c{s}.json"), probe, "probe")
        sigma = np.asarray(cal.legs["wrist"].load["noise_sd"])
        err.append(df[[f"wrist_{c}" for c in WRENCH]].to_numpy())
        se_cal.append(np.sqrt(df[[f"wrist_{c}_se" for c in WRENCH]].to_numpy() ** 2 - sigma**2))
    err, se_cal = np.array(err), np.array(se_cal)
    ratio = np.sqrt((err.std(axis=0, ddof=1) ** 2).mean(axis=0) / (se_cal**2).mean(axis=(0, 1)))
    tol = 3.0 / np.sqrt(2 * (R - 1))
    assert np.all(np.abs(ratio - 1.0) < tol), ratio


def test_a_list_of_single_row_poses_is_not_corrected_for_stream_effects(payload):
    """A clock offset re-samples the stream and creep relaxes between changes of load: a recording of one row per pose
    (no hold of two samples) cannot be corrected for them (an error naming column t), while calibration.json still
    corrects it."""
    folder, _ = payload
    rec = pd.read_csv(folder / "fresh.csv")
    dt = float(np.median(np.diff(rec["t"])))
    poses = rec.iloc[:: int(round(9.0 / dt))].reset_index(drop=True)   # one row per hold + move period (9 s)
    with pytest.raises(DataFormatError) as exc:
        contact_frame(payload_calibrations(folder / "out" / "calibration_with_effect.json"), poses, "poses.csv")
    assert exc.value.column == "t" and "single-row poses" in str(exc.value) and "clock_offset" in str(exc.value)
    out = contact_frame(payload_calibrations(folder / "out" / "calibration.json"), poses, "poses.csv")
    assert len(out) == len(poses)


def test_the_effect_specific_parts_of_the_correction_are_hooks_on_the_units():
    # what the free-load correction asks of a member is its unit's (effects/<name>.py), named nowhere else: the
    # units that follow the stream's clock (the list correction used to keep by name) and no effect name as a
    # string in the commands, the loads or the one effect correction
    import ast
    from pathlib import Path

    import ftcal_nlp
    from ftcal_nlp.effects import EFFECTS, LIBRARY_EFFECTS

    assert {n for n, u in EFFECTS.items() if u.follows_stream_clock} == {"clock_offset", "creep", "inertial_load"}
    assert {n for n, u in EFFECTS.items() if u.free_reference_keys} == {"offset_drift", "temperature"}
    root = Path(ftcal_nlp.__file__).parent
    files = [*(root / "correct").glob("*.py"), *(root / "export").glob("*.py"), *(root / "loads").glob("*.py"),
             root / "effects" / "correction.py", root / "diagnose" / "free_effect_file.py"]
    named = {(f.relative_to(root).as_posix(), node.value) for f in files for node in ast.walk(ast.parse(f.read_text()))
             if isinstance(node, ast.Constant) and node.value in LIBRARY_EFFECTS}
    assert not named, named
