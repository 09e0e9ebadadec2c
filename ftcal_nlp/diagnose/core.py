"""The diagnosis of one calibrated dataset: views -> attribution -> localisation -> result.

After calibration, what remains in held-out data is the gap between the model
(the "sim") and the robot (the "real"). ``diagnose`` says where it lies
(recording kind, legs, components, what it follows), which candidate effect of
the library explains it (every candidate added to the model in turn and scored
on data it was not fitted to) and how far it shrinks once that effect is
added, beside the noise floor.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from ..core.calibration import Calibration
from ..core.data import Dataset
from ..effects import Effect, resolve_effects
from ..models import ModelContext, resolve
from ..core.robot import Robot
from ..core.settings import CalibrationSettings, ChainThresholds, DiagnoseSettings
from ..core.solver import SolverError
from .attribute import (
    GAP_THRESHOLD,
    attribute,
    decide,
    explained_fraction,
    gap_threshold,
    ranking_bic,
)
from .hexchain import run_chain
from .refit import joint_refit
from .perleg import perleg_checks
from .localise import (
    components_with_gap,
    describe,
    legs_with_gap,
    localise_series,
    localise_standing,
    standing_legs,
    strongest_dependence,
)
from .result import DiagnosisResult
from .views import Views, hanging_series, standing_view, walking_views

log = logging.getLogger(__name__)

KIND_NAMES = {"standing": "standing", "hanging": "hanging", "walking swing": "walking", "design": "standing"}


def _model_and_balance(calibration: Calibration, model: Any, balance: str | None) -> tuple[Any, str]:
    meta = calibration.meta or {}
    balance = balance or meta.get("balance") or (meta.get("standing") or {}).get("balance") or "exact"
    model = model if model is not None else calibration.model
    try:
        resolve(model)
    except (ValueError, TypeError):
        log.warning("diagnosis: calibration model %r is not a known error model; using 'full'", model)
        model = "full"
    return model, balance


def diagnose(dataset: Dataset, hanging_result, poses, calibration: Calibration, robot: Robot,
             settings: DiagnoseSettings | None = None, *, model: Any = None, balance: str | None = None,
             x_start: np.ndarray | None = None, registry: Mapping[str, Effect] | None = None) -> DiagnosisResult:
    """Diagnose the sim-to-real gap of a calibrated dataset.

    ``hanging_result``: the :class:`~ftcal_nlp.estimate.hanging.HangingResult` (None: no hanging view,
    the calibration's offsets serve as the prior); ``poses``: the standing
    :class:`~ftcal_nlp.estimate.standing.Poses` (time order); ``calibration``: the finished
    calibration (its ``model`` and ``meta['balance']`` name the error model and balance);
    ``settings``: :class:`~ftcal_nlp.core.settings.DiagnoseSettings` (candidate effects, folds, seed);
    ``model``/``balance``: the calibration's error model and balance (None: from the calibration's
    ``model`` and ``meta``); ``x_start``: the standing fit's decision vector (warm start);
    ``registry``: the candidate effects by name (None: ``ftcal_nlp.effects.EFFECTS``; ``settings.effects``
    picks among them).
    """
    t0 = time.perf_counter()
    s = DiagnoseSettings() if settings is None else settings
    model, balance = _model_and_balance(calibration, model, balance)
    effects = resolve_effects(s.effects, registry)
    legs = tuple(robot.legs)
    prior = hanging_result.to_calibration(robot) if hanging_result is not None else calibration
    notes = []
    hang_recs = dataset.hanging
    t_ref = float(np.mean(np.concatenate([r.t for r in hang_recs]))) if hang_recs else (float(np.mean(poses.t)) if poses is not None else 0.0)
    sv = None
    if poses is not None and poses.n >= 2 * s.folds:
        spec = resolve(model).build(ModelContext(legs, robot.nominal_rotations(), robot.nominal_positions(), prior))
        sv = standing_view(dataset, poses, calibration, prior, robot, t_ref, spec.n_dof, s.folds, balance=balance, model=model, seed=s.seed)
    elif poses is not None:
        notes.append(f"only {poses.n} standing poses: too few for {s.folds}-fold cross-validation; standing not diagnosed")
    hs = hanging_series(hang_recs, hanging_result, robot, t_ref) if (hanging_result is not None and hang_recs) else None
    sw, wt = walking_views(dataset.walking, calibration, robot, t_ref) if dataset.walking else (None, None)
    views = Views(sv, hs, sw, wt, t_ref, legs, notes)
    att = attribute(views, effects, model, prior, robot, balance, folds=s.folds, seed=s.seed, x_start=x_start)
    verdict, effect, gap = decide(att, s.hexapod.explained_min)
    views = att.views or views

    loc = {}
    if views.standing is not None and att.standing_heldout is not None:
        loc["standing"] = localise_standing(views.standing, att.standing_heldout, prior.stacked(legs)[0], att.folds, legs)
    for key, series in (("hanging", views.hanging), ("walking swing", views.swing)):
        if series is not None:
            loc[key] = localise_series(series, len(legs), s.folds)

    phys = {k: v for k, v in gap.items() if k != "design"}
    primary = _primary(phys, att, verdict, effect, s.hexapod.explained_min)
    where: dict[str, Any] = {"recordings": [], "legs": [], "components": [], "explains": None}
    if gap:
        recs = []
        for k in sorted(gap, key=lambda k: gap[k], reverse=True):
            name = KIND_NAMES.get(k, k)
            if name not in recs:
                recs.append(name)
        where["recordings"] = recs
        if primary in loc and primary in phys:
            L = loc[primary]
            where["components"] = components_with_gap(L)
            where["legs"] = standing_legs(L, legs) if primary == "standing" else legs_with_gap(L, legs, GAP_THRESHOLD.get(primary, 0.25))
            where["explains"] = strongest_dependence({k: loc[k] for k in phys if k in loc})
        elif "design" in gap:
            where["explains"] = "body_tilt"
            where["components"] = ["fx", "fy"]
    perleg = None
    if poses is not None:
        perleg = perleg_checks(dataset, calibration, poses, robot, folds=s.folds, seed=s.seed, balance=balance, swing=sw)
    noise_statement = views.standing.floor_parts.get("statement") if views.standing is not None else None
    verdict, effect, where, evidence_notes = _weigh_evidence(verdict, effect, where, perleg, loc, phys, noise_statement)
    if verdict == "none" and noise_statement and noise_statement not in evidence_notes:
        evidence_notes.append(noise_statement)
    base = att.base.get(primary)
    by_name = {sc.effect: sc for sc in att.scores}
    before = base.rms_before if base is not None else np.full(6, np.nan)
    floor = base.floor if base is not None else np.full(6, np.nan)
    after = before
    if verdict == "effect" and primary in by_name[effect].kinds:
        after = by_name[effect].kinds[primary].rms_after
    joint = None
    if verdict == "effect" and s.joint_refit:
        try:
            joint = joint_refit(views, by_name[effect].model_effect or resolve_effects([effect], registry)[0], model, prior, calibration, robot, balance, folds=s.folds, seed=s.seed, x_start=x_start)
        except (SolverError, np.linalg.LinAlgError) as exc:
            views.notes.append(f"joint refit with {effect} failed: {exc}")
            log.warning("diagnosis: joint refit with %s failed: %s", effect, exc)
        else:
            jk = joint.kinds.get(primary)
            if jk is not None:  # how far it shrinks: the joint model's held-out residual (module refit.py)
                before, after = jk.rms_before, jk.rms_after
    chain = None
    if joint is not None:   # several effects: look again while a gap is left (hexchain.py)
        chain = run_chain(views, att, by_name[effect].model_effect or resolve_effects([effect], registry)[0], joint, effects, model,
                          prior, calibration, robot, balance, primary, s.hexapod, folds=s.folds, seed=s.seed, x_start=x_start)
        if chain.first is not None:   # a swap took the ranking's first out: the first named is the chain's
            effect, joint = chain.first.name, chain.first.joint
        if chain.links and primary in chain.links[-1].joint.kinds:   # the shrinkage: after every named effect
            after = chain.links[-1].joint.kinds[primary].rms_after
    shrink = {"heldout_rms_before": before, "heldout_rms_after": after, "noise_floor": floor, "kind": KIND_NAMES.get(primary, primary) if primary is not None else None,
              "kind_key": primary}
    ranking = []
    for sc in att.scores:
        k = sc.kinds.get(primary)
        ranking.append({"effect": sc.effect, "delta_bic": ranking_bic(sc, gap), "heldout_rms_after": k.rms_after if k is not None else before,
                        "explained": explained_fraction(sc, gap) if gap else 0.0, "status": sc.status, "note": sc.note,
                        "variant": dict(sc.model_effect.variant) if sc.model_effect is not None else {}})
    kinds = {k: {"excess": float(v.excess_before), "threshold": float(gap_threshold(k, v)), "n": int(v.n),
                 "heldout_rms": [float(x) for x in v.rms_before], "noise_floor": [float(x) for x in v.floor]} for k, v in att.base.items()}
    statement = (_statement(verdict, effect, gap, loc, att, ranking, shrink, where, s.hexapod.explained_min)
                 + _chain_statement(chain, shrink, s.hexapod) + list(evidence_notes))
    effect_fit = by_name[effect].fit if verdict == "effect" and effect in by_name else None
    return DiagnosisResult(verdict, effect, where, shrink, ranking, loc, tuple(statement), att.design, gap, kinds,
                           str(att.model), balance, time.perf_counter() - t0, tuple(views.notes), effect_fit, perleg,
                           views.standing.floor_parts.get("noise_model") if views.standing is not None else None, joint,
                           chain=chain, thresholds=s.hexapod)


PRIORITY = ("standing", "hanging", "walking swing")
CONSTANT_SHARE_MIN = 0.3   # a constant bias this large a share of the held-out residual is structure too


def _weigh_evidence(verdict: str, effect: str | None, where: dict, perleg, loc: dict, phys: dict, noise_statement: str | None = None):
    """The verdict with the library-free evidence (``perleg.py``) and the localisation weighed in.

    * An improper reading map on a leg (``det < 0``: swapped or sign-flipped axes) is something no
      library effect produces: ``unexplained`` on that leg, whatever the library's best candidate.
    * Per-leg findings that are not shared by most legs (a changed leg, a gain) and that no
      library effect was named for: ``unexplained`` on those legs.
    * ``unexplained`` needs evidence: a per-leg finding, a cross-validated dependence on a correlate
      (``where.explains``) or a material constant bias. A gap with none of these is per-pose scatter
      the noise model underrates: reported as noise (verdict ``none``) with its size.
    Returns ``(verdict, effect, where, notes)``.
    """
    notes = []
    findings = [f for f in (perleg.findings if perleg is not None else ()) if not f.shared]
    improper = [k for k in perleg.linear_map.flagged
                if any(perleg.linear_map.maps[k].improper(p) for p in perleg.linear_map.maps[k].parts)] if perleg is not None else []
    where = dict(where)
    if improper:
        legs = list(dict.fromkeys(improper))
        comps = sorted({c for f in findings if f.leg in legs for c in f.components}, key="fx fy fz tx ty tz".split().index)
        notes += [f.statement for f in findings if f.leg in legs]
        if effect is not None:
            notes.append(f"The library's best candidate ({effect}) is set aside: an improper reading map is outside the library.")
        return "unexplained", None, {**where, "legs": legs, "components": comps or where.get("components", [])}, notes
    if findings and verdict != "effect":
        legs = list(dict.fromkeys(f.leg for f in findings))
        comps = sorted({c for f in findings for c in f.components}, key="fx fy fz tx ty tz".split().index)
        notes += [f.statement for f in findings]
        recs = where.get("recordings") or sorted({"standing" if f.kind == "linear_map" else "walking" for f in findings})
        return "unexplained", None, {**where, "recordings": recs, "legs": legs, "components": comps}, notes
    if verdict == "unexplained":
        const = max((loc[k].constant_share for k in phys if k in loc), default=0.0)
        if where.get("explains") is None and const < CONSTANT_SHARE_MIN and not findings:
            notes.append("The held-out residual exceeds the noise floor without any structure: no cross-validated dependence on "
                         "a correlate, no constant bias, no per-leg finding. Reported as measurement noise, not as a gap.")
            if noise_statement:
                notes.append(noise_statement)
            return "none", None, {**where, "legs": [], "explains": None}, notes
    if findings:
        notes += [f.statement for f in findings]
    return verdict, effect, where, notes


def _primary(phys: dict, att, verdict: str, effect: str | None, explained_min: float) -> str | None:
    """The kind the shrinkage is reported on: by priority (the standing poses are the calibration's
    own data), among the kinds with a gap that the named effect explains (``explained_min`` of the kind's excess; any
    gap kind otherwise)."""
    if not phys:
        return "standing" if "standing" in att.base else next(iter(att.base), None)
    order = [k for k in PRIORITY if k in phys] + [k for k in phys if k not in PRIORITY]
    if verdict == "effect":
        sc = next(s for s in att.scores if s.effect == effect)
        good = [k for k in order if k in sc.kinds and sc.kinds[k].explained >= explained_min]
        if good:
            return good[0]
    return order[0]


def _statement(verdict, effect, gap, loc, att, ranking, shrink, where, explained_min: float) -> list[str]:
    out = []
    if verdict == "none" and not gap:
        out.append("No gap above the noise floor: every recording kind's held-out residual is at its floor, so no candidate effect is called.")
    elif verdict == "effect":
        b, a, f = (np.asarray(shrink[k], float) for k in ("heldout_rms_before", "heldout_rms_after", "noise_floor"))
        c = int(np.argmax(b / np.where(f > 0, f, 1.0)))
        unit = "N" if c < 3 else "N*m"
        out.append(f"The gap is explained by {effect}: adding it to the calibration model brings the held-out {shrink['kind']} RMS of "
                   f"{['fx', 'fy', 'fz', 'tx', 'ty', 'tz'][c]} from {b[c]:.3g} to {a[c]:.3g} {unit} (noise floor {f[c]:.2g} {unit}).")
    else:
        out.append("There is a gap above the noise floor that no candidate effect of the library explains (see where it lies below).")
    if gap:
        out.append("It lies in the " + ", ".join(where["recordings"]) + " recordings"
                   + (f", legs {', '.join(where['legs'])}" if where["legs"] else ", common to all legs")
                   + (f", components {', '.join(where['components'])}" if where["components"] else "")
                   + (f", and follows {where['explains'].replace('_', ' ')}." if where["explains"] else "."))
    for kind, L in loc.items():
        out.append(describe(L))
    d = att.design
    if d is not None:
        tilt = np.asarray(d["tilt_deg"])
        out.append(f"Design check: the fitted transducer frames share a tilt of ({tilt[0]:.2f}, {tilt[1]:.2f}) +- {d['tilt_se_deg']:.2f} deg "
                   f"about x, y of B (mounting scatter {d['scatter_deg']:.2f} deg; dBIC {d['delta_bic']:.1f}); a common tilt is what a "
                   "motion-capture bias (or a cable's horizontal pull) leaves when the model frees every rotation.")
    good = [r for r in ranking if r["status"] == "ok" and np.isfinite(r["delta_bic"])]
    if good:
        out.append("Candidates by dBIC where the gap lies: " + ", ".join(f"{r['effect']} {r['delta_bic']:.0f} (explains {100 * r['explained']:.0f}%)"
                                                                         for r in good[:4]) + ".")
        if verdict == "effect" and len(good) > 1 and good[1]["explained"] >= explained_min and good[1]["delta_bic"] - good[0]["delta_bic"] < 0.05 * abs(good[0]["delta_bic"]):
            out.append(f"{good[0]['effect']} and {good[1]['effect']} explain this gap almost equally well here; they are confusable on these recordings.")
    return out


def _chain_statement(chain, shrink, t: ChainThresholds) -> list[str]:
    """The effects the chain named (in the order they stand), the swaps it made and why it stopped (when it looked
    again)."""
    if chain is None or not chain.rounds:
        return []
    out = []
    for link in ([chain.first] if chain.first is not None else []) + chain.links:
        a = np.asarray(link.rms_after, float)
        if link is chain.first:
            lead, how = (f"First {link.name} (the ranking's first was swapped out): refit alone",
                         f"it explains {100 * link.explained:.0f} % of the gap on its own in the first ranking")
        else:
            lead = f"Then {link.name}: refit with the effects before it"
            how = (f"it removes {100 * link.explained:.0f} % of the excess the effects before it left" if link.via == "ranking" else
                   f"swapped in for another named effect; it removes {100 * link.explained:.0f} % of that kind's excess the "
                   f"chain had left" if link.via == "swap" else
                   f"found by its held-out evidence where the joint refit left a gap the ranking did not see; the joint refit "
                   f"with it removes {100 * link.explained:.0f} % of that kind's excess")
        if link.beside:
            how += f"; tested beside {', '.join(link.beside)}"
        z = f"{link.z:.1f}" if np.isfinite(link.z) else "n/a"
        out.append(f"{lead}, the held-out {shrink['kind']} RMS is " + " ".join(f"{v:.3g}" for v in a)
                   + f" (paired block-wise z {z} on the {link.kind or 'first'} recordings; {how}).")
    for sw in chain.swaps:
        e0, e1, z = sw["excess_before"].get(sw["kind"]), sw["excess_after"].get(sw["kind"]), sw["paired_z"]
        g = lambda v, f=".3g": "n/a" if v is None else format(v, f)  # noqa: E731  (diagnosis.json holds None, not NaN)
        how = "" if z is not None and z >= t.z_min else " with fewer parameters"
        out.append(f"With {', '.join(n for n in sw['named_before'] if n != sw['out'])} named, {sw['in']} in place of "
                   f"{sw['out']} predicts held-out data better{how} (excess over the floor {g(e0)} -> {g(e1)} on the "
                   f"{sw['kind']} recordings, paired block-wise z {g(z, '.1f')}): {sw['out']} is swapped out.")
    out.append(f"The chain of effects stopped: {chain.stop}.")
    return out


class CalibratedRun(Protocol):
    """What :func:`diagnose_run` reads of a calibration run (:class:`~ftcal_nlp.calibration_run.CalibrationRun`, which
    holds the diagnosis' result: a Protocol here keeps the diagnosis below it): the dataset, the stage results and the
    settings (read-only properties: the run is frozen)."""

    @property
    def dataset(self) -> Dataset: ...
    @property
    def hanging(self) -> Any: ...
    @property
    def poses(self) -> Any: ...
    @property
    def standing(self) -> Any: ...
    @property
    def calibration(self) -> Calibration: ...
    @property
    def settings(self) -> CalibrationSettings: ...


def diagnose_run(run: CalibratedRun, registry: Mapping[str, Effect] | None = None) -> DiagnosisResult:
    """The diagnosis of a calibration run with its own diagnose settings, model and balance (candidate
    effects from ``registry``, None: ``ftcal_nlp.effects.EFFECTS``)."""
    st = run.standing
    balance = st.balance if st is not None else run.settings.standing.balance
    model = run.calibration.model
    x0 = st.x if (st is not None and getattr(st, "x", None) is not None and st.model == model) else None
    return diagnose(run.dataset, run.hanging, run.poses, run.calibration, run.dataset.robot, run.settings.diagnose,
                    model=model, balance=balance, x_start=x0, registry=registry)
