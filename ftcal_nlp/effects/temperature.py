"""temperature: the offsets move with the transducer's temperature (thermal zero shift).

Needs a temperature per sample: the optional recording column ``{leg}_temp_C`` (or ``temp_C`` for
every transducer), degC (``docs/proposals/temperature.md``; ``data.Recording.temperature``).

Injected (``TemperatureInjector``; ``dT = T - 25 degC``):

    w_m = w + a_k dT + b_k dT^2,      a_k = scale [u_k s_k, 0.02 m v_k],  b_k = quadratic a_k

``u_k``, ``v_k`` random unit vectors, ``s_k`` ~ U(0.7, 1.3) (``scale`` N per degC of force, a 2 cm
lever for the torques), and the injector's temperature (written as ``{leg}_temp_C``; both simulators)

    T_k(t) = 25 + 3 (1 - exp(-t / 600 s)) + 2 sin(2 pi t / 45 s + p_k)    degC, t the session clock

(a warm-up and a swing of +-2 degC every 45 s, e.g. a fan cycling: over a recording of a few minutes
not a smooth function of time, so the face does not confuse it with an offset drift).

Off-face shape (the validation sweep; a correct diagnosis still says ``temperature``):

* temperature_lag   the gauges follow the measured temperature with a thermal time constant of
                    ``lag_s`` (30 s, between the face's grid points): ``w_m = w + a_k (lowpass_30s(T_k) - 25)``

Free face (``free_faces.py``): per channel ``(T_lag - Tbar)`` (and ``(T_lag - Tbar)^2``) with
``T_lag = lowpass_lag(T)`` (each recording apart), ``Tbar`` the mean over the samples (on a new recording the
calibration's, ``ctx.extra["temperature_mean_C"]``: then a recording held at one temperature is corrected too); parameters
``<c>.dT [N/degC]`` (and ``<c>.dT2 [N/degC^2]``; torques N*m); shapes: the degree (1, 2) and the
thermal lag (0, 20, 60 s), chosen by held-out residual, then the lag refined by a bounded search between the
grid's neighbours of the best (``free_refine``, ``free_refine.py``; 240 s beyond the largest). None without a temperature.

Correction: ``y - X beta`` (the free face on the recording's own temperature). A hexapod's
``correct`` has no temperature to read: readings unchanged (logged; ``Effect.correct``).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import DataFormatError
from .free_faces import WRENCH, FreeFace
from .free_refine import refine_scalar
from .injection import EffectInjector, Magnitude, OffFaceInjector
from .signals import lowpass
from .unit import Effect

T_REF_C = 25.0


def temperature_profile(t: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """``T`` (N, K) degC of the injector (module docstring) at session times ``t`` (N,) for phases ``phase`` (K,)."""
    t = np.asarray(t, float)[:, None]
    return T_REF_C + 3.0 * (1.0 - np.exp(-t / 600.0)) + 2.0 * np.sin(2.0 * np.pi * t / 45.0 + np.asarray(phase)[None, :])


class TemperatureInjector(EffectInjector):
    """Offsets that move ``scale`` N per degC (force; torque: a 2 cm lever) with the transducer's temperature."""

    name = "temperature"
    magnitude = Magnitude("N of force offset per degC", (0.04, 0.15), 0.08)   # a Gamma: ~0.1 % of 130 N per degC

    def __init__(self, scale: float | None = None, seed: int = 0, quadratic: float = 0.0):
        super().__init__(scale, seed)
        self.quadratic = float(quadratic)

    def _draw(self, K: int) -> np.ndarray:
        u = self.rng.normal(size=(K, 3))
        v = self.rng.normal(size=(K, 3))
        s = self.rng.uniform(0.7, 1.3, (K, 1))
        phase = self.rng.uniform(0.0, 2.0 * np.pi, (K, 1))
        return np.hstack([u / np.linalg.norm(u, axis=1, keepdims=True) * s, 0.02 * v / np.linalg.norm(v, axis=1, keepdims=True), phase])

    def gains(self, K: int) -> np.ndarray:
        """``a_k`` (K, 6): N (N*m) per degC."""
        return self.scale * self.drawn("_p", K, self._draw)[:, :6]

    def temperature(self, ctx) -> np.ndarray:
        """The transducers' temperatures (N, K) degC at the context's samples."""
        K = ctx.applied.shape[1]
        return temperature_profile(ctx.t, self.drawn("_p", K, self._draw)[:, 6])

    def felt(self, ctx) -> np.ndarray:
        """The temperature the gauges have (N, K): the measured one."""
        return self.temperature(ctx)

    def readings(self, ctx, w):
        dT = self.felt(ctx)[..., None] - T_REF_C
        a = self.gains(w.shape[1])[None]
        return w + a * dT + self.quadratic * a * dT**2


class TemperatureLagInjector(OffFaceInjector, TemperatureInjector):
    """The gauges follow the measured temperature with a thermal time constant ``lag_s`` (default 30 s)."""

    name = "temperature_lag"
    expect = "temperature"
    magnitude = Magnitude("N of force offset per degC (thermal lag 30 s)", (0.04, 0.15), 0.08)

    def __init__(self, scale: float | None = None, seed: int = 0, lag_s: float = 30.0):
        super().__init__(scale, seed)
        self.lag_s = float(lag_s)

    def felt(self, ctx):
        return lowpass(ctx.t, self.temperature(ctx), self.lag_s)


class Temperature(Effect):
    name = "temperature"
    description = "offsets that move with the transducer's temperature"
    explains = "temperature"
    kind = "sensor"
    injector_cls = TemperatureInjector
    shapes = (TemperatureLagInjector,)
    applies_to = frozenset({"hexapod", "free"})
    diagnosed_on = frozenset({"free"})
    free_explains = "temperature"
    DEGREES = (1, 2)
    LAGS_S = (0.0, 20.0, 60.0)
    free_reference_keys = ("temperature_mean_C",)

    def free_reference(self, ctx, shape):
        """The lagged temperature's mean over the calibration session (the face is centred on it, a new recording's
        correction on the calibration's); nothing without a temperature."""
        if ctx.temperature is None:
            return {}
        return {"temperature_mean_C": float(np.mean(self.lagged(ctx, float(shape["lag_s"]))))}

    def free_require(self, ctx, shape, leg, where):
        if ctx.temperature is None:
            raise DataFormatError(f"{where}: the calibration's effect temperature of transducer {leg} needs the "
                                  f"transducer's temperature: column '{leg}_temp_C' (or 'temp_C'), degC",
                                  path=where, column=f"{leg}_temp_C")

    def free_shapes(self, ctx):
        if ctx.temperature is None:
            return ()
        return tuple({"degree": d, "lag_s": lag} for d in self.DEGREES for lag in self.LAGS_S)

    def free_face(self, ctx, shape):
        T = ctx.temperature
        if T is None or not np.all(np.isfinite(T)) or (np.ptp(T) <= 0 and "temperature_mean_C" not in ctx.extra):
            return None
        basis = self._basis(ctx, float(shape["lag_s"]), int(shape["degree"]))
        d = basis.shape[1]
        names = [f"{WRENCH[c]}.dT{'' if j == 1 else j} [{'N' if c < 3 else 'N*m'}/degC{'' if j == 1 else f'^{j}'}]"
                 for c in range(6) for j in range(1, d + 1)]
        return FreeFace(None, tuple(names), dict(shape), basis=basis, channels=tuple(range(6)))

    @staticmethod
    def lagged(ctx, lag: float) -> np.ndarray:
        """``T_lag`` (N,): the temperature lagged by ``lag`` s within each recording."""
        Tl = np.empty(ctx.n)
        for r in np.unique(ctx.rec):
            i = ctx.rec == r
            Tl[i] = lowpass(ctx.t[i], ctx.temperature[i], lag)
        return Tl

    def _basis(self, ctx, lag: float, degree: int) -> np.ndarray:
        """``(T_lag - Tbar)^j``, j = 1..degree (N, degree), the temperature lagged within each recording."""
        Tl = self.lagged(ctx, lag)
        dT = Tl - ctx.extra.get("temperature_mean_C", Tl.mean())   # a new recording: the calibration's mean (free_reference)
        return np.stack([dT**j for j in range(1, degree + 1)], axis=1)

    def refine_range(self, lag: float) -> tuple[float, float]:
        """The lags :meth:`free_refine` searches for the grid's best ``lag``: between its neighbours on the grid
        ``LAGS_S`` extended to ``4 x`` its largest (a search over the whole range found a far local minimum: a
        lag of 240 s where the grid's best was 0 s and the truth 0 s, beside a named gain matrix)."""
        grid = sorted(set(self.LAGS_S) | {4.0 * max(self.LAGS_S)})
        i = int(np.argmin(np.abs(np.asarray(grid) - lag)))
        return float(grid[max(i - 1, 0)]), float(grid[min(i + 1, len(grid) - 1)])

    def free_refine(self, ctx, shape, resid):
        # The thermal lag by a bounded search between the grid's neighbours of its best lag (``refine_range``) on
        # the residual beside the free-load model's own columns (free_refine.py)
        if ctx.temperature is None:
            return None
        d = int(shape["degree"])

        def columns(lag: float) -> FreeFace:
            # the lagged basis on each channel (channel-major columns): a per-channel face, no (N, 6, 6 d) array
            return FreeFace.per_channel(self._basis(ctx, max(lag, 0.0), d), tuple(f"T{j}" for j in range(1, d + 1)))

        lo, hi = self.refine_range(float(shape["lag_s"]))
        lag = refine_scalar(ctx, resid, columns, lo, hi, xatol=0.5)
        return None if lag is None else {"degree": d, "lag_s": float(np.round(lag, 1))}

    #: per-fold tuning (``free_refine_near``): lags evenly over free_refine's range
    NEAR_POINTS = 9

    def free_refine_near(self, ctx, shape):
        # the lags free_refine searches among (its degree)
        if ctx.temperature is None:
            return ()
        lo, hi = self.refine_range(float(shape["lag_s"]))
        lags = np.round(np.linspace(lo, hi, self.NEAR_POINTS), 1)
        return tuple({"degree": int(shape["degree"]), "lag_s": float(lag)} for lag in dict.fromkeys(lags.tolist()))


EFFECT = Temperature()
