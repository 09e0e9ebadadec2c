"""The shared samples (``sample_payload``, ``sample_urdf``, ``sample_arm_notool``: independent data with truth)
calibrated on a first part and corrected on the rest: every check of ``correct`` on free loads passes a clean later
recording of each kind with no error and no warning, and the contact wrench comes out at the readings' noise."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import correct
from ftcal_nlp.run import main as run_main


SHARED = Path("/work/shared")
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


@pytest.mark.parametrize("sample, file, leg", [("sample_payload", "wrist.csv", "wrist"), ("sample_urdf", "leg.csv", "leg")])
def test_a_later_half_of_a_shared_sample_passes_at_the_noise(sample, file, leg, tmp_path, caplog) -> None:
    folder = tmp_path / sample
    shutil.copytree(SHARED / sample, folder)
    df = pd.read_csv(SHARED / sample / file)
    half = df["t"] < df["t"].iloc[0] + (df["t"].iloc[-1] - df["t"].iloc[0]) / 2
    df[half].to_csv(folder / file, index=False, float_format="%.17g")
    df[~half].to_csv(tmp_path / "later.csv", index=False, float_format="%.17g")
    (tmp_path / "run.toml").write_text(f'[data]\nmanifest = "{folder / "dataset.toml"}"\n[output]\ndir = "out"\n'
                                       '[diagnose]\nenabled = false\n')
    assert run_main([str(tmp_path / "run.toml"), "-q"]) == 0
    cal = tmp_path / "out" / "calibration.json"
    caplog.clear()   # the run's own warnings (undetermined directions of a half) are not correct's
    with caplog.at_level("WARNING"):
        assert correct.main([str(cal), str(tmp_path / "later.csv"), "-o", str(tmp_path / "c.csv")]) == 0
    assert "WARNING" not in caplog.text, caplog.text[-800:]
    noise = np.asarray(json.loads(cal.read_text())["legs"][leg]["noise_sd"])
    got = pd.read_csv(tmp_path / "c.csv")
    rms = np.sqrt((got[[f"{leg}_{c}" for c in WRENCH]].to_numpy() ** 2).mean(axis=0))
    assert np.all(rms / noise < 1.2), rms / noise


def test_the_shared_arms_held_out_holds_pass_at_the_noise_with_joints_only(tmp_path, caplog) -> None:
    """``sample_arm_notool`` calibrated on its first 15 holds (6.6 s each), the other 15 corrected with joints only
    (the calibration's gravity_body): no warning, the contact wrench at the readings' noise."""
    folder = tmp_path / "arm"
    folder.mkdir()
    for name in ("arm.urdf", "robot.toml"):
        shutil.copy(SHARED / "sample_arm_notool" / name, folder / name)
    df = pd.read_csv(SHARED / "sample_arm" / "wrist.csv")
    first = df["t"] < df["t"].iloc[0] + 15 * 6.6
    df[first].to_csv(folder / "wrist.csv", index=False, float_format="%.17g")
    df[~first].to_csv(tmp_path / "later.csv", index=False, float_format="%.17g")
    (folder / "dataset.toml").write_text('robot = "robot.toml"\n[[recording]]\nfile = "wrist.csv"\nkind = "hanging"\n'
                                         'gravity_body = [0, 0, -1]\n')
    (tmp_path / "run.toml").write_text(f'[data]\nmanifest = "{folder / "dataset.toml"}"\n[output]\ndir = "out"\n'
                                       '[diagnose]\nenabled = false\n')
    assert run_main([str(tmp_path / "run.toml"), "-q"]) == 0
    cal = tmp_path / "out" / "calibration.json"
    caplog.clear()
    with caplog.at_level("WARNING"):
        assert correct.main([str(cal), str(tmp_path / "later.csv"), "-o", str(tmp_path / "c.csv")]) == 0
    assert "WARNING" not in caplog.text, caplog.text[-800:]
    noise = np.asarray(json.loads(cal.read_text())["legs"]["wrist"]["noise_sd"])
    got = pd.read_csv(tmp_path / "c.csv")
    rms = np.sqrt((got[[f"wrist_{c}" for c in WRENCH]].to_numpy() ** 2).mean(axis=0))
    assert np.all(np.abs(rms / noise - 1) < 0.1), rms / noise
