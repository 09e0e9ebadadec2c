#!/usr/bin/env python3
"""Convert leledeyuan00/Gravity-Compensation-F-T-sensor recordings to the
ftcal_nlp interchange format (DATA_FORMAT.md section 5: wrist sensor with a
rigid payload, one transducer ``wrist`` without ``wrist_phi``, ``hanging``
recordings with ``qw..qz`` per sample).

Source
------
GitHub https://github.com/leledeyuan00/Gravity-Compensation-F-T-sensor
(snapshot read here: commit 139efe1841f97391002655ef370911d0417feaed,
2025-08-16), folder ``datas/``.  Real data: an ATI Axia80 EtherCAT sensor
("ATI axis-80 EnterCAT" in the README) on a robot arm, carrying a gripper,
read through ROS 2 (https://github.com/smartrobotsdesignlab/ATI_ROS2).

LICENCE: the repository has NO licence file and no licence statement
(README only).  Default copyright applies: all rights reserved.  Do NOT
commit the converted data; commit only this script, which reads the user's
own copy of the repository.  (Ask the author, Dayuan / leledeyuan00, for a
licence if a committed copy is wanted.)

Files converted (each to its own dataset directory; they are different
sessions, possibly with different payloads, so they are NOT merged):

* ``GP2025-07-22-22-06-02.txt`` -> ``<out>/timeseries/``
  1756 rows, 10 Hz (dt = 0.1000 s +- 0.1 ms), 175.5 s.  Columns
  ``t, fx, fy, fz, tx, ty, tz, qx, qy, qz, qw`` (README: "changed a new poses
  and static standing several seconds"; the MATLAB script
  ``gravity_pose_drifting_show.m`` reads t = col 1, force = 2:4,
  torque = 5:7, quaternion = [col 11, cols 8:10] i.e. w last in the file).
  Six holds of ~14.6 s separated by ~14.7 s of motion (two moves with a ~1 s
  pause; found here from the quaternion, <= 10 deg/s).  The sensor z axis stays within ~50 deg of straight down
  (narrow orientation range: mass and the z offset are correlated).
* ``recorded_messages_pose_100.txt`` + ``recorded_messages_wrench_100.txt``
  -> ``<out>/poses100/``: 100 static poses, one row each, NO time stamps.
* ``recorded_messages_pose.txt`` + ``recorded_messages_wrench.txt``
  -> ``<out>/poses7/``: 7 static poses (earlier session, March 2025, lighter
  payload), one row each, NO time stamps.
* ``static_pose_recording.txt`` (35 h static drift recording) is NOT in the
  stored snapshot (>= 4 MiB); if the user's copy has it, it is converted to
  ``<out>/static35h/`` (columns as the time series per ``drifting_show.m``:
  t, F, T; a quaternion is read if 11 columns are present, otherwise the
  file is skipped because the format needs an orientation).

Frames and signs (with the evidence)
------------------------------------
* Frame ``B`` := the ATI sensor frame ``sensor_link``; the transducer table
  is ``position_m = [0,0,0]``, ``rotation = I``.  So ``qw..qz`` is the
  orientation of the sensor in the robot base frame.
* Quaternion order in the files is ``[x, y, z, w]`` (README: "The
  orientation is recorded as [x,y,z,w] format"; ``gravity_compute.py`` uses
  ``scipy Rotation.from_quat`` which is xyzw; the MATLAB scripts reorder to
  wxyz).  It maps sensor vectors to base vectors (ROS tf ``base ->
  sensor_link``): checked below, fits are good only with this reading.
* The robot base frame is z-up: fitting ``F_s = R^T w + f0`` with a free
  weight vector ``w`` (in base) gives w = [0.10, -0.13, -12.16] N for the
  100 poses (0.8 deg from -z) and [-0.27, 0.07, -11.41] N for the time series
  (1.4 deg from -z).  So gravity is along -z of the base frame, as section 1
  requires for ``W`` (heading irrelevant).
* The pose files' wrench is NOT in the sensor frame: README "the sensor data
  transformed on the robot base frame"; ``gravity_compute.py`` models
  ``F = [0,0,G] + R f0`` (bias rotated by R).  Checked: treating it as base
  frame, force rms 0.12/0.21/0.42 N; treating it as sensor frame, 4.6 N.
  The torque was rotated only (``T_b = R T_s``; no moment transfer to the
  base origin): torque-model rms 1.4-2.1 mN*m vs 2.7-3.1 N*m with ``p x F``.
  So this script writes ``F_s = R^T F_b``, ``T_s = R^T T_b``.
* The time-series file IS in the sensor frame (fit rms 0.07/0.26/0.12 N in
  sensor frame vs 0.9/0.7/1.3 N if read as base frame), so it is copied.
* Sign: the fitted weight points DOWN (along gravity) in the sensor reading,
  i.e. the reading is the wrench the load exerts on the sensor, as section 1
  requires; no sign flip.  Torques agree with ``c x w`` with the CoM at
  c ~ [0, 0, +0.045..0.048] m in the sensor frame (gripper along +z).
* Units: N and N*m (ROS WrenchStamped; 12 N for a ~1.2 kg gripper, 45 mm
  lever: plausible).  t in s.  Readings are untared (force offset
  ~[-3.4, -4.7, -16.7] N, large and stable between the July and August
  sessions), which is what the format wants.

Gaps seen in the data (left in; the tool should find them)
------------------------------------------------------------
* time series: the wrench lags the pose stream by ~0.54 s (all-row force rms
  0.170 N unshifted, 0.046 N with the pose delayed 0.54 s); within holds the
  residual still creeps by up to ~0.09 N (z) over 14.6 s, sign varying.
* poses100: Fz offset drifts ~1.5 N over the first half of the session
  (block means of the residual -0.83 ... +0.73 N, then ~+0.1 N).

Uncertain
---------
* Whether each row of the pose files is a single sample or an average over a
  hold (the repo does not say).  Their rows get a synthetic clock
  (t = 1000 + i s): one row per pose, no motion samples in between; the tool
  must treat each row as its own quasi-static pose.  The time series has the
  real clock (t = 1000 + source t, to keep t > 0 and comparable).
* The 100-pose and the time-series session give |w| = 12.16 N vs 11.41 N;
  either the payload changed or the narrow orientation range of the time
  series biases the mass (mass and f0_z correlate when z stays near down).
* The robot model is not given (positions stay at one point to 0.1 mm: the
  arm rotates the sensor about a fixed point); no joint angles are recorded.

Usage
-----
    python3 convert_leledeyuan00_ati.py SRC_DATAS_DIR OUT_DIR [--check]

SRC_DATAS_DIR is the ``datas`` folder of the user's clone.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np


def quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n,3,3) from unit quaternions (n,4) in x,y,z,w order."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - z * w)
    R[:, 0, 2] = 2 * (x * z + y * w)
    R[:, 1, 0] = 2 * (x * y + z * w)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - x * w)
    R[:, 2, 0] = 2 * (x * z - y * w)
    R[:, 2, 1] = 2 * (y * z + x * w)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


ROBOT_TOML = """\
name = "{name}"
g = 9.81
legs = ["wrist"]

[transducers.wrist]
model = "ATI Axia80 EtherCAT (source README: 'ATI axis-80 EnterCAT'), read via ATI_ROS2"
position_m = [0.0, 0.0, 0.0]
rotation = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
"""

DATASET_TOML = """\
robot = "robot.toml"

[[recording]]
file = "wrist.csv"
kind = "hanging"
"""

README = """\
# {name}: converted from leledeyuan00/Gravity-Compensation-F-T-sensor

Real ATI Axia80 wrist F/T readings with a gripper, {what}.
Converted by data/external/convert_leledeyuan00_ati.py (see its docstring
for frames, signs and the evidence).  Source file(s): {files}.

LICENCE: the source repository has no licence (all rights reserved).
This converted copy is for local testing only. Do not commit it.
"""

HEADER = "t,wrist_fx,wrist_fy,wrist_fz,wrist_tx,wrist_ty,wrist_tz,qw,qx,qy,qz"


def write_dataset(out: str, name: str, t, F, T, q_xyzw, what: str, files: str) -> None:
    os.makedirs(out, exist_ok=True)
    if os.path.exists(os.path.join(out, "wrist.csv")):
        print(f"  overwriting {out}/wrist.csv (converter output, not a result)")
    qn = q_xyzw / np.linalg.norm(q_xyzw, axis=1, keepdims=True)
    # w first, as the format's qw,qx,qy,qz; sign of the quaternion kept
    rows = np.column_stack([t, F, T, qn[:, 3], qn[:, 0], qn[:, 1], qn[:, 2]])
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"{name}: t not strictly increasing")
    np.savetxt(os.path.join(out, "wrist.csv"), rows, delimiter=",", header=HEADER,
               comments="", fmt="%.10g")
    with open(os.path.join(out, "robot.toml"), "w") as f:
        f.write(ROBOT_TOML.format(name=name))
    with open(os.path.join(out, "dataset.toml"), "w") as f:
        f.write(DATASET_TOML)
    with open(os.path.join(out, "README.md"), "w") as f:
        f.write(README.format(name=name, what=what, files=files))
    print(f"  wrote {out}: {len(t)} rows")


def convert_timeseries(path: str):
    D = np.loadtxt(path, delimiter=",")
    if D.shape[1] != 11:
        raise ValueError(f"{path}: expected 11 columns t,F,T,qx,qy,qz,qw, got {D.shape[1]}")
    t = 1000.0 + D[:, 0]
    return t, D[:, 1:4], D[:, 4:7], D[:, 7:11]


def convert_pose_pair(pose_path: str, wrench_path: str):
    P = np.loadtxt(pose_path, delimiter=",")
    W = np.loadtxt(wrench_path, delimiter=",")
    if P.shape[1] != 7 or W.shape[1] != 6 or len(P) != len(W):
        raise ValueError(f"{pose_path}/{wrench_path}: expected (n,7) and (n,6)")
    q = P[:, 3:7]
    R = quat_xyzw_to_matrix(q)
    # wrench given in the base frame (F_b = R F_s, T_b = R T_s): back to sensor frame
    F = np.einsum("nji,nj->ni", R, W[:, :3])
    T = np.einsum("nji,nj->ni", R, W[:, 3:])
    t = 1000.0 + np.arange(len(P), dtype=float)
    return t, F, T, q


def skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def check(name: str, t, F, T, q, g=9.81) -> None:
    """Linear LS of offset + weight vector (free direction in base) + CoM, and
    the spread of |F - f0| (should be the constant m g)."""
    R = quat_xyzw_to_matrix(q)
    # quasi-static rows: rotation change to both neighbours < 0.01 deg (time series only)
    n = len(t)
    if n > 200:
        d = np.einsum("nij,nik->njk", R[1:], R[:-1])
        ang = np.degrees(np.arccos(np.clip((np.trace(d, axis1=1, axis2=2) - 1) / 2, -1, 1)))
        still = np.zeros(n, bool)
        still[1:-1] = (ang[1:] < 0.01) & (ang[:-1] < 0.01)
    else:
        still = np.ones(n, bool)
    idx = np.flatnonzero(still)
    A = np.zeros((3 * len(idx), 6))
    for k, i in enumerate(idx):
        A[3 * k:3 * k + 3, :3] = R[i].T
        A[3 * k:3 * k + 3, 3:] = np.eye(3)
    x = np.linalg.lstsq(A, F[idx].reshape(-1), rcond=None)[0]
    w, f0 = x[:3], x[3:]
    rF = (A @ x - F[idx].reshape(-1)).reshape(-1, 3)
    A2 = np.zeros((3 * len(idx), 6))
    for k, i in enumerate(idx):
        A2[3 * k:3 * k + 3, :3] = -skew(R[i].T @ w)
        A2[3 * k:3 * k + 3, 3:] = np.eye(3)
    y = np.linalg.lstsq(A2, T[idx].reshape(-1), rcond=None)[0]
    rT = (A2 @ y - T[idx].reshape(-1)).reshape(-1, 3)
    fm = np.linalg.norm(F[idx] - f0, axis=1)
    tilt = np.degrees(np.arccos(-w[2] / np.linalg.norm(w)))
    gs = np.einsum("nji,j->ni", R[idx], np.array([0, 0, -1.0]))  # gravity dir in sensor
    print(f"[{name}] quasi-static rows used: {len(idx)} of {n}")
    print(f"  weight vector in base w = {np.round(w, 3)} N, |w| = {np.linalg.norm(w):.3f} N "
          f"(m = {np.linalg.norm(w) / g:.4f} kg), tilt from -z = {tilt:.2f} deg")
    print(f"  force offset f0 = {np.round(f0, 3)} N; force rms per axis {np.round(np.sqrt((rF**2).mean(0)), 3)} N")
    print(f"  CoM in sensor frame c = {np.round(y[:3] * 1000, 1)} mm; torque offset t0 = "
          f"{np.round(y[3:], 4)} N*m; torque rms {np.round(np.sqrt((rT**2).mean(0)) * 1000, 2)} mN*m")
    print(f"  |F - f0| over rows: mean {fm.mean():.3f} N, sd {fm.std():.3f} N, range "
          f"[{fm.min():.3f}, {fm.max():.3f}] N")
    print(f"  gravity direction in sensor frame spans: min {np.round(gs.min(0), 2)} max {np.round(gs.max(0), 2)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("src", help="the datas/ folder of a clone of leledeyuan00/Gravity-Compensation-F-T-sensor")
    ap.add_argument("out", help="output root; one sub-directory per dataset")
    ap.add_argument("--check", action="store_true", help="print a least-squares sanity check")
    a = ap.parse_args(argv)
    jobs = []
    ts = os.path.join(a.src, "GP2025-07-22-22-06-02.txt")
    if os.path.exists(ts):
        jobs.append(("timeseries", convert_timeseries(ts),
                     "10 Hz time series, 6 holds of ~14.6 s and the moves between them (2025-07-22)",
                     "datas/GP2025-07-22-22-06-02.txt"))
    p100 = (os.path.join(a.src, "recorded_messages_pose_100.txt"), os.path.join(a.src, "recorded_messages_wrench_100.txt"))
    if all(map(os.path.exists, p100)):
        jobs.append(("poses100", convert_pose_pair(*p100),
                     "100 static poses, one row each, synthetic clock 1 s apart (2025-08)",
                     "datas/recorded_messages_pose_100.txt, datas/recorded_messages_wrench_100.txt"))
    p7 = (os.path.join(a.src, "recorded_messages_pose.txt"), os.path.join(a.src, "recorded_messages_wrench.txt"))
    if all(map(os.path.exists, p7)):
        jobs.append(("poses7", convert_pose_pair(*p7),
                     "7 static poses, one row each, synthetic clock 1 s apart (2025-03)",
                     "datas/recorded_messages_pose.txt, datas/recorded_messages_wrench.txt"))
    st = os.path.join(a.src, "static_pose_recording.txt")
    if os.path.exists(st):
        D = np.loadtxt(st, delimiter=",")
        if D.shape[1] == 11:
            jobs.append(("static35h", (1000.0 + D[:, 0], D[:, 1:4], D[:, 4:7], D[:, 7:11]),
                         "35 h static recording (temperature drift)", "datas/static_pose_recording.txt"))
        else:
            print(f"skipping {st}: {D.shape[1]} columns, no orientation to write qw..qz")
    if not jobs:
        print("no source files found in", a.src, file=sys.stderr)
        return 1
    for name, (t, F, T, q), what, files in jobs:
        write_dataset(os.path.join(a.out, name), f"leledeyuan00_ati_{name}", t, F, T, q, what, files)
        if a.check:
            check(name, t, F, T, q)
    return 0


if __name__ == "__main__":
    sys.exit(main())
