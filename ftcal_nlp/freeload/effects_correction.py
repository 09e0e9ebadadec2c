"""A free-load calibration refit with the diagnosis' named effects, and their correction of new recordings (issue 23,
item 3): what ``calibration_with_effect.json`` holds for payloads and URDF loads (``DATA_FORMAT.md`` section 5) and
what ``correct`` applies.

**Written** by a run whose free-load diagnosis named effects (:func:`free_effect_calibration`). Per transducer, the chain's
joint refit (``diagnose/chain.joint_fit``): the free-load model linearised around its fit ``x*`` and every named
effect's face, fitted together on every sample (weights ``1 / floor``)::

    y_n - h(x*; s_n) = J_n dx + sum_i X_i,n beta_i + e_n

The file holds

* the free-load calibration at ``x* + dx`` (one Gauss-Newton step: offsets, load parameters and tilts add, the mount
  turns ``E = E* expm([dr]x)``), with the keys of ``calibration.json``; ``noise_sd`` is the diagnosis' noise floor
  (held, still stretches), what is left of the readings once the effects are corrected;
* ``meta.effect``: ``{"name": "a+b", "kind": "free_load", "legs": {X: {"members": [...], "reference": {...}}}}``, each
  member ``{"name", "shape", "labels", "beta", "parameters": {label: {"value", "se"}}}`` in chain order, and the
  ``reference`` a face computes from the whole calibration session that a new recording cannot: ``t_span_s`` (the
  session span a time polynomial is scaled to), ``change_point_s`` (offset_drift's step), ``temperature_mean_C``
  (the lagged temperature's mean a temperature face is centred on); ``position_m`` the ft origin in B (an inertial
  face's lever, from ``robot.toml``);
* the covariance file ``calibration_with_effect_cov.npz`` (``meta.covariance_file``): per transducer the joint
  covariance of ``[x, beta_1 .. beta_m]``, ``C = s^2 G^+`` (``G`` the joint refit's weighted normal matrix, ``s^2`` its
  weighted residual variance with the AR(1) inflation), the directions ``G`` leaves undetermined in ``null``;
  labels ``{X}.<param>`` as ``calibration_cov.npz`` and ``{X}.effect<i>.<name>.<label>`` for ``beta_i``.
  Transducers without an effect keep their estimator's block.

**Applied** by ``correct`` (:func:`correct_readings`, called by ``correct_loads.contact_wrench``): the new recording's
context is rebuilt (``effects.free_faces.make_context``: its time, readings, the calibration's model readings
``pred_n = h(x; s_n)``, gravity in ft, joint angles, orientation, temperature; holds from the rates; the
``reference`` in ``ctx.extra``), then every member's own correction ``c_i = unit_i.free_correct(ctx, shape_i, beta_i)``::

    y_c = y + sum_i (c_i - y),          w_contact = y_c - h(x; s_n)

every member evaluated on the same context, as fitted (the faces built from the model readings take them at the
refit ``x* + dx``, where the diagnosis took them at ``x*``: a second-order difference, ``dx`` times ``beta``). Why the sum and not a composition in chain order: the joint
fit is a sum of faces, each built from the same recorded context; for a unit whose correction is its face's
subtraction (the default ``y - X beta``) the sum is exactly ``y - sum_i X_i beta_i``, the fitted model; a unit that
overrides it (``clock_offset``: the readings re-sampled ``delay_s`` later) replaces its linearised face by the exact
shift, equal to first order and moving the contact wrench in step too. A composition would build later corrections
from readings the fit never saw.

**Standard errors** (first order)::

    Var(w_contact) = [J_x, -D] C [J_x, -D]^T + diag(sigma^2),     D_i = d c_i / d beta_i

``J_x`` the model's derivative (``correct_loads``), ``D_i = -X_i`` for the default correction and central differences
of ``free_correct`` for a unit that overrides it; ``C`` the joint covariance (the cross terms between the calibration
and the effects included); ``sigma`` the noise floor. Left out: the uncertainty of the shapes (time constants, lags,
the delay grid's order: chosen by held-out evidence and held fixed) and the noise the re-sampling carries over.
Without the covariance file the stored se serve (diagonal: correlations left out, logged).

An effect that needs a signal the new recording lacks is an error naming the column: ``temperature`` (``{X}_temp_C``
or ``temp_C``), ``joint_limit_contact`` (``q_<joint>``), ``inertial_load`` (``qw..qz``: a rate of turn needs the
orientation). A face that is zero on the recording (no change of load for creep, no joint near its stop) corrects
nothing. A time polynomial (``offset_drift``) is evaluated on the session's clock: samples outside the session's span
are named in a warning (extrapolated there). A calibration without ``meta.effect`` is corrected as before.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from ..errors import DataFormatError
from ..geometry import rotvec_to_rotation
from ..loads.base import calibration_variance

log = logging.getLogger(__name__)

KIND = "free_load"
COVARIANCE_FILE = "calibration_with_effect_cov.npz"
#: rows per block of the variance (the (rows, 6, P + K) Jacobian stays a few MB)
CHUNK = 8192
#: relative step of the central differences of an overriding unit's correction in its parameters
DIFF_STEP = 1e-6
#: the signals an effect's correction needs and the columns that carry them (what the error names)
NEEDS = {"temperature": "temperature", "joint_limit_contact": "joint", "inertial_load": "orientation"}


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


# ---------------------------------------------------------------------------------------------- written by a run

def joint_covariance(jf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(C, undetermined, null)`` of the joint refit ``jf`` (``chain.JointFit``) over ``[dx, beta_1 .. beta_m]``:
    ``C = s^2 G^+`` (finite: zero rows where undetermined), as ``chain.joint_fit``'s se."""
    from ..diagnose.free_cv import null_directions, pinv

    if jf.G is None:
        raise ValueError("the joint refit carries no normal matrix (chain.JointFit.G)")
    Gi, und = pinv(jf.G)
    C = Gi * jf.s2
    C[und, :] = 0.0
    C[:, und] = 0.0
    return C, und, null_directions(jf.G)


def refit_result(fit, leg_diag):
    """The transducer's ``freeload.FreeLoadResult`` at the joint refit ``x* + dx`` (module docstring) with the joint
    covariance's block of the free-load parameters and the noise floor as ``sigma``; and ``(C, undetermined, null)``
    over ``[x, betas]``."""
    jf = leg_diag.joint
    C, und, null = joint_covariance(jf)
    P = len(fit.names)
    dx = np.asarray(jf.dx, float)
    p = len(fit.theta)
    at = 6 + p
    tilt = None
    if fit.tilt is not None:
        tilt, at = np.asarray(fit.tilt, float) + dx[at: at + 2], at + 2
    rec_tilts = {}
    for r, v in fit.recording_tilts.items():
        rec_tilts[r], at = np.asarray(v, float) + dx[at: at + 2], at + 2
    se = np.where(und[:P], np.inf, np.sqrt(np.clip(np.diag(C)[:P], 0.0, None)))
    Nx = null[:P]
    Nx = Nx[:, np.abs(Nx).max(axis=0) > 1e-12] if Nx.size else Nx
    floor = np.asarray(leg_diag.floor, float) if leg_diag.floor_known else np.asarray(fit.sigma, float)
    names = [s.effect.name for s in leg_diag.chain.steps]
    note = (f"{fit.leg}: refit jointly with {', '.join(names)} on every sample (one Gauss-Newton step from the "
            "free-load fit; diagnose/chain.py joint_fit); se and covariance are the joint refit's, the descriptions "
            "of undetermined directions the free-load fit's, its determined combinations not recomputed (left out)")
    out = replace(fit, offset=np.asarray(fit.offset, float) + dx[:6], theta=np.asarray(fit.theta, float) + dx[6: 6 + p],
                  rotation=np.asarray(fit.rotation, float) @ rotvec_to_rotation(dx[P - 3:]), tilt=tilt,
                  recording_tilts=rec_tilts, cov=C[:P, :P].copy(), se=se, null=Nx if Nx.shape[1] else None,
                  sigma=floor.copy(), determined=(), notes=[*fit.notes, note])
    return out, (C, und, null)


def reference_of(ctx, members) -> dict:
    """What the members' faces compute from the whole calibration session (module docstring), from its context."""
    ref = {"t_span_s": [float(ctx.t.min()), float(ctx.t.max())]}
    for m in members:
        if m.name == "offset_drift" and m.shape.get("step"):
            from ..effects.offset_drift import change_point

            ref["change_point_s"] = change_point(ctx)
        if m.name == "temperature" and ctx.temperature is not None:
            ref["temperature_mean_C"] = float(np.mean(lagged_temperature(ctx, float(m.shape["lag_s"]))))
    return ref


def lagged_temperature(ctx, lag: float) -> np.ndarray:
    """The temperature lagged by ``lag`` s within each recording, as the temperature face lags it (the same function)."""
    from ..effects.temperature import Temperature

    return Temperature.lagged(ctx, lag)


def _members(leg_diag) -> tuple[Member, ...]:
    jf = leg_diag.joint
    out = []
    for s, pars, beta in zip(leg_diag.chain.steps, jf.params, jf.betas):
        se = np.array([pars[n][1] for n in s.face.names], float)
        out.append(Member(s.effect.name, dict(s.shape), tuple(s.face.names), np.asarray(beta, float).copy(), se))
    return tuple(out)


def _json_num(v: float):
    return float(v) if np.isfinite(v) else None


def members_json(members, reference: dict, floor, position_m=None) -> dict:
    """A transducer's entry of ``meta.effect.legs`` (``position_m``: the ft origin in B, an inertial face's lever)."""
    return {**({} if position_m is None else {"position_m": [float(v) for v in position_m]}),
            "members": [{"name": m.name, "shape": m.shape, "labels": list(m.labels), "beta": [float(b) for b in m.beta],
                         "parameters": {lab: {"value": float(b), "se": _json_num(e)}
                                        for lab, b, e in zip(m.labels, m.beta, m.se)}} for m in members],
            "reference": reference, "noise_floor": [float(x) for x in floor]}


def free_effect_calibration(res):
    """``(Calibration, CalibrationCovariance)`` of ``calibration_with_effect.json`` and its covariance file for a
    free-load run ``res`` (``CalibrationRun``) whose diagnosis named effects; None when it named none."""
    from ..diagnose.free_model import context_for
    from ..freeload import free_load_calibration
    from ..freeload.result import FreeLoadResults
    from ..uncertainty import CalibrationCovariance

    d = res.diagnosis
    free = getattr(d, "free", None) or {}
    named = {k: v for k, v in free.items() if v.chain.steps and v.joint is not None and v.joint.G is not None}
    if res.free_loads is None or not named:
        return None
    legs, blocks, parts = {}, {}, []
    for k, fit in res.free_loads.legs.items():
        if k not in named:
            legs[k] = fit
            C = np.where(np.isfinite(fit.cov), fit.cov, 0.0)
            N = np.zeros((len(fit.names), 0)) if fit.null is None else np.asarray(fit.null, float)
            parts.append((list(fit.names), C, np.isinf(np.asarray(fit.se, float)), N))
            continue
        ld = named[k]
        legs[k], (C, und, null) = refit_result(fit, ld)
        members = _members(ld)
        ctx, _ = context_for(res.dataset, k, fit)
        blocks[k] = members_json(members, reference_of(ctx, members), legs[k].sigma, ctx.extra.get("position_m"))
        parts.append((list(fit.names) + beta_names(k, members), C, und, null))
    P = sum(len(n) for n, *_ in parts)
    cov, und_all = np.zeros((P, P)), np.zeros(P, bool)
    null_all = np.zeros((P, sum(N.shape[1] for *_, N in parts)))
    i = j = 0
    for names, C, und, N in parts:
        n = len(names)
        cov[i: i + n, i: i + n] = C
        und_all[i: i + n] = und
        null_all[i: i + n, j: j + N.shape[1]] = N
        i, j = i + n, j + N.shape[1]
    cc = CalibrationCovariance(tuple(n for names, *_ in parts for n in names), cov, und_all, None, null_all)
    results = FreeLoadResults(legs)
    cal = free_load_calibration(results, res.dataset.robot, res.dataset.hanging)
    order = list(dict.fromkeys(m["name"] for b in blocks.values() for m in b["members"]))
    effect = {"name": "+".join(order), "kind": KIND, "legs": blocks,
              "covariance": (f"{COVARIANCE_FILE}: per transducer the joint covariance of the free-load parameters and "
                             "every member's beta (labels {X}.effect<i>.<name>.<label>)")}
    meta = {**res.calibration.meta, "covariance_file": COVARIANCE_FILE, "effect": effect}
    meta.pop("covariance_note", None)
    return replace(cal, meta=meta), cc


# ---------------------------------------------------------------------------------------------- read by correct

def _fail(where: str, key: str, what: str) -> DataFormatError:
    return DataFormatError(f"{where}: meta.effect.{key}: {what}", path=where, column=f"meta.effect.{key}")


def free_effects_of(meta: dict, leg: str, where: str, entry: dict) -> FreeEffects | None:
    """The named effects of transducer ``leg`` in a calibration's ``meta`` (None: none named for it), checked: every
    member a library unit with a free face, ``beta`` and ``labels`` of one length, finite numbers. ``entry``: the leg's
    ``calibration.json`` entry (its ``mount_rotation``)."""
    from ..effects import EFFECTS, Effect

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
        if unit is None or type(unit).free_shapes is Effect.free_shapes:
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


def _require(fx: FreeEffects, ctx, where: str) -> None:
    """A clear error naming the column when a member needs a signal the recording lacks (module docstring)."""
    for m in fx.members:
        need = NEEDS.get(m.name)
        if need == "temperature" and ctx.temperature is None:
            raise DataFormatError(f"{where}: the calibration's effect temperature of transducer {fx.leg} needs the "
                                  f"transducer's temperature: column '{fx.leg}_temp_C' (or 'temp_C'), degC",
                                  path=where, column=f"{fx.leg}_temp_C")
        if need == "joint" and m.shape.get("joint") not in ctx.q:
            col = f"q_{m.shape.get('joint')}"
            raise DataFormatError(f"{where}: the calibration's effect joint_limit_contact of transducer {fx.leg} needs "
                                  f"the joint's angle: column '{col}' (rad)", path=where, column=col)
        if need == "orientation" and ctx.quat is None:
            raise DataFormatError(f"{where}: the calibration's effect inertial_load of transducer {fx.leg} needs the "
                                  "orientation stream: columns qw, qx, qy, qz (gx..gz give no rate of turn)",
                                  path=where, column="qw")
        if m.name == "clock_offset" and ctx.n < 4:
            raise DataFormatError(f"{where}: the calibration's effect clock_offset re-samples the readings: at least 4 "
                                  f"rows needed, got {ctx.n}", path=where, column="t")


#: samples this far (share of the session's span) outside it are named: a time polynomial extrapolated
SPAN_MARGIN = 0.01


def _check_span(fx: FreeEffects, ctx, where: str) -> None:
    """A warning when a time polynomial (offset_drift) is evaluated outside the calibration session's span: the
    recording must share the session's clock, and beyond the span the polynomial is extrapolated."""
    if not any(m.name == "offset_drift" for m in fx.members) or "t_span_s" not in fx.reference:
        return
    lo, hi = (float(v) for v in fx.reference["t_span_s"])
    pad = SPAN_MARGIN * (hi - lo)
    out = int(np.sum((ctx.t < lo - pad) | (ctx.t > hi + pad)))
    if out:
        log.warning("%s: %d of %d samples lie outside the calibration session's span t = %.6g..%.6g s: the offset_drift "
                    "polynomial of %s is extrapolated there (the recording must share the session's clock)",
                    where, out, ctx.n, lo, hi, fx.leg)


#: effects whose correction follows the readings' own clock between changes of load: a clock offset re-samples the
#: stream, creep relaxes after each change, the inertial wrench differentiates the orientation over time
STREAM_EFFECTS = ("clock_offset", "creep", "inertial_load")


def _check_stream(fx: FreeEffects, ctx, where: str) -> None:
    """An error when a recording without a hold of two samples or more (a list of single-row poses, its clock one
    tick per pose) is to be corrected for an effect that follows the stream's clock (``STREAM_EFFECTS``): re-sampling
    0.5 s later would mix two poses, and there is no relaxation between rows that are not a stream."""
    need = [m.name for m in fx.members if m.name in STREAM_EFFECTS]
    if not need:
        return
    ids, counts = np.unique(ctx.hold[ctx.hold >= 0], return_counts=True)
    if not np.any(counts >= 2):
        raise DataFormatError(
            f"{where}: column t: the recording has no hold of two samples or more (a list of single-row poses?), but "
            f"{fx.leg}'s calibration corrects for {', '.join(need)}, which follow the readings' own clock between changes "
            f"of load (median sample interval here {ctx.dt:.3g} s): correct a stream recorded as the calibration's was, "
            "or correct this one with calibration.json", column="t")


def context(p, fx: FreeEffects, t: np.ndarray, y: np.ndarray, pred: np.ndarray, g_B: np.ndarray,
            quat: np.ndarray | None, q: dict, temperature: np.ndarray | None):
    """The new recording's :class:`~ftcal_nlp.effects.free_faces.FreeLoadContext` (module docstring): ``p`` its
    ``correct_loads`` calibration, ``g_B`` gravity in B (with the calibration's tilt), ``pred`` the model readings."""
    from ..effects.free_faces import make_context
    from ..loads import RigidPayload

    n = len(t)
    E = fx.mount_rotation
    if hasattr(p, "load"):                                   # a URDF load: the sensor's pose moves with the joints
        from ..diagnose.free_model import _limits

        load, theta, limits = p.load, p.theta, _limits(p.load)
        R = load.nominal_rotation(q, n) @ p.E
        E = p.E
    else:
        load, theta, limits = RigidPayload(p.R_B_ft @ E.T), np.r_[p.mass_kg, p.h], {}
        R = np.broadcast_to(p.R_B_ft, (n, 3, 3))
    g_ft = np.einsum("nji,nj->ni", R, g_B)
    ctx = make_context(fx.leg, t, y, pred, g_ft, g_B=g_B, q=q, joint_limits=limits, quat=quat, temperature=temperature,
                       sigma=p.sigma, load=load, theta=theta, rotation=E, names=("recording",))
    ref = fx.reference
    if "t_span_s" in ref:
        ctx.extra["t_span"] = tuple(float(v) for v in ref["t_span_s"])
    if ref.get("change_point_s") is not None:
        ctx.extra["change_point_s"] = float(ref["change_point_s"])
    if "temperature_mean_C" in ref:
        ctx.extra["temperature_mean_C"] = float(ref["temperature_mean_C"])
    if fx.position_m is not None:
        ctx.extra["position_m"] = fx.position_m
    return ctx


def _overrides(unit) -> bool:
    from ..effects import Effect

    return type(unit).free_correct is not Effect.free_correct


def correct_readings(p, fx: FreeEffects, ctx, where: str = "recording") -> tuple[np.ndarray, list]:
    """``(y_c (N, 6), D)``: the readings corrected for every member (module docstring) and the derivative parts of
    ``y_c`` in the members' parameters (:func:`derivative_rows` forms them)."""
    from ..effects import EFFECTS

    _require(fx, ctx, where)
    _check_span(fx, ctx, where)
    _check_stream(fx, ctx, where)
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
    """``diag([J_x, -D] C [J_x, -D]^T)`` (N, 6) (module docstring), in blocks of ``CHUNK`` rows; inf where the row
    has a component along an undetermined direction (``loads.base.calibration_variance``)."""

    n = len(J)
    out = np.empty((n, 6))
    ns = SimpleNamespace(cov=fx.cov, null=fx.null, undetermined=fx.undetermined)
    for a in range(0, n, CHUNK):
        rows = slice(a, min(a + CHUNK, n))
        Jf = np.concatenate([J[rows], -derivative_rows(parts, fx.k, rows)], axis=2)
        out[rows] = calibration_variance(ns, Jf)
    return out
