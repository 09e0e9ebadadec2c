"""The free-load face protocol (effects/free_faces.py) and its worked example, offset_drift."""

import numpy as np
import pytest

from ftcal_nlp.effects import EFFECTS
from ftcal_nlp.effects.free_faces import FreeFace, body_rate, holds, load_history, make_context


def _ctx(seed=0, n=2000, sd=0.05):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 600.0, n)
    pred = np.zeros((n, 6))
    pred[:, 2] = 10.0 * np.cos(t / 60.0)
    still = (np.arange(n) // 100) % 2 == 0
    return rng, t, pred, still, sd


def test_offset_drift_free_face_recovers_a_legendre_drift():
    rng, t, pred, still, sd = _ctx()
    n = len(t)
    tau = 2 * t / t[-1] - 1
    true = np.zeros((n, 6))
    true[:, 0] = 0.8 * tau            # P1 on fx
    true[:, 5] = 0.05 * 0.5 * (3 * tau**2 - 1)   # P2 on tz
    y = pred + true + rng.normal(0, sd, (n, 6))
    ctx = make_context("s", t, y, pred, np.tile([0, 0, -9.81], (n, 1)), still=still)
    unit = EFFECTS["offset_drift"]
    shapes = unit.free_shapes(ctx)
    assert {"degree": 2} in shapes
    face = unit.free_face(ctx, {"degree": 2})
    assert isinstance(face, FreeFace) and face.X.shape == (n, 6, 12)
    # linear least squares with the offsets (constant per channel) beside the face
    A = np.concatenate([np.broadcast_to(np.eye(6), (n, 6, 6)), face.X], axis=2).reshape(6 * n, -1)
    r = (y - pred).reshape(-1)
    beta, *_ = np.linalg.lstsq(A, r, rcond=None)
    se = sd * np.sqrt(np.diag(np.linalg.inv(A.T @ A)))
    b = dict(zip(face.names, beta[6:]))
    s = dict(zip(face.names, se[6:]))
    assert abs(b["fx.P1 [N]"] - 0.8) < 4 * s["fx.P1 [N]"]
    assert abs(b["tz.P2 [N*m]"] - 0.05) < 4 * s["tz.P2 [N*m]"]
    assert abs(b["fy.P1 [N]"]) < 4 * s["fy.P1 [N]"]
    # the correction removes the drift (to the fit's precision)
    corr = unit.free_correct(ctx, {"degree": 2}, beta[6:])
    assert np.sqrt(np.mean((corr - beta[:6] - pred - (y - pred - true)) ** 2)) < 0.02


def test_holds_and_load_history():
    t = np.arange(40, dtype=float)
    still = np.r_[np.ones(10), np.zeros(5), np.ones(10), np.zeros(3), np.ones(2), np.zeros(10)].astype(bool)
    rec = np.zeros(40, int)
    h = holds(still, rec, min_hold=5)
    assert list(np.unique(h)) == [-1, 0, 1]
    assert (h[:10] == 0).all() and (h[15:25] == 1).all() and (h[28:30] == -1).all()
    pred = np.zeros((40, 6))
    pred[15:, 2] = 3.0
    since, step = load_history(t, rec, h, pred)
    assert since[0] == 0 and since[9] == 9          # first hold: from the recording's start
    assert since[15] == 1.0 and since[24] == 10.0   # second hold: from the last moving sample (t=14)
    assert (step[:15, 2] == 0).all() and np.allclose(step[15:25, 2], 3.0)


def test_body_rate_of_a_constant_turn():
    t = np.linspace(0, 2, 201)
    a = 0.3 * t   # about z at 0.3 rad/s
    quat = np.stack([np.cos(a / 2), 0 * a, 0 * a, np.sin(a / 2)], axis=1)
    w = body_rate(quat, t, np.zeros(len(t), int))
    assert np.allclose(w, [0, 0, 0.3], atol=1e-4)


def test_effect_without_free_face_is_no_candidate():
    ctx = make_context("s", np.arange(10.0), np.zeros((10, 6)), np.zeros((10, 6)), np.tile([0, 0, -9.81], (10, 1)))
    assert EFFECTS["casing_load"].free_shapes(ctx) == ()
    # the sensor matrix's face multiplies the load's own wrench, pred - offset: no offsets known, no face
    assert EFFECTS["gain_crosstalk"].free_shapes(ctx) == ()
    with_offset = make_context("s", np.arange(10.0), np.zeros((10, 6)), np.ones((10, 6)), np.tile([0, 0, -9.81], (10, 1)),
                               offset=np.zeros(6))
    assert EFFECTS["gain_crosstalk"].free_shapes(with_offset) == ({"block": "force"}, {"block": "full"})
    assert EFFECTS["gain_crosstalk"].free_face(with_offset, {"block": "full"}).k == 36
    with pytest.raises(ValueError):
        FreeFace(np.zeros((10, 5, 1)), ("a",))
