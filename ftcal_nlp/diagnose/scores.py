"""How much of a recording kind's residual an effect explains: held-out and information criteria.

For a kind (standing poses, hanging samples, walking swing samples) with
residuals ``e`` and per-component noise floors ``sigma`` (``views.py``):

* ``mse_before`` / ``mse_after`` (6,): held-out mean squared residual per
  component without / with the effect (N^2, (N*m)^2), cross-validated: the
  effect's parameters are never fitted to the data they are scored on;
* ``z_before`` / ``z_after``: the same, summed over components in units of the
  floor (``sum (e / sigma)^2``), and ``n`` the number of scalar residuals;
* ``delta_bic = n ln(RSS_after / RSS_before) + dof ln n`` on the in-sample
  floor-standardised RSS, ``dof`` the effective number of parameters added.

``excess = z / n - 1`` is the part of the residual above the floor (0 for a
model that leaves only noise); ``explained`` the fraction of the base's excess
that the effect removes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.results import bic


@dataclass(frozen=True)
class KindScore:
    kind: str
    mse_before: np.ndarray
    mse_after: np.ndarray
    floor: np.ndarray
    z_before: float
    z_after: float
    rss_before: float
    rss_after: float
    n: int
    dof: int
    # held-out sums of squares in floor units per block (standing: per pose; hanging, swing: per fold and leg),
    # without / with the effect: what the chain's paired test compares (``hexchain.py``); None: not kept
    blocks_before: np.ndarray | None = None
    blocks_after: np.ndarray | None = None

    @property
    def delta_bic(self) -> float:
        """BIC with the effect minus BIC without (``results.bic``; ``dof`` the effect's added degrees of freedom)."""
        if self.rss_before <= 0 or self.n < 2:
            return 0.0
        return bic(max(self.rss_after, 1e-300), self.n, self.dof) - bic(self.rss_before, self.n, 0)

    @property
    def excess_before(self) -> float:
        return self.z_before / self.n - 1.0

    @property
    def excess_after(self) -> float:
        return self.z_after / self.n - 1.0

    @property
    def explained(self) -> float:
        """Fraction of the held-out excess over the floor removed by the effect (can be < 0)."""
        ex = self.excess_before
        return float((self.z_before - self.z_after) / self.n / ex) if ex > 0 else 0.0

    @property
    def rms_before(self) -> np.ndarray:
        return np.sqrt(self.mse_before)

    @property
    def rms_after(self) -> np.ndarray:
        return np.sqrt(self.mse_after)


def base_score(kind: str, mse: np.ndarray, floor: np.ndarray, z: float, rss: float, n: int) -> KindScore:
    """The calibration model alone: nothing added."""
    return KindScore(kind, mse, mse, floor, z, z, rss, rss, n, 0)
