"""The exported C correction (ftcal_nlp.export) against the numpy correction it is generated from.

Compiled with the system C compiler and called through ctypes: on the sample's
walking recording it must reproduce ``correct_recording`` (the sample's true
calibration), and on random inputs (unwrapped angles, any orientation, a
calibration with a non-uniform CoM grid starting off zero) ``ground_wrenches``,
both to 1e-12 of the largest wrench: the two evaluate the same formulas in a
different order, so only rounding may separate them.
"""

import json
import shutil

import numpy as np
import pytest

from ftcal_nlp.core.calibration import Calibration, LegCalibration
from ftcal_nlp.correct import correct_file
from ftcal_nlp.core.data import WRENCH_COMPONENTS, read_table, recording_from_frame
from ftcal_nlp.correct import robot_from_calibration
from ftcal_nlp.export import compile_shared, load_compiled, main as export_main, write_c
from ftcal_nlp.core.geometry import quat_to_rotation, rotvec_to_rotation
from ftcal_nlp.core.physics import ground_wrenches

from conftest import require_sample

REL_TOL = 1e-12
pytestmark = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler (cc/gcc) on PATH")


def random_calibration(rng: np.random.Generator, n_legs: int = 4, uniform: bool = False) -> Calibration:
    legs = {}
    for i in range(n_legs):
        G = 24
        phi = np.linspace(0, 2 * np.pi, G, endpoint=False) if uniform else np.sort(rng.uniform(0.2, 2 * np.pi - 0.1, G))
        legs[f"L{i}"] = LegCalibration(
            offset=rng.normal(scale=[5, 5, 5, 0.3, 0.3, 0.3]),
            leg_weight_N=float(rng.uniform(3, 8)),
            com_phi=phi,
            com_xyz=rng.normal(scale=0.05, size=(G, 3)),
            rotation_to_body=rotvec_to_rotation(rng.normal(scale=1.0, size=3)),
            position_from_com_m=rng.normal(scale=0.2, size=3),
        )
    return Calibration(legs, mass_kg=10.0, g=9.81)


def export_and_load(cal, folder):
    files = write_c(cal, folder)
    return load_compiled(compile_shared(files), cal)


@pytest.mark.parametrize("uniform", [False, True])
def test_compiled_matches_numpy_on_random_inputs(tmp_path, uniform):
    rng = np.random.default_rng(16 + uniform)
    cal = random_calibration(rng, uniform=uniform)
    fn = export_and_load(cal, tmp_path)
    N, K = 2000, len(cal.leg_names)
    w = rng.normal(scale=20, size=(N, K, 6))
    phi = rng.uniform(-300, 300, size=(N, K))           # unwrapped over many turns
    phi[:50] = cal.legs["L0"].com_phi[rng.integers(0, 24, size=(50, 1))] + 2 * np.pi * rng.integers(-3, 3, size=(50, K))  # grid points
    q = rng.normal(size=(N, 4)) * rng.uniform(0.5, 2, size=(N, 1))  # unnormalised
    q[:5] = [np.cos(np.pi / 4), 0, np.sin(np.pi / 4), 0]             # body x axis vertical: heading undefined
    ref = ground_wrenches(w, phi, quat_to_rotation(q), cal)
    out = fn(w, phi, q)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out, ref, rtol=0, atol=REL_TOL * np.abs(ref).max())


def test_compiled_matches_correct_on_sample_walk(tmp_path):
    sample = require_sample()
    d = json.loads((sample / "truth.json").read_text())
    cal = Calibration.from_json_dict(d, mass_kg=8.18, g=9.81)
    fn = export_and_load(cal, tmp_path)
    rec = recording_from_frame(read_table(sample / "walk.csv"), robot_from_calibration(cal), name="walk", kind="walking")
    ok = np.all(np.isfinite(rec.quat), axis=1)
    rec = rec.select(ok)
    legs = cal.leg_names
    ref = correct_file(cal, sample / "walk.csv")
    ref = np.stack([ref[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy() for k in legs], axis=1)
    out = fn(rec.wrench_array(legs), rec.phi_array(legs), rec.quat)
    assert out.shape == ref.shape and len(out) > 1000
    np.testing.assert_allclose(out, ref, rtol=0, atol=REL_TOL * np.abs(ref).max())


def test_export_cli(tmp_path, capsys):
    rng = np.random.default_rng(3)
    cal = random_calibration(rng, n_legs=2, uniform=True)
    path = tmp_path / "calibration.json"
    cal.save(path)
    out = tmp_path / "c"
    assert export_main([str(path), "-o", str(out), "--name", "legs2"]) == 0
    assert {p.name for p in out.iterdir()} == {"legs2.c", "legs2.h", "USAGE.md", ".ftcal_manifest.json"}
    header = (out / "legs2.h").read_text()
    assert "int legs2_sample(" in header and "LEGS2_N_LEGS 2" in header
    assert "`L0`, `L1`" in (out / "USAGE.md").read_text()
    assert export_main([str(path), "-o", str(out), "--name", "legs2"]) == 2   # no overwrite without --force
    assert "exists" in capsys.readouterr().err
    # a CoM grid with a missing value cannot become a controller's function: named leg and points
    bad = cal.to_json_dict()
    bad["legs"]["L1"]["leg_com_grid"]["xyz"][3] = [None, 0.0, 0.0]
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    assert export_main([str(tmp_path / "bad.json"), "-o", str(tmp_path / "c2")]) == 2
    err = capsys.readouterr().err
    assert "L1" in err and "grid points [3]" in err
