"""Physics plausibility of a dataset before fitting, and of the fitted rotations after.

Each check is a pure function on a :class:`~ftcal_nlp.core.data.Dataset` (or its parts)
and the :class:`~ftcal_nlp.core.robot.Robot`; it raises
:class:`~ftcal_nlp.core.data.DataFormatError` naming the file, the column or key, what
was seen and what was expected, so that a unit, sign or order convention that is
off stops the run instead of giving a wrong calibration (issue 14). Each
threshold below lies between what the sample, the simulator with every effect
injector (``sim/effects.py``, ``sim/variants.py``; seeds 0-3, tilted-board
poses) and what the faults produce; the unit checks have margins of 10x and
more, the sign and order checks the margins stated with them (1.5x and more).
All thresholds are logged at every run (:data:`THRESHOLDS`).

Hanging, opposite pair ``(+, -)`` with nominal gravity axis ``a = R_nom^T g_body+``
in ft_k (report eqs. 4-5; the tilt ``R_j`` is a few degrees)::

    d_k = (mean f+ - mean f-) / 2 ~= m_k g a,     o_k = (mean f+ + mean f-) / 2 ~= f_o,k

* magnitudes: ``sum_k |d_k|`` over ``m g`` lies in ``[LEG_SHARE_MIN, LEG_SHARE_MAX]``
  (legs weigh something, and less than the robot): forces in kN or ``mass_kg`` in
  grams give ~1e-3 of the share;
* lever arms: ``|mean_k r_k x a| = |torque half difference| / |d_k|``, the legs'
  mean CoM off their transducers (0.13 m on BigAnt), has a median over legs
  within [``LEVER_MIN_M``, ``LEVER_MAX_M``]: torques in N*mm or kN*m leave it;
* directions: the angle between ``d_k`` and ``a``: most legs of every pair beyond
  ``REVERSED_DEG`` means negated readings (of one pair only: its ``gravity_body``
  swapped); more than ``MAX_FAULTY_LEGS`` legs beyond ``LEG_DIRECTION_WARN_DEG``
  means robot.toml's rotations are in another frame. One leg off is a wiring
  fault left to the diagnosis, logged as a warning naming the leg;
* shaft angles: the leg's torque ``r_k(phi) x m_k g a + tau_o`` is 2 pi periodic
  in ``phi``; binned by ``phi mod 2 pi`` (``N_BINS`` bins) its within-bin sum of
  squares is ``DEGREES_RATIO`` times larger than when binned by
  ``phi pi / 180`` only when the column holds degrees. Any recording's 99th
  percentile of ``|d phi / dt|`` above ``MAX_PHI_RATE_RAD_S`` is degrees too.

Standing (exact balance, ``DATA_FORMAT.md`` section 1): the readings less offsets,
summed in B with the nominal rotations, are ``S_B = R_WB^T e_z (m g - sum_k m_k g)``:

* tilt: the angle between ``S_B`` and the quaternion's up axis ``R_WB^T e_z``
  is below ``TILT_DEG`` in ``TILT_PERCENTILE`` % of the samples (mounting errors
  are a few degrees, the tilt of the board enters both; one leg's wiring fault
  reaches 18 deg); if not, the error says which reading of the columns (x, y,
  z, w order, the conjugate, another order) would agree; when none agrees it is
  no quaternion convention but a fault in the readings (a fully flipped channel
  of one leg reaches 42 deg) or the frames: a warning, and the post-fit rotation
  bound and the diagnosis' per-leg checks take it from there. On the still rows (no
  shaft moving: no leg inertia) the 99th percentile may exceed ``TILT_MIN_DEG``
  (a wiring fault's board poses reach 60 deg) only if no other reading of the
  columns comes ``QUAT_ORDER_RATIO`` times closer: orders that agree on level
  poses at a heading near 180 deg (the sample's) differ on the tilted ones;
* magnitude: median ``|S_B|`` over ``m g - sum_k m_k g`` lies within a factor
  ``BODY_WEIGHT_FACTOR``;
* torque axes: on the rows where no shaft moves (``STILL_RAD_S``), the moments
  ``sum_k (R_k tau_k + p_k x R_k f_k)`` balance ``c x S_B`` (``c`` the body CoM,
  fitted by least squares). No other order or sign of the torque columns (the
  47 other signed permutations, the same for every leg) may leave less than
  ``TORQUE_MAP_RATIO`` times the RMS residual of the columns as given: negated
  torques give 0.16x on the sample, a single column's sign flipped (tx or tz,
  which standing poses excite least) 0.58x; the best alternative of any simulator
  effect (three seeds, tilted-board poses) is >= 1.04x, the wiring variants the
  nearest.

After fitting, every rotation ``R_k`` lies within ``ROTATION_BOUND_DEG`` of its
design rotation (angle of ``R_k R_nom,k^T``); when more than ``MAX_FAULTY_LEGS``
legs do not, the message names the convention that is probably off. One leg
beyond the bound is that leg's fault (wiring, a wrong ``rotation`` in robot.toml:
the simulator's ``leg_axes_swapped`` and ``leg_axis_flipped`` give 50-120 deg),
logged as a warning and recorded in the run's notes for the diagnosis to place.
The fitted positions ``p'_k`` relative to their mean against the design
positions relative to theirs (the unknown CoM cancels) beyond
``TRANSLATION_BOUND_M`` are a warning only: the columns of two legs exchanged
leave it, but so does one leg's wiring fault, through the balance, on every leg
(the simulator's variants reach 180 mm).

Issue 24 adds, for every recording: column ``t`` in seconds (median sampling interval at most
``MAX_SAMPLE_INTERVAL_S``: a clock in ms at 500 Hz or slower leaves it); for standing recordings the
readings' share of the body weight along the quaternion's up axis within ``LOAD_SHARE`` (legs that bear
weight missing from robot.toml); for a calibration dataset, each recording listed once
(:func:`check_distinct_recordings`) and no channel held (:func:`sensor_faults`: ``STUCK_RUN`` identical
consecutive samples, which sensor noise never gives; dead = every channel of the leg at 0, saturated = held
at the channel's extreme, else stuck; :func:`screen_sensor_faults` refuses a leg held in every calibration
recording or a recording more than ``MAX_FAULT_SHARE`` held, and leaves the other held rows out);
after the fit, a standing residual above ``RESIDUAL_NOISE_FACTOR`` times the per-sample noise of the summed
readings is a warning (:func:`residual_note`). ``correct`` runs the checks that apply to a later recording
against the calibration it applies (:func:`check_recording_to_correct`: clock, shaft rate, and on the
ground the readings' sign and unit and the quaternion order with the calibration's offsets and rotations,
:func:`check_on_ground`), validates that calibration (:func:`check_calibration`) and flags held channels
rather than refusing them.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Mapping
from typing import Protocol
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from .calibration import ROTATION_TOL   # a stored rotation's tolerance: the one reader's
from .data import check_distinct_recordings, Dataset, DataFormatError, Recording, hanging_pairs, held_gravity_body
from .errors import MisSignedChannel
from .geometry import quat_to_rotation, rotation_to_rotvec, skew
from .robot import Robot

log = logging.getLogger(__name__)

LEG_SHARE_MIN = 0.01
LEG_SHARE_MAX = 1.0
REVERSED_DEG = 90.0
LEVER_MIN_M = 0.002
LEVER_MAX_M = 3.0
TRANSLATION_BOUND_M = 0.05
LEG_DIRECTION_WARN_DEG = 45.0
N_BINS = 36
DEGREES_RATIO = 4.0
MIN_PERIODICITY_SAMPLES = 4 * N_BINS
MAX_PHI_RATE_RAD_S = 50.0
TILT_DEG = 30.0
TILT_PERCENTILE = 90
TILT_MIN_DEG = 10.0
QUAT_ORDER_RATIO = 0.5
TORQUE_MAP_RATIO = 0.7
STILL_RAD_S = 0.05
STILL_STRIDE = 5
BODY_WEIGHT_FACTOR = 3.0
# standing: the summed readings along the up axis over the body weight; every simulator effect keeps 0.95-1.01,
# two legs of six left out of robot.toml give 0.58 (0.27-0.80), one ~0.83
LOAD_SHARE = (0.8, 1.25)
ROTATION_BOUND_DEG = 20.0
# One leg off is a wiring fault of that leg (the diagnosis places it); more legs share a convention.
MAX_FAULTY_LEGS = 1

THRESHOLDS = (
    f"leg weights {LEG_SHARE_MIN:.0%}..{LEG_SHARE_MAX:.0%} of m g, lever arms {LEVER_MIN_M:g}..{LEVER_MAX_M:g} m, hanging force direction < {REVERSED_DEG:.0f} deg, "
    f"shaft-angle periodicity ratio < {DEGREES_RATIO:g} and rate < {MAX_PHI_RATE_RAD_S:g} rad/s, standing tilt < {TILT_DEG:.0f} deg (p{TILT_PERCENTILE}; "
    f"p99 of still rows < {TILT_MIN_DEG:g} deg unless another quaternion order is {QUAT_ORDER_RATIO:g}x closer), "
    f"moment residual of any other torque order or sign > {TORQUE_MAP_RATIO:g}x as given, "
    f"body weight within {BODY_WEIGHT_FACTOR:g}x (standing, along the up axis: {LOAD_SHARE[0]:g}..{LOAD_SHARE[1]:g}x), fitted rotations < {ROTATION_BOUND_DEG:.0f} deg "
    f"from the design (relative translations < {TRANSLATION_BOUND_M * 1e3:.0f} mm: a warning)"
)


def _src(rec: Readings) -> str:
    return str(rec.path or rec.name)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between the vectors along the last axis (degrees)."""
    c = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


@dataclass(frozen=True)
class PairForces:
    """Means of one opposite hanging pair, per leg in ft_k: ``weight`` (K, 3) ``d_k`` (N); ``offset`` (K, 6)
    the mean wrench ``o_k`` (N, N*m; the offsets when the shafts turn full circles); ``axis`` (K, 3) the
    nominal unit gravity axis ``a``; ``torque`` (K, 3) the half difference of the mean torques (N*m)."""

    plus: Recording
    minus: Recording
    weight: np.ndarray
    offset: np.ndarray
    axis: np.ndarray
    torque: np.ndarray

    @property
    def where(self) -> str:
        return f"{_src(self.plus)} / {_src(self.minus)}"


def pair_forces(ds: Dataset) -> list[PairForces]:
    """Half difference and mean of the mean forces of every opposite hanging pair (module docstring)."""
    legs, out = ds.robot.legs, []
    R_nom = ds.robot.nominal_rotations()
    for p, m in hanging_pairs(ds.hanging):
        wp = np.stack([p.wrench[k].mean(axis=0) for k in legs])
        wm = np.stack([m.wrench[k].mean(axis=0) for k in legs])
        gb = held_gravity_body(p)
        axis = np.einsum("kji,j->ki", R_nom, gb / np.linalg.norm(gb))
        out.append(PairForces(p, m, (wp - wm)[:, :3] / 2, (wp + wm) / 2, axis, (wp - wm)[:, 3:] / 2))
    return out


def check_leg_weights(pairs: list[PairForces], robot: Robot, robot_source: str) -> np.ndarray:
    """Leg weights ``|d_k|`` (K,) N, averaged over the pairs, against the robot's weight (catches kN and grams)."""
    w = np.mean([np.linalg.norm(p.weight, axis=1) for p in pairs], axis=0)
    share = float(w.sum() / robot.weight_N)
    if not LEG_SHARE_MIN <= share <= LEG_SHARE_MAX:
        cols = ", ".join(f"{k}_fx..{k}_fz" for k in robot.legs[:2]) + ", ..."
        hint = ("are the force columns in kN, or mass_kg in grams?" if share < LEG_SHARE_MIN
                else "are the force columns in mN (or lbf), or mass_kg too small?")
        raise DataFormatError(
            f"{pairs[0].where}: the hanging leg weights (half the difference of opposite recordings, columns {cols}) sum to "
            f"{w.sum():.4g} N, {share:.3g} of the robot's weight {robot.weight_N:.4g} N (key mass_kg = {robot.mass_kg:g} in "
            f"{robot_source}); expected between {LEG_SHARE_MIN:g} and {LEG_SHARE_MAX:g} of it: {hint}"
        )
    return w


def check_lever_arms(pairs: list[PairForces]) -> None:
    """Torque over force of the hanging legs, ``|mean r_k x a|``, within [``LEVER_MIN_M``, ``LEVER_MAX_M``] (catches
    torques in N*mm or kN*m while the forces are in N)."""
    lever = np.max([np.linalg.norm(p.torque, axis=1) / np.maximum(np.linalg.norm(p.weight, axis=1), 1e-12) for p in pairs], axis=0)
    med = float(np.median(lever))
    if not LEVER_MIN_M <= med <= LEVER_MAX_M:
        hint = "are the torque columns in kN*m (or the forces in mN)?" if med < LEVER_MIN_M else "are the torque columns in N*mm?"
        raise DataFormatError(
            f"{pairs[0].where}: the hanging torques over the leg weights (columns {{leg}}_tx..{{leg}}_tz over {{leg}}_fx..{{leg}}_fz) "
            f"put the legs' centres of mass a median {med:.3g} m from their transducers; expected {LEVER_MIN_M:g} to "
            f"{LEVER_MAX_M:g} m (torques in N*m): {hint}"
        )


def check_force_directions(pairs: list[PairForces], robot: Robot, robot_source: str = "robot.toml") -> None:
    """Hanging force ``d_k`` along the nominal gravity axis (catches negated readings, a swapped ``gravity_body``,
    rotations of robot.toml in another frame); one leg off is logged for the diagnosis (module docstring)."""
    reversed_pairs: list[tuple[PairForces, np.ndarray]] = []
    faulty: dict[str, list[str]] = {}
    for p in pairs:
        ang = angle_deg(p.weight, p.axis)
        rev = ang > REVERSED_DEG
        if rev.sum() * 2 > len(ang) and np.median(ang) > 180 - LEG_DIRECTION_WARN_DEG:  # turned round, not sideways
            reversed_pairs.append((p, ang))
            continue
        for k, a in zip(robot.legs, ang):
            if a > LEG_DIRECTION_WARN_DEG:
                faulty.setdefault(k, []).append(f"{a:.0f} deg in {p.where}")
    if reversed_pairs:
        desc = "; ".join(f"{p.where}: median {np.median(a):.0f} deg" for p, a in reversed_pairs)
        if len(reversed_pairs) == len(pairs):
            raise DataFormatError(
                f"hanging force readings ({{leg}}_fx..{{leg}}_fz) point against gravity_body in every pair ({desc}); expected "
                f"within {REVERSED_DEG:.0f} deg of the nominal gravity axis: a reading is the wrench the leg exerts on the "
                "transducer (DATA_FORMAT.md section 1); are the readings negated (sign convention reversed)?"
            )
        raise DataFormatError(
            f"hanging force readings point against gravity_body ({desc}), while the other pairs agree; expected within "
            f"{REVERSED_DEG:.0f} deg: are the gravity_body keys of these two recordings in the manifest swapped?"
        )
    if len(faulty) > MAX_FAULTY_LEGS:
        listing = "; ".join(f"{k} ({', '.join(v)})" for k, v in faulty.items())
        raise DataFormatError(
            f"hanging force readings of legs {listing} are off the nominal gravity axis R_nom^T gravity_body; expected within "
            f"{LEG_DIRECTION_WARN_DEG:.0f} deg for all but {MAX_FAULTY_LEGS} leg: are the [transducers.*] rotation keys of "
            f"{robot_source} in another frame (expected ft_k -> B), or the columns {{leg}}_fx, {{leg}}_fy, {{leg}}_fz in another order?"
        )
    for k, v in faulty.items():
        log.warning("leg %s: hanging force (columns %s_fx..%s_fz) off the nominal gravity axis: %s (other legs agree; "
                    "expected within %.0f deg): a mis-signed channel or a wrong rotation in robot.toml for this leg?",
                    k, k, k, ", ".join(v), LEG_DIRECTION_WARN_DEG)


def _within_bin_ss(angle: np.ndarray, y: np.ndarray) -> float:
    """Sum of squares of ``y`` (N, d) about its mean in each of ``N_BINS`` bins of ``angle mod 2 pi``."""
    b = np.floor(np.mod(angle, 2 * np.pi) / (2 * np.pi) * N_BINS).astype(int).clip(0, N_BINS - 1)
    n = np.bincount(b, minlength=N_BINS).astype(float)
    ss = 0.0
    for j in range(y.shape[1]):
        s1 = np.bincount(b, y[:, j], minlength=N_BINS)
        s2 = np.bincount(b, y[:, j] ** 2, minlength=N_BINS)
        ss += float(np.sum(s2[n > 0] - s1[n > 0] ** 2 / n[n > 0]))
    return ss


def degrees_ratio(rec: Recording, legs: tuple[str, ...]) -> float:
    """Within-bin torque sum of squares binned by ``phi`` over binned by ``phi pi/180`` (module docstring)."""
    ss_rad = ss_deg = 0.0
    for k in legs:
        tau = rec.wrench[k][:, 3:] - rec.wrench[k][:, 3:].mean(axis=0)
        ss_rad += _within_bin_ss(rec.phi[k], tau)
        ss_deg += _within_bin_ss(np.radians(rec.phi[k]), tau)
    return ss_rad / ss_deg if ss_deg > 0 else 1.0


def check_shaft_angles(ds: Dataset) -> None:
    """Shaft angles in radians: torque periodicity in hanging, and a plausible rate everywhere (catches degrees)."""
    legs = ds.robot.legs
    for rec in ds.recordings:
        check_clock(rec)
        _check_shaft_rate(rec, legs)
        if rec.kind == "hanging" and rec.n >= MIN_PERIODICITY_SAMPLES:
            ratio = degrees_ratio(rec, legs)
            if ratio > DEGREES_RATIO:
                raise DataFormatError(
                    f"{_src(rec)}: columns {{leg}}_phi: the hanging torques repeat every 360 units of phi, not every 2 pi "
                    f"(within-bin scatter {ratio:.3g}x larger binned by phi as radians than as degrees; expected below "
                    f"{DEGREES_RATIO:g}); expected radians: are the shaft angles in degrees?"
                )


def _check_shaft_rate(rec: Recording, legs: tuple[str, ...], stride: int = 1) -> None:
    """The 99th percentile of every shaft's rate below ``MAX_PHI_RATE_RAD_S`` (degrees turn 57x faster); with
    ``stride`` > 1 from every ``stride``-th pair of consecutive samples (a long recording to correct)."""
    if rec.n < 2:
        return
    i = np.arange(0, rec.n - 1, max(1, int(stride)))
    phi = np.stack([rec.phi[k] for k in legs], axis=1)
    rate = np.abs(phi[i + 1] - phi[i]) / (rec.t[i + 1] - rec.t[i])[:, None]
    r99 = np.percentile(rate, 99, axis=0)
    if r99.max() > MAX_PHI_RATE_RAD_S:
        k = legs[int(np.argmax(r99))]
        raise DataFormatError(
            f"{_src(rec)}: column {k}_phi turns at {r99.max():.4g} rad/s (99th percentile); expected radians, below "
            f"{MAX_PHI_RATE_RAD_S:g} rad/s for a leg: is it in degrees?"
        )


def _up_angles(S_B: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Angle (deg) between the readings' up direction ``S_B`` (N, 3) and the quaternions' ``R_WB^T e_z``."""
    up = quat_to_rotation(quat)[:, 2, :]
    return angle_deg(S_B, up)


def check_standing(ds: Dataset, offsets: np.ndarray, leg_weights: np.ndarray) -> None:
    """Readings' gravity vs. the quaternion's tilt, and the body weight, in every standing recording.

    ``offsets`` (K, 6) offsets in ft_k and ``leg_weights`` (K,) N: from the hanging pairs or an
    earlier calibration.
    """
    for rec in ds.standing:
        check_on_ground(rec, ds.robot, offsets, leg_weights)


def check_on_ground(rec: Recording, robot: Robot, offsets: np.ndarray, leg_weights: np.ndarray, *,
                    whose: str = "the hanging") -> None:
    """The standing checks of one recording of the robot on the ground (standing or walking): the readings less
    ``offsets`` summed in B with ``robot``'s rotations (the design's, or a calibration's: ``correct``) against the
    body weight (sign and unit) and the quaternion's up axis (order), and the torque columns' order and sign.
    ``whose``: where the offsets and leg weights come from, for the message."""
    legs = robot.legs
    src = _src(rec)
    R = robot.nominal_rotations()
    offsets = np.asarray(offsets, float)
    body = robot.weight_N - float(np.sum(leg_weights))
    q = rec.quat
    if q is None:
        raise DataFormatError(f"{src}: no columns qw, qx, qy, qz; a recording on the ground needs the motion-capture orientation of B")
    ok = np.all(np.isfinite(q), axis=1)
    if not ok.any():
        raise DataFormatError(f"{src}: columns qw, qx, qy, qz hold no finite row; a {rec.kind} recording needs the "
                              "motion-capture orientation of B (empty only where tracking was lost)")
    F = np.stack([rec.wrench[k][ok, :3] for k in legs], axis=1) - offsets[:, :3]  # (N, K, 3)
    S_B = np.einsum("kij,nkj->ni", R, F)
    up = quat_to_rotation(q[ok])[:, 2, :]
    # the signed share along the quaternion's up axis: -1 for negated readings, ~1e-3 for kN, +1 as expected
    along = float(np.median(np.einsum("ni,ni->n", S_B, up)) / body) if body > 0 else np.inf
    ratio = float(np.median(np.linalg.norm(S_B, axis=1)) / body) if body > 0 else np.inf
    if not 1 / BODY_WEIGHT_FACTOR <= ratio <= BODY_WEIGHT_FACTOR:
        raise DataFormatError(
            f"{src}: {rec.kind}, the readings less {whose} offsets (columns {{leg}}_fx..{{leg}}_fz) sum to a median "
            f"{ratio * body:.4g} N; expected about the weight of the body without legs, {body:.4g} N (mass_kg = "
            f"{robot.mass_kg:g} less {whose} leg weights), within a factor {BODY_WEIGHT_FACTOR:g}: are the forces, or "
            "mass_kg, in another unit?"
        )
    if not 1 / BODY_WEIGHT_FACTOR <= along <= BODY_WEIGHT_FACTOR:
        if _quaternion_fixes_it(S_B, q[ok], body):
            check_quaternion(rec, S_B, ok)  # the quaternion, not the readings: names the reading of the columns
        if along < -1 / BODY_WEIGHT_FACTOR:
            raise DataFormatError(
                f"{src}: {rec.kind}, the readings less {whose} offsets (columns {{leg}}_fx..{{leg}}_fz) push the body down "
                f"(median {along:.2f} of the body weight along the quaternion's up axis); expected about +1 for a robot on "
                "the ground: are the readings negated (their sign convention reversed)?"
            )
        raise DataFormatError(
            f"{src}: {rec.kind}, the readings less {whose} offsets (columns {{leg}}_fx..{{leg}}_fz) carry a median "
            f"{along * body:.4g} N along the quaternion's up axis; expected the weight of the body without legs, "
            f"{body:.4g} N (mass_kg = {robot.mass_kg:g} less {whose} leg weights), within a factor {BODY_WEIGHT_FACTOR:g} "
            "for a robot on the ground: are the forces, or mass_kg, in another unit?"
        )
    if rec.kind == "standing" and not LOAD_SHARE[0] <= along <= LOAD_SHARE[1]:
        a = np.einsum("ni,ni->n", S_B, up) / body
        lo, hi = np.percentile(a, [10, 90])
        fix = leg_sign_fixes_it(R, F, S_B, up, body, legs)
        if fix is not None:
            leg, column, now = fix
            was = along
            raise MisSignedChannel(
                f"{src}: standing, the readings less {whose} offsets carry a median {was:.2f} of the weight of the body "
                f"without legs ({body:.4g} N) along the quaternion's up axis; expected 1 within {LOAD_SHARE[0]:g}.."
                f"{LOAD_SHARE[1]:g}, and {now:.2f} with the sign of column {column} (the axis of leg {leg} nearest the up "
                f"axis) reversed: is {column} mis-signed, or {leg}'s rotation in robot.toml wrong?", leg=leg, column=column)
        raise DataFormatError(
            f"{src}: standing, the readings less {whose} offsets (columns {{leg}}_fx..{{leg}}_fz) carry a median {along:.2f} "
            f"({lo:.2f}..{hi:.2f}, 10th..90th percentile) of the weight of the body without legs ({body:.4g} N) along the "
            f"quaternion's up axis; expected 1 within {LOAD_SHARE[0]:g}..{LOAD_SHARE[1]:g} (the simulator's effects stay within "
            f"0.95..1.01): is a leg that bears weight missing from robot.toml (legs = {list(legs)}), or mass_kg = "
            f"{robot.mass_kg:g} off?"
        )
    check_torque_axes(rec, robot, offsets)
    check_quaternion(rec, S_B, ok)


def leg_sign_fixes_it(R: np.ndarray, F: np.ndarray, S_B: np.ndarray, up: np.ndarray, body: float, legs) -> tuple[str, str, float] | None:
    """The one leg whose force axis nearest the up axis, sign reversed, brings the standing load share into
    ``LOAD_SHARE`` (closest to 1 of those that do), or None: ``(leg, column, share with it reversed)``. ``R``
    (K, 3, 3) sensor to B, ``F`` (N, K, 3) the readings less offsets, ``S_B`` (N, 3) their sum in B, ``up`` (N, 3)
    in B. A mis-signed channel of one leg makes that leg pull the body down by what it carries (a sum 0.64 of the
    body weight, 1.00 with the channel's sign reversed)."""
    best = None
    for i, k in enumerate(legs):
        axis = int(np.argmax(np.abs(np.median(up @ R[i], axis=0))))   # up in the leg's sensor frame: R_k^T up
        S_f = S_B - 2.0 * R[i][:, axis][None, :] * F[:, i, axis][:, None]
        a = float(np.median(np.einsum("ni,ni->n", S_f, up)) / body)
        if LOAD_SHARE[0] <= a <= LOAD_SHARE[1] and (best is None or abs(a - 1) < abs(best[2] - 1)):
            best = (k, f"{k}_f{'xyz'[axis]}", a)
    return best


def _quaternion_fixes_it(S_B: np.ndarray, q: np.ndarray, body: float) -> bool:
    """One of the usual misreadings of the quaternion columns (x, y, z, w order; the conjugate) puts the readings up
    with the body's weight: then the quaternion is off, not the readings. The other orders are not asked: some turn
    any up axis over, and a reversed sign or unit is the likelier fault."""
    for v in list(quaternion_readings().values())[:2]:
        qq = reread_quaternion(q, v)
        share = float(np.median(np.einsum("ni,ni->n", S_B, quat_to_rotation(qq)[:, 2, :])) / body)
        if 1 / BODY_WEIGHT_FACTOR <= share <= BODY_WEIGHT_FACTOR:
            return True
    return False


def reread_quaternion(q: np.ndarray, reading: list[int] | np.ndarray) -> np.ndarray:
    """Quaternions ``q`` (N, 4) read another way: an order of the columns (index list) or signs (the conjugate), as
    :func:`quaternion_readings` gives them."""
    return q[:, reading] if isinstance(reading, list) else q * reading


def quaternion_readings() -> dict[str, list[int] | np.ndarray]:
    """Other readings of the four columns qw..qz: every other order (as index lists) and the conjugate (signs)."""
    names = ("qw", "qx", "qy", "qz")
    out: dict[str, list[int] | np.ndarray] = {
        "the quaternion columns hold x, y, z, w (not w, x, y, z)": [3, 0, 1, 2],
        "the quaternion maps world to body (its conjugate is expected)": np.array([1.0, -1, -1, -1]),
    }
    for perm in itertools.permutations(range(4)):
        if list(perm) not in ([0, 1, 2, 3], [3, 0, 1, 2]):
            out[f"the columns are taken in the order {', '.join(names[i] for i in perm)}"] = list(perm)
    return out


def _still_rows(t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Rows (N,) whose shafts did not move since the previous row (no leg inertia in the readings)."""
    return np.r_[False, np.all(np.abs(np.diff(phi, axis=0)) <= STILL_RAD_S * np.diff(t)[:, None], axis=1)]


def check_quaternion(rec: Recording, S_B: np.ndarray, ok: np.ndarray) -> None:
    """The quaternion's up axis against the readings' (``S_B`` (N, 3) on the rows ``ok`` with an orientation):
    beyond ``TILT_DEG`` in ``TILT_PERCENTILE`` % of the samples, or, on the still rows, beyond ``TILT_MIN_DEG`` at
    the 99th percentile while another reading of the columns is ``QUAT_ORDER_RATIO`` times closer (module docstring)."""
    assert rec.quat is not None  # both callers checked it (a recording on the ground has qw..qz)
    q = rec.quat[ok]
    phi = rec.phi_array()[ok]
    still = _still_rows(rec.t[ok], phi)

    def stats(qq: np.ndarray) -> tuple[float, float]:
        a = _up_angles(S_B, qq)
        return float(np.percentile(a, TILT_PERCENTILE)), float(np.percentile(a[still], 99)) if still.sum() > 10 else 0.0

    given, given99 = stats(q)
    if given <= TILT_DEG and given99 <= TILT_MIN_DEG:
        return
    alt = {k: stats(reread_quaternion(q, v)) for k, v in quaternion_readings().items()}
    best = min(alt, key=lambda k: alt[k][1])
    if given > TILT_DEG:
        best = min(alt, key=lambda k: alt[k][0])
        if alt[best][0] > TILT_DEG:
            # No other reading of the columns fits either: not a quaternion convention but a fault in the readings
            # (one leg's channel mis-signed or its axes swapped tilts the summed force) or in the frames; the
            # post-fit rotation bound catches frames, the diagnosis' per-leg checks place a leg's fault.
            log.warning("%s: columns qw, qx, qy, qz: the body's up direction from the quaternion is %.0f deg (%sth percentile) from "
                        "the summed force readings and no other order of the columns agrees: a fault in the readings or the "
                        "frames; continuing (the fitted rotations are bounded after the fit, the diagnosis checks each leg)",
                        _src(rec), given, TILT_PERCENTILE)
            return
        hint = f"they agree within {alt[best][0]:.0f} deg if {best}"
        raise DataFormatError(
            f"{_src(rec)}: columns qw, qx, qy, qz: the body's up direction from the quaternion is {given:.0f} deg "
            f"({TILT_PERCENTILE}th percentile of the samples) from the direction of the summed force readings; expected within "
            f"{TILT_DEG:.0f} deg (qw..qz map B to the world, DATA_FORMAT.md section 3): {hint}"
        )
    if alt[best][1] < QUAT_ORDER_RATIO * given99:
        raise DataFormatError(
            f"{_src(rec)}: columns qw, qx, qy, qz: on the still rows the body's up direction from the quaternion is up to "
            f"{given99:.0f} deg (99th percentile) from the summed force readings', {alt[best][1]:.0f} deg if {best}; expected "
            f"the columns as given to agree best (qw..qz map B to the world, DATA_FORMAT.md section 3)"
        )


def moment_residuals(rec: Recording, robot: Robot, offsets: np.ndarray, torque_maps: list[np.ndarray]) -> np.ndarray:
    """RMS moment residual (N*m) of the still rows of a standing recording for each ``P`` of ``torque_maps``:
    ``sum_k (R_k P tau_k + p_k x R_k f_k)`` (nominal poses, readings less ``offsets``, ``P`` applied to the torque
    columns) less ``c x sum_k R_k f_k`` with the body CoM ``c`` fitted by least squares. The sum is linear in ``P``
    and the fit's projector is the same for every ``P``: both are formed once (NaN with too few rows)."""
    legs = robot.legs
    still = _still_rows(rec.t, rec.phi_array(legs))
    W = rec.wrench_array(legs)[still][::STILL_STRIDE] - offsets
    R = robot.nominal_rotations()
    if 3 * len(W) < 6:
        return np.full(len(torque_maps), np.nan)
    F = np.einsum("kij,nkj->nki", R, W[:, :, :3])
    G = np.einsum("kia,nkb->niab", R, W[:, :, 3:])                      # sum_k R_k P tau_k = G : P
    C = np.cross(robot.nominal_positions()[None], F).sum(axis=1)        # (N, 3)
    Q, _ = np.linalg.qr(-skew(F.sum(axis=1)).reshape(-1, 3))            # c x S = -[S]_x c
    out = []
    for P in torque_maps:
        M = (np.einsum("niab,ab->ni", G, P) + C).reshape(-1)
        out.append(float(np.sqrt(np.mean((M - Q @ (Q.T @ M)) ** 2))))
    return np.asarray(out)


def signed_permutations() -> list[np.ndarray]:
    """The 47 signed permutation matrices other than the identity (torque columns reordered or mis-signed)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            P = np.zeros((3, 3))
            P[range(3), perm] = signs
            if not np.allclose(P, np.eye(3)):
                out.append(P)
    return out


def _describe_map(P: np.ndarray) -> str:
    names = ("tx", "ty", "tz")
    return ", ".join(f"{n} <- {'-' if P[i].sum() < 0 else ''}{names[int(np.argmax(np.abs(P[i])))]}" for i, n in enumerate(names))


def check_torque_axes(rec: Recording, robot: Robot, offsets: np.ndarray) -> None:
    """Standing moment balance with the torque columns as given against every other order and sign (module docstring)."""
    maps = signed_permutations()
    res = moment_residuals(rec, robot, offsets, [np.eye(3)] + maps)
    given = res[0]
    if not np.isfinite(given):
        return
    i = int(np.argmin(res[1:]))
    best, P = res[1 + i], maps[i]
    if best < TORQUE_MAP_RATIO * given:
        what = ("are the torque readings negated (their sign convention reversed)?" if np.allclose(P, -np.eye(3))
                else f"are the torque columns in another order or sign ({_describe_map(P)} balances)?")
        raise DataFormatError(
            f"{_src(rec)}: columns {{leg}}_tx..{{leg}}_tz: the standing moment balance about the body's CoM leaves {given:.3g} N*m "
            f"RMS with the torques as given and {best:.3g} N*m with {_describe_map(P)}; expected the torques as given to "
            f"balance best (no other order or sign below {TORQUE_MAP_RATIO:g}x): {what}"
        )


def check_hanging_span(pairs: list[PairForces]) -> None:
    """The standing fit needs every offset and leg CoM: two non-parallel hanging pairs (``DATA_FORMAT.md`` section 4)."""
    g = np.stack([gb / np.linalg.norm(gb) for gb in (held_gravity_body(p.plus) for p in pairs)])
    if np.linalg.matrix_rank(g, tol=0.2) < 2:
        names = "; ".join(p.where for p in pairs)
        raise DataFormatError(
            f"hanging recordings ({names}): gravity_body of every pair is along {np.round(g[0], 3).tolist()}; the torque "
            "offsets and the leg CoM along that axis are then unknown and the standing fit needs them: expected at least "
            "two opposite pairs with non-parallel gravity_body (DATA_FORMAT.md section 4)"
        )


def check_dataset(ds: Dataset, prior=None) -> None:
    """Every plausibility check before fitting (module docstring); ``prior`` an earlier
    :class:`~ftcal_nlp.core.calibration.Calibration` when only the offsets are re-estimated (no hanging)."""
    log.info("plausibility checks: %s", THRESHOLDS)
    robot_source = str(ds.robot_path or "robot.toml")
    check_distinct_recordings(ds)
    check_shaft_angles(ds)
    if prior is None:
        if not ds.hanging:
            raise DataFormatError(f"{ds.manifest or 'dataset'}: no hanging recording; expected at least two opposite pairs "
                                  "(DATA_FORMAT.md section 4)")
        pairs = pair_forces(ds)
        weights = check_leg_weights(pairs, ds.robot, robot_source)
        check_lever_arms(pairs)
        check_force_directions(pairs, ds.robot, robot_source)
        check_hanging_span(pairs)
        offsets = np.mean([p.offset for p in pairs], axis=0)
    else:
        missing = [k for k in ds.robot.legs if k not in prior.legs]
        if missing:
            raise DataFormatError(f"the earlier calibration ([offsets_only] calibration): no calibration for leg(s) {missing} of "
                                  f"{robot_source}; expected every leg of the robot")
        offsets, weights, _, _ = prior.stacked(ds.robot.legs)
        if not (np.all(np.isfinite(offsets)) and np.all(np.isfinite(weights))):
            raise DataFormatError("the earlier calibration ([offsets_only] calibration): offsets or leg weights are null; "
                                  "expected a complete calibration (from two or more hanging pairs)")
    check_standing(ds, offsets, weights)


def rotation_errors_deg(cal, robot: Robot) -> np.ndarray:
    """Angle (deg) of ``R_k R_nom,k^T`` per leg of ``robot``."""
    R = np.stack([cal.legs[k].rotation_to_body for k in robot.legs])
    return np.degrees(np.linalg.norm(rotation_to_rotvec(R @ np.swapaxes(robot.nominal_rotations(), 1, 2)), axis=1))


def check_rotations(cal, robot: Robot, where: str) -> list[str]:
    """The fitted rotations against the design (module docstring); returns warnings for single legs beyond the bound."""
    err = rotation_errors_deg(cal, robot)
    off = err > ROTATION_BOUND_DEG
    if not off.any():
        return []
    listing = ", ".join(f"{k} {e:.0f} deg" for k, e, o in zip(robot.legs, err, off) if o)
    if off.sum() > MAX_FAULTY_LEGS:
        R = np.stack([cal.legs[k].rotation_to_body for k in robot.legs])
        transposed = np.degrees(np.linalg.norm(rotation_to_rotvec(R @ robot.nominal_rotations()), axis=1))
        if np.all(transposed <= ROTATION_BOUND_DEG):
            hint = "the fit agrees with the transposed design rotations: are robot.toml's rotations B -> ft_k instead of ft_k -> B?"
        elif np.median(err[off]) > 120:
            hint = ("a half-turn: are the readings negated (sign convention), or the quaternion columns in x, y, z, w order, "
                    "or the quaternion world -> body?")
        else:
            hint = ("is the quaternion world -> body instead of body -> world, or are robot.toml's [transducers.*] rotation "
                    "keys in another frame (expected ft_k -> B)?")
        raise DataFormatError(
            f"{where}: the fitted transducer rotations are far from the design rotations of robot.toml ({listing}); "
            f"expected within {ROTATION_BOUND_DEG:.0f} deg: a convention is probably off: {hint}"
        )
    msg = (f"{where}: fitted rotation of leg(s) {listing} from the design rotation (bound {ROTATION_BOUND_DEG:.0f} deg, "
           "the other legs agree): a wiring fault of that leg or a wrong rotation for it in robot.toml?")
    log.warning("%s", msg)
    return [msg]


def translation_errors_m(cal, robot: Robot) -> np.ndarray:
    """Distance (m) per leg between the fitted ``p'_k`` and the design position, each less its mean over legs."""
    p = np.stack([cal.legs[k].position_from_com_m for k in robot.legs])
    nom = robot.nominal_positions()
    return np.linalg.norm((p - p.mean(axis=0)) - (nom - nom.mean(axis=0)), axis=1)


def check_transducer_poses(cal, robot: Robot, where: str) -> list[str]:
    """Rotations (:func:`check_rotations`) and relative translations against the design; returns the warnings."""
    notes = check_rotations(cal, robot, where)
    err = translation_errors_m(cal, robot)
    off = err > TRANSLATION_BOUND_M
    if off.any():
        listing = ", ".join(f"{k} {e * 1e3:.0f} mm" for k, e, o in zip(robot.legs, err, off) if o)
        msg = (f"{where}: fitted transducer positions far from robot.toml's position_m ({listing}, relative to their mean; "
               f"expected within {TRANSLATION_BOUND_M * 1e3:.0f} mm): columns of two legs exchanged, a leg's wiring, or position_m?")
        log.warning("%s", msg)
        notes.append(msg)
    return notes


# ----------------------------------------------------------------------------- a recording to correct, its calibration

#: a sampling interval above this (median, in the units of column ``t``) is no force/torque recording in seconds:
#: a clock in ms at 500 Hz or slower (100 Hz: 10 units) is caught; the sparsest dataset a test calibrates is 1.3 s
MAX_SAMPLE_INTERVAL_S = 2.0
#: consecutive identical samples of one channel that no working transducer gives (noise moves the last digits)
STUCK_RUN = 25
#: rows of a long recording the checks of a correction look at (a regular subsample)
CHECK_ROWS = 50_000


def same_pose_share(step_deg: np.ndarray | None, joint_steps: np.ndarray | None, deg: float, rad: float) -> float:
    """The share of consecutive rows that hold one pose: the turn between them (``step_deg`` (N-1,), degrees) within
    ``deg`` and every joint's step (``joint_steps`` (N-1, m)) within ``rad``; nan when neither is given (rows that cannot
    be told apart). Holds sampled at a rate share their pose; a list of single-row poses does not (the clock checks of
    ``run`` and ``correct`` on free loads)."""
    if step_deg is not None:
        n = len(step_deg)
    elif joint_steps is not None:
        n = len(joint_steps)
    else:
        return float("nan")
    same = np.ones(n, bool)
    if step_deg is not None:
        same &= step_deg <= deg
    if joint_steps is not None:
        same &= np.all(np.abs(joint_steps) <= rad, axis=1)
    return float(same.mean())


def check_clock(rec: Recording) -> None:
    """Column ``t`` in seconds: a median sampling interval above ``MAX_SAMPLE_INTERVAL_S`` is milliseconds (or
    another unit): a 100 Hz recording in ms has 10 units between samples."""
    if rec.n < 3:
        return
    dt = float(np.median(np.diff(rec.t)))
    if dt > MAX_SAMPLE_INTERVAL_S:
        raise DataFormatError(
            f"{_src(rec)}: column t: median sampling interval {dt:.4g} ({1 / dt:.3g} samples per unit of t); expected "
            f"seconds, at most {MAX_SAMPLE_INTERVAL_S:g} s between the samples of a force/torque recording: is t in "
            "milliseconds (or microseconds)?"
        )


@dataclass(frozen=True)
class SensorFault:
    """Rows of one leg where channels did not move for ``STUCK_RUN`` samples or more: ``kind`` ``"dead"`` (every
    channel of the leg reads 0), ``"saturated"`` (held at the channel's extreme over the recording) or ``"stuck"``;
    ``channels`` the columns; ``rows`` (N,) bool; ``value`` the held value of the first channel."""

    source: str
    leg: str
    kind: str
    channels: tuple[str, ...]
    rows: np.ndarray
    value: float
    unit: str = "leg"   # what the message calls the transducer's carrier: a hexapod's leg, or "transducer"

    @property
    def fraction(self) -> float:
        return float(self.rows.mean()) if self.rows.size else 0.0

    def describe(self) -> str:
        idx = np.flatnonzero(self.rows)
        starts = idx[np.r_[True, np.diff(idx) > 1]]
        ends = idx[np.r_[np.diff(idx) > 1, True]]
        spans = ", ".join(f"{a + 1}-{b + 1}" for a, b in list(zip(starts, ends))[:4]) + (" ..." if len(starts) > 4 else "")
        what = {"dead": "reads 0 on every channel (dead or unplugged)", "saturated": f"clipped at {self.value:.6g}",
                "stuck": f"stuck at {self.value:.6g}"}[self.kind]
        return (f"{self.source}: {self.unit} {self.leg} columns {', '.join(self.channels)} {what} on {int(self.rows.sum())} of "
                f"{self.rows.size} samples ({100 * self.fraction:.1f} %; rows {spans})")


def _held_runs(x: np.ndarray, min_run: int) -> np.ndarray:
    """Rows (N,) in runs of at least ``min_run`` identical consecutive values (NaN never repeats)."""
    if len(x) < min_run:
        return np.zeros(len(x), bool)
    new = np.r_[True, x[1:] != x[:-1]]
    run_id = np.cumsum(new) - 1
    return np.bincount(run_id)[run_id] >= min_run


def with_fault_columns(frame: pd.DataFrame, faults: list[SensorFault], kept: np.ndarray) -> pd.DataFrame:
    """A corrected table with a warning per sensor fault (transducer, columns, rows of the recording) and a column
    ``{X}_fault`` (1 on its rows) after the others; ``kept`` (N,) the recording's rows the table holds. One wording for
    every transducer kind (``correct`` of a hexapod walk and of a free load)."""
    if not faults:
        return frame
    cols = {}
    for f in faults:
        log.warning("%s; those rows are corrected as read and flagged in column %s_fault", f.describe(), f.leg)
        cols[f"{f.leg}_fault"] = f.rows[kept].astype(np.int8)
    return pd.concat([frame, pd.DataFrame(cols, index=frame.index)], axis=1)


class Readings(Protocol):
    """What :func:`sensor_faults` reads of a recording (a :class:`~ftcal_nlp.core.data.Recording`, or a table's
    columns by transducer): the readings (N, 6) by leg, and where they come from (for the messages)."""

    @property
    def wrench(self) -> Mapping[str, np.ndarray]: ...

    @property
    def path(self) -> object: ...

    @property
    def name(self) -> str: ...


def sensor_faults(rec: Readings, legs: tuple[str, ...] | None = None, min_run: int = STUCK_RUN) -> list[SensorFault]:
    """Every leg of ``rec`` with channels held for ``min_run`` samples or more (:class:`SensorFault`), one per leg."""
    from .data import WRENCH_COMPONENTS

    out = []
    for k in legs or tuple(rec.wrench):
        W = rec.wrench[k]
        if len(W) < min_run or not np.any(W[1:] == W[:-1]):  # one pass: no channel ever repeats (the usual case)
            continue
        held = np.stack([_held_runs(W[:, j], min_run) for j in range(W.shape[1])], axis=1)
        if not held.any():
            continue
        rows = np.any(held, axis=1)  # np.any, not .any: numpy's stubs type the method's result as a scalar or an array
        chans = tuple(f"{k}_{c}" for j, c in enumerate(WRENCH_COMPONENTS) if held[:, j].any())
        j0 = int(np.flatnonzero(held.any(axis=0))[0])
        value = float(W[held[:, j0], j0][0])
        finite = W[np.isfinite(W[:, j0]), j0]
        if np.all(held, axis=1)[rows].all() and np.all(W[rows] == 0):
            kind = "dead"
        elif finite.size and value in (finite.max(), finite.min()) and np.any(W[~held[:, j0], j0] != value):
            kind = "saturated"
        else:
            kind = "stuck"
        out.append(SensorFault(_src(rec), k, kind, chans, rows, value))
    return out


def check_calibration(cal, source: str, legs: tuple[str, ...] | None = None) -> None:
    """A calibration fit to apply: mass and g positive, every offset, leg weight, rotation and position finite,
    rotations proper (orthogonal, determinant +1), and every leg of ``legs`` (a recording's) calibrated."""
    def bad(msg: str) -> DataFormatError:
        return DataFormatError(f"{source}: {msg}; expected a calibration.json written by a run (OUTPUT_FORMAT.md)")

    if not (np.isfinite(cal.mass_kg) and cal.mass_kg > 0 and np.isfinite(cal.g) and cal.g > 0):
        raise bad(f"mass_kg = {cal.mass_kg!r}, g = {cal.g!r}: not positive numbers")
    missing = [k for k in (legs or ()) if k not in cal.legs]
    if missing:
        raise bad(f"no calibration of leg(s) {missing} of the recording (calibrated legs {list(cal.leg_names)})")
    for k, l in cal.legs.items():
        for key, v in (("offset", l.offset), ("leg_weight_N", l.leg_weight_N), ("rotation_to_body", l.rotation_to_body),
                       ("position_from_com_m", l.position_from_com_m)):
            a = np.asarray(v, float)
            if not np.all(np.isfinite(a)):
                raise bad(f"legs.{k}.{key} holds a null, NaN or infinite value ({np.round(a, 6).tolist()})")
        R = np.asarray(l.rotation_to_body, float)
        err = float(np.abs(R.T @ R - np.eye(3)).max())
        det = float(np.linalg.det(R))
        if err > ROTATION_TOL or abs(det - 1) > ROTATION_TOL:
            raise bad(f"legs.{k}.rotation_to_body is not a rotation (determinant {det:.6g}, max |R^T R - I| {err:.3g}); "
                      "a proper rotation has determinant +1")
        xyz = np.asarray(l.com_xyz, float)
        if xyz.size == 0 or not np.isfinite(xyz).any():
            raise bad(f"legs.{k}.leg_com_grid.xyz holds no finite point")


def check_recording_to_correct(rec: Recording, cal, robot: Robot) -> list[SensorFault]:
    """The checks of a run that apply to a later recording corrected with the calibration ``cal``: column ``t`` in
    seconds, shaft angles in radians, and (on the ground) the readings' sign and unit, the quaternion order and the
    torque columns against the calibration (``robot`` carries its rotations and positions); errors raise. Returns
    the sensor faults (warnings: the caller logs them and flags the rows)."""
    # medians and percentiles: a regular subsample of a long recording says the same at a fraction of the cost
    stride = max(1, -(-rec.n // CHECK_ROWS))
    check_clock(rec)
    _check_shaft_rate(rec, robot.legs, stride)
    if rec.kind in ("walking", "standing") and rec.quat is not None:
        offsets, weights, _, _ = cal.stacked(robot.legs)
        sub = rec if stride == 1 else rec.select(np.arange(0, rec.n, stride))
        check_on_ground(sub, robot, offsets, weights, whose="the calibration's")
    return sensor_faults(rec, robot.legs)


# ----------------------------------------------------------------------------- a calibration dataset's sensors and files


#: a calibration recording with more of its rows held than this is refused rather than fitted on the rest
MAX_FAULT_SHARE = 0.5


def screen_sensor_faults(ds: Dataset, unit: str = "leg", every_recording_fatal: bool = True) -> tuple[Dataset, list[str]]:
    """Dead, stuck or clipped channels of the calibration recordings (hanging, standing), named before fitting.

    A leg whose channels are held in every calibration recording is an error (nothing to calibrate it from);
    otherwise the held rows of each such recording are left out of the fit, a warning names leg, columns, file
    and share, and the returned notes (for the report) say so. ``every_recording_fatal`` False (free loads, often one
    recording): a fault in every recording is refused only where it holds more than ``MAX_FAULT_SHARE`` of one. Walking recordings are left whole: their
    correction flags the rows (``{leg}_fault``)."""
    calib = [r for r in ds.recordings if r.kind in ("hanging", "standing")]
    found = {r.name: [replace(f, unit=unit) for f in sensor_faults(r, ds.robot.legs)] for r in calib}
    by_leg: dict[str, list[SensorFault]] = {}
    for fs in found.values():
        for f in fs:
            by_leg.setdefault(f.leg, []).append(f)
    for leg, fs in by_leg.items():
        if every_recording_fatal and len(fs) == len(calib):
            raise DataFormatError(
                f"{unit} {leg}: its transducer does not move in any calibration recording: " + "; ".join(f.describe() for f in fs)
                + f"; expected readings that change with the pose (is the sensor of {unit} {leg} connected, within its range?)"
            )
    if not by_leg:
        return ds, []
    notes, recs = [], []
    for rec in ds.recordings:
        fs = found.get(rec.name, [])
        if fs:
            rows = np.any([f.rows for f in fs], axis=0)
            if rows.mean() > MAX_FAULT_SHARE:
                raise DataFormatError("; ".join(f.describe() for f in fs) + f": {100 * rows.mean():.0f} % of the recording; "
                                      f"expected at most {100 * MAX_FAULT_SHARE:.0f} % of a calibration recording held (is the "
                                      "sensor connected, within its range?)")
            for f in fs:
                msg = f"{f.describe()}: those rows are left out of the calibration"
                log.warning("%s", msg)
                notes.append(f"sensor fault: {msg}")
            rec = rec.select(~rows)
        recs.append(rec)
    return replace(ds, recordings=tuple(recs)), notes


#: the standing residual (RMS over poses, force and torque norms) this many times the per-sample sensor noise of
#: the summed readings is far above noise: pose medians average many samples, so a fit that explains the data
#: leaves well below 1x (the sample: 0.25x); a dead leg leaves 25-170x
RESIDUAL_NOISE_FACTOR = 5.0


def residual_note(residuals: np.ndarray, noise, cal) -> str | None:
    """A warning text when the calibrated standing residual is far above the sensor noise, else None.

    ``residuals`` (P, 6) total-wrench residuals per pose (N, N*m); ``noise`` a
    :class:`~ftcal_nlp.estimate.sensor_noise.SensorNoise` (None: nothing to compare with); ``cal`` the calibration (the
    transducers' lever arms ``p_k``). The per-sample noise of the summed readings: force ``sqrt(sum_k tr S_f,k)``, torque
    ``sqrt(sum_k tr S_t,k + |p_k|^2 tr S_f,k)`` (isotropic lever-arm term)."""
    if noise is None or residuals is None or len(residuals) == 0:
        return None
    r = np.asarray(residuals, float)
    legs = [k for k in cal.leg_names if k in noise.readings]
    covs = [noise.readings[k] for k in legs]
    positions = [cal.legs[k].position_from_com_m for k in legs]
    f_var = sum(float(np.trace(c[:3, :3])) for c in covs)
    t_var = sum(float(np.trace(c[3:, 3:])) + float(np.sum(p**2)) * float(np.trace(c[:3, :3])) for c, p in zip(covs, positions))
    rms_f = float(np.sqrt(np.mean(np.sum(r[:, :3] ** 2, axis=1))))
    rms_t = float(np.sqrt(np.mean(np.sum(r[:, 3:] ** 2, axis=1))))
    ratio_f, ratio_t = rms_f / np.sqrt(f_var), rms_t / np.sqrt(t_var)
    if max(ratio_f, ratio_t) <= RESIDUAL_NOISE_FACTOR:
        return None
    return (f"the calibrated standing residual ({rms_f:.3g} N, {rms_t:.3g} N*m RMS over the poses) is {ratio_f:.0f}x "
            f"(forces) and {ratio_t:.0f}x (torques) the per-sample sensor noise of the summed readings ({np.sqrt(f_var):.3g} N, "
            f"{np.sqrt(t_var):.3g} N*m); expected below {RESIDUAL_NOISE_FACTOR:g}x: the model misses something in these data. "
            "See the diagnosis ([diagnose] enabled = true: diagnosis.json and the report's Diagnosis section: which "
            "effect, which leg) and any sensor fault named above")
