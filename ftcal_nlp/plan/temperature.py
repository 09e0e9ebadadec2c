"""How much temperature range a free-load session needs to determine a temperature effect (issue 32 item 4).

The temperature effect (``effects/temperature.py``) moves each channel's offset with the transducer's temperature:
``w_c = o_c + beta_c (T - T_ref) + e_c`` (``T`` the ``{X}_temp_C`` / ``temp_C`` column, ``DATA_FORMAT.md`` section 5).
Per channel the coefficient competes with the offset only; the Fisher information of ``[o_c, beta_c]`` with the
regressor ``[1, T_n - T_ref]`` over the ``n`` samples, noise sd ``s_c``, is

    F = (1 / s_c^2) [[n, S1], [S1, S2]],   S1 = sum (T_n - T_ref),  S2 = sum (T_n - T_ref)^2

and ``(F^-1)_beta = s_c^2 n / (n S2 - S1^2) = s_c^2 / sum (T_n - Tbar)^2`` whatever ``T_ref``: the coefficient is
determined by the temperature's spread about its mean, and a temperature that never varies (range within
``freeload.plausibility.TEMPERATURE_RESOLUTION_C``) makes it collinear with the offset: not determined. Left out:
the load's parameters (their regressors follow the orientations, the temperature's does not: their cross terms are
small in a session whose temperature does not follow the holds) and the effect's shape (degree, thermal lag), as
the plan of the load's parameters leaves out the effects.

Noise. ``s_c`` is the run's weight: a protocol's stated sd (white noise); a pilot's residual sd after its load fit
with the temperature regressed out per channel (a pilot that carries the effect would otherwise count it as
noise), widened by ``sqrt`` of ``freeload.problem.serial_inflation`` on those same residuals (as the load plan
widens its se).

Range needed. For the same temperature profile scaled in range, ``sum (T - Tbar)^2`` scales with the range squared,
so the range that brings every channel's se to its target is ``range * max_c(se_c / target_c)``; where the
temperature never varies the profile is a linear ramp over the samples in order (``sum (T - Tbar)^2 =
range^2 n (n + 1) / (12 (n - 1))``). The target (N/degC of force): ``--temperature-target`` (or the protocol key
``temperature_target_N_per_C``), torques the same multiple of their noise as the forces; by default
``s_c / TEMPERATURE_SPAN_C``: a correction carried over a 10 degC working range errs by at most the noise sd.

A protocol states its temperature with ``temperature_range_C`` (degC, the range a session sweeps: a linear ramp
over its samples in hold order); a pilot's comes from its temperature column on the samples its fit used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimate.freeload.plausibility import TEMPERATURE_RESOLUTION_C

#: degC: the working range a correction must hold over by default (the target ``s_c / span``)
TEMPERATURE_SPAN_C = 10.0
CHANNELS = ("fx", "fy", "fz", "tx", "ty", "tz")
UNITS = ("N/degC",) * 3 + ("N*m/degC",) * 3


@dataclass(frozen=True)
class TemperaturePlan:
    """One transducer's temperature coefficients: ``se`` (6,) (inf: not determined), ``target`` (6,), the ``range_C``
    the session has (or plans), the ``needed_range_C`` for ``se <= target`` on every channel, ``profile`` (``"pilot"``,
    ``"linear ramp"``), ``noise`` (6,) the sd per sample behind them and ``widening`` (6,) the serial factor."""

    range_C: float
    n_samples: int
    se: np.ndarray
    target: np.ndarray
    target_source: str
    needed_range_C: float
    profile: str
    noise: np.ndarray
    widening: np.ndarray

    @property
    def determined(self) -> bool:
        return bool(np.all(np.isfinite(self.se)))

    def to_json_dict(self) -> dict:
        return {"range_C": self.range_C, "samples": self.n_samples, "profile": self.profile,
                "determined": self.determined,
                "se": {f"{c}.dT [{u}]": (float(s) if np.isfinite(s) else None) for c, u, s in zip(CHANNELS, UNITS, self.se)},
                "target": {f"{c}.dT [{u}]": float(t) for c, u, t in zip(CHANNELS, UNITS, self.target)},
                "target_source": self.target_source, "needed_range_C": self.needed_range_C,
                "noise_sd": self.noise.tolist(), "serial_widening": self.widening.tolist()}

    def text(self) -> list[str]:
        head = (f"  temperature ({self.profile}, range {self.range_C:.3g} degC over {self.n_samples} samples): ")
        if not self.determined:
            head += ("never varies: the temperature coefficients cannot be told from the offsets (collinear with them)")
        else:
            f, t = self.se[:3], self.se[3:]
            head += f"se of the coefficients {np.sqrt(np.mean(f**2)):.3g} N/degC, {np.sqrt(np.mean(t**2)):.3g} N*m/degC (RMS)"
        ok = self.determined and bool(np.all(self.se <= self.target))
        need = (f"  temperature range needed for se <= target ({self.target_source}): {self.needed_range_C:.3g} degC"
                + (" (met)" if ok else f" ({'a ramp over the samples' if not self.determined else 'this profile scaled'})"))
        return [head, need]


def coefficient_se(T: np.ndarray, sd: np.ndarray, resolution_c: float = TEMPERATURE_RESOLUTION_C) -> np.ndarray:
    """se (6,) of the temperature coefficients from the 2x2 Fisher information of ``[offset, beta]`` per channel with
    the regressor ``[1, T - T_ref]`` (module docstring; ``T_ref`` the first sample: the result does not depend on it),
    ``sd`` (6,) the noise sd per sample (widened); inf where ``T`` ranges within ``resolution_c``."""
    T = np.asarray(T, float)
    if len(T) < 2 or np.ptp(T) <= resolution_c:
        return np.full(6, np.inf)
    d = T - T[0]
    n, S1, S2 = len(d), d.sum(), (d * d).sum()
    det = n * S2 - S1 * S1
    return np.asarray(sd, float) * np.sqrt(n / det)


def ramp_range(n: int, sd: np.ndarray, target: np.ndarray) -> float:
    """The range (degC) of a linear ramp over ``n`` equally spaced samples that brings every channel's se to its
    target: ``se = sd sqrt(12 (n - 1) / (n (n + 1))) / range``."""
    return float(np.max(np.asarray(sd, float) / np.asarray(target, float)) * np.sqrt(12.0 * (n - 1) / (n * (n + 1))))


def targets(noise: np.ndarray, target_force: float | None) -> tuple[np.ndarray, str]:
    """``(target (6,), source)``: ``target_force`` N/degC (torques the same multiple of their noise), else
    ``noise / TEMPERATURE_SPAN_C`` (module docstring)."""
    noise = np.asarray(noise, float)
    if target_force is None:
        return noise / TEMPERATURE_SPAN_C, f"noise sd / {TEMPERATURE_SPAN_C:g} degC working range"
    return target_force * noise / noise[:3].mean(), f"{target_force:g} N/degC, torques alike in noise sd"


def temperature_plan(T: np.ndarray, noise: np.ndarray, widening: np.ndarray | None = None,
                     target_force: float | None = None, profile: str = "pilot") -> TemperaturePlan:
    """The plan of a session whose samples have temperatures ``T`` (N,), the noise sd ``noise`` (6,) per sample and
    the serial ``widening`` (6,) (None: white)."""
    T = np.asarray(T, float)
    w = np.ones(6) if widening is None else np.asarray(widening, float)
    sd = np.asarray(noise, float) * w
    se = coefficient_se(T, sd)
    target, source = targets(noise, target_force)
    rng = float(np.ptp(T)) if len(T) else 0.0
    need = rng * float(np.max(se / target)) if np.all(np.isfinite(se)) else ramp_range(len(T), sd, target)
    return TemperaturePlan(rng, len(T), se, target, source, need, profile, np.asarray(noise, float), w)


def protocol_temperature(d: dict, n_samples: int, noise: np.ndarray, where: str,
                         target_force: float | None = None) -> TemperaturePlan | None:
    """A protocol's ``temperature_range_C`` as a linear ramp over its ``n_samples`` (white noise ``noise``); None
    without the key. ``temperature_target_N_per_C`` (or ``target_force``, the command line's) sets the target."""
    from .reading import PlanError

    if "temperature_range_C" not in d:
        return None
    for key in ("temperature_range_C", "temperature_target_N_per_C"):
        v = d.get(key, 1.0)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or v < 0 or (key != "temperature_range_C" and v <= 0):
            raise PlanError(f"{where}: key '{key}' must be a {'non-negative' if key == 'temperature_range_C' else 'positive'} "
                            f"number (degC: the range the session sweeps; N/degC: the force coefficients' target se), "
                            f"got {v!r}", key=key)
    target = target_force if target_force is not None else d.get("temperature_target_N_per_C")
    T = np.linspace(0.0, float(d["temperature_range_C"]), n_samples)
    return temperature_plan(T, noise, None, None if target is None else float(target), "linear ramp")


def pilot_temperature(ds, leg: str, fit, target_force: float | None = None) -> TemperaturePlan | None:
    """A pilot's temperature plan for transducer ``leg`` (its load fitted as ``fit``): the temperature on the samples
    the fit used, the noise and widening of the fit's residuals with ``[1, T - Tbar]`` regressed out per recording
    (module docstring); None when no recording carries the transducer's temperature."""
    from ..estimate.freeload.problem import serial_inflation

    res, src, idx, T = [], [], [], []
    for i, rec in enumerate(r for r in ds.hanging if r.hangs_free(leg)):
        m = fit.used.get(rec.name)
        if m is None or not m.any() or leg not in rec.temperature:
            continue
        r = rec.wrench[leg][m] - fit.predict_recording(rec, ds.robot.g)[m]
        t = np.asarray(rec.temperature[leg], float)[m]
        A = np.c_[np.ones(len(t)), t - t.mean()]
        r = r - A @ np.linalg.lstsq(A, r, rcond=None)[0]     # the offset and the effect: not noise
        res.append(r)
        src.append(np.full(len(t), i))
        idx.append(np.flatnonzero(m))
        T.append(t)
    if not T:
        return None
    r = np.concatenate(res)
    _, inflation = serial_inflation(r, np.concatenate(src), np.concatenate(idx))
    noise = np.sqrt(np.mean(r**2, axis=0))
    return temperature_plan(np.concatenate(T), noise, np.sqrt(inflation), target_force, "pilot")
