"""The shared samples (``sample_payload``, ``sample_urdf``: independent data with truth) calibrated on their first
half and corrected on the other: every check of ``correct`` on free loads passes a clean later recording of each
kind with no error and no warning, and the contact wrench comes out at the readings' noise (the arm's held-out
session: ``tests/test_correct_arm_guards.py``, ``tests/test_arm.py``)."""

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
