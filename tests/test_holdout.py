"""Validation on a later session (``holdout``, issue 32 item 6): calibrate on one simulated session of a wrist payload,
validate on another of the same truth (every region holds, RMS z ~1), on one where a cable touches the tool in one
region of gravity's direction (that region named, the others hold), and bad input (clear errors)."""

from __future__ import annotations


import numpy as np
import pandas as pd
import pytest
import tomli_w

from ftcal_nlp.config import load_config
from ftcal_nlp.core.errors import ConfigError, DataFormatError
from ftcal_nlp.estimate.freeload.holdout import REGION_CENTRES, REGION_NAMES, holdout, region_index, rms_band, LegSamples
from ftcal_nlp.holdout import main as holdout_main, validate
from ftcal_nlp.run import main as run_main
from ftcal_nlp.sim.free import PayloadConfig, gravity_in_ft, simulate_payload, true_rotation, write_free_load

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
TRUTH = dict(mass_kg=1.2, com_m=(0.005, -0.003, 0.07), offset=(2.0, -1.5, 0.7, 0.04, -0.03, 0.01),
             mount_rotvec=(0.01, -0.015, 0.02))
CABLE_N = 0.15     # a cable pulling the tool along fx in one region: ~7 sd of the noise per sample


def _session(seed: int, holds: int, t0: float) -> tuple[pd.DataFrame, np.ndarray]:
    """A session of the payload of ``TRUTH`` (``holds`` orientations drawn with ``seed``) and gravity's true
    direction in the sensor's frame per sample."""
    cfg = PayloadConfig(seed=seed, n_orientations=holds, hold_s=2.0, move_s=1.0, t0_s=t0, **TRUTH)
    res = simulate_payload(cfg)
    g = gravity_in_ft(res.R_WB, true_rotation(np.asarray(res.truth["nominal_rotation"]), np.asarray(TRUTH["mount_rotvec"])), 9.81)
    return res.frame, g / np.linalg.norm(g, axis=1, keepdims=True), res


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """Session 1 calibrated by a run whose ``[holdout]`` names session 2 (same truth, other orientations and noise);
    a session 3 with a cable touching in one region."""
    d = tmp_path_factory.mktemp("holdout")
    _, _, res1 = _session(1, 24, 1000.0)
    write_free_load(res1, d / "data")
    later, u2, _ = _session(2, 40, 5000.0)
    later.to_csv(d / "later.csv", index=False, float_format="%.17g")
    # the region whose centre most samples lie within 20 deg of: the cable touches there only (inside its cell)
    near = (u2 @ REGION_CENTRES.T) > np.cos(np.radians(20))
    j = int(np.argmax(near.sum(0)))
    touched = later.copy()
    touched.loc[near[:, j], "wrist_fx"] += CABLE_N
    touched.to_csv(d / "touched.csv", index=False, float_format="%.17g")
    (d / "run.toml").write_bytes(tomli_w.dumps({"data": {"manifest": "data/dataset.toml"}, "output": {"dir": "out"},
                                                "diagnose": {"enabled": False},
                                                "holdout": {"recordings": ["later.csv"]}}).encode())
    assert run_main([str(d / "run.toml"), "-q"]) == 0
    return d, REGION_NAMES[j], int(near[:, j].sum())


def test_same_truth_holds_everywhere(sessions) -> None:
    d, _, _ = sessions
    tab = pd.read_csv(d / "out" / "holdout" / "holdout.csv")
    assert len(tab) >= 8 and tab["holds"].all(), tab[["region", "n", "chi2_max", "p_bonferroni"]]
    assert "holds in every region" in (d / "out" / "holdout" / "holdout.md").read_text()
    assert (d / "out" / "holdout" / "holdout.png").stat().st_size > 10_000
    h, _ = validate(d / "out" / "calibration.json", [d / "later.csv"])
    lh = h.legs["wrist"]
    # RMS z per axis: within the band 20 000 samples give (~0.98-1.02), itself within [0.8, 1.25]
    assert 0.8 <= lh.band[0] and lh.band[1] <= 1.25
    assert np.all((lh.rms_z >= lh.band[0]) & (lh.rms_z <= lh.band[1])), (lh.rms_z, lh.band)
    assert h.tests == 6 * len(lh.regions) and h.holds


def test_cable_in_one_region_is_named(sessions, tmp_path, capsys) -> None:
    d, region, n_touched = sessions
    out = tmp_path / "v"
    assert holdout_main([str(d / "out" / "calibration.json"), str(d / "touched.csv"), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    tab = pd.read_csv(out / "holdout.csv")
    failing = tab.loc[tab["holds"] == 0, "region"].tolist()
    assert failing == [region], (failing, region, n_touched)
    row = tab.set_index("region").loc[region]
    # the mean fx error there: the cable's share of the region's samples, within 4 se
    share = n_touched / row["n"]
    assert abs(row["mean_fx"] - CABLE_N * share) < 4 * row["mean_se_fx"], (row["mean_fx"], CABLE_N * share)
    md = (out / "holdout.md").read_text()
    assert f"does not hold at: wrist gravity along {region} (fx off by" in md
    assert f"does not hold at gravity along {region}" in printed
    # a second call over the same folder needs --force; the manifest lists the three files
    assert holdout_main([str(d / "out" / "calibration.json"), str(d / "touched.csv"), "-o", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert holdout_main([str(d / "out" / "calibration.json"), str(d / "touched.csv"), "-o", str(out), "--force", "-q"]) == 0


def test_pure_function_on_white_noise() -> None:
    """z ~ N(0, 1) everywhere on the sphere (se = sigma, no calibration part): nothing fails at 1 % (seed 3); a
    bias of 1 sigma in one region's fz is found there alone."""
    rng = np.random.default_rng(3)
    n = 20_000
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    sigma = np.array([0.02, 0.02, 0.02, 0.001, 0.001, 0.001])
    w = rng.normal(size=(n, 6)) * sigma
    mk = lambda w: {"a": LegSamples("a", w, np.broadcast_to(sigma, (n, 6)).copy(), sigma, u, np.zeros(n, int),
                                    np.arange(n), np.arange(n) * 0.01)}
    h = holdout(mk(w))
    assert h.holds and len(h.legs["a"].regions) == 26 and h.tests == 156
    assert rms_band(1e4)[0] > 0.97
    w2 = w.copy()
    w2[region_index(u) == REGION_NAMES.index("-x+y"), 2] += sigma[2]
    assert [r.name for r in holdout(mk(w2)).failing] == ["-x+y"]


def _cli_error(args: list[str], capsys) -> str:
    assert holdout_main(args) == 2
    return capsys.readouterr().err


def test_bad_input(sessions, tmp_path, capsys) -> None:
    d, _, _ = sessions
    cal = str(d / "out" / "calibration.json")
    later = pd.read_csv(d / "later.csv")
    # a recording of another transducer
    other = tmp_path / "other.csv"
    later.rename(columns={f"wrist_{c}": f"ankle_{c}" for c in WRENCH}).to_csv(other, index=False)
    err = _cli_error([cal, str(other), "-o", str(tmp_path / "o1")], capsys)
    assert "ankle_fx" in err and "wrist" in err and not (tmp_path / "o1").exists()
    # the output of correct in place of the recording
    corrected = tmp_path / "corrected.csv"
    from ftcal_nlp import correct

    assert correct.main([cal, str(d / "later.csv"), "-o", str(corrected), "-q"]) == 0
    err = _cli_error([cal, str(corrected), "-o", str(tmp_path / "o2")], capsys)
    assert "wrist_fx_se" in err and "corrected table" in err
    # in contact throughout (a 5 N push): every region fails, the verdict says what that means
    pushed = tmp_path / "pushed.csv"
    later.assign(wrist_fz=later["wrist_fz"] + 5.0).to_csv(pushed, index=False, float_format="%.17g")
    assert holdout_main([cal, str(pushed), "-o", str(tmp_path / "o3"), "-q"]) == 0
    md = (tmp_path / "o3" / "holdout.md").read_text()
    assert "touched something throughout" in md
    # --alpha out of range; an output file that is an input (a recording named holdout.csv in the output folder)
    assert "--alpha" in _cli_error([cal, str(d / "later.csv"), "-o", str(tmp_path / "o4"), "--alpha", "2"], capsys)
    (tmp_path / "o6").mkdir()
    (tmp_path / "o6" / "holdout.csv").write_bytes((d / "later.csv").read_bytes())
    err = _cli_error([cal, str(tmp_path / "o6" / "holdout.csv"), "-o", str(tmp_path / "o6")], capsys)
    assert "would overwrite the recording" in err
    # a hexapod calibration
    from conftest import require_sample

    import json

    from ftcal_nlp.core.calibration import Calibration

    hexa = tmp_path / "hexa.json"
    Calibration.from_json_dict(json.loads((require_sample() / "truth.json").read_text()), mass_kg=8.18, g=9.81).save(hexa)
    assert "hexapod legs" in _cli_error([str(hexa), str(d / "later.csv"), "-o", str(tmp_path / "o5")], capsys)


@pytest.mark.parametrize("table, key", [
    ({"recordings": []}, "holdout.recordings"),
    ({"recordings": ["missing.csv"]}, "holdout.recordings"),
    ({"recordings": ["later.csv"], "alpha": 1.5}, "holdout.alpha"),
    ({"recordings": ["later.csv"], "gravity_body": [0, 0]}, "holdout.gravity_body"),
    ({"recordings": ["later.csv"], "recording": "x"}, "holdout.recording"),
])
def test_config_errors(sessions, tmp_path, table, key) -> None:
    d, _, _ = sessions
    (tmp_path / "later.csv").write_text((d / "later.csv").read_text()[:2000])
    cfg = tmp_path / "run.toml"
    cfg.write_bytes(tomli_w.dumps({"data": {"manifest": str(d / "data" / "dataset.toml")}, "output": {"dir": "out"},
                                   "holdout": table}).encode())
    with pytest.raises(ConfigError) as exc:
        load_config(cfg)
    assert exc.value.key == key and "[holdout]" in str(exc.value)


def test_run_checks_holdout_recordings_before_the_fit(sessions, tmp_path, capsys) -> None:
    d, _, _ = sessions
    bad = tmp_path / "bad.csv"
    pd.read_csv(d / "later.csv", nrows=50).drop(columns=["wrist_tz"]).to_csv(bad, index=False)
    cfg = tmp_path / "run.toml"
    cfg.write_bytes(tomli_w.dumps({"data": {"manifest": str(d / "data" / "dataset.toml")}, "output": {"dir": "out"},
                                   "holdout": {"recordings": ["bad.csv"]}}).encode())
    assert run_main([str(cfg), "-q"]) == 2
    err = capsys.readouterr().err
    assert "wrist_tz" in err and "[holdout]" in err and not (tmp_path / "out").exists()
    with pytest.raises(DataFormatError):
        validate(d / "out" / "calibration.json", [bad])


def test_own_recording_is_said_and_hexapod_dataset_refused(sessions, caplog) -> None:
    """Validating on the recording the calibration was fitted on is a warning (it checks the fit); a run config with
    [holdout] on a hexapod dataset is refused before the fit."""
    from conftest import require_sample

    from ftcal_nlp.config import HoldoutSettings
    from ftcal_nlp.core.data import read_dataset
    from ftcal_nlp.holdout import check_run_holdout

    d, _, _ = sessions
    with caplog.at_level("WARNING"):
        h, _ = validate(d / "out" / "calibration.json", [d / "data" / "wrist.csv"])
    assert "a recording the calibration" in caplog.text and h.holds
    ds = read_dataset(require_sample() / "dataset.toml")
    with pytest.raises(ConfigError, match="hexapod legs"):
        check_run_holdout(HoldoutSettings((d / "later.csv",)), ds)
