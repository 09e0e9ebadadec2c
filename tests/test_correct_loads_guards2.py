"""``correct`` on free loads, second round of guards (issue 30, the blind tester's findings): the calibration's ``g``
and its transducers, the URDF it was made with, joint columns the URDF lacks, faulty channels, ``t`` in ms, and
readings whose forces or torques are in another frame or unit, found on the rows without contact. Each through the
CLI (exit 2, one ``error:`` line naming the column or key), for a rigid payload and a URDF leg alike; and the
clean later recordings (with contact pushes) pass with no false error. Fixtures: one fast simulated calibration per
load kind for the module (as ``test_correct_loads_guards.py``)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import correct
from ftcal_nlp.config import load_config
from ftcal_nlp.run import run

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
SIM = {"payload": 'kind = "payload"\nn_orientations = 8\nhold_s = 3.0\n',
       "urdf_leg": 'kind = "urdf_leg"\nn_orientations = 8\nposes_per_orientation = 3\nhold_s = 3.0\nmove_s = 2.0\n'}


@pytest.fixture(scope="module", params=sorted(SIM))
def case(request, tmp_path_factory) -> SimpleNamespace:
    """A calibration.json of the simulated load, its recording (a table) and the transducer's name."""
    tmp = tmp_path_factory.mktemp(request.param)
    (tmp / "c.toml").write_text(f'[simulate]\n{SIM[request.param]}dir = "data"\nseed = 7\n'
                                '[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    res = run(load_config(tmp / "c.toml"))
    leg = res.dataset.robot.legs[0]
    rec = pd.read_csv(res.dataset.recordings[0].path)
    return SimpleNamespace(kind=request.param, cal=tmp / "out" / "calibration.json", rec=rec, leg=leg, root=tmp)


def _correct(case, tmp_path, rec: pd.DataFrame | None = None, cal: Path | None = None, name: str = "rec.csv"):
    path = tmp_path / name
    (case.rec if rec is None else rec).to_csv(path, index=False, float_format="%.17g")
    out = tmp_path / "out.csv"
    return correct.main([str(cal or case.cal), str(path), "-o", str(out), "--force"]), out


def _cal_edit(case, tmp_path, edit) -> Path:
    d = json.loads(case.cal.read_text())
    edit(d)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(d))
    shutil.copy(case.cal.parent / "calibration_cov.npz", tmp_path / "calibration_cov.npz")
    return path


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("error: "), err[-3:]
    return err[-1]


def test_a_calibration_g_in_another_unit_is_named(case, tmp_path, capsys) -> None:
    rc, out = _correct(case, tmp_path, cal=_cal_edit(case, tmp_path, lambda d: d.update(g=98.1)))
    assert rc == 2 and not out.exists()
    assert "cal.json g: 98.1; expected gravity's magnitude in m/s^2, between 1 and 30" in _error(capsys)


def test_a_calibration_without_transducers_says_so(case, tmp_path, capsys) -> None:
    rc, _ = _correct(case, tmp_path, cal=_cal_edit(case, tmp_path, lambda d: d.update(legs={})))
    assert rc == 2 and "cal.json legs: an empty table: the calibration holds no transducer" in _error(capsys)


def test_a_joint_column_the_urdf_lacks_is_named(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    rec["q_foo"] = 0.1
    rc, out = _correct(case, tmp_path, rec, name="foo.csv")
    if case.kind == "payload":   # no URDF: no joint is read, the column is an extra one (a warning, as run)
        assert rc == 0
        return
    err = _error(capsys)
    assert rc == 2 and "foo.csv: column 'q_foo': the calibration's URDF has no joint 'foo' (joints: [" in err


def test_a_urdf_edited_after_the_calibration_is_refused(case, tmp_path, capsys) -> None:
    d = json.loads(case.cal.read_text())["legs"][case.leg]
    if case.kind == "payload":   # no URDF: rotation_nominal is the design rotation of robot.toml
        R, E = np.asarray(d["rotation_to_body"]), np.asarray(d["mount_rotation"])
        assert np.abs(np.asarray(d["rotation_nominal"]) @ E - R).max() < 1e-12
        return
    assert np.asarray(d["rotation_nominal"]).shape == (3, 3)
    urdf = Path(d["urdf"])
    text = urdf.read_text()
    joint = re.search(r'<joint name="([^"]+)" type="fixed">\s*<parent link="[^"]+"/>\s*<child link="' + d["link"] + r'"/>\s*'
                      r'<origin xyz="([^"]*)" rpy="([^"]*)"/>', text)
    assert joint, "the simulated URDF's sensor joint"
    rpy = [float(v) for v in joint.group(3).split()]
    edited = text.replace(joint.group(0), joint.group(0).replace(f'rpy="{joint.group(3)}"',
                                                                   f'rpy="{rpy[0]} {rpy[1]} {rpy[2] + 0.3}"'))
    (tmp_path / "edited.urdf").write_text(edited)
    cal = _cal_edit(case, tmp_path, lambda dd: dd["legs"][case.leg].update(urdf=str(tmp_path / "edited.urdf")))
    rc, _ = _correct(case, tmp_path, cal=cal)
    err = _error(capsys)
    assert rc == 2 and f"legs.{case.leg}.rotation_nominal: the URDF {tmp_path / 'edited.urdf'} puts sensor link" in err
    assert f"one of {joint.group(1)}" in err and "17.2 deg" in err
