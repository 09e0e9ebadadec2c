"""Static poses from a raw standing recording (report Sec. I-B).

The report waited 5 s between poses, differentiated the force data with a
2nd-order Savitzky-Golay filter, called a pose steady once the L2 norm of the
force derivative stayed under 1 N/s, kept poses steady for more than 1.5 s and
represented each by the median of its steady samples; poses without full
motion capture were dropped (729 -> 635 -> 543 poses).

Here, stage by stage (the counts are kept in :attr:`Poses.counts`):

1. ``transitions``: candidate poses, the maximal intervals in which no shaft
   moves (every ``|d phi_k/dt| <= phi_rate_threshold_rad_s``, derivative by the
   same filter). Each commanded pose gives one candidate.
2. ``steady``: candidates whose longest run with force-derivative norm
   ``< deriv_threshold_N_s`` lasts at least ``min_steady_s``. The norm is taken
   over the force derivatives of all legs together (``deriv_norm = "legs"``,
   the default: internal forces that settle between legs count), or of their
   sum (``deriv_norm = "total"``). The report's 1 N/s suits its transducers: the
   filtered derivative of white noise ``sigma`` has a norm of about
   ``sqrt(3K) sqrt(12) sigma / (w^1.5 dt)`` (window ``w`` samples), 0.4 N/s for an
   ATI Gamma at 100 Hz but 0.9 N/s at twice its noise, where no run of 1.5 s stays
   under 1 N/s. So the threshold rises to ``deriv_noise_factor`` times the median
   norm over the still samples (mostly steady: a pose settles in a fraction of its
   hold) when that is larger; it is logged.
3. ``with_mocap``: steady poses whose steady run has at most a fraction
   ``max_mocap_missing`` (default 0) of samples without orientation.

A pose is the per-channel median of the steady run; its orientation is the
median quaternion (signs aligned, component-wise median, re-normalised) with the
yaw removed, since the heading does not enter any balance.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from ...core.data import DataFormatError, Recording
from ...core.geometry import quat_to_rotation, remove_yaw
from ...core.robot import Robot
from ...core.settings import PoseExtraction

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Poses:
    """Static standing poses, legs in ``legs`` order.

    ``w_m`` (P, K, 6) median raw readings in ft_k (N, N*m); ``phi`` (P, K) median
    shaft angles (rad); ``R_WB`` (P, 3, 3) body orientation with yaw removed
    (B -> W); ``t`` (P,) s, the middle of each steady run; ``counts`` the number
    of poses left after each stage; ``source`` (P,) index of the recording.
    """

    w_m: np.ndarray
    phi: np.ndarray
    R_WB: np.ndarray
    t: np.ndarray
    legs: tuple[str, ...]
    counts: dict[str, int] = field(default_factory=dict)
    source: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.t)

    def __len__(self) -> int:
        return self.n

    def subset(self, idx: np.ndarray) -> "Poses":
        """The poses at integer or boolean index ``idx`` (counts describe the whole set)."""
        idx = np.asarray(idx)
        return Poses(self.w_m[idx], self.phi[idx], self.R_WB[idx], self.t[idx], self.legs, dict(self.counts),
                     None if self.source is None else self.source[idx])

    @classmethod
    def concat(cls, parts: list["Poses"]) -> "Poses":
        """Poses of several recordings together; counts add up stage by stage."""
        parts = list(parts)
        if not parts:
            raise ValueError("Poses.concat: no poses given")
        legs = parts[0].legs
        for p in parts[1:]:
            if p.legs != legs:
                raise ValueError(f"Poses.concat: leg orders differ ({legs} vs {p.legs})")
        counts: dict[str, int] = {}
        for p in parts:
            for k, v in p.counts.items():
                counts[k] = counts.get(k, 0) + int(v)
        src = np.concatenate([np.full(p.n, i) for i, p in enumerate(parts)])
        return cls(
            np.concatenate([p.w_m for p in parts]), np.concatenate([p.phi for p in parts]),
            np.concatenate([p.R_WB for p in parts]), np.concatenate([p.t for p in parts]), legs, counts, src,
        )


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open ``(start, stop)`` index ranges where ``mask`` is true."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(d[0::2], d[1::2]))


def _median_quaternion(q: np.ndarray) -> np.ndarray:
    """Median orientation of unit quaternions (N, 4): signs aligned with the first, median, re-normalised."""
    q = q * np.where(q @ q[0] < 0, -1.0, 1.0)[:, None]
    m = np.median(q, axis=0)
    return m / np.linalg.norm(m)


def _odd_window(window_s: float, dt: float, polyorder: int, n: int) -> int:
    w = max(int(round(window_s / dt)), polyorder + 2)
    w += 1 - w % 2
    return min(w, n if n % 2 else n - 1)


def steady_runs(recording: Recording, robot: Robot, settings: PoseExtraction = PoseExtraction()) -> tuple[list[tuple[int, int]], int]:
    """Half-open sample ranges of the steady runs of a standing ``recording`` (stages 1 and 2 of the
    module docstring) and the number of candidate poses (stage 1).

    Raises :class:`~ftcal_nlp.core.data.DataFormatError` naming the recording if it has no
    orientation columns or no interval without shaft motion.
    """
    s = settings
    where = recording.path or recording.name
    if recording.quat is None:
        raise DataFormatError(f"{where}: standing recording without orientation columns qw, qx, qy, qz")
    legs = robot.legs
    t = recording.t
    W = recording.wrench_array(legs)       # (N, K, 6)
    phi = recording.phi_array(legs)        # (N, K)
    dt = float(np.median(np.diff(t)))
    # Savitzky-Golay assumes uniform sampling: time gaps (dropped rows) split the record.
    breaks = np.flatnonzero(np.diff(t) > s.max_gap_factor * dt) + 1
    chunks = [(a, b) for a, b in zip(np.r_[0, breaks], np.r_[breaks, len(t)])]
    min_len = s.polyorder + 2
    still_runs: list[tuple[int, int, np.ndarray]] = []  # candidate (start, stop, steady mask)
    for a, b in chunks:
        if b - a < min_len:
            continue
        win = _odd_window(s.window_s, dt, s.polyorder, b - a)
        dF = savgol_filter(W[a:b, :, :3], win, s.polyorder, deriv=1, delta=dt, axis=0)
        norm = np.linalg.norm(dF.sum(axis=1) if s.deriv_norm == "total" else dF.reshape(b - a, -1), axis=1)
        dphi = savgol_filter(phi[a:b], win, s.polyorder, deriv=1, delta=dt, axis=0)
        still = np.all(np.abs(dphi) <= s.phi_rate_threshold_rad_s, axis=1)
        for c0, c1 in _runs(still):
            still_runs.append((a + c0, a + c1, norm[c0:c1]))
    if not still_runs:
        raise DataFormatError(f"{where}: columns {{leg}}_phi: no interval in which every shaft stands still (|d phi/dt| <= "
                              f"{s.phi_rate_threshold_rad_s:g} rad/s, [standing.poses] phi_rate_threshold_rad_s); expected static poses "
                              "with transitions between them")

    threshold = s.deriv_threshold_N_s
    if s.deriv_noise_factor > 0:
        noise = s.deriv_noise_factor * float(np.median(np.concatenate([n for _, _, n in still_runs])))
        if noise > threshold:
            log.info("%s: force-derivative threshold raised from %g to %.3g N/s (%g x the still samples' median "
                     "norm: the readings are noisier than the fixed threshold allows)", where, threshold, noise, s.deriv_noise_factor)
            threshold = noise
    steady: list[tuple[int, int]] = []
    for c0, c1, norm in still_runs:
        runs = _runs(norm < threshold)
        if not runs:
            continue
        r0, r1 = max(runs, key=lambda r: r[1] - r[0])
        if (r1 - r0) * dt >= s.min_steady_s:
            steady.append((c0 + r0, c0 + r1))
    return steady, len(still_runs)


def extract_poses(recording: Recording, robot: Robot, settings: PoseExtraction = PoseExtraction()) -> Poses:
    """Static poses of a standing ``recording`` (Sec. I-B, stages in the module docstring).

    Raises :class:`~ftcal_nlp.core.data.DataFormatError` (from :func:`steady_runs`) naming the recording if it
    has no orientation columns or no interval without shaft motion.
    """
    s = settings
    legs = robot.legs
    t = recording.t
    W = recording.wrench_array(legs)       # (N, K, 6)
    phi = recording.phi_array(legs)        # (N, K)
    steady, n_candidates = steady_runs(recording, robot, s)

    q = recording.quat
    assert q is not None  # steady_runs raised otherwise
    keep = []
    for r0, r1 in steady:
        valid = np.all(np.isfinite(q[r0:r1]), axis=1)
        if valid.any() and 1.0 - valid.mean() <= s.max_mocap_missing:
            keep.append((r0, r1, valid))
    P, K = len(keep), len(legs)
    w_m = np.empty((P, K, 6))
    ph = np.empty((P, K))
    R_WB = np.empty((P, 3, 3))
    tt = np.empty(P)
    for i, (r0, r1, valid) in enumerate(keep):
        w_m[i] = np.median(W[r0:r1], axis=0)
        ph[i] = np.median(phi[r0:r1], axis=0)
        R_WB[i] = remove_yaw(quat_to_rotation(_median_quaternion(q[r0:r1][valid])))
        tt[i] = 0.5 * (t[r0] + t[r1 - 1])
    counts = {"transitions": n_candidates, "steady": len(steady), "with_mocap": P}
    return Poses(w_m, ph, R_WB, tt, tuple(legs), counts, np.zeros(P, dtype=int))
