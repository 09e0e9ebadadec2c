"""An effect is one unit (issue 21, item 1): a toy effect declared in one place, registered in a copy of
the registry, goes through simulation, diagnosis and correction without touching any other module.

The toy: every transducer's fz offset drifts at one rate, ``w_fz += r t / 1 h`` (r = 6 N/h). Its unit
declares the injector, a one-parameter standing face ``c_k = w - [0, 0, r t_h, 0, 0, 0]`` (``t_h`` hours
since the hanging reference time, where the hanging offsets absorbed the drift), the hanging face (the
same ramp on each hanging leg's fz) and, being a sensor effect, the default correction (its standing face
evaluated on samples). The diagnosis, given the copy of the registry, must name it among candidates that
do not explain a time ramp, and the joint refit must recover r within 4 of its standard errors.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from ftcal_nlp import CalibrationSettings, DiagnoseSettings, StandingSettings, calibrate
from ftcal_nlp.diagnose import diagnose
from ftcal_nlp.effects.correction import correct_for_effect
from ftcal_nlp.effects import EFFECTS, Effect, EffectInjector, LinearFace, Magnitude, ParamBlock, injector_classes, with_units
from ftcal_nlp.effects.injection import HOUR_S
from ftcal_nlp.sim import EFFECTS as SIM_EFFECTS, SimConfig, simulate
from ftcal_nlp.sim.effects import make_effects

RATE = 6.0          # N per hour of fz drift, every leg
SPEC = {"n_poses": 100, "hanging_cycles": 2.0, "walk_cycles": 1.0, "seed": 21}


class ToyRampInjector(EffectInjector):
    """Every transducer's fz offset drifts linearly on the session clock: ``w_fz += scale t / 1 h``."""

    name = "toy_fz_ramp"
    magnitude = Magnitude("N per hour of fz drift, every leg", (2.0, 8.0), RATE)

    def readings(self, ctx, w):
        out = np.array(w, float, copy=True)
        out[..., 2] += self.scale * np.asarray(ctx.t, float)[:, None] / HOUR_S
        return out


class ToyRamp(Effect):
    name = "toy_fz_ramp"
    kind = "sensor"
    description = "every transducer's fz offset drifts at one rate"
    explains = "time"
    injector_cls = ToyRampInjector
    shifts_offsets = True

    def standing_params(self, ctx):
        return ParamBlock.bounded(("r [N/h]",), 50.0)

    def standing(self, eta, pose, ctx):
        ramp = ca.vertcat(0, 0, eta[0] * pose.t_h, 0, 0, 0)
        return [w - ramp for w in pose.w], None, None

    def hanging_features(self, legs):
        blocks = []
        for l in legs:
            X = np.zeros((len(l.t), 6, 1))
            X[:, 2, 0] = (l.t - l.t_ref) / HOUR_S
            blocks.append(X)
        return LinearFace(blocks, ("r [N/h]",), False)


@pytest.fixture(scope="module")
def toy():
    registry = with_units(ToyRamp())
    injectors = make_effects([{"name": "toy_fz_ramp", "seed": 1}], injectors=injector_classes(registry))
    sim = simulate(SimConfig.from_dict({**SPEC, "effects": list(injectors)}))
    settings = CalibrationSettings(standing=StandingSettings(model="full"), diagnose=DiagnoseSettings(enabled=False))
    run = calibrate(sim.dataset, settings)
    d = diagnose(run.dataset, run.hanging, run.poses, run.calibration, run.dataset.robot,
                 DiagnoseSettings(effects=("casing_load", "hysteresis", "toy_fz_ramp")), model=run.calibration.model,
                 balance=run.standing.balance, registry=registry)
    return registry, sim, run, d


def test_the_registry_copy_holds_the_toy_and_nothing_global_changes(toy):
    registry = toy[0]
    assert "toy_fz_ramp" in registry and list(registry)[: len(EFFECTS)] == list(EFFECTS)
    assert "toy_fz_ramp" not in EFFECTS and "toy_fz_ramp" not in SIM_EFFECTS
    assert registry["toy_fz_ramp"].magnitude is ToyRampInjector.magnitude     # the unit's magnitude is its injector's
    with pytest.raises(ValueError, match="already in the registry"):
        with_units(ToyRamp(), registry=registry)
    with pytest.raises(ValueError, match="unknown effect 'toy_fz_ramp'"):
        make_effects(["toy_fz_ramp"])                                         # the global names never saw it
    with pytest.raises(TypeError, match="kind"):
        with_units(type("Bad", (ToyRamp,), {"kind": "neither"})())


def test_simulated_toy_is_named_refit_and_recovered(toy):
    registry, sim, run, d = toy
    assert sim.truth_json_dict()["effect"] == "toy_fz_ramp"
    assert d.verdict == "effect" and d.effect == "toy_fz_ramp", (d.verdict, d.effect, d.ranking[:3])
    block = d.joint.calibration.meta["effect"]
    assert block["name"] == "toy_fz_ramp"
    r, se = block["eta"][0], float(np.sqrt(block["eta_cov"][0][0]))
    assert 0 < se < 0.1 * RATE
    assert abs(r - RATE) < 4 * se, (r, se)


def test_the_toy_correction_removes_the_ramp_from_a_walk(toy):
    registry, sim, run, d = toy
    cal = d.joint.calibration
    block = cal.meta["effect"]
    rec = sim.dataset.walking[0]
    legs = cal.leg_names
    w = rec.wrench_array(legs)
    phi = np.stack([rec.phi[k] for k in legs], axis=1)
    R = np.broadcast_to(np.eye(3), (len(rec.t), 3, 3)).copy()
    w2, R2, cov = correct_for_effect(cal, w, phi, R, rec.t, registry=registry)
    t_h = (rec.t - block["t_ref_s"]) / HOUR_S
    expect = w.copy()
    expect[..., 2] -= block["eta"][0] * t_h[:, None]
    assert np.allclose(w2, expect, atol=1e-9) and np.array_equal(R2, R)
    # the rate's uncertainty carried to the corrected fz (first order), nothing else
    var = block["eta_cov"][0][0] * t_h**2
    assert np.allclose(cov[..., 2, 2], var[:, None], rtol=1e-9)
    assert np.allclose(np.delete(cov.reshape(len(t_h), len(legs), 36), 14, axis=2), 0.0)
    # what the ramp leaves after the correction, against the hanging offsets (which hold at t_ref): (r_true - r) t_h
    left = np.abs((RATE - block["eta"][0]) * t_h).max()
    assert left < 4 * np.sqrt(block["eta_cov"][0][0]) * np.abs(t_h).max()
    with pytest.raises(ValueError, match="not an effect of the library"):
        correct_for_effect(cal, w, phi, R, rec.t)       # the global registry does not know the toy


def test_a_units_kind_decides_its_correction():
    """Each unit's own correction: a body effect (cable, mass, leg inertia, moving CoMs) leaves per-foot readings and
    orientations as they are and adds no covariance; the sensor effects and the motion-capture bias change them."""
    from ftcal_nlp.core.calibration import Calibration

    sim = simulate(SimConfig.from_dict({"n_poses": 12, "hanging_cycles": 0.5, "walk_cycles": 0.2, "seed": 3}))
    truth = sim.truth
    legs = truth.leg_names
    rng = np.random.default_rng(0)
    N, K = 9, len(legs)
    w, phi = rng.normal(size=(N, K, 6)), rng.uniform(0, 2 * np.pi, (N, K))
    R, t = np.broadcast_to(np.eye(3), (N, 3, 3)).copy(), np.linspace(0, 3600.0, N)
    changed = {}
    for name, unit in EFFECTS.items():
        eta = rng.normal(size=200)
        meta = {"effect": {"name": name, "eta": list(eta), "t_ref_s": 0.0, "eta_cov": np.eye(200).tolist(),
                           "parameters": {f"hanging:{k}.fz/h": {"value": 1.0, "se": 0.1} for k in legs},
                           "R_nominal": np.asarray(sim.dataset.robot.nominal_rotations()).tolist()}}
        cal = Calibration(truth.legs, truth.mass_kg, truth.g, truth.model, truth.com_body_m, meta)
        w2, R2, cov = correct_for_effect(cal, w, phi, R, t)
        changed[name] = not (np.array_equal(w2, w) and np.array_equal(R2, R))
        if unit.kind == "body" and name != "mocap_bias":
            assert not changed[name] and cov is None, name
    # (the free-load effects of issue 23 correct a hexapod's readings only with parameters of their own: none here)
    assert changed["mocap_bias"] and all(changed[n] for n, u in EFFECTS.items()
                                         if u.kind == "sensor" and n != "hysteresis" and "hexapod" in u.diagnosed_on)
    assert {n for n, u in EFFECTS.items() if u.kind == "body"} == {"tether_force", "robot_mass", "mocap_bias", "leg_inertia",
                                                                    "moving_com"}


def test_diagnosed_on_says_which_faces_a_unit_has():
    """``diagnosed_on`` holds "free" exactly for the units with a free-load face (``free_shapes`` overridden) and
    "hexapod" for those with a hexapod face (a standing face, a linear hanging / swing face or the design face);
    the hexapod diagnosis' candidates are those (``attribute.hexapod_candidates``), the rest are not ranking rows."""
    from ftcal_nlp.diagnose.attribute import hexapod_candidates

    for name, u in EFFECTS.items():
        free = type(u).free_shapes is not Effect.free_shapes
        hexa = any(getattr(type(u), f) is not getattr(Effect, f)
                   for f in ("standing_params", "standing", "hanging_features", "swing_features", "standing_balance")) or u.design_face
        assert ("free" in u.diagnosed_on) == free, name
        assert ("hexapod" in u.diagnosed_on) == hexa, name
    assert "free" in EFFECTS["offset_drift"].diagnosed_on
    names = [u.name for u in hexapod_candidates(list(EFFECTS.values()))]
    assert names == [n for n, u in EFFECTS.items() if "hexapod" in u.diagnosed_on] and "clock_offset" not in names
