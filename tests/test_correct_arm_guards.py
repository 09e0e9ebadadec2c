"""``correct`` on an arm (a payload oriented by the joints, joints only, the calibration's ``gravity_body``), the
guards of issue 30's second round: a continuous joint's column in degrees (no URDF limit to exceed) named by the
fix that brings the forces to the calibration's prediction, torques mis-signed, ``t`` in ms, a URDF edited since
the calibration, a joint column the URDF lacks; the held-out session passes every check at the noise. The arm is
``tests/test_arm.py``'s simulated 4R arm with its last joint made continuous."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import correct

from test_arm import NOISE, URDF, write_arm

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
J4 = '<joint name="j4" type="revolute"><parent link="l3"/><child link="l4"/><origin xyz="0.3 0 0"/><axis xyz="1 0 0"/><limit lower="-3.1" upper="3.1" effort="1" velocity="1"/></joint>'
URDF_CONT = URDF.replace(J4, J4.replace('type="revolute"', 'type="continuous"').replace(
    '<limit lower="-3.1" upper="3.1" effort="1" velocity="1"/>', ""))


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    assert URDF_CONT != URDF and 'name="j4" type="continuous"' in URDF_CONT
    return write_arm(tmp_path_factory.mktemp("arm4c"), URDF_CONT)


def _correct(arm, tmp_path, df: pd.DataFrame, name: str, cal=None) -> tuple[int, str]:
    path = tmp_path / name
    df.to_csv(path, index=False, float_format="%.17g")
    rc = correct.main([str(cal or arm / "out" / "calibration.json"), str(path), "-o", str(tmp_path / "o.csv"), "--force"])
    return rc, str(path)


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("error: "), err[-3:]
    return err[-1]


def test_the_held_out_session_passes_every_check_at_the_noise(arm, tmp_path, caplog) -> None:
    with caplog.at_level("WARNING"):
        rc, _ = _correct(arm, tmp_path, pd.read_csv(arm / "later.csv"), "later.csv")
    assert rc == 0 and "WARNING" not in caplog.text
    got = pd.read_csv(tmp_path / "o.csv")
    rms = np.sqrt((got[[f"wrist_{c}" for c in WRENCH]].to_numpy() ** 2).mean(axis=0))
    assert np.all(np.abs(rms / NOISE - 1) < 0.1), rms / NOISE


def test_a_continuous_joint_in_degrees_is_named(arm, tmp_path, capsys) -> None:
    df = pd.read_csv(arm / "later.csv")
    df["q_j4"] = np.degrees(df["q_j4"])
    # continuous: no URDF limit to exceed, and under the bound of turns: only the forces can tell
    rc, path = _correct(arm, tmp_path, df, "deg.csv")
    err = _error(capsys)
    assert rc == 2 and f"{path}: column q_j4: " in err and "if it holds degrees (continuous joint" in err
    assert "expected joint angles in radians" in err


def test_a_limited_joint_in_degrees_is_named_by_its_limits(arm, tmp_path, capsys) -> None:
    df = pd.read_csv(arm / "later.csv")
    df["q_j2"] = np.degrees(df["q_j2"])
    rc, _ = _correct(arm, tmp_path, df, "deg2.csv")
    assert rc == 2 and "column 'q_j2' reaches" in _error(capsys)


@pytest.mark.parametrize("fault", ["negty", "ms", "foo"])
def test_torques_clock_and_joint_columns(arm, tmp_path, capsys, fault) -> None:
    df = pd.read_csv(arm / "later.csv")
    if fault == "negty":
        df["wrist_ty"] = -df["wrist_ty"]
    elif fault == "ms":
        df["t"] = (df["t"] - df["t"].iloc[0]) * 1000
    else:
        df["q_foo"] = 0.0
    rc, path = _correct(arm, tmp_path, df, f"{fault}.csv")
    err = _error(capsys)
    assert rc == 2
    assert {"negty": "if a reflected (left-handed) frame: ty negated", "ms": "is t in milliseconds?",
            "foo": "column 'q_foo': the calibration's URDF has no joint 'foo'"}[fault] in err


def test_a_urdf_edited_since_the_calibration_is_refused(arm, tmp_path, capsys) -> None:
    cal = json.loads((arm / "out" / "calibration.json").read_text())
    edited = URDF_CONT.replace('<origin xyz="0.05 0 0" rpy="0.1 1.4 1.2"/>', '<origin xyz="0.05 0 0" rpy="0.1 1.4 1.25"/>')
    assert edited != URDF_CONT
    (tmp_path / "arm4.urdf").write_text(edited)
    cal["legs"]["wrist"]["urdf"] = str(tmp_path / "arm4.urdf")
    (tmp_path / "calibration.json").write_text(json.dumps(cal))
    rc, _ = _correct(arm, tmp_path, pd.read_csv(arm / "later.csv"), "later.csv", cal=tmp_path / "calibration.json")
    err = _error(capsys)
    assert rc == 2 and "legs.wrist.rotation_nominal: the URDF" in err and "one of ft_joint, j4, j3, j2, j1" in err
