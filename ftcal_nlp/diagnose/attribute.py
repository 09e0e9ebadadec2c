"""Attribution: every candidate effect added in turn, scored on data it was not fitted to.

For each effect of the library and each recording kind where it has a face:

* standing: the selected error model plus the effect (``standing_fit.py``),
  k-fold cross-validated over the poses (the folds of ``selection.fold_indices``),
  against the model alone under the same folds; ``delta_bic`` from the full-data
  fits with the effective number of added parameters;
* hanging and walking swing: the linear faces (``linear_fit.py``), contiguous
  time-block folds;
* design (the effects with ``design_face``: mocap_bias, tether_force): when the model
  frees the transducer rotations it absorbs a mocap bias (and a tether's horizontal force)
  as one common tilt of all fitted frames; :func:`ftcal_nlp.effects.design_check` tests for it.

Effects are ranked by the sum of their ``delta_bic`` over the kinds where the
gap lies (BIC penalises the parameters a candidate spends; the held-out
improvement says whether it beats the floor). Verdict (``decide``):

* a kind has a gap when its held-out excess over the floor, ``mean_c
  (mse_c / floor_c^2) - 1``, exceeds its threshold (standing: 0.5, and four of
  its sampling standard errors ``sqrt(2/P)``; hanging 0.1; walking swing 1.0, whose
  floor comes from few samples);
  the design kind when its ``delta_bic < -10``;
* ``none``: no gap anywhere;
* ``effect``: the candidate with the lowest ``delta_bic`` among those with
  ``delta_bic < -10`` (strong evidence) that remove at least ``explained_min`` of the excess
  (``DiagnoseSettings.hexapod``, :func:`explaining`),
  averaged over the kinds with a gap (weights ``log(1 + excess)``) (a candidate that only fits the calibration's
  own small errors, e.g. a mass term absorbing the hanging leg weights' error,
  does not explain a gap elsewhere);
* ``unexplained``: a gap that no candidate explains.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np

from ..estimate.selection import fold_indices
from ..effects import Effect, design_check
from ..effects.combined import Combined
from .linear_fit import base_linear, rebase, recalibrate, score_linear
from .scores import KindScore
from ..core.solver import SolverError
from .standing_fit import AugmentedProblem
from .views import Views

log = logging.getLogger(__name__)

DBIC_STRONG = -10.0
GAP_THRESHOLD = {"standing": 0.5, "hanging": 0.1, "walking swing": 1.0}


@dataclass(frozen=True)
class EffectScore:
    """One candidate: per-kind scores, design check, parameters fitted on all standing poses."""

    effect: str
    kinds: dict
    status: str = "ok"
    design: dict | None = None
    fit: Any = None                  # AugmentedFit of the standing face on every pose (results protocol), or None
    note: str = ""
    time_s: float = 0.0
    model_effect: Any = None         # the Effect variant scored (faces of the chosen flexibility)

    @property
    def label(self) -> str:
        return self.model_effect.label if self.model_effect is not None else self.effect

    @property
    def delta_bic(self) -> float:
        """Sum over every kind the effect was scored on (and the design check)."""
        return self.delta_bic_on(None)

    def delta_bic_on(self, kinds) -> float:
        """Sum over ``kinds`` (None: all; ``"design"`` for the design check)."""
        if self.status != "ok":
            return float("nan")
        d = sum(s.delta_bic for k, s in self.kinds.items() if kinds is None or k in kinds)
        if self.design is not None and (kinds is None or "design" in kinds):
            d += self.design["delta_bic"]
        return float(d)


@dataclass(frozen=True)
class Attribution:
    base: dict                       # kind -> KindScore of the model alone
    scores: list                     # EffectScore, best first
    design: dict | None              # design check of the fitted frames (None: rotations not free)
    standing_heldout: np.ndarray | None = None   # (P, 6) W axes, model alone
    standing_after: dict = field(default_factory=dict)  # effect -> (P, 6) held-out residuals with it
    model: str = ""
    balance: str = "exact"
    views: Views | None = None       # the views scored (standing floor with its nugget)
    folds: list = field(default_factory=list)


def _kind_score(kind, floor, held_before, held_after, in_before, in_after, dof) -> KindScore:
    s = np.where(floor > 0, floor, 1.0)
    return KindScore(kind, (held_before**2).mean(0), (held_after**2).mean(0), floor,
                     float(((held_before / s) ** 2).sum()), float(((held_after / s) ** 2).sum()),
                     float(((in_before / s) ** 2).sum()), float(((in_after / s) ** 2).sum()), held_before.size, int(dof),
                     ((held_before / s) ** 2).sum(1), ((held_after / s) ** 2).sum(1))


def _warm_start(prob: AugmentedProblem, x_base: np.ndarray, base: AugmentedProblem) -> np.ndarray:
    """A start for ``prob`` (the named effects and one more, ``effects/combined.py``) from the fit ``x_base`` of
    ``base`` (the named effects): the model's and the named faces' values, the new face at its start."""
    x0 = np.array(prob.x0, float)
    x0[: prob.n_model] = x_base[: base.n_model]
    shifts = base.effect is not None and base.effect.shifts_offsets   # the model alone shifts no offsets
    m_face = base.n_eta - (6 if shifts else 0)
    x0[prob.n_model : prob.n_model + m_face] = x_base[base.n_model : base.n_model + m_face]
    if shifts:
        x0[-6:] = x_base[-6:]
    return x0


def rotations_free(problem: AugmentedProblem) -> bool:
    """Does the error model estimate the transducer rotations (so that it absorbs a common tilt)?"""
    return any(ca.depends_on(R, problem.spec.x) for R in problem.spec.R)


def attribute(views: Views, effects: list[Effect], model, prior, robot, balance: str, *, folds: int, seed: int,
              x_start: np.ndarray | None = None, base_effect: Combined | None = None) -> Attribution:
    """Score every effect in ``effects`` that has hexapod faces (module docstring); ``x_start`` the model's fitted
    x (warm start). ``base_effect``: the effects named so far (the chain, ``hexchain.py``): they are part of the
    base model (standing: its augmented problem; hanging, swing: their faces, cross-validated), each candidate is
    scored with them (``Combined(named + [candidate])``) against it, and the design check is left out when a named
    effect has a design face."""
    effects = hexapod_candidates(effects)
    base: dict = {}
    base_off = None
    sv = views.standing
    base_prob = None
    held0 = None
    design = None
    fidx = None
    raw: dict = {}   # the chain's base scores against the model alone (their dof), what candidates are rebased on
    ref_off = None   # the offsets the swing residuals were computed with (the chain: the model alone's)
    if sv is not None:
        base_prob = AugmentedProblem(model, prior, robot, balance, base_effect)
        fidx = fold_indices(sv.P, folds, seed)
        x0 = base_prob.x0 if x_start is None or len(x_start) != base_prob.n_model else x_start
        if base_effect is not None:
            x0 = np.concatenate([x0[: base_prob.n_model], base_prob.x0[base_prob.n_model :]])
            ref_off = AugmentedProblem(model, prior, robot, balance).transforms(x0)[2]
        cv0 = base_prob.cross_validate(sv.data, sv.R_WB, fidx, x0)
        xb, dof_b, held0, in0 = cv0.x, cv0.dof, cv0.held, cv0.r_in
        # the floor is the noise model's (floor.py), never raised from the residual it is compared with
        base["standing"] = _kind_score("standing", sv.floor, held0, held0, in0, in0, 0)
        R_b, _, base_off = base_prob.transforms(xb)
        if base_effect is None:
            ref_off = base_off
        if rotations_free(base_prob) and not (base_effect is not None and base_effect.design_face):
            design = design_check(R_b, robot.nominal_rotations())
    if base_effect is None:
        if views.hanging is not None:
            base["hanging"] = base_linear(views.hanging)
        if views.swing is not None:
            base["walking swing"] = base_linear(views.swing)
    else:
        if views.hanging is not None:
            face = base_effect.hanging_features(views.hanging.legs)
            raw["hanging"] = score_linear(views.hanging, face, folds)[0] if face is not None else None
            base["hanging"] = _as_base(raw["hanging"]) if face is not None else base_linear(views.hanging)
        if views.swing is not None:
            sw_b = recalibrate(views.swing, R_b, base_off, ref_off) if sv is not None else None
            face = base_effect.swing_features(views.swing.legs if sw_b is None else sw_b.legs)
            raw["walking swing"] = score_linear(views.swing, face, folds, after=sw_b)[0] if (face is not None or sw_b is not None) else None
            base["walking swing"] = _as_base(raw["walking swing"]) if raw["walking swing"] is not None else base_linear(views.swing)

    def scored(kind: str, sc: KindScore) -> KindScore:
        """A candidate's kind score against the base (the chain: against the named effects' faces)."""
        return rebase(sc, raw[kind]) if raw.get(kind) is not None else sc

    def score_one(eff: Effect) -> tuple[EffectScore, np.ndarray | None]:
        t0 = time.perf_counter()
        kinds: dict = {}
        status, note, fit, recal, held = "ok", "", None, None, None
        try:
            if sv is not None and eff.needs_report_balance and balance != "report":
                note = "not applicable: the calibration already uses the exact balance (moving CoMs included)"
            elif sv is not None:
                assert base_prob is not None and fidx is not None, "both are set with the standing view (above)"
                prob = AugmentedProblem(model, prior, robot, balance, eff if base_effect is None else Combined(base_effect.members + (eff,)))
                if prob.n_eta > 0 or prob.balance != balance:
                    x0 = np.concatenate([xb, prob.x0[prob.n_model :]]) if base_effect is None else _warm_start(prob, xb, base_prob)
                    cv = prob.cross_validate(sv.data, sv.R_WB, fidx, x0)
                    x, dof, held, r_in = cv.x, cv.dof, cv.held, cv.r_in
                    kinds["standing"] = _kind_score("standing", sv.floor, held0, held, in0, r_in, dof - dof_b)
                    fit = prob.result(x, prob.design(sv.data))
                    R_e, _, off_e = prob.transforms(x)
                    recal = (R_e, off_e)
            both = eff if base_effect is None else Combined(base_effect.members + (eff,))
            if views.hanging is not None:
                face = eff.hanging_features(views.hanging.legs)
                if face is not None:
                    kinds["hanging"] = scored("hanging", score_linear(views.hanging, both.hanging_features(views.hanging.legs)
                                                                      if base_effect is not None else face, folds)[0])
            if views.swing is not None:
                # The swing legs' weights are predicted with the calibration's rotations: with the
                # effect added to the standing fit they move, and the swing residual with them.
                sw_after = None
                if recal is not None:
                    sw_after = recalibrate(views.swing, recal[0], recal[1], ref_off)
                face = eff.swing_features(views.swing.legs if sw_after is None else sw_after.legs)
                if face is not None or sw_after is not None:
                    if base_effect is not None:
                        face = both.swing_features(views.swing.legs if sw_after is None else sw_after.legs)
                    kinds["walking swing"] = scored("walking swing", score_linear(views.swing, face, folds, after=sw_after)[0])
        except SolverError as exc:
            status = f"failed: {exc.status}"
            log.warning("diagnosis: %s", exc)
        dsg = design if (eff.design_face and design is not None) else None
        if not kinds and dsg is None:
            note = note or "no face on these recordings"
            if status == "ok":
                status = "not applicable"
        return EffectScore(eff.name, kinds, status, dsg, fit, note, time.perf_counter() - t0, eff), held

    scores, after = [], {}
    for eff in effects:
        # Faces flexible in their correlate (issue 13, item 4): every variant is scored and the one
        # with the smallest held-out residual (summed over kinds, in floor units) is kept.
        tried = [score_one(v) for v in eff.variants()]
        best, held = min(tried, key=lambda sh: (sh[0].status != "ok", sum(k.z_after for k in sh[0].kinds.values())))
        if len(tried) > 1:
            best = replace(best, time_s=sum(sc.time_s for sc, _ in tried))
        scores.append(best)
        if held is not None:
            after[eff.name] = held
    att = Attribution(base, scores, design, held0, after, getattr(base_prob.model, "name", str(model)) if base_prob else str(model),
                      balance, views, fidx or [])
    return replace(att, scores=ranked(att))


def _as_base(sc: KindScore) -> KindScore:
    """What the named effects' faces leave (``sc``'s after) as a base score: nothing added to it."""
    return KindScore(sc.kind, sc.mse_after, sc.mse_after, sc.floor, sc.z_after, sc.z_after, sc.rss_after, sc.rss_after, sc.n, 0,
                     sc.blocks_after, sc.blocks_after)


def hexapod_candidates(effects: list[Effect]) -> list[Effect]:
    """The candidates a hexapod dataset can be diagnosed with: the units whose ``diagnosed_on`` holds "hexapod" (a
    free-load-only unit has no standing, hanging or swing face; it is not a candidate here, not a row of the ranking)."""
    return [e for e in effects if "hexapod" in e.diagnosed_on]


def ranking_bic(score: EffectScore, gap: dict) -> float:
    """What candidates are ranked by: ``delta_bic`` summed over the kinds with a gap (all kinds
    when there is none). Elsewhere the calibration's own small errors would reward any flexible
    face (a tether's per-leg tilts fitting the few-mN swing residual a mass error leaves)."""
    return score.delta_bic_on(list(gap) if gap else None)


def ranked(att: Attribution) -> list:
    gap = gaps(att)
    # Ties (two candidates explaining a design-only gap alike) go to the smaller total dBIC: the
    # candidate whose other faces spend parameters for nothing loses.
    key = lambda s: (s.status != "ok" or (not s.kinds and s.design is None), np.nan_to_num(ranking_bic(s, gap), nan=np.inf),
                     np.nan_to_num(s.delta_bic, nan=np.inf))
    return sorted(att.scores, key=key)


# ----------------------------------------------------------------------------- verdict


def gap_threshold(kind: str, score: KindScore) -> float:
    return kind_threshold(kind, score.n / 6)    # a standing score counts pose x component values


def kind_threshold(kind: str, n_poses: float) -> float:
    """The gap threshold of ``kind``; on the standing poses it rises with the scatter of ``n_poses`` poses' excess."""
    thr = GAP_THRESHOLD.get(kind, 0.25)
    if kind == "standing":
        thr = max(thr, 4.0 * np.sqrt(2.0 / max(n_poses, 1)))
    return thr


def gaps(att: Attribution) -> dict:
    """Kinds with a gap -> their excess over the floor (design: -delta_bic / 10 as a size)."""
    out = {}
    for kind, s in att.base.items():
        if s.excess_before > gap_threshold(kind, s):
            out[kind] = s.excess_before
    if att.design is not None and att.design["delta_bic"] < DBIC_STRONG:
        out["design"] = -att.design["delta_bic"] / 10.0
    return out


def explained_fraction(score: EffectScore, gap: dict) -> float:
    """Fraction of the excess removed, averaged over the kinds with a gap with weights
    ``log(1 + excess)``: a secondary gap (e.g. the swing legs' weights mispredicted by rotations
    that absorbed the effect) counts, but less than the one where the effect shows most."""
    if not gap:
        return 0.0
    fr, wt = [], []
    for kind, size in gap.items():
        if kind == "design":
            fr.append(1.0 if score.design is not None else 0.0)
        elif kind in score.kinds:
            fr.append(float(np.clip(score.kinds[kind].explained, 0.0, 1.0)))
        else:
            fr.append(0.0)
        wt.append(np.log1p(max(size, 0.0)))
    w = np.asarray(wt)
    return float(np.average(fr, weights=w)) if w.sum() > 0 else float(np.mean(fr))


def explaining(att: Attribution, gap: dict, explained_min: float) -> list[EffectScore]:
    """The candidates that explain the gap ``gap``: strong evidence by ``delta_bic`` where it lies (``< DBIC_STRONG``)
    and at least ``explained_min`` of its excess removed (:func:`explained_fraction`)."""
    return [s for s in att.scores if s.status == "ok" and np.isfinite(ranking_bic(s, gap)) and ranking_bic(s, gap) < DBIC_STRONG
            and explained_fraction(s, gap) >= explained_min]


def decide(att: Attribution, explained_min: float) -> tuple[str, str | None, dict]:
    """``(verdict, effect, gaps)`` (module docstring)."""
    gap = gaps(att)
    if not gap:
        return "none", None, gap
    ok = explaining(att, gap, explained_min)
    if ok:
        return "effect", min(ok, key=lambda s: (ranking_bic(s, gap), s.delta_bic)).effect, gap
    return "unexplained", None, gap
