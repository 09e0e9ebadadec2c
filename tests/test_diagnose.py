"""Sim-to-real gap diagnosis (issue 7): effect library (both faces), numeric twins of the
augmented balance, linear faces, design check, and the diagnosis itself: every effect injected
alone at its test size is named, clean data say "none", the output follows OUTPUT_FORMAT.md.

The simulated sessions are small (120 poses, 2 leg turns per hanging recording, 1 walk cycle);
effects that do not touch the hanging recordings share the clean session's hanging fit (their
hanging recordings are checked to be bit-identical)."""

from __future__ import annotations

import json
from pathlib import Path
from dataclasses import replace

import numpy as np
import pytest
from conftest import SAMPLE, requires_sample

from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.diagnose import DiagnosisResult, diagnose
from ftcal_nlp.effects import EFFECTS as LIBRARY, HangingLeg, LinearFace, design_check
from ftcal_nlp.diagnose.linear_fit import score_linear
from ftcal_nlp.diagnose.standing_fit import AugmentedProblem, StandingData
from ftcal_nlp.diagnose.validation import plan, run_validation
from ftcal_nlp.pipeline import calibrate
from ftcal_nlp.diagnose.views import LegSeries, to_world
from ftcal_nlp.core.geometry import rotation_to_rotvec, rotvec_to_rotation
from ftcal_nlp.estimate.hanging import fit_hanging
from ftcal_nlp.core.settings import DiagnoseSettings
from ftcal_nlp.core.physics import balance_residual_exact, balance_residual_report
from ftcal_nlp.sim import EFFECTS, SimConfig, simulate
from ftcal_nlp.effects import LIBRARY_EFFECTS
from ftcal_nlp.sim.effects import make_effects
from ftcal_nlp.estimate.standing import Poses, extract_poses, fit_standing

HEXAPOD = [n for n, u in LIBRARY.items() if "hexapod" in u.diagnosed_on]   # the effects with hexapod faces
SEED = 11
SMALL = {"n_poses": 120, "hanging_cycles": 2.0, "walk_cycles": 1.0}
HANGING_EFFECTS = ("offset_drift", "gain_crosstalk", "casing_load", "chassis_flex", "leg_inertia", "sensor_nonlinearity")
FOLDS = 3

_cache: dict = {}


def session(effect: str):
    """(sim, hanging result, poses, standing result) of one small session with ``effect`` at its test size."""
    if effect in _cache:
        return _cache[effect]
    spec = [] if effect in ("none", "moving_com") else [{"name": effect, "seed": SEED}]
    sim = simulate(SimConfig.from_dict({**SMALL, "seed": SEED, "effects": spec}))
    ds = sim.dataset
    if effect in HANGING_EFFECTS or effect == "none":
        hang = fit_hanging(ds.hanging, ds.robot)
    else:
        clean_sim, hang = session("none")[:2]
        for a, b in zip(ds.hanging, clean_sim.dataset.hanging):  # the effect leaves the hanging recordings alone
            assert np.array_equal(a.wrench_array(), b.wrench_array())
    balance = "report" if effect == "moving_com" else "exact"
    prior = hang.to_calibration(ds.robot)
    poses = Poses.concat([extract_poses(r, ds.robot) for r in ds.standing])
    st = fit_standing(poses, prior, ds.robot, model="full", balance=balance)
    _cache[effect] = (sim, hang, poses, st)
    return _cache[effect]


def diagnosis(effect: str) -> DiagnosisResult:
    key = ("diag", effect)
    if key not in _cache:
        sim, hang, poses, st = session(effect)
        _cache[key] = diagnose(sim.dataset, hang, poses, st.calibration, sim.dataset.robot,
                               DiagnoseSettings(folds=FOLDS), balance=st.balance, x_start=st.x)
    return _cache[key]


# ----------------------------------------------------------------------------- the library and its injectors


def test_library_matches_the_contract_and_registers_every_injector():
    assert set(LIBRARY) == set(LIBRARY_EFFECTS)
    for name in LIBRARY:
        assert name in EFFECTS
        inj = make_effects([{"name": name, "scale": LIBRARY[name].magnitude.test, "seed": 3}])[0]
        assert inj.name == name and inj.scale == LIBRARY[name].magnitude.test
        lo, hi = LIBRARY[name].magnitude.realistic
        assert lo <= hi
    cfg = SimConfig.from_dict({"effects": ["tether_force"]})
    assert cfg.effects[0].name == "tether_force"
    with pytest.raises(ValueError, match="known effects: .*casing_load"):
        make_effects(["tether"])


def test_injectors_at_zero_scale_change_nothing():
    base = simulate(SimConfig(seed=2, n_poses=8, hanging_cycles=0.5, walk_cycles=0.5))
    for name in (n for n, u in LIBRARY.items() if "hexapod" in u.applies_to):   # the hexapod simulator's
        res = simulate(SimConfig(seed=2, n_poses=8, hanging_cycles=0.5, walk_cycles=0.5, effects=make_effects([{"name": name, "scale": 0.0}])))
        assert res.dataset.robot.mass_kg == base.dataset.robot.mass_kg, name
        for a, b in zip(res.dataset.recordings, base.dataset.recordings):
            np.testing.assert_allclose(a.wrench_array(), b.wrench_array(), atol=1e-12, err_msg=name)
            if a.quat is not None:
                np.testing.assert_allclose(np.nan_to_num(a.quat), np.nan_to_num(b.quat), atol=1e-12, err_msg=name)


def test_tether_injector_carries_the_cable_through_the_feet():
    """The readings change by exactly minus the cable's wrench in the body balance (E)."""
    sim_c = simulate(SimConfig(seed=4, n_poses=10, hanging_cycles=0.5, walk_cycles=0.0, mocap_jitter_deg=0.0, mocap_pose_error_deg=0.0))
    eff = make_effects([{"name": "tether_force", "scale": 2.0, "seed": 1}])
    sim_t = simulate(SimConfig(seed=4, n_poses=10, hanging_cycles=0.5, walk_cycles=0.0, mocap_jitter_deg=0.0, mocap_pose_error_deg=0.0, effects=eff))
    truth = sim_t.true_robot
    f_H, a = eff[0].params(truth)
    rc, rt = sim_c.dataset.standing[0], sim_t.dataset.standing[0]
    ok = np.all(np.isfinite(rt.quat), axis=1)
    from ftcal_nlp.core.geometry import quat_to_rotation, remove_yaw

    R_WB = quat_to_rotation(rt.quat[ok])
    dw = rt.wrench_array()[ok] - rc.wrench_array()[ok]
    off0 = np.zeros_like(truth.offsets)
    tot = balance_residual_exact(dw, R_WB, off0, truth.R, truth.p_prime, 0.0)  # W axes about the body CoM
    R_HB = remove_yaw(R_WB)
    f_B = np.einsum("nji,j->ni", R_HB, f_H)
    expect_B = -np.concatenate([f_B, np.cross(a - truth.com_body_m, f_B)], axis=1)
    expect_W = to_world(expect_B, R_WB)
    np.testing.assert_allclose(tot, expect_W, atol=1e-9)
    for a_, b_ in zip(sim_t.dataset.hanging, sim_c.dataset.hanging):  # the rig holds the body: the cable does not load the legs
        assert np.array_equal(a_.wrench_array(), b_.wrench_array())


# ----------------------------------------------------------------------------- numeric twins of the augmented balance


def _truth_x(problem: AugmentedProblem, cal: Calibration) -> np.ndarray:
    """The full model's decision vector at a calibration's transforms (rows of R_k, then p'_k)."""
    off, m, R, p = cal.stacked()
    return np.concatenate([R.reshape(len(R), 9).ravel(), p.ravel(), np.zeros(problem.n_eta)])


@pytest.mark.parametrize("balance", ["exact", "report"])
def test_augmented_residual_matches_physics(balance):
    sim, hang, poses, st = session("none")
    truth, robot = sim.truth, sim.dataset.robot
    pb = AugmentedProblem("full", truth, robot, balance)
    rcom = np.stack([truth.legs[k].com(poses.phi[:, i]) for i, k in enumerate(robot.legs)], axis=1)
    data = StandingData(poses.w_m, poses.R_WB[:, 2, :], poses.R_WB, np.zeros(poses.n), poses.w_m, poses.phi, rcom,
                        robot.nominal_rotations()[:, 2, :])
    Phi = pb.design(data)
    r = to_world(pb.residuals(_truth_x(pb, truth), Phi), poses.R_WB)
    if balance == "exact":
        ref = balance_residual_exact(poses.w_m, poses.R_WB, *[truth.stacked()[i] for i in (0, 2, 3)], truth.body_weight_N)
    else:
        ref = balance_residual_report(poses.w_m, poses.phi, poses.R_WB, truth)
    np.testing.assert_allclose(r, ref, atol=1e-9)


def test_effect_faces_reproduce_their_injected_physics():
    """With the injected parameters, each standing face's correction undoes its injector on the
    pose readings (first order: to within the square of the effect's relative size)."""
    sim, hang, poses, st = session("none")
    truth, robot = sim.truth, sim.dataset.robot
    rcom = np.stack([truth.legs[k].com(poses.phi[:, i]) for i, k in enumerate(robot.legs)], axis=1)
    base = StandingData(poses.w_m, poses.R_WB[:, 2, :], poses.R_WB, np.zeros(poses.n), poses.w_m, poses.phi, rcom, robot.nominal_rotations()[:, 2, :])
    off = truth.stacked()[0]
    # robot mass: readings of a robot 0.1 kg lighter than robot.toml says
    light = replace(truth, mass_kg=truth.mass_kg + 0.1)
    pb = AugmentedProblem("full", light, robot, "exact", LIBRARY["robot_mass"])
    x = _truth_x(pb, light)
    x[-1] = 1.0  # dM = 0.1 kg
    r = to_world(pb.residuals(x, pb.design(base)), poses.R_WB)
    ref = balance_residual_exact(poses.w_m, poses.R_WB, off, truth.stacked()[2], truth.stacked()[3], truth.body_weight_N)
    np.testing.assert_allclose(r, ref, atol=1e-9)
    # sensor nonlinearity: readings w_o + w_a + q w_a^2 undone by q
    q = np.array([0.3, -0.2, 0.5, 0.4, -0.3, 0.2])  # percent at the reference load
    qr = 0.01 * q / np.array([20.0] * 3 + [2.0] * 3)
    wa = poses.w_m - off
    nl = replace(base, w=off + wa + qr * wa**2)
    pb = AugmentedProblem("full", truth, robot, "exact", LIBRARY["sensor_nonlinearity"])
    x = _truth_x(pb, truth)
    x[-12:-6] = q           # shared per axis (the vertical one unused) ...
    x[-18:-12] = q[2]       # ... and each leg's vertical axis (ft z for BigAnt); the offset shift (last 6) stays 0
    r = to_world(pb.residuals(x, pb.design(nl)), poses.R_WB)
    resid_size = np.abs(qr * wa**2).max() * np.abs(2 * qr * wa).max()  # second-order remainder
    np.testing.assert_allclose(r, ref, atol=6 * resid_size + 1e-9)


def test_a_face_that_is_not_linear_in_the_features_is_refused():
    from ftcal_nlp.effects import Effect, ParamBlock

    class Squares(Effect):
        name = "bad"

        def standing_params(self, ctx):
            return ParamBlock(("q",))

        def standing(self, eta, pose, ctx):
            return [w - eta[0] * w**2 for w in pose.w], None, None  # w**2 is not a feature symbol

    sim, hang, poses, st = session("none")
    with pytest.raises(ValueError, match="not linear in the pose features"):
        AugmentedProblem("full", sim.truth, sim.dataset.robot, "exact", Squares())


# ----------------------------------------------------------------------------- linear faces and the design check


def test_linear_face_recovers_a_known_coefficient():
    rng = np.random.default_rng(0)
    legs = []
    beta = 0.7
    for k in range(3):
        n = 3000
        t = np.arange(n) * 0.01
        phi = 0.3 * t
        X = np.zeros((n, 6, 1))
        X[:, 0, 0] = np.cos(phi)
        e = X[:, :, 0] * beta + rng.normal(0, 0.05, (n, 6))
        legs.append(HangingLeg(f"L{k}", k, e, t, phi, np.full(n, 0.3), np.zeros(n, int), np.zeros((n, 3)), np.zeros((n, 3)),
                               np.zeros((n, 3)), 6.0, 9.81, 0.0, np.array([0, 0, 1.0])))
    series = LegSeries(legs, np.full((3, 6), 0.05), "test")
    face = LinearFace([np.concatenate([np.cos(l.phi)[:, None, None], np.zeros((len(l.t), 5, 1))], axis=1) for l in legs], ("b",), False)
    sc, b = score_linear(series, face, folds=5)
    se = 0.05 / np.sqrt(0.5 * 9000)  # noise sd / sqrt(sum cos^2) over the three legs
    assert abs(b[0] - beta) < 4 * se
    assert sc.explained > 0.99 and sc.delta_bic < -1000 and sc.dof == 1
    # the same on pure noise: nothing explained, BIC pays for the parameter
    noise = LegSeries([replace(l, e=rng.normal(0, 0.05, l.e.shape)) for l in legs], series.floor, "test")
    sc0, _ = score_linear(noise, face, folds=5)
    assert sc0.delta_bic > 0


def test_design_check_finds_a_common_tilt_only_when_there_is_one():
    rng = np.random.default_rng(5)
    R_nom = np.stack([np.eye(3)] * 6)
    scatter = rotvec_to_rotation(rng.normal(0, np.radians(0.9), (6, 3)))
    common = rotvec_to_rotation(np.radians([2.5, -1.0, 0.0]))
    with_bias = design_check(common @ scatter, R_nom)
    without = design_check(scatter, R_nom)
    assert with_bias["delta_bic"] < -10 and without["delta_bic"] > -10
    err = np.degrees(rotation_to_rotvec(common))[:2] - with_bias["tilt_deg"]
    assert np.all(np.abs(err) < 4 * with_bias["tilt_se_deg"])


# ----------------------------------------------------------------------------- the diagnosis


def test_clean_data_say_none():
    d = diagnosis("none")
    assert d.verdict == "none" and d.effect is None and d.where["recordings"] == []
    # the held-out residual sits at the data-derived floor (within the sampling error of ~P poses)
    P = session("none")[2].n
    ratio = np.asarray(d.shrinkage["heldout_rms_before"]) / np.asarray(d.shrinkage["noise_floor"])
    assert np.all(ratio < 1 + 4 * np.sqrt(1 / (2 * P)) + 0.15), ratio


@pytest.mark.parametrize("effect", HEXAPOD)
def test_each_effect_alone_is_named(effect):
    d = diagnosis(effect)
    assert d.verdict == "effect" and d.effect == effect, (d.verdict, d.effect, d.ranking[:3], d.gaps)
    assert d.ranking[0]["effect"] == effect
    b, a, f = (np.asarray(d.shrinkage[k]) for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"))
    if effect == "mocap_bias":
        # Free rotations absorb it exactly (held-out residual at the floor); the fitted frames
        # share its tilt: R_k -> R_b^T R_k, so their common tilt is minus the bias.
        assert set(d.gaps) == {"design"}
        inj = session(effect)[0].config.effects[0]
        beta = np.degrees(rotation_to_rotvec(inj.rotation()))[:2]
        assert np.all(np.abs(d.design["tilt_deg"] + beta) < 4 * d.design["tilt_se_deg"]), (d.design, beta)
        return
    worst = int(np.argmax(b / f))
    assert b[worst] > 1.2 * f[worst], "a named effect must have had a gap to explain"
    if effect == "gain_crosstalk":
        # Standing poses determine the gains along the loaded axes; the crosstalk comes from the four hanging
        # directions (the joint refit holds it there). Against the honest floor (floor.py) the joint model
        # brings fz from 0.92 to ~0.03 N (floor 0.008 N): most of the gap, not all of it (issue 13 stays open).
        assert a[worst] < 0.1 * b[worst], (b, a, f)
        return
    assert a[worst] < 0.5 * b[worst] and a[worst] < 2.0 * f[worst], (b, a, f)


def test_diagnosis_json_follows_the_contract(tmp_path):
    d = diagnosis("casing_load")
    js = json.loads(json.dumps(d.to_json_dict()))  # serialisable
    assert js["verdict"] in ("none", "effect", "unexplained") and js["effect"] == "casing_load"
    assert set(js["where"]) == {"recordings", "legs", "components", "explains"}
    assert js["where"]["explains"] in ("time", "shaft_angle", "load", "body_tilt", "shaft_speed", "pose_history", None)
    assert set(js["where"]["components"]) <= {"fx", "fy", "fz", "tx", "ty", "tz"}
    assert "standing" in js["where"]["recordings"] and "hanging" in js["where"]["recordings"]
    assert js["where"]["explains"] == "shaft_angle" and js["where"]["components"]
    for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"):
        assert len(js["shrinkage"][k]) == 6 and all(np.isfinite(js["shrinkage"][k]))
    # the candidates that apply to a hexapod dataset, each once (free-load-only units are not rows)
    assert sorted(r["effect"] for r in js["ranking"]) == sorted(HEXAPOD) and set(HEXAPOD) < set(LIBRARY)
    for r in js["ranking"]:
        assert set(r) >= {"effect", "delta_bic", "heldout_rms_after"} and len(r["heldout_rms_after"]) == 6
    bics = [r["delta_bic"] for r in js["ranking"] if r["delta_bic"] is not None and r["status"] == "ok"]
    assert bics == sorted(bics)
    # the named effect's fitted parameters come with standard errors (results protocol of the diagnosis' fit)
    assert d.verdict == "effect" and d.effect_fit is not None and len(js["effect_parameters"]) == len(d.effect_fit.effect_params)
    assert all(v["se"] is None or v["se"] > 0 for v in js["effect_parameters"].values())
    assert d.effect_fit.cov_params().shape == (len(d.effect_fit.params),) * 2 and "±" in d.effect_fit.summary().as_text()
    # hexapod datasets name one effect: `effects` is that one, with the same parameters and the shrinkage's RMS after
    assert [e["name"] for e in js["effects"]] == ["casing_load"] and js["effects"][0]["parameters"] == js["effect_parameters"]
    assert js["effects"][0]["heldout_rms_after"] == js["shrinkage"]["heldout_rms_after"]
    from ftcal_nlp.report.diagnosis import diagnosis_section

    sec = diagnosis_section(d, tmp_path)
    # shrinkage, the joint refit with the named effect, ranking, kinds, and the per-leg checks when a leg
    # stands out (a table) or not (a sentence)
    assert sec.title and sec.text and len(sec.tables) == 3 + (d.joint is not None) + bool(d.perleg.findings)
    assert d.joint is not None and "joint_refit" in js
    assert "noise_floor_parts" in js and js["noise_floor_parts"]
    for name, path in sec.figures:
        assert path.is_file() and path.stat().st_size > 5000, name
    assert "casing_load" in d.summary()


def test_localisation_finds_the_leg_of_a_one_leg_effect():
    """Casing load on one leg only: the hanging residual points at that leg."""
    from ftcal_nlp.effects.casing_load import CasingLoadInjector

    class OneLeg(CasingLoadInjector):
        def matrices(self, K):
            M = np.zeros((K, 2, 2))
            M[2] = [[self.scale, 0.0], [0.0, self.scale]]
            return M

    cfg = replace(SimConfig.from_dict({**SMALL, "n_poses": 60, "seed": SEED + 1, "walk_cycles": 0.0}), effects=(OneLeg(scale=0.8),))
    sim = simulate(cfg)
    ds = sim.dataset
    hang = fit_hanging(ds.hanging, ds.robot)
    poses = Poses.concat([extract_poses(r, ds.robot) for r in ds.standing])
    st = fit_standing(poses, hang.to_calibration(ds.robot), ds.robot, model="full")
    d = diagnose(ds, hang, poses, st.calibration, ds.robot, DiagnoseSettings(folds=FOLDS, effects=("casing_load", "offset_drift", "leg_inertia")), x_start=st.x)
    assert d.effect == "casing_load"
    loc = d.localisation["hanging"]
    assert int(np.nanargmax(loc.leg_excess)) == 2 and loc.top == "shaft_angle"
    from ftcal_nlp.diagnose.localise import legs_with_gap

    assert legs_with_gap(loc, ds.robot.legs, 0.1) == [ds.robot.legs[2]]


@requires_sample
def test_sample_dataset_has_no_gap():
    """The sample written by someone else (effect "none"): no gap, no false alarm."""
    ds = read_dataset(SAMPLE / "dataset.toml")
    hang = fit_hanging(ds.hanging, ds.robot)
    poses = Poses.concat([extract_poses(r, ds.robot) for r in ds.standing])
    st = fit_standing(poses, hang.to_calibration(ds.robot), ds.robot, model="full")
    d = diagnose(ds, hang, poses, st.calibration, ds.robot, DiagnoseSettings(folds=FOLDS), x_start=st.x)
    assert d.verdict == "none", (d.gaps, d.kinds, d.ranking[:3])


# ----------------------------------------------------------------------------- the validation's plan and bad input


def test_validation_plan_is_deterministic_and_balanced():
    cfg = {"n_datasets": 26, "seed": 3, "effects": None, "clean_share": 0.15, "magnitude": "realistic"}
    a, b = plan(cfg), plan(cfg)
    assert a == b
    labels = [x["effect"] for x in a]
    assert labels.count("none") == 4 and all(labels.count(e) == 2 for e in HEXAPOD) and set(labels) == {"none", *HEXAPOD}
    for x in a:
        if x["effect"] != "none":
            lo, hi = LIBRARY[x["effect"]].magnitude.realistic
            assert lo <= x["scale"] <= hi
    with pytest.raises(ValueError, match="unknown effect"):
        plan({**cfg, "effects": ["tether"]})
    with pytest.raises(ValueError, match="unknown key"):
        run_validation({"n_dataset": 2}, "/nonexistent", calibrate)


def test_the_docs_quote_the_chain_thresholds_from_the_settings():
    """``docs/diagnosis.md``'s table of the chain's thresholds is ``DiagnoseSettings``' (one set of names, a value per
    kind of evidence): a threshold changed in ``settings.py`` and not in the docs fails here."""
    from dataclasses import fields

    from ftcal_nlp.core.settings import ChainThresholds, DiagnoseSettings

    text = (Path(__file__).resolve().parent.parent / "docs" / "diagnosis.md").read_text()
    table = text.split("<!-- chain thresholds: settings.DiagnoseSettings -->", 1)[1].strip().split("\n\n", 1)[0]
    rows = {cells[0].strip("` "): cells for cells in ([c.strip() for c in ln.strip("|").split("|")]
                                                        for ln in table.splitlines()[2:])}
    s = DiagnoseSettings()
    assert set(rows) == {f.name for f in fields(ChainThresholds)}
    for name, cells in rows.items():
        assert float(cells[2]) == getattr(s.hexapod, name) and float(cells[3]) == getattr(s.free_loads, name), name
