"""The diagnosis of free loads (issue 23, items 1, 2, 4): clean data called clean, one effect named (off-face shapes
too), two effects both named, no false second, parameters with se, where a gap lies. Seeded, modest sizes."""

import dataclasses
import json

import numpy as np
import pytest

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.diagnose.free import diagnose_free
from ftcal_nlp.estimate.freeload import fit_free_loads
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_payload, simulate_urdf_leg, write_free_load

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


def _sim(kind: str, seed: int, effects=(), add=None, **kw):
    if kind == "payload":
        res = simulate_payload(PayloadConfig(seed=seed, n_orientations=12, hold_s=6.0, move_s=3.0, effects=tuple(effects), **kw))
    else:
        res = simulate_urdf_leg(UrdfLegConfig(seed=seed, n_orientations=6, poses_per_orientation=3, hold_s=4.0, move_s=2.0,
                                              effects=tuple(effects), **kw))
    if add is not None:   # a gap of our own, added to the written readings
        fr = res.frame.copy()
        cols = [c for c in fr.columns if c.endswith(tuple("_" + w for w in WRENCH))]
        fr[cols] = fr[cols].to_numpy() + add(fr, res)
        res = dataclasses.replace(res, frame=fr)
    return res


def _diagnose(res, tmp_path, name="d"):
    ds = read_dataset(write_free_load(res, tmp_path / name))
    return diagnose_free(ds, fit_free_loads(ds)), ds


def _names(d) -> list[str]:
    return [e["name"] for e in d.effects]


@pytest.mark.parametrize("kind,seed", [("payload", 0), ("payload", 1), ("payload", 2), ("urdf", 0), ("urdf", 1)])
def test_clean_free_loads_are_clean(kind, seed, tmp_path):
    d, _ = _diagnose(_sim(kind, seed), tmp_path)
    assert d.verdict == "none" and d.effects == [] and d.effect is None
    leg = next(iter(d.free.values()))
    # the floor from held still stretches matches the simulated noise (within 5 %), and the held-out RMS sits on it
    noise = np.array([0.02] * 3 + [0.0006] * 3) if kind == "payload" else np.array([0.05] * 3 + [0.003] * 3)
    np.testing.assert_allclose(leg.floor, noise, rtol=0.05)
    assert np.all(leg.before / leg.floor < 1.1)
    js = d.to_json_dict()
    assert js["effects"] == [] and js["verdict"] == "none"


def _sine(fr, res):
    t = fr["t"].to_numpy()
    a = np.zeros((len(t), 6))
    a[:, 1] = 0.15 * np.sin(2 * np.pi * (t - t[0]) / np.ptp(t))       # one period over the session on fy
    return a


def _step(fr, res):
    t = fr["t"].to_numpy()
    a = np.zeros((len(t), 6))
    on = t >= t[0] + 0.43 * np.ptp(t)
    a[on, 0], a[on, 4] = 0.25, 0.004
    return a


@pytest.mark.parametrize("kind,seed,effects,add,expect", [
    ("payload", 3, (), _sine, "offset_drift"),                                   # off-face: a sinusoidal drift
    ("payload", 4, (), _step, "offset_drift"),                                   # off-face: a step
    ("urdf", 3, (), _sine, "offset_drift"),
    ("urdf", 4, ({"name": "offset_drift_ramp", "scale": 20.0},), None, "offset_drift"),
    ("payload", 5, ({"name": "clock_offset_drift", "scale": 0.02},), None, "clock_offset"),   # 23b's off-face delay
    ("urdf", 5, ({"name": "clock_offset", "scale": 0.02},), None, "clock_offset"),
    ("payload", 6, ({"name": "creep"},), None, "creep"),
    ("urdf", 6, ({"name": "creep"},), None, "creep"),
    ("payload", 9, ({"name": "temperature"},), None, "temperature"),              # a temperature column: its correlate
    ("urdf", 9, ({"name": "inertial_load"},), None, "inertial_load"),
])
def test_one_effect_is_named_alone(kind, seed, effects, add, expect, tmp_path):
    d, _ = _diagnose(_sim(kind, seed, effects, add), tmp_path)
    assert d.verdict == "effect" and d.effect == expect, d.statement
    assert _names(d) == [expect], d.statement
    assert d.where["explains"] == {"offset_drift": "time", "clock_offset": "motion", "inertial_load": "motion",
                                   "temperature": "temperature"}.get(expect, d.where["explains"])
    e = d.effects[0]
    assert all(p["se"] is None or p["se"] > 0 for p in e["parameters"].values())
    leg = next(iter(d.free.values()))
    assert np.max(leg.after / leg.floor) < 0.5 * np.max(leg.before / leg.floor)   # the gap shrinks by half at least
    if effects and effects[0]["name"] in ("offset_drift_ramp", "clock_offset"):   # on-face: closed to (near) the floor
        assert np.all(leg.after / leg.floor < 1.25), leg.after / leg.floor


PAIRS = [("offset_drift_ramp", 20.0, "offset_drift"), ("clock_offset", 0.02, "clock_offset"), ("creep", None, "creep")]


def _eff(name, scale):
    return {"name": name} | ({"scale": scale} if scale is not None else {})


def test_two_effects_both_named_in_at_least_80_percent(tmp_path):
    cases = []
    for i, (a, b) in enumerate([(0, 1), (0, 2), (1, 2)] * 2 + [(0, 1), (0, 2), (1, 2), (0, 1)]):
        kind = "payload" if i % 2 == 0 else "urdf"
        cases.append((kind, 20 + i, PAIRS[a], PAIRS[b]))
    hits = []
    for kind, seed, a, b in cases:
        d, _ = _diagnose(_sim(kind, seed, (_eff(*a[:2]), _eff(*b[:2]))), tmp_path, f"{kind}{seed}")
        hits.append({a[2], b[2]} <= set(_names(d)))
    assert len(cases) == 10 and sum(hits) >= 8, hits


def test_a_single_effect_grows_a_false_second_at_most_once_in_ten(tmp_path):
    false = []
    for i in range(10):
        kind = "payload" if i % 2 == 0 else "urdf"
        name, scale, expect = PAIRS[i % 3]
        d, _ = _diagnose(_sim(kind, 40 + i, (_eff(name, scale),)), tmp_path, f"{kind}{i}")
        assert expect in _names(d), (kind, i, d.statement)
        false.append(len(d.effects) > 1)
    assert sum(false) <= 1, false


def test_delay_and_its_se_recover_truth(tmp_path):
    """The joint refit's clock offset (linearised around the free-load fit) is the injected delay within 4 se."""
    true = 0.02
    d, _ = _diagnose(_sim("payload", 7, ({"name": "clock_offset", "scale": true},)), tmp_path)
    assert d.effect == "clock_offset"
    pars = d.effects[0]["parameters"]
    vals = [(v["value"], v["se"]) for k, v in pars.items() if k in ("delay_s [s]", "torque.delay_s [s]")]
    assert vals, pars
    for v, se in vals:
        assert se is not None and abs(v - true) < 4 * se + 1e-3 * true, (v, se)
    # the free-load parameters refit with it: the offsets are determined (finite se) and the truth within 4 se
    jr = d.to_json_dict()["free_loads"]["wrist"]["joint_refit"]
    truth = json.loads(json.dumps(_sim("payload", 7, ({"name": "clock_offset", "scale": true},)).truth))
    for c, t in zip(WRENCH, truth["offset"]):
        p = jr[f"wrist.offset.{c}"]
        assert p["se"] is not None and abs(p["value"] - t) < 4 * p["se"], (c, p, t)


def test_a_gap_along_a_joint_is_unexplained_and_placed(tmp_path):
    """A wrench that follows a joint angle (no library effect makes it): unexplained, where.explains joint:<name>,
    and the residual plotted against that joint."""
    def bump(fr, res):
        q = fr["q_r_knee"].to_numpy()
        a = np.zeros((len(q), 6))
        a[:, 0] = 0.4 * np.cos(3.0 * q)
        return a

    d, _ = _diagnose(_sim("urdf", 8, (), bump), tmp_path)
    assert d.verdict == "unexplained", d.statement
    assert d.where["explains"] == "joint:r_knee" and "fx" in d.where["components"]
    leg = next(iter(d.free.values()))
    assert leg.plot["correlate"] == "joint:r_knee" and leg.plot["component"] == "fx"
    js = json.loads(json.dumps(d.to_json_dict()))
    assert js["where"]["explains"] == "joint:r_knee"


def test_run_writes_the_chain_and_its_report(tmp_path):
    """``python -m ftcal_nlp.run`` on a simulated payload with two effects: diagnosis.json lists both (in order, with
    parameters and se, held-out RMS after each; ``effect`` the first), and the report shows the chain and the figure."""
    from ftcal_nlp.run import main as run_main

    cfg = tmp_path / "run.toml"
    cfg.write_text('[data]\nmanifest = "data/dataset.toml"\n[simulate]\nkind = "payload"\nseed = 21\nn_orientations = 12\n'
                   'hold_s = 6.0\nmove_s = 3.0\neffects = [{name = "clock_offset", scale = 0.02}, '
                   '{name = "offset_drift_ramp", scale = 20.0}]\n[output]\ndir = "out"\n[diagnose]\nenabled = true\n')
    assert run_main([str(cfg)]) == 0
    d = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert d["verdict"] == "effect" and [e["name"] for e in d["effects"]] == ["clock_offset", "offset_drift"]
    assert d["effect"] == d["effects"][0]["name"] and d["where"]["explains"] == "motion"
    for e in d["effects"]:
        assert len(e["heldout_rms_after"]) == 6 and e["parameters"] and set(e["parameters_when_added"]) == set(e["parameters"])
        assert all(set(v) == {"value", "se"} for v in e["parameters"].values())
    # each step shrinks the held-out RMS
    rms = [np.asarray(d["shrinkage"]["heldout_rms_before"])] + [np.asarray(e["heldout_rms_after"]) for e in d["effects"]]
    assert all(np.sum((a / rms[0]) ** 2) > np.sum((b / rms[0]) ** 2) for a, b in zip(rms, rms[1:]))
    assert "wrist" in d["free_loads"] and d["free_loads"]["wrist"]["chain"]
    rep = (tmp_path / "out" / "report.md").read_text()
    assert "in the order added" in rep and "1. clock_offset" in rep and "2. offset_drift" in rep


def _pose_list(res, drift_N: float, n_keep: int | None = None):
    """The simulated recording as a list of poses: one row per hold (its mean), a synthetic clock of 1 s per row,
    and an fz drift of ``drift_N`` over the list (linear)."""
    fr = res.frame[res.held].copy()
    fr["hold"] = res.hold_index[res.held]
    rows = fr.groupby("hold").mean().reset_index(drop=True)
    if n_keep is not None:
        rows = rows.iloc[:n_keep]
    rows["t"] = 1000.0 + np.arange(len(rows))
    rows[f"{res.config.transducer}_fz"] += drift_N * np.linspace(-0.5, 0.5, len(rows))
    return dataclasses.replace(res, frame=rows, held=np.ones(len(rows), bool), hold_index=np.arange(len(rows)))


def test_a_list_of_poses_has_no_floor_but_its_drift_is_named(tmp_path):
    # 100 poses make 10 cross-validation blocks: with 6 (60 poses) the paired block-wise z of a linear drift sits at
    # ~3 whatever its size (the spread of its share from block to block), on the threshold
    res = simulate_payload(PayloadConfig(seed=11, n_orientations=100, hold_s=1.0, move_s=0.5, noise_force_N=0.05))
    d, _ = _diagnose(_pose_list(res, 1.5), tmp_path)
    leg = d.free["wrist"]
    assert not leg.floor_known and any("no noise floor is known" in n for n in d.notes)
    assert _names(d) == ["offset_drift"] and "fz" in d.where["components"], d.statement
    p1 = d.effects[0]["parameters"]["fz.P1 [N]"]
    assert abs(p1["value"] - 0.75) < 4 * p1["se"], p1          # P1 over [-1, 1]: half the drift
    clean, _ = _diagnose(_pose_list(res, 0.0), tmp_path, "clean")
    assert clean.verdict == "none" and clean.effects == []


def test_too_few_poses_are_not_diagnosed_and_no_error(tmp_path):
    res = simulate_payload(PayloadConfig(seed=12, n_orientations=8, hold_s=1.0, move_s=0.5))
    d, _ = _diagnose(_pose_list(res, 0.0, n_keep=7), tmp_path)
    assert d.verdict == "none" and d.effects == [] and any("not diagnosed" in n for n in d.notes)
    json.dumps(d.to_json_dict())
