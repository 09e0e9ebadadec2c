"""Does the plan's detection size detect? The diagnosis run on effects of the predicted size.

For a protocol and a few library effects: the plan's detection size of each (:mod:`ftcal_nlp.plan.detection`,
power 0.8 at the diagnosis' gap threshold, simulator seed 0); then, on ``seeds`` simulated datasets of the
protocol with the effect at that size (simulator and injector seed = the seed), ``calibrate()`` with the
diagnosis on (error model ``full``, every library candidate, no joint refit: the gap and the verdict do
not depend on it), and per dataset: the kind's held-out excess and threshold, whether it flags a gap on
the predicted kind (what the plan predicts: rate ~0.8), whether the verdict is other than ``none``
(the evidence weighing can still call a structureless gap noise) and whether it names the effect. Clean
datasets (no effect, the same seeds) give the false-alarm rate. Rates carry their binomial se.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..plan import Protocol, predict
from ..core.settings import CalibrationSettings, DiagnoseSettings, StandingSettings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DetectCheckSettings:
    protocol: Protocol = Protocol(hanging_turns=3.0, n_poses=200)
    effects: tuple[str, ...] = ("offset_drift", "casing_load", "leg_inertia")
    seeds: tuple[int, ...] = tuple(range(8))
    clean_seeds: tuple[int, ...] = tuple(range(4))


SETTINGS = CalibrationSettings(standing=StandingSettings(model="full", compare_baseline=False),
                               diagnose=DiagnoseSettings(joint_refit=False))


def diagnose_one(protocol: Protocol, effect: str | None, scale: float, seed: int) -> dict:
    """Simulate ``protocol`` (seed) with ``effect`` at ``scale`` and diagnose it; the kinds' excess and the verdict."""
    from ..pipeline import calibrate
    from ..sim import SimConfig, simulate

    t0 = time.perf_counter()
    c = protocol.sim_config(seed)
    d = {f: getattr(c, f) for f in c.__dataclass_fields__ if f != "effects"}
    spec = [{"name": effect, "scale": scale, "seed": seed}] if effect else []
    sim = simulate(SimConfig.from_dict({**d, "effects": spec}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = calibrate(sim.dataset, SETTINGS)
    dg = run.diagnosis
    if dg is None:   # the run skipped it (pipeline.optional): its note says why
        raise RuntimeError(f"detect check: {effect or 'no effect'} at {scale:g}, seed {seed}: no diagnosis "
                           f"({'; '.join(run.notes) or 'skipped'})")
    row = {"effect": effect or "none", "scale": scale, "seed": seed, "verdict": dg.verdict, "named": dg.effect or "",
           "time_s": time.perf_counter() - t0}
    for k, v in dg.kinds.items():
        row[f"excess_{k}"] = v["excess"]
        row[f"threshold_{k}"] = v["threshold"]
        row[f"gap_{k}"] = bool(k in dg.gaps)
    return row


def _rate(x) -> tuple[float, float]:
    x = np.asarray(x, float)
    p = float(x.mean()) if len(x) else float("nan")
    return p, float(np.sqrt(p * (1 - p) / max(len(x), 1)))


def run_detect_check(settings: DetectCheckSettings = DetectCheckSettings()) -> dict:
    """The check of the module docstring: per-run rows and per-effect rates."""
    t0 = time.perf_counter()
    pred = predict(settings.protocol, seed=0, detection=tuple(settings.effects))
    t_pred = time.perf_counter() - t0
    # None: no effect asked (predict computes sizes for a non-empty tuple only)
    sizes = {d.effect: d for d in pred.detection.sizes} if pred.detection is not None else {}
    rows = []
    for e in settings.effects:
        d = sizes[e]
        if not np.isfinite(d.size):
            log.warning("detect check: %s has no predicted detection size; skipped", e)
            continue
        for s in settings.seeds:
            rows.append({**diagnose_one(settings.protocol, e, d.size, s), "kind": d.kind})
            log.info("detect check %s seed %d: %s", e, s, rows[-1])
    for s in settings.clean_seeds:
        rows.append(diagnose_one(settings.protocol, None, 0.0, s))
    runs = pd.DataFrame(rows)
    summary = []
    for e, g in runs.groupby("effect", sort=False):
        kind = g["kind"].iloc[0] if e != "none" else None
        flagged = g[f"gap_{kind}"] if kind else g[[c for c in g if c.startswith("gap_")]].any(axis=1)
        p, se = _rate(flagged)
        pv, sev = _rate(g.verdict != "none")
        pn, sen = _rate(g.named == e)
        summary.append({"effect": e, "kind": kind or "any", "size": float(g.scale.iloc[0]),
                        "unit": sizes[e].unit if e in sizes else "", "runs": len(g), "gap_rate": p, "gap_rate_se": se,
                        "predicted_rate": 0.8 if kind else 0.0,
                        "mean_excess": float(g[f"excess_{kind}"].mean()) if kind else float("nan"),
                        "threshold": float(g[f"threshold_{kind}"].mean()) if kind else float("nan"),
                        "verdict_not_none_rate": pv, "named_rate": pn if kind else float("nan")})
    return {"settings": settings, "runs": runs, "table": pd.DataFrame(summary), "predict_s": t_pred,
            "detection": pred.detection_table()}


__all__ = ["DetectCheckSettings", "diagnose_one", "run_detect_check"]
