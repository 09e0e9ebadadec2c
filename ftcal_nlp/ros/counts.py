"""What an ingest keeps and drops, and the pieces every ingest path shares (:mod:`.ingest` for hexapods and
section-5 maps, :mod:`.arm` for arms): the counts, the result, session seconds from header stamps, and the
check that header stamps do not step back.

Session seconds: ``t = (stamp_ns - epoch_ns) * 1e-9``, the difference taken in int64 first (float64 seconds
since 1970 resolve only ~240 ns); ``epoch_ns + round(t * 1e9)`` gives the stamp back to the nanosecond while
``t`` stays under ~4.5e6 s (52 days).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.data import Dataset
from .bagio import BagError, Stream


@dataclass(frozen=True)
class IngestCounts:
    """What resampling one bag kept and dropped (rows of the wrench clock).

    Per-leg counts are independent (a row may be counted for several reasons);
    ``n_rows`` is what the recording holds. ``clock_gaps`` estimates the
    messages of the first leg (the clock) that never arrived: they leave no row.
    """

    name: str
    bag: str
    n_clock: int
    n_rows: int
    duplicate_stamps: int
    clock_gaps: int = 0
    unmatched_wrench: dict[str, int] = field(default_factory=dict)
    joint_outside_span: dict[str, int] = field(default_factory=dict)
    joint_gap: dict[str, int] = field(default_factory=dict)
    nan_readings: int = 0
    nan_orientation: int = 0
    invalid_pose_samples: int = 0
    joint_columns_dropped: dict[str, int] = field(default_factory=dict)   # section 5: rows without q_{joint}
    imu_dropped: int = 0                                                   # rows without accelerometer gravity
    temperature_outside_span: int = 0       # arm (ros/arm.py): rows too far outside the temperature stream


@dataclass(frozen=True)
class IngestResult:
    """A dataset built from a map's bags, with the counts and the session epoch (ns)."""

    dataset: Dataset
    counts: tuple[IngestCounts, ...]
    epoch_ns: int
    map: Any       # the map read: a .mapfile.IngestMap, or an .arm.ArmMap (not imported: .arm builds on this module)


def seconds(stamp_ns: np.ndarray, epoch_ns: int) -> np.ndarray:
    # Subtract in integers first: float64 seconds since 1970 lose sub-microsecond detail.
    return (np.asarray(stamp_ns, dtype=np.int64) - np.int64(epoch_ns)).astype(float) * 1e-9


def check_not_backwards(spec, key: str, st: Stream, max_backward_s: float) -> None:
    """Header stamps in bag (receive) order may step back by transport reordering,
    never by more than ``max_backward_s``: that is a clock reset, a looped
    playback or two clocks on one topic, and sorting would interleave them."""
    if len(st) < 2:
        return
    d = np.diff(st.stamp_ns)
    i = int(np.argmin(d))
    if d[i] < -max_backward_s * 1e9:
        raise BagError(
            f"{spec.bag}: topic '{st.topic}' ({key}): header stamps go backwards: sample {i + 2} of {len(st)} (bag order) is stamped "
            f"{-d[i] * 1e-9:.6g} s before the one received just ahead of it ({(st.stamp_ns[i] - st.stamp_ns[0]) * 1e-9:.6g} s after the first); "
            f"expected stamps that increase, up to max_backward_s = {max_backward_s:g} s of reordering. A clock reset, a looped playback "
            "or two publishers with different clocks on one topic? Split or fix the bag, or set time_source = \"receive\""
        )


def summary(c: IngestCounts) -> str:
    parts = [f"{c.n_rows} of {c.n_clock} clock rows kept"]
    for label, d in (("no matching reading", c.unmatched_wrench), ("outside joint span", c.joint_outside_span), ("in joint gap", c.joint_gap)):
        nz = {k: v for k, v in d.items() if v}
        if nz:
            parts.append(f"{label}: {nz}")
    nz = {k: v for k, v in c.joint_columns_dropped.items() if v}
    for n, text in ((c.clock_gaps, "about {} messages of the clock (first leg's wrench) missing"),
                    (c.duplicate_stamps, "{} duplicate clock stamps"),
                    (c.nan_readings, "{} rows with NaN readings"),
                    (c.nan_orientation, "{} rows without orientation (NaN)"),
                    (c.invalid_pose_samples, "{} invalid mocap samples ignored"),
                    (nz, "rows without a joint position (q_{{joint}}): {}"),
                    (c.imu_dropped, "{} rows without accelerometer gravity"),
                    (c.temperature_outside_span, "{} rows too far outside the temperature stream")):
        if n:
            parts.append(text.format(n))
    return "; ".join(parts)
