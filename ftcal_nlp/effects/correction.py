"""The named effects' correction of a recording, for every load: ``correct`` calls this module, each effect's own
part is a hook on its unit (``ftcal_nlp/effects/<name>.py``); no effect is named here.

**Hexapod legs** (``calibration_with_effect.json`` of a hexapod run, ``diagnose/refit.py``): ``meta["effect"]`` holds
the effect's name, its standing-face parameters ``eta`` (the scaled units of ``Effect.standing_params``) and their
covariance, the hanging-face parameters, the reference time ``t_ref_s`` and the design rotations. Correcting a sample
is the effect unit's own correction (``Effect.correct``), looked up in the effect registry:

    c_k = c_k(w_k; eta)          a sensor effect: corrected readings, per leg (gain, nonlinearity,
                                 casing load, chassis flex; hysteresis sees no previous pose here: none;
                                 ``faces.correct_by_face``)
    R_WB' = R_WB Z(eta)^T        mocap bias: so that the up vector R_WB'^T e_z = Z(eta) z
    w_o,k(t) = w_o,k + D_k (t - t_ref) / 1 h    offset drift: the per-leg rates of the joint hanging
                                 fit (a straight line, so it holds only near the session;
                                 ``--track-offsets`` follows drift)

A body effect (a cable's pull, a mass error, the legs' inertia or moving CoMs) acts on the body as a whole: the feet
carry what they carry, so per-foot wrenches are unchanged by it; this is logged. Several effects (the hexapod chain's
last joint refit, ``diagnose/hexchain.py``): ``meta.effect.name`` is ``"a+b"`` and ``meta.effect.members`` lists each
effect as a single effect's block would hold it, its ``eta`` a slice (``eta_slice``) of the joint ``eta`` whose
covariance is the joint ``eta_cov``. Every member is applied (``effects.combined.Combined.correct``: the corrections of
the recorded samples add up, as the fit had them; the members corrected by their standing face are evaluated as one
face, so the readings' covariance carries the cross-member terms of ``eta_cov``). A block without ``members`` (one
effect, as older versions wrote it) is applied exactly as before.

**Free loads** (``meta.effect.kind = "free_load"``, written by ``diagnose/free_effect_file.py``): per transducer the
members ``{"name", "shape", "labels", "beta", "parameters"}`` in chain order and the ``reference`` a face computes from
the whole calibration session that a new recording cannot (``t_span_s``, and what each unit's ``free_reference``
keeps: offset_drift's step time, the lagged temperature's mean); ``position_m`` the ft origin in B. Applied by
``correct`` (:func:`correct_readings`, called by ``correct.free.contact_wrench``): the new recording's context is
rebuilt (:func:`context`: its time, readings, the calibration's model readings ``pred_n = h(x; s_n)``, gravity in ft,
joint angles, orientation, temperature; holds from the rates; the ``reference`` in ``ctx.extra``), then every member's
own correction ``c_i = unit_i.free_correct(ctx, shape_i, beta_i)``::

    y_c = y + sum_i (c_i - y),          w_contact = y_c - h(x; s_n)

every member evaluated on the same context, as fitted (the faces built from the model readings take them at the
refit ``x* + dx``, where the diagnosis took them at ``x*``: a second-order difference, ``dx`` times ``beta``). Why the
sum and not a composition in chain order: the joint fit is a sum of faces, each built from the same recorded context;
for a unit whose correction is its face's subtraction (the default ``y - X beta``) the sum is exactly
``y - sum_i X_i beta_i``, the fitted model; a unit that overrides it (``clock_offset``: the readings re-sampled
``delay_s`` later) replaces its linearised face by the exact shift, equal to first order and moving the contact wrench
in step too. A composition would build later corrections from readings the fit never saw.

Standard errors (first order)::

    Var(w_contact) = [J_x, -D] C [J_x, -D]^T + diag(sigma^2),     D_i = d c_i / d beta_i

``J_x`` the model's derivative (``freeload.calibrated``), ``D_i = -X_i`` for the default correction and central
differences of ``free_correct`` for a unit that overrides it; ``C`` the joint covariance (the cross terms between the
calibration and the effects included); ``sigma`` the noise floor. Left out: the uncertainty of the shapes (time
constants, lags, the delay grid's order: chosen by held-out evidence and held fixed) and the noise the re-sampling
carries over. Without the covariance file the stored se serve (diagonal: correlations left out, logged).

What a member needs of the new recording is its unit's: ``free_require`` (an error naming the column: ``temperature``
a ``{X}_temp_C`` or ``temp_C``, ``joint_limit_contact`` its ``q_<joint>``, ``inertial_load`` ``qw..qz``,
``clock_offset`` four rows), ``free_session_check`` (a warning: offset_drift's polynomial evaluated outside the
session's span) and ``follows_stream_clock`` (a stream, not a list of single-row poses). A face that is zero on the
recording (no change of load for creep, no joint near its stop) corrects nothing. A calibration without
``meta.effect`` is corrected as before.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from ..core.calibration import Calibration
from ..core.errors import DataFormatError
from ..loads.base import calibration_variance
from .combined import Combined
from .faces import AugContext
from .free_faces import make_context
from .injection import HOUR_S
from .registry import EFFECTS
from .unit import Effect

log = logging.getLogger(__name__)

#: ``meta.effect.kind`` of a free-load calibration's effects
KIND = "free_load"
#: rows per block of a free load's variance (the (rows, 6, P + K) Jacobian stays a few MB)
FREE_CHUNK = 8192
#: relative step of the central differences of an overriding unit's correction in its parameters
DIFF_STEP = 1e-6


# ---------------------------------------------------------------------------------------------- hexapod legs

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


# ---------------------------------------------------------------------------------------------- free loads

@dataclass(frozen=True)
class Member:
    """One named effect of a transducer: its unit's ``name``, the face's ``shape``, the parameter ``labels`` and
    ``beta`` (face column order), ``se`` (inf: undetermined)."""

    name: str
    shape: dict
    labels: tuple[str, ...]
    beta: np.ndarray
    se: np.ndarray


@dataclass(frozen=True)
class FreeEffects:
    """A transducer's named effects (``members`` in chain order), the session ``reference`` (module docstring), the
    mount ``E`` and the ft origin in B (``position_m``: an inertial face's lever), and the joint covariance ``cov``
    over ``x_names + beta names`` with ``undetermined`` and ``null`` (as ``uncertainty.CalibrationCovariance.block``)."""

    leg: str
    members: tuple[Member, ...]
    reference: dict
    mount_rotation: np.ndarray
    position_m: np.ndarray | None = None
    cov: np.ndarray | None = None
    undetermined: np.ndarray | None = None
    null: np.ndarray | None = None
    full_cov: bool = False

    @property
    def k(self) -> int:
        return sum(len(m.beta) for m in self.members)

    def beta_names(self) -> list[str]:
        return beta_names(self.leg, self.members)


def beta_names(leg: str, members) -> list[str]:
    """The covariance file's labels of the members' parameters: ``{leg}.effect<i>.<name>.<label>`` (i from 1)."""
    return [f"{leg}.effect{i + 1}.{m.name}.{lab}" for i, m in enumerate(members) for lab in m.labels]



def _fail(where: str, key: str, what: str) -> DataFormatError:
    return DataFormatError(f"{where}: meta.effect.{key}: {what}", path=where, column=f"meta.effect.{key}")


def free_effects_of(meta: dict, leg: str, where: str, entry: dict) -> FreeEffects | None:
    """The named effects of transducer ``leg`` in a calibration's ``meta`` (None: none named for it), checked: every
    member a library unit with a free face, ``beta`` and ``labels`` of one length, finite numbers. ``entry``: the leg's
    ``calibration.json`` entry (its ``mount_rotation``)."""
    block = meta.get("effect") if isinstance(meta, dict) else None
    if not isinstance(block, dict) or block.get("kind") != KIND:
        return None
    legs = block.get("legs")
    if not isinstance(legs, dict):
        raise _fail(where, "legs", "expected a table of transducers, each with its members")
    if leg not in legs:
        return None
    lb = legs[leg]
    mem = lb.get("members") if isinstance(lb, dict) else None
    if not isinstance(mem, list) or not mem:
        raise _fail(where, f"legs.{leg}.members", "expected a non-empty list of effects")
    out = []
    for i, m in enumerate(mem):
        key = f"legs.{leg}.members[{i}]"
        if not isinstance(m, dict):
            raise _fail(where, key, "expected a table with name, shape, labels and beta")
        name = m.get("name")
        unit = EFFECTS.get(name) if isinstance(name, str) else None
        if not isinstance(name, str) or unit is None or type(unit).free_shapes is Effect.free_shapes:
            raise _fail(where, f"{key}.name", f"{name!r} is not an effect of the library with a free-load face "
                        f"{sorted(n for n, u in EFFECTS.items() if type(u).free_shapes is not Effect.free_shapes)}")
        shape, labels, beta = m.get("shape"), m.get("labels"), m.get("beta")
        if not isinstance(shape, dict):
            raise _fail(where, f"{key}.shape", f"expected a table of {name}'s shape parameters, got {shape!r}")
        if not isinstance(labels, list) or not all(isinstance(s, str) for s in labels):
            raise _fail(where, f"{key}.labels", "expected a list of the parameters' labels")
        try:
            b = np.asarray(beta, float)
        except (TypeError, ValueError):
            b = np.array([np.nan])
        if b.ndim != 1 or len(b) != len(labels) or not np.all(np.isfinite(b)):
            raise _fail(where, f"{key}.beta", f"expected {len(labels)} finite numbers (one per label), got {beta!r}")
        pars = m.get("parameters", {}) if isinstance(m.get("parameters", {}), dict) else {}
        se = np.array([np.inf if not isinstance(pars.get(lab), dict) or pars[lab].get("se") is None
                       else float(pars[lab]["se"]) for lab in labels])
        out.append(Member(name, dict(shape), tuple(labels), b, se))
    ref = lb.get("reference", {})
    if not isinstance(ref, dict):
        raise _fail(where, f"legs.{leg}.reference", "expected a table (t_span_s, ...)")
    E = np.asarray(entry.get("mount_rotation", np.eye(3)), float)
    pos = lb.get("position_m")
    if pos is not None and (np.shape(pos) != (3,) or not np.all(np.isfinite(np.asarray(pos, float)))):
        raise _fail(where, f"legs.{leg}.position_m", f"expected 3 finite numbers (m), got {pos!r}")
    return FreeEffects(leg, tuple(out), dict(ref), E, None if pos is None else np.asarray(pos, float))


def with_covariance(fx: FreeEffects, x_cov: np.ndarray, x_und: np.ndarray, x_names: list[str], cc) -> FreeEffects:
    """``fx`` with the joint covariance over ``x_names + beta names`` from the covariance file ``cc`` (None, or a
    name not in it: the calibration's own ``x_cov`` beside the members' stored se, correlations left out)."""
    block = None if cc is None else cc.block(list(x_names) + fx.beta_names())
    if block is not None:
        C, und, null = block
        return replace(fx, cov=np.where(np.isfinite(C), C, 0.0), undetermined=np.asarray(und, bool), null=null, full_cov=True)
    se = np.concatenate([m.se for m in fx.members])
    var = np.where(np.isfinite(se), se**2, 0.0)
    P = len(x_cov)
    C = np.zeros((P + len(var), P + len(var)))
    C[:P, :P] = x_cov
    C[P:, P:] = np.diag(var)
    log.info("%s: the effects' parameters with their stored se (no joint covariance file: correlations with the "
             "calibration's parameters left out)", fx.leg)
    return replace(fx, cov=C, undetermined=np.concatenate([np.asarray(x_und, bool), np.isinf(se)]), null=None, full_cov=False)


def context(p, fx: FreeEffects, t: np.ndarray, y: np.ndarray, pred: np.ndarray, g_B: np.ndarray,
            quat: np.ndarray | None, q: dict, temperature: np.ndarray | None):
    """The new recording's :class:`~ftcal_nlp.effects.free_faces.FreeLoadContext` (module docstring): ``p`` its
    calibrated load (``freeload.calibrated``: its :meth:`face_pose` gives the load, ``theta``, the joints' limits and
    the ft orientation per sample), ``g_B`` gravity in B (with the calibration's tilt), ``pred`` the model readings.
    The session ``reference`` goes back into ``ctx.extra``: ``t_span`` and every member's ``free_reference_keys``."""
    load, theta, limits, R, E = p.face_pose(q, len(t), fx.mount_rotation)
    g_ft = np.einsum("nji,nj->ni", R, g_B)
    ctx = make_context(fx.leg, t, y, pred, g_ft, g_B=g_B, q=q, joint_limits=limits, quat=quat, temperature=temperature,
                       sigma=p.sigma, load=load, theta=theta, rotation=E, offset=p.offset, names=("recording",))
    ref = fx.reference
    if "t_span_s" in ref:
        ctx.extra["t_span"] = tuple(float(v) for v in ref["t_span_s"])
    for key in dict.fromkeys(k for m in fx.members for k in EFFECTS[m.name].free_reference_keys):
        if ref.get(key) is not None:
            ctx.extra[key] = float(ref[key])
    if fx.position_m is not None:
        ctx.extra["position_m"] = fx.position_m
    return ctx


def _check_recording(fx: FreeEffects, ctx, where: str) -> None:
    """What every member's correction needs of the recording (its unit's ``free_require``: an error naming the
    column), where it extrapolates the session (``free_session_check``: a warning), and a stream for the members that
    follow the readings' own clock (:func:`stream_members`): an error when the recording has no hold of two samples or
    more (a list of single-row poses, its clock one tick per pose): re-sampling 0.5 s later would mix two poses, and
    there is no relaxation between rows that are not a stream."""
    for m in fx.members:
        EFFECTS[m.name].free_require(ctx, m.shape, fx.leg, where)
    for m in fx.members:
        EFFECTS[m.name].free_session_check(ctx, m.shape, fx.reference, fx.leg, where)
    need = stream_members(fx)
    if not need:
        return
    ids, counts = np.unique(ctx.hold[ctx.hold >= 0], return_counts=True)
    if not np.any(counts >= 2):
        raise DataFormatError(
            f"{where}: column t: the recording has no hold of two samples or more (a list of single-row poses?), but "
            f"{fx.leg}'s calibration corrects for {', '.join(need)}, which follow the readings' own clock between changes "
            f"of load (median sample interval here {ctx.dt:.3g} s): correct a stream recorded as the calibration's was, "
            "or correct this one with calibration.json", column="t")


def stream_members(fx: FreeEffects) -> list[str]:
    """The members whose correction follows the readings' own clock (``Effect.follows_stream_clock``: re-sampling,
    relaxation, a rate of turn): ``correct`` needs a stream with t in seconds for them."""
    return [m.name for m in fx.members if EFFECTS[m.name].follows_stream_clock]


def _overrides(unit) -> bool:
    return type(unit).free_correct is not Effect.free_correct


def correct_readings(p, fx: FreeEffects, ctx, where: str = "recording") -> tuple[np.ndarray, list]:
    """``(y_c (N, 6), D)``: the readings corrected for every member (module docstring) and the derivative parts of
    ``y_c`` in the members' parameters (:func:`derivative_rows` forms them)."""
    _check_recording(fx, ctx, where)
    y = ctx.y
    yc = y.copy()
    parts, c0 = [], 0
    for m in fx.members:
        unit = EFFECTS[m.name]
        c = np.asarray(unit.free_correct(ctx, m.shape, m.beta), float)
        if c.shape != y.shape:
            raise DataFormatError(f"{where}: effect {m.name} (shape {m.shape}) does not apply to this recording", path=where)
        yc += c - y
        k = len(m.beta)
        if _overrides(unit):   # central differences of the unit's own correction
            D = np.zeros((ctx.n, 6, k))
            for j in range(k):
                h = DIFF_STEP * max(1.0, abs(float(m.beta[j])))
                bp, bm = m.beta.copy(), m.beta.copy()
                bp[j] += h
                bm[j] -= h
                D[:, :, j] = (unit.free_correct(ctx, m.shape, bp) - unit.free_correct(ctx, m.shape, bm)) / (2 * h)
            parts.append(("dense", c0, D))
        else:                  # y - X beta: D = -X, as the face's channel blocks
            face = unit.free_face(ctx, m.shape)
            if face is None:
                log.info("%s: effect %s of %s: its face is zero on this recording (nothing to correct)", where, m.name, fx.leg)
            else:
                if face.k != k:
                    raise DataFormatError(f"{where}: meta.effect member {m.name} of {fx.leg} has {k} parameters, its face "
                                          f"on this recording {face.k} ({face.names}); expected the calibration's",
                                          path=where, column=f"meta.effect.legs.{fx.leg}")
                parts.append(("blocks", c0, face.channel_blocks()))
        c0 += k
    log.info("%s: %s corrected for %s (joint refit, as fitted: the corrections add)", where, fx.leg,
             ", ".join(m.name for m in fx.members))
    return yc, parts


def derivative_rows(parts: list, k: int, rows: slice) -> np.ndarray:
    """``D`` (rows, 6, k) of the corrected readings in the members' parameters (:func:`correct_readings`)."""
    n = rows.stop - rows.start
    D = np.zeros((n, 6, k))
    for kind, c0, data in parts:
        if kind == "dense":
            D[:, :, c0: c0 + data.shape[2]] = data[rows]
        else:
            for c, cols, B in data:
                D[:, c, c0 + cols] = -B[rows]
    return D


def joint_variance(J: np.ndarray, fx: FreeEffects, parts: list) -> np.ndarray:
    """``diag([J_x, -D] C [J_x, -D]^T)`` (N, 6) (module docstring), in blocks of ``FREE_CHUNK`` rows; inf where the
    row has a component along an undetermined direction (``loads.base.calibration_variance``)."""
    n = len(J)
    out = np.empty((n, 6))
    ns = SimpleNamespace(cov=fx.cov, null=fx.null, undetermined=fx.undetermined)
    for a in range(0, n, FREE_CHUNK):
        rows = slice(a, min(a + FREE_CHUNK, n))
        Jf = np.concatenate([J[rows], -derivative_rows(parts, fx.k, rows)], axis=2)
        out[rows] = calibration_variance(ns, Jf)
    return out
