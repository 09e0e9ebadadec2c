"""Apply a named effect's correction when correcting a recording (a calibration with an effect).

A calibration written with the diagnosis' named effect (``calibration_with_effect.json``,
``diagnose/joint.py``) carries in ``meta["effect"]`` the effect's name, its standing-face
parameters ``eta`` (the scaled units of ``Effect.standing_params``) and their covariance,
the hanging-face parameters, the reference time ``t_ref_s`` and the design rotations.
Correcting a sample is the effect unit's own correction (``Effect.correct`` in
``ftcal_nlp/effects/<name>.py``), looked up in the effect registry:

    c_k = c_k(w_k; eta)          a sensor effect: corrected readings, per leg (gain, nonlinearity,
                                 casing load, chassis flex; hysteresis sees no previous pose here: none)
    R_WB' = R_WB Z(eta)^T        mocap bias: so that the up vector R_WB'^T e_z = Z(eta) z
    w_o,k(t) = w_o,k + D_k (t - t_ref) / 1 h    offset drift: the per-leg rates of the joint hanging
                                 fit (a straight line, so it holds only near the session;
                                 ``--track-offsets`` follows drift)

A body effect (a cable's pull, a mass error, the legs' inertia or moving CoMs) acts on the
body as a whole: the feet carry what they carry, so per-foot wrenches are unchanged by it;
this is logged. Nothing here needs the diagnosis.

Several effects (the hexapod chain's last joint refit, ``diagnose/hexchain.py``): ``meta.effect.name`` is
``"a+b"`` and ``meta.effect.members`` lists each effect as a single effect's block would hold it, its ``eta``
a slice (``eta_slice``) of the joint ``eta`` whose covariance is the joint ``eta_cov``. Every member is applied
(``effects.combined.Combined.correct``: the corrections of the recorded samples add up, as the fit had them;
the members corrected by their standing face are evaluated as one face, so the readings' covariance carries the
cross-member terms of ``eta_cov``). A block without ``members`` (one effect, as older versions wrote it) is
applied exactly as before.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .calibration import Calibration
from .effects import EFFECTS, AugContext, Effect
from .errors import DataFormatError
from .effects.combined import Combined
from .effects.injection import HOUR_S


def effect_block(cal: Calibration) -> dict | None:
    """The calibration's named effect (``meta["effect"]`` written by a run), or None."""
    b = (cal.meta or {}).get("effect")
    return b if isinstance(b, dict) and b.get("name") else None


def _unit(reg: Mapping[str, Effect], name, variant, key: str, source: str) -> Effect:
    """The registry's unit ``name`` rebuilt with ``variant`` (``key``: where in the block, for the errors)."""
    if not isinstance(name, str) or name not in reg:
        raise DataFormatError(f"{source}: {key}.name {name!r} is not an effect of the library {sorted(reg)}")
    variant = variant or {}
    if not isinstance(variant, dict):
        raise DataFormatError(f"{source}: {key}.variant must be a table of keyword arguments of {name}, got {variant!r}")
    try:
        return type(reg[name])(**variant) if variant else reg[name]
    except (TypeError, ValueError) as exc:
        raise DataFormatError(f"{source}: {key}.variant {variant!r} does not rebuild {name}: {exc}") from None


def _effect(block: dict, source: str, reg: Mapping[str, Effect]) -> Effect:
    """The block's effect: one unit, or with ``members`` a :class:`Combined` of the members' units (in order)."""
    if "members" not in block:   # one effect (every version writes this)
        return _unit(reg, block["name"], block.get("variant"), "meta.effect", source)
    members = block["members"]
    if not isinstance(members, list) or not members or not all(isinstance(m, dict) for m in members):
        raise DataFormatError(f"{source}: meta.effect.members must be a non-empty list of tables (one per effect), got {members!r}")
    units = [_unit(reg, m.get("name"), m.get("variant"), f"meta.effect.members[{i}]", source) for i, m in enumerate(members)]
    joined = "+".join(u.name for u in units)
    if block["name"] != joined:
        raise DataFormatError(f"{source}: meta.effect.name {block['name']!r} does not match its members {joined!r}")
    try:
        return Combined(units)
    except ValueError as exc:
        raise DataFormatError(f"{source}: meta.effect.members: {exc}") from None


def _context(cal: Calibration, block: dict, source: str, registry: Mapping[str, Effect] | None = None) -> tuple[Effect, AugContext]:
    reg = EFFECTS if registry is None else registry
    eff = _effect(block, source, reg)
    legs = cal.leg_names
    R_nom = np.asarray(block.get("R_nominal", [cal.legs[k].rotation_to_body for k in legs]), float)
    if R_nom.shape != (len(legs), 3, 3):
        raise DataFormatError(f"{source}: meta.effect.R_nominal must be ({len(legs)}, 3, 3), got {R_nom.shape}")
    return eff, AugContext.from_calibration(cal, legs, R_nom)


def correct_for_effect(cal: Calibration, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t: np.ndarray, *,
                       source: str = "calibration", with_cov: bool = True, registry: Mapping[str, Effect] | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Readings (N, K, 6) and orientations (N, 3, 3) corrected for the calibration's named effect, and
    the covariance (N, K, 6, 6) of the corrected readings from the effect's parameter uncertainty.

    ``phi`` (N, K) shaft angles, ``t`` (N,) s on the session clock of the calibration's recordings;
    ``registry`` the effects by name (None: ``ftcal_nlp.effects.EFFECTS``). No effect: the inputs
    unchanged and no covariance. The covariance is first order, ``J_k Sigma_eta J_k^T`` with
    ``J_k = d c_k / d eta`` (the CasADi face's Jacobian) and ``Sigma_eta`` the joint standing fit's
    covariance of ``eta`` (``meta.effect.eta_cov``; None without it or ``with_cov``); offset drift:
    ``diag((t - t_ref)^2 / 1 h^2 se(D_k)^2)`` (its rates' se, correlations not stored). It enters the
    ground wrenches' se like reading noise (``uncertainty.ground_wrench_se``'s ``offset_cov``). The
    orientation map of a motion-capture bias is not propagated. Several effects (``meta.effect.members``):
    every member's correction (module docstring; ``Combined.correct`` says what the covariance leaves out).
    """
    block = effect_block(cal)
    if block is None:
        return w, R_WB, None
    eff, ctx = _context(cal, block, source, registry)
    t_h = (np.asarray(t, float) - float(block.get("t_ref_s", 0.0))) / HOUR_S
    return eff.correct(cal, block, ctx, w, phi, R_WB, t_h, with_cov=with_cov, source=source)


def apply_effect(cal: Calibration, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t: np.ndarray,
                 *, source: str = "calibration", registry: Mapping[str, Effect] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The corrected readings and orientations of :func:`correct_for_effect` (no covariance)."""
    return correct_for_effect(cal, w, phi, R_WB, t, source=source, with_cov=False, registry=registry)[:2]


def effect_reading_cov(cal: Calibration, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t: np.ndarray,
                       *, source: str = "calibration", registry: Mapping[str, Effect] | None = None) -> np.ndarray | None:
    """The covariance (N, K, 6, 6) of the corrected readings of :func:`correct_for_effect`, or None."""
    return correct_for_effect(cal, w, phi, R_WB, t, source=source, registry=registry)[2]
