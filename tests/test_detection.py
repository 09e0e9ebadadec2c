"""Detection size of the library effects (ftcal_nlp.plan.detection, ``python -m ftcal_nlp.plan``).

Scaling law: the diagnosis compares held-out residuals with a noise floor, and the residual an
effect leaves does not depend on the noise (the paired runs cancel it). Halving every noise source
(transducer, motion-capture jitter and per-pose error) halves every floor (readings, motion capture,
the calibration's own error: each is linear in the noise), so the hanging kind's detection size
halves (a casing load's force cannot be taken up by the hanging model, whatever its smoothing). On
the standing kind the CoM smoothing the GCV picks follows the noise and changes what the curve
takes up of a shaft-angle effect, so only bounds hold there. The power equation (D4) is checked on its own:
the size it returns has the asked power, and with one realisation and no noise it is
``sqrt(threshold / a)``.
"""

import json
from dataclasses import replace

import numpy as np
import pytest

from ftcal_nlp.plan.detection import POWER, power_at, size_at_power, threshold
from ftcal_nlp.plan import Protocol, main as plan_main, predict

SMALL = Protocol(hanging_turns=2.0, turn_s=10.0, rate_hz=50.0, n_poses=40)
EFFECT = "casing_load"   # seen by both kinds on this protocol
TOL_FLOOR = 0.05         # the standing floor's REML motion-capture term is re-estimated from other noise draws


def test_power_equation():
    la = np.log([30.0, 80.0, 200.0])
    s = size_at_power(la, 0.5, 0.05, 6 * 200)
    assert power_at(s, la, 0.5, 0.05, 6 * 200) == pytest.approx(POWER, abs=1e-6)
    assert power_at(2 * s, la, 0.5, 0.05, 6 * 200) > POWER > power_at(s / 2, la, 0.5, 0.05, 6 * 200)
    assert size_at_power(np.log([40.0]), 0.1, 0.0, 1e12) == pytest.approx(np.sqrt(0.1 / 40.0), rel=1e-4)
    assert threshold("standing", 40) == pytest.approx(4 * np.sqrt(2 / 40)) and threshold("standing", 729) == 0.5


def test_detection_size_halves_with_the_noise(tmp_path, capsys):
    proto = tmp_path / "protocol.toml"
    proto.write_text("\n".join(f"{k} = {v!r}" for k, v in
                               {"hanging_turns": 2.0, "turn_s": 10.0, "rate_hz": 50.0, "n_poses": 40}.items()) + "\n")
    out = tmp_path / "plan.json"
    assert plan_main([str(proto), "-o", str(out), "--detect", EFFECT]) == 0
    assert EFFECT in capsys.readouterr().out
    js1 = json.loads(out.read_text())["detection"]
    d1 = js1["effects"][EFFECT]
    assert d1["kind"] in ("standing", "hanging") and d1["unit"].startswith("N")
    per1 = d1["per_kind"]
    assert all(v is not None and v > 0 for v in per1.values()), per1
    assert d1["size"] == min(per1.values()) and d1["vs_realistic"] in ("below", "inside", "above")

    quiet = replace(SMALL, noise_force_N=SMALL.noise_force_N / 2, noise_torque_Nm=SMALL.noise_torque_Nm / 2,
                    mocap_pose_deg=SMALL.mocap_pose_deg / 2, mocap_jitter_deg=SMALL.mocap_jitter_deg / 2)
    det2 = predict(quiet, detection=(EFFECT,)).detection
    d2 = det2.sizes[0]
    np.testing.assert_allclose(det2.floors.standing / np.array(js1["floor"]["standing"]), 0.5, rtol=TOL_FLOOR)
    np.testing.assert_allclose(det2.floors.hanging / np.array(js1["floor"]["hanging"]), 0.5, rtol=1e-12)
    assert d2.per_kind["hanging"] / per1["hanging"] == pytest.approx(0.5, rel=TOL_FLOOR)
    # standing: the floor halves, the signal per size^2 can only drop (relatively less smoothing of the CoM
    # curve, which then takes up more of a shaft-angle effect): at least half, and smaller than before
    assert 0.5 * (1 - TOL_FLOOR) <= d2.per_kind["standing"] / per1["standing"] < 1.0


def test_unknown_effect_is_refused_before_simulating(tmp_path, capsys):
    assert plan_main(["-o", str(tmp_path / "p.json"), "--detect", "tether"]) == 2
    assert "unknown effect 'tether'" in capsys.readouterr().err


def test_free_load_effects_are_not_predicted_on_a_hexapod():
    det = predict(SMALL, detection=("inertial_load", "clock_offset")).detection
    assert [d.effect for d in det.sizes] == ["inertial_load", "clock_offset"]
    assert all(d.size == float("inf") and "no hexapod face" in d.note for d in det.sizes)
