"""The blocked cross-validation of the free diagnosis (diagnose/free_cv.py) on faces kept as channel blocks
(effects/free_faces.py): the cached per-block sums give the same fits as a direct least squares on the rows, for dense,
per-channel and channel-wise faces; a face tuned per fold (``fit_per_fold``) and the training blocks' sums
(``train_sse``) are the direct least squares of each fold's training rows; the refinement's normal equations
(effects/free_refine.py) equal a least squares on the stacked rows."""

import numpy as np
import pytest

from ftcal_nlp.diagnose.free_cv import Design, cv_blocks, fold_of_blocks
from ftcal_nlp.effects.free_faces import FreeFace


def _problem(seed=0, n=600, shuffled=False):
    rng = np.random.default_rng(seed)
    hold = np.repeat(np.arange(20), n // 20)
    block = cv_blocks(hold, np.zeros(n, int), 5)
    if shuffled:     # blocks that are not runs of consecutive samples: the design permutes the rows into block order
        block = rng.permutation(block)
    fold = fold_of_blocks(block, 5, seed)
    w = rng.uniform(0.5, 2.0, 6)
    Jx = np.zeros((n, 6, 9))
    Jx[:, np.arange(6), np.arange(6)] = 1.0                          # offsets: one column per channel
    Jx[:, :3, 6:] = rng.normal(size=(n, 3, 3))                       # a dense block on the forces only
    J = FreeFace(Jx, tuple(f"j{k}" for k in range(9)))
    P = FreeFace.per_channel(rng.normal(size=(n, 2)), ("a", "b"))            # one basis on every channel
    C = FreeFace.channelwise([rng.normal(size=(n, 2)) for _ in range(6)], tuple(f"c{k}" for k in range(12)))
    r = rng.normal(size=(n, 6)) / w + 0.3 * C.wrench(rng.normal(size=12)) + 0.2 * P.wrench(rng.normal(size=12))
    return Design(r, w, block, fold), (J, P, C), r, w, fold


def _lstsq(parts, r, w, rows):
    A = np.concatenate([p.X for p in parts], axis=2)[rows] * w[None, :, None]
    b = (r[rows] * w).reshape(-1)
    coef, *_ = np.linalg.lstsq(A.reshape(len(b), -1), b, rcond=None)
    return coef, A.reshape(len(b), -1), b


def test_channel_blocks_rebuild_the_dense_columns():
    _, (J, P, C), *_ = _problem()
    for face in (J, P, C):
        X = np.zeros_like(face.X)
        for c, cols, B in face.channel_blocks():
            X[:, c, cols] = B
        assert np.array_equal(X, face.X)
        beta = np.arange(face.k, dtype=float)
        np.testing.assert_allclose(face.wrench(beta), face.X @ beta, rtol=1e-13, atol=1e-12)
    # the dense Jacobian keeps only each channel's non-zero columns: offset c on channel c, the block on the forces
    assert [list(cols) for _, cols, _ in J.channel_blocks()] == [[0, 6, 7, 8], [1, 6, 7, 8], [2, 6, 7, 8], [3], [4], [5]]


@pytest.mark.parametrize("shuffled", [False, True])
def test_cross_validation_from_the_block_sums_is_the_direct_least_squares(shuffled):
    d, (J, P, C), r, w, fold = _problem(shuffled=shuffled)
    assert d._sorted is not shuffled
    cv = d.fit([J, P, C])
    parts = [J, P, C]
    heldout = np.empty_like(r)
    for f in range(5):
        coef, _, _ = _lstsq(parts, r, w, fold != f)
        np.testing.assert_allclose(cv._fold_beta[f], coef, rtol=1e-8, atol=1e-10)
        heldout[fold == f] = r[fold == f] - np.concatenate([p.X for p in parts], axis=2)[fold == f] @ coef
    np.testing.assert_allclose(cv.heldout, heldout, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(cv.chan_sse, (heldout**2).sum(axis=0), rtol=1e-9)
    coef, A, b = _lstsq(parts, r, w, slice(None))
    np.testing.assert_allclose(cv.beta, coef, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(cv.rss, np.sum((b - A @ coef) ** 2), rtol=1e-9)


def test_a_face_tuned_per_fold_is_each_folds_direct_fit_and_the_training_sums_its_residual():
    d, (J, P, C), r, w, fold = _problem(seed=3)
    rng = np.random.default_rng(9)
    # per fold its own channel-wise face (as a shape tuned on that fold's training blocks would give)
    faces = [FreeFace.channelwise([C.channel_blocks()[c][2] + 0.1 * rng.normal(size=(d.n, 2)) for c in range(6)], C.names)
             for _ in range(5)]
    whole = d.fit([J, P, C])
    cv = d.fit_per_fold([J, P], faces, whole)
    heldout = np.empty_like(r)
    for f in range(5):
        parts = [J, P, faces[f]]
        coef, _, _ = _lstsq(parts, r, w, fold != f)
        np.testing.assert_allclose(cv._fold_beta[f], coef, rtol=1e-8, atol=1e-10)
        heldout[fold == f] = r[fold == f] - np.concatenate([p.X for p in parts], axis=2)[fold == f] @ coef
    np.testing.assert_allclose(cv.heldout, heldout, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(cv.chan_sse, (heldout**2).sum(axis=0), rtol=1e-9)
    assert cv.beta is whole.beta and cv.rss == whole.rss        # the all-sample fit is the whole design's
    # the same face in every fold: the ordinary cross-validation
    same = d.fit_per_fold([J, P], [C] * 5, whole)
    np.testing.assert_allclose(same.block_sse, whole.block_sse, rtol=1e-12)
    # training blocks' weighted residual sum of squares of each fold's fit
    t = d.train_sse([J, P, C])
    for f in range(5):
        coef, A, b = _lstsq([J, P, C], r, w, fold != f)
        np.testing.assert_allclose(t[f], np.sum((b - A @ coef) ** 2), rtol=1e-9)


def test_the_refinements_normal_equations_are_the_stacked_least_squares():
    from ftcal_nlp.effects.free_faces import make_context
    from ftcal_nlp.effects.free_refine import residual_sse

    rng = np.random.default_rng(4)
    n = 500
    t = np.arange(n) * 0.01
    ctx = make_context("x", t, rng.normal(size=(n, 6)), rng.normal(size=(n, 6)), rng.normal(size=(n, 3)),
                       sigma=rng.uniform(0.5, 2.0, 6))
    resid = rng.normal(size=(n, 6))
    _, (_, P, C), *_ = _problem(n=n)
    sse = residual_sse(ctx, resid)
    w = 1.0 / ctx.sigma
    for face in (P, C):
        A = np.concatenate([np.broadcast_to(np.eye(6), (n, 6, 6)), face.X], axis=2) * w[None, :, None]   # offsets + face
        b = (resid * w).reshape(-1)
        coef, *_ = np.linalg.lstsq(A.reshape(len(b), -1), b, rcond=None)
        np.testing.assert_allclose(sse(face), np.sum((b - A.reshape(len(b), -1) @ coef) ** 2), rtol=1e-10)
        np.testing.assert_allclose(sse(face.X), sse(face), rtol=1e-12)      # the dense columns: the same


def test_a_released_design_keeps_its_fits_numbers_not_their_columns():
    # Design.release (the end of a diagnosis): the cached sums and the fits' parts are dropped, their numbers stay, a
    # residual formed before stays, one not formed raises (rather than being formed from nothing)
    d, (J, P, C), r, w, fold = _problem()
    cv, cv2 = d.fit([J, P]), d.fit([J, C])
    resid = cv.resid.copy()
    rms, sse, beta = cv.rms().copy(), cv.sse, cv.beta.copy()
    kept = cv.resid
    d.release()
    assert not d._gram and not d._vec and not d._keep
    np.testing.assert_array_equal(cv.rms(), rms)
    assert cv.sse == sse and np.array_equal(cv.beta, beta) and np.array_equal(kept, resid)
    with pytest.raises(RuntimeError, match="released"):
        _ = cv2.heldout
    with pytest.raises(RuntimeError, match="released"):
        _ = cv.resid
