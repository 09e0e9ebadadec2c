"""The vectorised numpy correction equals its textbook form (speed must not change results).

``periodic_interp`` against ``np.interp`` column by column on the grid extended by
one period; ``ground_wrenches`` against eq. 3 and the wrench map written leg by
leg with ``transform_wrench``. Only rounding may separate them: the interval
fraction from ``phi G / 2pi`` instead of ``mod(phi, 2pi)`` costs ~|phi| eps.
"""

import numpy as np
import pytest

from ftcal_nlp.core.calibration import periodic_interp
from ftcal_nlp.core.geometry import quat_to_rotation, remove_yaw, transform_wrench
from ftcal_nlp.core.physics import ground_wrenches, gravity_dir_in_ft, leg_gravity_wrench, total_com_from_body_com

from test_export import random_calibration

EPS = np.finfo(float).eps


def interp_by_column(phi, grid, values):
    x = np.mod(phi, 2 * np.pi)
    xp = np.r_[grid, grid[0] + 2 * np.pi]
    return np.stack([np.interp(x, xp, np.r_[values[:, j], values[0, j]]) for j in range(values.shape[1])], axis=-1)


@pytest.mark.parametrize("grid_kind", ["uniform", "uniform_shifted", "random"])
@pytest.mark.parametrize("missing", [False, True])
def test_periodic_interp_is_np_interp(grid_kind, missing):
    rng = np.random.default_rng(7)
    G, K = 36, 3
    grid = {"uniform": np.linspace(0, 2 * np.pi, G, endpoint=False),
            "uniform_shifted": np.linspace(0.1, 2 * np.pi + 0.1, G, endpoint=False),
            "random": np.sort(rng.uniform(0.3, 6.2, G))}[grid_kind]
    values = rng.normal(size=(K, G, 3))
    if missing:
        values[1, 4, 2] = np.nan
    phi = np.concatenate([rng.uniform(-100, 100, (500, K)), grid[:, None] + 2 * np.pi * rng.integers(-2, 3, (G, K)), [[-1e-300] * K, [np.nan] * K]])
    ref = np.stack([interp_by_column(phi[:, k], grid, values[k]) for k in range(K)], axis=1)
    out = periodic_interp(phi, grid, values)
    assert out.shape == ref.shape
    np.testing.assert_array_equal(np.isnan(out), np.isnan(ref))
    tol = 4 * EPS * (np.nanmax(np.abs(phi)) + 2 * np.pi) * G / (2 * np.pi) * np.nanmax(np.abs(np.diff(values, axis=1))) + 4 * EPS * np.nanmax(np.abs(values))
    np.testing.assert_allclose(out, ref, rtol=0, atol=tol)
    np.testing.assert_allclose(periodic_interp(phi[:, 0], grid, values[0]), ref[:, 0], rtol=0, atol=tol)


def ground_wrenches_textbook(w_m, phi, R_WB, cal):
    """physics.ground_wrenches as first written: eq. 3 per leg, then transform_wrench to the heading frame."""
    offsets, weights, rotations, p_prime = cal.stacked()
    R_HB = remove_yaw(R_WB)
    u = gravity_dir_in_ft(R_WB[:, None], rotations[None])
    r = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(cal.leg_names)], axis=1)
    w_gc = w_m - offsets - leg_gravity_wrench(u, r, weights)
    c_tot = total_com_from_body_com(phi, cal)
    R = np.einsum("nij,kjl->nkil", R_HB, rotations)
    p = np.einsum("nij,nkj->nki", R_HB, p_prime[None] - c_tot[:, None])
    return transform_wrench(R, p, w_gc)


@pytest.mark.parametrize("uniform", [False, True])
def test_ground_wrenches_is_textbook_form(uniform):
    rng = np.random.default_rng(5)
    cal = random_calibration(rng, n_legs=5, uniform=uniform)
    N = 5000  # more than one block
    w = rng.normal(scale=20, size=(N, 5, 6))
    phi = rng.uniform(-50, 50, size=(N, 5))
    R = quat_to_rotation(rng.normal(size=(N, 4)))
    ref = ground_wrenches_textbook(w, phi, R, cal)
    np.testing.assert_allclose(ground_wrenches(w, phi, R, cal), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
