"""Run config validation and the correction of new recordings (against the sample's walk_truth)."""

import json

import numpy as np
import pandas as pd
import pytest

from conftest import SAMPLE, require_sample
from ftcal_nlp.core.calibration import Calibration
from ftcal_nlp.config import ConfigError, load_config
from ftcal_nlp.correct import correct_file, main as correct_main
from ftcal_nlp.core.settings import CalibrationSettings


def _write(tmp_path, text):
    p = tmp_path / "run.toml"
    p.write_text(text)
    return p


def test_minimal_config(tmp_path):
    cfg = load_config(_write(tmp_path, '[data]\nmanifest = "d/dataset.toml"\n[output]\ndir = "out"\n[diagnose]\nenabled = true\n'))
    assert cfg.manifest == tmp_path / "d/dataset.toml" and cfg.output_dir == tmp_path / "out"
    st = cfg.settings.standing
    assert st.model == "auto" and st.solver == "ipopt" and st.balance == "exact"
    assert cfg.settings == CalibrationSettings()  # nothing but the defaults of settings.py


@pytest.mark.parametrize(
    "text, match",
    [
        ('[output]\ndir = "o"\n', r"needs \[data\].manifest"),
        ('[data]\nmanifest = "d.toml"\n', r"\[output\].dir"),
        ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing]\nsolver = "snopt"\n', r"\[standing\].solver.*'ipopt', 'baseline'.*snopt"),
        ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing]\nbalance = "approx"\n', r"\[standing\].balance"),
        ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[hanging]\nmetod = "nlp"\n', r"\[hanging\].*unknown key.*metod"),
        ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[selection]\nfolds = "five"\n', r"\[selection\].folds.*integer"),
        ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[diagnose]\nenabled = 1\n', r"\[diagnose\].enabled.*true or false"),
        ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing.poses]\nmin_steady_s = "long"\n', r"\[standing.poses\].min_steady_s.*number"),
        ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[bogus]\n', r"unknown section.*bogus"),
        ('[data\n', r"not valid TOML"),
    ],
)
def test_config_errors_name_the_key(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_config(_write(tmp_path, text))


def test_default_problem_config_is_valid():
    from pathlib import Path

    cfg = load_config(Path(__file__).resolve().parents[1] / "problems" / "bigant_sim.toml")
    assert cfg.simulate is not None and cfg.settings.standing.candidates == ("full", "rot6_trans1", "trans6", "trans1")


@pytest.fixture(scope="module")
def truth_calibration(tmp_path_factory):
    d = json.loads((require_sample() / "truth.json").read_text())
    path = tmp_path_factory.mktemp("cal") / "calibration.json"
    Calibration.from_json_dict(d, mass_kg=8.18, g=9.81).save(path)
    return path


def test_correction_of_sample_walk_matches_truth(truth_calibration):
    # README of the sample: the true parameters leave 0.05 N / 0.011 N*m RMS per component (noise only)
    out = correct_file(Calibration.load(truth_calibration), SAMPLE / "walk.csv")
    truth = pd.read_csv(SAMPLE / "walk_truth.csv")
    legs = ("FL", "ML", "HL", "FR", "MR", "HR")
    err = np.stack([out[[f"{k}_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy() - truth[[f"{k}_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy() for k in legs], 1)
    rms = np.sqrt((err**2).mean(axis=(0, 1)))
    print("RMS error per component", rms)
    assert np.all(rms[:3] < 1.5 * 0.05) and np.all(rms[3:] < 1.5 * 0.011)
    # totals: the sum over feet, and the robot's weight while the robot walks quasi-statically
    tot = out[[f"total_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy()
    np.testing.assert_allclose(tot, sum(out[[f"{k}_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")]].to_numpy() for k in legs), atol=1e-4)
    assert abs(np.median(tot[:, 2]) - 8.18 * 9.81) < 3 * 0.05 * np.sqrt(6)


def test_correct_cli_refuses_to_overwrite(truth_calibration, tmp_path, capsys):
    out = tmp_path / "walk_corrected.csv"
    assert correct_main([str(truth_calibration), str(SAMPLE / "walk.csv"), "-o", str(out)]) == 0
    first = out.read_bytes()
    assert correct_main([str(truth_calibration), str(SAMPLE / "walk.csv"), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == first


def test_correct_cli_bad_recording(truth_calibration, tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    pd.read_csv(SAMPLE / "walk.csv").drop(columns=["qx"]).to_csv(bad, index=False)
    assert correct_main([str(truth_calibration), str(bad), "-o", str(tmp_path / "o.csv")]) == 2
    assert "qx" in capsys.readouterr().err


def test_pose_thresholds_are_config_keys(tmp_path):
    cfg = load_config(_write(tmp_path, '[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing.poses]\nderiv_threshold_N_s = 2.5\nmin_steady_s = 1.0\nderiv_norm = "total"\n'))
    p = cfg.settings.standing.poses
    assert p.deriv_threshold_N_s == 2.5 and p.min_steady_s == 1.0 and p.deriv_norm == "total"
    with pytest.raises(ConfigError, match=r"\[standing.poses\].*deriv_norm"):
        load_config(_write(tmp_path, '[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing.poses]\nderiv_norm = "max"\n'))


def test_calibration_json_is_strict_and_round_trips(truth_calibration, tmp_path):
    cal = Calibration.load(truth_calibration)
    leg = cal.legs["FL"]
    from dataclasses import replace

    # an undetermined se (inf) and an unsupported CoM grid point (NaN) become null, and come back as NaN
    se = np.array([0.1, np.inf, 0.1])
    xyz = leg.com_xyz.copy()
    xyz[3] = np.nan
    odd = replace(cal, legs={**cal.legs, "FL": replace(leg, position_from_com_se_m=se, com_xyz=xyz)})
    path = tmp_path / "c.json"
    odd.save(path)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    back = Calibration.load(path)
    assert np.isnan(back.legs["FL"].position_from_com_se_m[1]) and np.isnan(back.legs["FL"].com_xyz[3]).all()
    np.testing.assert_allclose(back.legs["ML"].com_xyz, cal.legs["ML"].com_xyz)
    np.testing.assert_allclose(back.legs["FR"].rotation_to_body, cal.legs["FR"].rotation_to_body)


def test_weighting_key(tmp_path):
    cfg = load_config(_write(tmp_path, '[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing]\nweighting = "knorm"\n'))
    assert cfg.settings.standing.weighting == "knorm"
    with pytest.raises(ConfigError, match=r"\[standing\].weighting"):
        load_config(_write(tmp_path, '[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing]\nweighting = "ols"\n'))
    with pytest.raises(ConfigError, match=r'solver = "baseline".*weighting = "knorm"'):
        load_config(_write(tmp_path, '[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing]\nsolver = "baseline"\n'))


def test_unknown_keys_name_the_file_and_the_key_and_list_the_valid_ones(tmp_path):
    with pytest.raises(ConfigError) as exc:
        load_config(_write(tmp_path, '[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n[standing.poses]\nwindow = 0.3\n'))
    e = exc.value
    assert e.path == tmp_path / "run.toml" and e.key == "standing.poses.window"
    assert str(e).startswith(f"{tmp_path / 'run.toml'} [standing.poses]: unknown key(s) ['window']; known keys: ")
    assert "'window_s'" in str(e) and "'min_steady_s'" in str(e)
    # the top-level seed was set by bigant_sim.toml and read by nothing: gone, with where the seeds are
    with pytest.raises(ConfigError, match=r"unknown section\(s\) \['seed'\].*\[selection\] seed and \[diagnose\] seed") as exc:
        load_config(_write(tmp_path, 'seed = 0\n[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n'))
    assert exc.value.key == "seed"


def test_every_settings_field_is_a_config_key(tmp_path):
    """The config maps onto the settings generically: a value for every field of every settings table
    (non-defaults) comes back in ``cfg.settings``."""
    text = ('[data]\nmanifest = "d.toml"\n[output]\ndir = "o"\n'
            '[hanging]\nmethod = "baseline"\nn_grid = 36\nsmoothing = 2\ncompare_baseline = false\n'
            '[standing]\nmodel = "full"\ncandidates = ["full", "trans1"]\nsolver = "baseline"\nbalance = "report"\n'
            'weighting = "knorm"\ncovariance = "sandwich"\nrel_eig_tol = 1e-7\ncompare_baseline = false\n'
            '[standing.poses]\nwindow_s = 0.5\nderiv_threshold_N_s = 2\nmin_steady_s = 1\npolyorder = 3\nderiv_norm = "total"\n'
            'phi_rate_threshold_rad_s = 0.1\nmax_mocap_missing = 0.1\nmax_gap_factor = 4\nderiv_noise_factor = 0\n'
            '[selection]\nfolds = 4\nseed = 3\n'
            '[free_load]\nwindow_s = 0.5\npolyorder = 3\nrotation_rate_threshold_rad_s = 0.03\njoint_rate_threshold_rad_s = 0.03\n'
            'deriv_threshold_N_s = 2\nnoise_factor = 3\nmax_gap_factor = 4\nmin_samples = 10\nmount_rotation = false\n'
            'prior_weight = 1e-6\nrel_eig_tol = 1e-7\nloads = {wrist = "rigid_payload"}\ngravity_tilt = false\nrecording_tilt = true\n'
                'sensor_matrix = "force"\nsensor_matrix_ridge = [0, 10]\nsensor_matrix_folds = 3\nsensor_matrix_mass_rel_sd = 0.01\n'
            '[diagnose]\nenabled = false\neffects = ["offset_drift"]\nfolds = 3\nseed = 2\njoint_refit = false\n'
            '[diagnose.hexapod]\nz_min = 2.5\nmin_floor_share = 0.1\nmax_effects = 2\nexplained_min = 0.6\n'
            '[diagnose.free_loads]\nz_min = 3.5\nmin_floor_share = 0.02\nmax_effects = 3\nexplained_min = 0.4\n'
            '[correct]\ntrack_offsets = true\nknot_s = 10\npenalty = 0.1\ncontact_window_s = 20\ncontact_quantile = 0.2\n'
            'contact_enter_z = 4\ncontact_leave_z = 8\ncontact_min_gap_N = 5\n'
            '[offsets_only]\ncalibration = "c/calibration.json"\n')
    cfg = load_config(_write(tmp_path, text))
    s = cfg.settings
    assert (s.hanging.method, s.hanging.n_grid, s.hanging.smoothing, s.hanging.compare_baseline) == ("baseline", 36, 2.0, False)
    assert s.standing.candidates == ("full", "trans1") and s.standing.balance == "report" and s.standing.covariance == "sandwich"
    assert s.standing.rel_eig_tol == 1e-7 and s.standing.poses.polyorder == 3 and s.standing.poses.max_gap_factor == 4.0
    assert isinstance(s.standing.poses.deriv_threshold_N_s, float) and s.standing.poses.deriv_noise_factor == 0.0
    assert (s.selection.folds, s.selection.seed) == (4, 3)
    assert s.diagnose.effects == ("offset_drift",) and (s.diagnose.folds, s.diagnose.seed, s.diagnose.joint_refit) == (3, 2, False)
    assert (s.diagnose.hexapod.z_min, s.diagnose.hexapod.max_effects, s.diagnose.free_loads.explained_min) == (2.5, 2, 0.4)
    assert s.correct.track_offsets and s.correct.knot_s == 10.0 and s.correct.contact_min_gap_N == 5.0
    assert cfg.offsets_only.calibration == tmp_path / "c" / "calibration.json"
    # and generically: every field of every settings table was set from the file (none kept its default)
    from dataclasses import fields, is_dataclass

    def kept(obj, default, where):
        for f in fields(obj):
            v, d = getattr(obj, f.name), getattr(default, f.name)
            if is_dataclass(v):
                yield from kept(v, d, f"{where}.{f.name}")
            elif v == d:
                yield f"{where}.{f.name}"

    assert not list(kept(s, CalibrationSettings(), "settings")), list(kept(s, CalibrationSettings(), "settings"))
