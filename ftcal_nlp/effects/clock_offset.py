"""clock_offset: the readings lag (or lead) the orientation / joint stream by ``delay_s``.

Two clocks that are not in step: the transducer's readings are stamped ``delay_s`` late, so the
reading stamped ``t`` is the wrench of ``t - delay_s`` (negative: the readings lead):

    w_m(t) = w(t - d)                                             (injected, ``ClockOffsetInjector``)

``d`` from a fraction of a sample to several samples; the injector re-samples the noise-free
readings with a cubic spline (``signals.delayed``), held at the end values beyond the recording.
It needs nothing of a hexapod: the hexapod simulator and the free-load one both take it.

Off-face shapes (the validation sweep; a correct diagnosis still says ``clock_offset``):

* clock_offset_drift    d(t) = scale (0.5 + (t - t_0) / (t_1 - t_0))    (the clocks drift apart over the
                        recording: half the delay at its start, 1.5x at its end)
* clock_offset_jitter   d_n = scale + e_n,  e_n ~ N(0, (0.5 scale)^2) white per sample (stamps with jitter)

Free face (``free_faces.py``): the Taylor series of the re-sampling in ``d``,

    y(t) - pred(t) = pred(t - d) - pred(t) = -d pred'(t) + (d^2 / 2) pred''(t) - (d^3 / 6) pred'''(t) ...

columns ``-pred'`` (parameter ``delay_s`` [s]) and, with ``order`` 3, ``pred''/2`` and ``-pred'''/6``
(parameters ``delay_s^2`` [s^2], ``delay_s^3`` [s^3], free: they take up what a delay of several
samples leaves over fast moves, so ``delay_s`` stays unbiased); ``channels`` "all" (one delay) or
"force" (the forces' and the torques' delays apart). Shapes: (all, 1), (all, 3), (force, 1), chosen
by held-out residual. :func:`refine_delay` gives the exact least-squares delay by Gauss-Newton on
the re-sampled model readings (an offset per channel refit alongside), se
``1 / sqrt(sum_n,c pred'_nc^2 / sigma_c^2)``.

Correction: the readings re-sampled ``delay_s`` later, ``y'(t) = y(t + d)`` (a free load: the fitted
parameter; a hexapod recording: the effect block's ``delay_s [s]`` parameter, if any).
"""

from __future__ import annotations

import logging

import numpy as np

from ..core.errors import DataFormatError
from .free_faces import WRENCH, FreeFace, rate
from .injection import HOUR_S, EffectInjector, Magnitude, OffFaceInjector
from .signals import delayed
from .unit import Effect

log = logging.getLogger(__name__)


class ClockOffsetInjector(EffectInjector):
    """Readings stamped ``scale`` s late (negative: early): ``w_m(t) = w(t - scale)``."""

    name = "clock_offset"
    magnitude = Magnitude("s the readings lag the orientation / joint stream", (0.005, 0.04), 0.03)

    def delay(self, ctx) -> np.ndarray | float:
        return self.scale

    def readings(self, ctx, w):
        return delayed(ctx.t, w, self.delay(ctx))


class ClockOffsetDriftInjector(OffFaceInjector, ClockOffsetInjector):
    """A delay that grows over the recording: ``scale (0.5 + (t - t_0) / (t_1 - t_0))`` s (clock drift)."""

    name = "clock_offset_drift"
    expect = "clock_offset"
    magnitude = Magnitude("s the readings lag on average (growing from 0.5x to 1.5x)", (0.005, 0.04), 0.03)

    def delay(self, ctx):
        t = np.asarray(ctx.t, float)
        return self.scale * (0.5 + (t - t[0]) / max(float(t[-1] - t[0]), 1e-12))


class ClockOffsetJitterInjector(OffFaceInjector, ClockOffsetInjector):
    """A delay ``scale`` s with white jitter of sd ``0.5 scale`` per sample (stamps that jitter)."""

    name = "clock_offset_jitter"
    expect = "clock_offset"
    magnitude = Magnitude("s the readings lag on average (jitter sd half of it)", (0.005, 0.04), 0.03)

    def delay(self, ctx):
        return self.scale + ctx.rng.normal(0.0, 0.5 * abs(self.scale), len(ctx.t))


def delay_columns(pred_rate: np.ndarray, shape: str, higher: tuple = ()) -> tuple[np.ndarray, tuple[str, ...]]:
    """``X`` (N, 6, k) of a delay face from ``d pred / dt`` (N, 6): ``-pred'`` on every channel (``shape`` "all";
    with ``higher`` = the 2nd, 3rd .. derivatives of ``pred`` also their Taylor terms ``(-1)^j pred^(j) / j!``)
    or on the forces and the torques apart ("force")."""
    n = len(pred_rate)
    if shape == "all":
        cols = [-pred_rate] + [(-1) ** j * h / float(np.prod(np.arange(1, j + 1))) for j, h in enumerate(higher, start=2)]
        names = ("delay_s [s]",) + tuple(f"delay_s^{j} [s^{j}]" for j in range(2, len(higher) + 2))
        return np.stack(cols, axis=2), names
    X = np.zeros((n, 6, 2))
    X[:, :3, 0] = -pred_rate[:, :3]
    X[:, 3:, 1] = -pred_rate[:, 3:]
    return X, ("delay_s [s]", "torque.delay_s [s]")


def _channelwise_shared(cols: list, names: tuple, shape: dict) -> FreeFace:
    """A face whose k parameters act on every channel through each channel's own column ``cols[j][:, c]`` ((N, 6)
    each): the channel blocks of ``np.stack(cols, axis=2)`` (the columns not identically zero on a channel)."""
    blocks = []
    for c in range(6):
        nz = [j for j, col in enumerate(cols) if np.any(col[:, c] != 0)]
        if nz:
            blocks.append((c, np.array(nz), np.stack([cols[j][:, c] for j in nz], axis=0).T))   # column-major
    return FreeFace(None, names, shape, blocks=tuple(blocks))


def refine_delay(t: np.ndarray, rec: np.ndarray, y: np.ndarray, pred: np.ndarray, d0: float,
                 sigma: np.ndarray | None = None, iters: int = 8) -> tuple[float, float]:
    """``(delay_s, se)``: Gauss-Newton on ``y(t) = pred(t - d) + w_o`` (an offset per channel refit alongside),
    the model readings re-sampled exactly within each recording, from ``d0``; ``sigma`` (6,) the noise sd
    (None: the residual's)."""
    t, y, pred = (np.asarray(a, float) for a in (t, y, pred))
    rec = np.asarray(rec)
    d = float(d0)
    for _ in range(iters):
        shifted = np.empty_like(pred)
        slope = np.empty_like(pred)
        for r in np.unique(rec):
            i = rec == r
            shifted[i] = delayed(t[i], pred[i], d)
            slope[i] = np.gradient(shifted[i], t[i], axis=0)
        res = y - shifted
        res = res - res.mean(axis=0)
        g = slope - slope.mean(axis=0)          # d res / d d = +pred'(t - d); offsets projected out
        s2 = (np.var(res, axis=0) if sigma is None else np.asarray(sigma, float) ** 2)
        s2 = np.where(s2 > 0, s2, 1.0)
        info = float(np.sum(g**2 / s2))
        if info <= 0:
            return d, float("inf")
        step = -float(np.sum(g * res / s2)) / info
        d += step
        if abs(step) < 1e-9:
            break
    return d, 1.0 / np.sqrt(info)


class ClockOffset(Effect):
    name = "clock_offset"
    description = "the readings lag or lead the orientation / joint stream by delay_s"
    explains = "motion"
    kind = "sensor"
    injector_cls = ClockOffsetInjector
    shapes = (ClockOffsetDriftInjector, ClockOffsetJitterInjector)
    applies_to = frozenset({"hexapod", "free"})
    diagnosed_on = frozenset({"free"})
    free_explains = "motion"
    FREE_SHAPES = (("all", 1), ("all", 3), ("force", 1))
    follows_stream_clock = True   # the readings re-sampled delay_s later on their own clock

    def free_require(self, ctx, shape, leg, where):
        if ctx.n < 4:
            raise DataFormatError(f"{where}: the calibration's effect clock_offset re-samples the readings: at least 4 "
                                  f"rows needed, got {ctx.n}", path=where, column="t")

    def free_shapes(self, ctx):
        return tuple({"channels": c, "order": o} for c, o in self.FREE_SHAPES)

    def free_face(self, ctx, shape):
        # A delay shows where the load's wrench changes: d times its rate, plus d^2/2 its curvature (refine_delay is exact)
        if not np.any(np.abs(ctx.pred_rate) > 0):
            return None
        higher, d = [], ctx.pred_rate
        for _ in range(int(shape.get("order", 1)) - 1):
            d = rate(d, ctx.t, ctx.rec)
            higher.append(d)
        if shape["channels"] == "all":   # every channel its own rate (and curvature ...): channel-wise, no (N, 6, k) array
            cols = [-ctx.pred_rate] + [(-1) ** j * h / float(np.prod(np.arange(1, j + 1))) for j, h in enumerate(higher, start=2)]
            names = ("delay_s [s]",) + tuple(f"delay_s^{j} [s^{j}]" for j in range(2, len(higher) + 2))
            return _channelwise_shared(cols, names, dict(shape))
        X, names = delay_columns(ctx.pred_rate, shape["channels"], tuple(higher))
        return FreeFace(X, names, dict(shape))

    def correct(self, cal, block, ctx, w, phi, R_WB, t_h, *, with_cov=True, source="calibration"):
        # A hexapod's readings (no hexapod face fits a delay): re-sampled by the block's delay_s when it has one
        d = delay_of(block)
        if d is None or len(t_h) < 4:
            log.info("%s: clock_offset: no delay_s in the calibration's effect block; readings unchanged", source)
            return w, R_WB, None
        log.info("%s: clock_offset: readings re-sampled %.4g s later", source, d)
        return delayed(np.asarray(t_h, float) * HOUR_S, w, -d), R_WB, None

    def free_correct(self, ctx, shape, beta):
        # Re-sample the readings delay_s later (each recording apart); a torque delay of its own on the torques
        beta = np.asarray(beta, float)
        out = np.empty_like(ctx.y)
        for r in np.unique(ctx.rec):
            i = ctx.rec == r
            out[i, :3] = delayed(ctx.t[i], ctx.y[i, :3], -beta[0])
            out[i, 3:] = delayed(ctx.t[i], ctx.y[i, 3:], -beta[-1 if shape["channels"] == "force" else 0])
        return out


def delay_of(block: dict) -> float | None:
    """The delay (s) of an effect block: its parameter ``delay_s [s]`` (a value or ``{"value": ...}``), else None."""
    v = block.get("parameters", {}).get("delay_s [s]", block.get("delay_s"))
    v = v.get("value") if isinstance(v, dict) else v
    return None if v is None else float(v)


EFFECT = ClockOffset()
__all__ = ["EFFECT", "WRENCH", "ClockOffset", "ClockOffsetInjector", "refine_delay", "delay_columns"]
