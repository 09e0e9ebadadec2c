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


def apply_effect(cal: Calibration, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t: np.ndarray,
                 *, source: str = "calibration") -> tuple[np.ndarray, np.ndarray]:
    """Readings (N, K, 6) and orientations (N, 3, 3) corrected for the calibration's named effect.

    ``phi`` (N, K) shaft angles, ``t`` (N,) s on the session clock of the calibration's recordings.
    Returns them unchanged when the calibration names no effect.
    """
    block = effect_block(cal)
    if block is None:
        return w, R_WB
    from .diagnose.standing_fit import StandingData, pose_symbols

    eff, ctx = _context(cal, block, source)
    legs, K, N = ctx.legs, ctx.K, len(t)
    t_h = (np.asarray(t, float) - float(block.get("t_ref_s", 0.0))) / HOUR_S
    if eff.name == "offset_drift":
        D = np.zeros((K, 6))
        par = block.get("parameters", {})
        for k, leg in enumerate(legs):
            for c, comp in enumerate(("fx", "fy", "fz", "tx", "ty", "tz")):
                v = par.get(f"hanging:{leg}.{comp}/h")
                D[k, c] = v["value"] if isinstance(v, dict) and v.get("value") is not None else 0.0
        log.info("%s: offset_drift: offsets follow the per-leg drift rates of the joint fit (a straight line in time)", source)
        return w - t_h[:, None, None] * D[None], R_WB
    if eff.name in BODY_EFFECTS:
        log.info("%s: %s acts on the body, not on the transducers' readings: per-foot wrenches are unchanged", source, eff.name)
        return w, R_WB
    block_p = eff.standing_params(ctx)
    m = block_p.m if block_p is not None else 0
    eta = np.asarray(block.get("eta", []), float)[:m]
    if len(eta) != m:
        raise ValueError(f"{source}: meta.effect.eta has {len(eta)} values, {eff.name} needs {m}")
    d, pose = pose_symbols(K)
    e = ca.SX.sym("eta", m)
    c, zmap, _ = eff.standing(e, pose, ctx)
    Z = zmap if zmap is not None else ca.SX.eye(3)
    fn = ca.Function("effect", [d, e], [ca.vertcat(*c), ca.reshape(Z, 9, 1)])
    z = R_WB[:, 2, :]                                   # R_WB^T e_z, the up direction in B
    rcom = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(legs)], axis=1)
    n_vert = np.einsum("kji,j->ki", ctx.R_nominal, np.array([0.0, 0.0, 1.0]))
    data = StandingData(w, z, remove_yaw(R_WB), t_h, w, phi, np.nan_to_num(rcom), n_vert)
    cw, Zf = fn(data.features().T, eta)
    w_new = np.asarray(cw, float).T.reshape(N, K, 6)
    Zs = np.asarray(Zf, float).T.reshape(N, 3, 3).transpose(0, 2, 1)   # columns of Z were stacked (CasADi is column-major)
    return w_new, np.einsum("nij,nkj->nik", R_WB, Zs)
