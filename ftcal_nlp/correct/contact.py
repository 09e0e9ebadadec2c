"""Contact state of each foot (stance / swing) from its corrected ground wrench, with hysteresis.

A foot in the air carries no ground wrench: its corrected normal force ``f_z``
(heading frame, ``physics.ground_wrenches``) is zero up to noise, and up to the
change of its transducer's offset since calibration, which moves the whole
swing level. So the swing level is taken from the data: in windows of
``contact_window_s`` the low quantile ``b`` (``contact_quantile``) of ``f_z``,
kept where the window is clearly two-level (its ``1 - contact_quantile``
quantile exceeds it by ``contact_min_gap_N``, about half of a foot's share of
the weight: a window of pure stance, a standing recording, keeps the
calibration's zero; a foot may rest unloaded for more than half of the time,
so the median will not do), interpolated in time (held beyond the first and
last such window). With ``s`` the sample's standard
error of ``f_z`` (``uncertainty.py``; its median per foot), the thresholds are

    T_enter = contact_enter_z * s,     T_leave = contact_leave_z * s,

a foot goes to swing when ``f_z - b < T_enter`` and back to stance when
``f_z - b > T_leave``, in between it keeps its state (hysteresis, vectorised as
the last crossing carried forward). The thresholds are logged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..core.settings import CorrectSettings

__all__ = ["ContactState", "swing_baseline", "detect_contact"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ContactState:
    """``stance`` (N, K) bool per sample and foot; ``baseline_N`` (N, K) the swing level ``b``;
    ``enter_N`` / ``leave_N`` (K,) the thresholds above ``b`` (module docstring)."""

    stance: np.ndarray
    baseline_N: np.ndarray
    enter_N: np.ndarray
    leave_N: np.ndarray


def swing_baseline(t: np.ndarray, fz: np.ndarray, settings: CorrectSettings = CorrectSettings()) -> np.ndarray:
    """The swing level (N, K) of normal forces ``fz`` (N, K) at times ``t`` (N,) (module docstring)."""
    s = settings
    N, K = fz.shape
    if N == 0:
        return np.zeros_like(fz)
    # equal windows of about contact_window_s: a short last window could be all stance and look two-level
    nb = max(1, int(round((t[-1] - t[0]) / s.contact_window_s)))
    edges = np.linspace(t[0], t[-1], nb + 1)
    which = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, nb - 1)
    # samples in time order: each window is one slice (a mask per window would scan every sample nb times)
    order = None if np.all(which[1:] >= which[:-1]) else np.argsort(which, kind="stable")
    w_sorted = which if order is None else which[order]
    bounds = np.searchsorted(w_sorted, np.arange(nb + 1))
    centre = np.full(nb, np.nan)
    level = np.full((nb, K), np.nan)
    for b in range(nb):  # windows, not samples: a few per minute
        lo_i, hi_i = bounds[b], bounds[b + 1]
        if hi_i - lo_i < 10:
            continue
        sel = slice(lo_i, hi_i) if order is None else order[lo_i:hi_i]
        lo, hi = np.quantile(fz[sel], [s.contact_quantile, 1 - s.contact_quantile], axis=0)
        centre[b] = t[sel].mean()
        level[b] = np.where(hi - lo > s.contact_min_gap_N, lo, np.nan)
    out = np.zeros((N, K))
    for k in range(K):
        ok = np.isfinite(level[:, k]) & np.isfinite(centre)
        if ok.any():
            out[:, k] = np.interp(t, centre[ok], level[ok, k])
    return out


def _hysteresis(x: np.ndarray, enter: np.ndarray, leave: np.ndarray) -> np.ndarray:
    """Stance (N, K) of ``x`` (N, K) with thresholds (K,): below ``enter`` swing, above ``leave`` stance,
    otherwise the state of the last crossing (before any: the nearer threshold's side)."""
    N, K = x.shape
    out = np.empty((N, K), bool)
    it = np.int32 if N < 2**31 - 1 else np.int64  # half the memory traffic of int64
    order = np.arange(N, dtype=it)
    for k in range(K):  # one contiguous foot at a time: the (N, K) columns are strided
        xk = np.ascontiguousarray(x[:, k])
        up = xk > leave[k]
        last = np.maximum.accumulate(np.where(up | (xk < enter[k]), order, it(-1)))  # last crossing, carried forward
        out[:, k] = np.where(last >= 0, up[np.maximum(last, 0)], xk > 0.5 * (enter[k] + leave[k]))
    return out


def detect_contact(t: np.ndarray, fz: np.ndarray, fz_se: np.ndarray | None, settings: CorrectSettings = CorrectSettings(),
                   *, baseline: bool = True, legs: tuple[str, ...] | None = None) -> ContactState:
    """Stance or swing of every foot (module docstring). ``t`` (N,) s; ``fz`` (N, K) corrected normal
    forces (N); ``fz_se`` (N, K) their standard errors (None: thresholds in N of 0.05 N per z, the
    transducers' typical noise); ``baseline`` False: the swing level is zero (offsets already tracked)."""
    s = settings
    N, K = fz.shape
    base = swing_baseline(t, fz, s) if baseline else np.zeros((N, K))
    if fz_se is None or N == 0:
        unit = np.full(K, 0.05)
    else:
        se = np.where(np.isfinite(fz_se), fz_se, np.nan)
        unit = np.nan_to_num(np.nanmedian(se, axis=0), nan=0.05) if np.isfinite(se).any() else np.full(K, 0.05)
    enter, leave = s.contact_enter_z * unit, s.contact_leave_z * unit
    stance = _hysteresis(fz - base, enter, leave) if N else np.zeros((0, K), bool)
    names = legs or tuple(str(k) for k in range(K))
    log.info("contact: swing below %s N, stance above %s N over the swing level (%g / %g se; legs %s); swing fraction %s",
             np.round(enter, 3).tolist(), np.round(leave, 3).tolist(), s.contact_enter_z, s.contact_leave_z, list(names),
             np.round(1 - stance.mean(axis=0), 3).tolist() if N else [])
    return ContactState(stance, base, enter, leave)
