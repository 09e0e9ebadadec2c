#!/usr/bin/env python3
"""Convert an ergoCub / iCub ``robot_logger_device_*.mat`` log (YARPRobotLoggerDevice of
ami-iit/bipedal-locomotion-framework, MATLAB v7.3 = HDF5) to the ftcal_nlp interchange
format, DATA_FORMAT.md section 5 (URDF load below a leg transducer).

STATUS: DRAFT, NOT RUN ON REAL DATA.  The only logs found for it are Git-LFS objects that
cannot be read here; the URDF rewriting and the CSV writing were tested on the real
ergoCubSN000.urdf and on a synthetic log (``--selftest``).  Check the numbers (see
"sanity check" below) on the first real file.

Target source
-------------
github.com/ami-iit/paper_sorrentino_2024_icra_robot-dynamics-estimation (BSD-3-Clause,
Copyright (c) 2023 Artificial and Mechanical Intelligence / IIT), commit 8d1dc26:
``dataset/ZeroTorqueLeg/{RNEA,UKF}/robot_logger_device_2023_08_31_*.mat`` (32 MB each) and
``dataset/PDGravityLeg/...``, ``PDGravityTorso``, ``CartesianTracking``: ergoCub SN000 on a
fixed base (``root_link`` clamped, the source's own estimator uses gravity [0,0,-g] in
``root_link``), right leg moved (zero-torque / PD+gravity), FT sensors ``r_leg_ft``,
``r_foot_front_ft``, ``r_foot_rear_ft`` with accelerometers/gyros, joint states, motor
currents.  URDF: ``python/urdf/ergoCubSN000.urdf`` of the same repo.
Same log format: ami-iit/paper_Mohamed_2023_humanoids_nonlinear-ft-calibration (iRonCub
arms with 0-10 kg weights; data on Hugging Face), isorrentino/ft-calib-net (iCubGenova09,
LFS).  BSD-3 allows redistribution of a converted copy with the copyright notice and
licence text kept.

Data layout read (from python/rde_ergocub_application.py of the source):
``robot_logger_device/joints_state/positions/{data,timestamps,elements_names}``,
``robot_logger_device/FTs/<name>/{data,timestamps}`` (data squeezed to (N, 6) resp.
(N, n_joints)), ``accelerometers/<name>/...``.  Units assumed: FT N and N*m, joint
positions rad (YarpSensorBridge converts YARP degrees to rad: the source feeds them to
iDynTree unchanged), timestamps YARP clock s (Unix epoch).

Frames and signs
----------------
* ``B`` = the URDF root (``root_link`` for ergoCub), upright: ``gx,gy,gz = 0,0,-1`` on
  every row (fixed base; same assumption as the source).  If the base was tilted, this
  is wrong; use ``--gravity x,y,z``.
* The FT sensor in the URDF is a fixed joint (``r_leg_ft_sensor``: r_hip_2 -> r_hip_3)
  plus an iDynTree ``<sensor>`` element whose ``<origin>`` is the sensor frame relative to
  the joint's CHILD link (SDF convention, followed by iDynTree) and whose
  ``measure_direction`` is ``child_to_parent``: the wrench the child subtree (the leg)
  exerts on the parent, in the sensor frame, which is what section 1 asks for.  The
  format wants a LINK whose frame is the sensor frame and whose subtree is the load, so
  the URDF copy gets a massless link ``<leg>_ft_frame`` inserted between parent and child
  (joint ``<ft joint>``: parent -> new link at T_PC*T_CS; joint ``<ft joint>_to_child``:
  new link -> child at T_CS^-1).  Masses and all other joints are unchanged.
* UNCERTAIN: the sensor-origin convention (child link vs joint frame: identical here
  because the child link frame IS the joint frame) and the sign: sanity check = while
  the leg hangs still, ``F . g_ft > 0`` (force along gravity) and |F - offset| ~ leg
  weight (ergoCub right leg below r_leg_ft: 11.0 kg in ergoCubSN000.urdf).

Streams: FT and joint logs have their own timestamps.  Rows are FT samples; joint
positions are linearly interpolated to FT times (no shift applied; any lag between the
streams stays in the data for the tool to find).  Rows outside the joint log's time
span are dropped.

Usage:
    python3 convert_ergocub_robot_logger.py LOG.mat URDF OUT_DIR
        [--ft r_leg_ft] [--sensor r_leg_ft_sensor] [--leg r_leg] [--gravity 0,0,-1]
    python3 convert_ergocub_robot_logger.py --selftest URDF OUT_DIR
Needs numpy and h5py (pip install h5py) for real logs.
"""
from __future__ import annotations

import argparse
import os
import sys
import xml.etree.ElementTree as ET

import numpy as np


# ---------------------------------------------------------------- rotations
def rpy_to_R(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx  # URDF: fixed-axis roll, pitch, yaw


def R_to_rpy(R):
    p = np.arcsin(np.clip(-R[2, 0], -1, 1))
    if abs(np.cos(p)) > 1e-9:
        r = np.arctan2(R[2, 1], R[2, 2])
        y = np.arctan2(R[1, 0], R[0, 0])
    else:  # gimbal lock
        r = 0.0
        y = np.arctan2(-R[0, 1], R[1, 1])
    return r, p, y


def origin_T(el):
    T = np.eye(4)
    if el is None:
        return T
    xyz = [float(v) for v in el.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in el.get("rpy", "0 0 0").split()]
    T[:3, :3] = rpy_to_R(*rpy)
    T[:3, 3] = xyz
    return T


def T_attrs(T):
    r, p, y = R_to_rpy(T[:3, :3])
    return {"xyz": " ".join(f"{v:.12g}" for v in T[:3, 3]), "rpy": f"{r:.12g} {p:.12g} {y:.12g}"}


# ---------------------------------------------------------------- URDF
def insert_sensor_link(urdf_in: str, urdf_out: str, sensor: str, new_link: str) -> dict:
    """Rewrite the URDF so that ``new_link`` has the FT sensor's frame and the load below."""
    tree = ET.parse(urdf_in)
    robot = tree.getroot()
    sens = [s for s in robot.findall("sensor") if s.get("name") == sensor]
    if not sens:
        raise KeyError(f"{urdf_in}: no top-level <sensor name='{sensor}'>")
    s = sens[0]
    pj = s.find("parent")
    jname = pj.get("joint") if pj is not None else None
    ft = s.find("force_torque")
    frame = ft.findtext("frame", "child").strip() if ft is not None else "child"
    direction = ft.findtext("measure_direction", "child_to_parent").strip() if ft is not None else "child_to_parent"
    if direction != "child_to_parent":
        raise ValueError(f"{sensor}: measure_direction {direction}; flip the readings' sign before use")
    if frame not in ("sensor", "child"):
        raise ValueError(f"{sensor}: frame '{frame}' not handled")
    T_CS = origin_T(s.find("origin")) if frame == "sensor" else np.eye(4)
    joints = [j for j in robot.findall("joint") if j.get("name") == jname]
    if not joints:
        raise KeyError(f"{urdf_in}: sensor {sensor} names joint {jname}, not found")
    j = joints[0]
    if j.get("type") != "fixed":
        raise ValueError(f"{jname} is not fixed")
    P, C = j.find("parent").get("link"), j.find("child").get("link")
    T_PC = origin_T(j.find("origin"))
    if any(l.get("name") == new_link for l in robot.findall("link")):
        raise ValueError(f"link {new_link} already exists")
    # joint jname: P -> new_link, origin T_PC*T_CS
    o = j.find("origin")
    if o is None:
        o = ET.SubElement(j, "origin")
    o.attrib.update(T_attrs(T_PC @ T_CS))
    j.find("child").set("link", new_link)
    ET.SubElement(robot, "link", {"name": new_link})
    j2 = ET.SubElement(robot, "joint", {"name": f"{jname}_to_child", "type": "fixed"})
    ET.SubElement(j2, "origin", T_attrs(np.linalg.inv(T_CS)))
    ET.SubElement(j2, "parent", {"link": new_link})
    ET.SubElement(j2, "child", {"link": C})
    tree.write(urdf_out, xml_declaration=True, encoding="utf-8")
    return {"joint": jname, "parent": P, "child": C, "T_CS": T_CS}


def subtree_mass(urdf: str, link: str) -> float:
    robot = ET.parse(urdf).getroot()
    kids = {}
    for j in robot.findall("joint"):
        kids.setdefault(j.find("parent").get("link"), []).append(j.find("child").get("link"))
    mass = {l.get("name"): float(l.find("inertial/mass").get("value")) if l.find("inertial/mass") is not None else 0.0
            for l in robot.findall("link")}
    tot, stack = 0.0, [link]
    while stack:
        l = stack.pop()
        tot += mass.get(l, 0.0)
        stack += kids.get(l, [])
    return tot


def movable_joints(urdf: str) -> list:
    robot = ET.parse(urdf).getroot()
    return [j.get("name") for j in robot.findall("joint") if j.get("type") in ("revolute", "continuous", "prismatic")]


# ---------------------------------------------------------------- log reading
def read_log(path: str) -> dict:
    import h5py  # only needed for real logs

    def walk(g):
        out = {}
        for k, v in g.items():
            if not isinstance(v, h5py.Group) or k in ("#refs#", "log"):
                continue
            if "data" in v.keys():
                d = {"data": np.squeeze(np.array(v["data"])), "timestamps": np.squeeze(np.array(v["timestamps"]))}
                if "elements_names" in v.keys():
                    refs = v["elements_names"]
                    d["elements_names"] = ["".join(chr(c[0]) for c in g.file[r]) for r in refs[0]]
                out[k] = d
            else:
                out[k] = walk(v)
        return out

    with h5py.File(path, "r") as f:
        d = walk(f)
    return d.get("robot_logger_device", d)


def as_time_major(a: np.ndarray, n_t: int) -> np.ndarray:
    a = np.asarray(a, float)
    if a.ndim == 1:
        return a[:, None]
    if a.shape[0] == n_t:
        return a
    if a.shape[1] == n_t:
        return a.T
    raise ValueError(f"array {a.shape} does not match {n_t} timestamps")


# ---------------------------------------------------------------- conversion
def convert(log: dict, urdf_in: str, out: str, ft_key: str, sensor: str, leg: str, grav) -> None:
    os.makedirs(out, exist_ok=True)
    new_link = f"{leg}_ft_frame"
    insert_sensor_link(urdf_in, os.path.join(out, "robot.urdf"), sensor, new_link)
    fts = log["FTs"]
    if ft_key not in fts:
        alt = [k for k in fts if k.startswith(ft_key) or ft_key.startswith(k)]
        if not alt:
            raise KeyError(f"FT '{ft_key}' not in log; has {sorted(fts)}")
        ft_key = alt[0]
    tf = np.asarray(fts[ft_key]["timestamps"], float).ravel()
    W = as_time_major(fts[ft_key]["data"], len(tf))
    js = log["joints_state"]["positions"]
    tj = np.asarray(js["timestamps"], float).ravel()
    Q = as_time_major(js["data"], len(tj))
    names = js.get("elements_names")
    if names is None:
        raise KeyError("joints_state/positions has no elements_names; pass the joint list by hand")
    urdf_joints = set(movable_joints(urdf_in))
    keep = (tf >= tj[0]) & (tf <= tj[-1])
    order = np.argsort(tf[keep], kind="stable")
    t = tf[keep][order]
    W = W[keep][order]
    uniq = np.concatenate([[True], np.diff(t) > 0])
    t, W = t[uniq], W[uniq]
    cols = {"t": t}
    for k, c in enumerate("fx fy fz tx ty tz".split()):
        cols[f"{leg}_{c}"] = W[:, k]
    skipped = []
    for k, n in enumerate(names):
        if n in urdf_joints:
            cols[f"q_{n}"] = np.interp(t, tj, Q[:, k])
        else:
            skipped.append(n)
    g = np.asarray(grav, float) / np.linalg.norm(grav)
    for k, c in enumerate("gx gy gz".split()):
        cols[c] = np.full(len(t), g[k])
    hdr = list(cols)
    np.savetxt(os.path.join(out, f"{leg}.csv"), np.column_stack([cols[h] for h in hdr]), delimiter=",",
               header=",".join(hdr), comments="", fmt=["%.6f"] + ["%.10g"] * (len(hdr) - 1))
    with open(os.path.join(out, "robot.toml"), "w") as f:
        f.write(f'name = "ergocub_{leg}"\ng = 9.81\nlegs = ["{leg}"]\nurdf = "robot.urdf"\n\n'
                f'[transducers.{leg}]\nlink = "{new_link}"\n'
                f'model = "IIT FTSens strain2 ({sensor}); log key {ft_key}"\n')
    with open(os.path.join(out, "dataset.toml"), "w") as f:
        f.write(f'robot = "robot.toml"\n\n[[recording]]\nfile = "{leg}.csv"\nkind = "hanging"\nfree = ["{leg}"]\n')
    m = subtree_mass(os.path.join(out, "robot.urdf"), new_link)
    print(f"wrote {out}: {len(t)} rows, {len(hdr) - 10} joint columns; load mass in URDF {m:.3f} kg; "
          f"joints not in URDF (dropped): {skipped}")
    # quick look: force magnitude spread while joints still
    still = np.r_[True, np.all(np.abs(np.diff(np.column_stack([cols[h] for h in hdr if h.startswith('q_')]), axis=0)) < 1e-4, axis=1)]
    Fm = np.linalg.norm(W[still, :3], axis=1)
    print(f"  |F| over {still.sum()} still rows: mean {Fm.mean():.3f} N sd {Fm.std():.3f} (offset included); "
          f"URDF weight {m * 9.81:.2f} N")


def selftest(urdf: str, out: str) -> None:
    """Synthetic log in the reader's output layout (no physics): checks the plumbing only."""
    rng = np.random.default_rng(0)
    names = ["r_hip_pitch", "r_hip_roll", "r_hip_yaw", "r_knee", "r_ankle_pitch", "r_ankle_roll", "not_a_joint"]
    tj = 1.69e9 + np.arange(0, 10, 0.01)
    tf = 1.69e9 + 0.003 + np.arange(0, 10, 0.01)
    log = {"joints_state": {"positions": {"data": 0.1 * rng.standard_normal((len(tj), len(names))),
                                          "timestamps": tj, "elements_names": names}},
           "FTs": {"r_leg_ft": {"data": rng.standard_normal((6, len(tf))), "timestamps": tf}}}
    convert(log, urdf, out, "r_leg_ft", "r_leg_ft_sensor", "r_leg", (0, 0, -1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--selftest", action="store_true")
    ap.add_argument("args", nargs="+", help="LOG.mat URDF OUT_DIR  (or with --selftest: URDF OUT_DIR)")
    ap.add_argument("--ft", default="r_leg_ft", help="key under FTs in the log")
    ap.add_argument("--sensor", default="r_leg_ft_sensor", help="URDF <sensor> name")
    ap.add_argument("--leg", default="r_leg", help="transducer name in the output")
    ap.add_argument("--gravity", default="0,0,-1", help="gravity direction in the URDF root frame")
    a = ap.parse_args(argv)
    if a.selftest:
        selftest(*a.args)
        return 0
    logp, urdf, out = a.args
    convert(read_log(logp), urdf, out, a.ft, a.sensor, a.leg, [float(v) for v in a.gravity.split(",")])
    return 0


if __name__ == "__main__":
    sys.exit(main())
