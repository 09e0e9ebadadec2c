"""``correct`` for free loads (``DATA_FORMAT.md`` section 5, issue 22): per transducer the contact wrench.

A rigid payload on a wrist, or the URDF links below a sensor (``load_kind`` ``"rigid_payload"`` or
``"urdf_subtree"`` in ``calibration.json``): per sample, in the estimated (true) ft frame about its origin,

    w_contact = w_m - w_o - w_load                 (the factory matrix)
    w_contact = C (w_m - w_o) - w_load             (a sensor matrix ``C`` refitted in situ, ``sensor_matrix``)

``w_o + w_load`` and its derivative the calibrated load's (``correct/calibrated.py``: its model, the se's delta
method, the URDF and arm cases), the readings first corrected for the named effects of a
``calibration_with_effect.json`` (``effects/correction.py``). ``C`` follows the reading model of
``estimate/freeload/sensor_matrix.py`` (``C (r - o) = w(theta, E)``; :func:`apply_sensor_matrix`); without it, or
with ``C = I``, the code and the numbers are those of the first line. Its se: :func:`_matrix_variance` (``C``'s own
uncertainty is not propagated, and why). The contact wrench is what the environment adds to the tool's weight: zero
(within noise) while the tool touches nothing. The recording is read and checked by ``correct/recording.py``
(gravity per sample or the fixed base's, joint angles, what a run checks, the readings against the calibration:
as corrected, the effects applied and mapped by ``C``, where the calibration has either); rows without gravity or
with NaN readings are dropped and counted in the log.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from ..core.checks import with_fault_columns
from ..core.data import QUAT_COLUMNS, WRENCH_COMPONENTS
from ..effects import correction as fx
from ..core.errors import ConfigError
from ..estimate.freeload.sensor_matrix import apply_sensor_matrix
from ..loads.base import calibration_variance
from .calibrated import PayloadCalibration, UrdfLoadCalibration, tilted_gravity
from .recording import (base_gravity, channel_faults, check_against_calibration, clean_rows, gravity_of_frame, joint_angles,
                        orientation_of_frame, transducer_temperature)

log = logging.getLogger(__name__)


def contact_wrench(p: PayloadCalibration | UrdfLoadCalibration, w_m: np.ndarray, g_B: np.ndarray,
                   q: dict[str, np.ndarray] | None = None, R_WB: np.ndarray | None = None, *, t: np.ndarray | None = None,
                   quat: np.ndarray | None = None, temperature: np.ndarray | None = None,
                   where: str = "recording") -> tuple[np.ndarray, np.ndarray]:
    """Contact wrench (N, 6) and its se (N, 6) (module docstring) for readings ``w_m`` (N, 6), gravity ``g_B``,
    joint angles ``q`` (joint -> (N,); URDF loads) and the orientations ``R_WB`` (N, 3, 3) ``g_B`` came from
    (None: ``gx..gz``; a calibration's world tilt acts through them). A calibration with named effects
    (``p.effects``, ``calibration_with_effect.json``) corrects the readings for them first
    (``effects/correction.py``: needs the samples' times ``t``, and where the effects ask for them the
    orientation ``quat`` (N, 4) and the ``temperature`` (N,)); the se then carry the effects' parameters. A
    calibration with a sensor matrix (``p.sensor_matrix``) maps the readings less the offset through it."""
    wc, se, _model = _contact(p, w_m, g_B, q, R_WB, t=t, quat=quat, temperature=temperature, where=where)
    return wc, se


def _contact(p: PayloadCalibration | UrdfLoadCalibration, w_m: np.ndarray, g_B: np.ndarray,
             q: dict[str, np.ndarray] | None = None, R_WB: np.ndarray | None = None, *, t: np.ndarray | None = None,
             quat: np.ndarray | None = None, temperature: np.ndarray | None = None,
             where: str = "recording") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`contact_wrench` and the calibration's prediction ``w_o + w_load`` (N, 6) it subtracted (``contact +
    model`` is the reading as the calibration's checks see it: the effects and the matrix applied)."""
    q = {} if q is None else q
    model, J = p.predict(g_B, q, R_WB)
    C = p.sensor_matrix
    if p.effects is None:
        if C is None:
            var = calibration_variance(p, J) + p.sigma**2
            return w_m - model, np.sqrt(np.clip(var, 0.0, None)), model
        wc = apply_sensor_matrix(w_m, C, p.offset) - (model - p.offset)
        return wc, np.sqrt(np.clip(_matrix_variance(p, J, C), 0.0, None)), model
    if t is None:
        raise ValueError("contact_wrench: a calibration with effects needs the samples' times t")
    g_t = tilted_gravity(p, g_B, R_WB)[0]
    ctx = fx.context(p, p.effects, np.asarray(t, float), w_m, model, g_t, quat, q, temperature)
    yc, parts = fx.correct_readings(p, p.effects, ctx, where)
    if C is None:
        var = fx.joint_variance(J, p.effects, parts) + p.sigma**2
        return yc - model, np.sqrt(np.clip(var, 0.0, None)), model
    wc = apply_sensor_matrix(yc, C, p.offset) - (model - p.offset)
    return wc, np.sqrt(np.clip(_matrix_variance(p, J, C, parts), 0.0, None)), model


def _matrix_variance(p: PayloadCalibration | UrdfLoadCalibration, J: np.ndarray, C: np.ndarray,
                     parts: list | None = None) -> np.ndarray:
    """Var (N, 6) of ``w_c = C (y - w_o) - w_load`` (``y`` the readings, effect-corrected where ``parts`` are their
    derivatives in the effects' parameters ``beta``): the delta method with ``d w_c / d w_o = -C``, ``d w_c / d theta
    = -d w_load / d theta``, ``d w_c / d beta = C d y / d beta`` over the calibration's covariance, and the readings'
    noise ``diag(C diag(sigma^2) C^T)`` (``sigma`` the raw readings' noise sd).

    ``C``'s own uncertainty is not added: ``calibration.json`` stores its marginal se only, and its determined part
    is the load's (a force gain and the load's mass rest on the same data, or on the same weighing): the load's se,
    from the joint fit, already carry it, and its errors cancel those of ``C`` on the contact (``C (r - o)`` and the
    weight scale together). Added as independent terms they would count it twice (at a 2 % gain error, weighed mass:
    |z| RMS 0.83..0.91 on forces instead of 0.90..0.95). Entries the data leave undetermined are held at the factory
    value, taken without error as the factory matrix is without one."""
    Jc = J.copy()
    Jc[:, :, :6] = C
    if parts is None:
        var = calibration_variance(p, Jc)
    else:
        assert p.effects is not None
        n = len(J)
        var = np.empty((n, 6))
        ns = SimpleNamespace(cov=p.effects.cov, null=p.effects.null, undetermined=p.effects.undetermined)
        for a in range(0, n, fx.FREE_CHUNK):
            rows = slice(a, min(a + fx.FREE_CHUNK, n))
            D = np.einsum("ij,njk->nik", C, fx.derivative_rows(parts, p.effects.k, rows))
            var[rows] = calibration_variance(ns, np.concatenate([Jc[rows], -D], axis=2))
    return var + (C**2) @ (np.asarray(p.sigma, float) ** 2)


def contact_frame(cal_legs: dict[str, PayloadCalibration | UrdfLoadCalibration], df: pd.DataFrame, where: str,
                  gravity_body=None) -> pd.DataFrame:
    """The output table: ``t``, per transducer ``{X}_fx..tz`` (contact wrench, ft frame about its origin) and
    ``{X}_fx_se..tz_se``. The recording is checked first (:func:`clean_rows`, :func:`check_against_calibration`:
    what a run checks that applies to a recording to correct); rows without gravity or with NaN readings are
    dropped (counted in the log). Without orientation columns, gravity is the fixed base's (``gravity_body``: the
    ``--gravity-body`` option, else the calibration's; :func:`base_gravity`). A transducer whose calibration names
    effects or carries a sensor matrix is checked on its readings as corrected (``contact + w_o + w_load``: the
    effects applied, mapped by ``C``), what the calibration predicts; a temperature's shift of the offsets would
    otherwise leave no row at the noise."""
    legs = list(cal_legs)
    clean, keep = clean_rows(cal_legs, df, where)
    base = base_gravity(cal_legs, clean, where, gravity_body)
    q: dict[str, np.ndarray] = {}
    for cl in cal_legs.values():
        if cl.tree is not None:   # a load oriented or moved by the joints: their columns read against its URDF
            q.update(joint_angles(clean, cl.joints, cl.tree, where))
    faults = channel_faults(cal_legs, df, where)
    R_WB = orientation_of_frame(clean)
    t = clean["t"].to_numpy(float)
    quat = None
    if R_WB is not None:
        quat = clean[list(QUAT_COLUMNS)].to_numpy(float)
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)

    def one(k: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p = cal_legs[k]
        g_B = gravity_of_frame(clean, p.g, where, base[k])
        temp = transducer_temperature(df, k, keep, t, where) if p.effects is not None else None
        return _contact(p, clean[[f"{k}_{c}" for c in WRENCH_COMPONENTS]].to_numpy(float), g_B, q, R_WB, t=t, quat=quat,
                        temperature=temp, where=where)

    # corrected before the checks where the readings differ from what the calibration's model sees (else after them)
    early = {k: one(k) for k, p in cal_legs.items() if p.effects is not None or p.sensor_matrix is not None}
    checked = clean
    if early:
        checked = clean.copy()
        for k, (wc, _se, model) in early.items():
            checked[[f"{k}_{c}" for c in WRENCH_COMPONENTS]] = wc + model
    check_against_calibration(cal_legs, checked, where, base,
                              "--gravity-body" if gravity_body is not None else "the calibration's gravity_body",
                              {f.leg: f.rows[keep] for f in faults})
    out: dict[str, np.ndarray] = {"t": t}
    ses: dict[str, np.ndarray] = {}
    for k in legs:
        wc, se, _m = early[k] if k in early else one(k)
        for j, c in enumerate(WRENCH_COMPONENTS):
            out[f"{k}_{c}"] = wc[:, j]
            ses[f"{k}_{c}_se"] = se[:, j]
    return with_fault_columns(pd.DataFrame({**out, **ses}), faults, keep)


# ---------------------------------------------------------------------------------------------- the command's hooks
# (the same names in ``legs.py``; ``correct/__init__.py`` calls them)

def wrote(cal: dict) -> str:
    """What the command's log says it wrote."""
    return f": contact wrench of {list(cal)} in their ft frames"


def check_options(args: argparse.Namespace) -> None:
    """The options that apply to hexapod legs only are refused."""
    for opt, name in ((args.bag, "--bag"), (args.track_offsets, "--track-offsets")):
        if opt:
            raise ConfigError(f"{name} applies to hexapod calibrations; {args.calibration} holds free loads", key=name)


def prepare(cal: dict, args: argparse.Namespace) -> None:
    """Nothing before the recording is read (the reader checked the calibration and read its covariance)."""
    return None


def correct_table(cal: dict, df: pd.DataFrame, args: argparse.Namespace, prepared: None = None) -> tuple[pd.DataFrame, None]:
    """The contact wrench of each transducer over the recording ``df`` (:func:`contact_frame`); no tracked offsets."""
    return contact_frame(cal, df, str(args.recording), getattr(args, "gravity_body", None)), None


def write_extras(cal: dict, df: pd.DataFrame, tracking: None, args: argparse.Namespace, off_out: Path | None,
                 bag: Path | None) -> None:
    """Nothing beside the table (``--bag`` and ``--track-offsets`` are refused by :func:`check_options`)."""
