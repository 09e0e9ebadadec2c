"""The recording ``correct`` reads for free loads, checked as a run reads its own and against the calibration.

Gravity of a recording without orientation columns (joints only: an arm on its fixed base): ``g`` times the
calibration's ``gravity_body`` (per transducer, the direction its fit used for the base: the manifest's
``gravity_body`` with the recording's estimated tilt, ``recording_tilt_rad``, applied, written by the run where every
recording it used gave gravity by ``gravity_body`` alone and they agree, ``freeload.estimate.fixed_base_gravity``),
or ``correct --gravity-body X Y Z`` (B axes, normalised; it wins over the calibration's and is said in the log).
The tilt's uncertainty (tens of microradians on the shared arm) is left out of the se. A recording with orientation
columns uses them; with neither, the error names both ways.

Checks, before anything is corrected: the calibration as read (``calibration.read_calibration_json``, the one reader
of ``calibration.json``: finite numbers, proper rotations, one mounting rotation, a positive load mass); the
recording as a run reads its own (:func:`clean_rows`: the transducers match the calibration's, no empty table, no
column without a number, ``t`` strictly increasing, unit quaternions) and against the calibration
(:func:`check_against_calibration`: the forces' unit from the load's predicted weight, the orientation columns'
convention from its direction). A recording mostly in contact cannot test the convention: a warning, not an error.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.checks import MAX_SAMPLE_INTERVAL_S, reread_quaternion, same_pose_share
from ..core.data import GRAVITY_COLUMNS, JOINT_PREFIX, QUAT_COLUMNS, WRENCH_COMPONENTS
from ..effects.correction import stream_members
from ..core.errors import ConfigError, DataFormatError
from ..core.geometry import quat_to_rotation

log = logging.getLogger(__name__)


def orientation_of_frame(df: pd.DataFrame) -> np.ndarray | None:
    """``R_WB`` (N, 3, 3) from ``qw..qz`` (normalised; NaN rows where missing), or None without those columns."""
    if not set(QUAT_COLUMNS) <= set(map(str, df.columns)):
        return None
    q = df[list(QUAT_COLUMNS)].to_numpy(float)
    ok = np.all(np.isfinite(q), axis=1)
    out = np.full((len(q), 3, 3), np.nan)
    out[ok] = quat_to_rotation(q[ok] / np.linalg.norm(q[ok], axis=1, keepdims=True))
    return out


def gravity_of_frame(df: pd.DataFrame, g: float, where: str, base: np.ndarray | None = None) -> np.ndarray:
    """Gravity in B (N, 3), m/s^2, from ``qw..qz`` (``R_WB^T [0, 0, -g]``) or ``gx..gz`` (normalised, times g);
    NaN rows where the orientation is missing. Without those columns, ``g base`` for every row (``base`` the fixed
    base's unit gravity direction in B, :func:`base_gravity`); without a base either, an error."""
    cols = set(map(str, df.columns))
    if set(QUAT_COLUMNS) <= cols:
        q = df[list(QUAT_COLUMNS)].to_numpy(float)
        ok = np.all(np.isfinite(q), axis=1)
        out = np.full((len(q), 3), np.nan)
        out[ok] = -g * quat_to_rotation(q[ok] / np.linalg.norm(q[ok], axis=1, keepdims=True))[:, 2, :]
        return out
    if set(GRAVITY_COLUMNS) <= cols:
        v = df[list(GRAVITY_COLUMNS)].to_numpy(float)
        return g * v / np.linalg.norm(v, axis=1, keepdims=True)
    if base is not None:
        return np.broadcast_to(g * np.asarray(base, float), (len(df), 3)).copy()
    raise DataFormatError(f"{where}: the contact wrench needs gravity: columns qw, qx, qy, qz or gx, gy, gz, or for a fixed "
                          "base its direction (the calibration's gravity_body, or correct --gravity-body X Y Z)", path=where)


def base_gravity(cal_legs: dict, df: pd.DataFrame, where: str, option=None) -> dict[str, np.ndarray | None]:
    """Per transducer the fixed base's unit gravity direction in B for a recording without ``qw..qz`` / ``gx..gz``
    (None with them: they give it per sample): ``option`` (``--gravity-body``) where given, else the calibration's
    ``gravity_body``; neither is an error naming both ways. Said in the log."""
    cols = set(map(str, df.columns))
    if set(QUAT_COLUMNS) <= cols or set(GRAVITY_COLUMNS) <= cols:
        if option is not None:
            log.warning("%s: --gravity-body ignored: the recording gives gravity per sample (its orientation columns)", where)
        return {k: None for k in cal_legs}
    if option is not None:
        v = np.asarray(option, float)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
            raise ConfigError(f"--gravity-body {option}: expected three finite numbers, not all zero (gravity's direction "
                              "in B, pointing down)", key="--gravity-body")
        log.info("%s: no orientation columns: gravity along --gravity-body %s (B, normalised) for every sample", where,
                 np.round(v / np.linalg.norm(v), 6).tolist())
        return {k: v / np.linalg.norm(v) for k in cal_legs}
    missing = [k for k, p in cal_legs.items() if getattr(p, "gravity_body", None) is None]
    if missing:
        raise DataFormatError(f"{where}: no orientation columns (qw, qx, qy, qz or gx, gy, gz) and the calibration of {missing} "
                              "keeps no fixed base's gravity_body (it was made with gravity per sample or several held "
                              "orientations); expected orientation columns, or the base's gravity direction in B: correct "
                              "--gravity-body X Y Z (e.g. 0 0 -1 for a level base)", path=where)
    for k, p in cal_legs.items():
        log.info("%s: no orientation columns: transducer %s's gravity along the calibration's gravity_body %s (the fixed "
                 "base at calibration, its estimated tilt applied) for every sample", where, k,
                 np.round(p.gravity_body, 6).tolist())
    return {k: np.asarray(p.gravity_body, float) for k, p in cal_legs.items()}



def joint_angles(df: pd.DataFrame, joints: tuple[str, ...], tree, where: str) -> dict[str, np.ndarray]:
    """``q_{joint}`` columns of ``df`` for ``joints`` (rad; checked against the URDF limits: degrees are an error),
    a joint without a column held at 0 and named in a warning."""
    from ..core.data import check_joint_units

    missing = [j for j in joints if f"{JOINT_PREFIX}{j}" not in df.columns]
    if missing:
        log.warning("%s: joints %s have no column (%s): held at 0", where, missing, [f"{JOINT_PREFIX}{j}" for j in missing])
    q = {j: pd.to_numeric(df[f"{JOINT_PREFIX}{j}"], errors="coerce").to_numpy(float) for j in joints if j not in missing}
    fin = {j: v[np.isfinite(v)] for j, v in q.items()}
    check_joint_units({j: v for j, v in fin.items() if v.size}, tree, where)
    return q


#: readings whose median force norm is this many times above or below what the calibration predicts (offset plus
#: the load's weight) are in another unit: kN or mN are 1000x off; a tool pressing on something for most of a
#: recording stays well within (a 0.1 kg probe held at 50 N: ~50x)
UNIT_FACTOR = 100.0
#: the load's weight must stand this many noise sd above the readings' noise for its direction to test the
#: orientation columns (a light load in a noisy sensor says nothing about them)
DIRECTION_SNR = 10.0
#: rows of a long recording the checks against the calibration look at (a regular subsample)
CHECK_ROWS = 5000


def recorded_transducers(df: pd.DataFrame) -> tuple[str, ...]:
    """Names ``X`` for which the table holds every wrench column ``X_fx`` .. ``X_tz`` (a free load has no ``X_phi``)."""
    names = [str(c)[: -len("_fx")] for c in df.columns if str(c).endswith("_fx")]
    return tuple(k for k in names if all(f"{k}_{c}" in df.columns for c in WRENCH_COMPONENTS))


def check_transducers(cal_legs: dict, df: pd.DataFrame, where: str) -> None:
    """The recording carries exactly the calibration's transducers: one it lacks (columns ``X_fx..X_tz`` the
    calibration has no entry for) or one of the calibration's missing from it is an error naming the columns."""
    legs = list(cal_legs)
    extra = [k for k in recorded_transducers(df) if k not in cal_legs]
    if extra:
        raise DataFormatError(f"{where}: columns {extra[0]}_fx..{extra[0]}_tz of transducer(s) {extra} but the calibration "
                              f"covers only {legs}; expected a calibration of every transducer of the recording (or drop "
                              "those columns)", path=where, column=f"{extra[0]}_fx")
    missing = [f"{k}_{c}" for k in legs for c in WRENCH_COMPONENTS if f"{k}_{c}" not in df.columns]
    if missing:
        raise DataFormatError(f"{where}: missing column(s) {missing} of the calibrated transducer(s) {legs}; expected the "
                              "readings of every transducer of the calibration", path=where, column=missing[0])


def check_joint_columns(cal_legs: dict, df: pd.DataFrame, where: str) -> None:
    """Every ``q_{joint}`` column names a joint of the calibration's URDF (as ``run`` reads its recordings): a
    misspelt joint would otherwise be held at 0 in silence. A calibration without a URDF reads no joint column."""
    trees = [c.tree for c in cal_legs.values() if c.tree is not None]
    if not trees:
        return
    names = list(dict.fromkeys(j.name for tr in trees for j in tr.joints.values()))
    for c in map(str, df.columns):
        if c.startswith(JOINT_PREFIX) and c[len(JOINT_PREFIX):] not in names:
            raise DataFormatError(f"{where}: column '{c}': the calibration's URDF has no joint '{c[len(JOINT_PREFIX):]}' "
                                  f"(joints: {names}); expected q_{{joint}} columns of its joints (a misspelt name?)",
                                  path=where, column=c)


def _orientation_columns(df: pd.DataFrame, where: str) -> list[str]:
    """``qw..qz`` or ``gx..gz`` (complete), the gravity per sample; [] without either (a fixed base)."""
    from ..core.data import complete_group

    cols = [str(c) for c in df.columns]
    q, gcols = complete_group(cols, QUAT_COLUMNS, where), complete_group(cols, GRAVITY_COLUMNS, where)
    return q or gcols   # neither: a fixed base's gravity (base_gravity)


def clean_rows(cal_legs: dict, df: pd.DataFrame, where: str) -> tuple[pd.DataFrame, np.ndarray]:
    """The recording's columns ``correct`` reads as numbers, checked as a run reads its recordings (``data.py``): a
    cell that is not a number or a column without one is an error naming it; rows with a NaN time, reading or joint
    angle, and rows without an orientation, are dropped (counted in the log); fewer than two rows left, ``t`` not
    strictly increasing or not in seconds where the correction uses the clock (:func:`_check_clock`), quaternions not
    of norm 1 within 0.01 are
    errors naming the file and the column. Returns the numeric table of the kept rows and the kept-row mask."""
    from ..core.data import TEMP_COMMON, TEMP_SUFFIX, numeric_values

    if "t" not in df.columns:
        raise DataFormatError(f"{where}: missing column 't'", path=where, column="t")
    check_transducers(cal_legs, df, where)
    if len(df) == 0:
        raise DataFormatError(f"{where}: no rows (only the header); expected a recording to correct", path=where)
    orient = _orientation_columns(df, where)
    check_joint_columns(cal_legs, df, where)
    joints = [f"{JOINT_PREFIX}{j}" for c in cal_legs.values() for j in c.joints if f"{JOINT_PREFIX}{j}" in df.columns]
    joints = list(dict.fromkeys(joints))
    read = ["t"] + [f"{k}_{c}" for k in cal_legs for c in WRENCH_COMPONENTS] + joints
    known = set(read) | set(QUAT_COLUMNS) | set(GRAVITY_COLUMNS) | {TEMP_COMMON} | {f"{k}{TEMP_SUFFIX}" for k in cal_legs}
    extra = [str(c) for c in df.columns if str(c) not in known and not str(c).startswith(JOINT_PREFIX)]
    if extra:
        log.warning("%s: extra column(s) ignored: %s", where, extra)
    values = numeric_values(df, read + orient, where)
    n = len(df)
    ok_read = np.all(np.isfinite(values[:, :len(read)]), axis=1)
    ok_o = np.all(np.isfinite(values[:, len(read):]), axis=1)
    if orient == list(GRAVITY_COLUMNS):
        ok_o &= np.linalg.norm(values[:, len(read):], axis=1) > 0
    if (~ok_read).any():
        log.warning("%s: dropped %d of %d rows with NaN or infinite readings%s", where, int((~ok_read).sum()), n,
                    " or joint angles" if joints else "")
    if (ok_read & ~ok_o).any():
        log.warning("%s: dropped %d of %d rows without an orientation (%s)", where, int((ok_read & ~ok_o).sum()), n,
                    ", ".join(orient))
    keep = ok_read & ok_o
    if keep.sum() < 2:
        raise DataFormatError(f"{where}: fewer than 2 rows with finite readings and an orientation ({int(keep.sum())} of {n}); "
                              "expected a recording", path=where)
    clean = pd.DataFrame(values[keep], columns=read + orient)
    t = clean["t"].to_numpy()
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        row = int(np.flatnonzero(keep)[i + 1]) + 2   # the file's line (header is line 1)
        raise DataFormatError(f"{where}: column 't' is not strictly increasing (line {row}: {float(t[i])!r} -> {float(t[i + 1])!r}); expected "
                              "one row per sample in time order", path=where, column="t")
    _check_clock(cal_legs, t, where)
    check_holds_clock(t, clean, orient, joints, where)
    if orient == list(QUAT_COLUMNS):
        norms = np.linalg.norm(clean[list(QUAT_COLUMNS)].to_numpy(), axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-2):
            raise DataFormatError(f"{where}: columns qw, qx, qy, qz are not unit quaternions (norms {norms.min():.3g}.."
                                  f"{norms.max():.3g}); expected norm 1 within 0.01", path=where, column="qw")
    return clean, keep


def _check_clock(cal_legs: dict, t: np.ndarray, where: str) -> None:
    """Column ``t`` in seconds where the correction uses the clock: a calibration with effects that follow the
    readings' own clock (``effects.correction.stream_members``: re-sampling, relaxation) needs a stream, and a
    median sampling interval above ``checks.MAX_SAMPLE_INTERVAL_S`` is a clock in ms or a list of single-row poses.
    Otherwise ``t`` is copied as it is (a list of poses 9 s apart is a fine recording of a payload)."""
    need = {k: stream_members(p.effects) for k, p in cal_legs.items()
            if p.effects is not None}
    need = {k: v for k, v in need.items() if v}
    dt = float(np.median(np.diff(t)))
    if need and dt > MAX_SAMPLE_INTERVAL_S:
        leg, names = next(iter(need.items()))
        raise DataFormatError(
            f"{where}: column t: median sampling interval {dt:.4g} (units of t); {leg}'s calibration corrects for "
            f"{', '.join(names)}, which follow the readings' own clock: expected seconds, at most {MAX_SAMPLE_INTERVAL_S:g} s "
            "between the samples of a stream: is t in milliseconds, or is this a list of single-row poses (correct "
            "those with calibration.json)?", path=where, column="t")


#: a median interval of ``t`` above this (units of t) between rows that mostly share their pose is milliseconds:
#: a stream of holds at 100 Hz in ms has 10 units between samples; single-row poses seconds apart differ row to row
HOLD_CLOCK_DT = MAX_SAMPLE_INTERVAL_S
#: consecutive rows closer than this (deg of orientation, rad of each joint) share a pose
SAME_POSE_DEG = 0.5
SAME_JOINT_RAD = 0.01


def same_pose_fraction(clean: pd.DataFrame, orient: list[str], joints: list[str]) -> float:
    """The fraction of consecutive rows that share their pose: orientation (``qw..qz`` or ``gx..gz``) within
    ``SAME_POSE_DEG`` and every joint column within ``SAME_JOINT_RAD``; nan without either."""
    if len(clean) < 2:
        return float("nan")
    ang = None
    if orient:
        v = clean[orient].to_numpy(float)
        v = v / np.linalg.norm(v, axis=1, keepdims=True)
        dot = np.abs(np.einsum("ni,ni->n", v[1:], v[:-1])) if orient == list(QUAT_COLUMNS) else np.einsum("ni,ni->n", v[1:], v[:-1])
        ang = np.degrees(np.arccos(np.clip(dot, -1, 1))) * (2 if orient == list(QUAT_COLUMNS) else 1)
    steps = np.diff(clean[joints].to_numpy(float), axis=0) if joints else None
    return same_pose_share(ang, steps, SAME_POSE_DEG, SAME_JOINT_RAD)


def check_holds_clock(t: np.ndarray, clean: pd.DataFrame, orient: list[str], joints: list[str], where: str) -> None:
    """Column ``t`` in seconds, as ``run`` reads a stream of holds: a median interval above ``HOLD_CLOCK_DT`` units
    of t where most consecutive rows share their pose (:func:`same_pose_fraction`) is a clock in milliseconds; a
    list of single-row poses (each row another pose) is left as it is."""
    if len(t) < 3:
        return
    dt = float(np.median(np.diff(t)))
    if dt <= HOLD_CLOCK_DT:
        return
    same = same_pose_fraction(clean, orient, joints)
    if same > 0.5:
        raise DataFormatError(
            f"{where}: column t: median sampling interval {dt:.4g} (units of t) while {100 * same:.0f} % of consecutive rows "
            f"share their pose ({', '.join((orient or []) + joints)} within {SAME_POSE_DEG:g} deg / {SAME_JOINT_RAD:g} rad): "
            f"a stream of holds, not a list of poses; expected seconds, at most {HOLD_CLOCK_DT:g} s between the samples of "
            "a hold: is t in milliseconds?", path=where, column="t")


def _alternatives(df: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """The same rows read with the usual convention slips of the orientation columns: the quaternion's other
    orders and its conjugate (``checks.quaternion_readings``, the run's list), or gravity ``gx..gz`` negated."""
    if set(QUAT_COLUMNS) <= set(df.columns):
        from ..core.checks import quaternion_readings

        q = df[list(QUAT_COLUMNS)].to_numpy()
        out = {}
        for what, v in quaternion_readings().items():
            alt = df.copy()
            alt[list(QUAT_COLUMNS)] = reread_quaternion(q, v)
            out[what] = alt
        return out
    alt = df.copy()
    alt[list(GRAVITY_COLUMNS)] = -df[list(GRAVITY_COLUMNS)].to_numpy()
    return {"columns gx, gy, gz point up (a raw accelerometer reads +g when still: negate them)": alt}


def _load_angles(p, df: pd.DataFrame, w: np.ndarray, q: dict, where: str,
                 base: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per row the angle (deg) between the reading's force less the offset and the calibration's load force,
    and the calibration's full predicted wrench (offset and load) (N, 6); ``base`` as :func:`gravity_of_frame`."""
    from ..core.checks import angle_deg

    g_B = gravity_of_frame(df, p.g, where, base)
    model, _ = p.predict(g_B, q, orientation_of_frame(df))
    return angle_deg(w[:, :3] - p.offset[:3], model[:, :3] - p.offset[:3]), model


def check_against_calibration(cal_legs: dict, clean: pd.DataFrame, where: str, base: dict | None = None,
                              base_source: str = "", faulty: dict[str, np.ndarray] | None = None) -> None:
    """The readings against what the calibration predicts for them (every transducer, a regular subsample of
    ``CHECK_ROWS`` rows), as ``run`` checks its recordings against the robot: the forces' unit (median force norm
    within ``UNIT_FACTOR`` of the prediction's; torques within the run's lever-arm bound of the forces,
    ``data._check_units``), and, where the load's weight stands ``DIRECTION_SNR`` noise sd above the noise, the
    orientation columns' convention: the load force's direction from the columns as given must agree with the
    readings' best (median angle within ``checks.TILT_DEG``), else an error names the reading of the columns that
    agrees (x, y, z, w order; the conjugate; gravity negated). Without orientation columns, the fixed base's
    gravity (``base`` per transducer, :func:`base_gravity`; ``base_source`` where it came from, for the message) is
    tested the same way (negated: pointing up). Before the direction, the rows without contact test the frames
    (:func:`check_frames`; ``faulty`` per transducer the rows of a stuck or dead channel, left out). ``clean``'s
    readings are those the calibration's model predicts: ``correct/free.py`` passes them corrected for the named
    effects and mapped by a sensor matrix, where the calibration has either (a temperature's shift of the offsets
    would leave no raw row at the noise)."""
    from ..core.checks import QUAT_ORDER_RATIO, TILT_DEG
    from ..core.data import check_torque_units

    step = max(1, -(-len(clean) // CHECK_ROWS))
    every = clean.iloc[::step].reset_index(drop=True)
    base = base or {}
    for k, p in cal_legs.items():
        ok = np.ones(len(every), bool) if not faulty or k not in faulty else ~np.asarray(faulty[k], bool)[::step]
        if not ok.any():
            continue   # every row of a stuck or dead channel: said by the fault's warning
        sub = every[ok].reset_index(drop=True)
        w = sub[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy()
        q = {j: sub[f"{JOINT_PREFIX}{j}"].to_numpy() for j in p.joints if f"{JOINT_PREFIX}{j}" in sub.columns}
        gb = base.get(k)
        ang, model = _load_angles(p, sub, w, q, where, gb)
        f_read = float(np.median(np.linalg.norm(w[:, :3], axis=1)))
        f_pred = float(np.median(np.linalg.norm(model[:, :3], axis=1)))
        noise_f = float(np.linalg.norm(np.nan_to_num(np.asarray(p.sigma, float)[:3])))
        if f_pred > DIRECTION_SNR * noise_f and not 1 / UNIT_FACTOR <= f_read / f_pred <= UNIT_FACTOR:
            raise DataFormatError(
                f"{where}: columns {k}_fx..{k}_fz: median force {f_read:.4g} where the calibration predicts {f_pred:.4g} N "
                f"(offset plus the load's weight), {f_read / f_pred:.3g}x; expected N, within a factor {UNIT_FACTOR:g}: are the "
                "forces in another unit (kN, mN)?", path=where, column=f"{k}_fx")
        check_torque_units(w, f_pred, where, k)
        pending = check_frames(p, k, sub, w, q, where, gb)   # an orientation reading's error: after the direction's
        weight = float(np.median(np.linalg.norm(model[:, :3] - p.offset[:3], axis=1)))
        given = float(np.median(ang))
        if weight <= DIRECTION_SNR * noise_f or given <= TILT_DEG:
            if pending is not None:
                raise pending
            continue
        if gb is not None:
            alt = {"the gravity direction is negated (it points down in B: e.g. 0 0 -1 for a level base)":
                   float(np.median(_load_angles(p, sub, w, q, where, -gb)[0]))}
        else:
            alt = {what: float(np.median(_load_angles(p, a, w, q, where)[0])) for what, a in _alternatives(sub).items()}
        best = min(alt, key=lambda w: alt[w])
        cols = "qw, qx, qy, qz" if set(QUAT_COLUMNS) <= set(sub.columns) else "gx, gy, gz"
        if gb is not None and alt[best] <= TILT_DEG and alt[best] < QUAT_ORDER_RATIO * given:
            raise DataFormatError(
                f"{where}: no orientation columns; gravity along {base_source or 'the fixed base'} {np.round(gb, 4).tolist()}: "
                f"the load's weight along it is a median {given:.0f} deg from transducer {k}'s force readings less the "
                f"calibration's offset; expected within {TILT_DEG:.0f} deg: they agree within {alt[best]:.0f} deg if "
                f"{best}", path=where, column="gravity_body")
        if gb is not None:
            if pending is not None:
                raise pending
            log.warning("%s: the load's weight along %s is a median %.0f deg from transducer %s's force readings less the "
                        "offset: contact for most of the recording, another base orientation than the calibration's, or joint "
                        "angles off (a joint without its column, another zero)?",
                        where, base_source or "the fixed base's gravity", given, k)
            continue
        if alt[best] <= TILT_DEG and alt[best] < QUAT_ORDER_RATIO * given:
            raise DataFormatError(
                f"{where}: columns {cols}: the load's weight from them is a median {given:.0f} deg from transducer {k}'s force "
                f"readings less the calibration's offset; expected within {TILT_DEG:.0f} deg (DATA_FORMAT.md section 3: qw..qz "
                f"map B to the world, gx..gz point down): they agree within {alt[best]:.0f} deg if {best}",
                path=where, column=cols.split(",")[0])
        if pending is not None:
            raise pending
        log.warning("%s: columns %s: the load's weight from them is a median %.0f deg from transducer %s's force readings "
                    "less the offset and no other reading of the columns agrees: contact for most of the recording, or a "
                    "calibration of another mounting?", where, cols, given, k)


#: a row is at the noise (no contact) when its residual's norm, forces or torques, is within this many times the
#: norm of the readings' noise sd (3 components: a chi of 3 dof exceeds 5 sd with probability ~1e-5)
FREE_K = 5.0
#: the rows at the noise the frame checks need (of the regular subsample) before they test anything
MIN_FREE_ROWS = 20
#: a reading of the columns is named where it puts this many times more rows at the noise than the columns as
#: given, and at least MIN_FREE_ROWS of them (a recording mostly in contact leaves few rows to either)
FIX_RATIO = 5.0
#: the torques' other units tried (N*mm, kN*m)
TORQUE_SCALES = {"the torques are in N*mm (x0.001 turns them into N*m)": 1e-3,
                 "the torques are in kN*m (x1000 turns them into N*m)": 1e3}


def _describe_signed(P: np.ndarray, names: tuple[str, ...]) -> str:
    """``fx <- -fy, ...`` for the rows of a signed permutation that differ from the identity."""
    out = []
    for i, n in enumerate(names):
        j = int(np.argmax(np.abs(P[i])))
        if j == i and P[i, j] < 0:
            out.append(f"{n} negated")
        elif j != i:
            out.append(f"{n} <- {'-' if P[i, j] < 0 else ''}{names[j]}")
    return ", ".join(out)


def _signed_fix_text(P: np.ndarray, cols: list[str]) -> str:
    names = tuple(c.rsplit("_", 1)[1] for c in cols)
    if np.allclose(P, -np.eye(3)):
        return f"the columns {', '.join(cols)} are negated (their sign convention reversed)"
    what = "a reflected (left-handed) frame: " if np.linalg.det(P) < 0 else "another order or sign: "
    return f"{what}{_describe_signed(P, names)} (columns {cols[0]}..{cols[-1]})"


def _at_noise(r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Rows (N,) of residuals ``r`` (N, 3) within ``FREE_K`` times the noise's norm."""
    return np.linalg.norm(r, axis=1) <= FREE_K * float(np.linalg.norm(sigma))


def check_frames(p, k: str, sub: pd.DataFrame, w: np.ndarray, q: dict, where: str,
                 gb: np.ndarray | None) -> DataFormatError | None:
    """Transducer ``k``'s readings ``w`` (rows of ``sub``) against the calibration ``p`` on the rows without contact.

    Forces: the rows whose force residual (reading less offset and load) is at the noise (``FREE_K``) with the
    columns as given, against every signed permutation of the force columns, the other readings of the orientation
    columns (:func:`_alternatives`) and continuous joints' columns read as degrees: one that puts ``FIX_RATIO`` times
    more rows (and ``MIN_FREE_ROWS``) at the noise is an error naming it, the force frame's before the orientation's
    (a reflected frame cannot pass for another quaternion order); an orientation reading is returned (the error to
    raise) for the direction test that follows (:func:`check_against_calibration`) to name it first in its words. Torques: a contact has a force; on the rows whose force is
    at the noise the torque must be too (a couple without a force is no contact): where it is not on most of them,
    the torques' other units and every signed permutation are tried, and one that brings most to the noise is named;
    none is a warning. Fewer than ``MIN_FREE_ROWS`` rows at the noise (a recording mostly in contact, offsets
    drifted): a warning, nothing tested."""
    fc, tc = [f"{k}_{c}" for c in WRENCH_COMPONENTS[:3]], [f"{k}_{c}" for c in WRENCH_COMPONENTS[3:]]
    sf, st = np.nan_to_num(np.asarray(p.sigma, float)[:3]), np.nan_to_num(np.asarray(p.sigma, float)[3:])
    if not np.linalg.norm(sf) > 0 or not np.linalg.norm(st) > 0:
        return None
    g_B = gravity_of_frame(sub, p.g, where, gb)
    model, _ = p.predict(g_B, q, orientation_of_frame(sub))
    free = _at_noise(w[:, :3] - model[:, :3], sf)
    n_given = int(free.sum())
    cand: dict[str, int] = {}
    from ..core.checks import signed_permutations

    for P in signed_permutations():
        cand[_signed_fix_text(P, fc)] = int(_at_noise(w[:, :3] @ P.T - model[:, :3], sf).sum())
    for j in _continuous_joints(p, q):
        qq = {**q, j: q[j] * np.pi / 180}
        m2, _ = p.predict(g_B, qq, orientation_of_frame(sub))
        cand[f"column {JOINT_PREFIX}{j} holds degrees (continuous joint: no URDF limit to exceed; x pi/180 turns it into "
             "radians)"] = int(_at_noise(w[:, :3] - m2[:, :3], sf).sum())
    orient = {}
    if gb is None:
        for what, alt in _alternatives(sub).items():
            m2, _ = p.predict(gravity_of_frame(alt, p.g, where), q, orientation_of_frame(alt))
            orient[what] = int(_at_noise(w[:, :3] - m2[:, :3], sf).sum())
    best = max(cand, key=lambda w: cand[w])
    best_o = max(orient.values(), default=0)
    if cand[best] >= MIN_FREE_ROWS and cand[best] >= FIX_RATIO * max(n_given, 1) and cand[best] > best_o:
        joint = best.split(" ")[1] if best.startswith("column ") else None
        at = (f"{n_given} of {len(w)} rows (a regular subsample) have transducer {k}'s force at the noise (within {FREE_K:g}x "
              f"its sd, {FREE_K * np.linalg.norm(sf):.3g} N, of the calibration's offset plus the load)")
        if joint:
            raise DataFormatError(f"{where}: column {joint}: {at} with the column as given, {cand[best]} if it {best.split(' ', 2)[2]}; "
                                  "expected joint angles in radians (DATA_FORMAT.md section 5)", path=where, column=joint)
        raise DataFormatError(
            f"{where}: columns {fc[0]}..{fc[-1]}: {at} with the columns as given, {cand[best]} if {best}; expected the columns "
            "as given to leave the rows without contact at the noise (DATA_FORMAT.md: forces in N in the ft frame, a "
            "right-handed frame)", path=where, column=fc[0])
    what_o = max(orient, key=lambda w: orient[w]) if orient else None
    pending = None
    if what_o is not None and orient[what_o] >= MIN_FREE_ROWS and orient[what_o] >= FIX_RATIO * max(n_given, 1):
        pending = DataFormatError(
            f"{where}: columns {', '.join(_orientation_names(sub))}: {n_given} of {len(w)} rows (a regular subsample) have "
            f"transducer {k}'s force at the noise (within {FREE_K:g}x its sd of the calibration's offset plus the load) with "
            f"the columns as given, {orient[what_o]} if {what_o}; expected the columns as given to agree best "
            "(DATA_FORMAT.md section 3: qw..qz map B to the world, gx..gz point down)", path=where,
            column=_orientation_names(sub)[0])
    if n_given < MIN_FREE_ROWS:
        if pending is not None:
            return pending
        log.warning("%s: transducer %s: %d of %d rows (a regular subsample) have a force at the noise of the calibration's "
                    "prediction; the readings' frame and the torques' unit are tested on %d or more such rows without "
                    "contact: not tested (a short recording, one mostly in contact, offsets drifted since the calibration, "
                    "or another load)", where, k, n_given, len(w), MIN_FREE_ROWS)
        return None
    rt = w[free, 3:]
    mt = model[free, 3:]
    good = int(_at_noise(rt - mt, st).sum())
    if good >= 0.5 * n_given:
        return pending
    fixes = {what: int(_at_noise(rt * s - mt, st).sum()) for what, s in TORQUE_SCALES.items()}
    for P in signed_permutations():
        fixes[_signed_fix_text(P, tc)] = int(_at_noise(rt @ P.T - mt, st).sum())
    fix = max(fixes, key=lambda w: fixes[w])
    excess = float(np.median(np.linalg.norm(rt - mt, axis=1)))
    head = (f"{where}: columns {tc[0]}..{tc[-1]}: on the {n_given} rows (of {len(w)}, a regular subsample) whose force is at "
            f"the noise (no contact), the torque less the calibration's offset and load is a median {excess:.3g} N*m, "
            f"{excess / np.linalg.norm(st):.3g}x its noise sd; at the noise on {good} of them")
    if fixes[fix] >= 0.5 * n_given:
        raise DataFormatError(f"{head}, on {fixes[fix]} if {fix}; expected the torques as given at the noise where there "
                              "is no contact force (a couple without a force is no contact; torques in N*m, ft frame)",
                              path=where, column=tc[0])
    log.warning("%s; no other unit, order or sign of the torque columns brings them to the noise: torques in another "
                "frame or unit, or a calibration of another load?", head)
    return pending


def _orientation_names(df: pd.DataFrame) -> list[str]:
    return list(QUAT_COLUMNS) if set(QUAT_COLUMNS) <= set(map(str, df.columns)) else list(GRAVITY_COLUMNS)


def _continuous_joints(p, q: dict) -> list[str]:
    """Joints of ``q`` (with a column) that turn without URDF limits (continuous, or revolute without limits)."""
    tree = p.tree
    if tree is None:
        return []
    out = []
    for j in q:
        try:
            jt = tree.joint(j)
        except KeyError:
            continue
        if jt.type == "continuous" or (jt.type == "revolute" and (jt.lower is None or jt.upper is None or jt.upper <= jt.lower)):
            out.append(j)
    return out


@dataclass(frozen=True)
class _Readings:
    """A table's readings by transducer, as :func:`~ftcal_nlp.core.checks.sensor_faults` reads a recording's."""

    wrench: dict[str, np.ndarray]
    path: str
    name: str


def channel_faults(cal_legs: dict, df: pd.DataFrame, where: str) -> list:
    """The stuck, dead or clipped channels of each transducer over the recording's rows (``checks.sensor_faults``,
    the hexapod's screen; a cell that is no number never repeats)."""
    from ..core.checks import sensor_faults

    wrench = {k: df[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].apply(pd.to_numeric, errors="coerce").to_numpy(float)
              for k in cal_legs}
    return sensor_faults(_Readings(wrench, where, where), tuple(cal_legs))


def transducer_temperature(df: pd.DataFrame, leg: str, keep: np.ndarray, t: np.ndarray, where: str) -> np.ndarray | None:
    """Transducer ``leg``'s temperature (rows ``keep``) from ``{leg}_temp_C`` or ``temp_C`` (``data.py``'s reading:
    gaps interpolated in t, units checked), or None without either column."""
    from ..core.data import TEMP_COMMON, TEMP_SUFFIX, temperatures

    cols = [c for c in (f"{leg}{TEMP_SUFFIX}", TEMP_COMMON) if c in df.columns]
    return temperatures(df, cols, keep, t, [leg], where, Path(where)).get(leg) if cols else None
