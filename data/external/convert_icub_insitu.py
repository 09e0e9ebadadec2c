#!/usr/bin/env python3
"""Convert an iCub yarpdatadumper recording (insitu-ft-analysis layout) + its URDF to the ftcal_nlp interchange
format, DATA_FORMAT.md section 5 (a URDF load below a leg transducer, gravity per row from the stance leg).

Source
------
iCubGenova02, 2016-03-10, folder ``data/dumperLeftLegNoIMU/`` of github.com/nunoguedelha/insitu-ft-analysis at
commit 11a0cda (also in the history of isorrentino/insitu-ft-analysis; the robotology original has no snapshot
here); the URDF ``iCubGenova02.urdf`` from the same repository (commit d12648d), the model the authors used. The
method is Andrade Chavez, Traversaro et al. (in-situ F/T calibration, Humanoids 2016; Sensors 2019 19(24) 5521).

Licence status: the repository has NO licence file and no licence statement: all rights reserved. The data are
NOT redistributable: never commit them or a converted copy (write OUT outside the repository or into the
git-ignored ``data/``). This script is ours (the project's licence).

Input layout (yarpdatadumper, one folder per port, ``data.log`` one line per sample)
-------------------------------------------------------------------------------------
* ``icub/<part>/analog:o/data.log``: ``counter stamp fx fy fz tx ty tz`` (N, N*m; the strain gauges' factory
  calibration applied, untared), ~100 Hz. ``right_leg`` = the thigh sensor ``r_leg_ft_sensor``, ``right_foot`` =
  ``r_foot_ft_sensor`` (``left_*`` likewise).
* ``icub/<part>/stateExt:o/data.log``: ``counter stamp (q) [ok] (dq) [ok] ...``: the first parenthesised group is
  the joint positions in DEGREES; legs in the order hip_pitch, hip_roll, hip_yaw, knee, ankle_pitch, ankle_roll.
  The torso is not read (its port's joint order not checked here): it is not between the root and a foot.
* ``params.m`` of the folder: ``contactFrameName='l_sole'``, ``rData=[13.07,65.64]`` (the authors' interval in s
  from the start of the logs); the robot stands on its LEFT foot, the right leg swings in the air.

What is written (OUT/)
----------------------
``robot.urdf`` (the URDF with a massless link ``<leg>_ft_frame`` inserted at the sensor frame, by
``convert_ergocub_robot_logger.insert_sensor_link``: the sensor element says ``<frame>child</frame>`` and
``child_to_parent``, so the frame is the fixed joint's child link and the new link coincides with it),
``robot.toml`` (``legs = [<leg>]``, ``[transducers.<leg>] link``; no ``load_mass_kg``: the URDF's 4.73 kg is a
model value, not a weighing), ``dataset.toml`` (one ``hanging`` recording, ``free = [<leg>]``), ``<leg>.csv`` with
``t``, ``<leg>_fx..tz`` (the readings as logged: no taring, no sign change), ``q_<joint>`` for the 12 leg joints
(rad; linearly interpolated from each joint stream's own stamps to the F/T stamps), ``gx, gy, gz`` (or, with
``--orientation quat``, ``qw..qz``: B's orientation in the level sole frame, the same gravity; the tool may then fit a
world tilt). The other URDF joints (torso, arms, head) get no column: the tool holds them at 0 with a warning; none
moves the sensor or its load.

Frames, signs, units
--------------------
* ``B`` = the URDF root ``base_link`` (fixed to ``root_link``, the pelvis). Gravity per row in ``B``: the stance
  foot's sole frame (``l_sole``, z up out of the ground) is taken as level, ``g_B = R_B^{l_sole}(q) [0, 0, -1]``
  with ``R`` from the FK of the left leg's joints (the legs hang from ``root_link``; the torso is not on this path).
  The base's orientation is therefore only as good as "the stance sole is flat on level ground".
* ``ft`` = the frame of the sensor's child link (iDynTree ``<frame>child</frame>``); the reading is the wrench the
  child subtree (the leg below) exerts on the parent (``measure_direction child_to_parent``) = section 1's
  convention, so no sign change. Checked: the force fitted along ``g_ft`` has a POSITIVE mass (below).
* SI units: degrees -> rad; forces N, torques N*m as logged.
* Time: ``t`` = YARP stamp - t0, t0 = the earliest first stamp of any stream of the folder (for this folder the
  head's stateExt, 1457614036.659765; written in OUT/README.md). One clock for every stream and sensor, no shift
  between streams: a lag stays in the data for the tool to find. ``--window`` is in this ``t`` (default the
  authors' 13.07-65.64 s). F/T rows with a stamp not above the previous one are dropped (counted); rows outside a
  joint stream's span are dropped.

Sanity check (``--check``: linear LS ``F = o + m g g_ft`` of the forces; "still" = every right-leg joint slower
than 2 deg/s; the 48 signed axis permutations of the URDF's nominal wrench against the still rows; a scan of a lag
between the F/T and joint streams), measured on dumperLeftLegNoIMU (2026-12-02):

| sensor, window | rows / still | mass all / still [kg] (URDF) | force offset, still [N] | force rms still x y z [N] | best convention (force rms; torque rms) | lag scan |
|---|---|---|---|---|---|---|
| r_leg, 17-62 s (swing) | 4458 / 890 | 4.614 / 4.792 (4.732) | 3.4 -29.5 -81.1 | 1.80 4.36 0.82 | identity (1.80 4.38 0.74 N; 0.374 0.184 0.054 N*m); next: fy negated, fy 8.06 N | 5.548 N at 0 s, least 5.538 at +0.10 s |
| r_foot, 17-62 s | 4458 / 885 | 0.309 / 0.307 (0.382) | 291.8 -78.6 38.6 | 0.19 0.28 0.19 | identity (0.58 0.29 0.22 N; 5 6 4 mN*m) | none (0.537 N flat) |
| r_leg, 13.07-65.64 s (authors') | 5209 / 979 | 4.471 / 4.514 | 4.8 -31.4 -82.0 | 5.89 4.83 3.95 | identity (5.82 4.57 4.44 N) | 7.639 N at 0, least 7.631 at +0.10 s |
| r_foot, 13.07-65.64 s | 5208 / 970 | 0.226 / 0.248 | 291.6 -78.6 38.2 | 0.64 0.94 3.27 | not identity (contact corrupts it) | none |

So frames and signs are as the URDF says (identity best; the weight along gravity: positive mass within 1-5 % of the
URDF's 4.73 kg for the thigh), no lag between the streams worth a sample (<= 0.1 s, 0.2 % of the rms), but: (1) the
authors' window includes the right foot on or near the ground at both ends (foot sensor fz 41 N, sd 0.1-0.2 N, while
the foot hangs; 3-37 N with sd up to 51 N before ~14.5 s, unsettled until ~16.8 s, 21-36 N after ~62.2 s): use
``--window 17,62`` for a free leg; (2) the thigh sensor's force error is large
(fx, fy rms 1.8-4.4 N on still rows against a noise of ~0.7-1.3 N), pose-dependent (swing window: fx residual +17 N at 17-22 s and 59-62 s,
-3.7 N at 25-58 s with two joints at their limits: REAL_DATA.md); (3) the foot sensor reads 17-20 % less mass than the URDF's foot (0.31 vs 0.38 kg),
with a 292 N fx offset. Timestamps: F/T 100 Hz (dt 10.0-10.8 ms, none out of order), joints 100 Hz (dt 7-15 ms),
30 % of the joint rows repeat the previous positions.

Usage::

    python data/external/convert_icub_insitu.py SRC_FOLDER URDF OUT [--sensor r_leg_ft_sensor|r_foot_ft_sensor]
        [--window 13.07,65.64] [--contact l_sole] [--orientation gravity|quat] [--check]
    python data/external/convert_icub_insitu.py --selftest     # synthetic dumper logs, < 2 s

SRC_FOLDER is the dump folder (the one holding ``icub/`` and ``params.m``) or its ``icub/`` subfolder.
"""
from __future__ import annotations

import argparse
import importlib.util
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

LEG_JOINTS = ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")
SENSOR_PORT = {  # URDF <sensor> name -> (dumper part folder, transducer name written)
    "r_leg_ft_sensor": ("right_leg", "r_leg"),
    "r_foot_ft_sensor": ("right_foot", "r_foot"),
    "l_leg_ft_sensor": ("left_leg", "l_leg"),
    "l_foot_ft_sensor": ("left_foot", "l_foot"),
}
PARTS = {"r": "right_leg", "l": "left_leg"}
DEFAULT_WINDOW = (13.07, 65.64)   # params.m rData of dumperLeftLegNoIMU


def _ergocub():
    """``convert_ergocub_robot_logger`` beside this file (its URDF rewriting is reused, not copied)."""
    here = Path(__file__).resolve().parent / "convert_ergocub_robot_logger.py"
    spec = importlib.util.spec_from_file_location("convert_ergocub_robot_logger", here)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# ---------------------------------------------------------------- yarpdatadumper text
def read_analog(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps (N,), wrench (N, 6))`` of an ``analog:o/data.log`` (``counter stamp v1..v6``)."""
    a = np.loadtxt(path, ndmin=2)
    if a.shape[1] < 8:
        raise ValueError(f"{path}: {a.shape[1]} columns, expected counter, stamp and 6 values")
    return a[:, 1], a[:, 2:8]


_GROUP = re.compile(r"\(([^)]*)\)")


def read_state(path: Path, n_joints: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps (N,), positions (N, n_joints) in degrees)``: the first parenthesised group of a ``stateExt:o`` line."""
    t, q = [], []
    with open(path) as f:
        for k, line in enumerate(f, 1):
            if not line.strip():
                continue
            g = _GROUP.search(line)
            if g is None:
                raise ValueError(f"{path}: line {k}: no '(...)' group")
            v = [float(x) for x in g.group(1).split()]
            if len(v) < n_joints:
                raise ValueError(f"{path}: line {k}: {len(v)} positions, expected {n_joints}")
            t.append(float(line.split()[1]))
            q.append(v[:n_joints])
    return np.asarray(t), np.asarray(q)


def increasing(t: np.ndarray) -> np.ndarray:
    """Mask keeping a row only where its stamp is above every earlier kept one."""
    return np.r_[True, t[1:] > np.maximum.accumulate(t)[:-1]]


def first_stamp(path: Path) -> float:
    with open(path) as f:
        for line in f:
            if line.strip():
                return float(line.split()[1])
    raise ValueError(f"{path}: empty")


def icub_dir(src: Path) -> Path:
    return src / "icub" if (src / "icub").is_dir() else src


# ---------------------------------------------------------------- conversion
def load_streams(src: Path, sensor: str, stance: str = "l"):
    """The F/T stream of ``sensor``, both legs' joint streams (rad) and t0, all on ``t = stamp - t0``."""
    d = icub_dir(src)
    part, _ = SENSOR_PORT[sensor]
    t0 = min(first_stamp(p) for p in sorted(d.glob("*/*/data.log")))
    tf, W = read_analog(d / part / "analog:o" / "data.log")
    ok = increasing(tf)
    joints = {}
    for side, p in PARTS.items():
        tj, qd = read_state(d / p / "stateExt:o" / "data.log")
        okj = increasing(tj)
        joints[side] = (tj[okj] - t0, np.deg2rad(qd[okj]), int((~okj).sum()))
    return {"t0": t0, "t": tf[ok] - t0, "W": W[ok], "dropped_ft": int((~ok).sum()), "joints": joints}


def assemble(streams, tree, contact: str, window) -> dict:
    """Rows = F/T samples inside ``window`` and inside both joint streams; joint columns interpolated; gravity in B."""
    t, W = streams["t"], streams["W"]
    keep = (t >= window[0]) & (t <= window[1])
    for tj, _, _ in streams["joints"].values():
        keep &= (t >= tj[0]) & (t <= tj[-1])
    t, W = t[keep], W[keep]
    q = {}
    for side, (tj, qr, _) in streams["joints"].items():
        for k, n in enumerate(LEG_JOINTS):
            q[f"{side}_{n}"] = np.interp(t, tj, qr[:, k])
    R, _ = tree.pose(tree.root, contact, q, len(t))   # R_B^{sole}: sole vectors -> B vectors
    g = R @ np.array([0.0, 0.0, -1.0])   # gravity (down) in B: the contact sole level, its z up
    return {"t": t, "W": W, "q": q, "g": g, "R_WB": np.swapaxes(R, 1, 2)}   # W = the level sole frame


def write_dataset(out: Path, rows: dict, urdf: Path, sensor: str, leg: str, meta: str, orientation: str = "gravity") -> float:
    """The section-5 dataset in ``out``; returns the URDF mass below the sensor link (kg)."""
    erg = _ergocub()
    out.mkdir(parents=True, exist_ok=True)
    link = f"{leg}_ft_frame"
    erg.insert_sensor_link(str(urdf), str(out / "robot.urdf"), sensor, link)
    cols = {"t": rows["t"]}
    for k, c in enumerate(("fx", "fy", "fz", "tx", "ty", "tz")):
        cols[f"{leg}_{c}"] = rows["W"][:, k]
    for n, v in rows["q"].items():
        cols[f"q_{n}"] = v
    if orientation == "quat":   # B's orientation in the level sole frame: the tool may then fit a world tilt
        from ftcal_nlp.core.geometry import rotation_to_quat

        Q = rotation_to_quat(rows["R_WB"])
        for k, c in enumerate(("qw", "qx", "qy", "qz")):
            cols[c] = Q[:, k]
    else:
        for k, c in enumerate("xyz"):
            cols[f"g{c}"] = rows["g"][:, k]
    hdr = list(cols)
    np.savetxt(out / f"{leg}.csv", np.column_stack([cols[h] for h in hdr]), delimiter=",", header=",".join(hdr),
               comments="", fmt=["%.6f"] + ["%.9g"] * (len(hdr) - 1))
    (out / "robot.toml").write_text(
        f'name = "icub_{leg}"\ng = 9.81\nlegs = ["{leg}"]\nurdf = "robot.urdf"\n\n[transducers.{leg}]\nlink = "{link}"\n'
        f'model = "IIT FTSens ({sensor}), iCubGenova02"\n')
    (out / "dataset.toml").write_text(
        f'robot = "robot.toml"\n\n[[recording]]\nfile = "{leg}.csv"\nkind = "hanging"\nname = "{leg}_swing"\n'
        f'free = ["{leg}"]\n')
    (out / "README.md").write_text(meta)
    return erg.subtree_mass(str(out / "robot.urdf"), link)


def _load_tree(path):
    """``ftcal_nlp.core.kinematics.load_tree`` (its fixed joints with ``axis xyz="0 0 0"``, as in the iCub URDFs, give a
    harmless 0/0 on the unused axis: silenced)."""
    from ftcal_nlp.core.kinematics import load_tree

    with np.errstate(invalid="ignore", divide="ignore"):
        return load_tree(path)


def convert(src: Path, urdf: Path, out: Path, sensor: str = "r_leg_ft_sensor", window=DEFAULT_WINDOW,
            contact: str = "l_sole", orientation: str = "gravity") -> dict:
    if sensor not in SENSOR_PORT:
        raise KeyError(f"sensor {sensor!r}: one of {sorted(SENSOR_PORT)}")
    part, leg = SENSOR_PORT[sensor]
    tree = _load_tree(urdf)
    on_path = [j.name for j in tree.path_to_root(contact) if j.type != "fixed"]
    unknown = [n for n in on_path if n not in {f"{s}_{j}" for s in PARTS for j in LEG_JOINTS}]
    if unknown:
        raise ValueError(f"joints {unknown} lie between the root and {contact} and are not read")
    st = load_streams(src, sensor)
    rows = assemble(st, tree, contact, window)
    meta = (f"# iCub {leg} converted by data/external/convert_icub_insitu.py (NOT REDISTRIBUTABLE: no licence)\n\n"
            f"source folder: {src}\nsensor: {sensor} ({part}/analog:o); contact frame {contact} level\n"
            f"t = YARP stamp - t0, t0 = {st['t0']:.6f} (earliest first stamp of any stream)\n"
            f"window: {window[0]:g}..{window[1]:g} s; rows {len(rows['t'])}; F/T rows dropped for non-increasing "
            f"stamps {st['dropped_ft']}; joint rows dropped {', '.join(f'{k}: {v[2]}' for k, v in st['joints'].items())}\n")
    m = write_dataset(out, rows, urdf, sensor, leg, meta, orientation)
    print(f"wrote {out}: {len(rows['t'])} rows ({rows['t'][0]:.3f}..{rows['t'][-1]:.3f} s), load mass in URDF {m:.3f} kg; "
          f"t0 {st['t0']:.6f}; dropped F/T {st['dropped_ft']}")
    rows.update(leg=leg, link=f"{leg}_ft_frame", urdf_mass=m, t0=st["t0"], streams=st, contact=contact)
    return rows


# ---------------------------------------------------------------- sanity check
def gravity_in_ft(tree, link: str, q: dict, g_B: np.ndarray) -> np.ndarray:
    R, _ = tree.pose(tree.root, link, q, len(g_B))
    return np.einsum("nji,nj->ni", R, g_B)


def urdf_wrench(tree, link: str, q: dict, g_B: np.ndarray, G: float = 9.81) -> np.ndarray:
    """(N, 6) the URDF's nominal gravity wrench of every link below ``link``, in ``link``'s frame about its origin
    (section 1's sign: the weight points along gravity)."""
    n = len(g_B)
    Rs, ps = tree.pose(tree.root, link, q, n)
    W = np.zeros((n, 6))
    for lk in tree.below(link):
        b = tree.bodies.get(lk)
        if b is None:
            continue
        Rl, pl = tree.pose(tree.root, lk, q, n)
        c = pl + Rl @ b.com_m - ps                       # CoM relative to the sensor origin, in B
        f = b.mass_kg * G * g_B
        W[:, :3] += np.einsum("nji,nj->ni", Rs, f)
        W[:, 3:] += np.einsum("nji,nj->ni", Rs, np.cross(c, f))
    return W


def conventions(W: np.ndarray, P: np.ndarray) -> list:
    """The 48 signed permutations ``M`` of the axes, each applied to the URDF's wrench ``P`` (forces and torques
    alike), scored by the per-axis RMS of ``W - mean - (M P - mean)``: best first."""
    import itertools

    out = []
    for perm in itertools.permutations(range(3)):
        for sg in itertools.product((1, -1), repeat=3):
            M = np.zeros((3, 3))
            M[range(3), perm] = sg
            e = [(W[:, k] - W[:, k].mean(0)) - (P[:, k] @ M.T - (P[:, k] @ M.T).mean(0)) for k in (slice(0, 3), slice(3, 6))]
            rf, rt = (np.sqrt((x**2).mean(0)) for x in e)
            out.append((rf.sum() + 10 * rt.sum(), perm, sg, rf, rt))
    return sorted(out, key=lambda r: r[0])


def static_fit(W: np.ndarray, gft: np.ndarray, G: float = 9.81) -> dict:
    """LS ``F = o + m G g_ft``, ``T = o_T + c x (m G g_ft)`` (c the CoM in ft): mass, offsets, CoM, rms per axis."""
    n = len(W)
    A = np.zeros((3 * n, 4))
    for a in range(3):
        A[a::3, a] = 1.0
        A[a::3, 3] = G * gft[:, a]
    x, *_ = np.linalg.lstsq(A, W[:, :3].reshape(-1), rcond=None)
    rf = (W[:, :3].reshape(-1) - A @ x).reshape(n, 3)
    m = x[3]
    # T = o_T + h x g  with h = m c: T = o_T - [g]x h  (linear in o_T, h)
    gx = G * gft
    B = np.zeros((3 * n, 6))
    for a in range(3):
        B[a::3, a] = 1.0
    # (h x g)_x = h_y g_z - h_z g_y, etc.
    B[0::3, 4], B[0::3, 5] = gx[:, 2], -gx[:, 1]
    B[1::3, 3], B[1::3, 5] = -gx[:, 2], gx[:, 0]
    B[2::3, 3], B[2::3, 4] = gx[:, 1], -gx[:, 0]
    y, *_ = np.linalg.lstsq(B, W[:, 3:].reshape(-1), rcond=None)
    rt = (W[:, 3:].reshape(-1) - B @ y).reshape(n, 3)
    return {"mass": m, "offset_f": x[:3], "offset_t": y[:3], "com": y[3:] / m if m else y[3:] * np.nan,
            "rms_f": np.sqrt((rf**2).mean(0)), "rms_t": np.sqrt((rt**2).mean(0)), "n": n}


def check(rows: dict, urdf_out: Path, still_deg_s: float = 2.0) -> None:
    tree = _load_tree(urdf_out)
    t, W, q, g = rows["t"], rows["W"], rows["q"], rows["g"]
    side = rows["leg"][0]
    Q = np.column_stack([q[f"{side}_{n}"] for n in LEG_JOINTS])
    speed = np.abs(np.gradient(Q, t, axis=0)).max(axis=1)
    still = np.rad2deg(speed) < still_deg_s
    gft = gravity_in_ft(tree, rows["link"], q, g)
    tilt = np.rad2deg(np.arccos(np.clip(-g[:, 2], -1, 1)))
    print(f"gravity in B: angle to -z {tilt.min():.1f}..{tilt.max():.1f} deg; g_ft spans "
          f"x {gft[:, 0].min():+.2f}..{gft[:, 0].max():+.2f} y {gft[:, 1].min():+.2f}..{gft[:, 1].max():+.2f} "
          f"z {gft[:, 2].min():+.2f}..{gft[:, 2].max():+.2f}")
    for name, sel in (("all rows", np.ones(len(t), bool)), (f"still (< {still_deg_s:g} deg/s)", still)):
        f = static_fit(W[sel], gft[sel])
        print(f"{name}: n {f['n']}, mass {f['mass']:.3f} kg (URDF {rows['urdf_mass']:.3f}), force offset "
              f"{np.array2string(f['offset_f'], precision=2)} N, rms fxyz {np.array2string(f['rms_f'], precision=2)} N; "
              f"CoM {np.array2string(1e3 * f['com'], precision=1)} mm, torque offset "
              f"{np.array2string(f['offset_t'], precision=3)} N*m, rms txyz {np.array2string(f['rms_t'], precision=3)} N*m")
    # lag between the F/T and joint streams: re-interpolate the joints at t + d (d > 0: the joints lead)
    st = rows["streams"]
    best = []
    for d in np.arange(-0.30, 0.301, 0.02):
        qd = {}
        for s, (tj, qr, _) in st["joints"].items():
            for k, n in enumerate(LEG_JOINTS):
                qd[f"{s}_{n}"] = np.interp(t - d, tj, qr[:, k])
        Rb, _ = tree.pose(tree.root, rows["contact"], qd, len(t))
        gd = Rb @ np.array([0.0, 0.0, -1.0])
        f = static_fit(W, gravity_in_ft(tree, rows["link"], qd, gd))
        best.append((np.sqrt((f["rms_f"] ** 2).mean()), d))
    r0 = next(r for r, d in best if abs(d) < 1e-9)
    rb, db = min(best)
    conv = conventions(W[still], urdf_wrench(tree, rows["link"], {k: v[still] for k, v in q.items()}, g[still]))
    for k, (_, perm, sg, rf, rt) in enumerate(conv[:3]):
        print(f"convention #{k + 1} (axes {perm}, signs {sg}; still rows, URDF load): force rms "
              f"{np.array2string(rf, precision=2)} N, torque rms {np.array2string(rt, precision=3)} N*m")
    print(f"lag scan (joints evaluated at t - d, all rows): force rms {r0:.3f} N at d = 0, least {rb:.3f} N at "
          f"d = {db:+.2f} s")


# ---------------------------------------------------------------- selftest (synthetic dumper text)
SELFTEST_URDF = """<?xml version="1.0"?>
<robot name="mini">
  <link name="base_link"/>
  <link name="pelvis"><inertial><origin xyz="0 0 0"/><mass value="3"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <joint name="base_fixed_joint" type="fixed"><origin xyz="0 0 0" rpy="0 0 0"/><parent link="base_link"/><child link="pelvis"/></joint>
{legs}
  <sensor name="r_leg_ft_sensor" type="force_torque"><parent joint="r_leg_ft_sensor"/>
    <force_torque><frame>child</frame><measure_direction>child_to_parent</measure_direction></force_torque></sensor>
</robot>
"""
_AX = {"hip_pitch": "0 1 0", "hip_roll": "1 0 0", "hip_yaw": "0 0 1", "knee": "0 1 0", "ankle_pitch": "0 1 0",
       "ankle_roll": "1 0 0"}


def _selftest_urdf() -> str:
    parts = []
    for s, y in (("l", 0.07), ("r", -0.07)):
        prev = "pelvis"
        for k, n in enumerate(LEG_JOINTS):
            link = f"{s}_{n}_link"
            xyz = f"0 {y} -0.05" if k == 0 else "0 0 -0.12"
            parts.append(f'  <link name="{link}"><inertial><origin xyz="0.01 0 -0.05"/><mass value="0.5"/>'
                         f'<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>')
            parts.append(f'  <joint name="{s}_{n}" type="revolute"><origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="{_AX[n]}"/>'
                         f'<parent link="{prev}"/><child link="{link}"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>')
            prev = link
            if s == "r" and n == "hip_roll":   # the sensor below hip_roll, its frame turned
                parts.append('  <link name="r_hip_3"/>')
                parts.append('  <joint name="r_leg_ft_sensor" type="fixed"><origin xyz="0 0 -0.03" rpy="1.5707963 -1.5707963 0"/>'
                             f'<parent link="{prev}"/><child link="r_hip_3"/></joint>')
                prev = "r_hip_3"
        parts.append(f'  <link name="{s}_sole"/>')
        parts.append(f'  <joint name="{s}_sole_fixed_joint" type="fixed"><origin xyz="0 0 -0.1" rpy="0.1 0 0"/>'
                     f'<parent link="{prev}"/><child link="{s}_sole"/></joint>')
    return SELFTEST_URDF.format(legs="\n".join(parts))


def selftest(workdir: Path | None = None) -> dict:
    """Synthetic dumper folder (a mini biped; the right leg's readings = its URDF load's wrench + an offset, the
    joint streams on their own stamps, one repeated F/T stamp): convert, then check rows, timestamps, radians, the
    gravity direction and that the static fit returns the URDF mass and the offset."""
    from ftcal_nlp.core.kinematics import load_tree

    tmp = Path(workdir or tempfile.mkdtemp(prefix="icub_selftest_"))
    src = tmp / "dump" / "icub"
    urdf = tmp / "mini.urdf"
    urdf.write_text(_selftest_urdf())
    tree = load_tree(urdf)
    rng = np.random.default_rng(1)
    T0 = 1457614036.5
    tj = T0 + 0.0013 + np.arange(0, 20, 0.01)           # joints at 100 Hz
    tf = T0 + 0.0042 + np.arange(0, 19.9, 0.01)         # F/T on its own clock phase
    tf[500] = tf[499]                                   # a repeated stamp: dropped
    qdeg = {"l": np.column_stack([3 * np.sin(0.3 * (tj - T0) + k) for k in range(6)]),
            "r": np.column_stack([30 * np.sin(0.5 * (tj - T0) + k) for k in range(6)])}
    for side, part in PARTS.items():
        p = src / part / "stateExt:o"
        p.mkdir(parents=True)
        with open(p / "data.log", "w") as f:
            for i, (s, q) in enumerate(zip(tj, qdeg[side])):
                f.write(f"{i} {s:.6f} (" + " ".join(f"{v:.6f}" for v in q) + ") [ok] (0 0 0 0 0 0) [ok]\n")
    # the truth: gravity from the level left sole, the right leg's load wrench in r_hip_3
    q = {f"{s}_{n}": np.interp(tf, tj, np.deg2rad(qdeg[s][:, k])) for s in PARTS for k, n in enumerate(LEG_JOINTS)}
    Rl, _ = tree.pose(tree.root, "l_sole", q, len(tf))
    gB = Rl @ np.array([0.0, 0.0, -1.0])
    W = urdf_wrench(tree, "r_hip_3", q, gB)
    off = np.array([5.0, -30.0, -80.0, 1.0, -0.5, 0.2])
    W += off + 1e-3 * rng.standard_normal(W.shape)
    p = src / "right_leg" / "analog:o"
    p.mkdir(parents=True)
    with open(p / "data.log", "w") as f:
        for i, (s, w) in enumerate(zip(tf, W)):
            f.write(f"{i} {s:.6f} " + " ".join(f"{v:.6f}" for v in w) + "\n")
    out = tmp / "out"
    rows = convert(src.parent, urdf, out, "r_leg_ft_sensor", window=(2.0, 18.0))
    t0 = min(tj[0], tf[0])
    assert abs(rows["t0"] - t0) < 1e-6, rows["t0"]
    import pandas as pd

    df = pd.read_csv(out / "r_leg.csv")
    keep = (tf[np.r_[True, np.diff(tf) > 0]] - t0)
    keep = keep[(keep >= 2.0) & (keep <= 18.0)]
    assert len(df) == len(keep) and np.allclose(df["t"], keep, atol=2e-6), "rows are the F/T stamps, unshifted"
    assert np.all(np.diff(df["t"]) > 0)
    i = 700
    assert abs(df["q_r_knee"].iloc[i] - np.interp(df["t"].iloc[i] + t0, tj, np.deg2rad(qdeg["r"][:, 3]))) < 1e-6
    g = df[["gx", "gy", "gz"]].to_numpy()
    assert np.allclose(np.linalg.norm(g, axis=1), 1, atol=1e-6) and (g[:, 2] < -0.9).all()
    tree_out = load_tree(out / "robot.urdf")
    assert abs(rows["urdf_mass"] - 2.0) < 1e-9, rows["urdf_mass"]      # 4 links of 0.5 kg below the sensor
    gft = gravity_in_ft(tree_out, "r_leg_ft_frame", {k[2:]: df[k].to_numpy() for k in df if k.startswith("q_")}, g)
    fit = static_fit(df[[f"r_leg_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy(), gft)
    assert abs(fit["mass"] - 2.0) < 1e-3 and np.allclose(fit["offset_f"], off[:3], atol=5e-3), fit
    from ftcal_nlp.core.data import read_dataset

    ds = read_dataset(out / "dataset.toml")
    assert ds.robot.legs == ("r_leg",) or list(ds.robot.legs) == ["r_leg"]
    convert(src.parent, urdf, tmp / "out_quat", "r_leg_ft_sensor", window=(2.0, 18.0), orientation="quat")
    from ftcal_nlp.core.geometry import quat_to_rotation

    dq = pd.read_csv(tmp / "out_quat" / "r_leg.csv")
    R_WB = quat_to_rotation(dq[["qw", "qx", "qy", "qz"]].to_numpy())
    assert np.allclose(np.einsum("nji,j->ni", R_WB, [0.0, 0.0, -1.0]), g, atol=1e-7), "quat and gravity columns agree"
    print(f"selftest ok: {len(df)} rows, mass {fit['mass']:.4f} kg, offsets {np.array2string(fit['offset_f'], precision=3)}")
    return {"rows": len(df), "fit": fit}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("args", nargs="*", help="SRC_FOLDER URDF OUT")
    ap.add_argument("--sensor", default="r_leg_ft_sensor", choices=sorted(SENSOR_PORT))
    ap.add_argument("--window", default=",".join(f"{v:g}" for v in DEFAULT_WINDOW), help="t0,t1 in s (the t column)")
    ap.add_argument("--contact", default="l_sole", help="the stance foot's sole frame, taken as level")
    ap.add_argument("--orientation", choices=("gravity", "quat"), default="gravity",
                    help="gx,gy,gz (default) or qw..qz: B's orientation in the level sole frame (lets the tool fit a tilt)")
    ap.add_argument("--check", action="store_true", help="static LS fit, still rows and a lag scan")
    ap.add_argument("--selftest", action="store_true")
    a = ap.parse_args(argv)
    if a.selftest:
        selftest()
        return 0
    if len(a.args) != 3:
        ap.error("SRC_FOLDER URDF OUT expected")
    src, urdf, out = (Path(v) for v in a.args)
    w = tuple(float(v) for v in a.window.split(","))
    rows = convert(src, urdf, out, a.sensor, w, a.contact, a.orientation)
    if a.check:
        check(rows, out / "robot.urdf")
    return 0


if __name__ == "__main__":
    sys.exit(main())
