"""The one error family (issue 21): what the user can act on is a FtcalError carrying its file / key / column;
``pipeline.optional`` skips a comparison for such an error and names anything else a defect."""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.errors import ConfigError, DataFormatError, FtcalError, OutputError, OutputExistsError, SolverError
from ftcal_nlp.models import resolve
from ftcal_nlp.pipeline import optional
from ftcal_nlp.core.settings import HangingSettings, PoseExtraction
from ftcal_nlp.sim import SimConfig


def test_family_and_the_builtins_it_replaced():
    for cls in (DataFormatError, ConfigError, SolverError, OutputError, OutputExistsError):
        assert issubclass(cls, FtcalError)
    assert issubclass(DataFormatError, ValueError) and issubclass(ConfigError, ValueError)
    assert issubclass(SolverError, RuntimeError) and issubclass(OutputExistsError, FileExistsError)
    e = ConfigError("x", path="a/run.toml", key="hanging.n_grid")
    assert str(e.path) == "a/run.toml" and e.key == "hanging.n_grid"
    assert SolverError("y", "Infeasible_Problem_Detected").status == "Infeasible_Problem_Detected"


def test_optional_skips_a_user_error_with_its_reason(caplog):
    notes: list[str] = []

    def cannot():
        raise DataFormatError("leg FL: recordings a and b share almost no shaft angles", path="data/a.csv")

    with caplog.at_level(logging.DEBUG, logger="ftcal_nlp.pipeline"):
        assert optional("the report's baseline", notes, cannot) is None
    assert notes == ["the report's baseline was skipped: leg FL: recordings a and b share almost no shaft angles"]
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert [r.getMessage() for r in warnings] == notes
    assert "defect" not in notes[0]


def test_optional_names_anything_else_a_defect_with_its_traceback(caplog):
    notes: list[str] = []

    def broken():
        return np.zeros(3)[5]  # an IndexError: a bug of the package, not of the data

    with caplog.at_level(logging.DEBUG, logger="ftcal_nlp.pipeline"):
        assert optional("the sim-to-real gap diagnosis", notes, broken) is None
    assert len(notes) == 1
    assert notes[0].startswith("the sim-to-real gap diagnosis was skipped by a defect (IndexError: ")
    assert notes[0].endswith("please report it")
    debug = [r for r in caplog.records if r.levelno == logging.DEBUG]
    assert debug and debug[-1].exc_info is not None and debug[-1].exc_info[0] is IndexError
    assert "in broken" in caplog.text  # the traceback itself was logged (at debug)


def test_optional_passes_a_result_through():
    notes: list[str] = []
    assert optional("x", notes, lambda: 3) == 3 and notes == []


def test_settings_and_registry_errors_are_config_errors_naming_the_key():
    with pytest.raises(ConfigError) as exc:
        HangingSettings(n_grid=3)
    assert exc.value.key == "hanging.n_grid"
    with pytest.raises(ConfigError) as exc:
        PoseExtraction(max_mocap_missing=2.0)
    assert exc.value.key == "standing.poses.max_mocap_missing"
    with pytest.raises(ConfigError, match=r"unknown error model 'ful'; known models: \['full'"):
        resolve("ful")
    with pytest.raises(ConfigError) as exc:
        SimConfig.from_dict({"rate_hz": -1.0}, where="run.toml [simulate]")
    assert exc.value.key == "simulate.rate_hz" and str(exc.value).startswith("run.toml [simulate]: SimConfig.rate_hz")
    with pytest.raises(ConfigError) as exc:
        SimConfig.from_dict({"rate_hz": "fast"})
    assert exc.value.key == "rate_hz"


def test_data_errors_name_the_column():
    from ftcal_nlp.core.data import recording_from_frame
    from ftcal_nlp.core.robot import Robot, Transducer

    robot = Robot("r", 10.0, 9.81, ("A",), {"A": Transducer("A", np.array([0.1, 0, 0]), np.eye(3))})
    df = pd.DataFrame({"t": [0.0, 0.1, 0.2], "A_phi": [0.0, 0.1, 0.2], "A_fx": [1.0, "x", 2.0], "A_fy": 0.0,
                       "A_fz": 0.0, "A_tx": 0.0, "A_ty": 0.0, "A_tz": 0.0})
    with pytest.raises(DataFormatError, match="column 'A_fx' row 2") as exc:
        recording_from_frame(df, robot, name="h", kind="hanging", gravity_body=np.array([0, 0, -1.0]))
    assert exc.value.column == "A_fx"
    with pytest.raises(DataFormatError) as exc:
        recording_from_frame(df.drop(columns="A_tz"), robot, name="h", kind="hanging", gravity_body=np.array([0, 0, -1.0]))
    assert exc.value.column == "A_tz"


def test_a_bad_simulate_key_is_one_error_line_naming_the_file_and_key(tmp_path, capsys):
    from ftcal_nlp.run import main

    cfg = tmp_path / "run.toml"
    cfg.write_text('[simulate]\ndir = "data"\nn_poses = 12\nrate = 100\n[output]\ndir = "out"\n')
    assert main([str(cfg)]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert f"{cfg} [simulate]: unknown key(s) ['rate']" in lines[0] and "'rate_hz'" in lines[0]
    assert not (tmp_path / "out").exists() and not (tmp_path / "data").exists()
