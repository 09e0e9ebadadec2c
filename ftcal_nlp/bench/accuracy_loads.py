"""Accuracy on free loads (issue 22, section 5): errors over simulated datasets against the Cramer-Rao bound
(``crb/free_load.py``), the NLP beside the peers' plain least squares on the same data.

Scenarios (``sim.free``; a new truth and new noise per seed):

* ``payload_no_mount``: a wrist tool, no mounting rotation (the peers' model holds);
* ``payload_mount``: the same with the default drawn mounting rotation (~1 deg rms);
* ``urdf_leg``: the bundled four-joint leg below a sensor (no peer: theirs is a rigid payload).

Estimators: ``nlp`` (the free-load estimator, issue22a's API, through ``_nlp_fit``), ``ft_calib`` and
``calib_force`` (``peers.py``; given the simulator's held samples and the nominal ft orientation, as their
packages expect pose averages of held poses). Groups (estimate minus truth):

* payload: ``offsets`` (N, N*m), ``mass`` (kg), ``com`` (m, ft), ``mount_rotation`` (rad, the error rotation
  ``rotvec(E_true^T E_est)`` in the true ft axes; ft_calib's ``E`` is the identity);
* URDF load: ``offsets``, ``total_mass`` (the sum of the groups' masses: statics see only that), ``first_moments``
  (the joint groups' masses and first moments with what the data do not determine projected out,
  ``Bound.project``), ``mount_rotation``.

With the world tilt of the orientation stream (``[free_load] gravity_tilt``, the NLP's default) the NLP is scored
against the bound that has the tilt's two parameters too (``crb.free_load_bound(tilt=True)``; the
simulations have none: truth 0) and its tilt gets a row group ``gravity_tilt`` (deg); the peers, which have no
tilt, against the bound without it.

``z = e / sd_CRB`` with the bound of the mounting rotation unknown (what the NLP and calibForce estimate);
``z_known`` against the bound with the mounting known (what ft_calib assumes: where its model holds it should
reach that one). A group's ratio is ``sqrt(mean z^2)`` over its parameters and datasets.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from .. import crb as cl
from ..core.geometry import quat_to_rotation, rotation_to_rotvec, rotvec_to_rotation
from .peers import calib_force, ft_calib
from ..sim.free import PayloadConfig, UrdfLegConfig, gravity_in_ft, simulate_free
from ..sim.free.simulate import rpy_to_rotation

SCENARIOS = ("payload_no_mount", "payload_mount", "urdf_leg")
PAYLOAD_GROUPS = {"offsets": slice(0, 6), "mass": slice(6, 7), "com": slice(7, 10), "mount_rotation": slice(10, 13)}
GROUP_UNITS = {"offsets": "N, N*m", "mass": "kg", "com": "mm", "mount_rotation": "deg", "total_mass": "kg",
               "first_moments": "kg m, kg", "gravity_tilt": "deg"}
GROUP_SCALE = {"com": 1e3, "mount_rotation": np.degrees(1.0), "gravity_tilt": np.degrees(1.0)}
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass(frozen=True)
class LoadAccuracySettings:
    """``seeds`` per scenario; ``payload`` / ``urdf`` overrides of the simulator's configs."""

    seeds: tuple[int, ...] = tuple(range(20))
    scenarios: tuple[str, ...] = SCENARIOS
    estimators: tuple[str, ...] = ("nlp", "ft_calib", "calib_force")
    payload: dict = field(default_factory=dict)
    urdf: dict = field(default_factory=dict)

    def config(self, scenario: str, seed: int):
        if scenario == "payload_no_mount":
            return PayloadConfig(seed=seed, **{"mount_rotvec": (0.0, 0.0, 0.0), **self.payload})
        if scenario == "payload_mount":
            return PayloadConfig(seed=seed, **self.payload)
        if scenario == "urdf_leg":
            return UrdfLegConfig(seed=seed, **self.urdf)
        raise ValueError(f"unknown scenario {scenario!r}; known: {SCENARIOS}")


# ----------------------------------------------------------------------------- estimators


@dataclass(frozen=True)
class LoadEstimate:
    """An estimate in the bound's parameter order (``crb.payload_names(True)`` or ``urdf_names``);
    ``wall_s`` its time; ``kept`` the samples it used."""

    theta: np.ndarray
    wall_s: float
    kept: int


def held_inputs(res) -> tuple[np.ndarray, np.ndarray]:
    """The peers' inputs: gravity in the NOMINAL ft frame from the recorded orientation, and the readings, of the
    held samples."""
    cfg = res.config
    df = res.frame[res.held]
    R_WB = quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy())
    g_nom = gravity_in_ft(R_WB, rpy_to_rotation(cfg.rotation_rpy), cfg.g)
    return g_nom, df[[f"{cfg.transducer}_{c}" for c in WRENCH]].to_numpy()


def _peer(method: Callable) -> Callable:
    def fit(res, workdir: Path) -> LoadEstimate:
        if res.config.kind != "payload":
            raise NotImplementedError(f"{method.__name__} models a rigid payload only")
        g_nom, w = held_inputs(res)
        t0 = time.perf_counter()
        f = method(g_nom, w)
        wall = time.perf_counter() - t0
        return LoadEstimate(np.concatenate([f.offset, [f.mass_kg], f.com_m, f.mount_rotvec]), wall, len(w))
    return fit


def _nlp_fit(res, workdir: Path) -> LoadEstimate:
    """The free-load NLP on the dataset as written (its reader, its quasi-static selection)."""
    from .free_load_nlp import nlp_estimate  # the adapter to issue22a's estimator

    return LoadEstimate(*nlp_estimate(res, workdir))


ESTIMATORS: dict[str, Callable] = {"nlp": _nlp_fit, "ft_calib": _peer(ft_calib), "calib_force": _peer(calib_force)}


# ----------------------------------------------------------------------------- errors


def _rows(scenario, seed, est, group, names, e, sd, sd_known) -> list[dict]:
    return [{"scenario": scenario, "seed": seed, "estimator": est, "group": group, "param": n, "error": float(e[i]),
             "crb_sd": float(sd[i]), "z": float(e[i] / sd[i]),
             "crb_sd_known_mount": float(sd_known[i]) if sd_known is not None else np.nan,
             "z_known": float(e[i] / sd_known[i]) if sd_known is not None else np.nan} for i, n in enumerate(names)]


def payload_errors(scenario: str, seed: int, est: str, theta: np.ndarray, res, b: cl.LoadBound, b0: cl.LoadBound) -> list[dict]:
    """Rows of a payload estimate ``theta`` (offset, mass, com[, tilt], mount rotvec; ``b``'s order) against the truth
    and both bounds."""
    rv_true = np.asarray(res.truth["mount_rotvec"])
    nt = len(theta) - 13                                # 2: the NLP's world tilt (truth 0)
    e = theta[:10 + nt] - b.theta[:10 + nt]
    e_rot = rotation_to_rotvec(rotvec_to_rotation(rv_true).T @ rotvec_to_rotation(theta[-3:]))
    err = np.concatenate([e, e_rot])
    groups = {**PAYLOAD_GROUPS, "mount_rotation": slice(10 + nt, 13 + nt)}
    if nt:
        groups["gravity_tilt"] = slice(10, 12)
    rows = []
    for g, sl in groups.items():
        if g == "mount_rotation" and est == "ft_calib" and not np.any(rv_true):
            continue                                    # assumed nominal and exactly so: not an estimate
        names = b.names[sl]
        sd_known = b0.sd(names) if g not in ("mount_rotation", "gravity_tilt") else None
        rows += _rows(scenario, seed, est, g, names, err[sl], b.bound.sd[sl], sd_known)
    return rows


def urdf_errors(scenario: str, seed: int, est: str, theta: np.ndarray, res, b: cl.LoadBound, b0: cl.LoadBound) -> list[dict]:
    """Rows of a URDF-load estimate ``theta`` (``urdf_names`` order[, tilt]) against the truth and both bounds."""
    n = len(b.names)
    nt = 2 if "tilt_rx" in b.names else 0
    e = theta - b.theta
    rv_true = np.asarray(res.truth["mount_rotvec"])
    e[n - 3:] = rotation_to_rotvec(rotvec_to_rotation(rv_true).T @ rotvec_to_rotation(theta[n - 3:]))
    ep = b.bound.project(e)
    ep0 = b0.bound.project(e[: n - 3 - nt])
    masses = {nm: 1.0 for nm in b.names if nm.endswith(".mass_kg")}
    rows = _rows(scenario, seed, est, "offsets", b.names[:6], ep[:6], b.bound.sd[:6], b0.bound.sd[:6])
    e_m = sum(e[b.names.index(k)] for k in masses)
    rows += _rows(scenario, seed, est, "total_mass", ["total_mass_kg"], [e_m], [b.sd_of(masses)], [b0.sd_of(masses)])
    # the projected group parameters: directions the data determine (scaled-Fisher eigenvalues >= REL_EIG_TOL)
    sl = slice(6, n - 3 - nt)
    r = _rows(scenario, seed, est, "first_moments", b.names[sl], ep[sl], b.bound.sd[sl], b0.bound.sd[sl])
    for row, e0 in zip(r, ep0[sl]):
        row["z_known"] = float(e0 / row["crb_sd_known_mount"])
    rows += r
    if nt:
        rows += _rows(scenario, seed, est, "gravity_tilt", b.names[n - 5:n - 3], ep[n - 5:n - 3], b.bound.sd[n - 5:n - 3], None)
    rows += _rows(scenario, seed, est, "mount_rotation", b.names[n - 3:], ep[n - 3:], b.bound.sd[n - 3:], None)
    return rows


def evaluate(scenario: str, seed: int, settings: LoadAccuracySettings, workdir: Path) -> dict:
    """Simulate one dataset, run every estimator, compare with the truth and the bounds."""
    res = simulate_free(settings.config(scenario, seed))
    b = cl.free_load_bound(res, mount=True)
    b0 = cl.free_load_bound(res, mount=False)
    bt = cl.free_load_bound(res, mount=True, tilt=True)     # an estimate with the world tilt: scored against this one
    info = {"scenario": scenario, "seed": seed, "n": len(res.held), "n_held": int(res.held.sum()),
            "crb_dropped_dirs": b.bound.n_dropped, "mount_deg": float(np.degrees(np.linalg.norm(res.truth["mount_rotvec"])))}
    rows = []
    for name in settings.estimators:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                est = ESTIMATORS[name](res, workdir / f"{scenario}_{seed}_{name}")
        except NotImplementedError:
            continue                                    # a peer without a model of this load: no row
        except Exception as exc:                        # a failed estimate is a finding: counted and shown
            info[f"{name}_failure"] = f"{type(exc).__name__}: {exc}"
            continue
        info[f"{name}_wall_s"] = est.wall_s
        info[f"{name}_kept"] = est.kept
        errors = payload_errors if res.config.kind == "payload" else urdf_errors
        rows += errors(scenario, seed, name, est.theta, res, bt if len(est.theta) == len(bt.names) else b, b0)
    return {"rows": rows, "info": info}


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """One row per (scenario, estimator, group): ratio to the bound (± se over datasets), ratio to the known-mount
    bound, mean z (bias), RMS error and RMS bound in the group's unit."""
    out = []
    for (sc, est, g), d in rows.groupby(["scenario", "estimator", "group"], sort=False):
        per_seed = d.groupby("seed")["z"].apply(lambda z: float(np.mean(z**2)))
        ratio = float(np.sqrt(per_seed.mean()))
        se = float(per_seed.std(ddof=1) / np.sqrt(len(per_seed)) / (2 * ratio)) if len(per_seed) > 1 and ratio > 0 else np.nan
        zk = d["z_known"].dropna()
        s = GROUP_SCALE.get(g, 1.0)
        out.append({"scenario": sc, "estimator": est, "group": g, "unit": GROUP_UNITS[g], "ratio": ratio, "ratio_se": se,
                    "ratio_known_mount": float(np.sqrt(np.mean(zk**2))) if len(zk) else np.nan,
                    "mean_z": float(d.z.mean()), "rms_error": float(np.sqrt(np.mean(d.error**2))) * s,
                    "rms_crb": float(np.sqrt(np.mean(d.crb_sd**2))) * s, "n_datasets": int(d.seed.nunique())})
    return pd.DataFrame(out)


def run_load_accuracy(settings: LoadAccuracySettings = LoadAccuracySettings(), progress: bool = True) -> dict:
    """Every scenario and seed; returns ``rows``, ``info`` (DataFrames), ``summary`` and ``settings``."""
    from tqdm import tqdm

    rows, info = [], []
    with tempfile.TemporaryDirectory(prefix="ftcal_loads_") as tmp:
        todo = [(sc, s) for sc in settings.scenarios for s in settings.seeds]
        for sc, seed in tqdm(todo, desc="accuracy (free loads)", disable=not progress):
            r = evaluate(sc, seed, settings, Path(tmp))
            rows += r["rows"]
            info.append(r["info"])
    rows_df = pd.DataFrame(rows)
    return {"rows": rows_df, "info": pd.DataFrame(info), "summary": summarize(rows_df) if len(rows_df) else pd.DataFrame(),
            "settings": settings}
