"""``export`` of free-load calibrations (export/free.py, issue 22 item 5): the generated C, compiled, gives the
contact wrench that ``correct`` computes (numpy, correct/free.py) for a wrist payload and for the leg4 URDF load,
sample by sample, to rounding."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from ftcal_nlp import export
from ftcal_nlp.config import load_config
from ftcal_nlp.correct import contact_frame
from ftcal_nlp.correct.calibrated import payload_calibrations
from ftcal_nlp.export import ExportedFiles, compile_shared, load_compiled
from ftcal_nlp.export.free import joint_order
from ftcal_nlp.run import run

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
needs_cc = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler")

SIMS = {
    "payload": ('kind = "payload"\nseed = 5\nn_orientations = 6\nhold_s = 3.0\n', "wrist"),
    "urdf_leg": ('kind = "urdf_leg"\nseed = 5\nn_orientations = 5\nposes_per_orientation = 2\nhold_s = 3.0\nmove_s = 2.0\n', "leg"),
}


@needs_cc
@pytest.mark.parametrize("kind", list(SIMS))
def test_exported_c_is_the_correction(kind, tmp_path, capsys) -> None:
    table, rec_name = SIMS[kind]
    (tmp_path / "c.toml").write_text(f'[simulate]\n{table}dir = "data"\n[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    run(load_config(tmp_path / "c.toml"))
    cal = tmp_path / "out" / "calibration.json"
    assert export.main([str(cal), "-o", str(tmp_path / "c"), "--name", "contact"]) == 0
    assert "contact.c" in capsys.readouterr().out
    cals = payload_calibrations(cal)
    legs, joints = list(cals), joint_order(cals)
    assert (len(joints) == 6) == (kind == "urdf_leg")              # leg4: two hip joints above the sensor, four below
    lib = compile_shared(ExportedFiles(tmp_path / "c" / "contact.c", tmp_path / "c" / "contact.h", tmp_path / "c" / "USAGE.md"))
    fn = load_compiled(lib, cals, "contact")
    df = pd.read_csv(tmp_path / "data" / f"{rec_name}.csv")
    rng = np.random.default_rng(0)
    cols = [f"{k}_{c}" for k in legs for c in WRENCH]
    df[cols] += rng.normal(size=(len(df), len(cols)))               # contacts of a few N: the correction is linear in them
    expect = contact_frame(cals, df, "rec")[cols].to_numpy().reshape(len(df), len(legs), 6)
    q = df[[f"q_{j}" for j in joints]].to_numpy() if joints else None
    got = fn(df[cols].to_numpy(), q, df[["qw", "qx", "qy", "qz"]].to_numpy())
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-9 * max(1.0, np.abs(df[cols].to_numpy()).max()))
    usage = (tmp_path / "c" / "USAGE.md").read_text()
    assert "contact wrench" in usage and all(f"`{j}`" in usage for j in joints)
    assert export.main([str(cal), "-o", str(tmp_path / "c"), "--name", "contact"]) == 2      # exists, no --force
