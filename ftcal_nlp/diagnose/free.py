"""The diagnosis of free loads (``DATA_FORMAT.md`` section 5; issue 23): payloads and URDF loads.

Per transducer with a free load (``freeload``'s fit ``x* = [w_o, theta, r]``):

1. every sample of every recording in which the load hangs free, moving ones included
   (``free_model.context_for``): the residual ``r_n = y_n - h(x*; s_n)``;
2. the noise floor from held, still stretches of the readings (``free_model.hold_floor``), not from a fit;
3. blocked cross-validation (``free_cv.py``: blocks are holds with the move after them, or time blocks;
   ``folds``/``seed`` of :class:`~ftcal_nlp.core.settings.DiagnoseSettings`) of the model linearised around
   ``x*``, ``r ~ J dx``: the held-out RMS before any effect;
4. the chain (``chain.py``): the strongest effect of the library by held-out evidence (every unit with a
   free face, ``effects/free_faces.py``), refit jointly with it, look again, stop when the next adds nothing
   significant; the named effects refit together on every sample (parameters with se);
5. where the gap lies (``correlates.py``): the residual against time, each joint angle, the rates
   ("motion"), the load's history ("load", "pose_history") and temperature; the components above the floor.

Verdict (per transducer, then the dataset's: the first transducer with an effect, else with a gap):
``effect`` when the chain named one; else ``unexplained`` when a gap remains that a correlate follows
(``explained_min`` of ``DiagnoseSettings.free_loads``) or that is far above the floor (``FAR``: held-out RMS ``FAR`` x the floor);
else ``none`` (a gap without structure is reported as noise the floor underrates, with its size).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.data import Dataset
from ..effects import Effect, resolve_effects
from ..effects.free_refine import use_model_face
from ..core.settings import DiagnoseSettings
from .chain import GAP_REL, Chain, JointFit, excess_ratio, joint_fit, run_chain
from .correlates import CorrelateScore, score_correlates
from .free_cv import Design, cv_blocks, fold_of_blocks
from .free_model import context_for, hold_floor, model_face
from .result import DiagnosisResult

log = logging.getLogger(__name__)

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
#: a gap this many times the floor (held-out RMS) is "far above" it: unexplained even without a correlate
FAR = 2.0


@dataclass
class FreeLegDiagnosis:
    """One transducer's free-load diagnosis (module docstring)."""

    leg: str
    verdict: str
    floor: np.ndarray
    floor_samples: int
    before: np.ndarray                    # held-out RMS of the free-load model (6,)
    after: np.ndarray                     # held-out RMS after the chain (6,)
    chain: Chain
    joint: JointFit | None
    correlates: list[CorrelateScore]
    where: dict
    n: int
    n_still: int
    blocks: int
    notes: list[str] = field(default_factory=list)
    plot: dict = field(default_factory=dict)
    floor_known: bool = True              # False: no still stretch; ``floor`` is the fit's residual sd
    param_names: tuple = ()               # the free-load fit's parameters (the Jacobian's columns)
    fit_params: tuple = ()                # ... and their values at the fit
    added: list = field(default_factory=list)   # per named effect its parameters when it was added
    delay_blocks: dict = field(default_factory=dict)  # a named clock offset's delay per time block (``delay_change``)
    refit: Any = None                     # the free-load fit at the joint refit (``relinearised``; None: no effect)

    def to_json_dict(self) -> dict:
        """This transducer's diagnosis for ``diagnosis.json`` (``free_loads.<transducer>``)."""
        lst = lambda a: [float(x) for x in a]  # noqa: E731
        return {"verdict": self.verdict, "samples": self.n, "quasi_static": self.n_still, "cv_blocks": self.blocks,
                "noise_floor": lst(self.floor), "floor_samples": self.floor_samples,
                "noise_floor_source": "held, still stretches" if self.floor_known else "none (no still stretch): the fit's residual sd",
                "heldout_rms_before": lst(self.before), "heldout_rms_after": lst(self.after),
                "chain": [{"step": i + 1, "candidates": [{"effect": c.effect.name, "shape": c.shape, "status": c.status,
                                                           "paired_z": None if c.cv is None else float(c.z),
                                                           "explained": None if c.cv is None else float(c.excess_share),
                                                           "heldout_rms_after": None if c.cv is None else lst(c.cv.rms())}
                                                          for c in rd]} for i, rd in enumerate(self.chain.rounds)],
                "stop": self.chain.stop,
                "correlates": [{"correlate": c.name, "explained": float(c.explained), "heldout_rms_after": lst(c.heldout_rms)}
                               for c in self.correlates],
                "where": {k: v for k, v in self.where.items()}, "notes": list(self.notes),
                **({"clock_offset_blocks": self.delay_blocks} if self.delay_blocks else {}),
                **({"joint_refit": self.joint_refit_json()} if self.joint is not None else {})}

    def joint_refit_json(self) -> dict:
        """The free-load parameters refit with the named effects (linearised: the fit's value plus the change), with
        se (null: undetermined by these data)."""
        if self.joint is None:
            raise ValueError(f"{self.leg}: no effect named, no joint refit")
        assert self.refit is not None, "a joint refit comes with its free-load fit (relinearised)"
        x0 = np.asarray(self.fit_params, float)
        x = np.asarray(self.refit.params, float)
        return {n: {"value": float(v), "change": float(v - v0), "se": float(e) if np.isfinite(e) else None}
                for n, v0, v, e in zip(self.param_names, x0, x, self.joint.dx_se)}

    def effects_json(self) -> list[dict]:
        out = []
        for i, s in enumerate(self.chain.steps):
            pars = self.joint.params[i] if self.joint is not None else {}
            when = self.added[i] if i < len(self.added) else {}
            out.append({"name": s.effect.name, "transducer": self.leg, "shape": s.shape,
                        "parameters": {k: {"value": v, "se": e if np.isfinite(e) else None} for k, (v, e) in pars.items()},
                        "parameters_when_added": {k: {"value": v, "se": e if np.isfinite(e) else None} for k, (v, e) in when.items()},
                        "heldout_rms_after": [float(x) for x in s.fit.rms()],
                        "paired_z": float(s.z), "explained": float(s.excess_share),
                        "explains": _explains(s.effect, s)})
        return out


def _explains(effect: Effect, cand=None) -> str | None:
    e = getattr(effect, "free_explains", None) or effect.explains
    if e == "joint":
        j = (cand.shape or {}).get("joint") if cand is not None else None
        return f"joint:{j}" if j else None
    return e


def diagnose_leg(ds: Dataset, leg: str, fit, effects: list[Effect], s: DiagnoseSettings) -> FreeLegDiagnosis:
    """Steps 1-5 of the module docstring for transducer ``leg``."""
    ctx, notes = context_for(ds, leg, fit)
    floor, n_floor = hold_floor(ctx)
    floor_known = bool(np.all(np.isfinite(floor) & (floor > 0)))
    if not floor_known:
        # no still stretch (a list of single-row poses): no floor; the fit's residual sd balances the channels
        floor = np.asarray(fit.sigma, float).copy()
        notes.append(f"{leg}: the readings hold no held, still stretch (consecutive samples of one pose): no noise floor is "
                     "known; the channels are weighted by the free-load fit's residual sd, effects are named by held-out "
                     "significance alone and no gap size can be stated")
    ctx = dataclasses.replace(ctx, sigma=floor)   # what a face's refinement weighs channels by
    J = model_face(ctx, fit)      # the model Jacobian as its channel blocks
    names = J.names
    use_model_face(ctx, J)        # a face's refinement regresses on the same columns (no second Jacobian)
    block = cv_blocks(ctx.hold, ctx.rec, s.folds)
    if int(block.max()) + 1 < s.folds:
        notes.append(f"{leg}: {ctx.n} samples make {int(block.max()) + 1} cross-validation block(s), fewer than the {s.folds} "
                     "folds: not diagnosed")
        return _undiagnosed(leg, ctx, floor, n_floor, notes)
    fold = fold_of_blocks(block, s.folds, s.seed)
    design = Design(ctx.y - ctx.pred, 1.0 / floor, block, fold)
    ch = run_chain(design, J, ctx, effects, floor, s.free_loads, floor_known)
    base, cur = ch.base_fit, ch.current
    jf, refit, ctx_at, steps_at = (relinearised(ds, leg, fit, ch.steps, ctx, design, J, floor) if ch.steps
                                   else (None, None, ctx, []))
    # each effect's parameters as the chain added it (refit with those before it only): when later effects are
    # confounded with it, the joint refit splits what they share and says so by its se
    added = [joint_fit(design, J, ch.steps[:i + 1], ctx).params[i] for i in range(len(ch.steps) - 1)]
    if jf is not None:   # the last effect's: the joint refit of them all
        added.append(jf.params[-1])
    delay_blocks = delay_change(ctx_at, steps_at, jf, floor, notes) if jf is not None else {}
    ratio_after = excess_ratio(cur, floor)
    gap_after = floor_known and bool(np.max(ratio_after) > 1.0 + GAP_REL)
    gap_before = floor_known and bool(np.max(excess_ratio(base, floor)) > 1.0 + GAP_REL)
    extra = [st.face for st in ch.steps]
    # where: the gap as found (before any effect) when an effect explains it; what remains otherwise
    ref = cur if (gap_after and not ch.steps) or not ch.steps else base
    corr = score_correlates(design, J, ref, ctx, None) if (gap_before or gap_after) else []
    if ch.steps and gap_after:  # what the named effects leave: where it lies
        rest = score_correlates(design, J, ch.current_design, ctx, extra)
    else:
        rest = []
    top = corr[0] if corr and corr[0].explained >= s.free_loads.explained_min else None
    if ch.steps:
        verdict = "effect"
    elif gap_before and (top is not None or np.max(excess_ratio(base, floor)) > FAR):
        verdict = "unexplained"
    else:
        verdict = "none"
        if gap_before:
            notes.append(f"{leg}: the held-out residual exceeds the floor by up to "
                         f"{100 * (np.max(excess_ratio(base, floor)) - 1):.0f} % without following any correlate: "
                         "reported as noise the floor underrates, not as a gap")
    comps = []
    if verdict == "effect":    # where the named effects' fitted wrench stands out of the noise
        assert jf is not None, "effects named: jf is their joint refit"
        comps = _components(jf.wrench(steps_at), floor)
    elif verdict == "unexplained":
        comps = [c for c, r in zip(WRENCH, excess_ratio(base, floor)) if r > 1.0 + GAP_REL]
        if top is not None:   # where the correlate's fit stands out (a shared refit leaks a gap into other channels)
            w = top.wrench
            assert w is not None, "the best correlate keeps its face (correlates.py)"
            comps = _components(w, floor) or comps
    first_explains = _explains(ch.steps[0].effect, ch.steps[0]) if ch.steps else None
    explains = first_explains or (top.name if top is not None else None)
    where: dict[str, Any] = {"recordings": list(ctx.names) if verdict != "none" else [], "legs": [leg] if verdict != "none" else [],
             "components": comps, "explains": explains if verdict != "none" else None}
    rest_top = rest[0] if rest and rest[0].explained >= s.free_loads.explained_min else None
    if ch.steps and gap_after:
        where["remaining"] = {"components": [c for c, r in zip(WRENCH, ratio_after) if r > 1.0 + GAP_REL],
                              "explains": rest_top.name if rest_top is not None else None,
                              "heldout_rms_over_floor": [float(x) for x in ratio_after]}
    plot = {}
    show = top if verdict == "unexplained" else (rest_top if rest_top is not None else top)
    if show is not None:
        res = (cur if verdict == "unexplained" or rest_top is not None else base).heldout
        c = int(np.argmax(res.std(axis=0) / floor))
        plot = {"x": show.x, "y": res[:, c], "xlabel": show.xlabel, "component": WRENCH[c], "floor": float(floor[c]),
                "correlate": show.name, "leg": leg}
    design.release()   # the cached sums and every face tried (hundreds of MB on 10^5 samples) are not kept with the result
    return FreeLegDiagnosis(leg, verdict, floor, n_floor, base.rms(), cur.rms(), ch, jf, corr, where, ctx.n,
                            int(ctx.still.sum()), int(block.max()) + 1, notes, plot, floor_known, tuple(names),
                            tuple(float(v) for v in fit.params), added, delay_blocks, refit)


def relinearised(ds: Dataset, leg: str, fit, steps: list, ctx, design: Design, J, floor: np.ndarray):
    """``(joint refit, the free-load fit it gives, the context and the steps' faces at its point)``: the named effects
    refit together
    with the free-load model (``chain.joint_fit``), relinearised once. The first refit, linearised around the
    free-load fit ``x*``, gives ``x1 = x* + dx`` (``FreeLoadResult.moved``); the model, its Jacobian and the effects'
    faces (their shapes as named, with what each face took from the whole session, ``free_reference``, as it was)
    are formed again at ``x1`` and refit. Why: a face that scales with the model (a sensor matrix's ``E w(x)``, a
    creep of ``pred``) meets the fit's own change to second order (``E J dx``): on a 2 % gain matrix it moved the
    determined parts by up to 4 se on 10^4 samples, the second pass brings them within 2 (a third changes them
    by a tenth of an se). The weights, blocks and folds are the chain's."""
    jf0 = joint_fit(design, J, steps, ctx)
    at = fit.moved(jf0.dx)
    ctx1, _ = context_for(ds, leg, at)
    ctx1 = dataclasses.replace(ctx1, sigma=ctx.sigma)
    for st in steps:   # the session's references as the chain named them (a step's time, a temperature's mean)
        ctx1.extra.update(st.effect.free_reference(ctx, st.shape))
    J1 = model_face(ctx1, at)
    use_model_face(ctx1, J1)
    steps1 = []
    for st in steps:
        face = st.effect.free_face(ctx1, st.shape)
        if face is None or face.k != st.shaped_face.k:
            raise RuntimeError(f"{leg}: {st.effect.name} {st.shape}: its face does not form again at the joint refit's "
                               "point (a unit's face must follow from its shape and session reference)")
        steps1.append(dataclasses.replace(st, face=face, base=None))
    design1 = Design(ctx1.y - ctx1.pred, design.w, design.block, design.fold)
    jf = joint_fit(design1, J1, steps1, ctx1)
    design1.release()
    return jf, at.moved(jf.dx), ctx1, steps1


def delay_change(ctx, steps: list, jf: JointFit, floor: np.ndarray, notes: list[str]) -> dict:
    """Whether a named clock offset's delay changes over the recording (``clock_offset.delay_by_block``: the delay per
    time block on the joint refit's residual with the delay's own wrench added back, tested for constancy); a change is
    said in ``notes`` with the time of the largest jump (s from the start of its recording). ``{}`` without a named
    one-delay clock offset."""
    from ..effects.clock_offset import delay_by_block

    i = next((k for k, st in enumerate(steps) if st.effect.name == "clock_offset" and st.shape.get("channels") == "all"), None)
    if i is None:
        return {}
    d = float(jf.betas[i][0])
    out = delay_by_block(ctx.t, ctx.rec, jf.resid + jf.wrench(steps, i), ctx.pred, 1.0 / floor, d, jf.s2)
    start = {int(q): float(ctx.t[ctx.rec == q][0]) for q in np.unique(ctx.rec)}
    for b in out["blocks"]:
        q = int(b.pop("recording"))
        b["recording"] = ctx.names[q]
        b["t_start"] -= start[q]
        b["t_end"] -= start[q]
    jump = out.get("largest_jump")
    if jump is not None:
        q = int(jump["recording"])
        jump["recording"], jump["t_s"] = ctx.names[q], jump["t_s"] - start[q]
    if out["changes"] and jump is not None:
        notes.append(f"{ctx.leg}: the clock offset changes over the recording: the delay per time block "
                     + ", ".join(f"{b['delay_s']:.4g}" for b in out["blocks"]) + f" s (chi2 {out['chi2']:.1f} on "
                     f"{out['dof']} dof, p {out['p']:.2g}); the largest jump, {jump['from_s']:.4g} -> {jump['to_s']:.4g} s "
                     f"({jump['z']:.1f} se), at {jump['t_s']:.1f} s into {jump['recording']}")
    return out


def _undiagnosed(leg, ctx, floor, n_floor, notes) -> FreeLegDiagnosis:
    nan = np.full(6, np.nan)
    where: dict[str, Any] = {"recordings": [], "legs": [], "components": [], "explains": None}
    return FreeLegDiagnosis(leg, "none", floor, n_floor, nan, nan, Chain(None, stop="not diagnosed: too few samples"), None, [],
                            where, ctx.n, int(ctx.still.sum()), 0, notes, {}, False)


#: a channel lies in the gap when the fitted wrench of what explains it has an RMS of at least this share of its floor
COMPONENT_SHARE = 0.5


def _components(w: np.ndarray, floor: np.ndarray) -> list[str]:
    rel = np.sqrt(np.mean(w**2, axis=0)) / floor
    return [c for c, r in zip(WRENCH, rel) if r >= COMPONENT_SHARE * rel.max() or r >= COMPONENT_SHARE]


def diagnose_free(dataset: Dataset, free_loads, settings: DiagnoseSettings | None = None, *,
                  registry: Mapping[str, Effect] | None = None) -> DiagnosisResult:
    """The diagnosis of a free-load dataset (module docstring): ``free_loads`` the
    :class:`~ftcal_nlp.estimate.freeload.FreeLoadResults`; candidates from ``registry`` (None: the library), those with a
    free face (``free_shapes``), as picked by ``settings.effects``."""
    t0 = time.perf_counter()
    s = DiagnoseSettings() if settings is None else settings
    effects = resolve_effects(s.effects, registry)
    legs = {}
    for leg, fit in free_loads.legs.items():
        legs[leg] = diagnose_leg(dataset, leg, fit, effects, s)
        log.info("diagnosis of %s: %s; effects %s", leg, legs[leg].verdict, [st.effect.name for st in legs[leg].chain.steps])
    order = sorted(legs.values(), key=lambda d: ({"effect": 0, "unexplained": 1, "none": 2}[d.verdict],
                                                  -float(np.nan_to_num(np.max(d.before / d.floor)))))
    main = order[0]
    effects_json = [e for d in legs.values() for e in d.effects_json()]
    verdict = main.verdict
    effect = main.chain.steps[0].effect.name if verdict == "effect" else None
    shrink = {"heldout_rms_before": main.before, "heldout_rms_after": main.after, "noise_floor": main.floor, "kind": "hanging",
              "kind_key": "free load"}
    ranking = []
    first = main.chain.rounds[0] if main.chain.rounds else []
    for c in first:
        ranking.append({"effect": c.effect.name, "delta_bic": c.delta_bic,
                        "heldout_rms_after": c.cv.rms() if c.cv is not None else main.before,
                        "explained": max(c.excess_share, 0.0), "status": c.status, "note": c.note, "variant": dict(c.shape)})
    statement = _statement(main, legs)
    notes = tuple(n for d in legs.values() for n in d.notes)
    kinds = {f"free load {d.leg}": {"excess": float(np.max(d.before / d.floor) - 1.0), "threshold": GAP_REL, "n": d.n,
                                    "heldout_rms": [float(x) for x in d.before], "noise_floor": [float(x) for x in d.floor]}
             for d in legs.values()}
    gaps = {f"free load {d.leg}": float(np.max(d.before / d.floor) - 1.0) for d in legs.values() if d.verdict != "none"}
    return DiagnosisResult(verdict, effect, main.where, shrink, ranking, {}, tuple(statement), None, gaps, kinds,
                           "free_load", "n/a", time.perf_counter() - t0, notes, effects=effects_json, free=legs,
                           thresholds=s.free_loads)


def _fmt(v) -> str:
    return " ".join(f"{x:.3g}" for x in v)


def _statement(main: FreeLegDiagnosis, legs: dict) -> list[str]:
    out = []
    for d in legs.values():
        head = f"Transducer {d.leg} ({d.n} samples, {d.n_still} quasi-static, {d.blocks} cross-validation blocks): "
        if d.blocks == 0:
            out.append(head + "not diagnosed (too few samples for a blocked cross-validation).")
        elif d.verdict == "none" and not d.floor_known:
            out.append(head + "no noise floor is known (no held, still stretch in the readings) and no library effect passes "
                       "the held-out test (held-out RMS " + _fmt(d.before) + ").")
        elif d.verdict == "none":
            out.append(head + "no gap above the noise floor (held-out RMS " + _fmt(d.before) + " vs floor " + _fmt(d.floor) + ").")
        elif d.verdict == "effect":
            names = [st.effect.name for st in d.chain.steps]
            out.append(head + "the gap is explained by " + " then ".join(names) + "; held-out RMS " + _fmt(d.before)
                       + " -> " + _fmt(d.after) + (" (floor " + _fmt(d.floor) + ")." if d.floor_known else
                                                    " (no noise floor known: the fit's residual sd " + _fmt(d.floor) + ")."))
        else:
            w = d.where
            out.append(head + "a gap that no library effect explains: held-out RMS " + _fmt(d.before) + " vs floor " + _fmt(d.floor)
                       + f"; it lies in {', '.join(w['components']) or 'every component'}"
                       + (f" and follows {w['explains']}" if w.get("explains") else "") + ".")
        for i, st in enumerate(d.chain.steps):
            out.append(f"  {i + 1}. {st.effect.name} {st.shape or ''}: held-out RMS after " + _fmt(st.cv.rms())
                       + f" (paired block z {st.z:.1f}; removes {100 * st.excess_share:.0f} % of the "
                       + ("excess then left)." if d.floor_known else "held-out sum of squares then left)."))
        if d.chain.stop:
            out.append(f"  The chain stopped: {d.chain.stop}.")
        jump = d.delay_blocks.get("largest_jump") if d.delay_blocks.get("changes") else None
        if jump is not None:
            out.append(f"  The clock offset changes over the recording (per-block delays, chi2 {d.delay_blocks['chi2']:.1f} on "
                       f"{d.delay_blocks['dof']} dof): the largest jump, {jump['from_s']:.4g} -> {jump['to_s']:.4g} s, at "
                       f"{jump['t_s']:.1f} s into {jump['recording']}.")
        rem = d.where.get("remaining")
        if rem:
            out.append(f"  Left after the named effects: {', '.join(rem['components'])} above the floor"
                       + (f", following {rem['explains']}" if rem.get("explains") else "") + ".")
        if d.correlates:
            out.append("  Correlates (share of the held-out excess each explains): "
                       + ", ".join(f"{c.name} {100 * c.explained:.0f} %" for c in d.correlates[:5]) + ".")
    return out
