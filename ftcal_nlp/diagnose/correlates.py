"""Where a free load's gap lies: the residual against every correlate the data carry (issue 23, item 4).

Each correlate gives a flexible, effect-free basis per channel (columns act on one channel each, the
face convention of ``effects/free_faces.py``); the residual's dependence on it is scored like an effect,
by the blocked cross-validation of ``free_cv.py`` with the free-load model's Jacobian beside it, as the
share of the held-out excess over the floor it removes:

    explained = (SSE_base - SSE_corr) / (SSE_base - SSE_floor),   SSE_floor = 6 N (unit weighted variance)

* ``time``: Legendre ``P_1..P_6`` of the session time;
* ``joint:<name>``: each moving joint angle, piecewise-linear hat functions on ``HAT_KNOTS`` quantile knots
  (a wrench that appears near a limit is local in the angle, which a polynomial would smear);
* ``motion``: the rates: of gravity in ft (the body's turn), of the model's wrench, ``|omega|``, each
  joint's rate and acceleration (and the body's rate of turn from the orientation stream);
* ``load``: the load's history: its last change times a decay ``exp(-s / tau)`` of the time since it
  (``tau`` in ``LOAD_TAUS_S``), what a relaxation after each change of load follows;
* ``pose_history``: the last change of load itself, held through the hold (where the load came from);
* ``temperature``: hat functions of the temperature, when the recordings carry it.

The top correlate (the largest ``explained``, at least ``explained_min`` of ``DiagnoseSettings.free_loads``) is
``where.explains`` (``free.py``); the residual's channel with the largest gap against it is what the report plots.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..effects.free_faces import FreeFace, FreeLoadContext, session_time_basis
from .free_cv import CVFit, Design

HAT_KNOTS = 8
LOAD_TAUS_S = (0.5, 2.0, 8.0, 30.0)


def hats(x: np.ndarray, knots: int = HAT_KNOTS) -> np.ndarray:
    """Piecewise-linear hat functions (N, knots) on quantile knots of ``x`` (their sum is 1: the constant is in it)."""
    x = np.asarray(x, float)
    k = np.unique(np.quantile(x, np.linspace(0, 1, knots)))
    if len(k) < 2:
        return np.zeros((len(x), 0))
    return np.stack([np.interp(x, k, np.eye(len(k))[j]) for j in range(len(k))], axis=1)


def _face(basis: np.ndarray, label: str) -> FreeFace | None:
    basis = np.asarray(basis, float)
    if basis.ndim == 1:
        basis = basis[:, None]
    keep = np.ptp(basis, axis=0) > 0
    if not keep.any():
        return None
    return FreeFace.per_channel(basis if keep.all() else basis[:, keep], tuple(f"{label}{j}" for j in range(int(keep.sum()))))


def correlate_faces(ctx: FreeLoadContext) -> dict[str, tuple[FreeFace, np.ndarray, str]]:
    """``{name: (face, x for the figure, x label)}`` of every correlate the data carry (module docstring)."""
    out = {}
    if np.ptp(ctx.t) > 0:
        f = _face(session_time_basis(ctx, 6), "P")
        if f is not None:
            out["time"] = (f, ctx.t - ctx.t.min(), "session time since the first sample [s]")
    for j, q in ctx.q.items():
        f = _face(hats(q), "hat")
        if f is not None:
            out[f"joint:{j}"] = (f, q, f"joint angle {j} [rad]")
    mot = [ctx.g_rate, ctx.pred_rate, ctx.omega[:, None]]
    for j in ctx.q:
        mot += [ctx.qd[j][:, None], ctx.qdd[j][:, None]]
    if ctx.omega_B is not None:
        mot.append(ctx.omega_B)
    f = _face(np.concatenate(mot, axis=1), "rate")
    if f is not None:
        out["motion"] = (f, ctx.omega, "rate of turn of gravity in ft [rad/s]")
    if ctx.hold.max() >= 0:
        # the decays written side by side into one array (no per-tau copies to concatenate)
        dec = np.empty((ctx.n, 6 * len(LOAD_TAUS_S)))
        for k, tau in enumerate(LOAD_TAUS_S):
            np.multiply(ctx.load_step, np.exp(-ctx.since_change / tau)[:, None], out=dec[:, 6 * k:6 * k + 6])
        dec[ctx.hold < 0] = 0.0
        f = _face(dec, "decay")
        if f is not None:
            out["load"] = (f, ctx.since_change, "time since the last change of load [s]")
        f = _face(ctx.load_step, "step")
        if f is not None:
            out["pose_history"] = (f, np.linalg.norm(ctx.load_step[:, :3], axis=1), "size of the last change of load (force) [N]")
    if ctx.temperature is not None and np.ptp(ctx.temperature) > 0:
        f = _face(hats(ctx.temperature), "hat")
        if f is not None:
            out["temperature"] = (f, ctx.temperature, "temperature [degC]")
    return out


@dataclass(frozen=True)
class CorrelateScore:
    name: str
    explained: float
    heldout_rms: np.ndarray
    x: np.ndarray
    xlabel: str
    face: FreeFace | None = field(repr=False)   # kept for the best correlate only (its wrench), else None
    beta: np.ndarray = field(repr=False)         # the face's coefficients in the all-sample fit

    @cached_property
    def wrench(self) -> np.ndarray | None:
        """(N, 6) the correlate's fitted wrench (all samples), formed on demand; the best correlate's only (the one
        ``where`` may use), None for the others."""
        return None if self.face is None else self.face.wrench(self.beta)


def score_correlates(design: Design, J: FreeFace, base: CVFit, ctx: FreeLoadContext,
                     extra: list | None = None) -> list[CorrelateScore]:
    """Every correlate (module docstring) scored on ``design`` beside the Jacobian ``J`` (and ``extra`` face columns,
    the faces of the effects already named), best first."""
    floor_sse = 6.0 * design.n
    excess = max(base.sse - floor_sse, 1e-300)
    out = []
    X0 = [J] + list(extra or [])
    for name, (face, x, label) in correlate_faces(ctx).items():
        cv = design.fit(X0 + [face])
        design.forget(face)
        out.append(CorrelateScore(name, float((base.sse - cv.sse) / excess), cv.rms(), x, label, face, cv.beta[-face.k:]))
    out = sorted(out, key=lambda s: -s.explained)
    return out[:1] + [dataclasses.replace(s, face=None) for s in out[1:]]   # no face kept but the best's
