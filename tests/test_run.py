"""End to end: the default problem at a reduced size, outputs checked against the contract and the truth."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.config import load_config
from ftcal_nlp.core.geometry import rotation_to_rotvec
from ftcal_nlp.run import OutputExistsError, main, run

ROOT = Path(__file__).resolve().parents[1]
COMPONENTS = ("fx", "fy", "fz", "tx", "ty", "tz")


def _small_config(tmp_path: Path, extra: str = "") -> Path:
    text = (ROOT / "problems" / "bigant_sim.toml").read_text()
    text = text.replace('manifest = "../data/bigant_sim/dataset.toml"', f'manifest = "{tmp_path}/data/dataset.toml"')
    text = text.replace('dir = "../data/bigant_sim"\nseed = 0', f'dir = "{tmp_path}/data"\nseed = 3\nn_poses = 150\nhanging_cycles = 3.0\nwalk_cycles = 1.0')
    text = text.replace('dir = "../reports/bigant_sim"', f'dir = "{tmp_path}/out"')
    p = tmp_path / "small.toml"
    p.write_text(text + extra)
    return p


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("run")
    cfg = load_config(_small_config(tmp))
    return run(cfg), tmp


def test_outputs_follow_the_contract(small_run):
    res, tmp = small_run
    out = tmp / "out"
    cal = json.loads((out / "calibration.json").read_text())
    assert cal["model"] in ("full", "rot6_trans1", "trans6", "trans1")
    legs = res.dataset.robot.legs
    for k in legs:
        L = cal["legs"][k]
        assert len(L["offset"]) == 6 and len(L["offset_se"]) == 6
        assert np.isfinite(L["leg_weight_N"]) and np.isfinite(L["leg_weight_se_N"])
        phi = np.array(L["leg_com_grid"]["phi"])
        assert phi.min() >= 0 and phi.max() < 2 * np.pi and len(L["leg_com_grid"]["xyz"]) == len(phi)
        R = np.array(L["rotation_to_body"])
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-8)
        assert len(L["position_from_com_m"]) == 3 and len(L["position_from_com_se_m"]) == 3
    assert "com_body_m" in cal
    for name in ("model_selection", "parameters"):
        for ext in ("csv", "md", "tex"):
            assert (out / f"{name}.{ext}").is_file()
    for fig in ("naive_total.png", "leg_com.png", "hanging_residuals.png", "total_residuals.png", "walking_walk.png"):
        assert (out / fig).is_file() and (out / fig).stat().st_size > 10_000, fig
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 5
    md = (out / "report.md").read_text()
    assert "## Summary" in md and "## Notation" in md and "Model selection" in md
    assert f"{res.selection.folds}-fold" in md and "+-" not in md and " ± " in md
    for stem in ("parameters", "hanging", "model_selection"):  # a labelled first column, no tuple headers
        head = pd.read_csv(out / f"{stem}.csv").columns
        assert head[0] in ("parameter", "Model") and not any(c.startswith("(") for c in head), (stem, list(head))
    corrected = pd.read_csv(out / "corrected" / "walk.csv")
    expected = ["t"] + [f"{k}_{c}" for k in legs for c in COMPONENTS] + [f"total_{c}" for c in COMPONENTS]
    assert list(corrected.columns[: len(expected)]) == expected  # the contract's columns first, as they were
    assert list(corrected.columns[len(expected):]) == ([f"{k}_{c}_se" for k in (*legs, "total") for c in COMPONENTS]
                                                       + [f"{k}_contact" for k in legs])
    assert (out / "calibration_cov.npz").is_file() and cal["meta"]["covariance_file"] == "calibration_cov.npz"
    assert set(cal["meta"]["sensor_noise"]["readings"]) == set(legs)


def _z_scores(res, cal: Calibration, truth: Calibration) -> np.ndarray:
    """Errors over reported se for offsets, weights, rotations (rotation vectors) and translations."""
    rv_se = np.asarray(res.standing.rotvec_se)
    z = []
    for i, k in enumerate(res.dataset.robot.legs):
        l, t = cal.legs[k], truth.legs[k]
        z += list((l.offset - t.offset) / l.offset_se)
        z.append((l.leg_weight_N - t.leg_weight_N) / l.leg_weight_se_N)
        z += list(rotation_to_rotvec(t.rotation_to_body @ l.rotation_to_body.T) / rv_se[i])
        z += list((l.position_from_com_m - t.position_from_com_m) / l.position_from_com_se_m)
    return np.array(z)


def _check_z(z: np.ndarray) -> None:
    # ~80 values: a per-value 3 se bound fails by chance ~20 % of the time; a family-wise 0.5 % bound
    # is |z| < 4.1 (Bonferroni), and calibrated se give an RMS z near 1
    n = len(z)
    bound = float(__import__("scipy.stats").stats.norm.isf(0.005 / (2 * n)))
    print(f"{n} z-scores: max |z| {np.abs(z).max():.2f} (bound {bound:.2f}), rms {np.sqrt(np.mean(z**2)):.2f}")
    assert np.all(np.isfinite(z)) and np.abs(z).max() < bound
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.5


def test_calibration_matches_truth(small_run):
    """Offsets, weights, rotations and translations agree with the simulated truth within the reported se."""
    res, tmp = small_run
    assert res.calibration.model == "full" and res.standing.unidentified == ()
    _check_z(_z_scores(res, Calibration.load(tmp / "out" / "calibration.json"), res.truth))


def test_walking_correction_matches_simulated_truth(small_run):
    res, tmp = small_run
    corrected = pd.read_csv(tmp / "out" / "corrected" / "walk.csv")
    truth = pd.read_csv(tmp / "data" / "walk_truth.csv")
    merged = corrected.merge(truth, on="t", suffixes=("", "_true"))
    assert len(merged) >= 0.9 * len(truth)
    legs = res.dataset.robot.legs
    err = np.stack([merged[f"{k}_{c}"] - merged[f"{k}_{c}_true"] for k in legs for c in COMPONENTS[:3]])
    # noise-only error is ~0.05 N per component; a calibration error adds a little
    assert np.sqrt(np.mean(err**2)) < 0.15


def test_existing_output_is_not_overwritten(small_run, capsys):
    res, tmp = small_run
    before = (tmp / "out" / "calibration.json").read_bytes()
    cfg = load_config(tmp / "small.toml")
    with pytest.raises(OutputExistsError):
        run(cfg)
    assert main([str(cfg.path)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp / "out" / "calibration.json").read_bytes() == before


def test_offsets_only_reestimation(small_run, tmp_path):
    """Offsets drifted (Sec. V): an earlier calibration plus standing poses re-estimates them alone."""
    res, tmp = small_run
    cfg_path = tmp_path / "drift.toml"
    cfg_path.write_text(
        f'[data]\nmanifest = "{tmp}/data/dataset.toml"\n[output]\ndir = "{tmp_path}/out"\n'
        f'[offsets_only]\ncalibration = "{tmp}/out/calibration.json"\n[diagnose]\nenabled = false\n'
    )
    res2 = run(load_config(cfg_path))
    prev = Calibration.load(tmp / "out" / "calibration.json")
    for k in prev.legs:
        np.testing.assert_allclose(res2.calibration.legs[k].rotation_to_body, prev.legs[k].rotation_to_body)
        np.testing.assert_allclose(res2.calibration.legs[k].leg_weight_N, prev.legs[k].leg_weight_N)
        # same data, so the re-estimated offsets agree with the hanging ones within their uncertainty
        d = np.abs(res2.calibration.legs[k].offset[:3] - prev.legs[k].offset[:3])
        assert np.all(d < 0.5), (k, d)


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory):
    from conftest import require_sample

    SAMPLE = require_sample()
    tmp = tmp_path_factory.mktemp("sample")
    cfg_path = tmp / "sample.toml"
    # the minimal config of OUTPUT_FORMAT.md (diagnosis off here: it has its own tests)
    cfg_path.write_text(f'[data]\nmanifest = "{SAMPLE}/dataset.toml"\n[output]\ndir = "{tmp}/out"\n[diagnose]\nenabled = false\n')
    return run(load_config(cfg_path)), tmp, SAMPLE


def test_sample_run_recovers_truth_within_reported_se(sample_run):
    res, tmp, sample = sample_run
    assert res.calibration.model == "full"
    truth = Calibration.load(sample / "truth.json", g=9.81)
    _check_z(_z_scores(res, Calibration.load(tmp / "out" / "calibration.json"), truth))


def test_sample_walk_correction_within_noise(sample_run):
    # README of the sample: the truth leaves 0.05 N / 0.011 N*m RMS per component; allow 1.5x
    res, tmp, sample = sample_run
    corrected = pd.read_csv(tmp / "out" / "corrected" / "walk.csv")
    truth = pd.read_csv(sample / "walk_truth.csv")
    legs = res.dataset.robot.legs
    err = np.stack([corrected[[f"{k}_{c}" for c in COMPONENTS]].to_numpy() - truth[[f"{k}_{c}" for c in COMPONENTS]].to_numpy() for k in legs], 1)
    rms = np.sqrt((err**2).mean(axis=(0, 1)))
    print("sample walk RMS error per component", rms)
    assert np.all(rms[:3] < 1.5 * 0.05) and np.all(rms[3:] < 1.5 * 0.011)


def test_validation_config_dispatches_to_the_withheld_effect_validation(tmp_path, capsys):
    """A config with a [validation] table runs the diagnosis validation (issue 7) through run's CLI."""
    cfg = tmp_path / "val.toml"
    cfg.write_text(
        '[validation]\nn_datasets = 1\nseed = 2\nclean_share = 0.0\neffects = ["robot_mass"]\nmagnitude = "test"\n'
        '[validation.simulate]\nn_poses = 80\nhanging_cycles = 1.0\nwalk_cycles = 0.5\n'
        f'[output]\ndir = "{tmp_path}/out"\n'
    )
    assert main([str(cfg)]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    rows = pd.read_csv(tmp_path / "out" / "datasets.csv")
    assert len(rows) == 1 and rows.iloc[0].astype(str).str.contains("robot_mass").sum() >= 2, rows.iloc[0].to_dict()
    assert summary["accuracy"] == 1.0
    assert main([str(cfg)]) == 2 and "--force" in capsys.readouterr().err
