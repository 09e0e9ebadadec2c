"""Report sections of free loads (report/loads.py, issue 22 item 5): the load table with se and truth, measured
and predicted readings over time with the residual, the residual table; through ``run`` and ``write_report``."""

from __future__ import annotations

import numpy as np
import pytest

from ftcal_nlp.config import load_config
from ftcal_nlp.run import run


def _run(tmp_path, kind: str, extra: str = ""):
    (tmp_path / "c.toml").write_text(f'[simulate]\nkind = "{kind}"\ndir = "data"\nseed = 3\nn_orientations = 6\nhold_s = 4.0\n{extra}'
                                     '[output]\ndir = "out"\n[diagnose]\nenabled = false\n')
    return run(load_config(tmp_path / "c.toml"))


@pytest.fixture(scope="module")
def payload_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("payload")
    return tmp, _run(tmp, "payload")


def test_payload_report_has_the_load_table_readings_and_residuals(payload_run) -> None:
    tmp, res = payload_run
    out = tmp / "out"
    md = (out / "report.md").read_text()
    for head in ("## Summary", "## Load of wrist", "## Residuals", "## Stage times"):
        assert head in md
    assert "Free-load fit of wrist" in md and "kept" in md and "dropped" in md     # quasi-static counts in the report
    assert (out / "load_readings_wrist.png").stat().st_size > 10_000 and "load_readings_wrist.png" in md
    assert (out / "report.html").is_file()
    import pandas as pd

    tab = pd.read_csv(out / "load_wrist.csv", index_col=0)
    assert "truth" in tab.columns and "load mass [kg]" in tab.index and "mounting rotation z [deg]" in tab.index
    # the estimate agrees with the truth shown beside it within 4 se (the estimator's own tests check this fully)
    est, se = (float(x) for x in tab.loc["load mass [kg]", "estimate ± se"].split(" ± "))
    assert abs(est - float(tab.loc["load mass [kg]", "truth"])) < 4 * se + 1e-4
    rt = pd.read_csv(out / "load_residuals.csv", index_col=0)
    # quasi-static residual RMS at the simulator's noise (0.02 N, 0.0006 N*m): within 10 %
    noise = np.array([0.02] * 3 + [0.0006] * 3)
    assert np.allclose(rt["rms quasi-static"].to_numpy(), noise, rtol=0.1)
    assert np.all(rt["n quasi-static"] < rt["n all"])


def test_urdf_report_shows_group_truth_and_what_is_undetermined(tmp_path) -> None:
    res = _run(tmp_path, "urdf_leg", "poses_per_orientation = 3\n")
    md = (tmp_path / "out" / "report.md").read_text()
    assert "## Load of r_leg" in md and "not determined by the data" in md and "determined:" in md
    import pandas as pd

    tab = pd.read_csv(tmp_path / "out" / "load_r_leg.csv", index_col=0)
    row = "group r_knee: first moment x [kg mm] (r_shank)"
    est, se = (float(x) for x in tab.loc[row, "estimate ± se"].split(" ± "))
    assert np.isfinite(se) and abs(est - float(tab.loc[row, "truth"])) < 4 * se + 1e-3
    assert "inf" in tab.loc["group r_knee: mass [kg] (r_shank)", "estimate ± se"]     # statics see the total only
    assert res.free_loads is not None
