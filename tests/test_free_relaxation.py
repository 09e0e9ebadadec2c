"""FreeLoadContext.relaxation (issue 23 item 6, the speed of the free-load diagnosis): the relaxation column creep's
face and refinement are built of equals ``creep_term(t, pred, 1, (tau,))`` of each recording apart, exactly, on a
regular clock, an irregular one and a context restricted by ``select`` (which shares ``extra``, where the cache lives)."""

import numpy as np
import pytest

from ftcal_nlp.effects.creep import creep_term
from ftcal_nlp.effects.free_faces import make_context


def _reference(ctx, tau):
    out = np.zeros_like(ctx.pred)
    for r in np.unique(ctx.rec):
        i = ctx.rec == r
        out[i] = creep_term(ctx.t[i], ctx.pred[i], 1.0, (tau,))
    return -out


@pytest.mark.parametrize("clock", ["regular", "irregular"])
def test_relaxation_is_creep_term_per_recording(clock):
    rng = np.random.default_rng(3)
    n = 2400
    t = np.arange(n) / 100.0 if clock == "regular" else np.cumsum(rng.uniform(0.005, 0.015, n))
    rec = np.repeat([0, 1, 2], [700, 900, 800])
    pred = np.cumsum(rng.normal(size=(n, 6)), axis=0)
    ctx = make_context("w", t, pred, pred, rng.normal(size=(n, 3)), rec=rec)
    for tau in (0.3, 2.0, 40.0):
        got = ctx.relaxation(tau)
        assert got.shape == (n, 6) and np.array_equal(got, _reference(ctx, tau))
    # a restricted context shares extra: its own rows, not the full context's cache
    for sub in (ctx.select(rec > 0), ctx.select(np.arange(n) % 3 != 0)):
        assert np.array_equal(sub.relaxation(2.0), _reference(sub, 2.0))
    assert np.array_equal(ctx.relaxation(2.0), _reference(ctx, 2.0))
