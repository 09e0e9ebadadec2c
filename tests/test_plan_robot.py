"""``plan`` on a section-5 robot.toml with a protocol of holds, and on a pilot whose residuals are serially
correlated (issue 30 item 4).

The holds of a simulated session, written as a protocol, must give the se the estimator reports on that session
(white noise: the weighted fit attains the bound; REL as in test_plan_loads for the payload, looser for the URDF
leg whose holds the quasi-static selection trims more). A pilot with AR(1) noise: the run widens its se by the
AR(1) inflation, and the plan must carry it (within 25 %, the issue's bound; without the widening the plan is off
by the widening itself, > 2x here)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ftcal_nlp import plan as plan_cli
from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.core.errors import ConfigError
from ftcal_nlp.estimate.freeload import fit_free_load
from ftcal_nlp.core.geometry import rotation_to_quat
from test_plan_loads import fitted_payload
from ftcal_nlp.plan.free_load import FreeLoadPlan, plan_from_dataset, plan_from_robot
from ftcal_nlp.sim.free import (
    PayloadConfig,
    UrdfLegConfig,
    simulate_payload,
    simulate_urdf_leg,
    write_free_load,
)

REL = 0.05
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


def _held(res) -> list[int]:
    """A sample in the middle of each hold of a simulation."""
    out = []
    for k in range(int(res.hold_index.max()) + 1):
        idx = np.flatnonzero(res.hold_index == k)
        out.append(int(idx[len(idx) // 2]))
    return out


def _toml_list(v) -> str:
    return "[" + ", ".join(f"{float(x):.12g}" for x in v) + "]"


@pytest.fixture(scope="module")
def payload(tmp_path_factory):
    return fitted_payload(tmp_path_factory.mktemp("robot_payload"), seed=7)


@pytest.fixture(scope="module")
def urdf_leg(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("robot_urdf")
    res = simulate_urdf_leg(UrdfLegConfig(seed=5, n_orientations=8, poses_per_orientation=3, hold_s=4.0, move_s=2.0))
    manifest = write_free_load(res, tmp / "u")
    return tmp, res, manifest, fit_free_load(read_dataset(manifest), "r_leg")


def _payload_holds(res, hold_s: float, extra: str = "") -> str:
    quats = [rotation_to_quat(res.R_WB[i]) for i in _held(res)]
    return (f"[protocol]\nhold_s = {hold_s}\nrate_hz = 100.0\nnoise_force_N = 0.02\nnoise_torque_Nm = 0.0006\n"
            f"mass_kg = {res.truth['mass_kg']}\ncom_m = {_toml_list(res.truth['com_m'])}\n{extra}"
            "orientations = [\n" + "".join(f"  {_toml_list(q)},\n" for q in quats) + "]\n")


def _fit_se(fit) -> dict[str, float]:
    rep = fit.load_report()
    out = {f"offset_{c}": s for c, s in zip(WRENCH, fit.se[:6])}
    out["mass_kg"] = rep["load_mass_se_kg"]
    out.update({f"com_{c}": s for c, s in zip("xyz", rep["load_com_se_m"])})
    out.update({f"mount_r{c}": s for c, s in zip("xyz", fit.se[-3:])})
    return out


def test_robot_toml_without_holds_says_what_to_add(payload, urdf_leg, capsys) -> None:
    for tmp, robot in ((payload[0], payload[2].parent / "robot.toml"), (urdf_leg[0], urdf_leg[2].parent / "robot.toml")):
        assert plan_cli.main([str(robot), "-o", str(tmp / "never.json")]) == 2
        err = capsys.readouterr().err
        assert "--protocol HOLDS.toml" in err and "orientations = " in err and "holds = " in err, err
        assert "unknown key" not in err and not (tmp / "never.json").exists()


def test_payload_robot_with_held_orientations(payload, tmp_path, capsys) -> None:
    """robot.toml + the session's holds: the fit's se (the nominal rotation from the robot.toml's table); the same
    holds through a protocol naming the robot; holds all about the vertical: what they leave undetermined named."""
    _, res, manifest, fit = payload
    holds = tmp_path / "holds.toml"
    holds.write_text(_payload_holds(res, 6.0))
    out = tmp_path / "plan.json"
    assert plan_cli.main([str(manifest.parent / "robot.toml"), "--protocol", str(holds), "-o", str(out)]) == 0
    js = json.loads(out.read_text())["transducers"]["wrist"]
    assert js["load_kind"] == "rigid_payload" and js["undetermined"] == [] and js["serial_widening"] is None
    for n, s in _fit_se(fit).items():
        assert np.isfinite(js["se"][n]) and abs(js["se"][n] / s - 1) < REL, (n, js["se"][n], s)
    assert "white noise assumed" in capsys.readouterr().out
    named = tmp_path / "named.toml"
    named.write_text(_payload_holds(res, 6.0, f'robot = "{manifest.parent / "robot.toml"}"\ntransducer = "wrist"\n'))
    assert plan_cli.main([str(named), "-o", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["transducers"]["wrist"]["se"] == js["se"]
    yaw = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    flat = {"orientations": [[np.cos(a / 2), 0.0, 0.0, np.sin(a / 2)] for a in yaw], "mass_kg": 1.5}
    p = plan_from_robot(flat, tmp_path / "flat.toml", manifest.parent / "robot.toml").loads["wrist"]
    assert p.se()["mass_kg"] is None and p.se()["offset_fz"] is None and p.bound.unidentified
    assert all(np.isfinite(v) for v in p.se().values() if v is not None)
    assert any("mass_kg" in u for u in p.to_json_dict()["undetermined"])


def test_urdf_robot_with_joint_poses(urdf_leg, tmp_path) -> None:
    """A URDF load held through orientations and joint poses: finite se where the fit has them, the same parameters
    undetermined; joint poses alone with gravity_body (a fixed base) plan too, and say the tilt is taken as known."""
    _, res, manifest, fit = urdf_leg
    joints = [c[2:] for c in res.frame.columns if c.startswith("q_")]
    lines = []
    for i in _held(res):
        q = ", ".join(f"{j} = {float(res.frame[f'q_{j}'].iloc[i]):.12g}" for j in joints)
        lines.append(f"  {{quat = {_toml_list(rotation_to_quat(res.R_WB[i]))}, q = {{{q}}}}},\n")
    holds = tmp_path / "holds.toml"
    holds.write_text(f'[protocol]\nrobot = "{manifest.parent / "robot.toml"}"\nhold_s = 4.0\nnoise_force_N = 0.05\n'
                     "noise_torque_Nm = 0.003\nholds = [\n" + "".join(lines) + "]\n")
    out = tmp_path / "plan.json"
    assert plan_cli.main([str(holds), "-o", str(out)]) == 0
    js = json.loads(out.read_text())["transducers"]["r_leg"]
    fit_se = {n.split(".", 1)[1].replace(".h_", ".moment_").replace("offset.", "offset_").replace("mount.r", "mount_r")
              .replace("tilt.r", "tilt_r"): s for n, s in zip(fit.names, fit.se)}
    assert js["load_kind"] == "urdf_subtree" and set(js["se"]) == set(fit_se)
    for n, s in js["se"].items():
        assert (s is None) == np.isinf(fit_se[n]), n
        if s is not None:
            assert np.isfinite(s) and abs(s / fit_se[n] - 1) < 0.15, (n, s, fit_se[n])
    assert len(js["undetermined"]) == len(fit.undetermined) > 0
    assert abs(js["groups"]["load_mass"]["se"] / fit.load_report()["load_mass_se_kg"] - 1) < 0.15
    poses = [{j: float(res.frame[f"q_{j}"].iloc[i]) for j in joints} for i in _held(res)]
    arm = {"gravity_body": [0, 0, -1], "hold_s": 4.0, "holds": [{"q": q} for q in poses]}
    p = plan_from_robot(arm, tmp_path / "arm.toml", manifest.parent / "robot.toml").loads["r_leg"]
    assert np.isfinite(p.groups()["load_mass"][0]) and any("gravity_body" in n for n in p.notes)
    assert "tilt_rx" in p.bound.names and p.se()["tilt_rx"] is not None      # the joints above the sensor turn it
    still = {**arm, "holds": [{"q": {j: v for j, v in q.items() if j not in ("r_hip_yaw", "r_hip_roll")}} for q in poses]}
    p = plan_from_robot(still, tmp_path / "arm.toml", manifest.parent / "robot.toml").loads["r_leg"]
    assert "tilt_rx" not in p.bound.names and any("held at 0" in n for n in p.notes)   # the sensor never turns: held


@pytest.mark.parametrize("table, pattern", [
    ({}, r"no holds: add key 'holds'"),
    ({"orientations": [[1, 0, 0, 0]], "holds": [{}]}, r"keys \['holds', 'orientations'\] both give the holds"),
    ({"holds": [{"quat": [1, 0, 0, 0], "qq": 1}]}, r"holds\[0\]: unknown key\(s\) \['qq'\]"),
    ({"holds": [{"q": {}}]}, r"holds \[0\] have no 'quat'.*gravity_body = \[0, 0, -1\]"),
    ({"holds": [{"quat": [1, 0, 0, 0], "q": {"elbow": 0.1}}]}, r"names joints \['elbow'\].*no urdf"),
    ({"orientations": [[1, 0, 0, 0]], "transducer": "elbow"}, r"key 'transducer' = 'elbow': not a transducer.*\['wrist'\]"),
    ({"orientations": [[1, 0, 0, 0]], "kind": "urdf"}, r"key 'kind' = 'urdf'.*rigid_payload"),
    ({"orientations": [[1, 0, 0, 0]], "rotation_rpy": [0, 0, 1]}, r"unknown key\(s\) \['rotation_rpy'\] \(the nominal rotation is"),
    ({"orientations": [[1, 0, 0, 0]], "robot": "other.toml"}, r"key 'robot' = 'other.toml', but the command line gives"),
    ({"orientations": [[1, 0, 0, 0]], "gravity_body": [0, 0]}, r"key 'gravity_body' must be 3 numbers"),
])
def test_robot_protocol_errors_name_the_key(payload, table, pattern, tmp_path) -> None:
    with pytest.raises(ConfigError, match=pattern):
        plan_from_robot(table, tmp_path / "holds.toml", payload[2].parent / "robot.toml")


def _ar1(n: int, rho: float, sd: np.ndarray, rng) -> np.ndarray:
    """AR(1) noise (n, 6) of stationary sd ``sd`` per channel."""
    e = rng.standard_normal((n, 6)) * sd * np.sqrt(1 - rho**2)
    out = np.empty_like(e)
    out[0] = rng.standard_normal(6) * sd
    for i in range(1, n):
        out[i] = rho * out[i - 1] + e[i]
    return out


def test_pilot_with_serially_correlated_noise_carries_the_runs_widening(tmp_path) -> None:
    """A pilot whose noise is AR(1) (rho 0.9: a reading that stays through a hold): the run's se are widened
    (x~4); the plan's are within 25 % of them, and say so."""
    from ftcal_nlp.pipeline import calibrate
    from ftcal_nlp.core.settings import CalibrationSettings, DiagnoseSettings

    res = simulate_payload(PayloadConfig(seed=11, n_orientations=8, hold_s=6.0, move_s=3.0, noise_force_N=0.0,
                                         noise_torque_Nm=0.0))
    cols = [f"wrist_{c}" for c in WRENCH]
    res.frame[cols] = res.frame[cols].to_numpy() + _ar1(len(res.frame), 0.9, np.r_[np.full(3, 0.03), np.full(3, 0.001)],
                                                        np.random.default_rng(0))
    manifest = write_free_load(res, tmp_path / "ar")
    ds = read_dataset(manifest)
    run = calibrate(ds, CalibrationSettings(diagnose=DiagnoseSettings(enabled=False))).free_loads.legs["wrist"]
    plan = plan_from_dataset(ds).loads["wrist"]
    assert plan.widening is not None and plan.widening.min() > 2.0         # the widening matters here
    se = plan.se()
    for n, s in _fit_se(run).items():
        assert abs(se[n] / s - 1) < 0.25, (n, se[n], s)
    assert abs(plan.groups()["load_mass"][0] / run.load_report()["load_mass_se_kg"] - 1) < 0.25
    assert "se widened as the run widens them" in FreeLoadPlan("pilot", {"wrist": plan}).text()


def test_arm_without_the_tool_in_its_urdf_is_a_payload_through_the_joints(tmp_path, monkeypatch) -> None:
    """A URDF with no mass below the sensor link (most arms: the tool left out, DATA_FORMAT.md section 5): a rigid
    payload whose gravity comes through the joint angles; the same bound as a plain payload held at the sensor's
    orientations in W. (The reader refuses such a link today, issue 32: let it through here.)"""
    import re

    from ftcal_nlp.core import data
    from ftcal_nlp.sim.free.config import LEG4_URDF

    monkeypatch.setattr(data, "_transducer_link", lambda link, tree, where: link)
    urdf = LEG4_URDF.read_text()
    for link in ("r_thigh", "r_shank", "r_ankle", "r_foot"):   # the links below the sensor r_leg_ft: the tool left out
        urdf = re.sub(rf'(<link name="{link}">)\s*<inertial>.*?</inertial>', r"\1", urdf, flags=re.DOTALL)
    (tmp_path / "arm.urdf").write_text(urdf)
    (tmp_path / "arm.toml").write_text('name = "arm"\ng = 9.81\nlegs = ["wrist"]\nurdf = "arm.urdf"\n'
                                       '[transducers.wrist]\nlink = "r_leg_ft"\n')
    (tmp_path / "plain.toml").write_text('name = "plain"\ng = 9.81\nlegs = ["wrist"]\n[transducers.wrist]\n'
                                         'position_m = [0, 0, 0]\nrotation = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n')
    rng = np.random.default_rng(2)
    quat = rng.standard_normal((8, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    q = {"r_hip_yaw": rng.uniform(-0.5, 0.5, 8), "r_hip_roll": rng.uniform(-0.3, 0.3, 8)}
    load = {"mass_kg": 1.2, "com_m": [0.01, -0.02, 0.06], "hold_s": 2.0}
    holds = [{"quat": quat[i].tolist(), "q": {j: float(v[i]) for j, v in q.items()}} for i in range(8)]
    arm = plan_from_robot({**load, "holds": holds}, tmp_path / "h.toml", tmp_path / "arm.toml").loads["wrist"]
    assert arm.kind == "rigid_payload" and any("no link with mass below 'r_leg_ft'" in n for n in arm.notes)
    tree = data.read_robot(tmp_path / "arm.toml").tree
    from ftcal_nlp.core.geometry import quat_to_rotation

    R_W_ft = quat_to_rotation(quat) @ tree.pose(tree.root, "r_leg_ft", q, 8)[0]
    plain = plan_from_robot({**load, "orientations": rotation_to_quat(R_W_ft).tolist()}, tmp_path / "h.toml",
                            tmp_path / "plain.toml").loads["wrist"]
    a, b = arm.se(), plain.se()
    assert set(a) == set(b) and all(np.isfinite(v) for v in a.values())
    assert all(abs(a[n] / b[n] - 1) < 1e-6 for n in a), {n: a[n] / b[n] for n in a}


def test_protocol_naming_a_missing_robot(tmp_path) -> None:
    with pytest.raises(ConfigError, match=r"key 'robot' = 'nowhere.toml': .*nowhere.toml not found"):
        plan_from_robot({"robot": "nowhere.toml", "orientations": [[1, 0, 0, 0]]}, tmp_path / "holds.toml")


def test_pilot_of_a_fixed_base_urdf_load_bounds_the_recordings_tilt(tmp_path) -> None:
    """An arm-like pilot (a fixed level base: gravity_body = [0, 0, -1], no orientation columns; the joints above the
    sensor turn it) whose bodies differ from the URDF's (1.5x its masses): the run estimates the recording's tilt and weighs the
    mount by the fitted load, and the plan's se must be the run's for every parameter (the mount's included)."""
    import re

    import tomli_w

    res = simulate_urdf_leg(UrdfLegConfig(seed=4, n_orientations=6, poses_per_orientation=4, hold_s=3.0, move_s=2.0,
                                          max_tilt_deg=0.0))
    manifest = write_free_load(res, tmp_path / "arm")
    frame = res.frame.drop(columns=["qw", "qx", "qy", "qz"])
    entry = json.loads(json.dumps(res.manifest))
    entry["recording"][0]["gravity_body"] = [0, 0, -1]
    frame.to_csv(manifest.parent / entry["recording"][0]["file"], index=False)
    manifest.write_bytes(tomli_w.dumps(entry).encode())
    urdf = manifest.parent / res.robot["urdf"]    # nominal masses 1.5x the truth: a URDF is a prior, the data decide
    urdf.write_text(re.sub(r'<mass value="([0-9.eE+-]+)"', lambda m: f'<mass value="{1.5 * float(m.group(1))!r}"',
                           urdf.read_text()))
    ds = read_dataset(manifest)
    fit = fit_free_load(ds, "r_leg")
    assert fit.recording_tilts and fit.tilt is None                       # the recording's tilt is estimated
    plan = plan_from_dataset(ds).loads["r_leg"]
    se = plan.se()
    fit_se = dict(zip(fit.names, fit.se))
    for c in "xyz":
        assert abs(se[f"mount_r{c}"] / fit_se[f"r_leg.mount.r{c}"] - 1) < REL, c
    rec = next(iter(fit.recording_tilts))
    for c in "xy":
        assert abs(se[f"tilt_r{c}"] / fit_se[f"r_leg.{rec}.tilt.r{c}"] - 1) < REL, c
