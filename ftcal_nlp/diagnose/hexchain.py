"""Several effects on hexapod datasets (issue 23, item 2): after the first effect is named and refit with the whole
calibration (``joint.py``), look again; the free-load counterpart is ``chain.py``.

The first link is the single-effect diagnosis as it stands (``attribute.decide``, ``joint.joint_refit``): its name,
parameters and held-out RMS are unchanged by what follows. Then, while a gap is left:

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
* the best candidate by ``delta_bic`` where the gap lies, among those that remove at least ``EXPLAINED_MIN`` of the
  excess the named effects leave (``attribute.explained_fraction``) with ``delta_bic < DBIC_STRONG``, is added when
  it passes the stated held-out test (of candidates within ``BIC_TIE`` of the best, the one that adds the fewest
  parameters is taken): on the kind of ``EVIDENCE_KINDS`` where it removes most of the excess, the paired
  comparison of the held-out sums of squares without and with it, block by block (standing: each pose; hanging:
  each fold's time block of each leg), ``d_b = ln(SS0_b / SS1_b)``, has ``mean(d) / se(d) >= Z_MIN``
  (a candidate named for the design gap alone: the design check's ``delta_bic < DBIC_STRONG`` is its test), and its
  saving is material: at least ``MIN_FLOOR_SHARE`` of the floor's variance on that kind;
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
  (:func:`held_out_evidence`: paired block-wise z >= ``Z_MIN`` and a saving of ``MIN_FLOOR_SHARE`` of the floor's
  variance on such a kind, largest z first), each judged as above. The attribution fits the standing poses with the
  named faces but without the joint hanging fit's offsets and leg weights as a prior, so it can see no gap where the
  joint refit leaves one (a chassis flex beside a casing load: standing excess -0.92 in the attribution, 7.7 after
  the joint refit, the flex's paired z 15): there the ranking is silent, the held-out evidence is not.

The walking swing kind counts where the gap lies (ranking, the share explained) but is no evidence of its own: the
joint refit predicts a swing leg's weight by extrapolating the hanging faces (a drift's rate, a crosstalk read as
tilt while hanging) and with the frames the named effects turn, so what it leaves there is no measure of an effect
still missing (in the sweep a cable's face took up that remainder as a false second). Once an effect with a design
face (a common tilt of the frames: ``mocap_bias``, ``tether_force``) is named, it is left out of the gaps too
(``SKIP_AFTER_DESIGN``).

The chain stops when no gap is left, when no candidate makes a link, or after ``MAX_EFFECTS`` effects.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..effects import Effect, design_check
from ..effects.combined import Combined
from ..solver import SolverError
from .attribute import (
    DBIC_STRONG,
    Attribution,
    attribute,
    explained_fraction,
    gaps,
    kind_threshold,
    ranking_bic,
)
from .joint import JointRefit, joint_refit
from .scores import KindScore
from .views import Views

log = logging.getLogger(__name__)

Z_MIN = 3.0              # paired block-wise z of the held-out saving
EXPLAINED_MIN = 0.5      # share of the excess the named effects leave that the next must remove
MIN_FLOOR_SHARE = 0.05   # ... and at least this share of the floor's variance on its kind
MAX_EFFECTS = 3          # the most effects the chain names
EVIDENCE_KINDS = ("standing", "hanging")   # the calibration's own recordings: where a gap is left and a link's test lies
SKIP_AFTER_DESIGN = ("walking swing",)   # kinds not looked at once a design-face effect is named (below)
BIC_TIE = 2.0            # candidates this close in delta BIC are as good: the one with fewer parameters goes first
JOINT_MIN = 0.25         # the joint refit with the new effect: its kind's held-out excess falls by this share at least
JOINT_WORSE = 1.25       # ... and no kind's rises above this factor (and its threshold)
JOINT_TRIES = 2          # candidates with held-out evidence the joint refit tries when the ranking offers no link


@dataclass(frozen=True)
class Link:
    """One effect after the first: its unit (the variant the joint refit chose), the test's numbers, the joint refit
    of every named effect together, its own parameters ``{name: (value, se)}`` and the held-out RMS after it."""

    unit: Effect
    kind: str
    z: float
    explained: float
    delta_bic: float
    joint: JointRefit
    parameters: dict
    rms_after: np.ndarray
    via: str = "ranking"   # how the link was found: "ranking" (the stated test) or "held-out" (:func:`held_out_evidence`)

    @property
    def name(self) -> str:
        return self.unit.name


@dataclass
class HexChain:
    """The links after the first, every round's candidates (dicts), and why the chain stopped."""

    links: list = field(default_factory=list)
    rounds: list = field(default_factory=list)
    stop: str = ""

    def to_json_dict(self) -> dict:
        return {"rounds": self.rounds, "stop": self.stop}


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
    if sc.blocks_before is None or sc.blocks_after is None:
        return float("nan")
    b0, b1 = np.asarray(sc.blocks_before, float), np.asarray(sc.blocks_after, float)
    ok = (b0 > 0) & (b1 > 0)
    if ok.sum() < 3:
        return float("nan")
    d = np.log(b0[ok] / b1[ok])
    se = d.std(ddof=1) / np.sqrt(len(d))
    return float(d.mean() / se) if se > 0 else (float("inf") if d.mean() > 0 else 0.0)


def passes(sc, gap: dict) -> tuple[bool, str, str, float]:
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
    if "design" in gap and sc.design is not None and not ks.explained >= EXPLAINED_MIN:
        return True, "", "design", z
    if not (z >= Z_MIN):
        return False, f"paired block-wise z {z:.1f} < {Z_MIN:g} on the {kind} recordings", kind, z
    saved = (ks.z_before - ks.z_after) / ks.n
    if saved < MIN_FLOOR_SHARE:
        return False, f"saves {100 * saved:.1f} % of the floor's variance on the {kind} recordings (< {100 * MIN_FLOOR_SHARE:g} %)", kind, z
    return True, "", kind, z


def _round(att: Attribution, gap: dict) -> list[dict]:
    out = []
    for sc in att.scores:
        ok_, why, kind, z = passes(sc, gap) if sc.status == "ok" and gap else (False, sc.note or sc.status, "", float("nan"))
        out.append({"effect": sc.effect, "variant": dict(sc.model_effect.variant) if sc.model_effect is not None else {},
                    "delta_bic": None if not np.isfinite(ranking_bic(sc, gap)) else float(ranking_bic(sc, gap)),
                    "explained": float(explained_fraction(sc, gap)) if gap else 0.0, "status": sc.status,
                    "kind": kind or None, "paired_z": float(z) if np.isfinite(z) else None, "passes": bool(ok_),
                    **({"note": why} if why else {})})
    return out


def held_out_evidence(att: Attribution, left: dict, exclude: set) -> list[tuple]:
    """Candidates the joint refit tries when the ranking offers none that makes a link (module docstring):
    ``(score, kind, z, "held-out")`` of every scored candidate not in ``exclude`` whose paired block-wise z on a kind
    of ``left`` (the joint refit's gaps) is ``>= Z_MIN`` with a saving of ``>= MIN_FLOOR_SHARE`` of the floor's
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
            if z >= Z_MIN and (ks.z_before - ks.z_after) / ks.n >= MIN_FLOOR_SHARE and (best is None or z > best[2]):
                best = (sc, kind, z, "held-out")
        if best is not None:
            out.append(best)
    return sorted(out, key=lambda t: -t[2])


def _mark(round_: list, effect: str, via: str, outcome: str) -> None:
    """Note on the round's row of ``effect`` that the joint refit tried it (``via``) and what it found."""
    for row in round_:
        if row["effect"] == effect:
            row["joint_refit"] = {"via": via, "outcome": outcome}


def rebuild(members: tuple, variant: dict) -> tuple:
    """The members as the joint refit chose them (``Combined.variant``: ``{name: variant}``)."""
    return tuple(type(m)(**variant.get(m.name, m.variant)) for m in members)


def run_chain(views: Views, att: Attribution, first: Effect, joint: JointRefit, effects: list[Effect], model: Any, prior,
              calibration, robot, balance: str, primary: str | None, *, folds: int, seed: int,
              x_start: np.ndarray | None = None) -> HexChain:
    """The chain after the first link (module docstring). ``first``: the named effect's unit (the variant the
    attribution scored); ``joint``: its joint refit; ``att``: the first attribution (its design check);
    ``primary``: the kind the shrinkage is reported on."""
    ch = HexChain()
    named = (type(first)(**joint.variant),)
    cur = joint
    while True:
        # the swing legs' weights are predicted with the transducer frames, which a named design-face effect (a common
        # tilt) turns: after one, the swing kind says nothing about what is left (SKIP_AFTER_DESIGN)
        skip = SKIP_AFTER_DESIGN if any(m.design_face for m in named) else ()
        left = gap_left(cur)
        design_open = att.design is not None and not any(m.design_face for m in named) and design_gap(cur, robot)
        log.debug("diagnosis: chain after %s: gap left %s, design %s", [m.name for m in named], left, design_open)
        if not left and not design_open:
            ch.stop = "no gap above the floor is left after the joint refit"
            break
        if len(named) >= MAX_EFFECTS:
            ch.stop = f"{MAX_EFFECTS} effects named (the most the chain adds)"
            break
        base = Combined(named)
        cands = [e for e in effects if e.name not in {m.name for m in named}]
        try:
            att2 = attribute(views, cands, model, prior, robot, balance, folds=folds, seed=seed, x_start=x_start, base_effect=base)
        except (SolverError, np.linalg.LinAlgError) as exc:
            ch.stop = f"scoring the candidates beside {base.name} failed: {exc}"
            break
        gap = {k: v for k, v in gaps(att2).items() if k not in skip}
        ch.rounds.append(_round(att2, gap))
        tries, why_not = [], []
        ok = [s for s in att2.scores if s.status == "ok" and np.isfinite(ranking_bic(s, gap)) and ranking_bic(s, gap) < DBIC_STRONG
              and explained_fraction(s, gap) >= EXPLAINED_MIN] if gap else []
        if not gap:
            why_not.append("with the named effects in the model no gap above the floor is left")
        elif not ok:
            why_not.append(f"no candidate removes {100 * EXPLAINED_MIN:g} % of the excess the named effects leave with "
                    f"delta BIC < {DBIC_STRONG:g}")
        else:
            best = min(ok, key=lambda s: (ranking_bic(s, gap), s.delta_bic))
            # parsimony: as good by BIC (within BIC_TIE) with fewer parameters goes first (a mocap bias and a cable both
            # explain a common tilt of the frames; the cable spends parameters on every face)
            best = min((s for s in ok if ranking_bic(s, gap) <= ranking_bic(best, gap) + BIC_TIE),
                       key=lambda s: (sum(k.dof for k in s.kinds.values()), ranking_bic(s, gap), s.delta_bic))
            passes_, why, kind, z = passes(best, gap)
            if passes_:
                tries.append((best, kind, z, "ranking"))
            else:
                why_not.append(f"the next candidate, {best.effect}, adds nothing significant on held-out data ({why})")
        tries += held_out_evidence(att2, left, {t[0].effect for t in tries})[:JOINT_TRIES]
        link = None
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
            if good:
                link = (sc, kind, z, both, j2, via)
                break
            why_not.append(f"the joint refit with {sc.effect} does not predict held-out data better ({why})")
        if link is None:
            ch.stop = "; ".join(why_not)
            break
        best, kind, z, both, j2, via = link
        named = rebuild(both.members, j2.variant)
        mine = Combined(named).member_parameters(j2.parameters)[-1]
        pk = primary if primary in j2.kinds else next(iter(j2.kinds), None)
        after = j2.kinds[pk].rms_after if pk is not None else np.full(6, np.nan)
        if via == "ranking":
            explained, dbic = float(explained_fraction(best, gap)), float(ranking_bic(best, gap))
        else:   # the attribution saw no gap there: the share is what the joint refit removed of the kind's excess
            e0, e1 = excess(cur.kinds[kind]), excess(j2.kinds[kind])
            explained, dbic = (1.0 - e1 / e0 if e0 > 0 else 0.0), float(ranking_bic(best, {kind: left[kind]}))
        ch.links.append(Link(named[-1], kind, z, explained, dbic, j2, mine, after, via))
        log.info("diagnosis: chain adds %s (%s: z %.1f on %s, explains %.0f %%)", best.effect, via, z, kind, 100 * explained)
        cur = j2
    return ch
