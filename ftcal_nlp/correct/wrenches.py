"""Per-foot ground wrenches a researcher can use: values, standard errors, contact state, tracked offsets.

For N samples with orientation: the ground wrenches of ``physics.ground_wrenches``
(report eq. 3 in the heading frame), their standard errors
(``uncertainty.ground_wrench_se``: the calibration's joint covariance and the
sensor noise estimated at calibration), each foot's contact state
(``contact.detect_contact``), and, with ``track_offsets``, the offsets tracked
through the recording from the swing phases (``tracking.py``):

1. correct with the calibrated offsets; detect swing against a data-driven swing
   level (offsets may have moved);
2. fit each leg's offsets over time to its swing samples; correct the readings
   by ``w_o(t) - w_o,cal``; detect swing again with a zero swing level; refit;
3. correct with the final offsets; their covariance replaces the calibration's
   offset covariance in the standard errors.

Contact thresholds use each foot's median standard error of the normal force
(while tracking: of a subsample of ``SE_SAMPLES`` rows, the offsets changing
between passes); the se columns are computed on every row at the end.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..core.calibration import Calibration
from .contact import ContactState, detect_contact
from ..core.data import WRENCH_COMPONENTS, ground_wrench_frame, ground_wrench_table
from ..core.physics import ground_wrenches
from ..estimate.sensor_noise import SensorNoise
from ..core.settings import CorrectSettings
from .tracking import TrackedOffsets, swing_offset_readings, track_offsets
from ..estimate.uncertainty import CalibrationCovariance, WrenchUncertainty, ground_wrench_se

__all__ = ["Correction", "correct_arrays", "noise_of", "se_columns", "contact_columns", "TRACKING_PASSES"]

log = logging.getLogger(__name__)

SE_SAMPLES = 2000     # rows whose se set the contact thresholds
TRACKING_PASSES = 2   # swing detection and offset fit, alternated


@dataclass(frozen=True)
class Correction:
    """``frame``: ``OUTPUT_FORMAT.md`` columns, then ``{leg}_{c}_se`` and ``total_{c}_se``, then
    ``{leg}_contact`` (1 stance, 0 swing); ``ground`` (N, K, 6) (without tracking a view of the frame's
    block: the frame is copied on write, ``ground`` is not); ``uncertainty`` or None;
    ``contact``; ``tracking`` (None unless tracked)."""

    frame: pd.DataFrame
    ground: np.ndarray
    uncertainty: WrenchUncertainty | None
    contact: ContactState
    tracking: TrackedOffsets | None = None


def se_columns(legs) -> list[str]:
    return [f"{k}_{c}_se" for k in (*legs, "total") for c in WRENCH_COMPONENTS]


def contact_columns(legs) -> list[str]:
    return [f"{k}_contact" for k in legs]


def noise_of(cal: Calibration) -> SensorNoise | None:
    """The sensor noise stored in the calibration's meta (``sensor_noise``), or None."""
    d = cal.meta.get("sensor_noise") if isinstance(cal.meta, dict) else None
    return None if d is None else SensorNoise.from_json_dict(d, source="calibration meta.sensor_noise")


def _fz_se(w_m, phi, R_WB, cal, cov, noise, offset_cov=None) -> np.ndarray | None:
    """Standard errors (N_sub, K) of the normal forces on an even subsample (for thresholds only)."""
    if cov is None and noise is None:
        return None
    step = max(1, len(phi) // SE_SAMPLES)
    oc = None if offset_cov is None else offset_cov[::step]
    return ground_wrench_se(w_m[::step], phi[::step], R_WB[::step], cal, cov, noise, oc).se[:, :-1, 2]


def _contact(t, gw, se_sub, settings, legs, baseline: bool) -> ContactState:
    # the thresholds only need each foot's typical se: a subsample's median stands for all rows
    se = None
    if se_sub is not None:
        med = np.full(se_sub.shape[1], np.nan)      # a foot without any finite se keeps NaN (no numpy warning)
        ok = np.isfinite(se_sub).any(axis=0)
        med[ok] = np.nanmedian(se_sub[:, ok], axis=0)
        se = np.broadcast_to(med, gw.shape[:2])
    return detect_contact(t, gw[..., 2], se, settings, baseline=baseline, legs=legs)


def correct_arrays(cal: Calibration, t: np.ndarray, w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray,
                   cov: CalibrationCovariance | None = None, settings: CorrectSettings = CorrectSettings(),
                   reading_cov: np.ndarray | None = None) -> Correction:
    """Ground wrenches, standard errors, contact state (and tracked offsets) of N samples (module docstring).

    ``t`` (N,) s; ``w_m`` (N, K, 6) readings in ft_k; ``phi`` (N, K) rad; ``R_WB`` (N, 3, 3) finite;
    ``cov`` the calibration's covariance (None: se from the sensor noise in ``cal.meta`` alone, or NaN
    without one); ``reading_cov`` (N, K, 6, 6) a covariance of the readings beyond the sensor noise (the
    correction of a named effect, ``effects.correction.effect_reading_cov``), added to it."""
    legs = cal.leg_names
    noise = cov.noise if cov is not None and cov.noise is not None else noise_of(cal)
    has_se = cov is not None or noise is not None
    if not has_se:
        log.warning("no calibration covariance and no sensor noise: the se columns are NaN")
    if not (settings.track_offsets and len(t) >= 2):
        # the wrenches are computed straight into the output table's block (no second copy of N x K x 6)
        table, gw = ground_wrench_table(len(t), len(legs))
        ground_wrenches(w_m, phi, R_WB, cal, out=gw)
        unc = ground_wrench_se(w_m, phi, R_WB, cal, cov, noise, reading_cov) if has_se else None
        contact = _contact(t, gw, None if unc is None else unc.se[:, :-1, 2], settings, legs, baseline=True)
        return _correction(t, gw, unc, contact, None, legs, table)
    gw = ground_wrenches(w_m, phi, R_WB, cal)
    contact = _contact(t, gw, _fz_se(w_m, phi, R_WB, cal, cov, noise, reading_cov), settings, legs, baseline=True)
    y = swing_offset_readings(w_m, phi, R_WB, cal)
    off_cal = np.stack([cal.legs[k].offset for k in legs])
    cov_used = cov.without_offsets() if cov is not None else None
    for _ in range(TRACKING_PASSES):
        tracked = track_offsets(t, y, ~contact.stance, cal, settings, phi=phi, R_WB=R_WB, cov=cov)
        off, off_cov = tracked.at(t)
        if reading_cov is not None:
            off_cov = off_cov + reading_cov
        w_used = w_m - (off - off_cal[None])
        gw = ground_wrenches(w_used, phi, R_WB, cal)
        contact = _contact(t, gw, _fz_se(w_used, phi, R_WB, cal, cov_used, noise, off_cov), settings, legs, baseline=False)
    unc = ground_wrench_se(w_used, phi, R_WB, cal, cov_used, noise, off_cov) if has_se else None
    return _correction(t, gw, unc, contact, tracked, legs)


def _correction(t, gw, unc, contact, tracked, legs, table=None) -> Correction:
    frame = ground_wrench_frame(t, gw, legs, table)
    N, n_se = len(t), 6 * (len(legs) + 1)
    # Three blocks side by side, none copied (pandas' constructor copies an ndarray unless told not to);
    # without se one read-only NaN view stands for the N x 42 NaN block (no 300 MB written per million rows).
    se = unc.se.reshape(N, n_se) if unc is not None else np.broadcast_to(np.float64(np.nan), (N, n_se))
    extra = pd.DataFrame(se, columns=se_columns(legs), index=frame.index, copy=False)
    cont = pd.DataFrame(contact.stance.astype(np.int8), columns=contact_columns(legs), index=frame.index, copy=False)
    return Correction(pd.concat([frame, extra, cont], axis=1), gw, unc, contact, tracked)
