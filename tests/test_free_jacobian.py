"""The free-load diagnosis' model Jacobian in closed form (``diagnose/free_model.model_jacobian``) equals central
differences of the model readings (``freeload.problem.predict``) in every parameter: offsets, the load's
parameters, the world tilt of the orientation stream (``b = A_n u(tilt)``, where the fit has it) and the mount
rotation ``E expm([r]x)``, on a payload and on a URDF leg (per-sample levers), with and without the tilt; the
diagnosis' face of it (``model_face``, channel blocks) keeps every column the differences show per channel and no zero one."""

import numpy as np
import pytest

from ftcal_nlp.core.data import read_dataset
from ftcal_nlp.diagnose.free_model import context_for, model_face, model_jacobian
from ftcal_nlp.estimate.freeload import fit_free_loads
from ftcal_nlp.estimate.freeload.problem import predict, tilt_gravity
from ftcal_nlp.core.geometry import rotvec_to_rotation
from ftcal_nlp.core.settings import FreeLoadSettings
from ftcal_nlp.sim.free import PayloadConfig, UrdfLegConfig, simulate_free, write_free_load


@pytest.mark.parametrize("cfg", [PayloadConfig(seed=2, n_orientations=8, hold_s=3.0, move_s=2.0),
                                 UrdfLegConfig(seed=2, n_orientations=4, poses_per_orientation=2, hold_s=2.0, move_s=1.0)])
@pytest.mark.parametrize("tilt", [False, True])
def test_the_jacobian_is_the_central_differences(cfg, tilt, tmp_path):
    ds = read_dataset(write_free_load(simulate_free(cfg), tmp_path / "d"))
    leg, fit = next(iter(fit_free_loads(ds, FreeLoadSettings(gravity_tilt=tilt)).legs.items()))
    assert (fit.tilt is not None) == tilt
    ctx, _ = context_for(ds, leg, fit)
    J, names = model_jacobian(ctx, fit)
    b, K, mu, E = ctx.extra["b"], ctx.extra["K"], fit.load.mass_row, fit.rotation
    theta, w_o = np.asarray(fit.theta, float), np.asarray(fit.offset, float)
    p, nt = len(theta), 2 if tilt else 0
    assert J.shape == (ctx.n, 6, 6 + p + nt + 3) and tuple(names) == tuple(fit.names)
    h = 1e-6
    cols = []
    for k in range(6):                                     # offsets
        d = np.zeros(6)
        d[k] = h
        cols.append((predict(b, K, theta, mu, E, w_o + d) - predict(b, K, theta, mu, E, w_o - d)) / (2 * h))
    for k in range(p):                                     # the load's parameters
        d = np.zeros(p)
        d[k] = h * max(1.0, abs(theta[k]))
        cols.append((predict(b, K, theta + d, mu, E, w_o) - predict(b, K, theta - d, mu, E, w_o)) / (2 * d[k]))
    if tilt:                                               # the world tilt: b = A_n u(tilt)
        a, t0 = ctx.extra["a"], np.asarray(fit.tilt, float)
        np.testing.assert_allclose(b, np.einsum("nik,k->ni", a, tilt_gravity(t0)), rtol=0, atol=1e-12)
        for k in range(2):
            d = np.zeros(2)
            d[k] = h
            bp, bm = (np.einsum("nik,k->ni", a, tilt_gravity(t0 + sgn * d)) for sgn in (1, -1))
            cols.append((predict(bp, K, theta, mu, E, w_o) - predict(bm, K, theta, mu, E, w_o)) / (2 * h))
    for a in range(3):                                     # the mount rotation
        d = np.zeros(3)
        d[a] = h
        cols.append((predict(b, K, theta, mu, E @ rotvec_to_rotation(d), w_o)
                     - predict(b, K, theta, mu, E @ rotvec_to_rotation(-d), w_o)) / (2 * h))
    fd = np.stack(cols, axis=-1)
    # central differences of step 1e-6 on readings of O(10 N): rounding ~1e-16 * 10 / 1e-6 = 1e-9; curvature h^2
    np.testing.assert_allclose(J, fd, rtol=0, atol=1e-7 * max(1.0, np.max(np.abs(fd))))
    # the face the diagnosis uses (its channel blocks): every column the differences show on a channel, no zero column
    blocks = {c: (cols, B) for c, cols, B in model_face(ctx, fit).channel_blocks()}
    shown = np.max(np.abs(fd), axis=0) > 1e-7 * max(1.0, np.max(np.abs(fd)))              # (6, P)
    for c in range(6):
        cols, B = blocks[c]
        assert set(np.flatnonzero(shown[c]).tolist()) <= set(cols.tolist())
        assert B.flags.c_contiguous and np.all(np.any(B != 0, axis=0))
