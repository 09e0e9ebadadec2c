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

Free face (``free_faces.py``): the exact re-sampling of the model readings, ``y(t) - pred(t) = pred(t - d) - pred(t)``,
a face nonlinear in ``d``. It is linearised about a point ``d0`` (the shape's ``delay_s``):

    pred(t - d) - pred(t) ~ [pred(t - d0) - pred(t) + d0 pred'(t - d0)] + d (-pred'(t - d0))

the bracket a fixed offset of the face (``FreeFace.offset``: the designs fit the residual less it), the column
``-pred'(t - d0)`` with parameter ``delay_s [s]``, the delay itself (``pred(t - d0)``, ``pred'(t - d0)`` from one
cubic spline per recording, :func:`shifted`). The grid's shapes are the first-order faces about 0
(``{"channels": "all", "order": 1}``: the exact face at ``d0 = 0``; ``{"channels": "force", "order": 1}`` a delay of
the forces and one of the torques), scored by held-out residual; ``free_refine`` then profiles the exact delay
(:func:`profile_delay`: the weighted residual sum of squares of ``r - (pred(t - d) - pred(t))`` after the free-load
model's first-order columns, on a grid of ``PROFILE_STEP_S`` over ``+-PROFILE_RANGE_S`` and a bounded scalar search
about the grid's best; the profile is cheap: one spline evaluation and one right-hand side per point, where a design
per grid shape costs its normal equations) and the face is linearised about the profile's minimum: there the fitted ``delay_s`` is the exact least-squares delay to second order in the distance,
and its se (the joint refit's ``s^2 (A^T A)^+``, ``s^2`` widened by the residual's serial correlation) is that of
the profile's curvature (Gauss-Newton). Why not the Taylor series in ``d`` about 0 (``-d pred' + d^2/2 pred''
...``, still built for ``order`` > 1): at delays of 0.2 s over moves of 1-2 s it leaves a remainder 1-3x the floor
that a sub-second creep then takes, and its first coefficient reads the delay 3-8 % short. A first-order lag and
a delay are near-aliases; with the exact face the delay (one parameter) explains a delay to the floor.

A delay that changes over the recording (:func:`delay_by_block`, run by the diagnosis on the joint refit's residual
with the delay's own wrench added back): per contiguous time block ``b`` (8 over the samples) Gauss-Newton on
``r = pred(t - d_b) - pred(t) + c_b`` (an offset per channel and block), ``se_b = sqrt(s^2 / sum w^2 pred'^2)``;
constancy by ``chi2 = sum_b ((d_b - dbar) / se_b)^2`` on ``B - 1`` degrees of freedom, a change said when its
p-value is below ``CHANGE_P``, with the largest jump between neighbouring blocks and the time between them.
:func:`refine_delay` gives the exact least-squares delay by Gauss-Newton on the re-sampled model readings alone (an
offset per channel refit alongside), se ``1 / sqrt(sum_n,c pred'_nc^2 / sigma_c^2)``.

Correction: the readings re-sampled ``delay_s`` later, ``y'(t) = y(t + d)`` (a free load: the fitted
parameter; a hexapod recording: the effect block's ``delay_s [s]`` parameter, if any).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.interpolate import CubicSpline

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


def shifted(t: np.ndarray, rec: np.ndarray, x: np.ndarray, d: float,
            splines: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(x(t - d), x'(t - d))`` (N, 6) each, each recording apart: one cubic spline per recording through its samples
    (``signals.delayed``'s), its value and slope at ``t - d`` clipped to the recording's span (slope 0 beyond it);
    a recording of fewer than 4 rows as is (slope 0). ``splines``: a dict the splines are kept in across calls on the
    same ``t``, ``rec`` and ``x``."""
    t, x = np.asarray(t, float), np.asarray(x, float)
    out, slope = x.copy(), np.zeros_like(x)
    for r in np.unique(rec):
        i = np.flatnonzero(rec == r)
        if len(i) < 4:
            continue
        sp = splines.get(r) if splines is not None else None
        if sp is None:
            sp = CubicSpline(t[i], x[i], axis=0)
            if splines is not None:
                splines[r] = sp
        ts = t[i] - d
        inside = (ts >= t[i[0]]) & (ts <= t[i[-1]])
        ts = np.clip(ts, t[i[0]], t[i[-1]])
        out[i] = sp(ts)
        slope[i] = sp(ts, 1) * inside[:, None]
    return out, slope


def exact_face(ctx, d0: float, shape: dict) -> FreeFace | None:
    """The exact delay linearised about ``d0`` (module docstring): column ``-pred'(t - d0)`` on every channel
    (parameter ``delay_s [s]``, the delay itself) and the fixed offset ``pred(t - d0) - pred(t) + d0 pred'(t - d0)``."""
    sh, sl = shifted(ctx.t, ctx.rec, ctx.pred, d0)
    if not np.any(sl != 0):
        return None
    face = _channelwise_shared([-sl], ("delay_s [s]",), dict(shape))
    if d0 != 0:
        face.offset = sh - ctx.pred + d0 * sl
    return face


def profile_delay(ctx, resid: np.ndarray, span: float, step: float, xatol: float = 1e-4) -> float | None:
    """The delay in ``[-span, span]`` minimising the weighted residual sum of squares of ``resid - (pred(t - d) -
    pred(t))`` after the free-load model's first-order columns (``free_refine``: offsets, load parameters, mounting
    turn), the channels weighted by the floor: the exact profile over ``d``, on a grid of ``step`` (the profile of a
    motion that repeats has several minima) and by a bounded scalar search within a step of the grid's best."""
    from scipy.optimize import minimize_scalar

    from .free_refine import _gram, _rhs, _sse_after, model_face

    sd = ctx.sigma if ctx.sigma is not None else np.std(resid, axis=0)
    w2 = 1.0 / np.where(sd > 0, sd, 1.0) ** 2
    J = model_face(ctx)
    GJ = _gram(J, J, w2)     # the model's normal matrix once; per trial delay only the right-hand side

    def sse(d: float) -> float:
        rT = np.ascontiguousarray((resid - (shifted(ctx.t, ctx.rec, ctx.pred, d, splines)[0] - ctx.pred)).T)
        rr = float(np.sum(w2 * np.einsum("cn,cn->c", rT, rT)))
        return _sse_after(rr, GJ, _rhs(J, rT, w2))

    splines: dict = {}       # one spline per recording for every trial delay
    grid = np.arange(-span, span + 0.5 * step, step)
    d0 = float(grid[int(np.argmin([sse(float(d)) for d in grid]))])
    best = minimize_scalar(sse, bounds=(d0 - step, d0 + step), method="bounded", options={"xatol": xatol})
    return float(best.x) if best.success and np.isfinite(best.x) else None


def delay_by_block(t: np.ndarray, rec: np.ndarray, r: np.ndarray, pred: np.ndarray, w: np.ndarray, d0: float,
                   s2: float = 1.0, blocks: int = 8, iters: int = 6) -> dict:
    """Whether the delay changes over the recording (module docstring): ``r`` (N, 6) the residual of the joint refit
    without the delay (``y - model`` but for the shift), ``w`` (6,) the channel weights, ``s2`` the variance factor
    (the joint refit's: serial correlation included). Per contiguous block of samples (``blocks`` over the samples,
    dealt to the recordings by their size) Gauss-Newton on ``r = pred(t - d_b) - pred(t) + c_b`` from ``d0`` (``c_b``
    an offset per channel and block), ``se_b = sqrt(s2 / sum w^2 pred'(t - d_b)^2)``; constancy by
    ``chi2 = sum_b ((d_b - dbar) / se_b)^2`` on ``B - 1`` degrees of freedom (``dbar`` the weighted mean); the largest
    jump between neighbouring blocks of one recording, in se of the difference, and the time between them."""
    from scipy.stats import chi2 as chi2_dist

    t, r, pred, rec = np.asarray(t, float), np.asarray(r, float), np.asarray(pred, float), np.asarray(rec)
    w2 = np.asarray(w, float) ** 2
    n = len(t)
    rows = []
    for q in np.unique(rec):
        i = np.flatnonzero(rec == q)
        k = max(1, int(round(blocks * len(i) / n)))
        rows += [(q, j) for j in np.array_split(i, k) if len(j) >= 10]
    out = []
    for q, j in rows:
        i = np.flatnonzero(rec == q)
        d = float(d0)
        info = 0.0
        for _ in range(iters):
            sh, sl = shifted(t[i], np.zeros(len(i)), pred[i], d)
            pos = np.searchsorted(i, j)
            res = r[j] - (sh[pos] - pred[j])
            res = res - res.mean(axis=0)
            g = sl[pos] - sl[pos].mean(axis=0)        # d res / d d = +pred'(t - d), the offsets projected out
            info = float(np.sum(w2 * g**2))
            if info <= 0:
                break
            step = -float(np.sum(w2 * g * res)) / info
            d += step
            if abs(step) < 1e-7:
                break
        se = float(np.sqrt(s2 / info)) if info > 0 else float("inf")
        out.append({"recording": q, "t_start": float(t[j[0]]), "t_end": float(t[j[-1]]), "delay_s": d, "se": se})
    ok = [b for b in out if np.isfinite(b["se"]) and b["se"] > 0]
    if len(ok) < 2:
        return {"blocks": out, "chi2": float("nan"), "dof": 0, "p": float("nan"), "changes": False}
    dv = np.array([b["delay_s"] for b in ok])
    sv = np.array([b["se"] for b in ok])
    wt = 1.0 / sv**2
    mean = float(np.sum(wt * dv) / np.sum(wt))
    chi2 = float(np.sum(((dv - mean) / sv) ** 2))
    p = float(chi2_dist.sf(chi2, len(ok) - 1))
    jumps = [(abs(b["delay_s"] - a["delay_s"]) / np.hypot(a["se"], b["se"]), a, b)
             for a, b in zip(ok[:-1], ok[1:]) if a["recording"] == b["recording"]]
    res = {"blocks": out, "mean_delay_s": mean, "chi2": chi2, "dof": len(ok) - 1, "p": p, "changes": bool(p < CHANGE_P)}
    if jumps:
        z, a, b = max(jumps, key=lambda x: x[0])
        res["largest_jump"] = {"recording": a["recording"], "t_s": 0.5 * (a["t_end"] + b["t_start"]), "from_s": a["delay_s"],
                               "to_s": b["delay_s"], "z": float(z)}
    return res


#: a p-value of the per-block delays' constancy below this: the delay changes over the recording
CHANGE_P = 1e-3


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
    FREE_SHAPES = (("all", 1), ("force", 1))
    #: the exact delay's profile: over +-PROFILE_RANGE_S (drivers deliver readings up to 0.5 s late) in steps of
    #: PROFILE_STEP_S, then a bounded search within a step of the grid's best
    PROFILE_RANGE_S = 0.6
    PROFILE_STEP_S = 0.04
    follows_stream_clock = True   # the readings re-sampled delay_s later on their own clock

    def free_require(self, ctx, shape, leg, where):
        if ctx.n < 4:
            raise DataFormatError(f"{where}: the calibration's effect clock_offset re-samples the readings: at least 4 "
                                  f"rows needed, got {ctx.n}", path=where, column="t")

    def free_shapes(self, ctx):
        return tuple({"channels": c, "order": o} for c, o in self.FREE_SHAPES)

    def free_refine(self, ctx, shape, resid):
        # the exact delay by its profile (whichever first-order shape was best), the face then linearised about it:
        # its parameter is the delay, which the joint refit moves from the profile's minimum to second order only
        d = profile_delay(ctx, resid, self.PROFILE_RANGE_S, self.PROFILE_STEP_S)
        return None if d is None else {"channels": "all", "delay_s": float(np.round(d, 6))}

    def free_refine_near(self, ctx, shape):
        # none: the face's own parameter is the delay (the shape is only the point it is linearised about), so a shape
        # tuned per fold changes the held-out fit only to second order in the distance between the points
        return ()

    def free_face(self, ctx, shape):
        # the exact delay linearised about a point; else the Taylor series about 0 (order 1: the exact face at 0)
        if "delay_s" in shape:      # the exact re-sampling, linearised about delay_s
            return exact_face(ctx, float(shape["delay_s"]), shape)
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
__all__ = ["EFFECT", "WRENCH", "ClockOffset", "ClockOffsetInjector", "refine_delay", "delay_columns", "shifted",
           "exact_face", "profile_delay", "delay_by_block"]
