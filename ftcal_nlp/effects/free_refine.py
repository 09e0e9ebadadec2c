"""Refining a free face's nonlinear shape on the residual (the ``free_refine`` hook of ``free_faces.py``).

A face's grid point is refined by minimising, over the shape parameter(s) ``p``, the weighted residual
sum of squares of

    r = J dx + X(p) beta + e

``r`` the residual the diagnosis hands over, ``X(p)`` the face's columns for shape ``p``, ``J`` the
free-load model's own first-order columns (:func:`model_columns`: the offsets, the load's parameters
``theta`` and a small turn ``dr`` of the mounting, which took up part of the effect when the load was
fitted), channels weighted by the floor ``1 / sigma``. One parameter: a bounded scalar search
(:func:`refine_scalar`); several: Nelder-Mead (:func:`refine_simplex`).

Model readings of a linear load (``loads.base``): ``[m g_ft; s x g_ft] + w_o`` with ``m = mu theta``,
``s = K theta`` and ``g_ft`` with the fitted mounting rotation; a turn ``dr`` gives ``dg_ft = g_ft x dr``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.optimize import minimize, minimize_scalar


def model_columns(ctx) -> np.ndarray:
    """First-order columns (N, 6, 6 + p + 3) of the free-load model (module docstring): offsets, ``theta``, ``dr``;
    only the offsets without a fitted load in the context."""
    n = ctx.n
    cols = [np.broadcast_to(np.eye(6), (n, 6, 6))]
    load, theta = ctx.load, ctx.theta
    if load is not None and theta is not None:
        theta = np.asarray(theta, float)
        K = ctx.extra.get("K")
        K = np.broadcast_to(load.lever(ctx.q, n) if K is None else K, (n, 3, len(theta)))
        mu = np.asarray(load.mass_row, float)
        g = ctx.g_ft
        m, s = float(mu @ theta), np.einsum("nij,j->ni", K, theta)
        Jt = np.concatenate([g[:, :, None] * mu[None, None, :], np.cross(np.moveaxis(K, 2, 1), g[:, None, :]).transpose(0, 2, 1)], axis=1)
        dg = np.stack([np.cross(g, e) for e in np.eye(3)], axis=2)                     # (N, 3, 3): d g_ft / d dr_k
        Jr = np.concatenate([m * dg, np.cross(s[:, None, :], np.moveaxis(dg, 2, 1)).transpose(0, 2, 1)], axis=1)
        cols += [Jt, Jr]
    return np.concatenate(cols, axis=2)


def model_face(ctx):
    """:func:`model_columns` as a :class:`~.free_faces.FreeFace` (its channel blocks: each channel's 1 + p + 3
    non-zero columns), built once per context (cached in ``ctx.extra``, rebuilt for a context of other samples)."""
    from .free_faces import FreeFace

    c = ctx.extra.get("_model_face")
    if c is None or c[0] is not ctx.g_ft or c[1] is not ctx.theta:
        X = model_columns(ctx)
        names = tuple(f"m{j}" for j in range(X.shape[2]))
        # the channel blocks only (the dense array is mostly zeros)
        face = FreeFace(None, names, blocks=FreeFace(X, names).channel_blocks())
        c = ctx.extra["_model_face"] = (ctx.g_ft, ctx.theta, face)
    return c[2]


def use_model_face(ctx, face) -> None:
    """Let the refinements of ``ctx`` use ``face`` (a :class:`~.free_faces.FreeFace` of the free-load model's
    first-order columns, e.g. the diagnosis' own Jacobian) instead of building :func:`model_columns` again."""
    ctx.extra["_model_face"] = (ctx.g_ft, ctx.theta, face)


def _gram(a, b, w2: np.ndarray) -> np.ndarray:
    """``sum_n X_a,n^T W^2 X_b,n`` (ka, kb) from two faces' channel blocks."""
    out = np.zeros((a.k, b.k))
    ab = {c: (cols, B) for c, cols, B in a.channel_blocks()}
    for c, cols_b, Bb in b.channel_blocks():
        if c in ab:
            cols_a, Ba = ab[c]
            out[np.ix_(cols_a, cols_b)] += w2[c] * (Ba.T @ Bb)
    return out


def _rhs(a, rT: np.ndarray, w2: np.ndarray) -> np.ndarray:
    """``sum_n X_a,n^T W^2 r_n`` (ka,); ``rT`` (6, N) the residual channel-major."""
    out = np.zeros(a.k)
    for c, cols, B in a.channel_blocks():
        out[cols] += w2[c] * (B.T @ rT[c])
    return out


#: eigenvalues of the scaled normal matrix below this fraction of the largest: directions left at zero
REL_EIG = 1e-12


def _sse_after(rr: float, G: np.ndarray, v: np.ndarray) -> float:
    """``rr - v' G^+ v``: the least-squares residual sum of squares from the normal equations (a scaled
    eigen-decomposition; directions below ``REL_EIG`` of the largest eigenvalue left out)."""
    d = np.sqrt(np.clip(np.diag(G), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    lam, U = np.linalg.eigh(G / np.outer(d, d))
    keep = lam > REL_EIG * max(lam.max(), 1e-300)
    u = U[:, keep].T @ (v / d)
    return float(rr - np.sum(u**2 / lam[keep]))


def residual_sse(ctx, resid: np.ndarray) -> Callable[[np.ndarray], float]:
    """``sse(X)``: the weighted residual sum of squares of ``resid`` (N, 6) after the model's columns and ``X``
    (a :class:`~.free_faces.FreeFace`, or its (N, 6, k) columns) (module docstring). From the normal equations over
    each face's channel blocks: the model's own sums once, per ``X`` only its sums (a channel's columns meet only
    its rows: no (6 N, k) design is formed)."""
    from .free_faces import FreeFace

    sd = ctx.sigma if ctx.sigma is not None else np.std(resid, axis=0)
    w = 1.0 / np.where(sd > 0, sd, 1.0)
    w2 = w**2
    rT = np.ascontiguousarray(np.asarray(resid, float).T)
    rr = float(np.sum(w2 * np.einsum("cn,cn->c", rT, rT)))
    J = model_face(ctx)
    GJ, vJ = _gram(J, J, w2), _rhs(J, rT, w2)

    def sse(X) -> float:
        face = X if isinstance(X, FreeFace) else FreeFace(np.asarray(X, float), tuple(f"x{j}" for j in range(np.shape(X)[2])))
        GXJ = _gram(face, J, w2)
        G = np.block([[GJ, GXJ.T], [GXJ, _gram(face, face, w2)]])
        return _sse_after(rr, G, np.r_[vJ, _rhs(face, rT, w2)])

    return sse


def refine_scalar(ctx, resid: np.ndarray, columns: Callable[[float], np.ndarray], lo: float, hi: float,
                  xatol: float = 0.01) -> float | None:
    """The shape parameter in ``[lo, hi]`` whose columns ``columns(p)`` (a FreeFace, or (N, 6, k)) leave the least
    residual, or None."""
    sse = residual_sse(ctx, resid)
    best = minimize_scalar(lambda p: sse(columns(float(p))), bounds=(lo, hi), method="bounded", options={"xatol": xatol})
    return float(best.x) if best.success and np.isfinite(best.x) else None


def refine_simplex(ctx, resid: np.ndarray, columns: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
                   xatol: float = 0.01, maxfev: int = 80) -> np.ndarray | None:
    """Shape parameters from ``x0`` (Nelder-Mead) whose columns ``columns(p)`` leave the least residual, or None."""
    sse = residual_sse(ctx, resid)
    best = minimize(lambda p: sse(columns(np.asarray(p))), np.asarray(x0, float), method="Nelder-Mead",
                    options={"xatol": xatol, "fatol": 1e-9 * sse(np.zeros((ctx.n, 6, 0))), "maxfev": maxfev})
    return np.asarray(best.x) if np.all(np.isfinite(best.x)) else None
