"""``calibration_with_effect.json`` of a free-load run whose diagnosis named effects (issue 23, item 3): the free-load
calibration refit with them, and its joint covariance file; ``correct`` applies it (``effects/correction.py``).

Per transducer, the chain's joint refit (``chain.joint_fit``): the free-load model linearised around its fit ``x*``
and every named effect's face, fitted together on every sample (weights ``1 / floor``)::

    y_n - h(x*; s_n) = J_n dx + sum_i X_i,n beta_i + e_n

The file holds

* the free-load calibration at the joint refit (``diagnose/free.py`` ``relinearised``: two Gauss-Newton steps from
  ``x*``, ``FreeLoadResult.moved``: offsets, load parameters and tilts add, the mount turns ``E = E* expm([dr]x)``),
  with the keys of ``calibration.json``; ``noise_sd`` is the diagnosis' noise floor
  (held, still stretches), what is left of the readings once the effects are corrected;
* ``meta.effect``: ``{"name": "a+b", "kind": "free_load", "legs": {X: {"members": [...], "reference": {...}}}}``, each
  member ``{"name", "shape", "labels", "beta", "parameters": {label: {"value", "se"}}}`` in chain order, and the
  ``reference`` a face computes from the whole calibration session that a new recording cannot: ``t_span_s`` (the
  session span a time polynomial is scaled to) and what each unit's ``free_reference`` keeps (offset_drift's
  ``change_point_s``, temperature's ``temperature_mean_C``); ``position_m`` the ft origin in B (an inertial face's
  lever, from ``robot.toml``);
* the covariance file ``calibration_with_effect_cov.npz`` (``meta.covariance_file``): per transducer the joint
  covariance of ``[x, beta_1 .. beta_m]``, ``C = s^2 G^+`` (``G`` the joint refit's weighted normal matrix, ``s^2`` its
  weighted residual variance with the AR(1) inflation), the directions ``G`` leaves undetermined in ``null``;
  labels ``{X}.<param>`` as ``calibration_cov.npz`` and ``{X}.effect<i>.<name>.<label>`` for ``beta_i``.
  Transducers without an effect keep their estimator's block.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..effects.correction import KIND, Member, beta_names
from ..effects.registry import EFFECTS
from .free_cv import null_directions, pinv
from .free_model import context_for

COVARIANCE_FILE = "calibration_with_effect_cov.npz"


def joint_covariance(jf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(C, undetermined, null)`` of the joint refit ``jf`` (``chain.JointFit``) over ``[dx, beta_1 .. beta_m]``:
    ``C = s^2 G^+`` (finite: zero rows where undetermined), as ``chain.joint_fit``'s se."""
    if jf.G is None:
        raise ValueError("the joint refit carries no normal matrix (chain.JointFit.G)")
    Gi, und = pinv(jf.G)
    C = Gi * jf.s2
    C[und, :] = 0.0
    C[:, und] = 0.0
    return C, und, null_directions(jf.G)


def refit_result(fit, leg_diag):
    """The transducer's ``freeload.FreeLoadResult`` at the joint refit (module docstring: ``leg_diag.refit``) with the
    joint covariance's block of the free-load parameters and the noise floor as ``sigma``; and ``(C, undetermined,
    null)`` over ``[x, betas]``."""
    jf = leg_diag.joint
    C, und, null = joint_covariance(jf)
    P = len(fit.names)
    se = np.where(und[:P], np.inf, np.sqrt(np.clip(np.diag(C)[:P], 0.0, None)))
    Nx = null[:P]
    Nx = Nx[:, np.abs(Nx).max(axis=0) > 1e-12] if Nx.size else Nx
    floor = np.asarray(leg_diag.floor, float) if leg_diag.floor_known else np.asarray(fit.sigma, float)
    names = [s.effect.name for s in leg_diag.chain.steps]
    note = (f"{fit.leg}: refit jointly with {', '.join(names)} on every sample (linearised around the free-load fit, "
            "relinearised once: diagnose/free.py relinearised); se and covariance are the joint refit's, the descriptions "
            "of undetermined directions the free-load fit's, its determined combinations not recomputed (left out)")
    assert leg_diag.refit is not None, "a joint refit comes with its free-load fit (diagnose/free.py relinearised)"
    out = replace(leg_diag.refit, cov=C[:P, :P].copy(), se=se, null=Nx if Nx.shape[1] else None,
                  sigma=floor.copy(), determined=(), notes=[*fit.notes, note])
    return out, (C, und, null)


def reference_of(ctx, members) -> dict:
    """What the members' faces compute from the whole calibration session (``t_span_s`` and each unit's
    ``free_reference``), from its context: ``correction.context`` puts it back for a new recording."""
    ref = {"t_span_s": [float(ctx.t.min()), float(ctx.t.max())]}
    for m in members:
        ref.update(EFFECTS[m.name].free_reference(ctx, m.shape))
    return ref


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
    from ..estimate.freeload import free_load_calibration
    from ..estimate.freeload.result import FreeLoadResults
    from ..estimate.uncertainty import CalibrationCovariance

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
