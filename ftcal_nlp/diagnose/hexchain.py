"""The hexapod's kind of evidence for the chain of effects (``evidence.py``; issue 23, item 2): after the first effect
is named and refit with the whole calibration (``refit.py``), look again; the free-load counterpart is ``chain.py``.
Thresholds ``z_min``, ``explained_min``, ``min_floor_share``, ``max_effects`` of
:class:`~ftcal_nlp.core.settings.HexapodChain` (``DiagnoseSettings.hexapod``).

The first link is the single-effect diagnosis as it stands (``attribute.decide``, ``joint.joint_refit``): its name,
parameters and held-out RMS are unchanged by what follows unless a swap (below) takes it out. Then, while a gap is
left:

* **a gap remains** (also what decides whether to look again at all, so that a dataset the first effect explains
  costs what it did): after the last joint refit the held-out excess over the floor of the standing poses or the
  hanging legs (``EVIDENCE_KINDS``: the calibration's own recordings), ``mean_c (rms_after_c / floor_c)^2 - 1``,
  exceeds that kind's gap threshold (``attribute.gap_threshold``: standing 0.5 and four of its sampling se
  ``sqrt(2 / P)``, hanging 0.1); or, when the error
  model frees the transducer rotations and no named effect has a design face, the design check of the joint refit's
  rotations finds a common tilt (``delta_bic < -10``: a motion-capture bias that another effect hid from the first
  step's check);
* every candidate not yet named is scored with the named effects in the base model (``attribute.attribute`` with
  ``base_effect``: the standing problem with all the named faces plus the candidate's,
  :class:`~ftcal_nlp.effects.combined.Combined`; the hanging and swing faces stacked and cross-validated on the same
  folds; each candidate's variants as in the first step), against the named effects alone;
* the best candidate by ``delta_bic`` where the gap lies, among those that remove at least ``explained_min`` of the
  excess the named effects leave (``attribute.explained_fraction``) with ``delta_bic < DBIC_STRONG``, is added when
  it passes the stated held-out test (of candidates within ``BIC_TIE`` of the best, the one that adds the fewest
  parameters is taken): on the kind of ``EVIDENCE_KINDS`` where it removes most of the excess, the paired
  comparison of the held-out sums of squares without and with it, block by block (standing: each pose; hanging:
  each fold's time block of each leg), ``d_b = ln(SS0_b / SS1_b)``, has ``mean(d) / se(d) >= z_min``
  (a candidate named for the design gap alone: the design check's ``delta_bic < DBIC_STRONG`` is its test), and its
  saving is material: at least ``min_floor_share`` of the floor's variance on that kind;
* the named effects and the new one are refit with the whole calibration (``joint.joint_refit`` of the combined
  effect; the new effect's joint variant chosen there, the others kept as chosen): the link's parameters with se
  and the held-out RMS after it on the kind the shrinkage is reported on. The link stands when that joint model
  predicts held-out data better than the one before it: on the test's kind the held-out excess falls by
  ``JOINT_MIN`` at least, and no kind's (of ``EVIDENCE_KINDS``) excess rises above ``JOINT_WORSE`` x what it was
  (and its threshold);
  else the chain stops there (a face that helps beside the named ones' attribution faces can spoil the joint fit).
  A link named for the design gap alone is not judged so (free rotations absorb what it explains).
* when the ranking offers no link (no candidate passes, or the joint refit rejects the one that does), the joint
  refit tries up to ``JOINT_TRIES`` candidates by their held-out evidence where the joint refit left its gap
  (:func:`held_out_evidence`: paired block-wise z >= ``z_min`` and a saving of ``min_floor_share`` of the floor's
  variance on such a kind, largest z first), each judged as above. The attribution fits the standing poses with the
  named faces but without the joint hanging fit's offsets and leg weights as a prior, so it can see no gap where the
  joint refit leaves one: there the ranking is silent, the held-out evidence is not.

* when no link is made and a gap is left with two effects or more named, a **swap**: each named effect in turn is
  replaced by each candidate the first attribution scored (none swapped out before), and the others refit jointly with
  it (``joint.joint_refit``). A swap passes when the joint check passes on a kind of the gap (its excess falls by
  ``JOINT_MIN``, no kind's rises: as a link's) and either its paired block-wise z (the joint refits' held-out blocks,
  ``KindRefit.blocks``) is ``z_min`` at least or it spends fewer parameters: a swap to fewer parameters adds nothing a
  test would have to justify, and a held-out residual that falls is what cross-validation prefers. Of those that pass,
  the one with the least held-out excess, and of those it does not beat by ``z_min``, the one with the fewest
  parameters (:func:`choose_swap`). Then the chain looks again (``MAX_SWAPS`` at most); at its end the links are rebuilt
  as nested joint refits of the effects in the order they stand (a swapped-in effect last; ``HexChain.first`` when the
  ranking's first was swapped out). Why: greedy selection names first the candidate that explains the sum of two
  effects best on its own, and a many-parameter face can hold part of another effect (a common gain of every leg's
  force channel along up is a robot mass error in the standing balance; ``docs/diagnosis.md`` has the case).

The walking swing kind counts where the gap lies (ranking, the share explained) but is no evidence of its own: the
joint refit predicts a swing leg's weight by extrapolating the hanging faces (a drift's rate, a crosstalk read as
tilt while hanging) and with the frames the named effects turn, so what it leaves there is no measure of an effect
still missing (a face fitted to that remainder would be a false second). Once an effect with a design
face (a common tilt of the frames: ``mocap_bias``, ``tether_force``) is named, it is left out of the gaps too
(``SKIP_AFTER_DESIGN``).

The chain stops when no gap is left, or when neither a link nor a swap is made (a link: at most ``max_effects``
effects named): the loop of ``evidence.name_effects``, with :class:`HexapodEvidence` the kind.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..effects import Effect, design_check
from ..effects.combined import Combined
from ..core.settings import ChainThresholds
from ..core.solver import SolverError
from .attribute import (
    DBIC_STRONG,
    Attribution,
    attribute,
    explained_fraction,
    explaining,
    gaps,
    kind_threshold,
    ranking_bic,
)
from .evidence import name_effects
from .refit import JointRefit, joint_refit
from .scores import KindScore
from .views import Views

log = logging.getLogger(__name__)

EVIDENCE_KINDS = ("standing", "hanging")   # the calibration's own recordings: where a gap is left and a link's test lies
SKIP_AFTER_DESIGN = ("walking swing",)   # kinds not looked at once a design-face effect is named (below)
BIC_TIE = 2.0            # candidates this close in delta BIC are as good: the one with fewer parameters goes first
JOINT_MIN = 0.25         # the joint refit with the new effect: its kind's held-out excess falls by this share at least
JOINT_WORSE = 1.25       # ... and no kind's rises above this factor (and its threshold)
JOINT_TRIES = 2          # candidates with held-out evidence the joint refit tries when the ranking offers no link
MAX_SWAPS = 2            # the most swaps of a named effect for another (module docstring) a chain makes


@dataclass(frozen=True)
class Link:
    """One named effect: its unit (the variant the joint refit chose), the test's numbers, the joint refit of it with
    the effects before it, its own parameters ``{name: (value, se)}`` and the held-out RMS after it. ``beside``: the
    effects in the model when its test was taken, when they are not those before it now (a swap took one out)."""

    unit: Effect
    kind: str
    z: float
    explained: float
    delta_bic: float
    joint: JointRefit
    parameters: dict
    rms_after: np.ndarray
    via: str = "ranking"   # "ranking" (the stated test), "held-out" (:func:`held_out_evidence`) or "swap" (:func:`try_swaps`)
    beside: tuple = ()

    @property
    def name(self) -> str:
        return self.unit.name


@dataclass
class HexChain:
    """The links after the first, every round's candidates (dicts), the swaps, and why the chain stopped; ``first``
    the first effect's link when a swap took the ranking's first out (its test: the first attribution's)."""

    links: list = field(default_factory=list)
    rounds: list = field(default_factory=list)
    stop: str = ""
    swaps: list = field(default_factory=list)   # per swap: out, in, kind, paired_z, excess before / after, the tries
    first: Link | None = None                   # the first effect's link when a swap took the ranking's first out

    def to_json_dict(self) -> dict:
        return {"rounds": self.rounds, "stop": self.stop, **({"swaps": self.swaps} if self.swaps else {})}


def gap_left(joint: JointRefit) -> dict:
    """The kinds of ``EVIDENCE_KINDS`` whose held-out excess over the floor after the joint refit exceeds their
    threshold -> the excess."""
    out = {}
    for kind, k in joint.kinds.items():
        if kind not in EVIDENCE_KINDS:
            continue
        ex = excess(k)
        if np.isfinite(ex) and ex > kind_threshold(kind, k.n):
            out[kind] = ex
    return out


def excess(k) -> float:
    """A kind's held-out excess over its floor after a joint refit, ``mean_c (rms_after_c / floor_c)^2 - 1``."""
    fl = np.where(k.floor > 0, k.floor, np.nan)
    return float(np.nanmean((k.rms_after / fl) ** 2) - 1.0)


def joint_better(cur: JointRefit, new: JointRefit, kind: str) -> tuple[bool, str]:
    """Whether the joint refit with the new effect predicts held-out data better than the one before (module
    docstring): on the test's kind its excess falls by ``JOINT_MIN`` at least, and no kind's excess rises above
    ``JOINT_WORSE`` x what it was and its threshold."""
    for k, a in new.kinds.items():
        b = cur.kinds.get(k)
        if b is None or k not in EVIDENCE_KINDS:
            continue
        e0, e1 = excess(b), excess(a)
        if k == kind and not e1 <= (1.0 - JOINT_MIN) * e0:
            return False, f"{k} excess over the floor {e0:.3g} -> {e1:.3g}"
        if e1 > max(JOINT_WORSE * e0, kind_threshold(k, a.n)):
            return False, f"{k} excess over the floor rises {e0:.3g} -> {e1:.3g}"
    return True, ""


def design_gap(joint: JointRefit, robot) -> bool:
    """The design check (``effects.design_check``) of the joint refit's transducer rotations: a common tilt with
    ``delta_bic < DBIC_STRONG`` (what a motion-capture bias or a cable leaves once the named effects are fitted)."""
    cal = joint.calibration
    if cal is None:
        return False
    R = np.stack([np.asarray(cal.legs[k].rotation_to_body, float) for k in robot.legs])
    return design_check(R, robot.nominal_rotations())["delta_bic"] < DBIC_STRONG


def paired_z(sc: KindScore) -> float:
    """``mean(d) / se(d)`` of ``d_b = ln(SS0_b / SS1_b)`` over the blocks (module docstring); nan without blocks."""
    return blocks_z(sc.blocks_before, sc.blocks_after)


def blocks_z(before, after) -> float:
    """The paired block-wise z of the held-out sums of squares ``before`` -> ``after`` (same blocks); nan without."""
    if before is None or after is None:
        return float("nan")
    b0, b1 = np.asarray(before, float), np.asarray(after, float)
    if b0.shape != b1.shape:
        return float("nan")
    ok = (b0 > 0) & (b1 > 0)
    if ok.sum() < 3:
        return float("nan")
    d = np.log(b0[ok] / b1[ok])
    se = d.std(ddof=1) / np.sqrt(len(d))
    return float(d.mean() / se) if se > 0 else (float("inf") if d.mean() > 0 else 0.0)


def passes(sc, gap: dict, t: ChainThresholds) -> tuple[bool, str, str, float]:
    """Whether candidate ``sc`` (an ``attribute.EffectScore`` against the named effects) passes the module
    docstring's test where the gap lies (``gap``); returns ``(passes, why not, kind, z)``."""
    kinds = [k for k in gap if k in EVIDENCE_KINDS and k in sc.kinds]
    if not kinds:
        if "design" in gap and sc.design is not None:
            return True, "", "design", float("nan")
        return False, "no face where the gap lies", "", float("nan")
    kind = max(kinds, key=lambda k: sc.kinds[k].explained)
    ks = sc.kinds[kind]
    z = paired_z(ks)
    if "design" in gap and sc.design is not None and not ks.explained >= t.explained_min:
        return True, "", "design", z
    if not (z >= t.z_min):
        return False, f"paired block-wise z {z:.1f} < {t.z_min:g} on the {kind} recordings", kind, z
    saved = (ks.z_before - ks.z_after) / ks.n
    if saved < t.min_floor_share:
        return False, f"saves {100 * saved:.1f} % of the floor's variance on the {kind} recordings (< {100 * t.min_floor_share:g} %)", kind, z
    return True, "", kind, z


def _round(att: Attribution, gap: dict, t: ChainThresholds) -> list[dict]:
    out = []
    for sc in att.scores:
        ok_, why, kind, z = passes(sc, gap, t) if sc.status == "ok" and gap else (False, sc.note or sc.status, "", float("nan"))
        out.append({"effect": sc.effect, "variant": dict(sc.model_effect.variant) if sc.model_effect is not None else {},
                    "delta_bic": None if not np.isfinite(ranking_bic(sc, gap)) else float(ranking_bic(sc, gap)),
                    "explained": float(explained_fraction(sc, gap)) if gap else 0.0, "status": sc.status,
                    "kind": kind or None, "paired_z": float(z) if np.isfinite(z) else None, "passes": bool(ok_),
                    **({"note": why} if why else {})})
    return out


def held_out_evidence(att: Attribution, left: dict, exclude: set, t: ChainThresholds) -> list[tuple]:
    """Candidates the joint refit tries when the ranking offers none that makes a link (module docstring):
    ``(score, kind, z, "held-out")`` of every scored candidate not in ``exclude`` whose paired block-wise z on a kind
    of ``left`` (the joint refit's gaps) is ``>= z_min`` with a saving of ``>= min_floor_share`` of the floor's
    variance there, largest z first."""
    out = []
    for sc in att.scores:
        if sc.status != "ok" or sc.effect in exclude or sc.model_effect is None:
            continue
        best = None
        for kind in left:
            ks = sc.kinds.get(kind)
            if ks is None:
                continue
            z = paired_z(ks)
            if z >= t.z_min and (ks.z_before - ks.z_after) / ks.n >= t.min_floor_share and (best is None or z > best[2]):
                best = (sc, kind, z, "held-out")
        if best is not None:
            out.append(best)
    return sorted(out, key=lambda t: -t[2])


def _mark(round_: list, effect: str, via: str, outcome: str) -> None:
    """Note on the round's row of ``effect`` that the joint refit tried it (``via``) and what it found."""
    for row in round_:
        if row["effect"] == effect:
            row["joint_refit"] = {"via": via, "outcome": outcome}


def rebuild(members: tuple, joint: JointRefit) -> tuple:
    """The members as ``joint`` chose their variants (a :class:`Combined`'s ``variant`` is ``{name: variant}``, one
    effect's its own keywords)."""
    if len(members) == 1 and not joint.members:
        return (type(members[0])(**joint.variant),)
    return tuple(type(m)(**joint.variant.get(m.name, m.variant)) for m in members)


def evidence_excesses(j: JointRefit) -> dict:
    """Per kind of ``EVIDENCE_KINDS`` the held-out excess of ``j`` (None when not finite: what diagnosis.json holds)."""
    return {k: _finite(excess(v)) for k, v in j.kinds.items() if k in EVIDENCE_KINDS}


def removed_share(cur: JointRefit, new: JointRefit, kind: str) -> float:
    """The share of ``kind``'s held-out excess after ``cur`` that ``new`` removes (0 without an excess)."""
    e0, e1 = excess(cur.kinds[kind]), excess(new.kinds[kind])
    return 1.0 - e1 / e0 if e0 > 0 else 0.0


def swap_better(cur: JointRefit, alt: JointRefit, left: dict, t: ChainThresholds) -> tuple[bool, str, float]:
    """Whether ``alt`` (the joint refit with one named effect replaced by another) predicts held-out data better than
    ``cur`` (module docstring, the swap): on a kind of ``left`` the joint check passes (:func:`joint_better`: its excess
    falls by ``JOINT_MIN`` at least and no kind's rises), and either the paired block-wise z (``cur`` -> ``alt``) is
    ``z_min`` at least or ``alt`` spends fewer parameters (nothing is added that a test would have to justify).
    Returns ``(better, kind, z)``: the kind of the largest z among those that pass (else the largest z at all)."""
    if any(k in EVIDENCE_KINDS and k not in alt.kinds for k in cur.kinds):   # a failed part of the refit
        return False, "", float("nan")
    fewer = n_parameters(alt) < n_parameters(cur)
    out = (False, "", float("nan"))
    for kind in left:
        a, b = alt.kinds.get(kind), cur.kinds.get(kind)
        if a is None or b is None:
            continue
        z = blocks_z(b.blocks, a.blocks)
        good = (z >= t.z_min or fewer) and joint_better(cur, alt, kind)[0]
        if (good and not out[0]) or (good == out[0] and np.isfinite(z) and not z <= out[2]):
            out = (bool(good), kind, z)
    return out


def evidence_excess(j: JointRefit) -> float:
    """The held-out excess over the floor summed over the kinds of ``EVIDENCE_KINDS`` (what alternatives are ranked by)."""
    return float(sum(excess(k) for n, k in j.kinds.items() if n in EVIDENCE_KINDS))


def n_parameters(j: JointRefit) -> int:
    """The parameters a joint refit spent on its effects and the data determine (finite, non-zero se: a standing-face
    parameter held at its hanging estimate has none, an undetermined one an infinite se)."""
    return int(sum(1 for _, se in j.parameters.values() if np.isfinite(se) and se > 0))


def choose_swap(passing: list, th: ChainThresholds):
    """Of the swaps that pass (``(i, unit, joint, kind, z)``), the best by the summed excess (:func:`evidence_excess`);
    of those it does not beat on held-out data (paired block-wise z < ``z_min`` on the best's kind), the one that spends
    the fewest parameters (as the ranking's ``BIC_TIE``: a robot mass and a cable both take up a mass error)."""
    if not passing:
        return None
    best = min(passing, key=lambda t: evidence_excess(t[2]))
    kind = best[3]
    ref = best[2].kinds[kind].blocks
    tied = [t for t in passing if t is best or (kind in t[2].kinds and not blocks_z(t[2].kinds[kind].blocks, ref) >= th.z_min)]
    return min(tied, key=lambda t: (n_parameters(t[2]), evidence_excess(t[2])))


def try_swaps(views: Views, named: tuple, cur: JointRefit, left: dict, units: dict, exclude: set, model: Any, prior,
              calibration, robot, balance: str, t: ChainThresholds, *, folds: int, seed: int, x_start) -> tuple[Any, list]:
    """Every named effect replaced in turn by every candidate of ``units`` (name -> the unit the first attribution
    scored; none of ``exclude`` or ``named``), refit jointly with the others (``joint.joint_refit``) and judged by
    :func:`swap_better`; returns the chosen swap ``(i, unit, joint, kind, z)`` (:func:`choose_swap`) or None, and a row
    per try."""
    rows, passing = [], []
    have = {m.name for m in named}
    for i, m in enumerate(named):
        if m.design_face:   # named for a common tilt of the frames, which the kinds of the gap do not see
            continue
        rest = named[:i] + named[i + 1 :]
        for name, c in units.items():
            if name in have or name in exclude:
                continue
            try:
                j = joint_refit(views, Combined(rest + (c,)), model, prior, calibration, robot, balance, folds=folds, seed=seed,
                                x_start=x_start)
            except (SolverError, np.linalg.LinAlgError) as exc:
                rows.append({"out": m.name, "in": name, "outcome": f"failed: {exc}"})
                continue
            good, kind, z = swap_better(cur, j, left, t)
            rows.append({"out": m.name, "in": name, "kind": kind or None, "paired_z": _finite(z),
                         "excess": evidence_excesses(j),
                         "outcome": "better" if good else "not better"})
            if good:
                passing.append((i, c, j, kind, z))
    return choose_swap(passing, t), rows


class HexapodEvidence:
    """The hexapod's recordings (standing poses, hanging legs, walking swing) as a kind of evidence for
    :func:`evidence.name_effects` (module docstring): the named effects (``named``, the first included), the last
    joint refit (``cur``), each named effect's test (``tests``), the joint refits made (``refits``), the effects swapped
    out, and ``chain`` (the links after the first, every round, the swaps)."""

    def __init__(self, views: Views, att: Attribution, first: Effect, joint: JointRefit, effects: list[Effect], model: Any,
                 prior, calibration, robot, balance: str, primary: str | None, t: ChainThresholds, **kw) -> None:
        self.views, self.att, self.effects, self.model, self.prior = views, att, effects, model, prior
        self.calibration, self.robot, self.balance, self.primary, self.t, self.kw = calibration, robot, balance, primary, t, kw
        self.chain = HexChain()
        self.named = rebuild((first,), joint)
        # name -> (kind, z, explained, delta_bic, via, the names in the model when tested) of every effect named after the first
        self.tests: dict = {}
        self.refits = {(self.named[0].name,): joint}   # the joint refits made, by the names fitted (what a rebuild reuses)
        self.swapped_out: set = set()
        self.units = {sc.effect: sc.model_effect for sc in att.scores if sc.status == "ok" and sc.model_effect is not None}
        self.cur = joint
        self.left: dict = {}
        self.skip: tuple = ()

    def no_gap(self) -> str | None:
        named = self.named
        # the swing legs' weights are predicted with the transducer frames, which a named design-face effect (a common
        # tilt) turns: after one, the swing kind says nothing about what is left (SKIP_AFTER_DESIGN)
        self.skip = SKIP_AFTER_DESIGN if any(m.design_face for m in named) else ()
        self.left = left = gap_left(self.cur)
        design_open = self.att.design is not None and not any(m.design_face for m in named) and design_gap(self.cur, self.robot)
        log.debug("diagnosis: chain after %s: gap left %s, design %s", [m.name for m in named], left, design_open)
        if not left and not design_open:
            return "no gap above the floor is left after the joint refit"
        return None

    def n_named(self) -> int:
        return len(self.named)

    def next_link(self, why_not: list[str]) -> bool:
        link = _next_link(self.views, self.att, self.named, self.cur, self.left, self.skip, self.effects, self.swapped_out,
                          self.model, self.prior, self.calibration, self.robot, self.balance, self.chain, why_not, self.t,
                          **self.kw)
        if link is None:
            return False
        best, kind, z, both, j2, via, explained, dbic = link
        before = _names(self.named)
        self.named = named = rebuild(both.members, j2)
        self.tests[named[-1].name] = (kind, z, explained, dbic, via, before)
        self.refits[_names(named)] = j2
        self.chain.links.append(_link(named, j2, self.primary, self.tests))
        log.info("diagnosis: chain adds %s (%s: z %.1f on %s, explains %.0f %%)", best.effect, via, z, kind, 100 * explained)
        self.cur = j2
        return True

    def replace(self, why_not: list[str]) -> bool:
        """Would one named effect replaced by another predict held-out data better (module docstring)?"""
        named, cur, left, ch = self.named, self.cur, self.left, self.chain
        if not (len(named) >= 2 and len(ch.swaps) < MAX_SWAPS and left):
            return False
        sw, rows = try_swaps(self.views, named, cur, left, self.units, self.swapped_out, self.model, self.prior,
                             self.calibration, self.robot, self.balance, self.t, **self.kw)
        if sw is None:
            why_not.append(f"no named effect replaced by another candidate predicts held-out data better ({len(rows)} tried)")
            return False
        i, unit, j2, kind, z = sw
        out = named[i]
        ch.swaps.append({"out": out.name, "in": unit.name, "kind": kind, "paired_z": _finite(z),
                         "excess_before": evidence_excesses(cur), "excess_after": evidence_excesses(j2),
                         "named_before": list(_names(named)), "tried": rows})
        self.swapped_out.add(out.name)
        self.tests.pop(out.name, None)
        rest = named[:i] + named[i + 1 :]
        self.tests[unit.name] = (kind, z, removed_share(cur, j2, kind), float("nan"), "swap", _names(rest))
        self.named = rebuild(rest + (unit,), j2)
        self.refits[_names(self.named)] = j2
        log.info("diagnosis: chain swaps %s for %s (z %.1f on %s)", out.name, unit.name, z, kind)
        self.cur = j2
        return True


def run_chain(views: Views, att: Attribution, first: Effect, joint: JointRefit, effects: list[Effect], model: Any, prior,
              calibration, robot, balance: str, primary: str | None, t: ChainThresholds, *, folds: int, seed: int,
              x_start: np.ndarray | None = None) -> HexChain:
    """The chain after the first link (module docstring). ``first``: the named effect's unit (the variant the
    attribution scored); ``joint``: its joint refit; ``att``: the first attribution (its design check, the units a swap
    tries); ``primary``: the kind the shrinkage is reported on."""
    kw = dict(folds=folds, seed=seed, x_start=x_start)
    ev = HexapodEvidence(views, att, first, joint, effects, model, prior, calibration, robot, balance, primary, t, **kw)
    ch = ev.chain
    ch.stop = name_effects(ev, t)
    if ch.swaps:
        named, tests = ev.named, ev.tests
        if named[0].name != joint.effect:   # the ranking's first swapped out: the new first's test is the first attribution's
            tests[named[0].name] = first_test(att, named[0].name)
        _rebuild_links(ch, views, named, joint.effect, ev.refits, tests, primary, model, prior, calibration, robot, balance, **kw)
    return ch


def _finite(v: float) -> float | None:
    """``v`` for diagnosis.json: None when not finite (strict JSON has no NaN)."""
    return float(v) if np.isfinite(v) else None


def _names(named: tuple) -> tuple:
    return tuple(m.name for m in named)


def first_test(att: Attribution, name: str) -> tuple:
    """The first attribution's numbers for ``name`` as a test tuple (kind, z, explained, delta_bic, "ranking", ()):
    where the first gap lies, the kind it explains most of."""
    gap = gaps(att)
    sc = next((s for s in att.scores if s.effect == name), None)
    kinds = [k for k in gap if sc is not None and k in sc.kinds]
    if sc is None or not kinds:
        return ("", float("nan"), 0.0, float("nan"), "ranking", ())
    kind = max(kinds, key=lambda k: sc.kinds[k].explained)
    return (kind, paired_z(sc.kinds[kind]), float(explained_fraction(sc, gap)), float(ranking_bic(sc, gap)), "ranking", ())


def _link(named: tuple, j: JointRefit, primary: str | None, tests: dict, mine: dict | None = None) -> Link:
    """The link of ``named[-1]``: ``j`` is the joint refit of all of ``named`` (``mine``: its parameters, when ``j`` is
    a larger refit's)."""
    kind, z, explained, dbic, via, before = tests[named[-1].name]
    if mine is None:
        mine = Combined(named).member_parameters(j.parameters)[-1] if len(named) > 1 else dict(j.parameters)
    pk = primary if primary in j.kinds else next(iter(j.kinds), None)
    after = j.kinds[pk].rms_after if pk is not None else np.full(6, np.nan)
    beside = tuple(before) if tuple(before) != _names(named[:-1]) else ()
    return Link(named[-1], kind, z, explained, dbic, j, mine, after, via, beside)


def _rebuild_links(ch: HexChain, views: Views, named: tuple, first_name: str, refits: dict, tests: dict,
                   primary: str | None, model: Any, prior, calibration, robot, balance: str, **kw) -> None:
    """After a swap, the links again as nested joint refits of the effects in the order they stand (each refit with
    those before it; a refit already made is reused); ``ch.first`` when the swap took the ranking's first
    (``first_name``) out. A refit that fails leaves that link with the whole chain's joint refit, and says so in
    ``ch.stop``."""
    links = []
    whole = refits[_names(named)]
    for k in range(1, len(named) + 1):
        sub = named[:k]
        j, mine = refits.get(_names(sub)), None
        if j is None:
            try:
                j = joint_refit(views, sub[0] if k == 1 else Combined(sub), model, prior, calibration, robot, balance, **kw)
            except (SolverError, np.linalg.LinAlgError) as exc:
                ch.stop += f"; the joint refit of {'+'.join(_names(sub))} failed ({exc}): its link shows the whole chain's"
                j, mine = whole, Combined(named).member_parameters(whole.parameters)[k - 1]
            else:
                sub = rebuild(sub, j)
        if k == 1:
            if named[0].name != first_name:
                ch.first = _link(sub, j, primary, tests, mine)
            continue
        links.append(_link(sub, j, primary, tests, mine))
    ch.links = links


def _next_link(views: Views, att: Attribution, named: tuple, cur: JointRefit, left: dict, skip: tuple, effects: list,
               swapped_out: set, model: Any, prior, calibration, robot, balance: str, ch: HexChain, why_not: list,
               t: ChainThresholds, *, folds: int, seed: int, x_start) -> tuple | None:
    """One round of the chain (module docstring): score the candidates beside the named effects, try the ranking's
    best and those with held-out evidence in the joint refit; the link ``(score, kind, z, Combined, joint, via,
    explained, delta_bic)`` or None (the reasons appended to ``why_not``)."""
    base = Combined(named)
    cands = [e for e in effects if e.name not in {m.name for m in named} and e.name not in swapped_out]
    try:
        att2 = attribute(views, cands, model, prior, robot, balance, folds=folds, seed=seed, x_start=x_start, base_effect=base)
    except (SolverError, np.linalg.LinAlgError) as exc:
        why_not.append(f"scoring the candidates beside {base.name} failed: {exc}")
        return None
    gap = {k: v for k, v in gaps(att2).items() if k not in skip}
    ch.rounds.append(_round(att2, gap, t))
    tries = []
    ok = explaining(att2, gap, t.explained_min) if gap else []
    if not gap:
        why_not.append("with the named effects in the model no gap above the floor is left")
    elif not ok:
        why_not.append(f"no candidate removes {100 * t.explained_min:g} % of the excess the named effects leave with "
                       f"delta BIC < {DBIC_STRONG:g}")
    else:
        best = min(ok, key=lambda s: (ranking_bic(s, gap), s.delta_bic))
        # parsimony: as good by BIC (within BIC_TIE) with fewer parameters goes first (a mocap bias and a cable both
        # explain a common tilt of the frames; the cable spends parameters on every face)
        best = min((s for s in ok if ranking_bic(s, gap) <= ranking_bic(best, gap) + BIC_TIE),
                   key=lambda s: (sum(k.dof for k in s.kinds.values()), ranking_bic(s, gap), s.delta_bic))
        passes_, why, kind, z = passes(best, gap, t)
        if passes_:
            tries.append((best, kind, z, "ranking"))
        else:
            why_not.append(f"the next candidate, {best.effect}, adds nothing significant on held-out data ({why})")
    tries += held_out_evidence(att2, left, {c[0].effect for c in tries}, t)[:JOINT_TRIES]
    for sc, kind, z, via in tries:
        both = Combined(named + (sc.model_effect,))
        try:
            j2 = joint_refit(views, both, model, prior, calibration, robot, balance, folds=folds, seed=seed, x_start=x_start)
        except (SolverError, np.linalg.LinAlgError) as exc:
            why_not.append(f"the joint refit with {both.name} failed: {exc}")
            _mark(ch.rounds[-1], sc.effect, via, f"failed: {exc}")
            continue
        # a link named for the design gap alone is not judged by the joint refit: free rotations absorb what it
        # explains, and the swing legs' weights, predicted with the tilted frames, say nothing about it
        good, why = joint_better(cur, j2, kind) if kind != "design" else (True, "")
        _mark(ch.rounds[-1], sc.effect, via, "better" if good else why)
        if not good:
            why_not.append(f"the joint refit with {sc.effect} does not predict held-out data better ({why})")
            continue
        if via == "ranking":
            explained, dbic = float(explained_fraction(sc, gap)), float(ranking_bic(sc, gap))
        else:   # the attribution saw no gap there: the share is what the joint refit removed of the kind's excess
            explained, dbic = removed_share(cur, j2, kind), float(ranking_bic(sc, {kind: left[kind]}))
        return sc, kind, z, both, j2, via, explained, dbic
    return None
