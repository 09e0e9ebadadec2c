"""Interchange-format I/O: the sample loads, round trips, and every bad-input case gets a clear error."""

import logging
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.data import DataFormatError, hanging_pairs, read_dataset, read_robot, write_dataset

from conftest import SAMPLE, require_sample


@pytest.fixture(scope="module")
def sample():
    return read_dataset(require_sample() / "dataset.toml")


@pytest.fixture()
def small(tmp_path):
    """A copy of the sample cut to 300 rows per recording, all CSV."""
    import tomllib

    man = tomllib.loads((require_sample() / "dataset.toml").read_text())
    shutil.copy(SAMPLE / "robot.toml", tmp_path / "robot.toml")
    lines = ['robot = "robot.toml"']
    for e in man["recording"]:
        src = SAMPLE / e["file"]
        df = pd.read_parquet(src) if src.suffix == ".parquet" else pd.read_csv(src)
        name = Path(e["file"]).stem + ".csv"
        df.iloc[:300].to_csv(tmp_path / name, index=False)
        lines += ["", "[[recording]]", f'file = "{name}"', f'kind = "{e["kind"]}"']
        if "gravity_body" in e:
            lines.append(f"gravity_body = {e['gravity_body']}")
    (tmp_path / "dataset.toml").write_text("\n".join(lines) + "\n")
    return tmp_path


def test_sample_loads_with_types(sample):
    assert sample.robot.legs == ("FL", "ML", "HL", "FR", "MR", "HR")
    assert sample.robot.mass_kg == 8.18
    kinds = [r.kind for r in sample.recordings]
    assert kinds.count("hanging") == 4 and kinds.count("standing") == 1 and kinds.count("walking") == 1
    h = sample.hanging[0]
    assert h.wrench["FL"].shape == (h.n, 6) and h.phi["FL"].shape == (h.n,)
    assert h.quat is None and np.allclose(h.gravity_body, [1, 0, 0])
    st = sample.standing[0]
    assert st.quat.shape == (st.n, 4)
    # the standing recording has lost-mocap rows: kept as NaN orientation, not dropped
    assert np.isnan(st.quat).any() and st.n_dropped == 0
    assert len(hanging_pairs(sample.hanging)) == 2
    # one session clock: recordings taken later have larger t
    starts = [r.t[0] for r in sample.recordings]
    assert starts == sorted(starts)


def test_round_trip(small, tmp_path):
    ds = read_dataset(small / "dataset.toml")
    out = tmp_path / "copy"
    for fmt in ("csv", "parquet"):
        manifest = write_dataset(ds, out / fmt, fmt=fmt)
        back = read_dataset(manifest)
        for a, b in zip(ds.recordings, back.recordings):
            assert a.kind == b.kind and a.name == b.name
            np.testing.assert_allclose(a.t, b.t, rtol=1e-9)
            for k in ds.robot.legs:
                np.testing.assert_allclose(a.wrench[k], b.wrench[k], rtol=1e-8, atol=1e-12)
                np.testing.assert_allclose(a.phi[k], b.phi[k], rtol=1e-8, atol=1e-12)
        with pytest.raises(FileExistsError):
            write_dataset(ds, out / fmt, fmt=fmt)


def test_missing_file(small):
    (small / "walk.csv").unlink()
    with pytest.raises(DataFormatError, match=r"walk\.csv.*not found"):
        read_dataset(small / "dataset.toml")


def test_missing_manifest(tmp_path):
    with pytest.raises(DataFormatError, match=r"dataset\.toml.*not found"):
        read_dataset(tmp_path / "dataset.toml")


def test_missing_column(small):
    df = pd.read_csv(small / "hang_xpos.csv").drop(columns=["ML_ty"])
    df.to_csv(small / "hang_xpos.csv", index=False)
    with pytest.raises(DataFormatError, match=r"hang_xpos\.csv.*ML_ty"):
        read_dataset(small / "dataset.toml")


def test_non_increasing_t(small):
    df = pd.read_csv(small / "hang_zneg.csv")
    df.loc[10, "t"] = df.loc[9, "t"]
    df.to_csv(small / "hang_zneg.csv", index=False)
    with pytest.raises(DataFormatError, match=r"hang_zneg\.csv.*'t' is not strictly increasing"):
        read_dataset(small / "dataset.toml")


def test_non_rotation_matrix(small):
    text = (small / "robot.toml").read_text()
    text = text.replace("[transducers.ML]\nposition_m = [0.0, 0.15, 0.0]\nrotation = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
                        "[transducers.ML]\nposition_m = [0.0, 0.15, 0.0]\nrotation = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]")
    (small / "robot.toml").write_text(text)
    with pytest.raises(DataFormatError, match=r"transducers\.ML.*rotation.*proper rotation"):
        read_robot(small / "robot.toml")


def test_hanging_without_opposite(small):
    text = (small / "dataset.toml").read_text().replace("gravity_body = [0, 0, -1]", "gravity_body = [0, 1, 0]")
    (small / "dataset.toml").write_text(text)
    with pytest.raises(DataFormatError, match=r"hang_zpos\.csv.*no opposite"):
        read_dataset(small / "dataset.toml")


def test_nan_rows_dropped_and_counted(small, caplog):
    df = pd.read_csv(small / "hang_xneg.csv")
    df.loc[[5, 17, 40], "HR_fz"] = np.nan
    df.to_csv(small / "hang_xneg.csv", index=False)
    with caplog.at_level(logging.WARNING):
        ds = read_dataset(small / "dataset.toml")
    rec = [r for r in ds.recordings if r.name == "hang_xneg"][0]
    assert rec.n_dropped == 3 and rec.n == 297
    assert "dropped 3 of 300 rows" in caplog.text and "hang_xneg.csv" in caplog.text


def test_torque_in_newton_millimetres(small):
    df = pd.read_csv(small / "standing.csv")
    for c in ("tx", "ty", "tz"):
        df[f"FR_{c}"] *= 1000.0
    df.to_csv(small / "standing.csv", index=False)
    with pytest.raises(DataFormatError, match=r"standing\.csv.*FR_tx.*N\*mm"):
        read_dataset(small / "dataset.toml")


def test_force_in_millinewtons(small):
    df = pd.read_csv(small / "walk.csv")
    for c in ("fx", "fy", "fz", "tx", "ty", "tz"):
        df[f"HL_{c}"] *= 1000.0
    df.to_csv(small / "walk.csv", index=False)
    with pytest.raises(DataFormatError, match=r"walk\.csv.*HL_fx.*unit factor"):
        read_dataset(small / "dataset.toml")


def test_position_in_millimetres(small):
    text = (small / "robot.toml").read_text().replace("position_m = [0.25, 0.15, 0.0]", "position_m = [250.0, 150.0, 0.0]")
    (small / "robot.toml").write_text(text)
    with pytest.raises(DataFormatError, match=r"transducers\.FL.*mm"):
        read_robot(small / "robot.toml")


def test_missing_robot_key(small):
    """``mass_kg`` is needed only with standing or walking recordings (DATA_FORMAT.md section 5)."""
    text = (small / "robot.toml").read_text().replace("mass_kg = 8.18\n", "")
    (small / "robot.toml").write_text(text)
    assert read_robot(small / "robot.toml").mass_kg is None
    with pytest.raises(DataFormatError, match=r"robot\.toml: missing key 'mass_kg'.*standing"):
        read_dataset(small / "dataset.toml")
    text = text.replace("g = 9.81\n", "")
    (small / "robot.toml").write_text(text)
    with pytest.raises(DataFormatError, match=r"robot\.toml.*'g'"):
        read_robot(small / "robot.toml")


def test_standing_without_quaternion(small):
    pd.read_csv(small / "standing.csv").drop(columns=["qw"]).to_csv(small / "standing.csv", index=False)
    with pytest.raises(DataFormatError, match=r"standing\.csv.*qw"):
        read_dataset(small / "dataset.toml")


def test_extra_column_warns(small, caplog):
    df = pd.read_csv(small / "walk.csv")
    df["battery_V"] = 12.0
    df.to_csv(small / "walk.csv", index=False)
    read_dataset(small / "dataset.toml")
    logged = [r.getMessage() for r in caplog.records if "battery_V" in r.getMessage()]
    assert len(logged) == 1 and "walk.csv" in logged[0], logged  # once, naming file and column


def test_unknown_kind(small):
    text = (small / "dataset.toml").read_text().replace('kind = "walking"', 'kind = "running"')
    (small / "dataset.toml").write_text(text)
    with pytest.raises(DataFormatError, match=r"kind 'running'"):
        read_dataset(small / "dataset.toml")


def test_torque_ratio_names_forces_in_kN_first_when_they_never_reach_a_newton():
    """The lever-arm ratio of torques to forces cannot tell N*mm torques from kN forces: forces below 1 N (a 1.5 kg
    tool read in kN) put kN first; forces of newtons put N*mm first."""
    from ftcal_nlp.core.data import check_torque_units

    rng = np.random.default_rng(0)
    f = rng.normal(size=(200, 3)) * 14.7
    t = rng.normal(size=(200, 3)) * 0.3
    with pytest.raises(DataFormatError, match=r"are the forces in kN, or the torques in N\*mm\?"):
        check_torque_units(np.hstack([f / 1000.0, t]), None, "x.csv", "wrist")
    with pytest.raises(DataFormatError, match=r"are the torques in N\*mm, or the forces in kN\?"):
        check_torque_units(np.hstack([f, t * 1000.0]), None, "x.csv", "wrist")
    check_torque_units(np.hstack([f, t]), None, "x.csv", "wrist")   # N and N*m: a lever of 2 cm passes
