"""Plausibility of a free load's data before its fit and of the fit after (issue 30), as the hexapod's checks.

Physics that needs no fit: whatever hangs below a transducer, the force it reads less a constant offset is its
weight, ``f_n = f_o + m E^T b_n`` with ``m > 0`` (``loads.base``; ``b_n = R_nom,n^T g_B,n`` the nominal gravity in ft,
``E`` the mounting rotation, near ``I``). :func:`gravity_fit` fits that by the signed orthogonal Procrustes
(Umeyama) solution in closed form: the sign of ``m``, ``|m|``, ``E`` and the residual, for any load (a URDF load's
force sees its total mass only). :func:`load_fit` adds the torques at that ``E`` by linear least squares of the
load's own model (``t_n = t_o + (K_n theta) x E^T b_n``), weighted by the readings' noise. Both take arrays, so
``correct`` can run them on a recording it is given.

Before fitting (:func:`check_free_load_data`, on each transducer's quasi-static samples):

* quaternion order (:func:`check_quaternion_order`): the columns read as x, y, z, w (or as the conjugate, world ->
  body) leave less than ``QUAT_ORDER_RATIO`` (the hexapod's) of the force residual of the columns as given, and the
  given residual is over ``RESIDUAL_NOISE_FACTOR`` (the hexapod's) times the noise: an error naming the reading;
* gravity sign (:func:`check_gravity_sign`): where gravity spans three directions in ft, the weight following
  reversed gravity (``-b``) leaves less than ``QUAT_ORDER_RATIO`` of the residual of the weight following ``b``: an
  error naming where gravity came from (``gx..gz`` an accelerometer's reading, ``qw..qz`` a world whose z points
  down, the sign of ``gravity_body``) and the readings' sign; fewer directions cannot tell a reversed gravity from
  a mount turned half round: the fit's bounds below take it;
* joint angles (:func:`check_joint_degrees`): the URDF's revolute joints with limits are checked when read
  (``data.py``); continuous joints have none, so the load's model with their ``q_{joint}`` read as degrees must not
  leave ``DEGREES_RATIO`` (the hexapod's) times less weighted residual than with radians;
* units (:func:`check_units`): the weight in the forces within ``UNIT_FACTOR`` of the URDF's nominal mass of the
  load; without one, a force noise above ``MIN_FORCE_NOISE_N`` (kN readings of a real transducer fall below it; a
  rigid payload in mN is caught after the fit, by its lever arm); a weighed ``load_mass_kg`` ~1000x the weight in
  forces whose noise is a transducer's in N names the key (grams);
* a left-handed force frame (:func:`check_gravity_sign`): the weight follows gravity through a reflection (the
  negative-mass fit) whose proper part lies far from the nominal: not gravity's sign (``-I`` near the nominal) but
  the columns (one negated, two swapped), named by the nearest signed permutation. A transducer on the same
  recordings whose weight follows gravity as given clears the stream: the message then names the readings;
* torque signs (:func:`check_torque_signs`): a load with the URDF's nominal inertials predicts its torques; the
  columns as given must not leave more than their spread when a signed permutation of them agrees (as the hexapod's
  ``check_torque_axes``). Negated torques mirror a payload's CoM: with no nominal to hold it against, that one
  case is not caught;
* a temperature that never varies (:func:`check_temperature_varies`): the transducer's temperature (``{X}_temp_C`` or
  ``temp_C``) whose range over the samples is within ``TEMPERATURE_RESOLUTION_C`` is a warning, not an error: a
  temperature effect ``w = w_o + beta (T - T_ref)`` is then collinear with the offsets ``w_o`` (the regressor
  ``[1, T - T_ref]`` has rank 1: the Fisher information of ``beta`` is ``sum (T - Tbar)^2 / sigma^2``, zero), so the
  session cannot tell it from them and the diagnosis cannot name ``temperature`` (its face, ``effects/temperature.py``,
  is offered for any range above zero; within the resolution its coefficients are the noise over that range). A
  column without any number is the reader's error (``data.py``);
* the clock (:func:`check_pose_list_clock`): samples further apart than the hexapod's ``MAX_SAMPLE_INTERVAL_S`` are a
  list of poses only when consecutive rows are other poses; ``gx..gz`` and ``qw..qz`` both given must agree
  (:func:`check_gravity_columns_agree`).

After fitting (:func:`check_free_load_fit`) the fit is an error when the load mass is ``<= 0``, the mounting
rotation lies farther than ``ROTATION_BOUND_DEG`` (the hexapod's, 20 deg) from the nominal, the residual leaves
more than ``UNEXPLAINED_SHARE`` of the readings' spread over the holds unexplained while it is over
``RESIDUAL_NOISE_FACTOR`` times the noise, or the mass is ``UNIT_FACTOR`` times off the URDF's nominal total mass
(or, without one, the force noise is below ``MIN_FORCE_NOISE_N``: no six-axis transducer resolves that in N). The
residual's share, not its ratio to the noise alone: every simulator effect on a free load (``sim/free``, seed 3)
leaves 1-60x the noise (the diagnosis' business) but at most 3 % of the spread, while a convention error leaves
20-100 %. A URDF link group's determined mass below 0 by ``NEGATIVE_MASS_SE`` se, and a rigid payload's CoM outside
the hexapod's lever-arm range (``LEVER_MIN_M``..``LEVER_MAX_M``: forces in mN, torques in kN*m or N*mm) are errors too.
The error tries the likely causes in order, each by the linear refits above with the fix applied:
quaternion order, gravity sign (or the readings negated: the same data), joint angles in degrees, the frame
(mass positive, residual small, rotation far: the transducer's nominal rotation, in ``robot.toml`` or the URDF,
is wrong, or given B -> ft), torque signs (every signed permutation of the torque columns) and torque units (x1000,
/1000) where the forces are plausible, units (kN or mN: the mass 1000x off; a weighed mass in grams), and names those
that make the load plausible.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ...core.checks import (
    DEGREES_RATIO,
    LEVER_MAX_M,
    LEVER_MIN_M,
    MAX_SAMPLE_INTERVAL_S,
    same_pose_share,
    QUAT_ORDER_RATIO,
    RESIDUAL_NOISE_FACTOR,
    ROTATION_BOUND_DEG,
    signed_permutations,
)
from ...core.data import Recording
from ...core.errors import DataFormatError, ImplausibleLoadFit
from ...core.geometry import quat_to_rotation, rotation_to_rotvec

log = logging.getLogger(__name__)

#: share of the readings' spread (RMS about their mean, forces and torques apart) a fit may leave unexplained
UNEXPLAINED_SHARE = 0.1
#: a load mass this many times off the URDF's nominal total mass is no CAD discrepancy: a unit (1000x) is off
UNIT_FACTOR = 30.0
#: per-sample force noise (N) below any six-axis transducer's resolution: the forces are in kN (or scaled)
MIN_FORCE_NOISE_N = 1e-4
#: gravity directions in ft span this many dimensions when the centred unit directions' singular value over
#: sqrt(N) exceeds this (``estimate.NARROW``: ~1 deg)
SPAN_TOL = 0.02

THRESHOLDS = (f"free loads: quaternion order and gravity sign {QUAT_ORDER_RATIO:g}x of the residual, joint degrees "
              f"{DEGREES_RATIO:g}x; fitted mass > 0, mount < {ROTATION_BOUND_DEG:.0f} deg from nominal, residual < "
              f"{UNEXPLAINED_SHARE:.0%} of the spread or < {RESIDUAL_NOISE_FACTOR:g}x the noise, mass within {UNIT_FACTOR:g}x "
              "of the URDF's")


# ----------------------------------------------------------------------------- the linear physics


@dataclass(frozen=True)
class GravityFit:
    """``f_n = offset + mass_kg E^T b_n`` fitted in closed form: ``mass_kg`` signed (negative: the readings follow
    reversed gravity), ``rotation`` ``E`` (I where not determined), ``rms_N`` the residual RMS (force norm),
    ``spread_N`` the forces' RMS about their mean, ``span`` the dimensions gravity spans in ft (0-3),
    ``sign_determined`` whether the data tell the sign from a mount turned half round (three directions and the
    other sign's residual over 1 / ``QUAT_ORDER_RATIO`` times)."""

    mass_kg: float
    rotation: np.ndarray
    offset: np.ndarray
    rms_N: float
    spread_N: float
    span: int
    sign_determined: bool
    other_rms_N: float = float("nan")

    @property
    def angle_deg(self) -> float:
        return rotation_angle_deg(self.rotation)


def rotation_angle_deg(E: np.ndarray) -> float:
    """Angle (deg) of the rotation ``E``."""
    return float(np.degrees(np.linalg.norm(rotation_to_rotvec(np.asarray(E, float)))))


def gravity_span(b: np.ndarray) -> int:
    """Dimensions (0-3) the directions of ``b`` (N, 3) span about their mean (``SPAN_TOL``)."""
    u = b / np.linalg.norm(b, axis=1, keepdims=True)
    sv = np.linalg.svd(u - u.mean(axis=0), compute_uv=False) / np.sqrt(max(len(u), 1))
    return int(np.sum(sv > SPAN_TOL))


def _procrustes(fc: np.ndarray, bc: np.ndarray, sign: float) -> tuple[float, np.ndarray, float]:
    """Scale ``s >= 0`` and proper rotation ``R`` minimising ``|sign fc - s R bc|`` (Umeyama); and the RSS."""
    M = sign * fc.T @ bc
    U, S, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / max(float(np.sum(bc**2)), 1e-300))
    rss = float(np.sum((sign * fc - s * bc @ R.T) ** 2))
    return max(s, 0.0), R, rss


def gravity_fit(f: np.ndarray, b: np.ndarray) -> GravityFit:
    """The weight in the forces ``f`` (N, 3) along the nominal gravity in ft ``b`` (N, 3, m/s^2) (module docstring).

    Both signs are fitted; the better residual wins where gravity spans three directions; with fewer, where the
    two fit alike (a half turn about the normal of the plane gravity sweeps is a reversal), the one whose rotation
    is nearer the nominal; with one direction or none the rotation is the nominal's and the mass the force's
    projection on gravity."""
    ok = np.all(np.isfinite(f), axis=1) & np.all(np.isfinite(b), axis=1)
    f, b = f[ok], b[ok]
    fm, bm = f.mean(axis=0), b.mean(axis=0)
    fc, bc = f - fm, b - bm
    n = max(len(f), 1)
    spread = float(np.sqrt(np.sum(fc**2) / n))
    span = gravity_span(b) if len(b) > 2 else 0
    if span < 2:   # one direction: the projection on it; none: the mass is not in the forces (NaN)
        m = float(np.sum(fc * bc) / float(np.sum(bc**2))) if span == 1 else np.nan
        res = fc - np.nan_to_num(m) * bc
        return GravityFit(m, np.eye(3), fm - np.nan_to_num(m) * bm, float(np.sqrt(np.sum(res**2) / n)), spread, span, False)
    fits = {sg: _procrustes(fc, bc, sg) for sg in (1.0, -1.0)}
    (_, Rp, rp), (_, Rn, rn) = fits[1.0], fits[-1.0]
    if span == 3 and (rn < QUAT_ORDER_RATIO**2 * rp or rp < QUAT_ORDER_RATIO**2 * rn):
        sign, determined = (-1.0 if rn < rp else 1.0), True
    else:
        sign, determined = (-1.0 if rotation_angle_deg(Rn.T) < rotation_angle_deg(Rp.T) else 1.0), False
    s, R, rss = fits[sign]
    m = sign * s
    return GravityFit(m, R.T, fm - m * bm @ R.T, float(np.sqrt(rss / n)), spread, span, determined,
                      float(np.sqrt(fits[-sign][2] / n)))


@dataclass(frozen=True)
class LoadFit:
    """The load's whole model at a fixed mounting rotation, fitted linearly: ``theta`` (p,), ``offset`` (6,),
    ``rms`` (6,) residual RMS per channel, ``spread`` (2,) the forces' and torques' RMS about their mean (norms),
    ``unexplained`` (2,) the residual's share of them, ``mass_kg`` ``mu . theta``, ``se`` (p,) the se of ``theta``
    (inf where the data leave it undetermined; the residual's scale where the noise is not known)."""

    theta: np.ndarray
    offset: np.ndarray
    rms: np.ndarray
    spread: np.ndarray
    unexplained: np.ndarray
    mass_kg: float
    se: np.ndarray | None = None


def load_fit(w: np.ndarray, b: np.ndarray, K: np.ndarray, mu: np.ndarray, E: np.ndarray,
             noise: np.ndarray | None = None) -> LoadFit:
    """``w_n = w_o + [(mu . theta) E^T b_n; (K_n theta) x E^T b_n]`` by weighted linear least squares (minimum norm
    where the data leave directions undetermined); ``w`` (N, 6), ``b`` (N, 3), ``K`` (N, 3, p), ``noise`` (6,) the
    per-channel sd (weights; None or not positive: unit weights)."""
    ok = np.all(np.isfinite(w), axis=1) & np.all(np.isfinite(b), axis=1)
    w, b, K = w[ok], b[ok], np.broadcast_to(K, (len(ok), *K.shape[-2:]))[ok]
    n, p = len(w), K.shape[-1]
    gt = b @ np.asarray(E, float)                                    # (E^T b_n)^T
    X = np.zeros((n, 6, 6 + p))
    X[:, :, :6] = np.eye(6)
    X[:, :3, 6:] = gt[:, :, None] * np.asarray(mu, float)[None, None, :]
    X[:, 3:, 6:] = -np.einsum("nij,njp->nip", skew_rows(gt), K)      # s x g = -[g]x s
    sd = _sd(noise)
    Xw, yw = (X / sd[None, :, None]).reshape(-1, 6 + p), (w / sd).reshape(-1)
    U, S, Vt = np.linalg.svd(Xw, full_matrices=False)
    keep = S > S[0] * 1e-9 if S.size else S > 0
    x = Vt[keep].T @ ((U[:, keep].T @ yw) / S[keep])
    res = w - np.einsum("nik,k->ni", X, x)
    dof = max(yw.size - int(keep.sum()), 1)
    s2 = float(np.sum(((w - np.einsum("nik,k->ni", X, x)) / sd) ** 2)) / dof
    se = np.sqrt(np.sum((Vt[keep] / S[keep, None]) ** 2, axis=0) * (max(s2, 1.0) if _known(noise) else s2))
    se[np.sum(Vt[~keep] ** 2, axis=0) > 1e-6] = np.inf
    rms = np.sqrt(np.mean(res**2, axis=0))
    wc = w - w.mean(axis=0)
    spread = np.array([np.sqrt(np.mean(np.sum(wc[:, :3] ** 2, axis=1))), np.sqrt(np.mean(np.sum(wc[:, 3:] ** 2, axis=1)))])
    resn = np.array([np.sqrt(np.mean(np.sum(res[:, :3] ** 2, axis=1))), np.sqrt(np.mean(np.sum(res[:, 3:] ** 2, axis=1)))])
    return LoadFit(x[6:], x[:6], rms, spread, resn / np.maximum(spread, 1e-300), float(np.asarray(mu) @ x[6:]), se[6:])


def skew_rows(v: np.ndarray) -> np.ndarray:
    """``[v_n]x`` (N, 3, 3) for the rows of ``v`` (N, 3)."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return S


# ----------------------------------------------------------------------------- a recording's gravity, as given and fixed


def _joints(load) -> tuple[str, ...]:
    return tuple(getattr(load, "load_joints", ())) + tuple(getattr(load, "base_joints", ()))


def load_arrays(recs: Sequence[Recording], leg: str, load, g: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(w, b, K)`` over the recordings: readings (N, 6) of ``leg``, nominal gravity in ft (N, 3, m/s^2) and the
    load's lever (N, 3, p) for each sample's joint angles (joints without a column at 0, as the fit)."""
    ws, bs, Ks = [], [], []
    for rec in recs:
        n = rec.n
        q = {j: rec.q[j] if j in rec.q else np.zeros(n) for j in _joints(load)}
        R_nom = load.nominal_rotation(q, n)
        bs.append(np.einsum("nji,nj->ni", R_nom, g * rec.gravity_directions()))
        Ks.append(np.broadcast_to(load.lever(q, n), (n, 3, len(load.param_names))))
        ws.append(rec.wrench[leg])
    return np.concatenate(ws), np.concatenate(bs), np.concatenate(Ks)


class AsGiven(NamedTuple):
    """A transducer's data as given, computed once for every check before the fit: :func:`load_arrays` ``(w, b, K)``
    and the closed-form :func:`gravity_fit` ``gf`` of its forces."""

    w: np.ndarray
    b: np.ndarray
    K: np.ndarray
    gf: GravityFit


def as_given(recs: Sequence[Recording], leg: str, load, g: float) -> AsGiven:
    """:class:`AsGiven` of ``leg``'s load over ``recs``."""
    w, b, K = load_arrays(recs, leg, load, g)
    return AsGiven(w, b, K, gravity_fit(w[:, :3], b))


def with_quaternion(rec: Recording, quat: np.ndarray) -> Recording:
    """``rec`` with its orientation (and the gravity per sample from it, ``R_WB^T (0, 0, -1)``) replaced."""
    ok = np.all(np.isfinite(quat), axis=1)
    grav = -quat_to_rotation(np.nan_to_num(quat, nan=1.0))[:, 2, :]
    grav[~ok] = np.nan
    return replace(rec, quat=quat, gravity=grav)


def xyzw_order(rec: Recording) -> Recording:
    """``rec`` as if its columns qw, qx, qy, qz held x, y, z, w."""
    return with_quaternion(rec, rec.quat[:, [3, 0, 1, 2]]) if rec.quat is not None else rec


def conjugate(rec: Recording) -> Recording:
    """``rec`` as if its quaternion mapped the world to B (the conjugate of what it gives)."""
    return with_quaternion(rec, rec.quat * np.array([1.0, -1, -1, -1])) if rec.quat is not None else rec


def reversed_gravity(rec: Recording) -> Recording:
    """``rec`` with gravity reversed (the readings negated give the same data: both flip the weight's sign)."""
    if rec.gravity is not None:
        return replace(rec, gravity=-rec.gravity)
    return replace(rec, gravity_body=-np.asarray(rec.gravity_body, float))


def joints_in_degrees(rec: Recording, joints: Sequence[str]) -> Recording:
    """``rec`` with the columns ``q_{joint}`` of ``joints`` read as degrees."""
    return replace(rec, q={j: np.radians(v) if j in joints else v for j, v in rec.q.items()})


def gravity_source(rec: Recording) -> str:
    """Where a recording's gravity comes from, as the user wrote it."""
    if rec.gravity is not None and rec.quat is None:
        return "columns gx, gy, gz"
    if rec.quat is not None:
        return "columns qw, qx, qy, qz"
    return f"gravity_body = {np.round(np.asarray(rec.gravity_body, float), 6).tolist()}"


def continuous_joints(load, tree, recs: Sequence[Recording]) -> tuple[str, ...]:
    """The load's continuous joints with a ``q_{joint}`` column (revolute joints' limits are checked when read)."""
    if tree is None:
        return ()
    have = {j for r in recs for j in r.q}
    return tuple(j for j in _joints(load) if j in have and tree.joint(j).type == "continuous")


def _where(recs: Sequence[Recording], leg: str) -> str:
    return f"{', '.join(str(r.path or r.name) for r in recs)}: transducer {leg}"


# ----------------------------------------------------------------------------- before the fit


def check_quaternion_order(recs: Sequence[Recording], leg: str, load, g: float, noise: np.ndarray | None = None,
                           data: AsGiven | None = None) -> None:
    """Raise when another reading of the columns qw..qz explains the forces far better (module docstring). ``data``:
    :func:`as_given` of the same arguments, where the caller has it."""
    if not any(r.quat is not None for r in recs):
        return
    given = (data or as_given(recs, leg, load, g)).gf
    floor = _force_noise(noise)
    if given.rms_N <= RESIDUAL_NOISE_FACTOR * floor:
        return
    for what, fix in (("x, y, z, w (not w, x, y, z)", xyzw_order), ("the conjugate (world -> body, not body -> world)", conjugate)):
        w2, b2, _ = load_arrays([fix(r) for r in recs], leg, load, g)
        alt = gravity_fit(w2[:, :3], b2)
        if alt.rms_N < QUAT_ORDER_RATIO * given.rms_N:
            raise DataFormatError(
                f"{_where(recs, leg)}: columns qw, qx, qy, qz: the forces follow the load's weight along gravity from the "
                f"quaternion with a residual of {given.rms_N:.3g} N RMS ({given.rms_N / given.spread_N:.0%} of their spread), "
                f"{alt.rms_N:.3g} N with the columns read as {what} (load mass {alt.mass_kg:.4g} kg, mount "
                f"{alt.angle_deg:.3g} deg); expected the columns as given to agree best (qw..qz map B to the world, "
                f"DATA_FORMAT.md section 3): are the quaternion columns in {what.split(' (')[0]} order?"
                if what.startswith("x") else
                f"{_where(recs, leg)}: columns qw, qx, qy, qz: the forces follow the load's weight along gravity from the "
                f"quaternion with a residual of {given.rms_N:.3g} N RMS, {alt.rms_N:.3g} N with its conjugate (load mass "
                f"{alt.mass_kg:.4g} kg); expected qw..qz to map B to the world (DATA_FORMAT.md section 3): does the "
                "quaternion map the world to B?", column="qw")


def follows_gravity(recs: Sequence[Recording], leg: str, load, g: float, data: AsGiven | None = None) -> bool:
    """Whether ``leg``'s forces follow gravity as given (a positive weight where three directions tell the sign): the
    evidence a transducer sharing ``leg``'s orientation stream gives about the stream."""
    fit = (data or as_given(recs, leg, load, g)).gf
    return bool(fit.sign_determined and fit.mass_kg > 0 and fit.angle_deg <= ROTATION_BOUND_DEG)


def signed_permutation_near(Q: np.ndarray, det: float | None = None) -> tuple[np.ndarray, float]:
    """The signed permutation (of determinant ``det``, any where None) nearest the orthogonal ``Q``, and the angle (deg)
    between them."""
    maps = [np.eye(3)] + signed_permutations()
    if det is not None:
        maps = [P for P in maps if np.sign(np.linalg.det(P)) == np.sign(det)]
    P = max(maps, key=lambda P: float(np.sum(P * Q)))
    M = P.T @ Q
    if np.linalg.det(M) < 0:      # Q and P of opposite determinants: no rotation between them
        return P, 180.0
    return P, rotation_angle_deg(M)


def describe_columns(P: np.ndarray, leg: str, kind: str = "f") -> str:
    """The column mix-up a signed permutation ``P`` makes (the reading's column i holds ``P[i] .`` the true axes)."""
    c = "xyz"
    src = [(int(np.argmax(np.abs(P[i]))), float(np.sign(P[i][np.argmax(np.abs(P[i]))]))) for i in range(3)]
    parts, done = [], set()
    for i, (j, sg) in enumerate(src):
        if i in done:
            continue
        if j == i:
            if sg < 0:
                parts.append(f"{leg}_{kind}{c[i]} negated")
            continue
        if src[j][0] == i:
            done |= {i, j}
            neg = [f"{leg}_{kind}{c[k]}" for k in (i, j) if src[k][1] < 0]
            parts.append(f"{leg}_{kind}{c[i]} and {leg}_{kind}{c[j]} swapped" + (f" ({' and '.join(neg)} negated)" if neg else ""))
        else:
            parts.append(f"{leg}_{kind}{c[i]} holds {'-' if sg < 0 else ''}{kind}{c[j]}")
    return ", ".join(parts) or "none"


def check_gravity_sign(recs: Sequence[Recording], leg: str, load, g: float, siblings_ok: Sequence[str] = (),
                       data: AsGiven | None = None) -> None:
    """Raise when the forces follow reversed gravity where three gravity directions tell it (module docstring): through a
    reflection near the nominal frame (``-E`` with ``E`` within ``ROTATION_BOUND_DEG``: gravity or the readings' sign),
    or through a reflection far from it (the force columns form a left-handed frame: one negated, two swapped).
    ``siblings_ok``: transducers on the same recordings whose weight follows gravity as given (the stream is right)."""
    fit = (data or as_given(recs, leg, load, g)).gf
    if not (fit.sign_determined and fit.mass_kg < 0):
        return
    if fit.angle_deg > ROTATION_BOUND_DEG:
        Q = -fit.rotation.T                     # f ~ |m| Q b: the best orthogonal map, determinant -1
        P, off = signed_permutation_near(Q, det=-1.0)
        what = (f"the nearest column mix-up is {describe_columns(P, leg)} ({off:.2g} deg from the map found)"
                if off <= ROTATION_BOUND_DEG else
                f"no single column mix-up is near it (the nearest, {describe_columns(P, leg)}, is {off:.3g} deg off)")
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {leg}_fx..{leg}_fz form a left-handed frame: the load's weight follows gravity "
            f"through a reflection (determinant -1; residual {fit.rms_N:.3g} N RMS, load mass {-fit.mass_kg:.4g} kg) and through "
            f"no rotation (best: residual {fit.other_rms_N:.3g} N RMS), nor through reversed gravity or a relabelled quaternion "
            f"(the mount would be {fit.angle_deg:.3g} deg from the nominal); {what}; expected the columns of a right-handed "
            f"transducer frame (DATA_FORMAT.md section 1): {describe_columns(P, leg)}?", column=f"{leg}_fx")
    if siblings_ok:
        raise DataFormatError(
            f"{_where(recs, leg)}: the forces (columns {leg}_fx..{leg}_fz) follow gravity reversed: a load mass of "
            f"{fit.mass_kg:.4g} kg (residual {fit.rms_N:.3g} N RMS; {-fit.mass_kg:.4g} kg with gravity reversed), while "
            f"transducer(s) {', '.join(siblings_ok)} on the same recordings follow gravity as given (the gravity source is "
            f"right); expected a positive mass: are the readings of {leg} negated (a reading is the wrench the load exerts on "
            "the transducer, DATA_FORMAT.md section 1)?", column=f"{leg}_fx")
    raise DataFormatError(f"{_where(recs, leg)}: the forces (columns {leg}_fx..{leg}_fz) follow gravity reversed: "
                          f"{_reversal_hint(recs, leg, fit)}")


def _reversal_hint(recs: Sequence[Recording], leg: str, fit: GravityFit) -> str:
    srcs = sorted({gravity_source(r) for r in recs})
    why = []
    for s in srcs:
        if s.startswith("columns gx"):
            why.append("gx, gy, gz point up (an accelerometer's reading at rest; DATA_FORMAT.md section 5 wants gravity, "
                       "pointing down: minus the reading)")
        elif s.startswith("columns qw"):
            why.append("the orientation stream's world z points down (qw..qz must map B to a world whose z is up)")
        else:
            why.append(f"the sign of {s} is reversed (the direction of gravity, pointing down, in B)")
    return (f"a load mass of {fit.mass_kg:.4g} kg (residual {fit.rms_N:.3g} N RMS; {-fit.mass_kg:.4g} kg with gravity "
            f"reversed); expected a positive mass: {' or '.join(why)}? or are the readings negated (a reading is the wrench "
            "the load exerts on the transducer, DATA_FORMAT.md section 1)?")


def check_joint_degrees(recs: Sequence[Recording], leg: str, load, g: float, tree, noise: np.ndarray | None = None,
                        data: AsGiven | None = None) -> None:
    """Raise when the load's model fits far better with the continuous joints' columns read as degrees."""
    joints = continuous_joints(load, tree, recs)
    if not joints:
        return
    given = _weighted_rss(data or as_given(recs, leg, load, g), load, noise)
    alt = _weighted_rss(as_given([joints_in_degrees(r, joints) for r in recs], leg, load, g), load, noise)
    if alt * DEGREES_RATIO < given:
        cols = ", ".join(f"q_{j}" for j in joints)
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {cols} (continuous joints of the URDF): the load's model leaves "
            f"{given / alt:.3g}x less residual with them read as degrees than as radians (expected below {DEGREES_RATIO:g}x); "
            "expected radians: are the joint angles in degrees?", column=f"q_{joints[0]}")


def _weighted_rss(d: AsGiven, load, noise: np.ndarray | None) -> float:
    lf = load_fit(d.w, d.b, d.K, load.mass_row, d.gf.rotation, noise)
    sd = _sd(noise)
    return float(np.sum((lf.rms / sd) ** 2))


def _known(noise: np.ndarray | None) -> bool:
    """Whether ``noise`` is a usable per-channel sd (a list of poses has no consecutive samples to estimate it from)."""
    return noise is not None and bool(np.all(np.isfinite(noise)) and np.all(np.asarray(noise) > 0))


def _sd(noise: np.ndarray | None) -> np.ndarray:
    return np.asarray(noise, float) if _known(noise) else np.ones(6)


def _force_noise(noise: np.ndarray | None) -> float:
    if noise is None or not np.all(np.isfinite(noise[:3])):
        return 0.0
    return float(np.sqrt(np.sum(np.asarray(noise[:3], float) ** 2)))


def check_units(recs: Sequence[Recording], leg: str, load, g: float, noise: np.ndarray | None = None,
                weighed_kg: float | None = None, data: AsGiven | None = None) -> None:
    """Raise when the weight in the forces is ``UNIT_FACTOR`` times off the load's reference mass (:func:`reference_mass`:
    weighed, else the URDF's nominal), or (without one) the force noise lies below ``MIN_FORCE_NOISE_N``: the readings
    are in kN (or mN)."""
    fit = (data or as_given(recs, leg, load, g)).gf
    reference = reference_mass(load, weighed_kg)
    ref = reference.kg if reference else None
    m = abs(fit.mass_kg)
    floor = _force_noise(noise)
    if reference is not None and ref and np.isfinite(m) and not 1 / UNIT_FACTOR <= m / ref <= UNIT_FACTOR:
        grams = grams_hint(leg, m, reference, floor)
        if grams:
            raise DataFormatError(f"{_where(recs, leg)}: {grams}", column=f"{leg}_fx")
        unit = "kN" if m < ref else "mN"
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {leg}_fx..{leg}_fz: the load's weight in the forces is {m * g:.4g} N, a mass of "
            f"{m:.4g} kg against {reference.what} {ref:.4g} kg (expected within {UNIT_FACTOR:g}x; {m * (1000 if unit == 'kN' else 1e-3):.4g} "
            f"kg with the readings read as {unit}): expected N and N*m: are the readings in {unit} (and {unit}*m)?",
            column=f"{leg}_fx")
    if not ref and 0 < floor < MIN_FORCE_NOISE_N:
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {leg}_fx..{leg}_fz: the per-sample noise is {floor:.2g} N, below any six-axis "
            f"transducer's resolution ({MIN_FORCE_NOISE_N:g} N), with a load mass of {m:.4g} kg ({1000 * m:.4g} kg read as "
            "kN): expected N and N*m: are the readings in kN (and kN*m)?", column=f"{leg}_fx")


#: consecutive rows this close (gravity direction, deg; joint angles, rad) are the same pose: a hold, not a list of poses
SAME_POSE_DEG = 0.05
SAME_POSE_RAD = 1e-4
#: a list of poses has (nearly) no consecutive rows of one pose; holds sampled at a rate have most, less the moves
#: between them (the real ATI Axia80 time series at 10 Hz: 55 %)
SAME_POSE_SHARE = 0.3
#: gx..gz and the gravity from qw..qz (after the stream's constant world tilt) may disagree by this much (deg)
GRAVITY_AGREE_DEG = 3.0


def check_pose_list_clock(rec: Recording, joints: Sequence[str] = ()) -> None:
    """Column ``t`` of a recording whose samples lie more than ``MAX_SAMPLE_INTERVAL_S`` apart (taken as a list of poses,
    one pose a row): refused when more than ``SAME_POSE_SHARE`` of consecutive rows hold the same pose (gravity per
    sample within ``SAME_POSE_DEG``, joints within ``SAME_POSE_RAD``): holds sampled at a rate, with ``t`` in
    milliseconds. Without gravity per sample or joint columns the rows cannot be told apart: not checked."""
    if rec.n < 3:
        return
    dt = float(np.median(np.diff(rec.t)))
    if dt <= MAX_SAMPLE_INTERVAL_S:
        return
    gr = rec.gravity
    step = None if gr is None else np.degrees(np.arccos(np.clip(np.sum(gr[1:] * gr[:-1], axis=1), -1, 1)))
    cols = [np.diff(rec.q[j]) for j in joints if j in rec.q]
    share = same_pose_share(step, np.stack(cols, axis=1) if cols else None, SAME_POSE_DEG, SAME_POSE_RAD)
    if share > SAME_POSE_SHARE:   # nan (rows not told apart): not checked
        raise DataFormatError(
            f"{rec.path or rec.name}: column t: median interval {dt:.4g}; {100 * share:.0f} % of consecutive rows hold the "
            f"same pose (gravity within {SAME_POSE_DEG:g} deg, joints within {SAME_POSE_RAD:g} rad): they are holds sampled "
            f"at a rate, not single-row poses (expected seconds, at most {MAX_SAMPLE_INTERVAL_S:g} s between samples): is t in "
            "milliseconds?", column="t")


def check_gravity_columns_agree(rec: Recording) -> None:
    """Both ``gx..gz`` and ``qw..qz`` given (``DATA_FORMAT.md`` section 5: alternatives): the gravity ``gx..gz`` gives,
    carried to the stream's world by ``qw..qz``, must be one direction (the world's tilt) within ``GRAVITY_AGREE_DEG``."""
    if rec.quat is None or rec.gravity is None:
        return
    ok = np.all(np.isfinite(rec.quat), axis=1) & np.all(np.isfinite(rec.gravity), axis=1)
    if ok.sum() < 2:
        return
    from_q = -quat_to_rotation(rec.quat[ok])[:, 2, :]
    if np.allclose(from_q, rec.gravity[ok], atol=1e-9):    # gravity taken from the quaternion itself
        return
    d = np.einsum("nij,nj->ni", quat_to_rotation(rec.quat[ok]), rec.gravity[ok])
    mean = d.mean(axis=0)
    mean /= max(float(np.linalg.norm(mean)), 1e-300)
    ang = np.degrees(np.arccos(np.clip(d @ mean, -1, 1)))
    worst = float(np.percentile(ang, 95))
    if worst > GRAVITY_AGREE_DEG:
        tilt = float(np.degrees(np.arccos(np.clip(-mean[2], -1, 1))))
        raise DataFormatError(
            f"{rec.path or rec.name}: columns gx, gy, gz and qw, qx, qy, qz disagree: the gravity gx..gz gives, carried to the "
            f"world by qw..qz, spreads {worst:.3g} deg (95th percentile) about its mean direction ({tilt:.3g} deg from the "
            f"world's down); expected one direction within {GRAVITY_AGREE_DEG:g} deg (DATA_FORMAT.md section 5: gx..gz is an "
            "alternative to qw..qz; give one, or both of the same orientation)", column="gx")


#: the URDF's nominal model leaves more than this share of the torques' spread with the columns as given (it explains
#: less than their mean) while a signed permutation of the columns leaves below ``NOMINAL_FIXED`` and
#: ``1 / NOMINAL_GAIN`` of it: the torque columns are negated or reordered (clean URDF loads: 3-25 %; negated: 110-220 %)
NOMINAL_WORSE = 1.0
NOMINAL_FIXED = 0.5
NOMINAL_GAIN = 3.0


def _nominal_torque_share(t: np.ndarray, pred: np.ndarray) -> float:
    r = t - pred
    r = r - r.mean(axis=0)
    tc = t - t.mean(axis=0)
    return float(np.sqrt(np.sum(r**2) / max(float(np.sum(tc**2)), 1e-300)))


def _simplest(maps: list[tuple[float, np.ndarray]], tol: float = 1.1) -> tuple[float, np.ndarray]:
    """The best (score, map), preferring among those within ``tol`` of the best score all columns negated, then the fewest
    columns changed (directions the data do not excite leave several maps alike)."""
    best = min(v for v, _ in maps)
    near = [(v, P) for v, P in maps if v <= tol * best]
    return min(near, key=lambda vp: (not np.allclose(vp[1], -np.eye(3)), int(np.sum(np.abs(vp[1] - np.eye(3)) > 0.5)), vp[0]))


def check_torque_signs(recs: Sequence[Recording], leg: str, load, g: float, data: AsGiven | None = None) -> None:
    """A load with the URDF's nominal inertials (its prior): the torques it predicts at the weight's mounting rotation
    against the torque columns as given and under every signed permutation (as ``checks.check_torque_axes``); raise
    when the given columns disagree with it (``NOMINAL_WORSE``) and a permutation agrees (``NOMINAL_FIXED``,
    ``NOMINAL_GAIN``): negated torques mirror a payload's CoM or make link masses negative, and no fit can tell."""
    prior = load.prior() if hasattr(load, "prior") else None
    if prior is None:
        return
    w, b, K, gf = data or as_given(recs, leg, load, g)
    if not (gf.mass_kg > 0 and gf.angle_deg <= ROTATION_BOUND_DEG):
        return
    pred = np.cross(np.einsum("nip,p->ni", K, np.asarray(prior, float)), b @ gf.rotation)
    given = _nominal_torque_share(w[:, 3:], pred)
    if given <= NOMINAL_WORSE:
        return
    best, P = _simplest([(_nominal_torque_share(w[:, 3:] @ P, pred), P) for P in signed_permutations()])
    if best < NOMINAL_FIXED and best * NOMINAL_GAIN < given:
        what = (f"the torque readings negated ({leg}_tx..{leg}_tz: their sign convention reversed)"
                if np.allclose(P, -np.eye(3)) else f"the torque columns in another order or sign ({describe_columns(P, leg, 't')})")
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {leg}_tx..{leg}_tz: the URDF's nominal inertials of the load predict the torques "
            f"leaving {given:.0%} of their spread unexplained as given (more than their mean) and {best:.0%} with "
            f"{describe_columns(P, leg, 't')}; expected the torques as given to agree best (no other order or sign below "
            f"{NOMINAL_FIXED:.0%} and {NOMINAL_GAIN:g}x less): are {what}?", column=f"{leg}_tx")


def grams_hint(leg: str, m: float, reference: Reference | None, floor: float) -> str | None:
    """A weighed ``load_mass_kg`` ~1000x the mass the forces weigh while their noise is a transducer's in N (not kN's):
    the key is in grams. None otherwise."""
    if reference is None or not reference.what.startswith("the weighed") or not m > 0:
        return None
    ratio = reference.kg / m
    if not (abs(np.log10(ratio) - 3) < 0.5 and floor >= MIN_FORCE_NOISE_N):
        return None
    return (f"[transducers.{leg}] load_mass_kg = {reference.kg:.6g} is {ratio:.0f}x the mass the forces {leg}_fx..{leg}_fz "
            f"weigh ({m:.4g} kg), whose per-sample noise ({floor:.2g} N) is a transducer's in N (readings in kN would lie "
            f"below {MIN_FORCE_NOISE_N:g} N): expected kilograms: is load_mass_kg in grams ({reference.kg / 1000:.6g} kg)?")


#: degC: a temperature whose range (max - min) over a transducer's samples is within this is taken as constant: a
#: transducer's internal sensor resolves ~0.01-0.1 degC, and a coefficient from a range at its resolution has an se
#: of the noise over that range
TEMPERATURE_RESOLUTION_C = 0.01


def check_temperature_varies(recs: Sequence[Recording], leg: str,
                             resolution_c: float = TEMPERATURE_RESOLUTION_C) -> str | None:
    """The warning (logged and returned) when transducer ``leg``'s temperature over ``recs`` ranges within
    ``resolution_c`` (module docstring); None when it varies more, or no recording carries it."""
    temps = [np.asarray(r.temperature[leg], float) for r in recs if leg in r.temperature and len(r.temperature[leg])]
    if not temps:
        return None
    T = np.concatenate(temps)
    T = T[np.isfinite(T)]
    if len(T) and np.ptp(T) > resolution_c:
        return None
    span = f"ranges {np.ptp(T):.3g} degC (at {np.mean(T):.4g} degC)" if len(T) else "holds no number"
    msg = (f"transducer {leg}: temperature column '{leg}_temp_C' (or 'temp_C') {span} over the {len(T)} samples of "
           f"{sorted({r.name for r in recs if leg in r.temperature})}, within its resolution {resolution_c:g} degC: a "
           f"temperature effect cannot be told from the offsets (collinear with them): this session does not determine "
           f"'temperature' (the diagnosis cannot name it, correct cannot apply it); a session over a range of "
           f"temperatures does (plan says how much)")
    log.warning("%s", msg)
    return msg


def check_free_load_data(recs: Sequence[Recording], leg: str, load, g: float, tree=None,
                         noise: np.ndarray | None = None, weighed_kg: float | None = None,
                         siblings_ok: Sequence[str] = (), data: AsGiven | None = None) -> None:
    """Every check before fitting, in order: the clock of a list of poses, gx..gz against qw..qz, quaternion order,
    gravity sign (and a left-handed force frame), joint angles in degrees, units. ``recs``: the recordings in which
    ``leg``'s load hangs free (whole: the clock needs consecutive rows); ``noise`` (6,) the per-sample sd of the
    readings (None: not known); ``siblings_ok`` transducers on the same recordings that follow gravity as given."""
    for rec in recs:
        check_pose_list_clock(rec, _joints(load))
        check_gravity_columns_agree(rec)
    data = data or as_given(recs, leg, load, g)   # the readings and their gravity fit, once for every check
    check_quaternion_order(recs, leg, load, g, noise, data)
    check_gravity_sign(recs, leg, load, g, siblings_ok, data)
    check_joint_degrees(recs, leg, load, g, tree, noise, data)
    check_units(recs, leg, load, g, noise, weighed_kg, data)
    check_torque_signs(recs, leg, load, g, data)
    check_temperature_varies(recs, leg)


# ----------------------------------------------------------------------------- after the fit


@dataclass(frozen=True)
class Trial:
    """A cause tried on the data: ``name`` (quaternion order, ...), ``fixes`` whether the fix makes the load
    plausible, ``text`` what it gives."""

    name: str
    fixes: bool
    text: str


def _plausible(gf: GravityFit, lf: LoadFit, noise: np.ndarray | None) -> bool:
    return gf.mass_kg > 0 and gf.angle_deg <= ROTATION_BOUND_DEG and not _residual_far(lf, noise)


def _residual_far(lf: LoadFit, noise: np.ndarray | None) -> bool:
    over_noise = not _known(noise) or np.any(lf.rms > RESIDUAL_NOISE_FACTOR * _sd(noise))
    return bool(over_noise and np.any(lf.unexplained > UNEXPLAINED_SHARE))


def _refit(recs: Sequence[Recording], leg: str, load, g: float, noise) -> tuple[GravityFit, LoadFit]:
    w, b, K = load_arrays(recs, leg, load, g)
    gf = gravity_fit(w[:, :3], b)
    return gf, load_fit(w, b, K, load.mass_row, gf.rotation, noise)


def _describe(gf: GravityFit, lf: LoadFit) -> str:
    return (f"the load mass is {gf.mass_kg:.4g} kg, the mount {gf.angle_deg:.3g} deg from the nominal and the residual "
            f"{_pct(lf)} of the readings' spread")


def _pct(lf: LoadFit) -> str:
    return f"{100 * lf.unexplained[0]:.2g} % (forces), {100 * lf.unexplained[1]:.2g} % (torques)"


def try_causes(recs: Sequence[Recording], leg: str, load, g: float, tree=None, noise: np.ndarray | None = None,
               nominal_source: str = "robot.toml", reference: Reference | None = None) -> list[Trial]:
    """The likely causes of an implausible fit, in order (quaternion order, gravity sign, degrees, frame, units), each
    tried by the linear refits with its fix applied (module docstring)."""
    out: list[Trial] = []
    gf0, lf0 = _refit(recs, leg, load, g, noise)
    fixes: list[tuple[str, str, Callable[[Recording], Recording]]] = []
    if any(r.quat is not None for r in recs):
        fixes += [("quaternion order", "with qw, qx, qy, qz read as x, y, z, w", xyzw_order),
                  ("quaternion order", "with the conjugate quaternion (world -> body)", conjugate)]
    fixes.append(("gravity sign", "with gravity reversed", reversed_gravity))
    joints = continuous_joints(load, tree, recs)
    if joints:
        fixes.append(("degrees", f"with {', '.join('q_' + j for j in joints)} read as degrees",
                      lambda r: joints_in_degrees(r, joints)))
    for name, how, fix in fixes:
        gf, lf = _refit([fix(r) for r in recs], leg, load, g, noise)
        ok = _plausible(gf, lf, noise) and not _plausible(gf0, lf0, noise)
        text = f"{how} {_describe(gf, lf)}"
        if ok and name == "quaternion order":
            text += f": the quaternion columns are likely {'in x, y, z, w order' if 'x, y, z, w' in how else 'the conjugate'}"
        elif ok and name == "gravity sign":
            text += ": " + _reversal_hint(recs, leg, gf0).split("expected a positive mass: ", 1)[1]
        elif ok:
            text += ": the joint angles are likely in degrees"
        out.append(Trial(name, ok, text))
    # frame: the weight plausible and explained, only the rotation far from the nominal
    if gf0.mass_kg > 0 and gf0.angle_deg > ROTATION_BOUND_DEG and not _residual_far(lf0, noise):
        rv = rotation_to_rotvec(gf0.rotation)
        R_nom = getattr(load, "rotation", None)      # a rigid payload's constant nominal rotation
        transposed = R_nom is not None and rotation_angle_deg(R_nom @ gf0.rotation @ R_nom) <= ROTATION_BOUND_DEG
        why = " (the data agree with its transpose: is it given B -> ft?)" if transposed else ""
        out.append(Trial("frame", True, f"as given the weight is explained ({_describe(gf0, lf0)}) with the transducer "
                                        f"turned {gf0.angle_deg:.0f} deg (rotation vector {np.round(rv, 3).tolist()} rad, in ft) "
                                        f"from its nominal frame: {nominal_source} is likely wrong{why}"))
    else:
        out.append(Trial("frame", False, "the frame: not it (the mass or the residual is off too)"))
    out += _torque_trials(recs, leg, load, g, noise, gf0, lf0)
    # units: the mass 1000x off a reference, or a force noise no transducer has in N
    m = gf0.mass_kg
    floor = _force_noise(noise)
    ref = reference.kg if reference else None
    grams = grams_hint(leg, m, reference, floor) if ref and m > 0 else None
    if grams:
        out.append(Trial("units", True, grams))
    elif reference is not None and ref and m > 0 and not 1 / UNIT_FACTOR <= m / ref <= UNIT_FACTOR:
        unit = "kN" if m < ref else "mN"
        out.append(Trial("units", True, f"the load mass {m:.4g} kg is {ref / m if m < ref else m / ref:.3g}x "
                                        f"off {reference.what} {ref:.4g} kg ({m * (1000 if unit == 'kN' else 1e-3):.4g} kg "
                                        f"with the forces read as {unit}): are the readings in {unit} (and {unit}*m)?"))
    elif 0 < floor < MIN_FORCE_NOISE_N:
        out.append(Trial("units", True, f"the force noise is {floor:.2g} N per sample, below any six-axis transducer's "
                                        f"resolution ({MIN_FORCE_NOISE_N:g} N): in kN the load mass would be {1000 * m:.4g} kg: "
                                        "are the readings in kN (and kN*m)?"))
    else:
        out.append(Trial("units", False, "units: not it"))
    return out


def _load_plausible(load, lf: LoadFit, noise: np.ndarray | None, leg: str) -> bool:
    """The load's torques explained: residual not far, no link group's mass below 0, a payload's CoM within reach."""
    return not (_residual_far(lf, noise) or negative_groups(load, lf.theta, lf.se)
                or lever_arm_problem(load, lf.theta, lf.se, leg))


def _torque_trials(recs: Sequence[Recording], leg: str, load, g: float, noise: np.ndarray | None, gf0: GravityFit,
                   lf0: LoadFit) -> list[Trial]:
    """Torque signs (the columns negated, reordered: every signed permutation, as ``checks.check_torque_axes``) and
    torque units (x1000, /1000), tried where the forces' weight is plausible and the torques are not."""
    forces_ok = gf0.mass_kg > 0 and gf0.angle_deg <= ROTATION_BOUND_DEG and lf0.unexplained[0] <= UNEXPLAINED_SHARE
    if not forces_ok or _load_plausible(load, lf0, noise, leg):
        return [Trial("torque signs", False, "torque signs: not tried (the forces, or nothing, are off)"),
                Trial("torque units", False, "torque units: not tried")]
    w, b, K = load_arrays(recs, leg, load, g)
    nz = None if noise is None else np.asarray(noise, float)

    def refit(T: np.ndarray, scale: float = 1.0) -> LoadFit:
        w2 = w.copy()
        w2[:, 3:] = scale * w[:, 3:] @ T
        n2 = None if nz is None else np.r_[nz[:3], scale * np.abs(T).T @ nz[3:]]
        return load_fit(w2, b, K, load.mass_row, gf0.rotation, n2)

    out = []
    fits = {}
    for i, P in enumerate(signed_permutations()):
        lf = refit(P)
        if _load_plausible(load, lf, noise if nz is None else np.r_[nz[:3], np.abs(P).T @ nz[3:]], leg):
            fits[i] = (P, lf)
    if fits:
        _, P = _simplest([(max(lf.unexplained[1], 1e-12), P) for P, lf in fits.values()])
        lf = next(lf for Q, lf in fits.values() if Q is P)
        what = (f"the torque readings negated ({leg}_tx..{leg}_tz: their sign convention reversed)" if np.allclose(P, -np.eye(3))
                else f"{describe_columns(P, leg, 't')} (torque columns in another order or sign)")
        out.append(Trial("torque signs", True, f"with {what} the torques are explained (residual {_pct(lf)} of the readings' "
                                               f"spread): {what.removeprefix('the ')}?"))
    else:
        out.append(Trial("torque signs", False, "torque signs: not it"))
    for scale, unit in ((1000.0, "kN*m"), (1e-3, "N*mm")):
        lf = refit(np.eye(3), scale)
        if _load_plausible(load, lf, None if nz is None else np.r_[nz[:3], scale * nz[3:]], leg):
            out.append(Trial("torque units", True, f"with {leg}_tx..{leg}_tz read as {unit} the load is plausible (residual "
                                                   f"{_pct(lf)} of the readings' spread): are the torques in {unit}?"))
            break
    else:
        out.append(Trial("torque units", False, "torque units: not it"))
    return out


def check_free_load_fit(result, recs: Sequence[Recording], g: float, tree=None, noise: np.ndarray | None = None,
                        nominal_source: str = "robot.toml", weighed_kg: float | None = None) -> None:
    """Raise :class:`~ftcal_nlp.core.errors.ImplausibleLoadFit` when the fit ``result`` (a
    :class:`~ftcal_nlp.estimate.freeload.FreeLoadResult`) is physically implausible (module docstring); ``recs`` the samples
    it used (for the causes' refits), ``noise`` (6,) the readings' per-sample sd, ``nominal_source`` the key that gives
    the transducer's nominal rotation."""
    leg, load = result.leg, result.load
    mass = float(load.mass_row @ result.theta)
    angle = rotation_angle_deg(result.rotation)
    w, b, K = load_arrays(recs, leg, load, g)
    lf = load_fit(w, b, K, load.mass_row, result.rotation, noise)
    share = np.array([np.linalg.norm(result.rms[:3]), np.linalg.norm(result.rms[3:])]) / np.maximum(lf.spread, 1e-300)
    over = result.rms / _sd(noise) if _known(noise) else np.full(6, np.inf)
    reference = reference_mass(load, weighed_kg)
    ref = reference.kg if reference else None
    # what the data leave undetermined sits at the prior (named by the fit): no bound applies to it
    mass_known = bool(np.isfinite(result.load_report().get("load_mass_se_kg", np.inf)))
    mount_known = bool(np.all(np.isfinite(result.se[-3:])))
    problems = []
    if mass <= 0 and mass_known:
        problems.append(f"a load mass of {mass:.4g} kg (expected > 0)")
    if angle > ROTATION_BOUND_DEG and mount_known:
        problems.append(f"a mounting rotation {angle:.3g} deg from the nominal (expected within the {ROTATION_BOUND_DEG:.0f} deg "
                        "bound, ROTATION_BOUND_DEG)")
    if np.any(share > UNEXPLAINED_SHARE) and np.any(over > RESIDUAL_NOISE_FACTOR):
        vs = f", {np.max(over):.3g}x the per-sample noise" if _known(noise) else ""
        problems.append(f"a residual of {100 * share[0]:.2g} % (forces) and {100 * share[1]:.2g} % (torques) of the readings' "
                        f"spread{vs} (expected below {UNEXPLAINED_SHARE:.0%} of the spread, or {RESIDUAL_NOISE_FACTOR:g}x the "
                        "noise)")
    if reference is not None and ref and mass > 0 and mass_known and not 1 / UNIT_FACTOR <= mass / ref <= UNIT_FACTOR:
        problems.append(f"a load mass of {mass:.4g} kg against {reference.what} {ref:.4g} kg (expected within {UNIT_FACTOR:g}x)")
    floor = _force_noise(noise)
    if 0 < floor < MIN_FORCE_NOISE_N:
        problems.append(f"a force noise of {floor:.2g} N per sample (no six-axis transducer resolves below "
                        f"{MIN_FORCE_NOISE_N:g} N)")
    problems += negative_groups(load, result.theta, _param_se(result))
    lever = lever_arm_problem(load, result.theta, _param_se(result), leg)
    if lever:
        problems.append(lever)
    if not problems:
        return
    trials = try_causes(recs, leg, load, g, tree, noise, nominal_source, reference)
    found = [t for t in trials if t.fixes]
    tried = ", ".join(dict.fromkeys(t.name for t in trials))
    if found:
        causes = "; ".join(t.text for t in found)
    else:
        causes = (f"none of the usual conventions ({tried}) makes the load plausible; the readings or the model miss "
                  "something large (another load on the transducer, a wrong link or transducer, a recording that is not "
                  "this load's)")
    raise ImplausibleLoadFit(
        f"{_where(recs, leg)}: the free-load fit is not physical: {'; '.join(problems)}{' ' if problems[-1].endswith('?') else '. '}"
        f"Tried in order ({tried}): {causes}",
        leg=leg, causes=tuple(t.name for t in found))


#: a URDF link group's mass this many se below 0 is no estimate of a mass
NEGATIVE_MASS_SE = 3.0


def _param_se(result) -> np.ndarray:
    """The se of ``result.theta`` (inf where not determined), by the fit's parameter names."""
    names = list(result.names)
    out = np.full(len(result.theta), np.inf)
    for i, pn in enumerate(result.load.param_names):
        for key in (f"{result.leg}.{pn}", pn):
            if key in names:
                out[i] = float(np.asarray(result.se)[names.index(key)])
                break
    return out


def negative_groups(load, theta: np.ndarray, se: np.ndarray | None) -> list[str]:
    """The URDF link groups (two or more) whose fitted mass is determined and below 0 by more than ``NEGATIVE_MASS_SE``
    se, as problems for the message."""
    names = load.param_names
    idx = [i for i, n in enumerate(names) if n.endswith("mass_kg")]
    if len(idx) < 2 or se is None:
        return []
    out = []
    for i in idx:
        m, e = float(theta[i]), float(se[i])
        if np.isfinite(e) and m < -NEGATIVE_MASS_SE * e:
            group = names[i].rsplit(".", 1)[0]
            out.append(f"a mass of {m:.4g} +- {e:.2g} kg for link group '{group}' (expected > 0; {-m / max(e, 1e-300):.0f} se "
                       "below)")
    return out


def payload_com(load, theta: np.ndarray, se: np.ndarray | None) -> np.ndarray | None:
    """A rigid payload's CoM ``h / m`` (m, ft) where its mass and first moment are determined; None otherwise."""
    if tuple(load.param_names) != ("mass_kg", "h_x", "h_y", "h_z"):
        return None
    if se is None or not np.all(np.isfinite(se)) or not theta[0] > 0:
        return None
    return np.asarray(theta[1:], float) / float(theta[0])


def lever_arm_problem(load, theta: np.ndarray, se: np.ndarray | None, leg: str) -> str | None:
    """The hexapod's lever-arm rule (``checks.check_lever_arms``) on a rigid payload: its CoM from torques over forces
    within ``LEVER_MIN_M`` to ``LEVER_MAX_M`` of the transducer, else the readings' units are named."""
    c = payload_com(load, theta, se)
    if c is None:
        return None
    r = float(np.linalg.norm(c))
    if LEVER_MIN_M <= r <= LEVER_MAX_M:
        return None
    m = float(theta[0])
    hint = (f"are the forces {leg}_fx..{leg}_fz in mN (a load mass of {m / 1000:.4g} kg read as N) or the torques "
            f"{leg}_tx..{leg}_tz in kN*m?" if r < LEVER_MIN_M else
            f"are the torques {leg}_tx..{leg}_tz in N*mm, or the forces {leg}_fx..{leg}_fz in kN (a load mass of "
            f"{1000 * m:.4g} kg read as N)?")
    return (f"the load's centre of mass {r:.3g} m from the transducer (torques over forces; expected {LEVER_MIN_M:g} to "
            f"{LEVER_MAX_M:g} m, LEVER_MIN_M..LEVER_MAX_M, with forces in N and torques in N*m): {hint}")


class Reference(NamedTuple):
    """A mass to hold the load's against: ``kg`` and ``what`` it is, for the messages."""

    kg: float
    what: str


def reference_mass(load, weighed_kg: float | None = None) -> Reference | None:
    """The load's weighed mass (``[transducers.X] load_mass_kg``: a measurement) where given, else the URDF's nominal
    total mass of the load (its prior); None without either."""
    if weighed_kg is not None and weighed_kg > 0:
        return Reference(float(weighed_kg), "the weighed load_mass_kg")
    prior = load.prior() if hasattr(load, "prior") else None
    if prior is None:
        return None
    m = float(np.asarray(load.mass_row) @ np.asarray(prior, float))
    return Reference(m, "the URDF's nominal") if m > 0 else None


def weighed_mass_note(result, weighed_kg: float | None, z_min: float = 5.0, rel_min: float = 0.01) -> str | None:
    """A note when the fitted load mass differs from the weighed one by more than ``z_min`` se and ``rel_min`` of it: a
    gain of the force channels (or the weighing) the readings alone cannot tell from the mass; None otherwise."""
    if weighed_kg is None:
        return None
    rep_ = result.load_report()
    m, se = float(rep_["load_mass_kg"]), float(rep_.get("load_mass_se_kg", np.inf))
    d = m - weighed_kg
    if not np.isfinite(se) or abs(d) <= max(z_min * se, rel_min * weighed_kg):
        return None
    return (f"transducer {result.leg}: the fitted load mass {m:.5g} +- {se:.2g} kg differs from the weighed load_mass_kg "
            f"{weighed_kg:.5g} kg by {100 * d / weighed_kg:+.2g} % ({abs(d) / se:.0f} se): a gain of the force channels (or "
            "the weighing); the calibration keeps the fitted mass, which the contact wrench needs as the sensor reads it")


def nominal_rotation_source(ds, leg: str) -> str:
    """The key that gives transducer ``leg``'s nominal rotation, for the messages."""
    tr = ds.robot.transducers[leg]
    robot = str(ds.robot_path or "robot.toml")
    if tr.link is not None and ds.robot.tree is not None:
        j = ds.robot.tree.joints.get(tr.link)
        joint = f"joint '{j.name}' (origin rpy)" if j is not None else "the joints"
        return f"the URDF's rotation of link '{tr.link}' ({joint} above it in {ds.robot.urdf})"
    return f"[transducers.{leg}] rotation in {robot} (expected ft -> B)"
