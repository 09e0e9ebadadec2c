"""The free loads' kind of evidence for the chain of effects (``evidence.py``; issue 23, item 2): name the strongest
by held-out evidence, refit jointly with it, look again, stop when the next adds nothing significant on held-out data.
Free loads (``free.py``); thresholds ``z_min``, ``min_floor_share``, ``max_effects`` of
:class:`~ftcal_nlp.core.settings.FreeLoadChain` (``DiagnoseSettings.free_loads``).

A step scores every candidate effect not yet named: each shape of its free face (``free_shapes``) is added to
the design ``[J, X_1 .. X_m]`` of the free-load Jacobian and the faces named so far, and cross-validated
(``free_cv.py``: the same blocks and folds for every design); an effect's score is its best shape's. The best
candidate is added when all of these hold (the stated test):

* a gap remains: some channel's held-out RMS exceeds the noise floor by more than ``GAP_REL`` (relative);
* the paired block-wise comparison favours it: the log ratio of the held-out sums of squares without and with
  it, block by block (``d_b``), has ``mean(d) / se(d) >= z_min`` over the blocks;
* the saving is material against the floor: at least ``min_floor_share`` of the floor's sum of squares
  (``6 N`` in units of the noise variance: a saving smaller than that share of the noise is not an effect worth
  naming however significant), and at least ``MIN_EXCESS_SHARE`` of the held-out excess still over the floor
  or ``MIN_CHANNEL_SHARE`` of one component's (an effect confined to the forces, beside a remainder in the
  torques that no candidate explains).

Without a floor (the data hold no still stretch, e.g. a list of single-row poses: ``floor_known`` false) the
weights are the free-load fit's residual sd, there is no gap to test and no excess: a candidate is added when
its paired z passes and it saves at least ``MIN_GAIN_NO_FLOOR`` of the current held-out sum of squares.

An effect's shapes compete by held-out sum of squares, except a unit's nested shapes (``free_nested``: each holds the
one before): a larger one is kept only when its paired block-wise z against the one kept reaches ``NESTED_Z``.

A unit may refine its grid's best shape (``free_refine``: tuned on every sample). Its held-out score is then not
that of the shape tuned on every sample (optimistic) but per fold (``REFINE_PER_FOLD``): each fold's shape is the
best of the unit's ``free_refine_near`` shapes by the training blocks' residual sum of squares of the current design
with its face (``Design.train_sse``), and that fold is predicted with it (``Design.fit_per_fold``); the refined shape
is kept when this beats the grid's held-out score, and the shape tuned on every sample is the face later designs and
the joint refit use (later candidates are compared with that design, ``Chain.current_design``).

Among the candidates that pass, the best by held-out sum of squares is added, unless one with fewer parameters
explains at least ``PARSIMONY`` of what the best does: that one goes first (a flexible face can mimic a simpler
effect, e.g. a creep with a sub-second time constant a clock offset; the flexible one is scored again next
round). The chain ends after ``max_effects`` effects. :func:`joint_fit` refits the named effects together on every
sample (linearised around the free-load fit) and gives their parameters with se: ``cov = s^2 (A^T A)^+``,
``s^2`` the weighted residual variance times the AR(1) inflation of serially correlated residuals
(``freeload.problem.serial_inflation``: what a model error that stays through a hold does to the se).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from ..effects import Effect
from ..effects.free_faces import FreeFace, FreeLoadContext
from ..estimate.freeload.problem import serial_inflation
from ..core.settings import ChainThresholds
from .evidence import name_effects
from .free_cv import CVFit, Design, paired_gain, pinv

_T = TypeVar("_T")

GAP_REL = 0.15
MIN_EXCESS_SHARE = 0.25
MIN_CHANNEL_SHARE = 0.6
PARSIMONY = 0.85
MIN_GAIN_NO_FLOOR = 0.05
#: a unit whose shapes are nested (``free_nested``: each holds the one before, e.g. a sensor matrix's force block, then
#: all of it) keeps a larger shape only when it beats the one kept by this paired block-wise z (more columns always
#: fit the held-out blocks a little better by chance; the chain's own ``z_min`` for an effect)
NESTED_Z = 3.0
#: a face's refined shape (``free_refine``) is scored with each fold's shape tuned on the other folds' blocks alone
REFINE_PER_FOLD = True


@dataclass(frozen=True)
class Candidate:
    """One effect's best shape at one step: its face, the cross-validated fit with it, the saving and its z."""

    effect: Effect
    shape: dict
    face: FreeFace | None
    cv: CVFit | None
    gain: float = 0.0          # held-out SSE saved, share of the current one
    z: float = 0.0             # paired block-wise z of the saving
    excess_share: float = 0.0  # share of the current held-out excess over the floor it removes
    delta_bic: float = float("nan")
    status: str = "ok"
    note: str = ""
    shapes_tried: int = 0
    base: CVFit | None = None  # the design with ``face`` (tuned on every sample) when ``cv`` tuned it per fold

    def _scored(self, what: str, value: _T | None) -> _T:
        if value is None:
            raise ValueError(f"{self.effect.name}: not scored ({self.status}: {self.note}), no {what}")
        return value

    @property
    def fit(self) -> CVFit:
        """The cross-validated fit of a scored candidate (every named one is): ``cv`` where it is not None."""
        return self._scored("fit", self.cv)

    @property
    def shaped_face(self) -> FreeFace:
        """The face of a scored candidate (``face``, set with ``cv``)."""
        return self._scored("face", self.face)

    @property
    def design_cv(self) -> CVFit:
        """The cross-validation of the design with this candidate's ``face`` itself: what later designs build on."""
        return self.fit if self.base is None else self.base


@dataclass
class Chain:
    """The base fit, the named effects in order (``steps``), every step's candidates, the stop reason."""

    base: CVFit | None           # None: not diagnosed (too few samples), no fit at all
    steps: list[Candidate] = field(default_factory=list)
    rounds: list[list[Candidate]] = field(default_factory=list)
    stop: str = ""

    @property
    def base_fit(self) -> CVFit:
        """``base`` of a diagnosed chain."""
        if self.base is None:
            raise ValueError(f"the chain has no base fit ({self.stop})")
        return self.base

    @property
    def current(self) -> CVFit:
        return self.steps[-1].fit if self.steps else self.base_fit

    @property
    def current_design(self) -> CVFit:
        """The design of the named effects' faces as they join later designs (:attr:`Candidate.design_cv`): what the
        next candidates are compared with (the same faces in both)."""
        return self.steps[-1].design_cv if self.steps else self.base_fit


def excess_ratio(cv: CVFit, floor: np.ndarray) -> np.ndarray:
    """Held-out RMS over the floor per channel (6,)."""
    return cv.rms() / floor


def _bic(design: Design, cv: CVFit, ref: CVFit) -> float:
    """BIC of ``cv``'s full-sample fit relative to ``ref``'s (weighted Gaussian)."""
    m = design.n * 6
    rss, rss0 = cv.rss, ref.rss
    return m * np.log(max(rss, 1e-300) / max(rss0, 1e-300)) + (cv.k - ref.k) * np.log(m)


def score(design: Design, X0: list, cur: CVFit, ctx: FreeLoadContext, effect: Effect, memo: dict | None = None,
          floor_known: bool = True) -> Candidate:
    """``effect``'s best shape added to the parts ``X0`` (module docstring), against the current fit ``cur``; ``memo``
    keeps each (effect, shape)'s face across rounds (its cached blocks stay valid)."""
    memo = {} if memo is None else memo
    shapes = tuple(effect.free_shapes(ctx))
    if not shapes:
        return Candidate(effect, {}, None, None, status="not applicable", note="no free-load face")
    best = None
    tried = 0
    nested = bool(getattr(effect, "free_nested", False))
    for shape in shapes:
        key = (effect.name, repr(sorted(shape.items())))
        if key not in memo:
            memo[key] = effect.free_face(ctx, shape)
        face = memo[key]
        if face is None or not face.any():
            continue
        tried += 1
        cv = design.fit(X0 + [face])
        if best is None or (cv.sse < best[2].sse and (not nested or paired_gain(best[2], cv)[1] >= NESTED_Z)):
            best = (shape, face, cv)
    if best is None:
        return Candidate(effect, {}, None, None, status="not applicable", note="its face does not apply to these data")
    refine = getattr(effect, "free_refine", None)
    base_cv = None
    if refine is not None:   # the unit may refine its grid's best shape on the current residual (free_faces.py)
        def face_of(sh):
            key = (effect.name, repr(sorted(sh.items())))
            if key not in memo:
                memo[key] = effect.free_face(ctx, sh)
            return memo[key]

        shape2 = refine(ctx, dict(best[0]), cur.resid)
        face2 = face_of(shape2) if shape2 is not None and shape2 != best[0] else None
        near = [f for f in (face_of(sh) for sh in effect.free_refine_near(ctx, dict(best[0])))
                if f is not None and f.k == best[1].k] if REFINE_PER_FOLD else []
        if near:
            # held-out evidence of the refined shape: each fold's shape tuned on the other folds' blocks alone (among
            # the unit's shapes near the grid's best, ``free_refine_near``, by the training blocks' residual sum of
            # squares of the current design with that shape's face), and that fold predicted with it; the shape tuned
            # on every sample is what the chain keeps (its face joins later designs and the joint refit)
            whole = design.fit(X0 + [face2]) if face2 is not None else best[2]
            tsse = np.asarray([design.train_sse(X0 + [f]) for f in near])    # (shapes, folds)
            pick = np.argmin(tsse, axis=0)                                 # each fold's shape
            cv2 = design.fit_per_fold(X0, [near[int(i)] for i in pick], whole)
            tried += 1
            if cv2.sse < best[2].sse and _fits_as_well(whole, best[2]):
                best = (shape2 if face2 is not None else best[0], face2 if face2 is not None else best[1], cv2)
                base_cv = whole
        elif face2 is not None:
            cv2 = design.fit(X0 + [face2])
            tried += 1
            if cv2.sse < best[2].sse and _fits_as_well(cv2, best[2]):
                best = (shape2, face2, cv2)
    shape, face, cv = best
    gain, z = paired_gain(cur, cv)
    floor_sse = 6.0 * design.n
    share = (cur.sse - cv.sse) / max(cur.sse - floor_sse, 1e-300) if floor_known else gain
    return Candidate(effect, dict(shape), face, cv, gain, z, float(share), _bic(design, cv, cur), shapes_tried=tried,
                     base=base_cv)


def _fits_as_well(refined: CVFit, grid: CVFit) -> bool:
    """Whether a refined shape's fit on every sample is at least as good as the grid's best (what the refinement
    minimises; rounding aside): else the search failed and its per-fold score is not of the shape the chain keeps."""
    return refined.rss <= grid.rss * (1.0 + 1e-9)


def accepted(c: Candidate, cur: CVFit, design: Design, t: ChainThresholds, floor_known: bool = True,
             floor: np.ndarray | None = None) -> tuple[bool, str]:
    """Whether candidate ``c`` passes the stated test (module docstring) and why not."""
    if c.cv is None:
        return False, c.note
    saved = cur.sse - c.cv.sse
    if c.z < t.z_min:
        return False, f"paired block-wise z {c.z:.1f} < {t.z_min:g}"
    if not floor_known:
        if c.gain < MIN_GAIN_NO_FLOOR:
            return False, f"saves {100 * c.gain:.1f} % of the held-out sum of squares (< {100 * MIN_GAIN_NO_FLOOR:g} %; no floor known)"
        return True, ""
    if saved < t.min_floor_share * 6.0 * design.n:
        return False, f"saves {100 * saved / (6.0 * design.n):.2f} % of the floor's variance (< {100 * t.min_floor_share:g} %)"
    if floor is None:
        raise ValueError("accepted: the floor is needed when it is known (floor_known)")
    ch = channel_share(cur, c.cv, floor)
    if c.excess_share < MIN_EXCESS_SHARE and ch < MIN_CHANNEL_SHARE:
        return False, (f"removes {100 * c.excess_share:.0f} % of the remaining excess (< {100 * MIN_EXCESS_SHARE:g} %) and at most "
                       f"{100 * ch:.0f} % of one component's (< {100 * MIN_CHANNEL_SHARE:g} %)")
    return True, ""


def channel_share(cur: CVFit, new: CVFit, floor: np.ndarray) -> float:
    """The largest share of one component's held-out excess over the floor that ``new`` removes, over the components
    whose held-out RMS is above the floor by more than ``GAP_REL``."""
    e0 = cur.rms() ** 2 - floor**2
    e1 = new.rms() ** 2 - floor**2
    gap = cur.rms() / floor > 1.0 + GAP_REL
    if not gap.any():
        return 0.0
    return float(np.max(((e0 - np.maximum(e1, 0.0)) / e0)[gap]))


class FreeLoadEvidence:
    """The free loads' samples as a kind of evidence for :func:`evidence.name_effects` (module docstring): the design,
    the free-load model's Jacobian ``J`` as a face, the candidates and the floor; ``chain`` the named effects and
    every round."""

    def __init__(self, design: Design, J: FreeFace, ctx: FreeLoadContext, effects: list[Effect], floor: np.ndarray,
                 floor_known: bool, t: ChainThresholds) -> None:
        self.design, self.J, self.ctx, self.effects, self.floor, self.floor_known, self.t = (
            design, J, ctx, effects, floor, floor_known, t)
        self.chain = Chain(design.fit([J]))
        self.memo: dict = {}   # each (effect, shape)'s face across rounds (its cached blocks stay valid)

    def no_gap(self) -> str | None:
        ch = self.chain
        if self.floor_known and np.max(excess_ratio(ch.current_design, self.floor)) <= 1.0 + GAP_REL:
            return "no gap above the floor remains" if ch.steps else "no gap above the floor"
        return None

    def n_named(self) -> int:
        return len(self.chain.steps)

    def next_link(self, why_not: list[str]) -> bool:
        ch, design, floor_known, floor, t = self.chain, self.design, self.floor_known, self.floor, self.t
        cur = ch.current_design
        X0 = [self.J] + [s.shaped_face for s in ch.steps]
        named = {s.effect.name for s in ch.steps}
        cands = [score(design, X0, cur, self.ctx, e, self.memo, floor_known) for e in self.effects if e.name not in named]
        self.ctx.forget_relaxations()   # the faces keep their columns; the next round's trials are new time constants
        cands.sort(key=lambda c: (c.cv is None, c.cv.sse if c.cv is not None else 0.0))
        ch.rounds.append(cands)
        ok = [c for c in cands if c.cv is not None]
        if not ok:
            why_not.append("no candidate effect has a face for these data")
            return False
        best = ok[0]
        good, why = accepted(best, cur, design, t, floor_known, floor)
        if not good:
            why_not.append(f"the next candidate, {best.effect.name}, adds nothing significant on held-out data ({why})")
            return False
        # parsimony: a candidate with fewer parameters that explains nearly as much goes first (a flexible face can
        # mimic a simpler effect; the flexible one is looked at again in the next round)
        for c in ok[1:]:
            if (c.shaped_face.k < best.shaped_face.k and c.excess_share >= PARSIMONY * ok[0].excess_share
                    and accepted(c, cur, design, t, floor_known, floor)[0]):
                best = c
        ch.steps.append(best)
        return True

    def replace(self, why_not: list[str]) -> bool:
        return False   # no swap on free loads: every candidate is scored beside the named faces each round


def run_chain(design: Design, J: FreeFace, ctx: FreeLoadContext, effects: list[Effect], floor: np.ndarray,
              t: ChainThresholds, floor_known: bool = True) -> Chain:
    """The chain of the module docstring (``J`` the free-load model's Jacobian as a face)."""
    ev = FreeLoadEvidence(design, J, ctx, effects, floor, floor_known, t)
    ev.chain.stop = name_effects(ev, t)
    return ev.chain


@dataclass(frozen=True)
class JointFit:
    """The named effects refit together with the free-load model (linearised) on every sample: per effect its
    parameters ``{name: (value, se)}``; ``dx`` the change of the free-load parameters; ``s2`` the variance factor."""

    params: list[dict]
    dx: np.ndarray
    dx_se: np.ndarray
    s2: float
    resid: np.ndarray
    betas: tuple = ()          # per effect its parameter vector (face column order)
    G: np.ndarray | None = None  # the weighted normal matrix over [dx, betas] (cov = s2 G^+: the file `correct` reads)

    def wrench(self, steps: list[Candidate], i: int = 0) -> np.ndarray:
        """The fitted wrench (N, 6) of the ``i``-th named effect (a face's fixed offset included)."""
        face = steps[i].shaped_face
        return face.wrench(self.betas[i]) + (0.0 if face.offset is None else face.offset)


def joint_fit(design: Design, J: FreeFace, steps: list[Candidate], ctx: FreeLoadContext) -> JointFit:
    """The joint refit (module docstring)."""
    parts = [J] + [s.shaped_face for s in steps]
    cv = steps[-1].design_cv if steps else None
    if cv is None or cv._parts is None or len(cv._parts) != len(parts) or any(a is not b for a, b in zip(cv._parts, parts)):
        cv = design.fit(parts)    # else the chain's own fit of these parts (the same sums: the same numbers)
    G, beta = cv.G, cv.beta
    rw = cv.resid * design.w
    m, k = rw.size, cv.k
    s2 = float((rw**2).sum() / max(m - k, 1))
    _, infl = serial_inflation(rw, ctx.rec, ctx.index)
    s2 *= float(np.mean(infl))
    Gi, undetermined = pinv(G)
    se = np.sqrt(np.clip(np.diag(Gi * s2), 0.0, None))
    # a parameter along a direction the data leave undetermined has no se (pinv left it at zero)
    se = np.where(undetermined, np.inf, se)
    out, betas, c0 = [], [], J.k
    for s in steps:
        face = s.shaped_face
        sl = slice(c0, c0 + face.k)
        out.append({n: (float(v), float(e)) for n, v, e in zip(face.names, beta[sl], se[sl])})
        betas.append(beta[sl])
        c0 += face.k
    return JointFit(out, beta[:J.k], se[:J.k], s2, cv.resid, tuple(betas), G)
