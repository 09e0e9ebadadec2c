"""The exact symmetries of the in-situ sensor matrix held at the factory value (``estimate/freeload/sensor_matrix.py``,
``gauge``).

Without a weighed mass, scaling the force block ``C_ff -> a C_ff`` with the load's mass ``M -> a M`` leaves every
model reading ``o + C^-1 w`` unchanged: a curve, which the linearised tiny ridge did not hold (on a real iCub foot
recording the force block fell to 0.0016 and the mass to -0.11 kg). Checked on a simulated payload whose raw
readings are ``A`` times the factory-calibrated ones (``A = I + E``, ``E`` ~ N(0, 2 %), as ``test_sensor_matrix.py``):
the force block's scale stays exactly at the factory value (trace of ``C_ff`` = 3), the mass is then the true mass
times ``3 / tr(A^-1_ff)`` (the true correction ``A^-1`` brought to that scale) within the noise, and the fit ends at
the same point from any start along the curve (it ended wherever the start put it: 2 % apart). With ``"full"`` the
torque scale, the common rotation of both diagonal blocks and the skew part of ``C_tf`` are held as well; a weighed
mass holds nothing (the scale is then fitted: ``test_sensor_matrix.py::test_weighed_mass_determines_the_scale``).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from ftcal_nlp.core.settings import FreeLoadSettings
from ftcal_nlp.estimate.freeload import fit_free_loads
from ftcal_nlp.estimate.freeload import sensor_matrix as smx
from ftcal_nlp.estimate.freeload.estimate import free_load_data

from test_sensor_matrix import dataset as _dataset, gain

Z = 4.0          # tolerance in sd of the noise-limited mass
EXACT = 1e-12    # "exactly": rounding


def dataset(tmp_path_factory, seed: int, A: np.ndarray, weigh: bool = False):
    """``test_sensor_matrix.dataset``'s payload (10 orientations held 4 s) read through ``A``."""
    return _dataset(tmp_path_factory, "payload", seed, A, weigh)


def combos(sm) -> dict[str, dict]:
    return {c["combination"].split(".C.")[1]: c for c in sm.combinations}


@pytest.fixture(autouse=True)
def _quiet():
    logging.disable(logging.WARNING)
    yield
    logging.disable(logging.NOTSET)


def test_force_scale_held_exactly_without_weighed_mass(tmp_path_factory):
    A = gain(3)
    ds, sim, leg = dataset(tmp_path_factory, 3, A)
    r = fit_free_loads(ds, FreeLoadSettings(sensor_matrix="force")).legs[leg]
    sm = r.sensor_matrix
    assert np.isfinite(sm.ridge.chosen)                      # a matrix was fitted (2 % gain error: 6-20x the noise)
    c = combos(sm)["force.scale"]
    assert not c["determined"] and abs(c["value"]) < EXACT, c
    assert abs(np.trace(sm.C[:3, :3]) - 3.0) < EXACT
    assert any("exactly: force.scale" in n for n in sm.notes), sm.notes
    # the load took the scale: the true correction A^-1 brought to the factory scale, the mass with it; the noise
    # limit of the mass from the forces is sigma_f / (g sqrt(3 n))
    Ci = np.linalg.inv(A)
    expected = sim.truth["mass_kg"] * 3.0 / np.trace(Ci[:3, :3])
    sd = sim.config.noise_force_N / (sim.config.g * np.sqrt(3 * r.n_used))
    assert abs(r.load_report()["load_mass_kg"] - expected) < Z * sd, (r.load_report()["load_mass_kg"], expected, sd)
    # and the rest of the force block is the truth's at that scale (the residual at the noise floor)
    assert np.all(sm.rms[:3] < 1.1 * sim.config.noise_force_N)


def test_the_fit_does_not_depend_on_where_on_the_scale_curve_it_starts(tmp_path_factory):
    """Gauss-Newton (ridge 0) from the plain fit with the load's parameters scaled by 0.8, 1.25 and -1 (the same
    readings with C_ff scaled alike): one optimum, at the factory scale."""
    A = gain(1)
    ds, _sim, leg = dataset(tmp_path_factory, 1, A)
    s = FreeLoadSettings(sensor_matrix="force")
    base = fit_free_loads(ds, FreeLoadSettings()).legs[leg]
    data = free_load_data(ds, leg, s, base.load)
    pr = smx.Problem(data.y, data.a, data.group, data.K, np.asarray(base.load.mass_row, float), smx.pairs_of("force"),
                     True)
    W = 1.0 / np.asarray(base.sigma, float) ** 2
    tilt = np.zeros((len(data.groups), 2))
    B, held = smx.gauge(pr, smx.State(base.offset, base.theta, tilt, base.rotation, np.zeros(9)), W)
    assert held == ("force.scale",) and B.shape == (9, 8)
    pr = dataclasses.replace(pr, gauge=B, held=held)
    ends = []
    for f in (1.0, 0.8, 1.25, -1.0):
        start = smx.State(base.offset.copy(), f * base.theta, tilt.copy(), base.rotation.copy(), np.zeros(9))
        st = smx.solve(pr, start, W, 0.0, s.prior_weight)
        C = st.C(pr.pairs)
        assert abs(np.trace(C[:3, :3]) - 3.0) < EXACT
        ends.append((float(pr.mu @ st.theta), C))
    for M, C in ends[1:]:
        assert abs(M - ends[0][0]) < 1e-6 * abs(ends[0][0]) and np.allclose(C, ends[0][1], rtol=0, atol=1e-6), (M, ends[0][0])


def test_full_matrix_holds_every_exact_symmetry(tmp_path_factory):
    A = gain(5, full=True)
    ds, sim, leg = dataset(tmp_path_factory, 5, A)
    sm = fit_free_loads(ds, FreeLoadSettings(sensor_matrix="full")).legs[leg].sensor_matrix
    assert np.isfinite(sm.ridge.chosen)
    c = {k: v["value"] for k, v in combos(sm).items()}
    held = [c["force.scale"], c["torque.scale"]] + [c[f"force.rotation.{a}"] + c[f"torque.rotation.{a}"] for a in "xyz"] \
        + [c[f"torque_from_force.skew.{a}"] for a in "xyz"]
    assert np.all(np.abs(held) < EXACT), held
    assert np.all(sm.rms < 1.1 * np.r_[[sim.config.noise_force_N] * 3, [sim.config.noise_torque_Nm] * 3])


def test_weighed_mass_holds_nothing(tmp_path_factory):
    A = gain(4)
    ds, _sim, leg = dataset(tmp_path_factory, 4, A, weigh=True)
    sm = fit_free_loads(ds, FreeLoadSettings(sensor_matrix="force")).legs[leg].sensor_matrix
    assert not any("exactly" in n for n in sm.notes)
    c = combos(sm)["force.scale"]
    assert c["determined"] and abs(c["value"] - (np.trace(np.linalg.inv(A)[:3, :3]) / 3 - 1)) < Z * c["se"], c
