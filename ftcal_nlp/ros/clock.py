"""One clock per recording: asynchronous ROS streams resampled onto the wrench clock.

Every function works on float seconds since the session epoch and never
extrapolates: a clock time outside a stream's span, or inside a gap of that
stream longer than ``max_gap_s``, gets no value (a mask says so, or NaN). What
the caller does with such rows (drop and count, or keep as NaN orientation as
``DATA_FORMAT.md`` section 3 asks for ``qw..qz``) is its business.

* wrenches of the other transducers: nearest sample within half a period of the
  clock row (:func:`match_nearest`), or the linear interpolation between the
  bracketing samples where such a sample exists (:func:`interp_linear`);
* shaft angles: unwrapped, then linear (:func:`interp_linear`);
* orientation: spherical linear interpolation (:func:`slerp_quat`), the
  geodesic between the two bracketing mocap samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..core.errors import DataFormatError


@dataclass(frozen=True)
class Resampled:
    """Values of one stream on the clock.

    ``values`` (N, d), NaN where there is no value; ``outside`` (N,) clock rows
    outside the stream's span; ``in_gap`` (N,) rows inside a gap longer than the
    allowed one (``outside`` and ``in_gap`` are disjoint).
    """

    values: np.ndarray
    outside: np.ndarray
    in_gap: np.ndarray

    @property
    def missing(self) -> np.ndarray:
        return self.outside | self.in_gap


def sort_unique(stamps: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Sort samples by stamp and keep the first of each repeated stamp.

    Bags store messages in receive order, which need not be header-stamp order.
    Returns ``(stamps, values, n_duplicates)``.
    """
    stamps = np.asarray(stamps)
    order = np.argsort(stamps, kind="stable")
    s, v = stamps[order], np.asarray(values)[order]
    keep = np.ones(len(s), dtype=bool)
    keep[1:] = s[1:] != s[:-1]
    return s[keep], v[keep], int((~keep).sum())


def median_period(stamps: np.ndarray) -> float:
    """Median sample period (s) of a sorted stream with at least two samples."""
    if len(stamps) < 2:
        raise DataFormatError("a stream needs at least two samples to have a period")
    return float(np.median(np.diff(stamps)))


def match_nearest(clock: np.ndarray, stamps: np.ndarray, tol: float) -> np.ndarray:
    """Index of the sample of ``stamps`` (sorted) nearest to each clock time.

    -1 where the nearest sample is further than ``tol`` seconds away.
    """
    n = len(stamps)
    out = np.full(len(clock), -1, dtype=np.int64)
    if n == 0:
        return out
    j = np.searchsorted(stamps, clock)
    lo = np.clip(j - 1, 0, n - 1)
    hi = np.clip(j, 0, n - 1)
    d_lo = np.abs(clock - stamps[lo])
    d_hi = np.abs(stamps[hi] - clock)
    idx = np.where(d_hi < d_lo, hi, lo)
    ok = np.minimum(d_lo, d_hi) <= tol
    out[ok] = idx[ok]
    return out


def _span_and_gaps(clock: np.ndarray, stamps: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(outside, in_gap) masks of clock times against a sorted stream."""
    n = len(stamps)
    if n == 0:
        return np.ones(len(clock), dtype=bool), np.zeros(len(clock), dtype=bool)
    outside = (clock < stamps[0]) | (clock > stamps[-1])
    if n == 1:
        return outside | (clock != stamps[0]), np.zeros(len(clock), dtype=bool)
    j = np.clip(np.searchsorted(stamps, clock, side="right"), 1, n - 1)
    width = stamps[j] - stamps[j - 1]
    exact = (clock == stamps[j - 1]) | (clock == stamps[j])
    in_gap = ~outside & ~exact & (width > max_gap_s)
    return outside, in_gap


def interp_linear(clock: np.ndarray, stamps: np.ndarray, values: np.ndarray, max_gap_s: float = np.inf) -> Resampled:
    """Linear interpolation of ``values`` (M,) or (M, d) at the sorted ``stamps`` onto ``clock``.

    Clock rows outside ``[stamps[0], stamps[-1]]`` or between two samples more
    than ``max_gap_s`` apart get NaN (never extrapolated, never bridged).
    """
    v = np.asarray(values, dtype=float)
    v2 = v[:, None] if v.ndim == 1 else v
    outside, in_gap = _span_and_gaps(clock, stamps, max_gap_s)
    out = np.full((len(clock), v2.shape[1]), np.nan)
    ok = ~(outside | in_gap)
    if ok.any():
        for c in range(v2.shape[1]):
            out[ok, c] = np.interp(clock[ok], stamps, v2[:, c])
    return Resampled(out, outside, in_gap)


def slerp_quat(clock: np.ndarray, stamps: np.ndarray, quat_wxyz: np.ndarray, max_gap_s: float) -> Resampled:
    """Orientation at the clock times by slerp between the bracketing samples.

    ``quat_wxyz`` (M, 4) maps body to world vectors; need not be normalised and
    may switch sign between samples (the geodesic is taken). Output (N, 4)
    ``[qw, qx, qy, qz]`` with ``qw >= 0``, NaN outside the span and inside gaps
    longer than ``max_gap_s``.
    """
    q = np.asarray(quat_wxyz, dtype=float)
    outside, in_gap = _span_and_gaps(clock, stamps, max_gap_s)
    out = np.full((len(clock), 4), np.nan)
    ok = ~(outside | in_gap)
    if ok.any():
        rots = Rotation.from_quat(q[:, [1, 2, 3, 0]])
        r = rots[np.searchsorted(stamps, clock[ok])] if len(stamps) == 1 else Slerp(stamps, rots)(clock[ok])
        xyzw = r.as_quat()
        wxyz = xyzw[:, [3, 0, 1, 2]]
        out[ok] = wxyz * np.where(wxyz[:, :1] < 0, -1.0, 1.0)
    return Resampled(out, outside, in_gap)
