"""Joint refit with the named effect (issue 13, item 1) and the effect's correction in ``correct``.

One small session with a casing load (its shaft-angle load acts while hanging, standing and
walking): the diagnosis names it, refits the whole calibration with it, and the joint model's
held-out residual must come down to its floor on every recording kind and component (the
issue's 1.5x); the calibration written with the effect must correct a walk to the noise level.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ftcal_nlp import CalibrationSettings, calibrate
from ftcal_nlp.calibration import Calibration
from ftcal_nlp.correct import correct_recording
from ftcal_nlp.data import WRENCH_COMPONENTS
from ftcal_nlp.diagnose.effects import LIBRARY
from ftcal_nlp.effect_correction import apply_effect
from ftcal_nlp.geometry import cayley, rotvec_to_rotation
from ftcal_nlp.sim import SimConfig, simulate

SMALL = {"n_poses": 120, "hanging_cycles": 2.0, "walk_cycles": 2.0, "seed": 11}
SHRINK_MAX = 1.5       # the criterion: after the named effect, held-out RMS within 1.5x its floor


@pytest.fixture(scope="module")
def casing():
    sim = simulate(SimConfig.from_dict({**SMALL, "effects": [{"name": "casing_load", "seed": 11}]}))
    return sim, calibrate(sim.dataset, CalibrationSettings())


def test_joint_refit_closes_the_gap_on_every_kind(casing):
    sim, run = casing
    d = run.diagnosis
    assert d.verdict == "effect" and d.effect == "casing_load"
    j = d.joint
    assert j is not None and set(j.kinds) == {"hanging", "standing", "walking swing"}
    for kind, k in j.kinds.items():
        assert np.all(k.rms_after <= SHRINK_MAX * k.floor), (kind, k.rms_after / k.floor)
    # the gap was real: the calibration alone is far above the floor on fx/fy of the hanging legs
    assert j.kinds["hanging"].rms_before[0] > 5 * j.kinds["hanging"].floor[0]
    out = d.to_json_dict()["joint_refit"]
    assert out["effect"] == "casing_load" and set(out["kinds"]) == set(j.kinds)
    assert all(p["se"] is None or p["se"] > 0 for p in out["parameters"].values())
    # the shrinkage reported is the joint model's, on the primary kind
    assert np.allclose(d.shrinkage["heldout_rms_after"], j.kinds[d.shrinkage["kind_key"]].rms_after)


def _foot_rms(df, truth, legs):
    cols = [f"{k}_{c}" for k in legs for c in WRENCH_COMPONENTS]
    e = (df[cols].to_numpy() - truth[cols].to_numpy()[: len(df)]).reshape(len(df), len(legs), 6)
    return np.sqrt((e**2).mean(axis=(0, 1)))


def test_calibration_with_effect_corrects_a_walk(casing, tmp_path):
    sim, run = casing
    path = tmp_path / "calibration_with_effect.json"
    run.diagnosis.joint.calibration.save(path)
    cal = Calibration.load(path)
    assert cal.meta["effect"]["name"] == "casing_load"
    rec, legs = sim.dataset.walking[0], cal.leg_names
    plain = _foot_rms(correct_recording(run.calibration, rec), sim.walk_truth, legs)
    joint = _foot_rms(correct_recording(cal, rec), sim.walk_truth, legs)
    # the casing load (~0.7 N on fx, fy) is gone: what is left is the readings' noise (0.05 N) and
    # the calibration's own error, within 1.5x of the readings' floor
    floor = run.diagnosis.joint.kinds["hanging"].floor
    assert np.all(plain[:2] > 5 * floor[:2])
    assert np.all(joint[:2] < SHRINK_MAX * floor[:2]), joint


def _calibration_with(effect: str, eta, K=6):
    sim = simulate(SimConfig.from_dict({"n_poses": 12, "hanging_cycles": 0.5, "walk_cycles": 0.2, "seed": 3}))
    cal = sim.truth
    meta = {"effect": {"name": effect, "eta": list(eta), "t_ref_s": 0.0, "parameters": {},
                       "R_nominal": np.asarray(sim.dataset.robot.nominal_rotations()).tolist()}}
    return sim, Calibration(cal.legs, cal.mass_kg, cal.g, cal.model, cal.com_body_m, meta)


def test_effect_correction_formulas():
    """The CasADi faces evaluated over samples equal their formulas (casing load, mocap bias)."""
    rng = np.random.default_rng(0)
    K, N = 6, 7
    w = rng.normal(size=(N, K, 6))
    phi = rng.uniform(0, 2 * np.pi, (N, K))
    R = rotvec_to_rotation(rng.normal(scale=0.2, size=(N, 3)))
    t = np.linspace(0, 100, N)
    eta = rng.normal(size=4 * K)
    sim, cal = _calibration_with("casing_load", eta)
    w2, R2 = apply_effect(cal, w, phi, R, t)
    a = eta.reshape(K, 4)
    expect = w.copy()
    expect[..., 0] -= a[None, :, 0] * np.cos(phi) + a[None, :, 1] * np.sin(phi)
    expect[..., 1] -= a[None, :, 2] * np.cos(phi) + a[None, :, 3] * np.sin(phi)
    assert np.allclose(w2, expect, atol=1e-12) and np.array_equal(R2, R)
    q = rng.normal(size=3)
    _, cal = _calibration_with("mocap_bias", q)
    w3, R3 = apply_effect(cal, w, phi, R, t)
    up = np.einsum("nji,j->ni", R3, np.array([0, 0, 1.0]))
    assert np.array_equal(w3, w)
    assert np.allclose(up, np.einsum("ij,nj->ni", cayley(0.01 * q), R[:, 2, :]), atol=1e-12)


def test_a_casing_load_of_other_harmonics_is_closed_by_the_flexible_face():
    """The injector puts the load on the 3rd and 5th harmonics of the shaft angle (``sim/variants.py``);
    the library's face starts from the 1st. The joint refit chooses the harmonics by the hanging held-out
    residual and must close the gap on every kind to 1.5x its floor."""
    from ftcal_nlp import StandingSettings

    spec = {"n_poses": 100, "hanging_cycles": 2.0, "walk_cycles": 1.0, "seed": 35,
            "effects": [{"name": "casing_load_harmonics", "seed": 35, "scale": 1.5}]}
    run = calibrate(simulate(SimConfig.from_dict(spec)).dataset, CalibrationSettings(standing=StandingSettings(model="full")))
    d = run.diagnosis
    assert d.verdict == "effect" and d.effect == "casing_load"
    assert d.joint.variant["harmonics"] >= 5   # the 5th harmonic is there
    for kind, k in d.joint.kinds.items():
        assert np.all(k.rms_after <= SHRINK_MAX * k.floor), (kind, k.rms_after / k.floor)
    assert d.joint.kinds["hanging"].rms_before[0] > 10 * d.joint.kinds["hanging"].floor[0]
