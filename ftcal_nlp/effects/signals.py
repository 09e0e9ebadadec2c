"""Time-series helpers the effect units share: resampling with a delay, first-order lags, derivatives.

* :func:`delayed`: ``x(t - d)`` of samples ``x`` at times ``t`` (a cubic spline through the samples;
  ``d`` a number or per sample, s), held at the end values beyond the recording;
* :func:`lowpass`: the first-order lag ``tau y' + y = x`` with ``y(t_0) = x(t_0)`` (the state at
  rest when the recording starts), exact for an input held between samples (zero-order hold):

      y_n = y_{n-1} + (1 - exp(-(t_n - t_{n-1}) / tau)) (x_n - y_{n-1})

  ``tau = 0`` gives ``x`` itself;
* :func:`relaxation`: ``x - lowpass(x, tau)``, what is still to relax after each change of ``x``
  (zero at rest, ``dx exp(-s / tau)`` a time ``s`` after a step ``dx``);
* :func:`rate`: ``dx/dt`` by central differences on the sample clock (``np.gradient``).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.signal import lfilter


def delayed(t: np.ndarray, x: np.ndarray, delay) -> np.ndarray:
    """``x(t - delay)`` (same shape as ``x``, time along axis 0): a cubic spline through the samples,
    evaluated at ``t - delay`` clipped to the recording's span (``delay`` a number or (N,), s)."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    if len(t) < 4:
        raise ValueError(f"delayed: need at least 4 samples, got {len(t)}")
    ts = np.clip(t - np.asarray(delay, float), t[0], t[-1])
    return CubicSpline(t, x, axis=0)(ts)


def lowpass(t: np.ndarray, x: np.ndarray, tau: float) -> np.ndarray:
    """The first-order lag of ``x`` (time along axis 0) with time constant ``tau`` s (module docstring)."""
    x = np.asarray(x, float)
    if tau < 0:
        raise ValueError(f"lowpass: tau must be >= 0 s, got {tau!r}")
    if tau == 0 or len(x) < 2:
        return x.copy()
    dt = np.diff(np.asarray(t, float))
    a = 1.0 - np.exp(-dt / tau)
    flat = x.reshape(len(x), -1)
    if np.ptp(dt) <= 1e-9 * max(float(np.mean(dt)), 1e-12):    # a regular clock: one IIR filter, no Python loop
        a0 = float(a[0])
        zi = (1.0 - a0) * flat[0]           # y_0 = x_0: the state at rest
        y = np.empty_like(flat)
        y[0] = flat[0]
        y[1:] = lfilter([a0], [1.0, -(1.0 - a0)], flat[:-1], axis=0, zi=zi[None, :])[0]
        return y.reshape(x.shape)
    y = np.empty_like(flat)
    y[0] = flat[0]
    for n in range(1, len(flat)):
        y[n] = y[n - 1] + a[n - 1] * (flat[n - 1] - y[n - 1])
    return y.reshape(x.shape)


def relaxation(t: np.ndarray, x: np.ndarray, tau: float) -> np.ndarray:
    """``x - lowpass(x, tau)``: what of each change of ``x`` is still to relax (module docstring)."""
    return np.asarray(x, float) - lowpass(t, x, tau)


def rate(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``dx/dt`` along axis 0 by central differences (one-sided at the ends)."""
    x = np.asarray(x, float)
    return np.zeros_like(x) if len(x) < 2 else np.gradient(x, np.asarray(t, float), axis=0)
