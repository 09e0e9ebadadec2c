"""``correct`` with a free-load calibration checks a recording as a run checks its own and checks the calibration as
it reads it (issue 30 item 3): each bad input through the CLI gives exit 2 and one ``error:`` line naming the file
and the column or key, for a rigid payload and a URDF load alike; the guards new to the hexapod path (an output
naming an input) on the shared sample. Fixtures: one fast simulated calibration per load kind for the module."""

from __future__ import annotations

import json
import logging
import shutil
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import correct, export
from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.config import load_config
from ftcal_nlp.correct import contact_frame
from ftcal_nlp.correct.calibrated import payload_calibrations
from ftcal_nlp.core.errors import DataFormatError
from ftcal_nlp.core.geometry import quat_to_rotation, rotvec_to_rotation
from ftcal_nlp.run import run

from conftest import require_sample

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
QUAT = ["qw", "qx", "qy", "qz"]
SIM = {"payload": 'kind = "payload"\nn_orientations = 8\nhold_s = 3.0\n',
       "urdf_leg": 'kind = "urdf_leg"\nn_orientations = 8\nposes_per_orientation = 3\nhold_s = 3.0\nmove_s = 2.0\n'}


@pytest.fixture(scope="module", params=sorted(SIM))
def case(request, tmp_path_factory) -> SimpleNamespace:
    """A calibration.json of the simulated load, its recording (a table), the transducer's name and the key its
    mounting rotation is read from."""
    mount = "rotation_to_body" if request.param == "payload" else "mount_rotation"
    return simulated_case(request.param, tmp_path_factory.mktemp(request.param), seed=5, mount=mount)


def simulated_case(kind: str, tmp: Path, seed: int, **extra) -> SimpleNamespace:
    """``kind`` (a key of ``SIM``) simulated with ``seed`` into ``tmp/data`` and run into ``tmp/out`` (no diagnosis):
    its calibration.json, recording (a table), transducer name and folder, with ``extra``."""
    (tmp / "c.toml").write_text(f'[simulate]\n{SIM[kind]}dir = "data"\nseed = {seed}\n'
                                '[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    res = run(load_config(tmp / "c.toml"))
    return SimpleNamespace(kind=kind, cal=tmp / "out" / "calibration.json", rec=pd.read_csv(res.dataset.recordings[0].path),
                           leg=res.dataset.robot.legs[0], root=tmp, **extra)


def _correct(case, tmp_path, rec: pd.DataFrame | None = None, cal: Path | None = None, name: str = "rec.csv",
             extra: tuple[str, ...] = ()) -> tuple[int, Path]:
    path = tmp_path / name
    (case.rec if rec is None else rec).to_csv(path, index=False)
    out = tmp_path / "out.csv"
    return correct.main([str(cal or case.cal), str(path), "-o", str(out), "--force", *extra]), out


def cal_edited(case, tmp_path, edit) -> Path:
    """A copy of the case's calibration (and its covariance file) as ``tmp_path/cal.json`` with ``edit(dict)`` applied."""
    d = json.loads(case.cal.read_text())
    edit(d)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(d))
    shutil.copy(case.cal.parent / "calibration_cov.npz", tmp_path / "calibration_cov.npz")
    return path


def _cal_with(case, tmp_path, edit) -> Path:
    """:func:`cal_edited` with ``edit(leg entry)``."""
    return cal_edited(case, tmp_path, lambda d: edit(d["legs"][case.leg]))


def error_line(capsys) -> str:
    """The last line on stderr, asserted to be the CLI's one ``error:`` line."""
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("error: "), err[-3:]
    return err[-1]


_error = error_line


def test_the_recording_as_written_is_corrected(case, tmp_path) -> None:
    # the baseline: every check below passes on the recording itself (none fires on good data)
    rc, out = _correct(case, tmp_path)
    assert rc == 0 and len(pd.read_csv(out)) == len(case.rec)


def test_forces_in_kN_are_named(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    cols = [f"{case.leg}_{c}" for c in WRENCH[:3]]
    rec[cols] = rec[cols] / 1000
    rc, out = _correct(case, tmp_path, rec, name="kN.csv")
    err = _error(capsys)
    assert rc == 2 and not out.exists()
    assert f"kN.csv: columns {case.leg}_fx..{case.leg}_fz: median force" in err and "0.001x" in err and "kN" in err


def test_torques_in_Nmm_are_named(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    cols = [f"{case.leg}_{c}" for c in WRENCH[3:]]
    rec[cols] = rec[cols] * 1000
    rc, _ = _correct(case, tmp_path, rec, name="Nmm.csv")
    assert rc == 2 and f"Nmm.csv: columns {case.leg}_tx..{case.leg}_tz reach" in _error(capsys)


def test_quaternion_in_xyzw_order_is_named(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    rec[QUAT] = rec[["qx", "qy", "qz", "qw"]].to_numpy()
    rc, _ = _correct(case, tmp_path, rec, name="xyzw.csv")
    err = _error(capsys)
    assert rc == 2 and "xyzw.csv: columns qw, qx, qy, qz: the load's weight from them is a median" in err
    assert "if the quaternion columns hold x, y, z, w (not w, x, y, z)" in err


def test_non_unit_quaternions_are_refused_as_run_refuses_them(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    rec[QUAT] = rec[QUAT] * 1.05
    rc, _ = _correct(case, tmp_path, rec, name="norm.csv")
    assert rc == 2 and "norm.csv: columns qw, qx, qy, qz are not unit quaternions (norms 1.05..1.05)" in _error(capsys)


def test_gravity_pointing_up_is_named(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    g = -quat_to_rotation(rec[QUAT].to_numpy())[:, 2, :]          # R_WB^T (0, 0, -1): gx..gz point down
    rec = rec.drop(columns=QUAT)
    rec[["gx", "gy", "gz"]] = g
    assert _correct(case, tmp_path, rec, name="down.csv")[0] == 0
    rec[["gx", "gy", "gz"]] = -g
    rc, _ = _correct(case, tmp_path, rec, name="up.csv")
    err = _error(capsys)
    assert rc == 2 and "up.csv: columns gx, gy, gz: the load's weight from them is a median 180 deg" in err
    assert "point up" in err


def test_an_empty_recording_is_an_error(case, tmp_path, capsys) -> None:
    rc, out = _correct(case, tmp_path, case.rec.iloc[:0], name="empty.csv")
    assert rc == 2 and not out.exists()
    assert "empty.csv: no rows (only the header); expected a recording to correct" in _error(capsys)


def test_a_repeated_time_is_named_with_its_line(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    rec.loc[5, "t"] = rec.loc[4, "t"]
    rc, _ = _correct(case, tmp_path, rec, name="dup.csv")
    assert rc == 2 and "dup.csv: column 't' is not strictly increasing (line 7:" in _error(capsys)


def test_time_order_is_checked_before_any_effect_correction(case) -> None:
    """A calibration with effects that follow the clock (calibration_with_effect.json): a repeated t or a clock in
    ms is named before the effects' re-sampling sees it (scipy's "x must be strictly increasing" before)."""
    cals = payload_calibrations(case.cal)
    fake = SimpleNamespace(members=(SimpleNamespace(name="clock_offset"),))
    cals = {k: replace(p, effects=fake) for k, p in cals.items()}
    rec = case.rec.copy()
    rec.loc[5, "t"] = rec.loc[4, "t"]
    with pytest.raises(DataFormatError, match=r"rec.csv: column 't' is not strictly increasing") as exc:
        contact_frame(cals, rec, "rec.csv")
    assert exc.value.column == "t"
    ms = case.rec.copy()
    ms["t"] = ms["t"] * 1000
    with pytest.raises(DataFormatError, match=r"ms.csv: column t: median sampling interval .*clock_offset.*milliseconds"):
        contact_frame(cals, ms, "ms.csv")


def test_rows_with_nan_readings_are_dropped_and_counted(case, tmp_path, caplog) -> None:
    rec = case.rec.copy()
    rec.loc[10:19, f"{case.leg}_fy"] = np.nan
    with caplog.at_level(logging.WARNING):
        rc, out = _correct(case, tmp_path, rec, name="gaps.csv")
    assert rc == 0 and len(pd.read_csv(out)) == len(rec) - 10
    assert f"gaps.csv: dropped 10 of {len(rec)} rows with NaN or infinite readings" in caplog.text


def test_a_column_without_any_number_is_an_error(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    rec[f"{case.leg}_fx"] = np.nan
    rc, _ = _correct(case, tmp_path, rec, name="nan.csv")
    assert rc == 2 and f"nan.csv: column(s) ['{case.leg}_fx'] hold no finite value" in _error(capsys)


def test_the_transducers_of_the_recording_and_the_calibration_must_match(case, tmp_path, capsys) -> None:
    rec = case.rec.copy()
    for c in WRENCH:
        rec[f"spare_{c}"] = rec[f"{case.leg}_{c}"]
    rc, _ = _correct(case, tmp_path, rec, name="two.csv")
    err = _error(capsys)
    assert rc == 2 and f"two.csv: columns spare_fx..spare_tz of transducer(s) ['spare'] but the calibration covers only ['{case.leg}']" in err
    rc, _ = _correct(case, tmp_path, case.rec.drop(columns=[f"{case.leg}_tz"]), name="short.csv")
    assert rc == 2 and f"short.csv: missing column(s) ['{case.leg}_tz'] of the calibrated transducer(s)" in _error(capsys)


def test_a_nan_offset_in_the_calibration_is_named(case, tmp_path, capsys) -> None:
    cal = _cal_with(case, tmp_path, lambda l: l["offset"].__setitem__(2, None))
    rc, out = _correct(case, tmp_path, cal=cal)
    assert rc == 2 and not out.exists()
    assert f"cal.json legs.{case.leg}.offset: holds a null, NaN or infinite value" in _error(capsys)


def test_a_mounting_rotation_that_is_no_rotation_is_named(case, tmp_path, capsys) -> None:
    cal = _cal_with(case, tmp_path, lambda l: l.__setitem__(case.mount, (2 ** (1 / 3) * np.asarray(l[case.mount])).tolist()))
    rc, _ = _correct(case, tmp_path, cal=cal)
    err = _error(capsys)
    assert rc == 2 and f"cal.json legs.{case.leg}.{case.mount}: determinant 2," in err and "proper rotation" in err
    # export reads the calibration with the same reader
    assert export.main([str(cal), "-o", str(tmp_path / "c")]) == 2
    assert f"cal.json legs.{case.leg}.{case.mount}: determinant 2," in _error(capsys)


def test_the_copies_of_the_mounting_rotation_must_agree(case, tmp_path, capsys) -> None:
    """Each stored copy edited alone (a URDF load stores no rotation_to_body: its ft -> B moves with the joints)."""
    stored = [k for k in ("mount_rotvec", "mount_rotation", "rotation_to_body") if k in json.loads(case.cal.read_text())["legs"][case.leg]]
    assert stored == (["mount_rotvec", "mount_rotation", "rotation_to_body"] if case.kind == "payload" else ["mount_rotvec", "mount_rotation"])
    turn = rotvec_to_rotation(np.array([0.0, 0.0, 0.01]))          # 0.6 deg: far beyond the copies' rounding
    for edited in stored:
        def edit(l):
            l[edited] = (np.asarray(l[edited]) + [0.0, 0.0, 0.01]).tolist() if edited == "mount_rotvec" else \
                (np.asarray(l[edited]) @ turn).tolist()
        rc, _ = _correct(case, tmp_path, cal=_cal_with(case, tmp_path, edit))
        err = _error(capsys)
        assert rc == 2 and f"cal.json legs.{case.leg}." in err and "disagree by 0.01" in err, (edited, err)
        assert f"the mounting rotation is read from legs.{case.leg}.{case.mount}" in err


def test_a_load_mass_that_is_not_positive_is_named(case, tmp_path, capsys) -> None:
    rc, _ = _correct(case, tmp_path, cal=_cal_with(case, tmp_path, lambda l: l.__setitem__("load_mass_kg", -1.0)))
    assert rc == 2 and f"cal.json legs.{case.leg}.load_mass_kg: -1.0; expected the load's mass, a positive number" in _error(capsys)


@pytest.mark.parametrize("target", ["recording", "calibration"])
def test_the_output_is_never_an_input(case, tmp_path, capsys, target) -> None:
    cal = _cal_with(case, tmp_path, lambda l: None)
    rec = tmp_path / "rec.csv"
    case.rec.to_csv(rec, index=False)
    out = rec if target == "recording" else cal
    before = out.read_bytes()
    assert correct.main([str(cal), str(rec), "-o", str(out), "--force"]) == 2
    assert f"the output would overwrite the {target}" in _error(capsys) and out.read_bytes() == before


# ----------------------------------------------------------------------------- the hexapod: the same reader, the same refusal

@pytest.fixture(scope="module")
def hexapod(tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("hexapod")
    cal = tmp / "calibration.json"
    Calibration.load(require_sample() / "truth.json", g=9.81, mass_kg=8.18).save(cal)
    rec = tmp / "walk.csv"
    pd.read_csv(require_sample() / "walk.csv").iloc[:2000].to_csv(rec, index=False)
    return cal, rec


@pytest.mark.parametrize("target", ["recording", "calibration"])
def test_the_hexapod_output_is_never_an_input(hexapod, capsys, target) -> None:
    cal, rec = hexapod
    out = rec if target == "recording" else cal
    before = out.read_bytes()
    assert correct.main([str(cal), str(rec), "-o", str(out), "--force"]) == 2
    assert f"the output would overwrite the {target}" in _error(capsys) and out.read_bytes() == before


def test_the_hexapod_calibration_is_checked_when_read(hexapod, tmp_path, capsys) -> None:
    cal, rec = hexapod
    d = json.loads(cal.read_text())
    d["legs"]["FL"]["rotation_to_body"] = (2 ** (1 / 3) * np.asarray(d["legs"]["FL"]["rotation_to_body"])).tolist()
    bad = tmp_path / "cal.json"
    bad.write_text(json.dumps(d))
    assert correct.main([str(bad), str(rec), "-o", str(tmp_path / "o.csv")]) == 2
    assert "cal.json legs.FL.rotation_to_body: determinant 2," in _error(capsys)
    assert export.main([str(bad), "-o", str(tmp_path / "c")]) == 2
    assert "cal.json legs.FL.rotation_to_body: determinant 2," in _error(capsys)


def test_a_calibration_mixing_free_loads_and_legs_is_named(case, hexapod, tmp_path, capsys) -> None:
    d = json.loads(hexapod[0].read_text())
    d["legs"]["wrist"] = json.loads(case.cal.read_text())["legs"][case.leg]
    bad = tmp_path / "mixed.json"
    bad.write_text(json.dumps(d))
    assert correct.main([str(bad), str(hexapod[1]), "-o", str(tmp_path / "o.csv")]) == 2
    assert "mixed.json legs.FL.load_kind: missing, where ['wrist'] name theirs" in _error(capsys)
