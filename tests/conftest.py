"""Shared test settings: hypothesis without wall-clock deadlines (CI has 2 shared cores); the sample path."""

import os

# Multi-threaded BLAS on 2 shared cores makes the many small LAPACK calls of the
# estimators 10-30x slower; it must be limited before numpy is first imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from hypothesis import settings  # noqa: E402

settings.register_profile("ftcal", deadline=None, max_examples=60, derandomize=True)
settings.load_profile("ftcal")

from pathlib import Path

import numpy as np
import pytest

# The sample dataset written by someone else lives in shared/ beside the clone (CI and
# developers alike); FTCAL_SAMPLE points elsewhere if needed. Without it the tests that read
# it are skipped (never an error at import or collection): tests carry ``@requires_sample``,
# fixtures and helpers call ``require_sample()``.
SAMPLE = Path(os.environ.get("FTCAL_SAMPLE", Path(__file__).resolve().parents[2] / "shared" / "sample"))
HAVE_SAMPLE = (SAMPLE / "dataset.toml").is_file()
SAMPLE_MISSING = f"../shared/sample not found (no dataset.toml at {SAMPLE}; set FTCAL_SAMPLE to the sample directory)"
requires_sample = pytest.mark.skipif(not HAVE_SAMPLE, reason=SAMPLE_MISSING)


def require_sample() -> Path:
    """The sample directory, or skip the calling test (or every test using the calling fixture)."""
    if not HAVE_SAMPLE:
        pytest.skip(SAMPLE_MISSING)
    return SAMPLE


def constant_phi_windows(rec, legs, settle_s=1.0, min_s=2.0):
    """Row indices of each run of constant shaft angles (a pose of the sample), from ``settle_s`` after it starts."""
    phi = rec.phi_array(legs)
    edges = np.flatnonzero(np.any(np.diff(phi, axis=0) != 0, axis=1)) + 1
    starts, ends = np.r_[0, edges], np.r_[edges, len(phi)]
    rate = 1 / np.median(np.diff(rec.t))
    return [np.arange(a + int(settle_s * rate), b) for a, b in zip(starts, ends) if b - a >= min_s * rate]
