"""Plausibility of free loads (issue 30 item 2): convention errors in a wrist payload, a URDF leg or an arm stop the
run with an error naming the cause, before the fit (quaternion order, gravity sign, joint degrees, units) or after
it (a mount far from the nominal: the frame; mass <= 0 where gravity spans too few directions to tell before);
clean data of every kind pass. Small simulated datasets (``sim/free``); the arm is the shared ``sample_arm``
recording cut to its first holds."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.data import read_dataset, read_robot, write_robot
from ftcal_nlp.core.errors import DataFormatError, ImplausibleLoadFit
from ftcal_nlp.estimate.freeload.plausibility import (
    MIN_FORCE_NOISE_N,
    QUAT_ORDER_RATIO,
    gravity_fit,
    load_fit,
    rotation_angle_deg,
)
from ftcal_nlp.core.geometry import rotvec_to_rotation
from ftcal_nlp.pipeline import calibrate
from ftcal_nlp.run import main as run_main
from ftcal_nlp.core.settings import CalibrationSettings, DiagnoseSettings
from ftcal_nlp.sim.free import (
    PayloadConfig,
    UrdfLegConfig,
    simulate_payload,
    simulate_urdf_leg,
    write_free_load,
)

SHARED = Path("/work/shared")
needs_arm = pytest.mark.skipif(not (SHARED / "sample_arm" / "wrist.csv").is_file(), reason="shared samples absent")
SETTINGS = CalibrationSettings(diagnose=DiagnoseSettings(enabled=False))
Q = ["qw", "qx", "qy", "qz"]


@pytest.fixture(scope="module")
def payload():
    return simulate_payload(PayloadConfig(seed=8, n_orientations=6, hold_s=3.0, move_s=1.5))


@pytest.fixture(scope="module")
def payload_g():
    return simulate_payload(PayloadConfig(seed=9, n_orientations=6, hold_s=3.0, move_s=1.5, orientation="gravity"))


@pytest.fixture(scope="module")
def leg():
    return simulate_urdf_leg(UrdfLegConfig(seed=5, n_orientations=5, poses_per_orientation=2, hold_s=3.0, move_s=2.0))


def _write(res, folder: Path, frame: pd.DataFrame | None = None) -> Path:
    return write_free_load(res if frame is None else replace(res, frame=frame), folder)


def _arm(folder: Path, holds: int = 12) -> Path:
    """The shared arm sample (joints-only URDF, gravity_body) cut to its first ``holds`` holds (4 s + >= 2.5 s each)."""
    folder.mkdir()
    for f in ("dataset.toml", "robot.toml", "arm.urdf"):
        (folder / f).write_text((SHARED / "sample_arm" / f).read_text())
    df = pd.read_csv(SHARED / "sample_arm" / "wrist.csv")
    df[df["t"] < df["t"].iloc[0] + holds * 6.6].to_csv(folder / "wrist.csv", index=False)
    return folder / "dataset.toml"


def _calibrate(manifest: Path):
    return calibrate(read_dataset(manifest), SETTINGS)


# ----------------------------------------------------------------------------- the linear physics


def test_gravity_fit_recovers_sign_mass_and_mount() -> None:
    """Closed-form fit of f = f_o + m E^T b: the sign from three gravity directions, the mount as drawn."""
    rng = np.random.default_rng(0)
    b = rng.normal(size=(400, 3))
    b *= 9.81 / np.linalg.norm(b, axis=1, keepdims=True)
    E = rotvec_to_rotation(np.array([0.1, -0.2, 0.3]))
    f = np.array([1.0, -2.0, 0.5]) + 1.3 * b @ E + rng.normal(scale=0.02, size=b.shape)
    fit = gravity_fit(f, b)
    assert fit.sign_determined and abs(fit.mass_kg - 1.3) < 1e-3 and rotation_angle_deg(fit.rotation @ E.T) < 0.1
    assert fit.rms_N < 0.05
    rev = gravity_fit(f, -b)
    assert rev.sign_determined and abs(rev.mass_kg + 1.3) < 1e-3 and rev.rms_N < QUAT_ORDER_RATIO * 0.1
    K = np.zeros((len(b), 3, 4))
    K[:, :, 1:] = np.eye(3)
    h = 1.3 * np.array([0.01, 0.0, 0.08])
    w = np.c_[f, np.cross(h, b @ E) + 0.1]
    lf = load_fit(w, b, K, np.array([1.0, 0, 0, 0]), fit.rotation, np.r_[[0.02] * 3, [1e-9] * 3])
    assert abs(lf.mass_kg - 1.3) < 1e-3 and np.allclose(lf.theta[1:], h, atol=1e-3) and np.all(lf.unexplained < 0.01)


# ----------------------------------------------------------------------------- clean data of every kind


def test_clean_payload_and_leg_pass(payload, leg, tmp_path) -> None:
    for name, res in (("payload", payload), ("leg", leg)):
        run = _calibrate(_write(res, tmp_path / name))
        r = next(iter(run.free_loads.legs.values()))
        assert float(r.load.mass_row @ r.theta) > 0 and rotation_angle_deg(r.rotation) < 5


@needs_arm
def test_clean_arm_passes(tmp_path) -> None:
    run = _calibrate(_arm(tmp_path / "arm"))
    assert abs(float(run.free_loads.legs["wrist"].load.mass_row @ run.free_loads.legs["wrist"].theta) - 0.8446) < 0.05


# ----------------------------------------------------------------------------- before the fit


@pytest.mark.parametrize("which", ["payload", "leg"])
def test_quaternion_in_xyzw_order_is_named(which, payload, leg, tmp_path) -> None:
    res = payload if which == "payload" else leg
    df = res.frame.copy()
    df[Q] = df[Q].to_numpy()[:, [1, 2, 3, 0]]
    with pytest.raises(DataFormatError, match=r"columns qw, qx, qy, qz: .* with the columns read as x, y, z, w .*are the "
                                              r"quaternion columns in x, y, z, w order\?"):
        _calibrate(_write(res, tmp_path / "d", df))


def test_gravity_pointing_up_is_named(payload_g, tmp_path) -> None:
    df = payload_g.frame.copy()
    df[["gx", "gy", "gz"]] *= -1.0            # an accelerometer's reading: up
    with pytest.raises(DataFormatError, match=r"follow gravity reversed: a load mass of -1\.\d+ kg .*gx, gy, gz point up"):
        _calibrate(_write(payload_g, tmp_path / "d", df))


@needs_arm
def test_gravity_body_up_is_named_on_an_arm(tmp_path) -> None:
    m = _arm(tmp_path / "arm")
    m.write_text(m.read_text().replace("gravity_body = [0, 0, -1]", "gravity_body = [0, 0, 1]"))
    with pytest.raises(DataFormatError, match=r"follow gravity reversed: .*the sign of gravity_body = \[0\.0, 0\.0, 1\.0\]"):
        _calibrate(m)


def test_degrees_on_a_continuous_joint_are_named(leg, tmp_path) -> None:
    """The knee carries links below the sensor: only the torques see it (the forces see the total mass)."""
    df = leg.frame.copy()
    df["q_r_knee"] = np.degrees(df["q_r_knee"])
    d = _write(leg, tmp_path / "d", df).parent
    urdf = d / "robot.urdf"
    urdf.write_text(re.sub(r'(<joint name="r_knee" type=)"revolute"', r'\1"continuous"', urdf.read_text()))
    with pytest.raises(DataFormatError, match=r"columns q_r_knee \(continuous joints of the URDF\): .* are the joint "
                                              r"angles in degrees\?"):
        _calibrate(d / "dataset.toml")
    # the same joint in radians passes: the check needs degrees
    _calibrate(_write(leg, tmp_path / "ok"))


@needs_arm
def test_degrees_on_an_arm_with_continuous_joints_are_named(tmp_path) -> None:
    m = _arm(tmp_path / "arm")
    urdf = m.parent / "arm.urdf"
    urdf.write_text(urdf.read_text().replace('type="revolute"', 'type="continuous"'))
    df = pd.read_csv(m.parent / "wrist.csv")
    q = [c for c in df.columns if c.startswith("q_")]
    df[q] = np.degrees(df[q])
    df.to_csv(m.parent / "wrist.csv", index=False)
    with pytest.raises(DataFormatError, match=r"are the joint angles in degrees\?"):
        _calibrate(m)


@pytest.mark.parametrize("which", ["payload", "leg"])
def test_readings_in_kN_are_named(which, payload, leg, tmp_path) -> None:
    """A URDF load: its weight against the URDF's nominal mass; a payload: a force noise no transducer has in N."""
    res = payload if which == "payload" else leg
    df = res.frame.copy()
    cols = [c for c in df.columns if re.search(r"_[ft][xyz]$", c)]
    df[cols] /= 1000.0
    expect = (rf"per-sample noise is .* below any six-axis transducer's resolution \({MIN_FORCE_NOISE_N:g} N\)" if which == "payload"
              else r"a mass of 0\.00\d+ kg against the URDF's nominal \d\.\d+ kg")
    with pytest.raises(DataFormatError, match=expect + r".*are the readings in kN \(and kN\*m\)\?"):
        _calibrate(_write(res, tmp_path / "d", df))


# ----------------------------------------------------------------------------- after the fit


def test_mount_90_deg_off_nominal_names_the_frame(payload, tmp_path) -> None:
    d = _write(payload, tmp_path / "d").parent
    robot = read_robot(d / "robot.toml")
    tr = robot.transducers["wrist"]
    R = tr.rotation @ rotvec_to_rotation(np.array([0.0, 0.0, np.pi / 2]))
    write_robot(replace(robot, transducers={"wrist": replace(tr, rotation=R)}), d / "robot.toml")
    with pytest.raises(ImplausibleLoadFit, match=r"a mounting rotation (8|9)\d(\.\d)? deg from the nominal \(expected within the 20 deg bound"
                                                 r".*turned 9\d deg .*\[transducers\.wrist\] rotation in .*robot\.toml .*is likely "
                                                 r"wrong") as ei:
        _calibrate(d / "dataset.toml")
    assert ei.value.causes == ("frame",) and ei.value.leg == "wrist"


def test_reversed_gravity_in_a_plane_is_named_after_the_fit(payload_g, tmp_path) -> None:
    """Gravity sweeping one plane cannot tell a reversed gravity from a mount turned half round before the fit; the
    fit's mass <= 0 is the error, and reversing gravity is the cause that makes the load plausible."""
    df = payload_g.frame.copy()
    g = df[["gx", "gy", "gz"]].to_numpy()
    ang = np.arctan2(g[:, 1], g[:, 2])                               # every direction into the y-z plane, pointing up
    df[["gx", "gy", "gz"]] = -np.c_[np.zeros(len(g)), np.sin(ang), np.cos(ang)]
    good = np.c_[np.zeros(len(g)), np.sin(ang), np.cos(ang)]
    # the readings of the payload for the planar gravity: re-simulate forces by the payload's own model
    cfg = payload_g.config
    E = rotvec_to_rotation(np.asarray(payload_g.truth["mount_rotvec"], float))
    R_nom = rotvec_to_rotation(np.array([0.0, 0.0, cfg.rotation_rpy[2]]))
    gft = 9.81 * good @ R_nom @ E
    off = np.asarray(payload_g.truth["offset"], float)
    rng = np.random.default_rng(1)
    w = np.c_[cfg.mass_kg * gft, np.cross(cfg.mass_kg * np.asarray(cfg.com_m), gft)] + off
    w += rng.normal(size=w.shape) * np.r_[[cfg.noise_force_N] * 3, [cfg.noise_torque_Nm] * 3]
    df[[f"wrist_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]] = w
    with pytest.raises(ImplausibleLoadFit, match=r"a load mass of -1\.\d+ kg \(expected > 0\).*with gravity reversed the load "
                                                 r"mass is 1\.\d+ kg.*gx, gy, gz point up") as ei:
        _calibrate(_write(payload_g, tmp_path / "d", df))
    assert ei.value.causes == ("gravity sign",)


def test_the_command_line_prints_one_error_and_exits_2(payload, tmp_path, capsys) -> None:
    df = payload.frame.copy()
    df[Q] = df[Q].to_numpy()[:, [1, 2, 3, 0]]
    _write(payload, tmp_path / "data", df)
    cfg = tmp_path / "run.toml"
    cfg.write_text('[data]\nmanifest = "data/dataset.toml"\n[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    rc = run_main([str(cfg)])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err and "x, y, z, w order?" in lines[0]


def test_a_failed_fit_names_the_cause_that_fixes_the_load(payload, tmp_path, monkeypatch) -> None:
    """IPOPT lost on data off by a convention the checks before the fit cannot tell (here a mount 90 deg off the
    nominal): the solver's failure comes with the cause whose linear refit makes the load plausible."""
    from ftcal_nlp.estimate import freeload
    from ftcal_nlp.core.errors import SolverError

    d = _write(payload, tmp_path / "d").parent
    robot = read_robot(d / "robot.toml")
    tr = robot.transducers["wrist"]
    write_robot(replace(robot, transducers={"wrist": replace(tr, rotation=tr.rotation @ rotvec_to_rotation(np.array([0, 0, np.pi / 2])))}),
                d / "robot.toml")

    def lost(*_a, **_k):
        raise SolverError("IPOPT did not converge", status="Search_Direction_Becomes_Too_Small")

    monkeypatch.setattr(freeload, "fit_free_loads", lost)
    with pytest.raises(ImplausibleLoadFit, match=r"the free-load fit failed \(IPOPT did not converge\); tried in order: .*"
                                                 r"rotation in .*robot\.toml .*is likely wrong") as ei:
        _calibrate(d / "dataset.toml")
    assert ei.value.causes == ("frame",)
    monkeypatch.undo()
    with pytest.raises(SolverError):           # clean data and a failing solver: the solver's own error stands
        monkeypatch.setattr(freeload, "fit_free_loads", lost)
        _calibrate(_write(payload, tmp_path / "clean"))


# ----------------------------------------------------------------------------- a weighed load mass (load_mass_kg)


def _weighed(res, folder: Path, kg: float, frame: pd.DataFrame | None = None) -> Path:
    """The dataset of ``res`` with ``[transducers.wrist] load_mass_kg = kg`` in its robot.toml."""
    d = _write(res, folder, frame).parent
    robot = read_robot(d / "robot.toml")
    write_robot(replace(robot, transducers={"wrist": replace(robot.transducers["wrist"], load_mass_kg=kg)}), d / "robot.toml")
    assert read_robot(d / "robot.toml").transducers["wrist"].load_mass_kg == kg   # read back, not dropped
    return d / "dataset.toml"


def test_readings_in_mN_against_a_weighed_mass_are_named(payload, tmp_path) -> None:
    """A rigid payload has no URDF mass; the weighed one tells a unit: mN readings weigh 1000x the tool."""
    m = float(payload.truth["mass_kg"])
    df = payload.frame.copy()
    cols = [c for c in df.columns if re.search(r"_[ft][xyz]$", c)]
    df[cols] *= 1000.0
    with pytest.raises(DataFormatError, match=r"against the weighed load_mass_kg \d\.\d+ kg .*are the readings in mN"):
        _calibrate(_weighed(payload, tmp_path / "d", m, df))


def test_a_weighed_mass_the_readings_disagree_with_is_noted(payload, tmp_path, caplog) -> None:
    """3 % off the true mass: far beyond the fit's se (the run keeps its fitted mass and says so); the true mass: silent."""
    m = float(payload.truth["mass_kg"])
    run = _calibrate(_weighed(payload, tmp_path / "off", 1.03 * m))
    notes = [n for n in run.notes if "weighed load_mass_kg" in n]
    assert len(notes) == 1 and re.search(r"by -2\.\d %", notes[0]), run.notes
    fitted = run.free_loads.legs["wrist"].load_report()
    assert abs(fitted["load_mass_kg"] - m) < 4 * fitted["load_mass_se_kg"]    # the fit is the readings', not the weighing's
    run = _calibrate(_weighed(payload, tmp_path / "true", m))
    assert not [n for n in run.notes if "weighed load_mass_kg" in n], run.notes


def test_a_weighed_mass_that_is_no_mass_is_refused(payload, tmp_path) -> None:
    d = _write(payload, tmp_path / "d").parent
    text = (d / "robot.toml").read_text().replace("[transducers.wrist]", "[transducers.wrist]\nload_mass_kg = -1.2", 1)
    (d / "robot.toml").write_text(text)
    with pytest.raises(DataFormatError, match=r"\[transducers\.wrist\]: 'load_mass_kg' = -1\.2; expected the load's mass"):
        read_robot(d / "robot.toml")
