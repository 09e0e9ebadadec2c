"""A later walk of a simulated robot whose transducer offsets have moved and keep drifting (issue 15).

The report (Sec. V) saw offsets move by up to 10 N within six months. The same
true robot as a :class:`~ftcal_nlp.sim.simulate.SimResult` walks again on a new
session clock (``t`` from ``t0_s``) with, per leg k,

    w_o,k(t) = w_o,k + s_k + d_k (1 - exp(-(t - t_0) / tau)) / (1 - exp(-T / tau))

``s_k`` the shift since calibration (force up to ``shift_N`` in a random
direction, magnitude uniform in [0.5, 1] of it; torque likewise up to
``shift_Nm``), ``d_k`` the drift over the walk's duration ``T`` (``drift_N``,
``drift_Nm``, random directions), ``tau`` its time constant (a warm-up that has
not settled). Sensors as in ``simulate.py``; the ground truth is the walk's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..core.data import Recording, ground_wrench_frame
from .effects import NoEffect
from .recordings import walking_series
from .simulate import SimResult, _recording, _sensor_readings

__all__ = ["LaterWalk", "OffsetShift", "simulate_later_walk"]


class OffsetShift(NoEffect):
    """``w + s_k + d_k g(t)`` (module docstring); ``shift`` (K, 6), ``drift`` (K, 6), ``t0``, ``duration``, ``tau``."""

    name = "offset_drift"

    def __init__(self, shift: np.ndarray, drift: np.ndarray, t0: float, duration: float, tau_s: float):
        self.shift, self.drift = np.asarray(shift, float), np.asarray(drift, float)
        self.t0, self.duration, self.tau_s = float(t0), float(duration), float(tau_s)
        self.scale = float(np.max(np.linalg.norm(self.shift[:, :3], axis=1)))

    def change(self, t: np.ndarray) -> np.ndarray:
        """The offset change since calibration (N, K, 6) at times ``t``."""
        g = (1 - np.exp(-(np.asarray(t) - self.t0) / self.tau_s)) / (1 - np.exp(-self.duration / self.tau_s))
        return self.shift[None] + g[:, None, None] * self.drift[None]

    def readings(self, ctx, w):
        return w + self.change(ctx.t)


@dataclass(frozen=True)
class LaterWalk:
    """``recording`` (kind walking); ``truth`` per-foot ground wrenches (``OUTPUT_FORMAT.md`` columns);
    ``offset_change`` (N, K, 6) the true offsets less the calibration session's, ft_k."""

    recording: Recording
    truth: pd.DataFrame
    offset_change: np.ndarray


def _directions(rng: np.random.Generator, K: int, size: float, lo: float) -> np.ndarray:
    v = rng.normal(size=(K, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True) * size * rng.uniform(lo, 1.0, (K, 1))


def simulate_later_walk(sim: SimResult, *, cycles: float = 5.0, shift_N: float = 10.0, shift_Nm: float = 0.2,
                        drift_N: float = 2.0, drift_Nm: float = 0.04, tau_s: float = 60.0, t0_s: float = 30.0,
                        seed: int = 1) -> LaterWalk:
    """The later walk of ``sim``'s robot (module docstring); deterministic in ``seed``. ``shift_N = drift_N = 0``
    gives the drift-free reference walk with the same motion and noise."""
    truth = sim.true_robot
    K = len(truth.legs)
    ss = np.random.SeedSequence([seed, 15])
    s_walk, s_sensor, s_shift = ss.spawn(3)
    rs = np.random.default_rng(s_shift)
    shift = np.hstack([_directions(rs, K, shift_N, 0.5), _directions(rs, K, shift_Nm, 0.5)])
    drift = np.hstack([_directions(rs, K, drift_N, 1.0), _directions(rs, K, drift_Nm, 1.0)])
    base = replace(sim.config, walk_cycles=float(cycles), effects=())
    ser, ground = walking_series(truth, base, t0_s, np.random.default_rng(s_walk), name="later_walk")
    eff = OffsetShift(shift, drift, ser.t[0], ser.t[-1] - ser.t[0], tau_s)
    cfg = replace(base, effects=(eff,))
    w_m, quat = _sensor_readings(ser, truth, cfg, np.random.default_rng(s_sensor), [np.random.default_rng(0)])
    rec = _recording(ser, truth.legs, w_m, quat)
    return LaterWalk(rec, ground_wrench_frame(ser.t, ground, truth.legs), eff.change(ser.t))
