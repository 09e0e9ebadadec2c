"""The temperature part of a free-load plan (plan/temperature.py, issue 32 item 4): the se of the temperature
coefficients from the Fisher information of [offset, beta] with the regressor [1, T - T_ref] recovers the analytic
se of a linear ramp, ``sigma / sqrt(sum (T - Tbar)^2)``, widened by the serial factor; the range needed for a target
brings the se to it; a temperature that never varies leaves the coefficients undetermined; ``plan`` writes them to
plan.json and its text for a protocol stating ``temperature_range_C``; a hexapod takes no --temperature-target. And
the run's warning on a temperature column that never varies (freeload/plausibility.check_temperature_varies)."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from ftcal_nlp.plan.command import main as plan_main
from ftcal_nlp.plan.temperature import (TEMPERATURE_SPAN_C, coefficient_se, ramp_range, targets,
                                        temperature_plan)

NOISE = np.array([0.05, 0.05, 0.05, 0.003, 0.003, 0.003])


@pytest.mark.parametrize("n,span,t0", [(100, 5.0, 20.0), (4000, 0.5, 35.0), (7, 12.0, -5.0)])
def test_linear_ramp_recovers_the_analytic_se(n, span, t0):
    T = t0 + np.linspace(0.0, span, n)
    se = coefficient_se(T, NOISE)
    analytic = NOISE / np.sqrt(np.sum((T - T.mean()) ** 2))
    assert np.allclose(se, analytic, rtol=1e-9)
    # closed form of an equally spaced ramp, and the reference temperature does not matter
    assert np.allclose(se, NOISE * np.sqrt(12.0 * (n - 1) / (n * (n + 1))) / span, rtol=1e-9)
    assert np.allclose(coefficient_se(T + 40.0, NOISE), se, rtol=1e-6)
    # the serial widening multiplies the se (the run weighs by 1 / (s^2 k))
    w = np.array([1.0, 2.0, 3.0, 1.5, 1.0, 8.0])
    p = temperature_plan(T, NOISE, w, profile="linear ramp")
    assert np.allclose(p.se, analytic * w, rtol=1e-9)
    # the same against a brute-force Fisher information of [offset, beta] with the regressor [1, T - 25]
    A = np.c_[np.ones(n), T - 25.0]
    brute = NOISE * np.sqrt(np.linalg.inv(A.T @ A)[1, 1])
    assert np.allclose(se, brute, rtol=1e-6)


def test_range_needed_brings_the_se_to_the_target():
    rng = np.random.default_rng(3)
    n = 3000
    # a pilot's profile: a warm-up and a swing (not a ramp); the needed range scales it
    t = np.arange(n) / 100.0
    T = 25 + 3 * (1 - np.exp(-t / 10)) + 0.2 * np.sin(2 * np.pi * t / 7) + rng.normal(0, 0.01, n)
    p = temperature_plan(T, NOISE, target_force=1e-4)
    Tn = T.mean() + (T - T.mean()) * p.needed_range_C / p.range_C
    assert np.isclose(np.max(coefficient_se(Tn, NOISE) / p.target), 1.0, rtol=1e-9)
    # torques the same multiple of their noise as the forces
    assert np.allclose(p.target, 1e-4 * NOISE / 0.05)
    # default target: the noise over a 10 degC working range
    tgt, src = targets(NOISE, None)
    assert np.allclose(tgt, NOISE / TEMPERATURE_SPAN_C) and "10 degC" in src


@pytest.mark.parametrize("T", [np.full(500, 27.3), 27.3 + 0.004 * (np.arange(500) % 2)])
def test_a_temperature_that_never_varies_is_not_determined(T):
    p = temperature_plan(T, NOISE, target_force=2e-3)
    assert not p.determined and np.all(np.isinf(p.se))
    assert "cannot be told from the offsets" in "\n".join(p.text())
    # the range needed: a linear ramp over the same samples meeting the target
    assert p.needed_range_C == pytest.approx(ramp_range(500, NOISE, p.target))
    ramp = np.linspace(0.0, p.needed_range_C, 500)
    assert np.max(coefficient_se(ramp, NOISE) / p.target) == pytest.approx(1.0, rel=1e-9)
    assert json.loads(json.dumps(p.to_json_dict()))["se"]["fx.dT [N/degC]"] is None


def test_plan_of_a_protocol_with_a_temperature_range(tmp_path, capsys):
    proto = tmp_path / "holds.toml"
    proto.write_text('[protocol]\nkind = "payload"\nn_orientations = 10\nhold_s = 4.0\nrate_hz = 50.0\n'
                     'noise_force_N = 0.05\nnoise_torque_Nm = 0.003\ntemperature_range_C = 3.0\n')
    assert plan_main([str(proto), "-o", str(tmp_path / "plan.json"), "--temperature-target", "0.001"]) == 0
    out = capsys.readouterr().out
    assert "temperature (linear ramp, range 3 degC over 2000 samples)" in out and "range needed" in out
    t = json.loads((tmp_path / "plan.json").read_text())["transducers"]["payload"]["temperature"]
    n = 10 * 200
    analytic = NOISE * np.sqrt(12.0 * (n - 1) / (n * (n + 1))) / 3.0
    assert np.allclose(list(t["se"].values()), analytic, rtol=1e-9)
    assert t["target"]["fx.dT [N/degC]"] == pytest.approx(0.001)
    assert t["needed_range_C"] == pytest.approx(3.0 * np.max(analytic / np.array(list(t["target"].values()))))
    # without the key: no temperature part
    proto.write_text('[protocol]\nkind = "payload"\nn_orientations = 10\n')
    assert plan_main([str(proto), "-o", str(tmp_path / "plan2.json"), "-q"]) == 0
    assert json.loads((tmp_path / "plan2.json").read_text())["transducers"]["payload"]["temperature"] is None


def test_bad_temperature_keys_are_named(tmp_path, capsys):
    proto = tmp_path / "holds.toml"
    proto.write_text('[protocol]\nkind = "payload"\nn_orientations = 4\ntemperature_range_C = "5 degC"\n')
    assert plan_main([str(proto), "-o", str(tmp_path / "p.json"), "-q"]) != 0
    assert "temperature_range_C" in capsys.readouterr().err
    assert plan_main(["-o", str(tmp_path / "h.json"), "--temperature-target", "0.001", "--no-detection", "-q"]) != 0
    assert "hexapod" in capsys.readouterr().err


# ----------------------------------------------------------------------------- the run: a temperature that never varies


def test_constant_temperature_column_is_named_at_run_time(tmp_path, caplog, capsys):
    from ftcal_nlp.run import main as run_main
    from ftcal_nlp.sim.free import PayloadConfig, simulate_payload, write_free_load

    sim = simulate_payload(PayloadConfig(seed=5, n_orientations=8, hold_s=4.0, move_s=2.0))
    man = write_free_load(sim, tmp_path / "data")
    csv = tmp_path / "data" / "wrist.csv"
    import pandas as pd

    f = pd.read_csv(csv)
    f["wrist_temp_C"] = 27.25 + 0.005 * (np.arange(len(f)) % 2)     # a sensor at its resolution: never varies
    f.to_csv(csv, index=False)
    (tmp_path / "run.toml").write_text(f'[data]\nmanifest = "{man}"\n[output]\ndir = "{tmp_path / "out"}"\n'
                                       "[diagnose]\nenabled = true\n")
    with caplog.at_level(logging.WARNING):
        assert run_main([str(tmp_path / "run.toml"), "-q"]) == 0
    msg = [r.getMessage() for r in caplog.records if "wrist_temp_C" in r.getMessage()]
    assert msg and "cannot be told from the offsets" in msg[0] and "does not determine 'temperature'" in msg[0]
    diag = json.loads((tmp_path / "out" / "diagnosis.json").read_text())["free_loads"]["wrist"]
    assert not (tmp_path / "out" / "calibration_with_effect.json").exists() or "temperature" not in json.dumps(
        json.loads((tmp_path / "out" / "calibration_with_effect.json").read_text())["meta"]["effect"])
    assert diag is not None
    # plan on it as a pilot: the same warning, and the coefficients not determined with the range a ramp would need
    from ftcal_nlp.core.data import read_dataset
    from ftcal_nlp.plan.free_load import plan_from_dataset

    caplog.clear()
    with caplog.at_level(logging.WARNING):
        t = plan_from_dataset(read_dataset(man), temperature_target=1e-3).loads["wrist"].temperature
    assert any("wrist_temp_C" in r.getMessage() for r in caplog.records)
    assert not t.determined and t.range_C == pytest.approx(0.005)
    assert t.needed_range_C == pytest.approx(ramp_range(t.n_samples, t.noise * t.widening, t.target))
    # 0.02 N sqrt(12 / 3203 samples) / (1e-3 N/degC) = 1.2 degC
    assert 1.0 < t.needed_range_C < 1.5 and "cannot be told from the offsets" in "\n".join(t.text())
    # a column without any number is the reader's error, naming it
    f["wrist_temp_C"] = np.nan
    f.to_csv(csv, index=False)
    capsys.readouterr()
    assert run_main([str(tmp_path / "run.toml"), "-q", "--force"]) != 0
    err = capsys.readouterr().err
    assert "wrist.csv" in err and "'wrist_temp_C'" in err and "no finite value" in err, err


def test_check_temperature_varies_on_recordings():
    from types import SimpleNamespace

    from ftcal_nlp.estimate.freeload.plausibility import check_temperature_varies

    rec = lambda name, T: SimpleNamespace(name=name, temperature={"wrist": np.asarray(T, float)})  # noqa: E731
    assert check_temperature_varies([rec("a", np.linspace(20, 21, 50))], "wrist") is None
    assert check_temperature_varies([rec("a", np.full(50, 20.0))], "elbow") is None        # no temperature: silent
    # each recording constant, at another temperature: the session varies
    assert check_temperature_varies([rec("a", np.full(50, 20.0)), rec("b", np.full(50, 24.0))], "wrist") is None
    msg = check_temperature_varies([rec("a", np.full(50, 20.0)), rec("b", np.full(50, 20.004))], "wrist")
    assert "'wrist_temp_C'" in msg and "['a', 'b']" in msg and "collinear" in msg
