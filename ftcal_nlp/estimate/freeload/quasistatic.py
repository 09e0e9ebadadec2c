"""Quasi-static samples of a free load: where the body, the joints and the readings hold still enough.

A free load is moved slowly or held (``DATA_FORMAT.md`` section 5); its model
is static, so the estimator uses only samples where

* the body's rate of turn ``|omega|`` (from ``qw..qz``: ``||dR/dt||_F / sqrt 2``;
  from ``gx..gz`` only the gravity direction's rate ``|dg/dt|``),
* every joint's rate ``|dq/dt|`` (``q_{joint}`` columns), and
* the norm of the force derivative ``|df/dt|`` of the transducer

are under their thresholds. Derivatives by a Savitzky-Golay filter (as the
standing poses, ``standing/poses.py``), per stretch without time gaps. Each
threshold rises to ``noise_factor`` times the median of its rate over the
samples the other two rates call still, when that is larger: noisier streams
(mocap jitter, a noisier transducer) keep their holds instead of losing them
all. The thresholds used and the kept/dropped counts are returned and logged.

A recording whose samples lie farther apart than the filter window (median
interval > ``window_s``) is a list of poses (one row per hold, e.g. an average
or a snapshot per pose): no rate can be formed, each tracked sample is taken as
a hold, and the log says so.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter

from ...core.geometry import quat_to_rotation
from ...core.settings import FreeLoadSettings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class QuasiStatic:
    """The selection of one recording for one transducer: ``mask`` (N,) kept samples; ``thresholds`` used
    (rotation rad/s, joint rad/s, force N/s); ``counts`` {"samples", "tracked", "kept", "dropped"}."""

    mask: np.ndarray
    thresholds: dict[str, float]
    counts: dict[str, int]


def _odd_window(window_s: float, dt: float, polyorder: int, n: int) -> int:
    w = max(int(round(window_s / dt)), polyorder + 2)
    w += 1 - w % 2
    return min(w, n if n % 2 else n - 1)


def _derivative(x: np.ndarray, t: np.ndarray, s: FreeLoadSettings) -> np.ndarray:
    """Savitzky-Golay derivative of ``x`` (N, d) along time, stretch by stretch between time gaps;
    stretches too short for the filter get inf (never quasi-static)."""
    out = np.full(x.shape, np.inf)
    if len(t) < 2:
        return out
    dt = float(np.median(np.diff(t)))
    breaks = np.flatnonzero(np.diff(t) > s.max_gap_factor * dt) + 1
    for a, b in zip(np.r_[0, breaks], np.r_[breaks, len(t)]):
        if b - a < s.polyorder + 2:
            continue
        win = _odd_window(s.window_s, dt, s.polyorder, b - a)
        if win <= s.polyorder:
            continue
        out[a:b] = savgol_filter(x[a:b], win, s.polyorder, deriv=1, delta=dt, axis=0)
    return out


def rates(t: np.ndarray, force: np.ndarray, quat: np.ndarray | None, gravity: np.ndarray | None,
          q: dict[str, np.ndarray], s: FreeLoadSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rotation rate rad/s, largest joint rate rad/s, force-derivative norm N/s), each (N,); NaN orientations
    are filled from their neighbours for the filter and left out by the caller."""
    n = len(t)
    if quat is not None:
        qq = _fill(quat)
        R = quat_to_rotation(qq / np.linalg.norm(qq, axis=1, keepdims=True)).reshape(n, 9)
        rot = np.linalg.norm(_derivative(R, t, s), axis=1) / np.sqrt(2.0)
    elif gravity is not None:
        rot = np.linalg.norm(_derivative(_fill(gravity), t, s), axis=1)
    else:
        rot = np.zeros(n)
    joint = np.abs(_derivative(np.stack(list(q.values()), axis=1), t, s)).max(axis=1) if q else np.zeros(n)
    dF = np.linalg.norm(_derivative(force, t, s), axis=1)
    return rot, joint, dF


def _fill(x: np.ndarray) -> np.ndarray:
    """Rows with NaN replaced by the nearest earlier finite row (the first finite row before any)."""
    ok = np.all(np.isfinite(x), axis=1)
    if ok.all() or not ok.any():
        return np.nan_to_num(x)
    idx = np.where(ok, np.arange(len(x)), 0)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(ok))
    idx[:first] = first
    return x[idx]


def select_quasi_static(t: np.ndarray, force: np.ndarray, quat: np.ndarray | None, gravity: np.ndarray | None,
                        q: dict[str, np.ndarray], s: FreeLoadSettings, where: str = "") -> QuasiStatic:
    """The quasi-static samples of one recording (module docstring)."""
    n = len(t)
    tracked = np.ones(n, bool)
    if gravity is not None:
        tracked &= np.all(np.isfinite(gravity), axis=1)
    if n < 2 or float(np.median(np.diff(t))) > s.window_s:
        log.info("%s: samples %.3g s apart, more than the %g s window: a list of poses, each sample taken as a hold", where,
                 float(np.median(np.diff(t))) if n > 1 else float("nan"), s.window_s)
        counts = {"samples": n, "tracked": int(tracked.sum()), "kept": int(tracked.sum()), "dropped": int(n - tracked.sum())}
        return QuasiStatic(tracked, {"pose_list": 1.0}, counts)
    rot, joint, dF = rates(t, force, quat, gravity, q, s)
    thr = {"rotation_rad_s": s.rotation_rate_threshold_rad_s, "joint_rad_s": s.joint_rate_threshold_rad_s,
           "force_N_s": s.deriv_threshold_N_s}
    vals = {"rotation_rad_s": rot, "joint_rad_s": joint, "force_N_s": dF}
    if s.noise_factor > 0:
        base = {k: vals[k] <= thr[k] for k in thr}
        for k in thr:
            others = tracked & np.all([base[o] for o in thr if o != k], axis=0) & np.isfinite(vals[k])
            if others.any():
                level = s.noise_factor * float(np.median(vals[k][others]))
                if level > thr[k]:
                    log.info("%s: %s threshold raised from %g to %.3g (%g x the median over still samples: noisier than the fixed "
                             "threshold allows)", where, k, thr[k], level, s.noise_factor)
                    thr[k] = level
    mask = tracked & (rot <= thr["rotation_rad_s"]) & (joint <= thr["joint_rad_s"]) & (dF <= thr["force_N_s"])
    counts = {"samples": n, "tracked": int(tracked.sum()), "kept": int(mask.sum()), "dropped": int(n - mask.sum())}
    return QuasiStatic(mask, thr, counts)
