"""Apply a named effect's correction when correcting a recording (a calibration with an effect).

A calibration written with the diagnosis' named effect (``calibration_with_effect.json``,
``diagnose/joint.py``) carries in ``meta["effect"]`` the effect's name, its standing-face
parameters ``eta`` (the scaled units of ``Effect.standing_params``), the hanging-face
parameters, the reference time ``t_ref_s`` and the design rotations. Correcting a sample
then uses what the effect does to one transducer's readings or to the measured orientation
(``effects/base.py``, eq. (A)):

    c_k = c_k(w_k; eta)          corrected readings, per leg (gain, nonlinearity, casing load,
                                 chassis flex; hysteresis sees no previous pose here: none)
    R_WB' = R_WB Z(eta)^T        so that the up vector R_WB'^T e_z = Z(eta) z   (mocap bias)
    w_o,k(t) = w_o,k + D_k (t - t_ref) / 1 h                                   (offset drift: the
                                 per-leg rates of the joint hanging fit; a straight line, so it
                                 holds only near the session; ``--track-offsets`` follows drift)

The standing face's extra wrench ``e_p`` acts on the body as a whole (a cable's pull, a mass
error): the feet carry what they carry, so per-foot wrenches are unchanged by it; this is
logged. The corrections are the same CasADi expressions the diagnosis fitted, evaluated over
all samples at once.
"""

from __future__ import annotations

import logging

import casadi as ca
import numpy as np

from .calibration import Calibration
from .geometry import remove_yaw

log = logging.getLogger(__name__)

HOUR_S = 3600.0
BODY_EFFECTS = ("tether_force", "robot_mass", "moving_com", "leg_inertia")
CHUNK = 4096        # samples per block of the effect's correction


def effect_block(cal: Calibration) -> dict | None:
    """The calibration's named effect (``meta["effect"]`` written by a run), or None."""
    b = (cal.meta or {}).get("effect")
    return b if isinstance(b, dict) and b.get("name") else None


def _context(cal: Calibration, block: dict, source: str):
    from .diagnose.effects import LIBRARY
    from .diagnose.effects.base import AugContext

    name = block["name"]
    if name not in LIBRARY:
        raise ValueError(f"{source}: meta.effect.name {name!r} is not an effect of the library {sorted(LIBRARY)}")
    legs = cal.leg_names
    R_nom = np.asarray(block.get("R_nominal", [cal.legs[k].rotation_to_body for k in legs]), float)
    if R_nom.shape != (len(legs), 3, 3):
        raise ValueError(f"{source}: meta.effect.R_nominal must be ({len(legs)}, 3, 3), got {R_nom.shape}")
    variant = block.get("variant") or {}
    try:
        eff = type(LIBRARY[name])(**variant) if variant else LIBRARY[name]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: meta.effect.variant {variant!r} does not rebuild {name}: {exc}") from None
    return eff, AugContext.from_calibration(cal, legs, R_nom)


def correct_for_effect(cal: Calibration, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t: np.ndarray, *,
                       source: str = "calibration", with_cov: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Readings (N, K, 6) and orientations (N, 3, 3) corrected for the calibration's named effect, and
    the covariance (N, K, 6, 6) of the corrected readings from the effect's parameter uncertainty.

    ``phi`` (N, K) shaft angles, ``t`` (N,) s on the session clock of the calibration's recordings.
    No effect: the inputs unchanged and no covariance. The covariance is first order,
    ``J_k Sigma_eta J_k^T`` with ``J_k = d c_k / d eta`` (the CasADi face's Jacobian) and ``Sigma_eta``
    the joint standing fit's covariance of ``eta`` (``meta.effect.eta_cov``; None without it or
    ``with_cov``); offset drift: ``diag((t - t_ref)^2 / 1 h^2 se(D_k)^2)`` (its rates' se, correlations
    not stored). It enters the ground wrenches' se like reading noise (``uncertainty.ground_wrench_se``'s
    ``offset_cov``). The orientation map of a motion-capture bias is not propagated. Samples are
    taken in blocks of ``CHUNK`` (the standing features are a few hundred columns per sample).
    """
    block = effect_block(cal)
    if block is None:
        return w, R_WB, None
    eff, ctx = _context(cal, block, source)
    legs, K, N = ctx.legs, ctx.K, len(t)
    t_h = (np.asarray(t, float) - float(block.get("t_ref_s", 0.0))) / HOUR_S
    if eff.name == "offset_drift":
        log.info("%s: offset_drift: offsets follow the per-leg drift rates of the joint fit (a straight line in time)", source)
        cov = None
        if with_cov:
            cov = np.zeros((N, K, 6, 6))
            cov[..., np.arange(6), np.arange(6)] = (t_h[:, None, None] * _drift_rates(block, legs, "se")[None]) ** 2
        return w - t_h[:, None, None] * _drift_rates(block, legs, "value")[None], R_WB, cov
    if eff.name in BODY_EFFECTS:
        log.info("%s: %s acts on the body, not on the transducers' readings: per-foot wrenches are unchanged", source, eff.name)
        return w, R_WB, None
    from .diagnose.standing_fit import pose_symbols

    eta = _eta(eff, ctx, block, source)
    m = len(eta)
    C = _eta_cov(block, m, source) if with_cov else None
    d, pose = pose_symbols(K)
    e = ca.SX.sym("eta", m)
    c, zmap, _ = eff.standing(e, pose, ctx)
    Z = zmap if zmap is not None else ca.SX.eye(3)
    outs = [ca.vertcat(*c), ca.reshape(Z, 9, 1)] + ([ca.jacobian(ca.vertcat(*c), e)] if C is not None else [])
    fn = ca.Function("effect", [d, e], outs)
    w_new, R_new = np.empty_like(w, dtype=float), np.empty_like(R_WB, dtype=float)
    cov = np.zeros((N, K, 6, 6)) if C is not None else None
    for a in range(0, N, CHUNK):
        s = slice(a, min(N, a + CHUNK))
        n = s.stop - s.start
        res = fn(_features(cal, ctx, w[s], phi[s], R_WB[s], t_h[s]).T, eta)
        w_new[s] = np.asarray(res[0], float).T.reshape(n, K, 6)
        Zs = np.asarray(res[1], float).T.reshape(n, 3, 3).transpose(0, 2, 1)   # columns of Z were stacked (CasADi is column-major)
        R_new[s] = np.einsum("nij,nkj->nik", R_WB[s], Zs)
        if cov is not None:
            J = np.asarray(res[2], float).reshape(6 * K, n, m).transpose(1, 0, 2).reshape(n, K, 6, m)   # samples side by side
            cov[s] = np.einsum("nkam,mq,nkbq->nkab", J, C, J)
    return w_new, R_new, cov


def apply_effect(cal: Calibration, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t: np.ndarray,
                 *, source: str = "calibration") -> tuple[np.ndarray, np.ndarray]:
    """The corrected readings and orientations of :func:`correct_for_effect` (no covariance)."""
    return correct_for_effect(cal, w, phi, R_WB, t, source=source, with_cov=False)[:2]


def effect_reading_cov(cal: Calibration, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t: np.ndarray,
                       *, source: str = "calibration") -> np.ndarray | None:
    """The covariance (N, K, 6, 6) of the corrected readings of :func:`correct_for_effect`, or None."""
    return correct_for_effect(cal, w, phi, R_WB, t, source=source)[2]


def _drift_rates(block: dict, legs, key: str) -> np.ndarray:
    """Offset drift's per-leg rates (K, 6) N/h (``key`` "value") or their se ("se"); missing: 0."""
    D = np.zeros((len(legs), 6))
    par = block.get("parameters", {})
    for k, leg in enumerate(legs):
        for c, comp in enumerate(("fx", "fy", "fz", "tx", "ty", "tz")):
            v = par.get(f"hanging:{leg}.{comp}/h")
            D[k, c] = v[key] if isinstance(v, dict) and v.get(key) is not None else 0.0
    return D


def _eta(eff, ctx, block: dict, source: str) -> np.ndarray:
    block_p = eff.standing_params(ctx)
    m = block_p.m if block_p is not None else 0
    eta = np.asarray(block.get("eta", []), float)[:m]
    if len(eta) != m:
        raise ValueError(f"{source}: meta.effect.eta has {len(eta)} values, {eff.name} needs {m}")
    return eta


def _eta_cov(block: dict, m: int, source: str) -> np.ndarray | None:
    """The covariance of the face's ``m`` parameters from ``meta.effect.eta_cov`` (None: not stored)."""
    if "eta_cov" not in block:
        return None
    C = np.asarray(block["eta_cov"], float)
    if C.ndim != 2 or C.shape[0] != C.shape[1] or C.shape[0] < m:
        raise ValueError(f"{source}: meta.effect.eta_cov must be square with at least {m} rows (the face's parameters first), got {C.shape}")
    return C[:m, :m]      # the offset shift that follows the face's parameters is the calibration's, not the effect's


def _features(cal: Calibration, ctx, w, phi, R_WB, t_h) -> np.ndarray:
    """The standing features of every sample (``StandingData.features``; the previous pose is the sample itself)."""
    from .diagnose.standing_fit import StandingData

    rcom = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(ctx.legs)], axis=1)
    n_vert = np.einsum("kji,j->ki", ctx.R_nominal, np.array([0.0, 0.0, 1.0]))
    return StandingData(w, R_WB[:, 2, :], remove_yaw(R_WB), t_h, w, phi, np.nan_to_num(rcom), n_vert).features()
