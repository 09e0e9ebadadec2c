"""Temperature on free loads end to end (issue 32 item 4): a payload (``sim/free``) and the simulated 4R arm of
``test_arm`` (a tool left out of the URDF, read through the joints) with offsets that move with the transducer's
temperature (``effects/temperature.py``, ``{X}_temp_C``) are calibrated with the diagnosis; the chain names
``temperature`` and ``calibration_with_effect.json`` carries the coefficients (N/degC, N*m/degC, with se) and the
calibration's reference temperature. A LATER recording 8 degC warmer (the same rig, its own temperature column, a
range the calibration never saw) corrected with that file gives a contact wrench at zero within its se (|z| RMS
near 1), and biased far above its se with ``calibration.json`` alone; the correction is the calibration's
coefficients on the recording's temperature relative to the CALIBRATION's mean (relative to the recording's own
mean, the 8 degC shift would be left in the offsets). A later payload recording held at one temperature (33 degC) is
corrected likewise; ``correct``'s checks against the calibration look at the readings after the effect correction
(before it, 5-8 degC x the coefficients move the offsets ~0.5 N and no row is at the noise). ``plan`` on the calibration
session predicts the coefficients' se the run gives, within a factor it states."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w

from ftcal_nlp.correct import main as correct_main
from ftcal_nlp.effects.temperature import T_REF_C, TemperatureInjector, temperature_profile
from ftcal_nlp.core.kinematics import load_tree
from ftcal_nlp.run import main as run_main
from ftcal_nlp.sim.free import PayloadConfig, simulate_payload, write_free_load

from test_arm import NOISE as ARM_NOISE
from test_arm import URDF, _arm_frame

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
SHIFT_C = 8.0        # the later recording: this much warmer than the calibration session throughout
SCALE = 0.08         # N of force offset per degC (the injector's default: ~0.1 % of 130 N per degC)
RIG = dict(offset=(1.0, -2.0, 0.5, 0.05, -0.03, 0.02), mount_rotvec=(0.01, -0.02, 0.015), n_orientations=12,
           hold_s=6.0, move_s=3.0)
PAYLOAD_NOISE = np.array([0.02] * 3 + [0.0006] * 3)


class Warmer(TemperatureInjector):
    """The same transducer (gains and phases from the same seed) ``shift`` degC warmer: a later session."""

    def __init__(self, shift: float, scale: float | None = None, seed: int = 0):
        super().__init__(scale, seed)
        self.shift = float(shift)

    def temperature(self, ctx) -> np.ndarray:
        return super().temperature(ctx) + self.shift


class Held(TemperatureInjector):
    """The same transducer held at one temperature ``temp_c`` throughout (a later recording in a climate chamber)."""

    def __init__(self, temp_c: float, scale: float | None = None, seed: int = 0):
        super().__init__(scale, seed)
        self.temp_c = float(temp_c)

    def temperature(self, ctx) -> np.ndarray:
        return np.full_like(super().temperature(ctx), self.temp_c)


def _calibrate(folder: Path, manifest: Path) -> None:
    (folder / "run.toml").write_text(f'[data]\nmanifest = "{manifest}"\n[output]\ndir = "{folder / "out"}"\n'
                                     "[diagnose]\nenabled = true\n")
    assert run_main([str(folder / "run.toml"), "-q"]) == 0


def _correct(folder: Path, later: Path, leg: str) -> dict:
    """``later`` corrected with both files: ``{file: (contact (N, 6), se (N, 6))}``."""
    out = {}
    for name in ("calibration.json", "calibration_with_effect.json"):
        dst = folder / f"c_{later.stem}_{name}.csv"
        assert correct_main([str(folder / "out" / name), str(later), "-o", str(dst)]) == 0
        got = pd.read_csv(dst)
        cols = [f"{leg}_{c}" for c in WRENCH]
        out[name] = (got[cols].to_numpy(), got[[f"{c}_se" for c in cols]].to_numpy())
    return out


@pytest.fixture(scope="module")
def payload(tmp_path_factory):
    folder = tmp_path_factory.mktemp("temp_payload")
    cal = simulate_payload(PayloadConfig(seed=41, effects=(TemperatureInjector(scale=SCALE, seed=3),), **RIG))
    later = simulate_payload(PayloadConfig(seed=42, effects=(Warmer(SHIFT_C, scale=SCALE, seed=3),), **RIG))
    _calibrate(folder, write_free_load(cal, folder / "data"))
    later.frame.to_csv(folder / "later.csv", index=False)
    T_cal = cal.frame["wrist_temp_C"].to_numpy()
    return folder, "wrist", PAYLOAD_NOISE, T_cal, later.frame, _correct(folder, folder / "later.csv", "wrist")


def _arm_with_temperature(tree, seed: int, holds: int, shift: float, t0: float) -> pd.DataFrame:
    """``test_arm``'s joint-space session with the temperature injector's offsets ``a (T - 25 degC)`` added and its
    temperature (``shift`` degC warmer) in ``wrist_temp_C`` (the injector's profile on the session clock)."""
    f = _arm_frame(tree, seed, holds, t0=t0)
    inj = TemperatureInjector(scale=SCALE, seed=3)
    a = inj.gains(1)[0]
    phase = inj.drawn("_p", 1, inj._draw)[:, 6]
    T = temperature_profile(f["t"].to_numpy() - t0 + 1000.0, phase)[:, 0] + shift
    for i, c in enumerate(WRENCH):
        f[f"wrist_{c}"] += a[i] * (T - T_REF_C)
    f["wrist_temp_C"] = T
    return f


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("temp_arm")
    (folder / "arm4.urdf").write_text(URDF)
    tree = load_tree(folder / "arm4.urdf")
    cal = _arm_with_temperature(tree, 1, 24, 0.0, 1.7e9)
    cal.to_csv(folder / "wrist.csv", index=False, float_format="%.17g")
    _arm_with_temperature(tree, 2, 14, SHIFT_C, 1.8e9).to_csv(folder / "later.csv", index=False, float_format="%.17g")
    (folder / "robot.toml").write_bytes(tomli_w.dumps({"name": "arm4", "g": 9.81, "legs": ["wrist"], "urdf": "arm4.urdf",
                                                       "transducers": {"wrist": {"link": "ft_sensor"}}}).encode())
    (folder / "dataset.toml").write_bytes(tomli_w.dumps({"robot": "robot.toml", "recording": [
        {"file": "wrist.csv", "kind": "hanging", "gravity_body": [0.0, 0.0, -1.0]}]}).encode())
    _calibrate(folder, folder / "dataset.toml")
    later = pd.read_csv(folder / "later.csv")
    return folder, "wrist", ARM_NOISE, cal["wrist_temp_C"].to_numpy(), later, _correct(folder, folder / "later.csv", "wrist")




@pytest.mark.parametrize("case", ["payload", "arm"])
def test_later_warmer_recording_corrected_with_the_calibration_reference(case, request):
    folder, leg, noise, T_cal, later, out = request.getfixturevalue(case)
    T_later = later[f"{leg}_temp_C"].to_numpy()
    assert T_later.min() > T_cal.max()                       # a range the calibration never saw
    # the diagnosis named temperature; the file carries the coefficients with se and the reference temperature
    diag = json.loads((folder / "out" / "diagnosis.json").read_text())["free_loads"][leg]
    assert "temperature" in json.dumps(diag)
    eff = json.loads((folder / "out" / "calibration_with_effect.json").read_text())["meta"]["effect"]
    assert eff["name"] == "temperature"
    block = eff["legs"][leg]
    (member,) = block["members"]
    assert member["name"] == "temperature" and member["shape"]["degree"] in (1, 2)
    pars = member["parameters"]
    assert all(np.isfinite(p["se"]) and p["se"] > 0 for p in pars.values())
    ref = block["reference"]["temperature_mean_C"]
    if member["shape"]["lag_s"] == 0.0:
        assert ref == pytest.approx(float(np.mean(T_cal)), rel=1e-12)   # the calibration session's mean, not 25 degC
    else:
        assert abs(ref - np.mean(T_cal)) < 0.5
    # the linear coefficients against the injected gains (the simulator's truth): within 4 se
    a = TemperatureInjector(scale=SCALE, seed=3).gains(1)[0]
    d1 = [f"{c}.dT [{'N' if i < 3 else 'N*m'}/degC]" for i, c in enumerate(WRENCH)]
    if member["shape"]["degree"] == 1:
        z = [(pars[k]["value"] - a[i]) / pars[k]["se"] for i, k in enumerate(d1)]
        assert np.max(np.abs(z)) < 4.0, z
    # the later recording: zero within its se with the effect, biased without
    e_fx, se_fx = out["calibration_with_effect.json"]
    e_0, se_0 = out["calibration.json"]
    z_fx = np.sqrt(((e_fx / se_fx) ** 2).mean(axis=0))
    assert np.all((z_fx > 0.85) & (z_fx < 1.2)), z_fx
    assert np.all(np.abs(e_fx.mean(axis=0)) < 0.2 * noise), e_fx.mean(axis=0) / noise
    z_0 = np.sqrt(((e_0 / se_0) ** 2).mean(axis=0))
    assert np.max(z_0) > 3.0, z_0
    # relative to the recording's own mean the shift (coefficients x 8 degC) would stay: far above the noise
    lost = np.abs([pars[k]["value"] for k in d1]) * (np.mean(T_later) - ref)
    assert np.max(lost / noise) > 10.0


def test_plan_of_the_calibration_session_predicts_the_coefficients_se(payload):
    """``plan`` on the calibration session as a pilot (plan/temperature.py): the coefficients' predicted se against
    those the run's joint refit gives (calibration_with_effect.json). The plan counts the quasi-static samples the
    load fit uses (7 373 of 10 500 here) and widens by their serial correlation; the refit uses every sample: the
    plan is the larger, by ~sqrt(10 500 / 7 373) = 1.19 times its widening (1.05..1.36): measured 1.26..1.79."""
    from ftcal_nlp.core.data import read_dataset
    from ftcal_nlp.plan.free_load import plan_from_dataset

    folder, leg, *_ = payload
    p = plan_from_dataset(read_dataset(folder / "data" / "dataset.toml")).loads[leg].temperature
    pars = json.loads((folder / "out" / "calibration_with_effect.json").read_text())["meta"]["effect"]["legs"][leg][
        "members"][0]["parameters"]
    run_se = np.array([v["se"] for v in pars.values()])
    ratio = p.se / run_se
    assert np.all((ratio > 0.9) & (ratio < 2.0)), ratio
    # 4 degC of swing determine the coefficients far below the default target (noise over 10 degC): well met
    assert p.determined and np.all(p.se < p.target) and p.needed_range_C < p.range_C


def test_later_recording_held_at_one_temperature(payload, tmp_path):
    """A later recording whose temperature never varies (33 degC throughout, 5 degC above the calibration's mean) is
    corrected too: the face is centred on the calibration's reference, so a constant temperature still moves the
    offsets by the coefficients times its distance from it."""
    folder, leg, noise, *_ = payload
    later = simulate_payload(PayloadConfig(seed=43, effects=(Held(33.0, scale=SCALE, seed=3),), **RIG))
    later.frame.to_csv(tmp_path / "held.csv", index=False)
    out = _correct(folder, tmp_path / "held.csv", leg)
    e_fx, se_fx = out["calibration_with_effect.json"]
    e_0, se_0 = out["calibration.json"]
    z_fx = np.sqrt(((e_fx / se_fx) ** 2).mean(axis=0))
    assert np.all((z_fx > 0.85) & (z_fx < 1.2)), z_fx
    assert np.all(np.abs(e_fx.mean(axis=0)) < 0.2 * noise), e_fx.mean(axis=0) / noise
    assert np.max(np.sqrt(((e_0 / se_0) ** 2).mean(axis=0))) > 3.0
