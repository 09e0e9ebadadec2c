"""Benchmarks (issue 8): the Cramer-Rao machinery against known answers, and a tiny end-to-end run.

No timing assertions: the bench measures time, the tests only check that what
it computes is right and that it writes its files.
"""

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import crb
from ftcal_nlp.bench.accuracy import summarize
from ftcal_nlp.bench.scaling import fit_exponent, replicate_poses
from ftcal_nlp.core.calibration import periodic_interp
from ftcal_nlp.core.geometry import rotvec_to_rotation
from ftcal_nlp.core.physics import balance_residual_exact
from ftcal_nlp.estimate.standing.poses import Poses


def _gls_monte_carlo(A, sd, theta, n_draws, rng):
    W = 1.0 / sd**2
    M = np.linalg.solve(A.T @ (W[:, None] * A), (A * W[:, None]).T)  # GLS: theta_hat = M y
    Y = A @ theta + rng.standard_normal((n_draws, len(sd))) * sd
    return Y @ M.T


def test_crb_of_linear_gaussian_model_is_the_gls_covariance():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(40, 3))
    sd = rng.uniform(0.5, 2.0, 40)
    theta = np.array([1.0, -2.0, 0.5])
    b = crb.crb(crb.fisher_information(A[:, None, :], sd[:, None, None] ** 2))  # 40 scalar observations
    known = np.linalg.inv(A.T @ (A / sd[:, None] ** 2))
    np.testing.assert_allclose(b.cov, known, rtol=1e-10)
    assert b.n_dropped == 0
    # the GLS estimator attains it: sample variances within 4 se (se of a variance: var sqrt(2/n))
    n = 4000
    est = _gls_monte_carlo(A, sd, theta, n, rng)
    ratio = est.var(axis=0) / np.diag(known)
    assert np.all(np.abs(ratio - 1.0) < 4 * np.sqrt(2.0 / n)), ratio
    np.testing.assert_allclose(est.mean(axis=0), theta, atol=4 * np.sqrt(np.diag(known) / n).max())


def test_crb_drops_an_unidentifiable_direction_and_projects_errors_off_it():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(30, 2))
    A = np.column_stack([A, A[:, 0]])  # third parameter indistinguishable from the first
    F = A.T @ A
    b = crb.crb(F)
    assert b.n_dropped == 1
    null = np.array([1.0, 0.0, -1.0])  # F null = 0
    np.testing.assert_allclose(b.project(null), 0.0, atol=1e-10)
    e = np.array([0.3, -0.2, 0.1])
    pe = b.project(e)
    np.testing.assert_allclose(b.project(pe), pe, atol=1e-12)  # a projection
    np.testing.assert_allclose(F @ (e - pe), 0.0, atol=1e-10)  # only the null part was removed
    # on the identifiable combinations the bound is the ordinary one
    T = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0]])  # theta_1 + theta_3, theta_2
    np.testing.assert_allclose(T @ b.cov @ T.T, np.linalg.inv((A @ np.linalg.pinv(T)).T @ (A @ np.linalg.pinv(T))), rtol=1e-8)


def test_ls_covariance_with_inverse_noise_weight_equals_the_bound():
    rng = np.random.default_rng(2)
    J = rng.normal(size=(50, 6, 4))
    L = rng.normal(size=(6, 6)) * 0.3 + np.eye(6)
    Sigma = L @ L.T
    bound = crb.crb(crb.fisher_information(J, Sigma[None].repeat(50, 0))).cov
    np.testing.assert_allclose(crb.ls_covariance(J, Sigma[None].repeat(50, 0), np.linalg.inv(Sigma)), bound, rtol=1e-8)
    # any other weight can only be worse (Gauss-Markov)
    worse = crb.ls_covariance(J, Sigma[None].repeat(50, 0))
    assert np.all(np.linalg.eigvalsh(worse - bound) > -1e-12)


def _hanging_prediction(theta, phis, us, G):
    """Readings of every sample (sum_j N_j, 6) at theta in crb.HangingLayout order, numpy, via calibration.periodic_interp."""
    J = len(phis)
    lay = crb.HangingLayout(J, G)
    mg = theta[lay.mg]
    w_o = theta[lay.w_o]
    r = theta[2 * J + 7:].reshape(G, 3)
    grid = np.arange(G) * 2 * np.pi / G
    out = []
    for j, (phi, u) in enumerate(zip(phis, us)):
        v = u + crb.tangent_plane(u) @ theta[2 * j: 2 * j + 2]
        f = mg * v / np.linalg.norm(v)
        rr = periodic_interp(phi, grid, r)
        out.append(np.hstack([np.broadcast_to(f, rr.shape), np.cross(rr, f)]) + w_o)
    return np.vstack(out)


def test_hanging_fisher_matches_a_finite_difference_jacobian_of_the_readings():
    rng = np.random.default_rng(3)
    G = 8
    phis = [rng.uniform(0, 4 * np.pi, 150), rng.uniform(0, 4 * np.pi, 170)]
    us = [np.array([0.99, 0.1, 0.05]), np.array([0.05, -0.1, -0.99])]
    us = [u / np.linalg.norm(u) for u in us]
    mg, sigma = 6.2, np.array([0.05, 0.05, 0.05, 0.003, 0.003, 0.003])
    r = rng.normal(0, 0.03, (G, 3)) + [0, 0.04, -0.13]
    theta = np.concatenate([np.zeros(4), [mg], rng.normal(0, 1, 6), r.ravel()])
    h = 1e-6
    cols = []
    for i in range(len(theta)):
        d = np.zeros_like(theta)
        d[i] = h
        cols.append((_hanging_prediction(theta + d, phis, us, G) - _hanging_prediction(theta - d, phis, us, G)) / (2 * h))
    Jfd = np.stack(cols, axis=-1)  # (N, 6, n)
    F_fd = np.einsum("nci,c,ncj->ij", Jfd, 1 / sigma**2, Jfd)
    F = crb.hanging_leg_fisher(phis, us, mg, r, sigma)
    np.testing.assert_allclose(F, F_fd, rtol=1e-5, atol=1e-6 * np.abs(F).max())


def _random_standing(rng, P=5, K=6):
    R = rotvec_to_rotation(rng.normal(0, 0.05, (K, 3))) @ np.diag([1.0, -1.0, -1.0])
    p = rng.normal(0, 0.2, (K, 3))
    off = rng.normal(0, 1, (K, 6))
    w = rng.normal(0, 10, (P, K, 6))
    R_WB = rotvec_to_rotation(rng.normal(0, 0.3, (P, 3)))
    return R, p, off, w, R_WB


def _residual_B(w, R_WB, off, R, p, Mb_g):
    rW = balance_residual_exact(w, R_WB, off, R, p, Mb_g)
    return np.concatenate([np.einsum("pji,pj->pi", R_WB, rW[:, :3]), np.einsum("pji,pj->pi", R_WB, rW[:, 3:])], axis=1)


def test_standing_jacobians_match_finite_differences_of_the_physics_balance():
    rng = np.random.default_rng(4)
    R, p, off, w, R_WB = _random_standing(rng)
    K = len(R)
    m = rng.uniform(5, 7, K)
    Mg = 80.0

    def res(x):
        d, pp, o, mm = x[: 3 * K].reshape(K, 3), x[3 * K: 6 * K].reshape(K, 3), x[6 * K: 12 * K].reshape(K, 6), x[12 * K:]
        return _residual_B(w, R_WB, o, rotvec_to_rotation(d) @ R, pp, Mg - mm.sum())

    x0 = np.concatenate([np.zeros(3 * K), p.ravel(), off.ravel(), m])
    h = 1e-6
    Jfd = np.stack([(res(x0 + h * e) - res(x0 - h * e)) / (2 * h) for e in np.eye(len(x0))], axis=-1)
    J_s, J_h = crb.standing_jacobians(w, R_WB, R, p, off)
    np.testing.assert_allclose(J_s, Jfd[..., : 6 * K], atol=1e-6)
    np.testing.assert_allclose(J_h, Jfd[..., 6 * K:], atol=1e-6)


def test_pose_noise_covariance_matches_monte_carlo():
    rng = np.random.default_rng(5)
    R, p, off, w, R_WB = _random_standing(rng, P=2)
    Mb_g, sigma = 44.0, np.array([0.05, 0.05, 0.05, 0.003, 0.003, 0.003])
    n = np.array([300.0, 150.0])
    sz = np.radians([0.05, 0.1])
    Sig = crb.pose_noise_cov(R, p, R_WB, Mb_g, sigma, n, sz)
    N = 20000
    r0 = _residual_B(w, R_WB, off, R, p, Mb_g)
    for i in range(2):
        wn = w[i] + rng.standard_normal((N,) + w[i].shape) * sigma * np.sqrt(np.pi / (2 * n[i]))
        Rn = R_WB[i] @ rotvec_to_rotation(rng.standard_normal((N, 3)) * sz[i])
        d = _residual_B(wn, Rn, off, R, p, Mb_g) - r0[i]
        emp = d.T @ d / N
        scale = np.sqrt(np.outer(np.diag(Sig[i]), np.diag(Sig[i])))
        # sampling error of a covariance entry: about scale sqrt(2 / N) (0.01); 5 such
        assert np.all(np.abs(emp - Sig[i]) < 5 * np.sqrt(2.0 / N) * scale + 1e-12), np.abs(emp - Sig[i]) / scale


def test_group_ratio_is_one_for_standard_normal_errors():
    rng = np.random.default_rng(6)
    rows = pd.DataFrame({"seed": np.repeat(np.arange(20), 50), "pipeline": "x", "group": "offsets", "leg": "FL",
                         "param": "fx", "crb_sd": 0.1})
    rows["z"] = rng.standard_normal(len(rows))
    rows["error"] = rows.z * rows.crb_sd
    maha = pd.DataFrame({"seed": range(20), "pipeline": "x", "group": "offsets", "leg": "FL", "m2": 50.0, "rank": 50})
    s = summarize(rows, maha).iloc[0]
    assert abs(s.ratio - 1.0) < 4 * s.ratio_se and s.ratio_se < 0.05  # 1000 z values: se ~ 1/sqrt(2000)
    assert s.ratio_mahalanobis == pytest.approx(1.0)


def test_fit_exponent_and_replicated_poses():
    n = np.array([100, 1000, 10000])
    assert fit_exponent(n, 3.0 * n**0.5) == pytest.approx(0.5)
    rng = np.random.default_rng(7)
    base = Poses(rng.normal(size=(7, 6, 6)), rng.normal(size=(7, 6)), np.eye(3)[None].repeat(7, 0), np.arange(7.0),
                 ("a", "b", "c", "d", "e", "f"), {"with_mocap": 7})
    sig = np.full(6, 0.01)
    p = replicate_poses(base, 30, sig)
    assert p.n == 30 and p.legs == base.legs
    d = p.w_m[:28].reshape(4, 7, 6, 6) - base.w_m
    assert 0.008 < d.std() < 0.012  # fresh noise of the requested size on every copy
    assert np.all(np.diff(p.t) != 0)


def test_bench_runs_end_to_end_at_a_tiny_size(tmp_path):
    from ftcal_nlp.bench.runner import run_bench, tiny_settings

    res = run_bench(tiny_settings(), tmp_path, progress=False)
    for name in ("summary.md", "bench.json", "accuracy.csv", "accuracy.md", "accuracy.png", "accuracy_groups.csv",
                 "accuracy_params.csv.gz", "speed.csv", "speed.md", "speed.png", "scaling_points.csv",
                 "scaling_exponents.csv", "scaling.png", "profile_hot_spots.csv", "profile_top_self.csv", "correction_speed.csv", "plan_check.csv"):
        assert (tmp_path / name).is_file() and (tmp_path / name).stat().st_size > 0, name
    text = (tmp_path / "summary.md").read_text()
    for head in ("### Accuracy", "### Speed", "### Scaling", "### Where the time goes", "### Correction", "### Correction speed",
                 "### Plan check"):
        assert head in text
    corr = res["correction"]
    assert list(corr["table"].task) == ["ground wrenches only", "with se and contact state", "with se, contact and tracked offsets"]
    assert np.all(corr["table"].samples_per_s > 0) and (tmp_path / "correction.csv").is_file()
    assert np.isfinite(corr["accuracy"]["ratio_tracked_over_reference_max"])  # accuracy: test_tracking.py
    exp = res["export"]
    assert len(exp["table"]) == 3 and np.all(exp["table"].us_per_sample > 0)
    assert exp["max_abs_diff_N"] < 1e-9  # compiled C and numpy are the same function
    plan = res["plan"]["table"]
    assert set(plan.group) == {"offsets_force", "offsets_torque", "leg_weights", "com_curves", "com_curves_unsmoothed",
                               "rotations", "translations", "total_com"} and np.all(plan.predicted_se > 0)
    acc = res["accuracy"]["summary"]
    assert set(acc.group) == {"offsets", "leg_weights", "com_curves", "com_curves_vs_sinusoid", "rotations", "translations", "com"}
    assert np.all(np.isfinite(acc.ratio)) and np.all(acc.ratio > 0)
    assert res["accuracy"]["info"].standing_dropped_dirs.iloc[0] >= 0
    sc = res["scaling"]["points"]
    assert sc["error"].isna().all(), sc["error"].dropna().tolist()
    assert np.all(np.isfinite(sc.wall_s))
    sp = res["speed"]["times"]
    assert {"load", "poses", "hanging", "model selection", "standing", "report"} <= set(sp.stage)
    check_the_load_parts(res, tmp_path)


def check_the_load_parts(res, out) -> None:
    """The free-load parts of the tiny run ("loads", "load_speed"; once test_bench_loads.py's own second run of them with
    the same settings): their sections, files, speed rows of every estimator, and ratios of the NLP on both loads."""
    text = (out / "summary.md").read_text()
    assert "### Free loads" in text and "### Free-load speed" in text
    for name in ("accuracy_loads_params.csv.gz", "accuracy_loads_datasets.csv", "speed_loads.csv"):
        assert (out / name).is_file(), name
    t = res["load_speed"]["times"]
    done = set(zip(t.problem, t.estimator))
    assert res["load_speed"]["failures"] == {}
    assert done == {("payload", "nlp"), ("payload", "ft_calib"), ("payload", "calib_force"), ("urdf_chain6", "nlp")}
    assert np.all(t.wall_s > 0) and np.all(t.first_call_s > 0)
    acc = res["loads"]
    assert not any(c.endswith("_failure") for c in acc["info"].columns), acc["info"].filter(like="failure")
    s = acc["summary"].set_index(["scenario", "estimator", "group"])
    for key in [("payload_mount", "nlp", g) for g in ("offsets", "mass", "com", "mount_rotation")] + \
               [("urdf_leg", "nlp", g) for g in ("offsets", "total_mass", "first_moments", "mount_rotation")]:
        assert np.isfinite(s.loc[key, "ratio"]) and s.loc[key, "ratio"] > 0, key
    assert not [k for k in s.index if k[0] == "urdf_leg" and k[1] != "nlp"]      # no peer models a URDF load
