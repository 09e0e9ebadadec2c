"""Accuracy: errors of each parameter group over many simulated datasets, against the Cramer-Rao bound.

For every seed the simulator draws a new true robot and new noise; both
pipelines calibrate it:

* ``nlp``: hanging ``method="nlp"``, standing ``solver="ipopt"``, exact balance (physics.py (E));
* ``baseline``: the report's method, hanging ``method="baseline"``, standing
  ``solver="baseline"`` (Cayley + alternating least squares), report balance (eq. 9).

Both fit the ``full`` error model (the simulator's truth has a rotation and a
translation error on every transducer). Groups and their errors (estimate
minus truth):

* ``offsets``: ``w_o,k`` (6 per leg, N and N*m), ``leg_weights``: ``m_k g`` (N),
  ``com_curves``: ``r_k`` on the 72-point grid (m, ft_k), against the bound for
  unbiased grid values, and again (``com_curves_vs_sinusoid``) against the bound
  of the simulator's own curve family (a sinusoid in x and z, constant y), which
  an estimator that knew that family could reach;
* ``rotations``: ``rotvec(R_k,est R_k,true^T)`` (rad, B axes), ``translations``:
  ``p'_k`` relative to the body-without-legs CoM (m, B axes);
* ``com``: the total CoM relative to the body-without-legs CoM with every leg at
  ``phi = 0`` (``physics.total_com_from_body_com``): the body CoM itself is not
  identifiable with six free translations, the total CoM (what the correction of
  walking data moves its torques to) is.

Each error is divided by its bound (crb/hexapod.py): ``z = e / sd_CRB``; standing
errors first have their unidentifiable components removed (``Bound.project``).
A group's ratio is ``sqrt(mean z^2)`` over its parameters and the datasets: 1
for an efficient unbiased estimator. The Mahalanobis version
``sqrt(mean_d e_g^T C_gg^+ e_g / rank)`` accounts for correlations within a group.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..core.geometry import rotation_to_rotvec
from ..core.physics import total_com_from_body_com
from ..pipeline import calibrate
from ..core.settings import CalibrationSettings, DiagnoseSettings, HangingSettings, StandingSettings
from ..crb import DatasetBounds, dataset_bounds

GROUPS = ("offsets", "leg_weights", "com_curves", "com_curves_vs_sinusoid", "rotations", "translations", "com")
GROUP_UNITS = {"offsets": "N, N*m", "leg_weights": "N", "com_curves": "mm", "com_curves_vs_sinusoid": "mm", "rotations": "deg",
               "translations": "mm", "com": "mm"}

PIPELINES = {
    "nlp": {"hanging": "nlp", "solver": "ipopt", "balance": "exact", "weighting": "fgls"},
    # ablation: the NLP with eq. 8's fixed K-norm instead of the feasible-GLS weighting
    "nlp_knorm": {"hanging": "nlp", "solver": "ipopt", "balance": "exact", "weighting": "knorm"},
    "baseline": {"hanging": "baseline", "solver": "baseline", "balance": "report"},
    # ablations: which part of the baseline's error is the balance (eq. 9), which the solvers
    "baseline_exact_balance": {"hanging": "baseline", "solver": "baseline", "balance": "exact"},
    "nlp_report_balance": {"hanging": "nlp", "solver": "ipopt", "balance": "report"},
}


@dataclass(frozen=True)
class AccuracySettings:
    """Datasets of the accuracy bench: ``seeds`` and the reduced simulation sizes (see module docstring)."""

    seeds: tuple[int, ...] = tuple(range(20))
    hanging_cycles: float = 3.0
    n_poses: int = 250
    model: str = "full"
    pipelines: tuple[str, ...] = ("nlp", "baseline")
    sim_overrides: dict = field(default_factory=dict)

    def sim_config(self, seed: int):
        from ..sim import SimConfig

        return SimConfig(seed=seed, hanging_cycles=self.hanging_cycles, n_poses=self.n_poses, walk_cycles=0.0, **self.sim_overrides)


def _rows(seed, pipeline, group, legs_labels, err, sd, extra=None) -> list[dict]:
    out = []
    for i, (leg, lab) in enumerate(legs_labels):
        d = {"seed": seed, "pipeline": pipeline, "group": group, "leg": leg, "param": lab,
             "error": float(err[i]), "crb_sd": float(sd[i]), "z": float(err[i] / sd[i])}
        if extra:
            for k, v in extra.items():
                d[k] = float(v[i])
        out.append(d)
    return out


def _maha(e: np.ndarray, C: np.ndarray) -> tuple[float, int]:
    """``e^T C^+ e`` and the rank of C (relative tolerance 1e-10)."""
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    keep = w > 1e-10 * w.max()
    q = V[:, keep].T @ e
    return float(np.sum(q**2 / w[keep])), int(keep.sum())


def pipeline_errors(seed: int, pipeline: str, hang, stand, sim, bounds: DatasetBounds) -> tuple[list[dict], list[dict]]:
    """Per-parameter rows and per-(group, dataset) Mahalanobis rows of one fitted pipeline."""
    truth = sim.truth
    legs = tuple(sim.dataset.robot.legs)
    K = len(legs)
    hb, sb = bounds.hanging, bounds.standing
    rows, maha = [], []
    # hanging groups
    for k in legs:
        l, t = hang.legs[k], truth.legs[k]
        C = hb.offset_cov(k)
        e = l.offset - t.offset
        rows += _rows(seed, pipeline, "offsets", [(k, c) for c in ("fx", "fy", "fz", "tx", "ty", "tz")], e, np.sqrt(np.diag(C)))
        m2, rk = _maha(e, C)
        maha.append({"seed": seed, "pipeline": pipeline, "group": "offsets", "leg": k, "m2": m2, "rank": rk})
        e = np.array([l.leg_weight_N - t.leg_weight_N])
        sd = np.array([np.sqrt(hb.weight_var(k))])
        rows += _rows(seed, pipeline, "leg_weights", [(k, "mg")], e, sd)
        maha.append({"seed": seed, "pipeline": pipeline, "group": "leg_weights", "leg": k, "m2": float((e[0] / sd[0]) ** 2), "rank": 1})
        sd = hb.com_sd(k)
        e = l.com_xyz - t.com_xyz
        labels = [(k, f"{c}@{g}") for g in range(len(sd)) for c in "xyz"]
        rows += _rows(seed, pipeline, "com_curves", labels, e.ravel(), sd.ravel(), {"model_bias_z": (bounds.interp_bias[k] / sd).ravel()})
        rows += _rows(seed, pipeline, "com_curves_vs_sinusoid", labels, e.ravel(), bounds.com_sd_sin[k].ravel())
    # standing groups (conditional bound; unidentifiable directions projected out)
    R_est = stand.calibration.stacked(legs)[2]
    p_est = stand.calibration.stacked(legs)[3]
    tr = sim.true_robot
    e_rot = rotation_to_rotvec(R_est @ np.swapaxes(tr.R, 1, 2))
    e_p = p_est - tr.p_prime
    e = np.concatenate([e_rot.ravel(), e_p.ravel()])
    e_proj = sb.bound.project(e)
    sd = sb.bound.sd
    refs = sb.reference_covs()
    for name, sl, comps in (("rotations", slice(0, 3 * K), "xyz"), ("translations", slice(3 * K, 6 * K), "xyz")):
        labels = [(k, c) for k in legs for c in comps]
        extra = {key: np.sqrt(np.diag(C))[sl] / sd[sl] for key, C in refs.items()}
        rows += _rows(seed, pipeline, name, labels, e_proj[sl], sd[sl], {**extra, "raw_error": e[sl]})
        m2, rk = _maha(e_proj[sl], sb.bound.cov[sl, sl])
        maha.append({"seed": seed, "pipeline": pipeline, "group": name, "leg": "all", "m2": m2, "rank": rk})
    # total CoM
    zero = np.zeros((1, K))
    e = total_com_from_body_com(zero, stand.calibration)[0] - total_com_from_body_com(zero, truth)[0]
    sd = np.sqrt(np.diag(bounds.com_cov))
    extra = {key: np.sqrt(np.diag(C)) / sd for key, C in bounds.com_ref.items()}
    rows += _rows(seed, pipeline, "com", [("robot", c) for c in "xyz"], e, sd, extra)
    m2, rk = _maha(e, bounds.com_cov)
    maha.append({"seed": seed, "pipeline": pipeline, "group": "com", "leg": "robot", "m2": m2, "rank": rk})
    return rows, maha


def pipeline_settings(pipeline: str, model: str) -> CalibrationSettings:
    """The :func:`ftcal_nlp.calibrate` settings of one pipeline of :data:`PIPELINES` with a fixed ``model``."""
    spec = PIPELINES[pipeline]
    return CalibrationSettings(
        hanging=HangingSettings(method=spec["hanging"], compare_baseline=False),
        standing=StandingSettings(model=model, solver=spec["solver"], balance=spec["balance"],
                                  weighting=spec.get("weighting", "knorm"), compare_baseline=False),
        diagnose=DiagnoseSettings(enabled=False))


def run_pipeline(pipeline: str, sim, poses, model: str = "full"):
    """``calibrate`` with one pipeline's settings; returns ``(HangingResult, StandingResult)``.

    ``poses`` (those the bounds were computed on) must be the run's own: checked."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = calibrate(sim.dataset, pipeline_settings(pipeline, model))
    assert run.poses is not None  # a full calibration of a simulated dataset (it has standing recordings) has poses
    if run.poses.n != poses.n or not np.array_equal(run.poses.w_m, poses.w_m):
        raise RuntimeError(f"pipeline {pipeline}: calibrate extracted other poses than the bound was computed on")
    return run.hanging, run.standing


def evaluate_seed(seed: int, settings: AccuracySettings = AccuracySettings()) -> dict:
    """Simulate one dataset, fit every pipeline, compare with the truth and the bounds.

    Returns ``rows`` (per parameter), ``maha`` (per group), ``info`` (one dict: pose counts,
    dropped directions, the residual check, failures).
    """
    from ..sim import simulate
    from ..estimate.standing import extract_poses

    sim = simulate(settings.sim_config(seed))
    robot = sim.dataset.robot
    poses = extract_poses(sim.dataset.standing[0], robot)
    bounds = dataset_bounds(sim, poses)
    info: dict[str, float | str] = {"seed": seed, "n_poses": poses.n, "hanging_samples": sum(r.n for r in sim.dataset.hanging),
            "standing_dropped_dirs": bounds.standing.bound.n_dropped,
            "hanging_dropped_dirs": int(sum(b.n_dropped for b in bounds.hanging.bounds.values())),
            "pose_residual_check": bounds.standing.residual_check,
            "pose_median_samples": bounds.standing.n_samples_median,
            "pose_orientation_sd_deg": float(np.degrees(bounds.standing.sigma_z_median))}
    rows, maha = [], []
    for name in settings.pipelines:
        try:
            hang, stand = run_pipeline(name, sim, poses, settings.model)
        except RuntimeError as exc:  # a failed solve is a finding: counted, not hidden
            info[f"{name}_failure"] = f"{type(exc).__name__}: {exc}"
            continue
        r, m = pipeline_errors(seed, name, hang, stand, sim, bounds)
        rows += r
        maha += m
    return {"rows": rows, "maha": maha, "info": info}


def summarize(rows: pd.DataFrame, maha: pd.DataFrame) -> pd.DataFrame:
    """One row per (pipeline, group): ratio = sqrt(mean z^2) with its se over datasets, the Mahalanobis
    ratio, the RMS error and RMS bound in the group's unit, and the reference ratios (standing groups)."""
    out = []
    scale = {"com_curves": 1e3, "com_curves_vs_sinusoid": 1e3, "translations": 1e3, "com": 1e3, "rotations": np.degrees(1.0), "leg_weights": 1.0, "offsets": 1.0}
    for (pipe, group), d in rows.groupby(["pipeline", "group"], sort=False):
        per_seed = d.groupby("seed")["z"].apply(lambda z: float(np.mean(z**2)))
        ms = float(per_seed.mean())
        ratio = np.sqrt(ms)
        se = float(per_seed.std(ddof=1) / np.sqrt(len(per_seed)) / (2 * ratio)) if len(per_seed) > 1 else float("nan")
        m = maha[(maha.pipeline == pipe) & (maha.group == group)]
        mr = float(np.sqrt(m.m2.sum() / m["rank"].sum())) if len(m) else float("nan")
        row = {"pipeline": pipe, "group": group, "ratio": ratio, "ratio_se": se, "ratio_mahalanobis": mr,
               "n_datasets": int(d.seed.nunique()), "n_params": int(len(d) / max(d.seed.nunique(), 1)),
               "unit": GROUP_UNITS[group]}
        if group == "offsets":
            for part, comps in (("force", ("fx", "fy", "fz")), ("torque", ("tx", "ty", "tz"))):
                dd = d[d.param.isin(comps)]
                row[f"rms_error_{part}"] = float(np.sqrt(np.mean(dd.error**2)))
                row[f"rms_crb_{part}"] = float(np.sqrt(np.mean(dd.crb_sd**2)))
        row["rms_error"] = float(np.sqrt(np.mean(d.error**2))) * scale[group]
        row["rms_crb"] = float(np.sqrt(np.mean(d.crb_sd**2))) * scale[group]
        row["max_abs_z"] = float(np.abs(d.z).max())
        row["mean_z"] = float(d.z.mean())
        for key, col in (("ls_ratio", "knorm_ls_ratio"), ("two_stage_ratio", "two_stage_ratio"), ("gls_const_ratio", "gls_const_ratio")):
            if key in d and d[key].notna().any():
                row[col] = float(np.sqrt(np.mean(d[key] ** 2)))
        if "model_bias_z" in d and d["model_bias_z"].notna().any():
            row["grid_model_bias_z"] = float(np.sqrt(np.mean(d.model_bias_z**2)))
        out.append(row)
    return pd.DataFrame(out)


def run_accuracy(settings: AccuracySettings = AccuracySettings(), progress: bool = True) -> dict:
    """Every seed of ``settings``; returns ``rows``, ``maha``, ``info`` (DataFrames) and ``summary``."""
    from tqdm import tqdm

    rows, maha, info = [], [], []
    for seed in tqdm(settings.seeds, desc="accuracy (datasets)", disable=not progress):
        r = evaluate_seed(seed, settings)
        rows += r["rows"]
        maha += r["maha"]
        info.append(r["info"])
    rows_df, maha_df = pd.DataFrame(rows), pd.DataFrame(maha)
    return {"rows": rows_df, "maha": maha_df, "info": pd.DataFrame(info), "summary": summarize(rows_df, maha_df),
            "settings": settings}
