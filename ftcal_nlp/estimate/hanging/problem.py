"""One leg's hanging calibration problem: recordings, gravity axes, pairs, identifiability.

The gravity axis of recording ``j`` in ``ft_k`` is ``a_j = R_k,nom^T gravity_body_j``
(nominal rotation from ``robot.toml``, gravity direction from the manifest):
signs and pairs come from these vectors, never from leg names (the sample's
right-side transducers are turned 180 deg about z, so ``+x`` in B is ``-x`` in
their frame). The true direction is ``u_j = R_j a_j`` with a small unknown
rotation ``R_j`` per recording (hanging tilt and mounting error together).

Identifiability (report Sec. III-A.3): the torque ``r(phi) x m g u_j`` of one
pair leaves ``r`` unidentified along ``a_j``; a second, non-parallel pair fills
that line. A grid point of the CoM curve is reported in the components that
the gravity axes of the recordings with data near it pin down; the rest is
NaN and named in a warning. With a single axis more is lost than the report's
first-order analysis shows: each pair's common tilt trades against the force
offset across the axis, and (times the unidentified CoM along the axis)
against the torque offset, so those offsets are NaN too, and the pair's
common tilt is fixed at zero as a gauge (``pins_common_tilt``). A leg whose shaft never turns cannot separate the
offsets from the hanging tilt (report: "the std of tau_o over all samples"
needs ``r(phi)`` to move), and recordings without an opposite cannot separate
the offset from the weight: both raise :class:`HangingDataError`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ...core.data import DataFormatError, Recording, hanging_pairs, held_gravity_body
from ...core.robot import Robot
from ...core.solver import SolverError
from .binning import RecordingStats, compress_recording, periodic_grid

PRIOR_SD_M = 1.0  # weak prior on every CoM grid point (keeps the CoM QP strictly convex)
GAUGE_SD_M = 1e-6  # pins the CoM component along the gravity axis of a single pair

# A grid point counts as supported by a recording when at least this much
# interpolation weight (about one sample) falls on it.
_MIN_SUPPORT = 1.0
# Two axes at angle theta have singular values sqrt(1 +- cos theta), ratio tan(theta/2):
# axes closer than ~11 deg (ratio below 0.1) do not fill each other's null space.
_AXIS_RANK_TOL = 0.1
# A line direction with |component| above this makes that CoM component ambiguous.
_AMBIGUOUS_COMPONENT = 1e-3


class HangingDataError(DataFormatError):
    """Hanging recordings that cannot calibrate a leg; the message names leg and recordings."""


HangingSolveError = SolverError  # IPOPT or Clarabel failed on a hanging problem (the one solver error, solver.py)


@dataclass(frozen=True)
class LegProblem:
    """Everything the estimators need for leg ``leg``.

    ``a`` (J, 3): nominal unit gravity directions in ft_k; ``pairs``: index
    pairs (down, up) of opposite recordings; ``stats``: compressed recordings;
    ``grid`` (G,) rad; ``com_mask`` (G, 3): CoM components identified by the
    data; ``null_dir`` (3,) the unidentified line when all pairs share one axis;
    ``offset_mask`` (6,): offset components identified (torque offsets across a
    single pair's axis are not).
    """

    leg: str
    names: tuple[str, ...]
    a: np.ndarray
    pairs: tuple[tuple[int, int], ...]
    grid: np.ndarray
    stats: tuple[RecordingStats, ...]
    means: np.ndarray
    com_mask: np.ndarray
    null_dir: np.ndarray | None
    warnings: tuple[str, ...]
    offset_mask: np.ndarray

    @property
    def prior_precision(self) -> np.ndarray:
        """Precision (3, 3), 1/m^2, of the prior on each CoM grid point.

        A weak ``1/s_p^2`` (s_p = 1 m) keeps the QP strictly convex. With a
        single pair the CoM along the gravity axis ``a`` is seen only through
        products with the hanging tilt (``r_a(phi) m g a x tilt``): bilinear,
        weak, and confounded with the torque offset, so a free ``r_a`` lets the
        noise or the smoothness penalty decide it and biases the offsets and
        the tilts. It is fixed instead (gauge ``r . a = 0``, precision 1e12) and
        reported as NaN.
        """
        P = np.eye(3) / PRIOR_SD_M**2
        if self.null_dir is not None:
            P = P + np.outer(self.null_dir, self.null_dir) / GAUGE_SD_M**2
        return P

    @property
    def pins_common_tilt(self) -> bool:
        """True when each pair's common tilt ``(u_down + u_up)/2`` must be fixed to zero (a gauge).

        Only with a single gravity axis: the common tilt then trades exactly
        against the force offset across ``a`` (``f_down + f_up = m g (u_down +
        u_up) + 2 f_o``) and, through the unidentified CoM along ``a``, against the
        torque offset; free, IPOPT walks along that flat valley (tens of degrees
        on the sample's z pair). The offsets across ``a`` are reported as NaN.
        """
        return self.null_dir is not None

    def pair_bases(self) -> np.ndarray:
        """(P, 3, 2) bases of the planes perpendicular to each pair's down axis."""
        return np.stack([tangent_basis(self.a[d]) for d, _ in self.pairs])

    @property
    def n_grid(self) -> int:
        return len(self.grid)

    @property
    def n_rec(self) -> int:
        return len(self.names)

    @property
    def n_samples(self) -> int:
        return sum(s.n for s in self.stats)


def check_recordings(recordings: Sequence[Recording], robot: Robot) -> list[tuple[int, int]]:
    """Validate hanging recordings for ``robot``; return opposite pairs as index pairs."""
    recordings = list(recordings)
    if not recordings:
        raise HangingDataError("no hanging recordings: at least one opposite pair is needed (DATA_FORMAT.md section 4)")
    for r in recordings:
        src = r.path or r.name
        if r.kind != "hanging":
            raise HangingDataError(f"{src}: recording of kind '{r.kind}' given to the hanging calibration (expected 'hanging')")
        if r.gravity_body is None:
            raise HangingDataError(f"{src}: hanging recording without 'gravity_body'")
        missing = [k for k in robot.legs if k not in r.wrench or k not in r.phi]
        if missing:
            raise HangingDataError(f"{src}: no readings for leg(s) {missing}")
    try:
        pairs = hanging_pairs(recordings)
    except DataFormatError as exc:
        raise HangingDataError(f"hanging recordings {[r.name for r in recordings]}: {exc}") from exc
    index = {id(r): i for i, r in enumerate(recordings)}
    return [(index[id(d)], index[id(u)]) for d, u in pairs]


def tangent_basis(a: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3, 2) of the plane perpendicular to ``a``."""
    _, _, Vt = np.linalg.svd(np.asarray(a, float)[None, :])
    return Vt[1:].T


def _axis_name(n: np.ndarray) -> str:
    i = int(np.argmax(np.abs(n)))
    if abs(abs(n[i]) - 1.0) < _AMBIGUOUS_COMPONENT:
        return f"ft {'xyz'[i]}"
    return "ft direction [" + ", ".join(f"{v:.2f}" for v in n) + "]"


def _identified_components(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Components of r pinned down by torques with gravity along ``axes`` (m, 3).

    Returns (mask (3,), null line direction or None).
    """
    if len(axes) == 0:
        return np.zeros(3, bool), None
    s = np.linalg.svd(axes, compute_uv=False)
    rank = int(np.sum(s > _AXIS_RANK_TOL * s[0]))
    if rank >= 2:
        return np.ones(3, bool), None
    n = axes[0] / np.linalg.norm(axes[0])
    return np.abs(n) <= _AMBIGUOUS_COMPONENT, n


def build_leg_problem(leg: str, recordings: Sequence[Recording], robot: Robot, pairs: Sequence[tuple[int, int]], n_grid: int) -> LegProblem:
    """Compress the hanging recordings of ``leg`` and work out what they identify."""
    recordings = list(recordings)
    R_nom = robot.transducers[leg].given_rotation()
    a = np.stack([R_nom.T @ (gb / np.linalg.norm(gb)) for gb in map(held_gravity_body, recordings)])
    grid = periodic_grid(n_grid)
    stats = tuple(compress_recording(r.name, r.phi[leg], r.wrench[leg], n_grid) for r in recordings)
    means = np.stack([r.wrench[leg].mean(axis=0) for r in recordings])
    names = tuple(r.name for r in recordings)

    step = 2 * np.pi / n_grid
    spans = {s.name: s.phi_span for s in stats}
    if max(spans.values()) < step:
        raise HangingDataError(
            f"leg {leg}: the shaft never turns in the hanging recordings "
            + ", ".join(f"{k} (range {v:.3g} rad)" for k, v in spans.items())
            + f"; the leg must turn (at least {step:.3g} rad) to separate the offsets from the hanging tilt and to see the CoM curve"
        )

    warnings: list[str] = []
    pair_axes = np.stack([a[d] for d, _ in pairs])
    _, null = _identified_components(pair_axes)
    offset_mask = np.ones(6, bool)
    if null is not None:
        warnings.append(
            f"leg {leg}: CoM along {_axis_name(null)} unidentified: only one opposite pair "
            f"(gravity along {_axis_name(null)}); those components are NaN"
        )
        offset_mask[:3] = np.abs(null) >= 1.0 - _AMBIGUOUS_COMPONENT
        offset_mask[3:] = False
        comps = ", ".join([f"f{'xyz'[c]}" for c in range(3) if not offset_mask[c]] + ["tx", "ty", "tz"])
        warnings.append(
            f"leg {leg}: offset {comps} unidentified: with one pair the force offset across {_axis_name(null)} trades "
            "against the pair's common hanging tilt, and the torque offset against that tilt times the unidentified CoM; "
            "reported as NaN. The weight, the force offset along the axis and the other CoM components are fitted "
            "with the common tilt fixed at zero: they hold to first order in the tilt, which their standard errors do not cover"
        )
    mask = np.zeros((n_grid, 3), bool)
    supported = np.stack([s.support >= _MIN_SUPPORT for s in stats])  # (J, G)
    for g in range(n_grid):
        mask[g], _ = _identified_components(a[supported[:, g]])
    unsupported = ~supported.any(axis=0)
    if unsupported.any():
        warnings.append(
            f"leg {leg}: no data near {int(unsupported.sum())} of {n_grid} grid angles "
            f"(phi {_ranges(grid[unsupported], step)}); CoM reported as NaN there"
        )
    partial = supported.any(axis=0) & ~mask.all(axis=1)
    if null is None and partial.any():
        warnings.append(
            f"leg {leg}: at {int(partial.sum())} grid angles (phi {_ranges(grid[partial], step)}) only one gravity axis has data; "
            "the CoM component along it is NaN there"
        )
    return LegProblem(leg, names, a, tuple((d, u) for d, u in pairs), grid, stats, means, mask, null, tuple(warnings), offset_mask)


def _ranges(values: np.ndarray, step: float) -> str:
    """Compact text of grid angles, e.g. '0.00-1.05, 3.14 rad'."""
    out, start, prev = [], values[0], values[0]
    for v in values[1:]:
        if v - prev > 1.5 * step:
            out.append((start, prev))
            start = v
        prev = v
    out.append((start, prev))
    return ", ".join(f"{s:.2f}" if s == e else f"{s:.2f}-{e:.2f}" for s, e in out) + " rad"
