"""The diagnosis' cost bench (issue 23, item 6; ``bench/speed.py`` ``run_diagnosis_ratio``, part ``diagnosis_ratio``):
on small problems it times ``calibrate()`` with and without the diagnosis on both kinds (the payload clean and with
two effects injected), states the ratio and writes its table. A benchmark, not a timed test: no bound on the measured times here."""

import numpy as np

from ftcal_nlp.bench import report
from ftcal_nlp.bench.speed import DIAGNOSIS_RATIO_TARGET, DiagnosisRatioSettings, run_diagnosis_ratio


def test_diagnosis_ratio_rows_on_small_problems(tmp_path):
    s = DiagnosisRatioSettings(repeats=1, hexapod_sim={"hanging_cycles": 1.5, "n_poses": 60, "walk_cycles": 0.5},
                               payload_samples=5_000)
    dr = run_diagnosis_ratio(s, progress=False)
    t = dr["times"]
    assert list(t.problem) == ["hexapod", "payload", "payload_effects"]
    assert list(t.injected) == ["", "", "creep + clock_offset"]
    assert np.all(t.without_s > 0) and np.all(t.with_s > 0) and np.all(t.diagnosis_s > 0)
    np.testing.assert_allclose(t.ratio, t.diagnosis_s / t.without_s)
    np.testing.assert_allclose(t.ratio_whole, t.with_s / t.without_s)
    assert np.all(t.without_cpu_s > 0) and np.all(t.diagnosis_cpu_s > 0)          # CPU time beside the wall clock
    np.testing.assert_allclose(t.ratio_cpu, t.diagnosis_cpu_s / t.without_cpu_s)
    assert np.all(t.target == DIAGNOSIS_RATIO_TARGET)
    assert set(t.verdict) <= {"none", "effect", "unexplained"}   # the diagnosis ran on both kinds
    # the payload of ~5000 samples (the load-speed bench's schedule), clean and with the two effects
    assert abs(int(t.samples[t.problem == "payload"].iloc[0]) - 5_000) < 500
    assert int(t.samples[t.problem == "payload_effects"].iloc[0]) == int(t.samples[t.problem == "payload"].iloc[0])
    text = report.write_all(tmp_path, None, None, None, None, "tiny", diagnosis_ratio=dr)
    assert "### The diagnosis' cost" in text and (tmp_path / "speed_diagnosis_ratio.csv").is_file()
