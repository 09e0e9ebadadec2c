"""Several effects on hexapod datasets (issue 23, item 2; ``diagnose/hexchain.py``, ``effects/combined.py``).

* stacked linear faces: one face stacked alone scores exactly as itself; two faces (one per leg, one shared) recover
  both known coefficients within 4 se, and the rebased score says what the second adds beside the first;
* the combined standing face: the corrections of two effects add up (numeric check of the augmented residual);
* the paired block-wise z: large for a real saving, small for noise;
* end to end on small simulated sessions: two effects injected together are both named in the chain, each with
  parameters and se and the held-out RMS after it; a single effect is named alone (no false second), and the
  diagnosis.json / report carry the chain.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from ftcal_nlp.diagnose.hexchain import paired_z
from ftcal_nlp.core.settings import HexapodChain

HEX = HexapodChain()   # the hexapod chain's thresholds (DiagnoseSettings.hexapod)
Z_MIN = HEX.z_min
from ftcal_nlp.diagnose.linear_fit import rebase, score_linear
from ftcal_nlp.diagnose.scores import KindScore
from ftcal_nlp.diagnose.views import LegSeries
from ftcal_nlp.effects import EFFECTS, HangingLeg, LinearFace
from ftcal_nlp.effects.combined import Combined
from ftcal_nlp.effects.faces import per_leg_face, stack_faces

SD = 0.05


def _series(rng, beta_leg: np.ndarray, beta_shared: float, n: int = 2000, K: int = 3):
    """K legs; the residual is a per-leg cos(phi) on fx (``beta_leg[k]``) plus a shared sin(phi) on fy, plus noise."""
    legs = []
    for k in range(K):
        t = np.arange(n) * 0.01
        phi = 0.37 * t + k
        e = rng.normal(0, SD, (n, 6))
        e[:, 0] += beta_leg[k] * np.cos(phi)
        e[:, 1] += beta_shared * np.sin(phi)
        legs.append(HangingLeg(f"L{k}", k, e, t, phi, np.full(n, 0.37), np.zeros(n, int), np.zeros((n, 3)), np.zeros((n, 3)),
                               np.zeros((n, 3)), 6.0, 9.81, 0.0, np.array([0, 0, 1.0])))
    return LegSeries(legs, np.full((K, 6), SD), "hanging")


def _faces(legs):
    def cos_fx(l):
        X = np.zeros((len(l.t), 6, 1))
        X[:, 0, 0] = np.cos(l.phi)
        return X

    per = per_leg_face(legs, cos_fx, ("c",))
    shared = LinearFace([np.concatenate([np.zeros((len(l.t), 1, 1)), np.sin(l.phi)[:, None, None], np.zeros((len(l.t), 4, 1))], axis=1)
                         for l in legs], ("s",), False)
    return per, shared


def test_one_face_stacked_alone_scores_as_itself():
    rng = np.random.default_rng(1)
    series = _series(rng, np.array([0.3, -0.2, 0.5]), 0.0)
    per, _ = _faces(series.legs)
    a, ba = score_linear(series, per, folds=5)
    st = stack_faces([("x", per)], series.legs)
    b, bb = score_linear(series, st, folds=5)
    assert st.names == ("x:L0.c", "x:L1.c", "x:L2.c") and st.cols is not None
    np.testing.assert_allclose(bb, ba, rtol=1e-12)
    for f in ("z_after", "rss_after", "dof"):
        assert getattr(b, f) == pytest.approx(getattr(a, f), rel=1e-12), f
    np.testing.assert_allclose(b.blocks_after, a.blocks_after, rtol=1e-12)


def test_two_stacked_faces_recover_both_and_the_second_is_scored_beside_the_first():
    rng = np.random.default_rng(2)
    beta_leg, beta_shared = np.array([0.3, -0.2, 0.5]), 0.15
    series = _series(rng, beta_leg, beta_shared)
    per, shared = _faces(series.legs)
    both = stack_faces([("a", per), ("b", shared)], series.legs)
    sc, beta = score_linear(series, both, folds=5)
    n = len(series.legs[0].t)
    se_leg, se_shared = SD / np.sqrt(0.5 * n), SD / np.sqrt(0.5 * 3 * n)
    assert np.all(np.abs(beta[:3] - beta_leg) < 4 * se_leg) and abs(beta[3] - beta_shared) < 4 * se_shared
    assert sc.dof == 4
    first = score_linear(series, stack_faces([("a", per)], series.legs), folds=5)[0]
    second = rebase(sc, first)
    # beside the first face the second removes nearly all that is left (a sine of 0.15 against noise of 0.05)
    assert second.dof == 1 and second.explained > 0.95 and paired_z(second) > 10
    # on noise the second face adds nothing: z small, no saving
    noise = _series(np.random.default_rng(3), beta_leg, 0.0)
    per_n, shared_n = _faces(noise.legs)
    s1 = score_linear(noise, stack_faces([("a", per_n)], noise.legs), folds=5)[0]
    s2 = rebase(score_linear(noise, stack_faces([("a", per_n), ("b", shared_n)], noise.legs), folds=5)[0], s1)
    assert paired_z(s2) < 3 and s2.explained < 0.05


def test_paired_z_of_blocks():
    rng = np.random.default_rng(4)
    b0 = rng.chisquare(6, 200)
    k = lambda b1: KindScore("standing", np.ones(6), np.ones(6), np.ones(6), b0.sum(), b1.sum(), 1.0, 1.0, 1200, 1, b0, b1)  # noqa: E731
    assert paired_z(k(0.5 * b0 * rng.uniform(0.8, 1.2, 200))) > 20
    assert abs(paired_z(k(b0 * rng.uniform(0.8, 1.2, 200)))) < 3
    assert np.isnan(paired_z(replace(k(b0), blocks_before=None)))


def test_combined_standing_face_adds_the_corrections():
    import casadi as ca

    from ftcal_nlp.effects import AugContext, pose_symbols

    K = 6
    legs = tuple(f"L{k}" for k in range(K))
    ctx = AugContext(legs, [ca.DM(np.zeros(6))] * K, np.stack([np.eye(3)] * K), np.full(K, 6.0), 9.81)
    drift, casing = EFFECTS["offset_drift"], EFFECTS["casing_load"]
    both = Combined([drift, casing])
    assert both.name == "offset_drift+casing_load" and both.shifts_offsets
    blk = both.standing_params(ctx)
    m1, m2 = drift.standing_params(ctx).m, casing.standing_params(ctx).m
    assert blk.m == m1 + m2 and blk.names[0].startswith("offset_drift:") and blk.names[-1].startswith("casing_load:")
    d, pose = pose_symbols(K)
    eta = ca.SX.sym("eta", blk.m)
    c, z, e = both.standing(eta, pose, ctx)
    c1, _, e1 = drift.standing(eta[:m1], pose, ctx)
    c2, _, _ = casing.standing(eta[m1:], pose, ctx)
    f = ca.Function("f", [eta, d], [ca.vertcat(*c, e), ca.vertcat(*[a + b - w for a, b, w in zip(c1, c2, pose.w)], e1)])
    rng = np.random.default_rng(5)
    got, want = f(rng.normal(size=blk.m), rng.normal(size=d.numel()))
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=1e-12)
    # a hanging estimate held in the standing fit moves to the member's place in eta
    held = both.standing_from_hanging({"casing_load:L2.x_cos": 0.4}, ctx)
    own = casing.standing_from_hanging({"L2.x_cos": 0.4}, ctx)
    assert held == {m1 + i: v for i, v in own.items()}
    assert [m.name for m in both.joint_variants()[0].members] == ["offset_drift", "casing_load"]
    with pytest.raises(ValueError):
        Combined([drift, drift])


# ----------------------------------------------------------------------------- end to end

SMALL = {"n_poses": 100, "hanging_cycles": 2.0, "walk_cycles": 1.0}


def _calibrated(seed: int, effects: list[tuple[str, float]], library: tuple[str, ...] | None = None):
    """(sim, calibrate()'s result) of a SMALL session with ``effects`` injected, the diagnosis at 5 folds (exact balance)."""
    from ftcal_nlp.diagnose.validation import DEFAULTS, _settings
    from ftcal_nlp.pipeline import calibrate
    from ftcal_nlp.sim import SimConfig, simulate

    spec = [{"name": n, "scale": s, "seed": seed} for n, s in effects]
    sim = simulate(SimConfig.from_dict({**SMALL, "seed": seed, "effects": spec}))
    settings = _settings({**DEFAULTS, "folds": 5}, "exact")
    if library is not None:   # the candidates a user names (DiagnoseSettings.effects): a smaller library costs less
        settings = replace(settings, diagnose=replace(settings.diagnose, effects=library))
    return sim, calibrate(sim.dataset, settings)


def _diagnosis(seed: int, effects: list[tuple[str, float]], library: tuple[str, ...] | None = None):
    sim, run = _calibrated(seed, effects, library)
    return sim, run.diagnosis


def test_two_effects_are_both_named_with_parameters(tmp_path):
    """An offset drift and a casing load: both named, each with parameters and se, the joint refit recovers the casing
    load; and on the same run the chain's calibration corrects the walk closer to the truth than the first link's
    (``_check_the_chains_calibration_corrects_a_walk``, once ``test_effect_correction_chain.py``'s own smaller run of
    the same two effects with the candidates restricted to them: one calibrate() now checks both)."""
    sim, run = _calibrated(5, [("offset_drift", 4.0), ("casing_load", 1.5)])
    d = run.diagnosis
    js = json.loads(json.dumps(d.to_json_dict()))
    names = [e["name"] for e in js["effects"]]
    assert d.verdict == "effect" and set(names) == {"offset_drift", "casing_load"}, (names, js.get("chain"))
    assert js["effect"] == names[0]
    for e in js["effects"]:
        assert len(e["heldout_rms_after"]) == 6 and e["parameters"]
        assert all(v["se"] is None or v["se"] > 0 for v in e["parameters"].values())
    second = js["effects"][1]
    assert second["paired_z"] >= 3 and second["explained"] >= 0.5
    # the chain's end is the shrinkage's after; each link lowers the held-out RMS
    assert js["shrinkage"]["heldout_rms_after"] == second["heldout_rms_after"]
    assert np.mean(second["heldout_rms_after"]) < np.mean(js["effects"][0]["heldout_rms_after"])
    assert js["chain"]["stop"] and js["chain"]["rounds"]
    # the joint refit of both recovers the casing load's first harmonic on every leg (hanging face) within 4 se
    pars = d.chain.links[-1].joint.parameters
    legs = sim.dataset.robot.legs
    M = next(e for e in sim.config.effects if e.name == "casing_load").matrices(len(legs))
    z = [(pars[f"hanging:casing_load:{leg}.{a}_{f}"][0] - M[k, i, j]) / pars[f"hanging:casing_load:{leg}.{a}_{f}"][1]
         for k, leg in enumerate(legs) for i, a in enumerate("xy") for j, f in enumerate(("cos", "sin"))]
    assert np.all(np.abs(z) < 4), np.round(z, 1)
    from ftcal_nlp.report.diagnosis import diagnosis_section

    sec = diagnosis_section(d, tmp_path)
    assert any("in the order added" in t[0] for t in sec.tables)
    _check_the_chains_calibration_corrects_a_walk(sim, run, [t[0] for t in sec.tables], tmp_path)


BLOCKS = 10       # contiguous time blocks of the walk for the paired comparison
CHAIN_Z_MIN = 4.0  # the chain's correction is closer to the truth by this many se of the block-wise differences
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


def _errors(df, truth, legs):
    """Per-foot (N, K, 3) and total (N, 3) force errors of a corrected walk against the simulator's truth."""
    cols = [f"{k}_{c}" for k in legs for c in WRENCH[:3]]
    foot = (df[cols].to_numpy() - truth[cols].to_numpy()[: len(df)]).reshape(len(df), len(legs), 3)
    tc = [f"total_{c}" for c in WRENCH[:3]]
    return foot, df[tc].to_numpy() - truth[tc].to_numpy()[: len(df)]


def _blocks_z(s0: np.ndarray, s1: np.ndarray) -> float:
    """``mean(d) / se(d)`` of the block means ``d_b`` of ``s0 - s1`` (per-sample scores) over contiguous blocks."""
    d = np.array([b.mean() for b in np.array_split(s0 - s1, BLOCKS)])
    return float(d.mean() / (d.std(ddof=1) / np.sqrt(len(d))))


def _check_the_chains_calibration_corrects_a_walk(sim, run, captions, tmp_path):
    """``calibration_with_effect.json`` after the hexapod chain (issue 23, item 2; moved here from
    ``test_effect_correction_chain.py``, whose end-to-end test ran a smaller session of the same two effects): the chain
    names both, and the file (the chain's last joint refit) corrects the walk closer to the truth than the first link's
    joint calibration (one effect), per foot and in total: the squared force errors in units of the readings' noise
    floor, compared block by block over the walk, fall by ``CHAIN_Z_MIN`` se at least."""
    from ftcal_nlp.core.calibration import Calibration
    from ftcal_nlp.correct import correct_recording
    from ftcal_nlp.run import effect_calibration, last_joint

    d = run.diagnosis
    assert {e["name"] for e in d.effects_list()} == {"offset_drift", "casing_load"}, (d.effects_list(), d.chain)
    assert last_joint(d) is d.chain.links[-1].joint and last_joint(d) is not d.joint
    path = tmp_path / "calibration_with_effect.json"
    effect_calibration(run).save(path)
    cal = Calibration.load(path)
    blk = cal.meta["effect"]
    assert blk["name"] == d.chain.links[-1].joint.effect and {m["name"] for m in blk["members"]} == {"offset_drift", "casing_load"}
    # the calibration's covariance file stands in where the error model is the calibration's; either way the note says
    # which effects the joint refit had
    assert run.uncertainty is not None
    assert ("covariance_file" in cal.meta) == (cal.model == run.calibration.model)
    assert all(n in cal.meta["covariance_note"] for n in ("offset_drift", "casing_load")), cal.meta["covariance_note"]
    first = d.joint.calibration
    assert first.meta["effect"]["name"] == d.effect and "members" not in first.meta["effect"]
    rec, legs = sim.dataset.walking[0], cal.leg_names
    floor = d.joint.kinds["hanging"].floor[:3]              # the readings' noise per force component
    out_chain, out_first = correct_recording(cal, rec), correct_recording(first, rec)
    assert np.all(np.isfinite(out_chain[[f"{k}_fx_se" for k in legs]].to_numpy()))
    (f1, t1), (f0, t0) = _errors(out_chain, sim.walk_truth, legs), _errors(out_first, sim.walk_truth, legs)
    foot = [((f / floor) ** 2).mean(axis=(1, 2)) for f in (f0, f1)]
    total = [((t / (np.sqrt(len(legs)) * floor)) ** 2).mean(axis=1) for t in (t0, t1)]
    z_foot, z_total = _blocks_z(*foot), _blocks_z(*total)
    rms = lambda f: np.sqrt((f**2).reshape(len(f), -1, 3).mean(axis=(0, 1)))   # noqa: E731
    assert z_foot >= CHAIN_Z_MIN and z_total >= CHAIN_Z_MIN, (z_foot, z_total, rms(f0), rms(f1), rms(t0), rms(t1))
    # the report says what the file holds
    assert any("holds the chain's last joint refit" in c and all(n in c for n in ("offset_drift", "casing_load")) for c in captions), captions


def test_a_single_effect_grows_no_second():
    _, d = _diagnosis(7, [("casing_load", 1.5)])
    assert d.effect == "casing_load" and [e["name"] for e in d.effects_list()] == ["casing_load"], d.chain


def test_the_stated_test_and_the_joint_check():
    """``passes``: z, saving and the design gap as stated; ``gap_left`` / ``joint_better`` on joint refits' kinds."""
    from types import SimpleNamespace

    from ftcal_nlp.diagnose.hexchain import JOINT_MIN, gap_left, joint_better, kind_threshold, passes
    from ftcal_nlp.diagnose.refit import KindRefit

    rng = np.random.default_rng(6)
    b0 = rng.chisquare(6, 100) * 3.0

    def ks(b1):
        return KindScore("standing", np.ones(6), np.ones(6), np.ones(6), b0.sum(), b1.sum(), 1.0, 1.0, 600, 6, b0, b1)

    good = SimpleNamespace(kinds={"standing": ks(b0 / 2.5)}, design=None)
    assert passes(good, {"standing": 2.0}, HEX)[0]
    noise = SimpleNamespace(kinds={"standing": ks(b0 * rng.uniform(0.9, 1.1, 100))}, design=None)
    assert not passes(SimpleNamespace(kinds={"walking swing": ks(b0 / 2.5)}, design=None), {"walking swing": 2.0}, HEX)[0]
    ok, why, kind, z = passes(noise, {"standing": 2.0}, HEX)
    assert not ok and "paired block-wise z" in why and kind == "standing"
    tiny = SimpleNamespace(kinds={"standing": ks(b0 - 0.01 * b0.mean())}, design=None)  # significant, not material
    ok, why, _, _ = passes(tiny, {"standing": 2.0}, HEX)
    assert not ok and "floor's variance" in why
    tilt = SimpleNamespace(kinds={}, design={"delta_bic": -20.0})
    assert passes(tilt, {"design": 2.0}, HEX)[:3] == (True, "", "design")
    assert not passes(SimpleNamespace(kinds={}, design=None), {"standing": 2.0}, HEX)[0]

    fl = np.full(6, 0.1)
    refit = lambda **kinds: SimpleNamespace(kinds={k: KindRefit(k, fl, fl * r, fl, 100) for k, r in kinds.items()})  # noqa: E731
    assert kind_threshold("standing", 100) == pytest.approx(max(0.5, 4 * np.sqrt(2 / 100)))
    # the walking swing kind is no evidence of a gap left (module docstring)
    assert gap_left(refit(standing=1.1, hanging=1.2, **{"walking swing": 3.0})) == {"hanging": pytest.approx(0.44)}
    cur = refit(standing=2.0, hanging=1.0)
    assert joint_better(cur, refit(standing=1.2, hanging=1.0), "standing") == (True, "")
    e1 = (1.0 - JOINT_MIN) * 3.0 + 1.0   # excess just above what the check allows
    assert not joint_better(cur, refit(standing=np.sqrt(e1 + 0.01), hanging=1.0), "standing")[0]
    ok, why = joint_better(cur, refit(standing=1.0, hanging=2.0), "standing")
    assert not ok and "hanging" in why
    swing = {"walking swing": 1.0}
    assert joint_better(refit(standing=2.0, hanging=1.0, **swing), refit(standing=1.0, hanging=1.0, **{"walking swing": 9.0}), "standing")[0]


def test_held_out_evidence_where_the_joint_refit_left_its_gap():
    """``held_out_evidence``: candidates with paired z >= Z_MIN and a material saving on a kind the joint refit left a
    gap on, largest z first; noise, immaterial savings, other kinds, failed or excluded candidates are not tried."""
    from types import SimpleNamespace

    from ftcal_nlp.diagnose.hexchain import held_out_evidence

    rng = np.random.default_rng(8)
    b0 = rng.chisquare(6, 100) * 3.0

    def ks(b1):
        return KindScore("standing", np.ones(6), np.ones(6), np.ones(6), b0.sum(), b1.sum(), 1.0, 1.0, 600, 6, b0, b1)

    def cand(name, kinds, status="ok"):
        return SimpleNamespace(effect=name, kinds=kinds, status=status, model_effect=object())

    strong = cand("a", {"standing": ks(b0 / 3.0 * rng.uniform(0.8, 1.2, 100))})
    weaker = cand("b", {"standing": ks(b0 / 1.3 * rng.uniform(0.8, 1.2, 100))})
    noise = cand("c", {"standing": ks(b0 * rng.uniform(0.9, 1.1, 100))})
    tiny = cand("d", {"standing": ks(b0 - 0.01 * b0.mean())})
    elsewhere = cand("e", {"hanging": ks(b0 / 3.0)})
    failed = cand("f", {"standing": ks(b0 / 3.0)}, status="failed: x")
    att = SimpleNamespace(scores=[weaker, noise, tiny, elsewhere, failed, strong])
    got = held_out_evidence(att, {"standing": 7.7}, set(), HEX)
    assert [t[0].effect for t in got] == ["a", "b"] and all(t[1] == "standing" and t[2] >= Z_MIN and t[3] == "held-out" for t in got)
    assert got[0][2] > got[1][2]
    assert [t[0].effect for t in held_out_evidence(att, {"standing": 7.7}, {"a"}, HEX)] == ["b"]
    assert held_out_evidence(att, {"hanging": 1.0}, set(), HEX)[0][0].effect == "e"
    assert held_out_evidence(att, {}, set(), HEX) == []


def _refit(blocks: dict, n_par: int):
    """A joint refit's stand-in: per kind the held-out blocks (floor units, 6 components each) and the RMS they make."""
    from types import SimpleNamespace

    from ftcal_nlp.diagnose.refit import KindRefit

    fl = np.full(6, 0.1)
    kinds = {k: KindRefit(k, fl, fl * np.sqrt(np.mean(b) / 6.0), fl, len(b), np.asarray(b, float)) for k, b in blocks.items()}
    return SimpleNamespace(kinds=kinds, parameters={f"p{i}": (0.0, 1.0) for i in range(n_par)})


def test_a_swap_passes_when_significant_or_with_fewer_parameters():
    """``swap_better``: the joint check on a kind of the gap, and a paired z >= Z_MIN or fewer parameters; an alternative
    that predicts worse, or spoils another kind, never passes. ``choose_swap``: the least excess, then of those it does
    not beat by Z_MIN the fewest parameters."""
    from ftcal_nlp.diagnose.hexchain import blocks_z, choose_swap, excess, swap_better

    rng = np.random.default_rng(11)
    P = 100
    floor_like = rng.chisquare(6, P)                       # a model at the floor: mean 6 per pose
    hang = rng.chisquare(6, 30)
    # the current model: at the floor on most poses, far off on a few held-out poses (a many-parameter face's scatter)
    cur_b = floor_like * rng.lognormal(0.0, 0.8, P)
    cur_b[:5] *= 60.0
    cur = _refit({"standing": cur_b, "hanging": hang}, 54)
    left = {"standing": excess(cur.kinds["standing"])}
    assert left["standing"] > 2.0
    alt_b = floor_like
    assert blocks_z(cur_b, alt_b) < Z_MIN          # the premise: heavy-tailed, not significant by the paired test
    ok, kind, z = swap_better(cur, _refit({"standing": alt_b, "hanging": hang}, 1), left, HEX)
    assert ok and kind == "standing" and z < Z_MIN
    # the same fall with more parameters needs the paired test
    assert not swap_better(cur, _refit({"standing": alt_b, "hanging": hang}, 60), left, HEX)[0]
    # a consistent fall passes it whatever the parameters
    steady = _refit({"standing": cur_b / 3.0 * rng.lognormal(0.0, 0.5, P), "hanging": hang}, 60)
    ok, kind, z = swap_better(cur, steady, left, HEX)
    assert ok and kind == "standing" and Z_MIN <= z < 50
    # fewer parameters but no better held out; or better there and worse on the hanging legs
    assert not swap_better(cur, _refit({"standing": cur_b * 1.01, "hanging": hang}, 1), left, HEX)[0]
    assert not swap_better(cur, _refit({"standing": alt_b, "hanging": hang * 3.0}, 1), left, HEX)[0]
    # choose: the least excess (a), and of those a does not beat by Z_MIN the fewest parameters (b, not the worse c)
    a = (0, "a", _refit({"standing": alt_b, "hanging": hang}, 20), "standing", 5.0)
    b = (1, "b", _refit({"standing": alt_b * rng.lognormal(0.0, 0.3, P), "hanging": hang}, 6), "standing", 5.0)
    c = (1, "c", _refit({"standing": alt_b * 1.6 * rng.lognormal(0.0, 0.3, P), "hanging": hang}, 1), "standing", 5.0)
    assert blocks_z(b[2].kinds["standing"].blocks, alt_b) < Z_MIN <= blocks_z(c[2].kinds["standing"].blocks, alt_b)
    assert choose_swap([c, a, b], HEX)[1] == "b"
    assert choose_swap([c], HEX)[1] == "c" and choose_swap([], HEX) is None
    # a refit that lost a kind (its standing fit failed) never passes
    assert not swap_better(cur, _refit({"hanging": hang}, 1), left, HEX)[0]
    # parameters held at their hanging estimates (se 0) or undetermined (se inf) are not spent
    from types import SimpleNamespace

    from ftcal_nlp.diagnose.hexchain import n_parameters
    assert n_parameters(SimpleNamespace(parameters={"a": (1.0, 0.1), "b": (1.0, 0.0), "c": (0.0, np.inf)})) == 1


def test_a_swap_names_the_pair_the_greedy_first_step_aliased():
    """A hysteresis and a weighing error together: the first step names gain_crosstalk (a common gain of every leg's
    force channel along up is a robot mass error in the standing balance), the chain adds the hysteresis beside it, and
    the swap replaces the crosstalk's 54 parameters by the robot mass, which predicts the held-out poses better. Both
    named; the mass error recovered within 4 se; the swap in diagnosis.json and the statement."""
    from ftcal_nlp.diagnose.validation import INJECTORS

    hi = {n: float(INJECTORS[n].magnitude.realistic[1]) for n in ("hysteresis", "robot_mass")}
    # the library: the pair and the candidates that explain the whole gap on their own here (as gain_crosstalk does)
    lib = ("gain_crosstalk", "hysteresis", "robot_mass", "tether_force", "sensor_nonlinearity")
    sim, d = _diagnosis(87, [("hysteresis", hi["hysteresis"]), ("robot_mass", hi["robot_mass"])], lib)
    js = json.loads(json.dumps(d.to_json_dict()))
    names = [e["name"] for e in js["effects"]]
    assert set(names) == {"hysteresis", "robot_mass"} and js["effect"] == names[0], (names, js["chain"])
    sw = js["chain"]["swaps"]
    assert [(s["out"], s["in"]) for s in sw] == [("gain_crosstalk", "robot_mass")]
    assert sw[0]["excess_after"]["standing"] < sw[0]["excess_before"]["standing"]
    assert js["effects"][-1]["found_by"] == "swap"
    assert any("is swapped out" in line for line in js["statement"])
    # the ranking's first was swapped out: the first that stands is the hysteresis, with its attribution's parameters
    assert js["effect"] == "hysteresis" and js["effects"][0]["parameters"] and js["effects"][0]["found_by"] == "ranking"
    assert any(line.startswith("First hysteresis") for line in js["statement"])
    # the refit's mass error: stated minus true (robot.toml says mass_kg +- scale)
    v, se = d.chain.links[-1].parameters["dM [0.1 kg]"]
    err = sim.dataset.robot.mass_kg - sim.true_robot.mass_kg
    assert abs(0.1 * v - err) < 4 * 0.1 * se, (0.1 * v, 0.1 * se, err)


def test_the_rebuild_after_a_swap_reuses_refits_and_reports_a_failed_one(monkeypatch):
    """``_rebuild_links``: nested refits in the order the effects stand, a refit already made reused (no solve), the
    new first's link when the ranking's first was swapped out, a link tested beside an effect since swapped out says
    so (``beside``); a prefix refit that fails leaves the whole chain's refit on that link and is said in ``stop``."""
    from types import SimpleNamespace

    from ftcal_nlp.diagnose import hexchain as H
    from ftcal_nlp.diagnose.refit import KindRefit
    from ftcal_nlp.core.solver import SolverError

    a, b, c = EFFECTS["hysteresis"], EFFECTS["robot_mass"], EFFECTS["offset_drift"]
    fl = np.full(6, 0.1)

    def refit(rms, **pars):
        return SimpleNamespace(kinds={"standing": KindRefit("standing", fl * 3, fl * rms, fl, 100, np.ones(100))},
                               parameters=pars, effect="x", variant={})

    whole = refit(1.0, **{"hysteresis:h": (1.0, 0.1), "robot_mass:dM [0.1 kg]": (-2.0, 0.01), "offset_drift:d": (3.0, 0.3)})
    ab = refit(1.5, **{"hysteresis:h": (1.1, 0.1), "robot_mass:dM [0.1 kg]": (-2.1, 0.01)})
    tests = {"hysteresis": ("standing", 8.1, 0.78, -50.0, "held-out", ("gain_crosstalk",)),
             "robot_mass": ("standing", 2.8, 1.04, float("nan"), "swap", ("hysteresis",)),
             "offset_drift": ("standing", 5.0, 0.6, -30.0, "ranking", ("hysteresis", "robot_mass"))}
    refits = {("hysteresis", "robot_mass"): ab, ("hysteresis", "robot_mass", "offset_drift"): whole}

    def fails(*args, **kw):
        raise SolverError("IPOPT: Maximum_Iterations_Exceeded", "Maximum_Iterations_Exceeded")

    monkeypatch.setattr(H, "joint_refit", fails)
    ch = H.HexChain(stop="no gap above the floor is left after the joint refit")
    H._rebuild_links(ch, None, (a, b, c), "gain_crosstalk", refits, tests, "standing", None, None, None, None, "exact")
    # the first alone was never refit and its refit fails: the whole chain's, its own parameters taken out of it
    assert ch.first is not None and ch.first.name == "hysteresis" and ch.first.joint is whole
    assert ch.first.parameters == {"h": (1.0, 0.1)} and ch.first.beside == ("gain_crosstalk",)
    assert "the joint refit of hysteresis failed" in ch.stop and "Maximum_Iterations" in ch.stop
    # the others reuse the refits made: robot_mass on hysteresis + robot_mass, offset_drift on the whole
    assert [lk.name for lk in ch.links] == ["robot_mass", "offset_drift"]
    assert ch.links[0].joint is ab and ch.links[0].parameters == {"dM [0.1 kg]": (-2.1, 0.01)} and ch.links[0].via == "swap"
    assert ch.links[0].beside == () and ch.links[1].joint is whole and ch.links[1].beside == ()
    np.testing.assert_allclose(ch.links[0].rms_after, fl * 1.5)
