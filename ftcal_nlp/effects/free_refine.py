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


def residual_sse(ctx, resid: np.ndarray) -> Callable[[np.ndarray], float]:
    """``sse(X)``: the weighted residual sum of squares of ``resid`` (N, 6) after the model's columns and ``X``
    (N, 6, k) (module docstring)."""
    sd = ctx.sigma if ctx.sigma is not None else np.std(resid, axis=0)
    w = 1.0 / np.where(sd > 0, sd, 1.0)
    r = (np.asarray(resid, float) * w).reshape(-1)
    J = (model_columns(ctx) * w[None, :, None]).reshape(len(r), -1)

    def sse(X: np.ndarray) -> float:
        A = np.concatenate([J, (X * w[None, :, None]).reshape(len(r), -1)], axis=1)
        coef, *_ = np.linalg.lstsq(A, r, rcond=None)
        return float(np.sum((r - A @ coef) ** 2))

    return sse


def refine_scalar(ctx, resid: np.ndarray, columns: Callable[[float], np.ndarray], lo: float, hi: float,
                  xatol: float = 0.01) -> float | None:
    """The shape parameter in ``[lo, hi]`` whose columns ``columns(p)`` (N, 6, k) leave the least residual, or None."""
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
