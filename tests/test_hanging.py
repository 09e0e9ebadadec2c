"""Hanging calibration (issue 4): exact compression, numpy/CasADi twins, the baseline's smoother,
recovery of the sample's and the simulator's truth within the reported standard errors, standard
errors against the spread over seeds, NLP against the report's method, and thin or bad data."""

import time
from dataclasses import FrozenInstanceError, replace

import casadi as ca
import numpy as np
import pytest

from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.core.data import Recording, read_dataset
from ftcal_nlp.core.geometry import is_rotation, rotation_to_rotvec, rotvec_to_rotation, skew
from ftcal_nlp.estimate.hanging import (
    HangingDataError,
    HangingResult,
    HangingSolveError,
    fit_hanging,
    hanging_residuals,
)
from ftcal_nlp.estimate.hanging import nlp as nlp_module
from ftcal_nlp.estimate.hanging.baseline import kalman_smoother_random_walk
from ftcal_nlp.estimate.hanging.binning import compress_recording, interp_matrix, periodic_grid
from ftcal_nlp.estimate.hanging.com_qp import ComQP, prior, solve_closed_form, torque_design, penalty
from ftcal_nlp.estimate.hanging.model import LegState, pseudo_residuals, pseudo_residuals_sx
from ftcal_nlp.estimate.hanging.problem import build_leg_problem, check_recordings
from ftcal_nlp.core.robot import Robot, Transducer
from ftcal_nlp.sim import SimConfig, simulate

from conftest import SAMPLE, require_sample, requires_sample

G = 72
RZ_PI = np.diag([-1.0, -1.0, 1.0])  # right-side transducers of the sample: +x in B is -x in ft


# ----------------------------------------------------------------------------- a tiny hanging generator


def tiny_hanging(seed, *, gravity=((1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, 0, -1)), rotations=None, n=1500, turns=2.0,
                 tilt_deg=2.0, phi_path=None):
    """Hanging recordings following DATA_FORMAT.md exactly, with their truth.

    force = m g u_ft, torque = r(phi) x force (about the ft origin), u_ft = R_k^T R_tilt gravity_body,
    R_k the true rotation (nominal times a ~1 deg mounting error), a random ``tilt_deg`` tilt per
    recording, offsets added, Gaussian noise 0.05 N / 0.003 N*m. ``phi_path(leg, j, n)`` overrides
    the shaft angle (default ``turns`` full turns from a random phase).
    """
    rng = np.random.default_rng(seed)
    rotations = rotations or {"L": np.eye(3), "R": RZ_PI}
    legs = tuple(rotations)
    robot = Robot("tiny", 3.0, 9.81, legs, {k: Transducer(k, np.zeros(3), np.asarray(R, float)) for k, R in rotations.items()})
    truth = {}
    for k in legs:
        truth[k] = dict(
            offset=rng.normal(0.0, [1.0, 1.0, 1.0, 0.1, 0.1, 0.1]),
            mg=6.0 + rng.normal(0.0, 0.2),
            R=robot.transducers[k].rotation @ rotvec_to_rotation(rng.normal(0.0, np.radians(1.0), 3)),
            amp=np.array([0.03, 0.0, 0.018]),
            phase=rng.uniform(0, 2 * np.pi),
            mean=np.array([rng.normal(0, 0.01), 0.044, -0.12]),
        )

    def com(k, phi):
        tk = truth[k]
        return tk["mean"] + tk["amp"] * np.stack([np.sin(phi + tk["phase"]), np.zeros_like(phi), np.cos(phi + tk["phase"])], -1)

    recs = []
    for j, gb in enumerate(gravity):
        gb = np.asarray(gb, float) / np.linalg.norm(gb)
        axis = np.cross(gb, rng.normal(size=3))
        R_tilt = rotvec_to_rotation(axis / np.linalg.norm(axis) * np.radians(tilt_deg))
        t = 100.0 * j + np.arange(n) * 0.01
        phi, wrench = {}, {}
        for k in legs:
            tk = truth[k]
            phi[k] = phi_path(k, j, n) if phi_path else rng.uniform(0, 2 * np.pi) + np.linspace(0, 2 * np.pi * turns, n)
            u = tk["R"].T @ R_tilt @ gb
            f = np.broadcast_to(tk["mg"] * u, (n, 3))
            w = np.hstack([f, np.cross(com(k, phi[k]), f)]) + tk["offset"]
            wrench[k] = w + rng.normal(0.0, 1.0, (n, 6)) * np.array([0.05] * 3 + [0.003] * 3)
        recs.append(Recording(f"rec{j}", "hanging", t, phi, wrench, None, gb))
    for k in legs:
        truth[k]["com_grid"] = com(k, periodic_grid(G))
    return recs, robot, truth


def zscores(res, truth_offset, truth_mg, truth_com):
    """(offset z (6,), weight z, CoM z (G, 3)) of one leg's result against the truth."""
    return ((res.offset - truth_offset) / res.offset_se, (res.leg_weight_N - truth_mg) / res.leg_weight_se_N,
            (res.com_xyz - truth_com) / res.com_xyz_se)


def assert_com_within_3se(z, where):
    """Grid values within 3 se: with ~200 values per leg the Gaussian expectation of |z| > 3 is 0.27 %,
    so at most 1 % may exceed it, and their RMS must be that of unit normals (0.6..1.4)."""
    z = z[np.isfinite(z)]
    frac, rms = np.mean(np.abs(z) > 3), np.sqrt(np.mean(z**2))
    assert frac <= 0.01 and 0.6 <= rms <= 1.4, f"{where}: CoM z beyond 3 in {frac:.1%} of {z.size}, RMS {rms:.2f}"


# ----------------------------------------------------------------------------- exactness and twins


def test_compression_is_exact():
    rng = np.random.default_rng(0)
    phi = rng.uniform(-3, 20, 3000)
    y = rng.normal(size=(3000, 6)) * [1, 2, 3, 0.1, 0.2, 0.3]
    st = compress_recording("x", phi, y, G)
    Wx = interp_matrix(phi, G)
    for _ in range(3):
        M = rng.normal(size=(6, G))
        raw = np.sum((y - Wx @ M.T) ** 2, axis=0)
        comp = np.sum((st.Y - st.X @ M.T) ** 2, axis=0) + st.pure_rss
        np.testing.assert_allclose(comp, raw, rtol=1e-9)
    np.testing.assert_allclose(st.x1, st.X @ np.ones(G), rtol=1e-12)
    np.testing.assert_allclose(st.support, Wx.sum(axis=0), rtol=1e-12)


@pytest.fixture(scope="module")
def tiny():
    return tiny_hanging(3)


def test_numpy_and_casadi_residuals_agree(tiny):
    recs, robot, _ = tiny
    pb = build_leg_problem("R", recs, robot, check_recordings(recs, robot), G)
    rng = np.random.default_rng(1)
    s = LegState(rotvec_to_rotation(rng.normal(0, 0.1, (4, 3))), 6.1, rng.normal(size=6), rng.normal(0, 0.05, (G, 3)))
    f = s.forces(pb.a)
    res_sx = pseudo_residuals_sx([ca.DM(st.Y.T) for st in pb.stats], [ca.DM(st.x1).T for st in pb.stats],
                                 [ca.DM(fj) for fj in f], ca.DM(s.w_o), [ca.DM((st.X @ s.r).T) for st in pb.stats])
    for a, b in zip(pseudo_residuals(pb, s), res_sx):
        np.testing.assert_allclose(np.asarray(b).T, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())


def test_kalman_smoother_is_the_rts_smoother():
    rng = np.random.default_rng(2)
    N, q, r, p0 = 40, 0.01, 0.01, 1.0
    H = -skew(rng.normal(0, 6, (N, 3)))
    y = rng.normal(0, 0.5, (N, 3))
    # textbook Kalman filter + Rauch-Tung-Striebel smoother, random-walk state
    m, P, ms, Ps, mp, Pp = np.zeros(3), np.eye(3) * p0, [], [], [], []
    for i in range(N):
        if i:
            m, P = m, P + q * np.eye(3)
        mp.append(m), Pp.append(P)
        S = H[i] @ P @ H[i].T + r * np.eye(3)
        K = P @ H[i].T @ np.linalg.inv(S)
        m, P = m + K @ (y[i] - H[i] @ m), (np.eye(3) - K @ H[i]) @ P
        ms.append(m), Ps.append(P)
    xs = [ms[-1]]
    for i in range(N - 2, -1, -1):
        C = Ps[i] @ np.linalg.inv(Pp[i + 1])
        xs.insert(0, ms[i] + C @ (xs[0] - mp[i + 1]))
    np.testing.assert_allclose(kalman_smoother_random_walk(y, H, q, r, p0), np.array(xs), atol=1e-9)


def test_com_qp_cvxpy_matches_closed_form(tiny):
    recs, robot, truth = tiny
    pb = build_leg_problem("L", recs, robot, check_recordings(recs, robot), G)
    f = np.stack([truth["L"]["mg"] * truth["L"]["R"].T @ r.gravity_body for r in recs])
    W_tau = np.full(3, 1 / 0.003**2)
    A, b, _ = torque_design(pb, f, W_tau)
    lam = 1e9
    z_np = solve_closed_form(A, b, lam, G, pb.prior_precision)
    z_cp = ComQP("L", G, pb.prior_precision).solve(A, b, lam)
    sd = np.sqrt(np.diag(np.linalg.inv(A.T @ A + lam * penalty(G) + prior(G, pb.prior_precision))))
    assert np.max(np.abs(z_cp - z_np) / sd) < 0.01  # the solvers agree far inside one standard error


def test_smoothing_weight_acts(tiny):
    recs, robot, truth = tiny
    one = replace(robot, legs=("L",))
    stiff = fit_hanging(recs, one, smoothing=1e13).legs["L"]
    auto = fit_hanging(recs, one).legs["L"]
    amp_true = np.ptp(truth["L"]["com_grid"][:, 0])
    assert np.ptp(stiff.com_xyz[:, 0]) < 0.1 * amp_true  # a huge penalty flattens the curve
    assert abs(np.ptp(auto.com_xyz[:, 0]) - amp_true) < 0.05 * amp_true  # GCV keeps it


# ----------------------------------------------------------------------------- the sample (someone else's simulator)


@pytest.fixture(scope="module")
def sample():
    ds = read_dataset(require_sample() / "dataset.toml", kinds=["hanging"])
    truth = Calibration.load(SAMPLE / "truth.json", g=ds.robot.g)
    t0 = time.perf_counter()
    nlp = fit_hanging(ds.hanging, ds.robot)
    t_nlp = time.perf_counter() - t0
    base = fit_hanging(ds.hanging, ds.robot, method="baseline")
    return ds, truth, nlp, base, t_nlp


def test_sample_recovery_within_3se(sample):
    ds, truth, res, base, t_nlp = sample
    print(f"\nsample, NLP: {t_nlp:.2f} s for {len(res.legs)} legs")
    print("leg  offset err/se (fx fy fz tx ty tz)        mg err/se  CoM max|z| RMS z  time s  |df_o| nlp/base mN")
    for k, l in res.legs.items():
        tr = truth.legs[k]
        zo, zm, zc = zscores(l, tr.offset, tr.leg_weight_N, tr.com_xyz)
        dn = 1e3 * np.linalg.norm(l.offset[:3] - tr.offset[:3])
        db = 1e3 * np.linalg.norm(base.legs[k].offset[:3] - tr.offset[:3])
        print(f"{k:4} {np.array2string(zo, precision=2, suppress_small=True):40} {zm:7.2f}  {np.nanmax(np.abs(zc)):6.2f} "
              f"{np.sqrt(np.nanmean(zc**2)):5.2f}  {l.solve_time_s:6.2f}  {dn:.2f} / {db:.2f}")
        assert l.converged and not l.warnings
        assert np.all(np.abs(zo) <= 3), f"{k}: offset z {zo}"
        assert abs(zm) <= 3, f"{k}: weight z {zm}"
        assert_com_within_3se(zc, k)
        np.testing.assert_allclose(l.noise_sd, [0.05] * 3 + [0.0025] * 3, rtol=0.05)  # the sample's noise


def test_sample_misalignments_are_exact_rotations_in_the_gauge(sample):
    ds, _, res, _, _ = sample
    for k, l in res.legs.items():
        for rec in ds.hanging:
            R = l.misalignment[rec.name]
            a = ds.robot.transducers[k].rotation.T @ rec.gravity_body
            assert is_rotation(R, tol=1e-8)
            assert abs(rotation_to_rotvec(R) @ a) < 1e-8  # rotation axis perpendicular to the gravity axis
            assert 0.1 < np.degrees(np.linalg.norm(rotation_to_rotvec(R))) < 10  # tilt plus mounting error


def test_sample_residuals_show_the_misalignment(sample):
    ds, _, res, _, _ = sample
    with_m = hanging_residuals(res, ds.hanging, ds.robot)
    without = hanging_residuals(res, ds.hanging, ds.robot, with_misalignment=False)
    for k, l in res.legs.items():
        assert with_m[k].shape == (sum(r.n for r in ds.hanging), 6)
        np.testing.assert_allclose(np.sqrt(np.mean(with_m[k] ** 2, axis=0)), l.residual_rms, rtol=1e-6)
        np.testing.assert_allclose(l.residual_rms, l.noise_sd, rtol=0.02)
        # the report's Fig. 5: without the hanging misalignment the forces leak m g sin(tilt)
        assert np.sqrt(np.mean(without[k][:, :3] ** 2, axis=0)).max() > 1.5 * l.noise_sd[:3].max()


def test_result_objects(sample):
    ds, _, res, base, _ = sample
    assert isinstance(res, HangingResult) and res.method == "nlp" and base.method == "baseline"
    summ = res.summary()
    text = summ.as_text()
    assert all(k in text for k in ds.robot.legs) and "±" in text and "leg weight m g [N]" in text
    assert "<table" in summ.as_html() and "$\\pm$" in summ.as_latex()
    tab = res.table()
    assert tab.shape == (7, 6) and list(tab.columns) == list(ds.robot.legs) and tab.index.name == "parameter"
    # results protocol: labelled params, bse, covariance and intervals agree with the per-leg fields
    p, se, cov = res.params, res.bse, res.cov_params()
    l = res.legs["FL"]
    assert p["FL.mg"] == l.leg_weight_N and se["FL.mg"] == l.leg_weight_se_N
    np.testing.assert_array_equal(p[[f"FL.w_o.{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]], l.offset)
    assert list(cov.index) == list(p.index) and cov.shape == (len(p), len(p))
    fin = np.isfinite(se.to_numpy())
    np.testing.assert_allclose(np.sqrt(np.diag(cov.to_numpy())[fin]), se.to_numpy()[fin], rtol=1e-9)
    assert cov.loc["FL.mg", "ML.mg"] == 0.0  # legs are independent
    ci = res.conf_int(0.05)
    np.testing.assert_allclose(ci.loc["FL.mg", "upper"] - p["FL.mg"], 1.959964 * se["FL.mg"], rtol=1e-5)
    tilt = np.linalg.norm(p[[f"FL.tilt[{ds.hanging[0].name}].{c}" for c in "xyz"]])
    assert abs(np.degrees(tilt) - l.misalignment_deg()[ds.hanging[0].name][0]) < 1e-9
    cal = res.to_calibration(ds.robot)
    for k in ds.robot.legs:
        np.testing.assert_array_equal(cal.legs[k].rotation_to_body, ds.robot.transducers[k].rotation)
        np.testing.assert_array_equal(cal.legs[k].position_from_com_m, ds.robot.transducers[k].position_m)
        np.testing.assert_array_equal(cal.legs[k].offset, res.legs[k].offset)
    assert cal.com_body_m is None
    with pytest.raises(FrozenInstanceError):
        res.legs["FL"].leg_weight_N = 0.0
    assert "baseline" in base.summary().as_text() and np.isinf(base.bse).sum() == 0


# ----------------------------------------------------------------------------- the simulator, several seeds

SEEDS = range(6)


@pytest.fixture(scope="module")
def sim_runs():
    runs = []
    for seed in SEEDS:
        sim = simulate(SimConfig(seed=seed, hanging_cycles=2, n_poses=1, walk_cycles=0.0, rate_hz=50.0))
        robot = replace(sim.dataset.robot, legs=("FL", "FR"))  # a left and a turned right transducer
        runs.append((sim, fit_hanging(sim.dataset.hanging, robot), fit_hanging(sim.dataset.hanging, robot, method="baseline")))
    return runs


def test_sim_recovery_and_standard_errors_match_spread(sim_runs):
    err, se = [], []
    for sim, res, _ in sim_runs:
        for k, l in res.legs.items():
            tr = sim.truth.legs[k]
            zo, zm, zc = zscores(l, tr.offset, tr.leg_weight_N, tr.com_xyz)
            assert np.all(np.abs(zo) <= 3) and abs(zm) <= 3, f"seed {sim.config.seed} {k}: {zo} {zm}"
            assert_com_within_3se(zc, f"seed {sim.config.seed} {k}")
            err.append(np.r_[l.offset - tr.offset, l.leg_weight_N - tr.leg_weight_N, (l.com_xyz - tr.com_xyz).ravel()])
            se.append(np.r_[l.offset_se, l.leg_weight_se_N, l.com_xyz_se.ravel()])
    err, se = np.array(err), np.array(se)
    # spread over seeds (2 legs x 6 seeds) against the mean reported se, pooled per group of numbers
    ratio = err.std(axis=0) / se.mean(axis=0)
    groups = {"force offset": slice(0, 3), "torque offset": slice(3, 6), "weight": slice(6, 7), "CoM grid": slice(7, None)}
    for name, sl in groups.items():
        r = float(np.exp(np.mean(np.log(ratio[sl]))))
        print(f"{name}: spread over seeds / reported se = {r:.2f}")
        assert 0.5 <= r <= 2.0, f"{name}: spread/se = {r:.2f}"


def test_nlp_offsets_beat_the_report_method_with_2deg_tilt(sim_runs, sample):
    def errors(pairs):
        """Mean over legs of |df_o| (mN), |dtau_o| (mN*m) and |d mg| (mN) for (result, truth calibration) pairs."""
        e = [(np.linalg.norm(r.legs[k].offset[:3] - t.legs[k].offset[:3]), np.linalg.norm(r.legs[k].offset[3:] - t.legs[k].offset[3:]),
              abs(r.legs[k].leg_weight_N - t.legs[k].leg_weight_N)) for r, t in pairs for k in r.legs]
        return 1e3 * np.mean(e, axis=0)

    assert all(sim.config.hanging_tilt_deg == 2.0 for sim, _, _ in sim_runs)
    ds, truth, res, base, _ = sample
    rows = {"simulator (2 deg tilt, 6 seeds x 2 legs)": (errors([(r, s.truth) for s, r, _ in sim_runs]), errors([(b, s.truth) for s, _, b in sim_runs])),
            "sample (6 legs)": (errors([(res, truth)]), errors([(base, truth)]))}
    print("\nmean error            |df_o| mN      |dtau_o| mN*m     |d mg| mN      (NLP / baseline)")
    for name, (n, b) in rows.items():
        print(f"{name}: " + "   ".join(f"{x:.3f} / {y:.3f}" for x, y in zip(n, b)))
        assert np.all(n < b), f"{name}: NLP {n} not below baseline {b}"


# ----------------------------------------------------------------------------- other axes, thin and bad data


def test_general_gravity_axes_and_transducer_rotation():
    tilted = rotvec_to_rotation([0.3, -0.5, 1.0])
    s2 = 1 / np.sqrt(2)
    recs, robot, truth = tiny_hanging(5, gravity=((s2, s2, 0), (-s2, -s2, 0), (0, 0.6, 0.8), (0, -0.6, -0.8)),
                                      rotations={"T": tilted}, n=2000)
    l = fit_hanging(recs, robot).legs["T"]
    zo, zm, zc = zscores(l, truth["T"]["offset"], truth["T"]["mg"], truth["T"]["com_grid"])
    assert np.all(np.abs(zo) <= 3) and abs(zm) <= 3, (zo, zm)
    assert_com_within_3se(zc, "T")


@requires_sample
def test_single_pair_leaves_the_com_line_unidentified(caplog):
    ds = read_dataset(SAMPLE / "dataset.toml", kinds=["hanging"])
    truth = Calibration.load(SAMPLE / "truth.json", g=ds.robot.g)
    robot = replace(ds.robot, legs=("FL", "FR"))
    x_pair = [r for r in ds.hanging if r.name in ("hang_xpos", "hang_xneg")]
    res = fit_hanging(x_pair, robot)
    logged = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert sum("CoM along ft x unidentified: only one opposite pair" in m for m in logged) == 2, logged  # once per leg
    for k, l in res.legs.items():
        assert any(w.startswith(f"leg {k}: CoM along ft x unidentified: only one opposite pair (gravity along ft x)") for w in l.warnings)
        assert np.isnan(l.com_xyz[:, 0]).all() and np.isfinite(l.com_xyz[:, 1:]).all()
        assert np.isnan(l.com_xyz_se[:, 0]).all() and not l.com_mask[:, 0].any()
        assert np.isfinite(l.offset[0]) and np.isnan(l.offset[1:]).all()  # only f_x along the axis
        # what is reported holds to first order in the tilt: m g (1 - cos 5 deg) < 0.025 N
        assert abs(l.leg_weight_N - truth.legs[k].leg_weight_N) < 0.025
        assert np.nanmax(np.abs(l.com_xyz[:, 1:] - truth.legs[k].com_xyz[:, 1:])) < 0.005  # |r_x| sin 5 deg


@requires_sample
def test_no_opposite_pair_is_an_error():
    ds = read_dataset(SAMPLE / "dataset.toml", kinds=["hanging"])
    no_pair = [r for r in ds.hanging if r.name in ("hang_xpos", "hang_zpos")]
    with pytest.raises(HangingDataError, match="hang_xpos.*no opposite"):
        fit_hanging(no_pair, ds.robot)
    with pytest.raises(HangingDataError, match="no hanging recordings"):
        fit_hanging([], ds.robot)


def test_leg_that_never_turns_is_an_error():
    recs, robot, _ = tiny_hanging(6, phi_path=lambda k, j, n: np.full(n, 0.3) if k == "R" else np.linspace(0, 4 * np.pi, n))
    with pytest.raises(HangingDataError, match=r"leg R: the shaft never turns.*rec0"):
        fit_hanging(recs, robot)


def test_partial_turn_reports_com_only_where_supported(caplog):
    # leg L sweeps back and forth over [0.5, 3.5] rad only
    recs, robot, truth = tiny_hanging(7, n=2400, phi_path=lambda k, j, n: 2.0 + 1.5 * np.sin(np.linspace(0, 6 * np.pi, n) + j))
    l = fit_hanging(recs, replace(robot, legs=("L",))).legs["L"]
    assert any("leg L: no data near" in r.getMessage() for r in caplog.records if r.levelname == "WARNING")
    grid = l.com_phi
    inside = (grid > 0.5 + 2 * np.pi / G) & (grid < 3.5 - 2 * np.pi / G)
    outside = (grid < 0.5 - 2 * np.pi / G) | (grid > 3.5 + 2 * np.pi / G)
    assert l.com_mask[inside].all() and not l.com_mask[outside].any()
    assert np.isnan(l.com_xyz[outside]).all() and np.isfinite(l.com_xyz[inside]).all()
    np.testing.assert_array_equal(np.isfinite(l.com_xyz), l.com_mask)
    zo, zm, zc = zscores(l, truth["L"]["offset"], truth["L"]["mg"], truth["L"]["com_grid"])
    assert np.all(np.abs(zo) <= 3) and abs(zm) <= 3, (zo, zm)
    assert_com_within_3se(zc, "partial L")


def test_bad_arguments_and_recordings(tiny):
    recs, robot, _ = tiny
    with pytest.raises(ValueError, match=r"unknown hanging method 'qp'.*\['nlp', 'baseline'\]"):
        fit_hanging(recs, robot, method="qp")
    standing = replace(recs[0], kind="standing")
    with pytest.raises(HangingDataError, match="rec0: recording of kind 'standing'"):
        fit_hanging([standing] + recs[1:], robot)
    with pytest.raises(ValueError, match="smoothing"):
        fit_hanging(recs, robot, smoothing="gcv")


def test_ipopt_failure_is_reported(tiny, monkeypatch):
    recs, robot, _ = tiny
    monkeypatch.setitem(nlp_module._IPOPT, "max_iter", 1)
    with pytest.raises(HangingSolveError, match=r"leg L: IPOPT failed.*\['rec0', 'rec1', 'rec2', 'rec3'\]"):
        fit_hanging(recs, robot)


@requires_sample
def test_no_smoothing_is_allowed():
    """smoothing=0 (no penalty) is a valid setting: the fit runs and still recovers the weights."""
    from conftest import SAMPLE
    from ftcal_nlp.core.data import read_dataset

    ds = read_dataset(SAMPLE / "dataset.toml", kinds=["hanging"])
    truth = Calibration.load(SAMPLE / "truth.json", g=9.81)
    res = fit_hanging(ds.hanging, ds.robot, smoothing=0.0)
    for k, l in res.legs.items():
        assert abs(l.leg_weight_N - truth.legs[k].leg_weight_N) < 4 * l.leg_weight_se_N
