"""Every written time column equals the recording's to the last bit, whatever the epoch; every float keeps
its precision (issue 24, item 4). Before, ``float_format="%.7g"`` put t ~ 1.6e7 s (a session clock months
after calibration) up to 4.7 s off, and Unix time (1.6e9 s) minutes off."""

import json
from decimal import Decimal
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import ftcal_nlp.run as run_mod
from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.correct import correct_file, main as correct_main
from ftcal_nlp.core.csvout import write_csv
from ftcal_nlp.core.settings import CorrectSettings

from conftest import require_sample

EPOCHS = {"session clock months later": 1.6e7 + 1 / 3, "Unix time": 1.6e9 + 1 / 7}


def _read(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, engine="pyarrow")  # the reader of data.read_table


@pytest.fixture(scope="module")
def truth_calibration(tmp_path_factory) -> Path:
    d = json.loads((require_sample() / "truth.json").read_text())
    d["g"] = 9.81
    p = tmp_path_factory.mktemp("cal") / "calibration.json"
    p.write_text(json.dumps(d))
    return p


@pytest.mark.parametrize("epoch", list(EPOCHS))
def test_correct_writes_the_recordings_times_and_full_precision(epoch, truth_calibration, tmp_path):
    walk = _read(require_sample() / "walk.csv")
    walk["t"] = walk["t"] + EPOCHS[epoch]
    src = write_csv(walk, tmp_path / "walk.csv")
    t_in = _read(src)["t"].to_numpy()
    assert np.array_equal(t_in, walk["t"].to_numpy())  # the input itself round-trips
    out = tmp_path / "c.csv"
    assert correct_main([str(truth_calibration), str(src), "-o", str(out), "-q", "--track-offsets"]) == 0
    got = _read(out)
    assert np.array_equal(got["t"].to_numpy(), t_in)  # to the last bit
    assert np.array_equal(_read(tmp_path / "c_offsets.csv")["t"].to_numpy(), t_in)
    # every value as computed (the in-memory table), not 7 significant digits of it
    ref = correct_file(Calibration.load(truth_calibration), src, settings=CorrectSettings(track_offsets=True))
    num = [c for c in ref.columns if ref[c].dtype.kind == "f"]
    assert np.array_equal(got[num].to_numpy(float), ref[num].to_numpy(float), equal_nan=True)
    assert list(got.columns) == list(ref.columns) and not any(c.startswith('"') for c in open(out).readline().split(","))


def test_run_writes_corrected_and_tracked_offsets_at_full_precision(tmp_path):
    rng = np.random.default_rng(5)
    t = 1.6e9 + np.cumsum(rng.uniform(0.009, 0.011, 1000))
    frame = pd.DataFrame({"t": t, "FL_fx": rng.normal(size=1000) * 1e-9 + 3.0, "FL_contact": rng.integers(0, 2, 1000).astype(np.int8)})
    res = SimpleNamespace(corrected={"walk": frame}, tracked_offsets={})
    run_mod.write_corrected(res, tmp_path)
    back = _read(tmp_path / "corrected" / "walk.csv")
    assert np.array_equal(back["t"].to_numpy(), t) and np.array_equal(back["FL_fx"].to_numpy(), frame["FL_fx"].to_numpy())
    assert np.array_equal(back["FL_contact"].to_numpy(), frame["FL_contact"].to_numpy())
    # no temporary file is left beside the table
    assert sorted(p.name for p in (tmp_path / "corrected").iterdir()) == ["walk.csv"]


def test_bag_stamps_are_exact_to_the_nanosecond_at_unix_time(tmp_path):
    pytest.importorskip("rosbags")
    from ftcal_nlp.ros.bagio import read_wrench_topics, write_ground_wrench_bag

    t = 1.6e9 + np.arange(50) * 0.01 + 1 / 3
    w = {"FL": np.ones((50, 6))}
    write_ground_wrench_bag(tmp_path / "bag", t, w)
    stamps = read_wrench_topics(tmp_path / "bag")
    got = next(v[0] for k, v in stamps.items() if k.endswith("/FL"))
    exact = np.array([int((Decimal(float(x)) * 10**9).to_integral_value()) for x in t], dtype=np.int64)
    assert np.abs(got - exact).max() <= 1  # ns; t * 1e9 in floating point was off by up to 128 ns
