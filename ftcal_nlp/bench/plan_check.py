"""Does the plan predict? Predicted se against the se the calibration reports and the spread over seeds.

For each protocol (a reference, half the hanging time, half the poses): the
plan's prediction (:func:`ftcal_nlp.plan.predict`, seed 0); the se that
``calibrate()`` reports on the simulated dataset of that protocol (seed 0);
and the spread of the calibration's errors against the truth over ``seeds``
simulated datasets, ``sqrt(mean error^2)`` over the group's parameters and the
seeds. Both are given as ratios to the prediction (goal: within 20 %).
``spread_ratio_sd`` is the sampling sd of the spread ratio from the number of
values behind it (``1 / sqrt(2 n)``, n = seeds x parameters).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..core.geometry import rotation_to_rotvec
from ..core.physics import total_com_from_body_com
from ..pipeline import calibrate
from ..plan import GROUPS, Protocol, predict, reported_se
from .accuracy import pipeline_settings

TOLERANCE = 0.2
SETTINGS = pipeline_settings("nlp", "full")  # the run's NLP defaults, full model, no baselines or diagnosis


@dataclass(frozen=True)
class PlanCheckSettings:
    reference: Protocol = Protocol(hanging_turns=3.0, n_poses=250)
    seeds: tuple[int, ...] = tuple(range(20))
    halves: bool = True  # also half the hanging time and half the poses


def group_errors(cal, truth) -> dict[str, np.ndarray]:
    """Errors of a calibration against the truth, per group (SI; see :data:`ftcal_nlp.plan.GROUPS`)."""
    legs = truth.leg_names
    e_off = np.stack([cal.legs[k].offset - truth.legs[k].offset for k in legs])
    _, _, R_e, p_e = cal.stacked(legs)
    _, _, R_t, p_t = truth.stacked(legs)
    zero = np.zeros((1, len(legs)))
    return {
        "offsets_force": e_off[:, :3].ravel(),
        "offsets_torque": e_off[:, 3:].ravel(),
        "leg_weights": np.array([cal.legs[k].leg_weight_N - truth.legs[k].leg_weight_N for k in legs]),
        "com_curves": np.concatenate([(cal.legs[k].com_xyz - truth.legs[k].com(cal.legs[k].com_phi)).ravel() for k in legs]),
        "rotations": rotation_to_rotvec(R_e @ np.swapaxes(R_t, 1, 2)).ravel(),
        "translations": (p_e - p_t).ravel(),
        "total_com": total_com_from_body_com(zero, cal)[0] - total_com_from_body_com(zero, truth)[0],
    }


def calibrate_protocol(protocol: Protocol, seed: int):
    """``calibrate()`` (full model, no diagnosis) on the simulated dataset of ``protocol`` with ``seed``; and the truth."""
    from ..sim import simulate

    sim = simulate(protocol.sim_config(seed))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = calibrate(sim.dataset, SETTINGS)
    return run.calibration, sim.truth


def check_protocol(name: str, protocol: Protocol, seeds) -> list[dict]:
    """One row per group: predicted se, reported se (seed ``seeds[0]``), spread over ``seeds``, their ratios."""
    pred = predict(protocol, seed=seeds[0])
    errs: dict[str, list] = {g: [] for g in GROUPS}
    reported: dict[str, float] = {}       # of seeds[0] (there is one: predict above took it)
    for i, s in enumerate(seeds):
        cal, truth = calibrate_protocol(protocol, s)
        if i == 0:
            reported = reported_se(cal)
        for g, e in group_errors(cal, truth).items():
            errs[g].append(e)
    rows = []
    for g, (unit, f) in GROUPS.items():
        e = np.concatenate(errs[g]) if errs[g] else np.array([])
        spread = float(np.sqrt(np.mean(e**2))) * f if e.size else float("nan")
        rows.append({"protocol": name, "group": g, "unit": unit, "predicted_se": pred.se[g],
                     "reported_se": reported[g], "reported_ratio": reported[g] / pred.se[g],
                     "spread": spread, "spread_ratio": spread / pred.se[g], "n_values": int(e.size),
                     "spread_ratio_sd": (spread / pred.se[g]) / np.sqrt(2 * e.size) if e.size else float("nan"),
                     "duration_s": protocol.duration_s})
    return rows


def run_plan_check(settings: PlanCheckSettings = PlanCheckSettings()) -> dict:
    """Every protocol of ``settings``; a table and how many (group, protocol) ratios are within 20 %."""
    ref = settings.reference
    protocols = {"reference": ref}
    if settings.halves:
        protocols["half hanging time"] = replace(ref, hanging_turns=ref.hanging_turns / 2)
        protocols["half poses"] = replace(ref, n_poses=max(8, ref.n_poses // 2))
    rows = []
    for name, p in protocols.items():
        rows += check_protocol(name, p, settings.seeds)
    t = pd.DataFrame(rows)
    checked = t[t.group != "com_curves_unsmoothed"]
    rep = checked.reported_ratio.dropna()
    within = {"reported": (int((abs(rep - 1) <= TOLERANCE).sum()), int(len(rep))),
              "spread": (int((abs(checked.spread_ratio - 1) <= TOLERANCE).sum()), int(len(checked)))}
    return {"settings": settings, "table": t, "within": within, "tolerance": TOLERANCE}


__all__ = ["PlanCheckSettings", "calibrate_protocol", "group_errors", "run_plan_check"]
