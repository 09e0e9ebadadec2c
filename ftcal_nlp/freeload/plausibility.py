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
  rigid payload in mN has no reference and is not caught).

After fitting (:func:`check_free_load_fit`) the fit is an error when the load mass is ``<= 0``, the mounting
rotation lies farther than ``ROTATION_BOUND_DEG`` (the hexapod's, 20 deg) from the nominal, the residual leaves
more than ``UNEXPLAINED_SHARE`` of the readings' spread over the holds unexplained while it is over
``RESIDUAL_NOISE_FACTOR`` times the noise, or the mass is ``UNIT_FACTOR`` times off the URDF's nominal total mass
(or, without one, the force noise is below ``MIN_FORCE_NOISE_N``: no six-axis transducer resolves that in N). The
residual's share, not its ratio to the noise alone: every simulator effect on a free load (``sim/free``, seed 3)
leaves 1-60x the noise (the diagnosis' business) but at most 3 % of the spread, while a convention error leaves
20-100 %. The error tries the likely causes in order, each by the linear refits above with the fix applied:
quaternion order, gravity sign (or the readings negated: the same data), joint angles in degrees, the frame
(mass positive, residual small, rotation far: the transducer's nominal rotation, in ``robot.toml`` or the URDF,
is wrong, or given B -> ft), units (kN or mN: the mass 1000x off), and names those that make the load plausible.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..checks import (
    DEGREES_RATIO,
    QUAT_ORDER_RATIO,
    RESIDUAL_NOISE_FACTOR,
    ROTATION_BOUND_DEG,
)
from ..data import Recording
from ..errors import DataFormatError, ImplausibleLoadFit
from ..geometry import quat_to_rotation, rotation_to_rotvec

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
    return GravityFit(m, R.T, fm - m * bm @ R.T, float(np.sqrt(rss / n)), spread, span, determined)


@dataclass(frozen=True)
class LoadFit:
    """The load's whole model at a fixed mounting rotation, fitted linearly: ``theta`` (p,), ``offset`` (6,),
    ``rms`` (6,) residual RMS per channel, ``spread`` (2,) the forces' and torques' RMS about their mean (norms),
    ``unexplained`` (2,) the residual's share of them, ``mass_kg`` ``mu . theta``."""

    theta: np.ndarray
    offset: np.ndarray
    rms: np.ndarray
    spread: np.ndarray
    unexplained: np.ndarray
    mass_kg: float


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
    x = np.linalg.lstsq(Xw, yw, rcond=None)[0]
    res = w - np.einsum("nik,k->ni", X, x)
    rms = np.sqrt(np.mean(res**2, axis=0))
    wc = w - w.mean(axis=0)
    spread = np.array([np.sqrt(np.mean(np.sum(wc[:, :3] ** 2, axis=1))), np.sqrt(np.mean(np.sum(wc[:, 3:] ** 2, axis=1)))])
    resn = np.array([np.sqrt(np.mean(np.sum(res[:, :3] ** 2, axis=1))), np.sqrt(np.mean(np.sum(res[:, 3:] ** 2, axis=1)))])
    return LoadFit(x[6:], x[:6], rms, spread, resn / np.maximum(spread, 1e-300), float(np.asarray(mu) @ x[6:]))


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


def check_quaternion_order(recs: Sequence[Recording], leg: str, load, g: float, noise: np.ndarray | None = None) -> None:
    """Raise when another reading of the columns qw..qz explains the forces far better (module docstring)."""
    if not any(r.quat is not None for r in recs):
        return
    w, b, _ = load_arrays(recs, leg, load, g)
    given = gravity_fit(w[:, :3], b)
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


def check_gravity_sign(recs: Sequence[Recording], leg: str, load, g: float) -> None:
    """Raise when the forces follow reversed gravity where three gravity directions tell it (module docstring)."""
    w, b, _ = load_arrays(recs, leg, load, g)
    fit = gravity_fit(w[:, :3], b)
    if fit.sign_determined and fit.mass_kg < 0:
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


def check_joint_degrees(recs: Sequence[Recording], leg: str, load, g: float, tree, noise: np.ndarray | None = None) -> None:
    """Raise when the load's model fits far better with the continuous joints' columns read as degrees."""
    joints = continuous_joints(load, tree, recs)
    if not joints:
        return
    given = _weighted_rss(recs, leg, load, g, noise)
    alt = _weighted_rss([joints_in_degrees(r, joints) for r in recs], leg, load, g, noise)
    if alt * DEGREES_RATIO < given:
        cols = ", ".join(f"q_{j}" for j in joints)
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {cols} (continuous joints of the URDF): the load's model leaves "
            f"{given / alt:.3g}x less residual with them read as degrees than as radians (expected below {DEGREES_RATIO:g}x); "
            "expected radians: are the joint angles in degrees?", column=f"q_{joints[0]}")


def _weighted_rss(recs: Sequence[Recording], leg: str, load, g: float, noise: np.ndarray | None) -> float:
    w, b, K = load_arrays(recs, leg, load, g)
    gf = gravity_fit(w[:, :3], b)
    lf = load_fit(w, b, K, load.mass_row, gf.rotation, noise)
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
                weighed_kg: float | None = None) -> None:
    """Raise when the weight in the forces is ``UNIT_FACTOR`` times off the load's reference mass (:func:`reference_mass`:
    weighed, else the URDF's nominal), or (without one) the force noise lies below ``MIN_FORCE_NOISE_N``: the readings
    are in kN (or mN)."""
    w, b, _ = load_arrays(recs, leg, load, g)
    fit = gravity_fit(w[:, :3], b)
    reference = reference_mass(load, weighed_kg)
    ref = reference.kg if reference else None
    m = abs(fit.mass_kg)
    if ref and np.isfinite(m) and not 1 / UNIT_FACTOR <= m / ref <= UNIT_FACTOR:
        unit = "kN" if m < ref else "mN"
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {leg}_fx..{leg}_fz: the load's weight in the forces is {m * g:.4g} N, a mass of "
            f"{m:.4g} kg against {reference.what} {ref:.4g} kg (expected within {UNIT_FACTOR:g}x; {m * (1000 if unit == 'kN' else 1e-3):.4g} "
            f"kg with the readings read as {unit}): expected N and N*m: are the readings in {unit} (and {unit}*m)?",
            column=f"{leg}_fx")
    floor = _force_noise(noise)
    if not ref and 0 < floor < MIN_FORCE_NOISE_N:
        raise DataFormatError(
            f"{_where(recs, leg)}: columns {leg}_fx..{leg}_fz: the per-sample noise is {floor:.2g} N, below any six-axis "
            f"transducer's resolution ({MIN_FORCE_NOISE_N:g} N), with a load mass of {m:.4g} kg ({1000 * m:.4g} kg read as "
            "kN): expected N and N*m: are the readings in kN (and kN*m)?", column=f"{leg}_fx")


def check_free_load_data(recs: Sequence[Recording], leg: str, load, g: float, tree=None,
                         noise: np.ndarray | None = None, weighed_kg: float | None = None) -> None:
    """Every check before fitting, in order: quaternion order, gravity sign, joint angles in degrees, units. ``recs``: the
    recordings in which ``leg``'s load hangs free (its quasi-static rows, or a recording to correct); ``noise`` (6,)
    the per-sample sd of the readings (None: not known)."""
    check_quaternion_order(recs, leg, load, g, noise)
    check_gravity_sign(recs, leg, load, g)
    check_joint_degrees(recs, leg, load, g, tree, noise)
    check_units(recs, leg, load, g, noise, weighed_kg)


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
    # units: the mass 1000x off a reference, or a force noise no transducer has in N
    m = gf0.mass_kg
    floor = _force_noise(noise)
    ref = reference.kg if reference else None
    if ref and m > 0 and not 1 / UNIT_FACTOR <= m / ref <= UNIT_FACTOR:
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


def check_free_load_fit(result, recs: Sequence[Recording], g: float, tree=None, noise: np.ndarray | None = None,
                        nominal_source: str = "robot.toml", weighed_kg: float | None = None) -> None:
    """Raise :class:`~ftcal_nlp.errors.ImplausibleLoadFit` when the fit ``result`` (a
    :class:`~ftcal_nlp.freeload.FreeLoadResult`) is physically implausible (module docstring); ``recs`` the samples
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
        problems.append(f"a mounting rotation {angle:.3g} deg from the nominal (expected within {ROTATION_BOUND_DEG:.0f} deg, "
                        "the bound of a hexapod's legs)")
    if np.any(share > UNEXPLAINED_SHARE) and np.any(over > RESIDUAL_NOISE_FACTOR):
        vs = f", {np.max(over):.3g}x the per-sample noise" if _known(noise) else ""
        problems.append(f"a residual of {100 * share[0]:.2g} % (forces) and {100 * share[1]:.2g} % (torques) of the readings' "
                        f"spread{vs} (expected below {UNEXPLAINED_SHARE:.0%} of the spread, or {RESIDUAL_NOISE_FACTOR:g}x the "
                        "noise)")
    if ref and mass > 0 and mass_known and not 1 / UNIT_FACTOR <= mass / ref <= UNIT_FACTOR:
        problems.append(f"a load mass of {mass:.4g} kg against {reference.what} {ref:.4g} kg (expected within {UNIT_FACTOR:g}x)")
    floor = _force_noise(noise)
    if 0 < floor < MIN_FORCE_NOISE_N:
        problems.append(f"a force noise of {floor:.2g} N per sample (no six-axis transducer resolves below "
                        f"{MIN_FORCE_NOISE_N:g} N)")
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
        f"{_where(recs, leg)}: the free-load fit is not physical: {'; '.join(problems)}. Tried in order ({tried}): {causes}",
        leg=leg, causes=tuple(t.name for t in found))


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
