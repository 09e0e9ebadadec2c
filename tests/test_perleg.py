"""Per-leg checks without the effect library (issue 13, item 3): a free linear map of each leg's
readings (standing) and each leg's weight and CoM refit on its swing phases (walking).

Faults are injected here, directly into copies of simulated recordings, with shapes that are not
the checks' own models: a leg's fx/fy swapped after hanging, a leg's fy sign-flipped in every
recording, a 3 % fz gain after hanging, a point mass on a leg (at a point of its toe loop, not its
CoM curve) in standing and walking or walking only. Each must be named on the right leg and kind;
clean sessions of several seeds must raise no flag. Sessions are small (120 poses, 2 leg turns
per hanging recording, 1 walk cycle) and calibrated once each (model "full", no diagnosis).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from ftcal_nlp import CalibrationSettings, DiagnoseSettings, HangingSettings, StandingSettings, calibrate
from ftcal_nlp.diagnose.perleg import (
    ALPHA,
    LegMap,
    PerLegFindings,
    _describe_part,
    _nearest_signed_permutation,
    _perm_phrase,
    linear_map_check,
    perleg_checks,
    swing_check,
)
from ftcal_nlp.core.geometry import quat_to_rotation, rotvec_to_rotation
from ftcal_nlp.core.physics import gravity_dir_in_ft, leg_gravity_wrench
from ftcal_nlp.sim import SimConfig, simulate

SMALL = dict(n_poses=120, hanging_cycles=2.0, walk_cycles=1.0)
SETTINGS = CalibrationSettings(hanging=HangingSettings(compare_baseline=False),
                               standing=StandingSettings(model="full", compare_baseline=False),
                               diagnose=DiagnoseSettings(enabled=False))
CLEAN_SEEDS = (1, 2, 3)
FAULT_SEED = 21
SWAP_XY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

_cache: dict = {}


# ----------------------------------------------------------------------------- injections (no injector classes)


def _modify(ds, kinds, fn):
    """A copy of ``ds`` with ``fn`` applied to every recording of ``kinds``."""
    return replace(ds, recordings=tuple(fn(r) if r.kind in kinds else r for r in ds.recordings))


def _leg_matrix(leg: str, M6: np.ndarray):
    """Readings of ``leg`` (offset included, as a transducer would) mapped by the 6x6 ``M6``."""
    def fn(rec):
        w = dict(rec.wrench)
        w[leg] = w[leg] @ M6.T
        return replace(rec, wrench=w)
    return fn


def _blk(M3: np.ndarray, torque: np.ndarray | None = None) -> np.ndarray:
    out = np.eye(6)
    out[:3, :3] = M3
    if torque is not None:
        out[3:, 3:] = torque
    return out


def _point_mass(sim, leg: str, mass_kg: float, frac: float = 0.7):
    """The gravity wrench of a point mass on ``leg``, at ``frac`` of the way from the hip to the
    toe loop (it turns with the shaft, unlike a CoM shift), added to that leg's readings with the
    recording's orientation (held over motion-capture losses)."""
    tr = sim.true_robot
    k = tr.legs.index(leg)

    def fn(rec):
        q = rec.quat
        ok = np.all(np.isfinite(q), axis=1)
        q = q[np.maximum.accumulate(np.where(ok, np.arange(len(q)), 0))]
        u = gravity_dir_in_ft(quat_to_rotation(q), tr.R[k])
        s = frac * tr.foot_ft(rec.phi_array(tr.legs))[:, k]
        w = dict(rec.wrench)
        w[leg] = w[leg] + leg_gravity_wrench(u, s, mass_kg * tr.g)
        return replace(rec, wrench=w)
    return fn


FAULTS = {
    "swap_fxfy_ML": (("standing", "walking"), lambda sim: _leg_matrix("ML", _blk(SWAP_XY))),
    "flip_fy_HR": (("hanging", "standing", "walking"), lambda sim: _leg_matrix("HR", np.diag([1.0, -1.0, 1.0, 1.0, 1.0, 1.0]))),
    "gain_fz_FL": (("standing", "walking"), lambda sim: _leg_matrix("FL", np.diag([1.0, 1.0, 1.03, 1.0, 1.0, 1.0]))),
    "mass50_HL": (("standing", "walking"), lambda sim: _point_mass(sim, "HL", 0.05)),
}


def _sim(seed: int):
    key = ("sim", seed)
    if key not in _cache:
        _cache[key] = simulate(SimConfig(seed=seed, **SMALL))
    return _cache[key]


def session(seed: int, fault: str = "none"):
    """(dataset, calibration run, findings) of one small session with ``fault`` injected."""
    key = (seed, fault)
    if key not in _cache:
        sim = _sim(seed)
        ds = sim.dataset
        if fault == "mass50walk_HL":  # walking only: hanging and standing untouched, the clean calibration holds
            run = session(seed)[1]
            ds = _modify(ds, ("walking",), _point_mass(sim, "HL", 0.05))
        else:
            if fault != "none":
                kinds, make = FAULTS[fault]
                ds = _modify(ds, kinds, make(sim))
            run = calibrate(ds, SETTINGS)
        res = perleg_checks(ds, run.calibration, run.poses, ds.robot, folds=5, seed=0)
        _cache[key] = (ds, run, res)
    return _cache[key]


# ----------------------------------------------------------------------------- the description of a map


def test_nearest_signed_permutation_and_its_words():
    rng = np.random.default_rng(0)
    for _ in range(20):
        perm = rng.permutation(3)
        P = np.diag(rng.choice([-1.0, 1.0], 3))[perm]
        U = P @ rotvec_to_rotation(rng.normal(0, np.radians(5), 3))
        assert np.array_equal(_nearest_signed_permutation(U), P)
    ax = ("fx", "fy", "fz")
    assert _perm_phrase(np.eye(3), ax) == ""
    assert _perm_phrase(SWAP_XY, ax) == "fx and fy swapped"
    assert _perm_phrase(np.diag([1.0, -1.0, 1.0]), ax) == "fy sign-flipped"
    assert _perm_phrase(np.diag([1.0, 1.0, -1.0]) @ SWAP_XY, ax) == "fx and fy swapped; fz sign-flipped"
    cyc = np.eye(3)[[1, 2, 0]]
    assert _perm_phrase(cyc, ax) == "reading fx carries fy, reading fy carries fz, reading fz carries fx"


def test_describe_part_recovers_gains_crosstalk_and_permutation():
    R_nom = np.diag([1.0, -1.0, -1.0])
    R_true = rotvec_to_rotation(np.radians([1.0, -0.5, 0.8])) @ R_nom
    S = np.array([[1.0, 0.0, 0.01], [0.0, 1.0, 0.0], [0.01, 0.0, 1.03]])   # reading = S Pi (true in sensor axes)
    Pi = np.diag([1.0, -1.0, 1.0]) @ SWAP_XY
    G_true = S @ Pi
    A = R_true @ np.linalg.inv(G_true)        # the map that corrects the readings back into B
    vals, P = _describe_part(A, R_nom)
    assert np.array_equal(P, Pi)
    np.testing.assert_allclose(vals[:3], [1.0, 1.0, 1.03], atol=1e-3)
    np.testing.assert_allclose(vals[3:6], [0.0, 0.01, 0.0], atol=1e-3)
    assert np.linalg.norm(vals[6:]) < 2.0      # the mounting error, deg


# ----------------------------------------------------------------------------- clean sessions: no false alarm


@pytest.mark.parametrize("seed", CLEAN_SEEDS)
def test_clean_sessions_raise_no_flag(seed):
    ds, run, res = session(seed)
    assert isinstance(res, PerLegFindings)
    assert res.clean and res.findings == () and res.legs == ()
    lm, sw = res.linear_map, res.swing
    assert lm.selected == () and lm.flagged == ()
    assert np.all(lm.ratio > 0.9), lm.ratio                       # a free map never pays on held-out clean poses
    assert np.all(lm.p_value > ALPHA / 18), lm.p_value
    assert set(sw.fits) == set(ds.robot.legs) and sw.flagged == ()
    for f in sw.fits.values():
        assert abs(f.theta[0]) < 0.02 and abs(f.theta[1]) < 0.06      # N: weight and moment as hung
        assert abs(f.z_weight) < sw.z_bound and abs(f.z_moment) < sw.z_bound
    assert "no leg's readings need more" in res.statements[0]


# ----------------------------------------------------------------------------- injected faults: the right leg and kind


def _only(res: PerLegFindings, leg: str):
    assert res.legs == (leg,), [f.statement for f in res.findings]


def test_swapped_force_axes_after_hanging_are_named():
    _, _, res = session(FAULT_SEED, "swap_fxfy_ML")
    _only(res, "ML")
    lm = res.linear_map
    assert lm.flagged == ("ML",)
    m = lm.maps["ML"]
    assert "force" in m.parts and m.improper("force")
    assert np.array_equal(m.perm["force"], SWAP_XY)
    assert lm.steps[0].best("ML")[1] < 0.05                      # held-out RSS down by > 20x
    f = next(f for f in res.findings if f.kind == "linear_map")
    assert "fx and fy swapped" in f.statement and {"fx", "fy"} <= set(f.components) and "fz" not in f.components


def test_sign_flipped_axis_in_every_recording_is_named():
    _, _, res = session(FAULT_SEED, "flip_fy_HR")
    _only(res, "HR")
    m = res.linear_map.maps["HR"]
    assert m.improper("force")
    np.testing.assert_array_equal(m.perm["force"], np.diag([1.0, -1.0, 1.0]))
    if "torque" in m.parts:                                      # the torques were not touched
        np.testing.assert_array_equal(m.perm["torque"], np.eye(3))
    f = next(f for f in res.findings if f.kind == "linear_map")
    assert "fy sign-flipped" in f.statement and "fy" in f.components


def test_gain_error_after_hanging_is_named_with_its_size():
    _, _, res = session(FAULT_SEED, "gain_fz_FL")
    _only(res, "FL")
    m = res.linear_map.maps["FL"]
    assert m.parts[0] == "force" and not m.improper("force")
    gains, se = m.values[:3], m.bse.to_numpy()[:3]
    assert abs(gains[2] - 1.03) < 0.002 and se[2] < 0.001
    assert np.all(np.abs(gains[:2] - 1.0) < np.maximum(4 * se[:2], 0.005))   # the horizontal axes are less determined
    f = next(f for f in res.findings if f.kind == "linear_map")
    assert "fz gain" in f.statement and f.components == ("fz",)
    # the swing phases see the same gain as a heavier leg, and say where it comes from
    sw = next((f for f in res.findings if f.kind == "swing"), None)
    if sw is not None:
        assert sw.leg == "FL" and "linear-map finding" in sw.statement


@pytest.mark.parametrize("fault", ["mass50_HL", "mass50walk_HL"])
def test_point_mass_on_a_leg_is_a_changed_leg(fault):
    _, run, res = session(FAULT_SEED, fault)
    _only(res, "HL")
    assert res.linear_map.flagged == ()
    sw = res.swing
    assert sw.flagged == ("HL",)
    f = sw.fits["HL"]
    assert abs(f.theta[0] - 0.05 * run.calibration.g) < 0.03      # N: 50 g
    assert f.z_weight > sw.z_bound and f.theta[1] > f.theta[0]      # placed farther out than the leg's CoM
    st = next(x for x in res.findings if x.kind == "swing").statement
    assert st.startswith("Leg HL weighs") and "more than when it hung" in st and "changed after it hung" in st


# ----------------------------------------------------------------------------- what is missing: said, never a crash


def test_missing_walking_and_few_samples_are_said_not_crashed():
    ds, run, _ = session(CLEAN_SEEDS[0])
    no_walk = replace(ds, recordings=tuple(r for r in ds.recordings if r.kind != "walking"))
    res = perleg_checks(no_walk, run.calibration, run.poses, ds.robot, folds=5, seed=0)
    assert res.swing.fits == {} and any("no walking recordings" in s for s in res.statements)
    few = swing_check(ds, run.calibration, ds.robot, min_samples=10**6)
    assert few.fits == {} and len(few.notes) == len(ds.robot.legs) and "swing samples" in few.notes[0]
    blind = _modify(ds, ("walking",), lambda r: replace(r, quat=np.full_like(r.quat, np.nan)))
    sw = swing_check(blind, run.calibration, ds.robot)
    assert sw.fits == {} and sw.notes and "no swing phases" in sw.notes[0]
    lm = linear_map_check(run.poses.subset(np.arange(12)), run.calibration, ds.robot, folds=5, seed=0)
    assert lm.steps == () and "too few" in lm.note
    res = perleg_checks(ds, run.calibration, None, ds.robot, folds=5, seed=0)
    assert res.linear_map.n_poses == 0 and any("too few" in s for s in res.statements)
    assert "Per-leg checks" in res.summary().as_text()


# ----------------------------------------------------------------------------- results protocol and speed


def test_results_protocol_and_summaries():
    _, _, res = session(FAULT_SEED, "gain_fz_FL")
    lm, sw = res.linear_map, res.swing
    m = lm.maps["FL"]
    assert isinstance(m, LegMap)
    assert len(m.params) == 18 and m.params.index[2] == "FL.force_gain.fz"
    assert np.isnan(m.bse["FL.torque_gain.tz"]) == ("torque" not in m.parts)
    ci = m.conf_int()
    assert ci.loc["FL.force_gain.fz", "lower"] < 1.03 < ci.loc["FL.force_gain.fz", "upper"] + 0.001
    assert len(lm.params) == 18 * len(lm.legs) and len(lm.bse) == len(lm.params)
    f = sw.fits["ML"]
    assert list(f.params.index[:2]) == ["ML.dW_N", "ML.kappa_N"] and np.all(f.bse.iloc[:4] > 0)
    assert f.cov_params().shape == (7, 7)
    for s in (m.summary(), lm.summary(), f.summary(), sw.summary(), res.summary()):
        for text in (s.as_text(), s.as_html(), s.as_latex()):
            assert len(text) > 50
    assert "FL" in lm.summary().as_text() and "fz gain" in lm.table().loc["FL", "what the map shows"]


def test_checks_are_fast():
    ds, run, _ = session(CLEAN_SEEDS[0])
    t0 = time.perf_counter()
    perleg_checks(ds, run.calibration, run.poses, ds.robot, folds=5, seed=0)
    assert time.perf_counter() - t0 < 3.0
