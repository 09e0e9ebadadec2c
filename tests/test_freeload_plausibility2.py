"""Plausibility of free loads, second round (issue 30, the blind tester's findings): a left-handed force frame, torque
signs and units, a payload's lever arm, negative link-group masses, ``t`` in milliseconds on holds, dead or stuck
channels, a weighed mass in grams, ``gx..gz`` against ``qw..qz``. Each convention error is named; clean data of every
kind, with every simulator effect on free loads, the shared samples and a genuine list of poses pass."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.data import read_dataset, read_robot, write_robot
from ftcal_nlp.effects import EFFECTS, applies_to
from ftcal_nlp.core.errors import DataFormatError, ImplausibleLoadFit
from ftcal_nlp.estimate.freeload.plausibility import (
    check_pose_list_clock,
    describe_columns,
    gravity_fit,
    lever_arm_problem,
    load_arrays,
    load_fit,
    negative_groups,
    signed_permutation_near,
)
from ftcal_nlp.core.geometry import quat_to_rotation
from ftcal_nlp.loads import RigidPayload
from ftcal_nlp.pipeline import _free_load_samples, calibrate
from ftcal_nlp.core.settings import CalibrationSettings, DiagnoseSettings
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_free, write_free_load

SHARED = Path("/work/shared")
SETTINGS = CalibrationSettings(diagnose=DiagnoseSettings(enabled=False))
F = ["wrist_fx", "wrist_fy", "wrist_fz"]
T = ["wrist_tx", "wrist_ty", "wrist_tz"]
PAYLOAD = dict(n_orientations=6, hold_s=3.0, move_s=1.5)
LEG = dict(n_orientations=5, poses_per_orientation=2, hold_s=3.0, move_s=2.0)


@pytest.fixture(scope="module")
def payload():
    return simulate_free(PayloadConfig(seed=8, **PAYLOAD))


@pytest.fixture(scope="module")
def leg():
    return simulate_free(UrdfLegConfig(seed=5, **LEG))


def _write(res, folder: Path, frame: pd.DataFrame | None = None) -> Path:
    return write_free_load(res if frame is None else replace(res, frame=frame), folder)


def _calibrate(manifest: Path):
    return calibrate(read_dataset(manifest), SETTINGS)


def _prefit(manifest: Path) -> dict:
    """The checks before the fit (sensor faults aside) on a dataset, and its per-transducer samples."""
    return _free_load_samples(read_dataset(manifest), SETTINGS)


def _linear_problems(samples: dict, g: float = 9.81) -> list[str]:
    """The lever-arm and link-group problems of the linear fit at the weight's mount (the checks after the fit add)."""
    out = []
    for leg_, (recs, noise, load) in samples.items():
        w, b, K = load_arrays(recs, leg_, load, g)
        lf = load_fit(w, b, K, load.mass_row, gravity_fit(w[:, :3], b).rotation, noise)
        out += negative_groups(load, lf.theta, lf.se) + [p for p in [lever_arm_problem(load, lf.theta, lf.se, leg_)] if p]
    return out


# ----------------------------------------------------------------------------- clean data of every kind passes


FREE_EFFECTS = [n for n in EFFECTS if "free" in applies_to(n)]


@pytest.mark.parametrize("effect", FREE_EFFECTS)
@pytest.mark.parametrize("kind", ["payload", "leg"])
def test_clean_data_with_each_simulator_effect_pass_the_checks(kind, effect, tmp_path) -> None:
    cfg = PayloadConfig(seed=3, effects=(effect,), **PAYLOAD) if kind == "payload" else UrdfLegConfig(seed=3, effects=(effect,), **LEG)
    if effect == "joint_limit_contact" and kind == "payload":
        with pytest.raises(ValueError, match="no moving joint"):    # a rigid payload has no end stop to touch
            simulate_free(cfg)
        return
    samples = _prefit(_write(simulate_free(cfg), tmp_path / "d"))
    assert _linear_problems(samples) == []


@pytest.mark.parametrize("sample", ["sample_payload", "sample_urdf", "sample_arm"])
def test_the_shared_samples_pass_the_checks(sample) -> None:
    manifest = SHARED / sample / "dataset.toml"
    if not manifest.is_file():
        pytest.skip("shared samples absent")
    ds = read_dataset(manifest)
    assert _linear_problems(_free_load_samples(ds, SETTINGS), ds.robot.g) == []


# ----------------------------------------------------------------------------- a left-handed force frame


def test_signed_permutations_are_named() -> None:
    P, off = signed_permutation_near(np.diag([1.0, 1.0, -1.0]) @ np.eye(3), det=-1.0)
    assert np.allclose(P, np.diag([1, 1, -1])) and off < 1e-9
    assert describe_columns(P, "w") == "w_fz negated"
    assert describe_columns(np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, 1]]), "w") == "w_fx and w_fy swapped"
    assert describe_columns(np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]]), "w", "t") == "w_tx holds tz, w_ty holds tx, w_tz holds ty"


@pytest.mark.parametrize("how, expect", [("negate_fz", r"wrist_fz negated\?"), ("swap", r"wrist_fx and wrist_fy swapped\?")])
def test_a_left_handed_force_frame_is_named_not_the_gravity(payload, tmp_path, how, expect) -> None:
    df = payload.frame.copy()
    if how == "negate_fz":
        df["wrist_fz"] *= -1
    else:
        df[["wrist_fx", "wrist_fy"]] = df[["wrist_fy", "wrist_fx"]].to_numpy()
    with pytest.raises(DataFormatError, match=r"columns wrist_fx\.\.wrist_fz form a left-handed frame: .*determinant -1.*" + expect) as ei:
        _prefit(_write(payload, tmp_path / "d", df))
    assert "qw..qz must map" not in str(ei.value) and "gravity_body" not in str(ei.value)


def _two(payload, folder: Path, frame: pd.DataFrame) -> Path:
    """A dataset of two transducers on one orientation stream: wrist and w2 (w2 reads ``frame``'s w2 columns)."""
    d = _write(payload, folder, frame).parent
    robot = read_robot(d / "robot.toml")
    write_robot(replace(robot, legs=("wrist", "w2"), transducers={**robot.transducers, "w2": robot.transducers["wrist"]}),
                d / "robot.toml")
    return d / "dataset.toml"


@pytest.mark.parametrize("how", ["negate_fz", "negate_forces"])
def test_a_sibling_on_the_same_stream_clears_the_stream(payload, tmp_path, how) -> None:
    df = payload.frame.copy()
    for c in "xyz":
        df[f"w2_f{c}"], df[f"w2_t{c}"] = df[f"wrist_f{c}"], df[f"wrist_t{c}"]
    _prefit(_two(payload, tmp_path / "ok", df))          # two good transducers: no error
    if how == "negate_fz":
        df["w2_fz"] *= -1
        expect = r"transducer w2: columns w2_fx\.\.w2_fz form a left-handed frame.*w2_fz negated\?"
    else:
        df[["w2_fx", "w2_fy", "w2_fz"]] *= -1
        expect = r"transducer w2: .*follow gravity reversed.*transducer\(s\) wrist on the same recordings follow gravity as given.*readings of w2 negated"
    with pytest.raises(DataFormatError, match=expect) as ei:
        _prefit(_two(payload, tmp_path / "bad", df))
    assert "qw..qz must map" not in str(ei.value)


# ----------------------------------------------------------------------------- torques: signs, units, lever arm


@pytest.mark.parametrize("cols, expect", [(["r_leg_tx", "r_leg_ty", "r_leg_tz"], r"are the torque readings negated"),
                                          (["r_leg_ty"], r"\(r_leg_ty negated\)\?")])
def test_negated_torques_of_a_urdf_load_are_named(leg, tmp_path, cols, expect) -> None:
    df = leg.frame.copy()
    df[cols] *= -1
    with pytest.raises(DataFormatError, match=r"columns r_leg_tx\.\.r_leg_tz: the URDF's nominal inertials .*" + expect):
        _prefit(_write(leg, tmp_path / "d", df))


def test_a_negated_torque_column_of_a_payload_is_named_after_the_fit(payload, tmp_path) -> None:
    """A rigid payload has no URDF inertials: the fit is implausible and the torque signs' refit names the column."""
    df = payload.frame.copy()
    df["wrist_ty"] *= -1
    with pytest.raises(ImplausibleLoadFit, match=r"torque signs.*with wrist_ty negated \(torque columns in another order or "
                                                 r"sign\) the torques are explained") as ei:
        _calibrate(_write(payload, tmp_path / "d", df))
    assert "torque signs" in ei.value.causes and "none of the usual conventions" not in str(ei.value)


def test_negative_link_group_masses_are_named() -> None:
    class TwoGroups:
        param_names = ("upper.mass_kg", "upper.h_x", "lower.mass_kg", "lower.h_x")

    theta, se = np.array([4.4, 0.1, -0.7, 0.0]), np.array([0.01, 0.01, 0.02, 0.01])
    (msg,) = negative_groups(TwoGroups(), theta, se)
    assert "link group 'lower'" in msg and "-0.7" in msg
    assert negative_groups(TwoGroups(), theta, np.array([0.01, 0.01, np.inf, 0.01])) == []   # undetermined: no bound
    assert negative_groups(TwoGroups(), theta, np.array([0.01, 0.01, 0.5, 0.01])) == []      # within 3 se of 0


def test_the_lever_arm_rule_names_the_units() -> None:
    load, se = RigidPayload(), np.full(4, 1e-3)
    assert lever_arm_problem(load, np.array([1.5, 0.0, 0.0, 0.12]), se, "w") is None               # CoM 8 cm
    assert re.search(r"8e-05 m .*forces w_fx\.\.w_fz in mN \(a load mass of 1\.5 kg", lever_arm_problem(
        load, np.array([1500.0, 0.0, 0.0, 0.12]), se, "w"))
    assert "torques w_tx..w_tz in N*mm" in lever_arm_problem(load, np.array([1.5, 0.0, 0.0, 120.0]), se, "w")
    assert lever_arm_problem(load, np.array([1.5, 0.0, 0.0, 0.0]), np.r_[1e-3, np.inf, 1e-3, 1e-3], "w") is None


def test_payload_forces_in_mN_are_named(payload, tmp_path) -> None:
    df = payload.frame.copy()
    df[F] *= 1000.0
    with pytest.raises(ImplausibleLoadFit, match=r"centre of mass .* from the transducer .*expected 0\.002 to 3 m.*"
                                                 r"forces wrist_fx\.\.wrist_fz in mN"):
        _calibrate(_write(payload, tmp_path / "d", df))


def test_torques_in_kNm_are_named_after_a_failed_fit(payload, tmp_path, monkeypatch) -> None:
    from ftcal_nlp.estimate import freeload
    from ftcal_nlp.core.errors import SolverError

    def lost(*_a, **_k):
        raise SolverError("IPOPT did not converge", status="Search_Direction_Becomes_Too_Small")

    df = payload.frame.copy()
    df[T] /= 1000.0
    monkeypatch.setattr(freeload, "fit_free_loads", lost)
    with pytest.raises(ImplausibleLoadFit, match=r"IPOPT did not converge.*wrist_tx\.\.wrist_tz read as kN\*m the load is "
                                                 r"plausible.*are the torques in kN\*m\?") as ei:
        _calibrate(_write(payload, tmp_path / "d", df))
    assert "torque units" in ei.value.causes


# ----------------------------------------------------------------------------- the clock of a list of poses


def _pose_list(res) -> pd.DataFrame:
    """One row per hold (the hold's median): a list of poses as a bench logs it, 9 s apart."""
    held = np.asarray(res.held, bool)
    rows = res.frame[held].groupby(np.asarray(res.hold_index)[held]).median().reset_index(drop=True)
    rows["t"] = 9.0 * np.arange(len(rows))
    return rows


def test_t_in_milliseconds_on_holds_is_refused_a_list_of_poses_passes(payload, tmp_path) -> None:
    df = payload.frame.copy()
    df["t"] = 1000.0 * (df["t"] - df["t"].iloc[0])
    with pytest.raises(DataFormatError, match=r"column t: median interval 10; \d+ % of consecutive rows hold the same pose.*"
                                              r"is t in milliseconds\?"):
        _prefit(_write(payload, tmp_path / "ms", df))
    poses = _pose_list(payload)
    assert len(poses) >= 6
    run = _calibrate(_write(payload, tmp_path / "poses", poses))   # each row a pose: no refusal, a plausible fit
    r = run.free_loads.legs["wrist"]
    assert abs(float(r.theta[0]) - float(payload.truth["mass_kg"])) < 0.05 * float(payload.truth["mass_kg"])
    rec = read_dataset(_write(payload, tmp_path / "poses_ms", poses.assign(t=1000.0 * poses["t"]))).hanging[0]
    check_pose_list_clock(rec)      # 9000 apart, every row another pose: a list of poses still


# ----------------------------------------------------------------------------- sensors, weighed mass, gravity columns


def test_dead_and_stuck_channels_of_a_free_load_are_named(payload, tmp_path) -> None:
    df = payload.frame.copy()
    df["wrist_fx"] = 0.0
    with pytest.raises(DataFormatError, match=r"transducer wrist columns wrist_fx stuck at 0 on \d+ of \d+ samples"):
        _calibrate(_write(payload, tmp_path / "dead", df))
    df = payload.frame.copy()
    df.loc[100:400, "wrist_fy"] = df["wrist_fy"].iloc[100]
    run = _calibrate(_write(payload, tmp_path / "stuck", df))
    notes = [n for n in run.notes if n.startswith("sensor fault")]
    assert len(notes) == 1 and "transducer wrist columns wrist_fy stuck at" in notes[0] and "left out" in notes[0]


def test_a_weighed_mass_in_grams_names_the_key(payload, tmp_path) -> None:
    d = _write(payload, tmp_path / "d").parent
    robot = read_robot(d / "robot.toml")
    m = float(payload.truth["mass_kg"])
    write_robot(replace(robot, transducers={"wrist": replace(robot.transducers["wrist"], load_mass_kg=1000 * m)}), d / "robot.toml")
    with pytest.raises(DataFormatError, match=r"\[transducers\.wrist\] load_mass_kg = \d+(\.\d+)? is \d+x the mass the forces "
                                              r".*is load_mass_kg in grams") as ei:
        _calibrate(d / "dataset.toml")
    assert "are the readings in" not in str(ei.value)      # the readings' noise is a transducer's in N: the key is named


def test_gravity_columns_that_disagree_with_the_quaternion_are_refused(payload, tmp_path) -> None:
    df = payload.frame.copy()
    g = -quat_to_rotation(df[["qw", "qx", "qy", "qz"]].to_numpy())[:, 2, :]
    df["gx"], df["gy"], df["gz"] = g.T
    _prefit(_write(payload, tmp_path / "same", df))                # both, of one orientation: fine
    df["gx"], df["gy"], df["gz"] = 0.0, 0.0, -1.0
    with pytest.raises(DataFormatError, match=r"columns gx, gy, gz and qw, qx, qy, qz disagree.*expected one direction within"):
        _prefit(_write(payload, tmp_path / "differ", df))
