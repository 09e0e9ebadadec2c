"""offset_drift: the offsets change slowly with time over the session (a warm-up).

Injected (``OffsetDriftInjector``; ``d_k`` the per-leg drift after one hour, force ~``scale`` N
in a random direction, torque ``scale`` x 2 cm):

    w_o(t) = w_o + d_k (1 - exp(-t/tau)) / (1 - exp(-1 h/tau)),   tau = 1200 s

Off-face shapes (the validation sweep; a correct diagnosis still says ``offset_drift``):

* offset_drift_ramp   w_o(t) = w_o + d_k t / 1 h                       (linear, no saturation)
* offset_drift_step   w_o(t) = w_o + d_k [t >= t_s]                    (``scale`` N at once; t_s: the middle
                      of the standing recording unless ``t_step_s`` is given; hanging before, walking after)
* offset_drift_fast   w_o(t) = w_o + d_k (1 - exp(-t/tau)) / (1 - exp(-1 h/tau)),  tau = 150 s
                      (mostly over when standing starts)

Model faces (``t_h`` hours since hanging):

* standing   e_p = -sum_j D_j P_j(tau)  (Legendre, j <= degree 1, 2 or 4)   6 x degree (B axes);
             or P_1 plus S [t > t_step] (a step at the residual's change point)
* hanging    a rate per leg, plus P_2, P_3 of the hanging time or a warm-up exp(-t/tau)
             on a grid of tau (the joint refit keeps the best held-out); walking swing: the rate

Free loads (``free_faces.py``): ``P_1..P_d`` of the session time per channel over the free-load
recordings, ``d`` in 1, 2, 3, 5, 8 or ``P_1`` plus a step at the change point of the hold medians (the shape, chosen by held-out residual); corrected as ``y - X beta`` (a new recording: the calibration's change point and session span, ``ctx.extra``).

Correction: the offsets follow the joint fit's per-leg rates, ``w_o,k(t) = w_o,k + D_k (t - t_ref) / 1 h``
(a straight line: it holds only near the session; ``--track-offsets`` follows drift), with
variance ``(t - t_ref)^2 / 1 h^2 se(D_k)^2`` per component (the rates' correlations are not stored).
"""

from __future__ import annotations

import logging

import numpy as np

from .free_faces import FreeFace, session_time_basis
from .faces import TIME_BASIS, WRENCH, HangingLeg, ParamBlock, PoseSym, legendre_time, per_leg_face
from .injection import HOUR_S, EffectInjector, InjectionContext, Magnitude, OffFaceInjector
from .unit import Effect

log = logging.getLogger(__name__)


class OffsetDriftInjector(EffectInjector):
    """Warm-up drift: ``scale`` N of force drift per leg after one hour (torque: scale x 2 cm)."""

    name = "offset_drift"
    magnitude = Magnitude("N of force drift per leg after one hour", (1.0, 4.0), 3.0)

    def __init__(self, scale: float | None = None, seed: int = 0, tau_s: float = 1200.0):
        super().__init__(scale, seed)
        self.tau_s = float(tau_s)
        self._dir: np.ndarray | None = None

    def _drift(self, K: int) -> np.ndarray:
        if self._dir is None or len(self._dir) != K:
            f = self.rng.normal(size=(K, 3))
            f /= np.linalg.norm(f, axis=1, keepdims=True)
            t = self.rng.normal(size=(K, 3))
            t /= np.linalg.norm(t, axis=1, keepdims=True)
            amp = self.rng.uniform(0.7, 1.3, (K, 1))
            self._dir = np.hstack([f, 0.02 * t]) * amp
        return self.scale * self._dir

    def readings(self, ctx, w):
        K = w.shape[1]
        frac = (1 - np.exp(-ctx.t / self.tau_s)) / (1 - np.exp(-HOUR_S / self.tau_s))
        return w + frac[:, None, None] * self._drift(K)[None]


class _DriftShape(OffFaceInjector, OffsetDriftInjector):
    """Offset drift ``w_o + fraction(ctx) d_k`` with ``offset_drift``'s per-leg vectors ``d_k``."""

    expect = "offset_drift"

    def fraction(self, ctx: InjectionContext) -> np.ndarray:
        raise NotImplementedError

    def readings(self, ctx, w):
        return w + self.fraction(ctx)[:, None, None] * self._drift(w.shape[1])[None]


class OffsetDriftRampInjector(_DriftShape):
    """Linear drift: ``d_k t / 1 h`` on the session clock (``scale`` N of force after one hour)."""

    name = "offset_drift_ramp"
    magnitude = Magnitude("N of force drift per leg after one hour (linear)", (1.0, 4.0), 3.0)

    def fraction(self, ctx):
        return np.asarray(ctx.t, float) / HOUR_S


class OffsetDriftStepInjector(_DriftShape):
    """A step of ``d_k`` (``scale`` N of force) at ``t_step_s`` on the session clock; None: the middle
    of the standing recording (hanging recordings come before it, walking after)."""

    name = "offset_drift_step"
    magnitude = Magnitude("N of force step per leg", (0.5, 2.0), 2.0)

    def __init__(self, scale: float | None = None, seed: int = 0, t_step_s: float | None = None):
        super().__init__(scale, seed)
        self.t_step_s = None if t_step_s is None else float(t_step_s)

    def fraction(self, ctx):
        t = np.asarray(ctx.t, float)
        if self.t_step_s is not None:
            return (t >= self.t_step_s).astype(float)
        if ctx.kind == "standing":
            return (t >= 0.5 * (t[0] + t[-1])).astype(float)
        return np.full(len(t), 1.0 if ctx.kind == "walking" else 0.0)


class OffsetDriftFastInjector(_DriftShape):
    """Warm-up with time constant ``tau_s`` (default 150 s, far from ``offset_drift``'s 1200 s),
    normalised as the library's: ``scale`` N of force after one hour."""

    name = "offset_drift_fast"
    magnitude = Magnitude("N of force drift per leg after one hour (tau 150 s)", (1.0, 4.0), 3.0)

    def __init__(self, scale: float | None = None, seed: int = 0, tau_s: float = 150.0):
        super().__init__(scale, seed, tau_s=tau_s)
        if not self.tau_s > 0:
            raise ValueError(f"{self.name}.tau_s: expected a positive time constant in s, got {tau_s!r}")

    def fraction(self, ctx):
        return (1 - np.exp(-np.asarray(ctx.t, float) / self.tau_s)) / (1 - np.exp(-HOUR_S / self.tau_s))


class OffsetDrift(Effect):
    name = "offset_drift"
    description = "offsets change slowly with time over the session (warm-up)"
    explains = "time"
    kind = "sensor"
    injector_cls = OffsetDriftInjector
    applies_to = frozenset({"hexapod", "free"})   # it needs nothing of a hexapod
    diagnosed_on = frozenset({"hexapod", "free"})   # hexapod faces and a free-load face (``free_face``)
    shapes = (OffsetDriftRampInjector, OffsetDriftStepInjector, OffsetDriftFastInjector)
    shifts_offsets = True
    DEGREES = (1, 2, 4)   # the smooth time bases tried (attribution keeps the best held-out)
    # Hanging faces the joint refit chooses among (best held-out): a straight line, a cubic, or a line
    # plus a warm-up exp(-t / tau) on a grid of time constants (thermal warm-ups are first-order lags;
    # the grid's factor 2 leaves any true tau up to 40 % off its nearest point)
    HANGING_CUBIC = "cubic"
    HANGING_TAUS_S = (100.0, 200.0, 400.0, 800.0, 1600.0, 3200.0)

    def __init__(self, degree: int = 2, hanging: str | float = "line", step: bool = False):
        if not 1 <= degree <= TIME_BASIS:
            raise ValueError(f"offset_drift: degree must be 1..{TIME_BASIS}, got {degree}")
        self.step = bool(step)
        if hanging not in ("line", self.HANGING_CUBIC) and not (isinstance(hanging, (int, float)) and hanging > 0):
            raise ValueError(f"offset_drift: hanging must be 'line', 'cubic' or a warm-up time constant in s, got {hanging!r}")
        self.degree = int(degree)
        self.hanging = hanging if isinstance(hanging, str) else float(hanging)

    def variants(self):
        # the smooth bases, and a line plus a step at the change point of the residual (a knock, a
        # re-seated connector: no smooth basis follows it)
        return tuple(OffsetDrift(d) for d in self.DEGREES) + (OffsetDrift(1, step=True),)

    def joint_variants(self):
        # A warm-up still curving while the legs hang (a short time constant) biases the leg weights
        # through the opposite-pair differences unless the hanging face follows its curve
        return tuple(OffsetDrift(self.degree, h, self.step) for h in ("line", self.HANGING_CUBIC, *self.HANGING_TAUS_S))

    @property
    def variant(self):
        return ({"degree": self.degree} | ({"hanging": self.hanging} if self.hanging != "line" else {})
                | ({"step": True} if self.step else {}))

    def standing_params(self, ctx):
        names = tuple(f"D{j}.{c} [N]" for j in range(1, self.degree + 1) for c in WRENCH)
        return ParamBlock.bounded(names + (tuple(f"S.{c} [N]" for c in WRENCH) if self.step else ()), 20.0)

    def standing(self, eta, pose: PoseSym, ctx):
        # A drift of any shape, smooth in time: Legendre terms P_1..P_d of the session time (the
        # constant is the offset shift: the hanging offsets average a drift that was already moving)
        e = -sum(eta[6 * j : 6 * j + 6] * pose.tb[j] for j in range(self.degree))
        if self.step:
            e = e - eta[6 * self.degree : 6 * self.degree + 6] * pose.step
        return pose.w, None, e

    def hanging_features(self, legs):
        # Per leg and component: a rate (N per hour, what `correct` extrapolates) and the curve of a
        # warm-up: Legendre P_2, P_3 of the time over the leg's hanging span ("cubic") or
        # exp(-(t - t_0) / tau) (either is not extrapolated beyond the hanging recordings)
        extra = ()
        if self.hanging == self.HANGING_CUBIC:
            extra = tuple(f"{c}.P{j}" for j in (2, 3) for c in WRENCH)
        elif self.hanging != "line":
            extra = tuple(f"{c}.exp{self.hanging:g}s" for c in WRENCH)

        def make(l: HangingLeg):
            curves = []
            lo, hi = float(l.t.min()), float(l.t.max())
            if self.hanging == self.HANGING_CUBIC:
                curves = list(legendre_time(l.t, lo, hi, (2, 3)).T)
            elif isinstance(self.hanging, float):   # a warm-up time constant (__init__: not 'line')
                curves = [np.exp(-(l.t - lo) / self.hanging)]
            X = np.zeros((len(l.t), 6, 6 * (1 + len(curves))))
            for j, c in enumerate([(l.t - l.t_ref) / HOUR_S, *curves]):
                X[:, np.arange(6), 6 * j + np.arange(6)] = c[:, None]
            return X

        return per_leg_face(legs, make, tuple(f"{c}/h" for c in WRENCH) + extra)

    def swing_features(self, legs):
        # the walk comes after the hanging recordings: only the rate is carried over (a straight line)
        return OffsetDrift(self.degree).hanging_features(legs)

    # ---- free loads (``free_faces.py``): a Legendre polynomial of the session time per channel
    FREE_DEGREES = (1, 2, 3, 5, 8)
    #: samples this far (share of the session's span) outside it are named: a time polynomial extrapolated
    SPAN_MARGIN = 0.01
    free_reference_keys = ("change_point_s",)

    def free_reference(self, ctx, shape):
        """The step's session time (a new recording's step is the calibration's, not its own change point)."""
        return {"change_point_s": change_point(ctx)} if shape.get("step") else {}

    def free_session_check(self, ctx, shape, reference, leg, where):
        """A warning when samples lie outside the calibration session's span (``reference["t_span_s"]``): the
        recording must share the session's clock, and beyond the span the polynomial is extrapolated."""
        if "t_span_s" not in reference:
            return
        lo, hi = (float(v) for v in reference["t_span_s"])
        pad = self.SPAN_MARGIN * (hi - lo)
        out = int(np.sum((ctx.t < lo - pad) | (ctx.t > hi + pad)))
        if out:
            log.warning("%s: %d of %d samples lie outside the calibration session's span t = %.6g..%.6g s: the offset_drift "
                        "polynomial of %s is extrapolated there (the recording must share the session's clock)",
                        where, out, ctx.n, lo, hi, leg)

    def free_shapes(self, ctx):
        # the degree is the shape: a line, a bend, an S, flexible curves (held-out evidence picks one); and a line
        # plus a step at the change point of the readings' hold medians (a knock, a re-seated connector)
        return tuple({"degree": d} for d in self.FREE_DEGREES) + ({"degree": 1, "step": True},)

    def free_face(self, ctx, shape):
        # P_1..P_d of the session time over the free-load recordings (the constant is the offsets' own)
        d = int(shape["degree"])
        if np.ptp(ctx.t) <= 0:
            return None
        basis, labels = session_time_basis(ctx, d), [f"P{j}" for j in range(1, d + 1)]
        if shape.get("step"):
            t_s = ctx.extra["change_point_s"] if "change_point_s" in ctx.extra else change_point(ctx)   # a new recording: the calibration's
            if t_s is None:
                return None
            basis = np.concatenate([basis, (ctx.t >= t_s).astype(float)[:, None]], axis=1)
            labels.append(f"step@{t_s:.6g}s")
        return FreeFace.per_channel(basis, tuple(labels), shape=shape)

    def correct(self, cal, block, ctx, w, phi, R_WB, t_h, *, with_cov=True, source="calibration"):
        # The offsets follow the per-leg rates of the joint hanging fit (a straight line in time)
        log.info("%s: offset_drift: offsets follow the per-leg drift rates of the joint fit (a straight line in time)", source)
        cov = None
        if with_cov:
            cov = np.zeros((len(t_h), ctx.K, 6, 6))
            cov[..., np.arange(6), np.arange(6)] = (t_h[:, None, None] * drift_rates(block, ctx.legs, "se")[None]) ** 2
        return w - t_h[:, None, None] * drift_rates(block, ctx.legs, "value")[None], R_WB, cov


def change_point(ctx) -> float | None:
    """The session time of the boundary between quasi-static holds across which the readings' residual (hold medians of
    ``y - pred``, each channel scaled by the scatter of its hold medians) changes most (the best split into two constant
    levels); None with fewer than 4 holds."""
    hs = np.unique(ctx.hold[ctx.hold >= 0])
    if len(hs) < 4:
        return None
    r = ctx.y - ctx.pred
    med = np.stack([np.median(r[ctx.hold == h], axis=0) for h in hs])
    t0 = np.array([ctx.t[ctx.hold == h].min() for h in hs])
    order = np.argsort(t0)
    med, t0 = med[order], t0[order]
    scale = 1.4826 * np.median(np.abs(np.diff(med, axis=0)), axis=0) + 1e-12
    z = (med - med.mean(axis=0)) / scale
    n = len(z)
    best, k_best = -1.0, None
    cs = np.cumsum(z, axis=0)
    for k in range(2, n - 1):   # at least two holds on each side
        gain = (cs[k - 1] ** 2 / k + (cs[-1] - cs[k - 1]) ** 2 / (n - k)).sum()
        if gain > best:
            best, k_best = gain, k
    return None if k_best is None else float(t0[k_best])


def drift_rates(block: dict, legs, key: str) -> np.ndarray:
    """The joint fit's per-leg drift rates (K, 6) N/h (``key`` "value") or their se ("se") from the block's
    hanging-face parameters ``hanging:<leg>.<c>/h``; missing: 0."""
    D = np.zeros((len(legs), 6))
    par = block.get("parameters", {})
    for k, leg in enumerate(legs):
        for c, comp in enumerate(WRENCH):
            v = par.get(f"hanging:{leg}.{comp}/h")
            D[k, c] = v[key] if isinstance(v, dict) and v.get(key) is not None else 0.0
    return D


EFFECT = OffsetDrift()
