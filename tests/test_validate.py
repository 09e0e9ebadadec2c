"""Validation that cannot be tuned to (issue 13, item 5): the off-face injectors of
``ftcal_nlp.sim.variants`` change the readings in the intended way and leave the truth alone;
the sweep's plan is deterministic and complete (clean datasets, both sizes of every effect
and variant, a clean twin for each); a tiny sweep runs through joblib on two processes and
writes the table.

Injector checks compare a session with the effect to its clean twin (same seed) with the
sensor noise switched off, so a reading's change is the effect exactly."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.diagnose.validation import (
    check_config,
    effect_sizes,
    is_right,
    run_items,
    run_validation,
    score,
    sweep_plan,
)
from ftcal_nlp.pipeline import calibrate
from ftcal_nlp.core.geometry import quat_to_rotation, rotation_to_rotvec
from ftcal_nlp.sim import EFFECTS, SimConfig, simulate
from ftcal_nlp.effects import EFFECTS as LIBRARY, LIBRARY_EFFECTS, applies_to
from ftcal_nlp.effects.injection import HOUR_S
from ftcal_nlp.sim.variants import VARIANTS, OffFaceInjector

SEED = 5
TINY = {"n_poses": 12, "hanging_cycles": 1.0, "walk_cycles": 0.5, "noise_force_N": 0.0, "noise_torque_Nm": 0.0, "seed": SEED}
SMALL = {"n_poses": 60, "hanging_cycles": 2.0, "walk_cycles": 1.0}  # the end-to-end run (tests/test_diagnose.py: 120)

_cache: dict = {}


def session(name: str | None = None, **kw):
    """(sim, injector) of a tiny noise-free session with effect ``name`` (None: the clean twin)."""
    key = (name, tuple(sorted(kw.items())))
    if key not in _cache:
        inj = EFFECTS[name](seed=SEED, **kw) if name else None
        cfg = SimConfig.from_dict(TINY)
        sim = simulate(SimConfig(**{**cfg.__dict__, "effects": (inj,) if inj else ()}))
        _cache[key] = (sim, inj)
    return _cache[key]


def wrenches(sim) -> dict[str, np.ndarray]:
    """Recording name -> readings (N, K, 6) in leg order."""
    legs = sim.dataset.robot.legs
    return {r.name: np.stack([r.wrench[k] for k in legs], axis=1) for r in sim.dataset.recordings}


def change(name: str, **kw) -> tuple[dict, dict, object, object]:
    """(readings with the effect, clean readings, sim with the effect, injector)."""
    sim, inj = session(name, **kw)
    return wrenches(sim), wrenches(session()[0]), sim, inj


def test_registry_and_expectations():
    assert set(VARIANTS) <= set(EFFECTS) and not set(VARIANTS) & set(LIBRARY_EFFECTS)
    for name, cls in VARIANTS.items():
        assert issubclass(cls, OffFaceInjector) and cls.name == name
        lo, hi = cls.magnitude.realistic
        assert 0 < lo <= hi and cls.magnitude.test > 0
        inj = cls(seed=3)
        assert inj.expect in (*LIBRARY, "none", "unexplained")
        assert bool(inj.expect_legs) == (inj.expect == "unexplained")
        assert repr(inj) == repr(cls(seed=3))  # leg, axis, sign: drawn from the seed alone
    expect = {n: c.expect for n, c in VARIANTS.items()}
    assert expect["offset_drift_ramp"] == expect["offset_drift_step"] == expect["offset_drift_fast"] == "offset_drift"
    assert expect["casing_load_harmonics"] == "casing_load" and expect["mocap_pose_noise"] == "none"
    assert expect["leg_axes_swapped"] == expect["leg_axis_flipped"] == expect["leg_mass_changed"] == "unexplained"


@pytest.mark.parametrize("name", sorted(n for n in VARIANTS if "hexapod" in applies_to(n)))   # the hexapod simulator's
def test_variant_leaves_the_truth_alone(name):
    sim, _ = session(name)
    clean = session()[0]
    a, b = sim.truth_json_dict(), clean.truth_json_dict()
    assert a["effect"] == name and a["in_library"] is False
    assert {k: v for k, v in a.items() if k not in ("effect", "scale", "in_library")} == \
           {k: v for k, v in b.items() if k not in ("effect", "scale", "in_library")}
    assert sim.dataset.robot.mass_kg == clean.dataset.robot.mass_kg  # robot.toml as weighed
    np.testing.assert_array_equal(sim.walk_truth.to_numpy(), clean.walk_truth.to_numpy())


def test_swapped_leg_exchanges_fx_fy():
    w, w0, _, inj = change("leg_axes_swapped")
    k = session()[0].dataset.robot.legs.index(inj.leg)
    for rec in w:
        np.testing.assert_allclose(w[rec][:, k, 0], w0[rec][:, k, 1], atol=1e-12)
        np.testing.assert_allclose(w[rec][:, k, 1], w0[rec][:, k, 0], atol=1e-12)
        np.testing.assert_array_equal(np.delete(w[rec], k, axis=1), np.delete(w0[rec], k, axis=1))
        np.testing.assert_array_equal(w[rec][:, k, 2:], w0[rec][:, k, 2:])


def test_flipped_leg_axis_changes_sign():
    w, w0, _, inj = change("leg_axis_flipped")
    k = session()[0].dataset.robot.legs.index(inj.leg)
    j = ("fx", "fy", "fz", "tx", "ty", "tz").index(inj.axis)
    for rec in w:
        np.testing.assert_allclose(w[rec][:, k, j], -w0[rec][:, k, j], atol=1e-12)
        d = w[rec] - w0[rec]
        d[:, k, j] = 0.0
        assert np.all(d == 0.0)


def test_mass_change_adds_its_weight_after_hanging_only():
    w, w0, sim, inj = change("leg_mass_changed")
    truth = sim.true_robot
    k = truth.legs.index(inj.leg)
    dmg = abs(inj.delta_kg) * truth.g
    for rec in sim.dataset.recordings:
        d = w[rec.name] - w0[rec.name]
        if rec.kind == "hanging":  # the change came after hanging
            assert np.all(d == 0.0)
            continue
        assert np.abs(d[:, k, :3]).max() > 0.3 * dmg
        # no net wrench on the body: the feet carry the extra weight that leg k weighs
        f_B = np.einsum("kij,nkj->nki", truth.R, d[..., :3])
        t_B = np.einsum("kij,nkj->nki", truth.R, d[..., 3:]) + np.cross(truth.p_prime[None], f_B)
        np.testing.assert_allclose(f_B.sum(axis=1), 0.0, atol=1e-9)
        np.testing.assert_allclose(t_B.sum(axis=1), 0.0, atol=1e-9)
    # while leg k swings, its reading changes by exactly dm g along gravity, at its CoM
    walk = sim.dataset.walking[0]
    d = w[walk.name] - w0[walk.name]
    swing = np.abs(sim.walk_truth[f"{inj.leg}_fz"].to_numpy()) < 1e-9
    assert swing.sum() > 10
    f_k = d[swing, k, :3]
    np.testing.assert_allclose(np.linalg.norm(f_k, axis=-1), dmg, rtol=1e-9)
    f_B = f_k @ truth.R[k].T
    assert np.all(f_B[:, 2] * inj.sign < -0.99 * dmg)               # down in B (level walk) when added
    r = truth.leg_com_ft(np.stack([walk.phi[l] for l in truth.legs], axis=1))[swing, k]
    np.testing.assert_allclose(d[swing, k, 3:], np.cross(r, f_k), atol=1e-12)


@pytest.mark.parametrize("name", ["offset_drift_ramp", "offset_drift_step", "offset_drift_fast"])
def test_drift_shapes(name):
    w, w0, sim, inj = change(name)
    K = len(sim.dataset.robot.legs)
    d_k = inj._drift(K)                                               # the drift's per-leg vector (scale)
    for rec in sim.dataset.recordings:
        d = w[rec.name] - w0[rec.name]
        t = rec.t
        if name == "offset_drift_ramp":
            frac = t / HOUR_S
        elif name == "offset_drift_fast":
            frac = (1 - np.exp(-t / 150.0)) / (1 - np.exp(-HOUR_S / 150.0))
        elif rec.kind == "standing":
            frac = (t >= 0.5 * (t[0] + t[-1])).astype(float)
        else:
            frac = np.full(len(t), 1.0 if rec.kind == "walking" else 0.0)
        np.testing.assert_allclose(d, frac[:, None, None] * d_k[None], atol=1e-12)
    if name == "offset_drift_step":  # a step of ``scale`` N (x 0.7-1.3 per leg) in the middle of standing
        st = next(r for r in sim.dataset.recordings if r.kind == "standing")
        d = w[st.name] - w0[st.name]
        assert np.all(d[0] == 0.0) and np.allclose(d[-1], d_k)
        assert np.all((np.linalg.norm(d_k[:, :3], axis=1) > 0.69 * inj.scale) & (np.linalg.norm(d_k[:, :3], axis=1) < 1.31 * inj.scale))


def test_casing_harmonics_have_no_first_harmonic():
    w, w0, sim, inj = change("casing_load_harmonics")
    rec = sim.dataset.hanging[0]
    legs = sim.dataset.robot.legs
    d = w[rec.name] - w0[rec.name]
    assert np.all(d[..., 2:] == 0.0) and np.abs(d[..., :2]).max() > 0.1 * inj.scale
    phi = np.stack([rec.phi[k] for k in legs], axis=1)
    for k in range(len(legs)):
        basis = np.column_stack([np.cos(h * phi[:, k]) for h in (1, 3, 5)] + [np.sin(h * phi[:, k]) for h in (1, 3, 5)])
        coef = np.linalg.lstsq(basis, d[:, k, :2], rcond=None)[0]
        np.testing.assert_allclose(basis @ coef, d[:, k, :2], atol=1e-9)    # exactly harmonics 3 and 5 ...
        assert np.abs(coef[[0, 3]]).max() < 1e-9                             # ... no first harmonic


def test_mocap_pose_noise_is_held_per_pose_in_standing_only():
    sim, inj = session("mocap_pose_noise")
    clean = session()[0]
    for a, b in zip(sim.dataset.recordings, clean.dataset.recordings):
        np.testing.assert_array_equal(a.wrench_array(), b.wrench_array())  # readings untouched
        if a.kind != "standing" and a.quat is not None:
            np.testing.assert_array_equal(a.quat, b.quat)
    st, st0 = sim.dataset.standing[0], clean.dataset.standing[0]
    ok = ~np.isnan(st.quat).any(axis=1)
    # R_clean^T R = exp([delta_p]) exactly: one error per pose (zero between poses), ~scale deg per axis
    rel = rotation_to_rotvec(np.einsum("nji,njk->nik", quat_to_rotation(st0.quat[ok]), quat_to_rotation(st.quat[ok])))
    delta = inj.pose_errors(SimpleNamespace(name=st.name), len(sim.pose_phi))
    cand = np.vstack([np.zeros(3), delta])
    assert np.abs(rel[:, None] - cand[None]).max(axis=-1).min(axis=1).max() < 1e-9
    assert (np.abs(rel).max(axis=1) > 0).mean() > 0.5
    assert np.degrees(delta.std()) == pytest.approx(inj.scale, rel=0.4)


# ----------------------------------------------------------------------------- the plan


def sweep_cfg(**kw) -> dict:
    return check_config({"seed": 2, **kw})[0]


def test_sweep_plan_is_deterministic_and_complete():
    cfg = sweep_cfg()
    a, b = sweep_plan(cfg), sweep_plan(cfg)
    assert a == b
    assert [x["index"] for x in a] == list(range(len(a)))
    clean = [x for x in a if x["role"] == "clean"]
    assert len(clean) >= 6
    from ftcal_nlp.diagnose.validation import HEXAPOD_EFFECTS, HEXAPOD_VARIANTS

    # the hexapod sweep: the effects with hexapod faces and the shapes a hexapod takes (free-load ones apart)
    assert set(HEXAPOD_EFFECTS) == {n for n, u in LIBRARY.items() if "hexapod" in u.diagnosed_on} and "offset_drift" in HEXAPOD_EFFECTS
    assert "clock_offset" not in HEXAPOD_EFFECTS and "clock_offset_drift" not in HEXAPOD_VARIANTS
    assert {x["effect"] for x in a if x["role"] in ("library", "variant")} == set(HEXAPOD_EFFECTS) | set(HEXAPOD_VARIANTS)
    for role, names in (("library", HEXAPOD_EFFECTS), ("variant", HEXAPOD_VARIANTS)):
        for name in names:
            got = [x for x in a if x["role"] == role and x["effect"] == name]
            assert sorted(x["size"] for x in got) == ["hi", "lo"], name
            lo, hi = EFFECTS[name].magnitude.realistic
            assert {x["scale"] for x in got} == {lo, hi}
    with_effect = [x for x in a if x["role"] in ("library", "variant")]
    seeds = [x["seed"] for x in clean + with_effect]
    assert len(set(seeds)) == len(seeds)  # each dataset on its own seed
    twins = {x["index"]: x for x in a if x["role"] == "twin"}
    assert len(twins) == len(with_effect)
    for x in with_effect:
        t = twins[x["twin"]]
        assert t["seed"] == x["seed"] and t["effect"] == "none" and t["twin"] == x["index"]
        assert x["expect"] == (x["effect"] if x["effect"] in LIBRARY else VARIANTS[x["effect"]].expect)
        if x["expect"] == "unexplained":
            assert x["expect_legs"] == VARIANTS[x["effect"]](scale=x["scale"], seed=x["seed"]).leg
    assert sweep_plan(sweep_cfg(seed=3)) != a
    test_sizes = sweep_plan(sweep_cfg(sizes="test", effects=["offset_drift"], variants=["leg_axes_swapped"], n_clean=0))
    assert [(x["effect"], x["size"], x["scale"]) for x in test_sizes if x["role"] != "twin"] == [
        ("offset_drift", "half", 1.5), ("offset_drift", "test", 3.0), ("leg_axes_swapped", "lo", 1.0), ("leg_axes_swapped", "hi", 1.0)]
    assert effect_sizes("leg_mass_changed", "realistic") == (("lo", 0.05), ("hi", 0.2))


def test_config_errors_name_the_key(tmp_path):
    for cfg, key in (({"n_clean": -1}, "n_clean"), ({"sizes": "big"}, "sizes"), ({"variants": ["leg_swap"]}, "variants"),
                     ({"design": "grid"}, "design"), ({"workers": 0}, "workers"), ({"backend": 3}, "backend"),
                     ({"tolerance": 0}, "tolerance"), ({"simulate": {"n_pose": 3}}, "validation.simulate"),
                     ({"simulate": {"seed": 3}}, "validation.simulate"), ({"n_datasets": 2, "oops": 1}, "unknown key"),
                     ({"n_datasets": 2, "n_clean": 3}, "n_clean"), ({"design": "sweep", "clean_share": 0.2}, "clean_share")):
        with pytest.raises(ValueError, match=key.replace(".", r"\.")):
            run_validation(cfg, tmp_path, calibrate)


def test_scoring_against_the_twin():
    rows = pd.DataFrame([
        {"index": 0, "seed": 1, "role": "library", "effect": "offset_drift", "expect": "offset_drift", "expect_legs": "",
         "named": "offset_drift", "legs": "", "verdict": "effect", "kind_key": "standing", "twin": 2, "time_s": 1.0,
         **{f"before_{c}": 10.0 for c in "fx fy fz tx ty tz".split()}, **{f"after_{c}": 1.2 for c in "fx fy fz tx ty tz".split()},
         **{f"floor_{c}": 1.1 for c in "fx fy fz tx ty tz".split()}},
        {"index": 1, "seed": 3, "role": "variant", "effect": "leg_axes_swapped", "expect": "unexplained", "expect_legs": "FL",
         "named": "gain_crosstalk", "legs": "FL", "verdict": "effect", "kind_key": "standing", "twin": 3, "time_s": 1.0},
        {"index": 2, "seed": 1, "role": "twin", "effect": "none", "named": "none", "kind_key": "standing", "twin": 0,
         "kinds_json": '{"standing": {"floor": [1, 1, 1, 1, 1, 0.5], "rms": [1, 1, 1, 1, 1, 1]}}', "time_s": 1.0},
        {"index": 3, "seed": 3, "role": "twin", "effect": "none", "named": "error", "twin": 1, "time_s": 1.0},
    ])
    s = score(rows, 1.5).set_index("index")
    assert s.loc[0, "right"] and s.loc[0, "after_ratio_fx"] == pytest.approx(1.2) and s.loc[0, "after_ratio_tz"] == pytest.approx(2.4)
    assert not s.loc[0, "shrink_ok"]  # tz: 2.4x the twin's floor
    assert s.loc[1, "right"] and s.loc[1, "right_leg"] and np.isnan(s.loc[1, "after_ratio_fx"])  # placed on the right leg
    assert is_right("unexplained", "", "unexplained", "HL") and not is_right("none", "HL FL", "unexplained", "HL")


# ----------------------------------------------------------------------------- end to end


def test_tiny_sweep_through_joblib(tmp_path):
    cfg, sim_over = check_config({"seed": 1, "n_clean": 1, "effects": ["offset_drift"], "variants": [], "folds": 3,
                                  "workers": 2, "simulate": SMALL})
    items = sweep_plan(cfg)
    hi = next(x for x in items if x["size"] == "hi")
    items = [items[0], hi, items[hi["twin"]]]                       # a clean dataset, one effect and its twin
    summary = run_items(items, cfg, sim_over, tmp_path, calibrate)
    assert summary["finished"] == (3, 3) and summary["workers"] == 2 and summary["backend"] == "LokyBackend"
    assert summary["clean"][1] == 1 and summary["library"][1] == 1
    table = (tmp_path / "validation.md").read_text()
    assert "| what | measured | goal |" in table and "| runs that finish | 3/3 | 3/3 |" in table
    assert "library effects named right" in table and "clean data called clean" in table
    scores = pd.read_csv(tmp_path / "scores.csv")
    assert len(scores) == 1 and scores.loc[0, "effect"] == "offset_drift"
    assert {f"after_ratio_{c}" for c in "fx fy fz tx ty tz".split()} <= set(scores.columns)
    rows = pd.read_csv(tmp_path / "datasets.csv")
    assert list(rows["index"]) == [x["index"] for x in items] and (rows["role"] == "twin").sum() == 1
    assert np.isfinite(scores.filter(like="twin_floor_").to_numpy(float)).all()


def test_pairs_in_the_plan_and_their_rows_of_the_table():
    """Issue 23, item 2: pairs of library effects (each at the high end of its realistic range, own seeds, after the
    twins), restricted to the effects withheld; the table counts pairs with both named and single effects with a
    false second."""
    from ftcal_nlp.diagnose.validation import PAIRS, sweep_summary, validation_table

    a = sweep_plan(sweep_cfg())
    pairs = [x for x in a if x["role"] == "pair"]
    assert [tuple(x["effect"].split("+")) for x in pairs] == list(PAIRS) and 6 <= len(PAIRS) <= 10
    assert min(x["index"] for x in pairs) > max(x["index"] for x in a if x["role"] == "twin")
    for x in pairs:
        want = [EFFECTS[n].magnitude.realistic[1] for n in x["effect"].split("+")]
        assert [float(v) for v in x["scales"].split()] == want and x["twin"] is None and x["expect"] == x["effect"]
    seeds = [x["seed"] for x in a if x["role"] != "twin"]
    assert len(set(seeds)) == len(seeds)
    only = sweep_plan(sweep_cfg(effects=["offset_drift", "casing_load"], variants=[], n_clean=0))
    assert [x["effect"] for x in only if x["role"] == "pair"] == ["offset_drift+casing_load"]
    mine = sweep_plan(sweep_cfg(effects=["offset_drift"], variants=[], n_clean=0, pairs=["robot_mass+mocap_bias"]))
    assert [x["effect"] for x in mine if x["role"] == "pair"] == ["robot_mass+mocap_bias"]
    for bad in (["robot_mass+clock_offset"], ["casing_load+casing_load"], ["moving_com+casing_load"], ["casing_load"], "x"):
        with pytest.raises(ValueError, match=r"\[validation\]\.pairs"):
            check_config({"pairs": bad})

    def row(i, role, effect, named, effects):
        return {"index": i, "seed": i, "role": role, "effect": effect, "expect": effect, "expect_legs": "", "named": named,
                "legs": "", "verdict": "effect", "kind_key": "standing", "twin": None, "time_s": 1.0, "effects": effects,
                "size": "hi", "scale": 1.0}

    rows = pd.DataFrame([row(0, "library", "casing_load", "casing_load", "casing_load"),
                         row(1, "library", "offset_drift", "offset_drift", "offset_drift hysteresis"),
                         row(2, "variant", "casing_load", "casing_load", "casing_load"),
                         row(3, "pair", "offset_drift+casing_load", "casing_load", "casing_load offset_drift"),
                         row(4, "pair", "robot_mass+mocap_bias", "robot_mass", "robot_mass")])
    sc = score(rows, 1.5)
    s = sweep_summary(rows, sc, 1.0, 1.5)
    assert s["pairs"] == (1, 2) and s["false_second"] == (1, 3)
    table = validation_table(rows, sc, s)
    assert "both named | 1/2 (robot_mass+mocap_bias: `robot_mass`) | >= 80% |" in table
    assert "a false second named | 1/3 (offset_drift hi: `offset_drift` then `hysteresis`) | <= 10% |" in table


def test_a_sweep_of_pairs_alone_is_summarised():
    """A sweep of pairs only (no single effect, no clean dataset) is counted, not a KeyError on the empty scores."""
    from ftcal_nlp.diagnose.validation import sweep_summary, validation_table

    rows = pd.DataFrame([{"index": 0, "seed": 0, "role": "pair", "effect": "offset_drift+casing_load",
                          "expect": "offset_drift+casing_load", "expect_legs": "", "named": "casing_load", "legs": "",
                          "verdict": "effect", "kind_key": "standing", "twin": None, "time_s": 1.0,
                          "effects": "casing_load offset_drift", "size": "hi", "scale": None}])
    sc = score(rows, 1.5)
    s = sweep_summary(rows, sc, 1.0, 1.5)
    assert s["pairs"] == (1, 1) and s["false_second"] == (0, 0) and s["library"] == (0, 0)
    assert "both named | 1/1" in validation_table(rows, sc, s)


def test_a_dataset_rejected_naming_its_leg_counts_as_placed():
    """An input check that refuses a dataset with an error naming the faulty leg's column (``rejected``) has placed a
    fault outside the library on its leg; one naming another leg, or no column, has not (an error)."""
    from ftcal_nlp.diagnose.validation import REJECTED, rejected_leg, sweep_summary, validation_table
    from ftcal_nlp.core.errors import DataFormatError, MisSignedChannel

    legs = ("FL", "ML", "HL", "FR", "MR", "HR")
    assert rejected_leg(MisSignedChannel("x", leg="FR", column="FR_fz"), legs) == "FR"
    # another input error naming a leg's column (a temperature, a unit) is no fault found
    assert rejected_leg(DataFormatError("x", column="FR_temp_C"), legs) is None
    assert rejected_leg(DataFormatError("x", column="FR_fz"), legs) is None and rejected_leg(DataFormatError("x"), legs) is None
    assert rejected_leg(MisSignedChannel("x", leg="XX", column="XX_fz"), legs) is None

    def row(i, legs_named, named):
        return {"index": i, "seed": i, "role": "variant", "effect": "leg_axis_flipped", "expect": "unexplained",
                "expect_legs": "FR", "named": named, "legs": legs_named, "verdict": named, "kind_key": "standing",
                "twin": None, "time_s": 1.0, "effects": "", "size": "lo", "scale": 1.0}

    rows = pd.DataFrame([row(0, "FR", REJECTED), row(1, "MR", REJECTED)])
    sc = score(rows, 1.5)
    assert list(sc["right"]) == [True, False]
    s = sweep_summary(rows, sc, 1.0, 1.5)
    assert s["outside"] == (1, 2) and s["finished"] == (2, 2)
    assert "leg_axis_flipped lo (FR) rejected by the input check naming its leg" in validation_table(rows, sc, s)
