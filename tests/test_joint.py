"""Joint refit with the named effect (issue 13, item 1) and the effect's correction in ``correct``.

One small session with a casing load (its shaft-angle load acts while hanging, standing and
walking): the diagnosis names it, refits the whole calibration with it, and the joint model's
held-out residual must come down to its floor on every recording kind and component (the
issue's 1.5x); the calibration written with the effect must correct a walk to the noise level.
"""

from __future__ import annotations


import numpy as np
import pytest

from ftcal_nlp import CalibrationSettings, HangingSettings, StandingSettings, calibrate
from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.correct import correct_recording
from ftcal_nlp.core.data import WRENCH_COMPONENTS
from ftcal_nlp.effects.correction import apply_effect
from ftcal_nlp.core.geometry import cayley, rotvec_to_rotation
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
    from ftcal_nlp.run import COVARIANCE_FILE, effect_calibration

    sim, run = casing
    path = tmp_path / "calibration_with_effect.json"
    effect_calibration(run).save(path)
    cal = Calibration.load(path)
    # where the joint calibration keeps the calibration's error model, its covariance file stands in
    same = run.diagnosis.joint.calibration.model == run.calibration.model
    assert (cal.meta.get("covariance_file") == COVARIANCE_FILE) == (same and run.uncertainty is not None)
    assert cal.meta["effect"]["name"] == "casing_load"
    rec, legs = sim.dataset.walking[0], cal.leg_names
    plain = _foot_rms(correct_recording(run.calibration, rec), sim.walk_truth, legs)
    joint = _foot_rms(correct_recording(cal, rec), sim.walk_truth, legs)
    # the casing load (~0.7 N on fx, fy) is gone: what is left is the readings' noise (0.05 N) and
    # the calibration's own error, within 1.5x of the readings' floor
    floor = run.diagnosis.joint.kinds["hanging"].floor
    assert np.all(plain[:2] > 5 * floor[:2])
    assert np.all(joint[:2] < SHRINK_MAX * floor[:2]), joint
    # the effect's parameter uncertainty (meta.effect.eta_cov) widens the se columns, never narrows them
    assert np.asarray(cal.meta["effect"]["eta_cov"]).shape[0] >= 4 * len(legs)
    bare = Calibration(cal.legs, cal.mass_kg, cal.g, cal.model, cal.com_body_m,
                       {**cal.meta, "effect": {k: v for k, v in cal.meta["effect"].items() if k != "eta_cov"}})
    se = [correct_recording(c, rec)[[f"{k}_{q}_se" for k in legs for q in WRENCH_COMPONENTS]].to_numpy().reshape(-1, len(legs), 6)
          for c in (cal, bare)]
    assert np.all(np.isfinite(se[0])) and np.all(se[0] >= se[1] - 1e-12)
    assert np.all((se[0] - se[1])[..., :2].mean(axis=(0, 1)) > 0)


def _calibration_with(effect: str, eta, K=6):
    sim = simulate(SimConfig.from_dict({"n_poses": 12, "hanging_cycles": 0.5, "walk_cycles": 0.2, "seed": 3}))
    cal = sim.truth
    meta = {"effect": {"name": effect, "eta": list(eta), "t_ref_s": 0.0, "parameters": {},
                       "R_nominal": np.asarray(sim.dataset.robot.nominal_rotations()).tolist()}}
    return sim, Calibration(cal.legs, cal.mass_kg, cal.g, cal.model, cal.com_body_m, meta)


def _samples(seed: int, N: int, t_end: float, K: int = 6):
    """Random readings, shaft angles, orientations and times of N samples (and the generator)."""
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(N, K, 6))
    phi = rng.uniform(0, 2 * np.pi, (N, K))
    R = rotvec_to_rotation(rng.normal(scale=0.2, size=(N, 3)))
    return rng, K, N, w, phi, R, np.linspace(0, t_end, N)


def test_effect_correction_formulas():
    """The CasADi faces evaluated over samples equal their formulas (casing load, mocap bias)."""
    rng, K, N, w, phi, R, t = _samples(0, 7, 100.0)
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


def test_joint_hanging_fit_recovers_leg_weights_under_a_warm_up():
    """A fast warm-up (tau 150 s, ~3 N over the hanging recordings) biases the calibrated leg weights
    by up to 0.26 N through the opposite-pair differences and reads as large hanging tilts. The joint
    hanging fit (Gauss-Newton on the hanging model with the drift's face, the face chosen by held-out
    residual among ``OffsetDrift.joint_variants``, none of which is the injector's exponential) must
    bring every leg weight back to truth. Tolerance: 0.015 N, what a warm-up curve 40 % off in its time
    constant leaves (the weights' own se is ~0.001 N); and at least 10x smaller than the bias."""
    from ftcal_nlp.effects.offset_drift import OffsetDrift
    from ftcal_nlp.diagnose.refit import hanging_joint
    from ftcal_nlp.diagnose.views import hanging_series
    from ftcal_nlp.estimate.hanging import fit_hanging

    sim = simulate(SimConfig.from_dict({"n_poses": 30, "hanging_cycles": 1.0, "walk_cycles": 0.0, "seed": 5,
                                        "effects": [{"name": "offset_drift_fast", "scale": 4.0, "seed": 5}]}))
    ds = sim.dataset
    hang = fit_hanging(ds.hanging, ds.robot)
    series = hanging_series(ds.hanging, hang, ds.robot, float(np.mean(np.concatenate([r.t for r in ds.hanging]))))
    w0 = np.array([hang.legs[k].leg_weight_N for k in ds.robot.legs])
    bias = w0 - sim.true_robot.weights_N
    best = None
    for v in OffsetDrift().joint_variants():
        kind, _, _, d_mg, _, _, _ = hanging_joint(series, v.hanging_features, 5)
        z = float(np.sum((kind.rms_after / kind.floor) ** 2))
        if best is None or z < best[0]:
            best = (z, v, d_mg)
    err = w0 + best[2] - sim.true_robot.weights_N
    assert np.max(np.abs(bias)) > 0.15
    assert best[1].hanging != "line"      # the straight line does not follow the warm-up
    assert np.max(np.abs(err)) < min(0.015, 0.1 * np.max(np.abs(bias))), (err, best[1].variant)


def test_change_point_finds_a_step():
    """``views.change_point``: a step of 3 sd in two components on a trend, 60 poses: found between
    the two poses around it (the scan's resolution); fewer than two segments' poses: None."""
    from ftcal_nlp.diagnose.views import MIN_SEGMENT_POSES, change_point

    rng = np.random.default_rng(4)
    t = np.sort(rng.uniform(0.0, 0.5, 60))
    r = rng.normal(size=(60, 6)) + 2.0 * t[:, None]
    r[t > t[37], :2] += 3.0
    s = change_point(t, r)
    assert t[37] <= s <= t[38]
    assert change_point(t[: 2 * MIN_SEGMENT_POSES], r[: 2 * MIN_SEGMENT_POSES]) is None


def test_effect_reading_covariance_is_the_faces_jacobian_through_eta_cov():
    """A casing load's corrected fx, fy are linear in its parameters (a, b, c, d per leg): their
    variance under ``eta_cov`` is ``cos^2 var(a) + sin^2 var(b)`` (and ``c``, ``d`` for fy), torques none;
    an offset drift's is the rate's variance times the squared hours from the reference."""
    from ftcal_nlp.effects.correction import effect_reading_cov

    rng, K, N, w, phi, R, t = _samples(1, 5, 7200.0)
    s = rng.uniform(0.1, 1.0, 4 * K)
    sim, cal = _calibration_with("casing_load", rng.normal(size=4 * K))
    cal.meta["effect"]["eta_cov"] = np.diag(s**2).tolist()
    C = effect_reading_cov(cal, w, phi, R, t)
    v = s.reshape(K, 4) ** 2
    assert np.allclose(C[..., 0, 0], np.cos(phi) ** 2 * v[None, :, 0] + np.sin(phi) ** 2 * v[None, :, 1], rtol=1e-10)
    assert np.allclose(C[..., 1, 1], np.cos(phi) ** 2 * v[None, :, 2] + np.sin(phi) ** 2 * v[None, :, 3], rtol=1e-10)
    assert np.allclose(C[..., 0, 1], 0.0) and np.allclose(C[..., 3:, 3:], 0.0)
    _, cal = _calibration_with("offset_drift", [])
    legs = cal.leg_names
    cal.meta["effect"]["parameters"] = {f"hanging:{legs[2]}.fz/h": {"value": 1.0, "se": 0.3}}
    C = effect_reading_cov(cal, w, phi, R, t)
    assert np.allclose(C[:, 2, 2, 2], (t / 3600.0 * 0.3) ** 2) and np.count_nonzero(C) == np.count_nonzero(t)


def test_the_com_move_is_the_nuisance_steps():
    """``moved_com`` moves a CoM curve as the joint hanging fit's steps move the series' CoM (``_nuisance_update``)."""
    from dataclasses import replace

    from ftcal_nlp.diagnose.refit import COM_HARMONICS, _nuisance_update, moved_com
    from ftcal_nlp.effects.faces import HangingLeg

    rng = np.random.default_rng(3)
    n, n_h = 50, 1 + 2 * COM_HARMONICS
    phi = rng.uniform(0, 2 * np.pi, n)
    f = rng.normal(0, 3, (n, 3))
    r = rng.normal(0, 0.05, (n, 3))
    leg = HangingLeg("FL", 0, np.zeros((n, 6)), np.arange(n) * 0.01, phi, np.zeros(n), np.zeros(n, int), f, r,
                     np.zeros((n, 3)), 5.0, 9.81, 0.0, np.array([0.0, 0.0, 1.0]))
    leg = replace(leg, e=leg.e + leg.applied)     # any residual: the update moves it with the model
    b = np.zeros(7 + 3 + 3 * n_h)
    b_r = rng.normal(0, 0.01, (n_h, 3))
    b[10:] = b_r.ravel()
    moved = _nuisance_update(leg, b, 1)
    np.testing.assert_allclose(moved.r, moved_com(r, phi, b_r), atol=1e-15)


GAIN_POSES = {"n_poses": 300, "hanging_cycles": 2.0, "walk_cycles": 1.0, "seed": 1}


def test_a_gain_matrix_per_leg_closes_every_kind_on_enough_poses():
    """Issue 33 (the hexapod): a 3 % force matrix per leg, 300 standing poses (on the report's 100 most of its 54
    entries have no se and the held-out fz stays ~2.6x its floor: ``docs/diagnosis.md``). Named, and the joint refit,
    with the CoM curves its hanging fit moved carried into the other kinds, brings every kind within the issue's 1.5x
    of its floor (measured 0.97-1.09x); every entry of the matrices has a finite se."""
    sim = simulate(SimConfig.from_dict({**GAIN_POSES, "effects": [{"name": "gain_crosstalk", "scale": 0.03, "seed": 1}]}))
    settings = CalibrationSettings(hanging=HangingSettings(compare_baseline=False),
                                   standing=StandingSettings(model="full", compare_baseline=False))
    run = calibrate(sim.dataset, settings)
    d = run.diagnosis
    assert d.effect == "gain_crosstalk", [e["name"] for e in d.effects_list()]
    j = d.joint
    for kind, k in j.kinds.items():
        assert np.all(k.rms_after <= SHRINK_MAX * k.floor), (kind, k.rms_after / k.floor)
        assert np.max(k.rms_before / k.floor) > 2.0, (kind, k.rms_before / k.floor)   # a gap on every kind first
    ses = [s for n, (_, s) in j.parameters.items() if n.startswith("g[")]
    assert len(ses) == 54 and np.all(np.isfinite(ses))
