"""Hanging calibration (report Sec. III-A): transducer offsets, leg weights, leg CoM curves.

With the robot hanging free in opposite directions, each leg's transducer
reads (report eqs. 4-7, exact rotation ``R_j`` per recording ``j``)

    f_m,i = m_k g R_j a_j + f_o + nu_i,   tau_m,i = r_k(phi_i) x (m_k g R_j a_j) + tau_o + omega_i,

with ``a_j = R_k,nom^T gravity_body_j`` the nominal gravity axis in ft_k. Pairs
and signs come from ``gravity_body`` and the nominal rotations, never from leg
names.

``fit_hanging(..., method="nlp")`` (default): exact compression of the samples
by shaft-angle bin (binning.py), the CoM curve as a smoothness-penalised QP
with a GCV-chosen weight (com_qp.py), and one CasADi/IPOPT problem per leg
with exact SO(3) constraints over rotations, weight, offset and CoM grid
(nlp.py, estimate.py); standard errors from the Fisher information
(uncertainty.py). ``method="baseline"``: the report's own procedure with
``s^+``, ``s^-`` and a Kalman smoother (baseline.py), for comparison.

Thin data: one opposite pair leaves the CoM along its gravity axis unknown
(NaN there, with a warning naming the axis), and with it the torque offset and
the force offset across the axis (NaN, warned); grid angles the shaft never
reached are NaN (``com_mask``); no opposite pair, or a shaft that never turns,
raise :class:`HangingDataError` naming the leg and recordings. Warnings are
logged once each (logger ``ftcal_nlp.estimate.hanging``) and kept in ``LegHangingResult.warnings``.
"""

from __future__ import annotations

import logging
from typing import Sequence

import numpy as np
from tqdm.auto import tqdm

from ...core.data import Recording, held_gravity_body
from ...core.robot import Robot
from ...core.settings import HANGING_METHODS as METHODS
from ...core.settings import HangingSettings, with_overrides
from .baseline import fit_leg_baseline
from .estimate import fit_leg_nlp
from .model import sample_prediction
from .nlp import HangingNLP
from .problem import HangingDataError, HangingSolveError, build_leg_problem, check_recordings
from .result import HangingResult, LegHangingResult

__all__ = ["fit_hanging", "hanging_residuals", "HangingResult", "LegHangingResult", "HangingDataError", "HangingSolveError",
           "METHODS"]

log = logging.getLogger(__name__)

def fit_hanging(recordings: Sequence[Recording], robot: Robot, settings: HangingSettings | None = None, *,
                nlp_cache: dict | None = None, **overrides) -> HangingResult:
    """Calibrate every leg of ``robot`` from its hanging recordings.

    ``recordings``: the ``hanging`` recordings of a dataset (opposite pairs by
    ``gravity_body``). ``settings``: :class:`~ftcal_nlp.core.settings.HangingSettings`
    (``method`` ``"nlp"`` or ``"baseline"``, ``n_grid`` CoM grid points on [0, 2pi),
    ``smoothing`` ``"auto"`` (GCV) or the weight ``lam`` (1/m^2) of the
    second-difference penalty in the noise-standardised objective); keyword
    ``overrides`` replace single fields (``fit_hanging(recs, robot, method="baseline")``).
    Both estimators are deterministic. ``nlp_cache``: a dict kept by a caller fitting many datasets of one
    protocol (their legs share the symbolic NLP; building it is a third of a small fit).
    """
    s = with_overrides(settings, HangingSettings, overrides, "fit_hanging")
    method, n_grid, smoothing = s.method, s.n_grid, s.smoothing
    recordings = list(recordings)
    pairs = check_recordings(recordings, robot)
    legs: dict[str, LegHangingResult] = {}
    cache: dict[tuple, HangingNLP] = {} if nlp_cache is None else nlp_cache
    for leg in tqdm(robot.legs, desc=f"hanging ({method})", unit="leg", disable=None, leave=False):
        if method == "nlp":
            problem = build_leg_problem(leg, recordings, robot, pairs, n_grid)
            legs[leg] = fit_leg_nlp(problem, smoothing=smoothing, nlp_cache=cache)
        else:
            build_leg_problem(leg, recordings, robot, pairs, n_grid)  # the same data checks
            legs[leg] = fit_leg_baseline(leg, recordings, robot, pairs, n_grid)
        for msg in legs[leg].warnings:
            log.warning("%s", msg)
    return HangingResult(legs, method)


def hanging_residuals(
    result: HangingResult, recordings: Sequence[Recording], robot: Robot, *, with_misalignment: bool = True
) -> dict[str, np.ndarray]:
    """Residuals ``w_m - model`` per leg, (N, 6) N and N*m over all ``recordings`` in order (Fig. 5).

    ``with_misalignment=False`` uses the nominal gravity axes (``R_j = I``), the
    report's "without s" violins. The model curve ``com_xyz_fit`` is used, so
    unidentified CoM and offset components (a single pair) enter at their fitted
    (gauge) values.
    """
    out = {}
    for leg, l in result.legs.items():
        R_nom = robot.transducers[leg].given_rotation()
        blocks = []
        for rec in recordings:
            if rec.name not in l.misalignment:
                raise ValueError(f"recording '{rec.name}' was not part of the hanging fit of leg {leg} (fitted: {list(l.misalignment)})")
            gb = held_gravity_body(rec)
            a = R_nom.T @ (gb / np.linalg.norm(gb))
            R = l.misalignment[rec.name] if with_misalignment else np.eye(3)
            blocks.append(rec.wrench[leg] - sample_prediction(rec.phi[leg], a, R, l.leg_weight_N, l.offset_fit, l.com_phi, l.com_xyz_fit))
        out[leg] = np.vstack(blocks)
    return out
