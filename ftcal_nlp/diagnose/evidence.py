"""The chain of effects, once for every kind of evidence (issue 23, item 2; issue 31): name the strongest candidate by
held-out evidence, refit jointly with the effects named before it, look again.

The loop (:func:`name_effects`):

1. stop when no gap above the floor is left (:meth:`EvidenceKind.no_gap` says why);
2. when fewer than ``max_effects`` are named, the kind's next link (:meth:`EvidenceKind.next_link`): every candidate
   not yet named is scored beside the named ones, the best is tested (paired block-wise z of its held-out saving at
   least ``z_min``, a saving of at least ``min_floor_share`` of the floor's variance, and the kind's own conditions)
   and refit jointly with them; when it stands, look again;
3. else an alternative to naming one more (:meth:`EvidenceKind.replace`: the hexapod's swap of a named effect for
   another; free loads have none); when made, look again;
4. else stop: the reasons steps 2-3 gave, joined.

The thresholds are :class:`~ftcal_nlp.core.settings.ChainThresholds` (one set of names; each kind its own values in
:class:`~ftcal_nlp.core.settings.DiagnoseSettings`). What a kind's evidence is, how a candidate is scored and refit, is
behind :class:`EvidenceKind`: the hexapod's standing poses, hanging legs and walking swing (``hexchain.py``, each
link a joint refit of the whole calibration) and the free loads' samples (``chain.py``, each link a refit of the
linearised free-load model with the named faces).
"""

from __future__ import annotations

import logging
from typing import Protocol

from ..core.settings import ChainThresholds

log = logging.getLogger(__name__)


class EvidenceKind(Protocol):
    """What the chain's loop asks of a kind of evidence; the kind keeps the named effects and every round."""

    def no_gap(self) -> str | None:
        """Why the chain stops because no gap above the floor is left (None: a gap is left, look again)."""

    def n_named(self) -> int:
        """How many effects are named so far (the first included)."""

    def next_link(self, why_not: list[str]) -> bool:
        """Score, test and refit the next candidate; True when one was named, else the reasons appended to ``why_not``."""

    def replace(self, why_not: list[str]) -> bool:
        """An alternative when no link is made; True when made, else the reasons (if any) appended to ``why_not``."""


def name_effects(kind: EvidenceKind, t: ChainThresholds) -> str:
    """The loop of the module docstring over ``kind``; returns why the chain stopped."""
    log.debug("chain of effects (%s), thresholds: z_min %g, min_floor_share %g, max_effects %d, explained_min %g",
              type(kind).__name__, t.z_min, t.min_floor_share, t.max_effects, t.explained_min)
    while True:
        stop = kind.no_gap()
        if stop is not None:
            return stop
        why_not: list[str] = []
        if kind.n_named() >= t.max_effects:
            why_not.append(f"{t.max_effects} effects named (the most the chain adds)")
        elif kind.next_link(why_not):
            continue
        if kind.replace(why_not):
            continue
        return "; ".join(why_not)
