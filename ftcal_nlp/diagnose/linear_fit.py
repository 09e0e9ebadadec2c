"""Linear faces of the effects on per-sample residuals (hanging, walking swing), cross-validated.

To first order an effect adds ``X_i beta`` to the residual ``e_i`` (6,) of a
sample of the fitted model (hanging: report eqs. 4-7; a foot in the air: its
leg's weight only), with features ``X_i`` (6, m) from ``Effect.hanging_features``
/ ``swing_features``. Standardised by the leg's floor (``y = e / sigma``), the
least-squares fit of ``beta`` needs per fold only ``A = sum X^T X``,
``b = sum X^T y`` and ``sum y^2``, accumulated per leg and component.

Folds are contiguous in time: every recording is cut into ``folds`` equal
time blocks and fold f holds the f-th block of each, so a slow effect is
scored on stretches it was not fitted to (interleaved samples would leak
through their neighbours). Regressing the fitted model's residuals leaves the
calibration parameters where they were; a joint refit could explain more, so
the improvement is a lower bound (conservative), and the base's held-out
residual is its in-sample residual scaled by ``n / (n - p)`` (p parameters per
leg and component of the hanging fit, a ~1 % correction).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..effects.faces import LinearFace
from .scores import KindScore, base_score
from .views import LegSeries

RIDGE = 1e-9


def time_folds(series: LegSeries, folds: int) -> list[np.ndarray]:
    """Fold index (N_k,) per leg: ``folds`` contiguous time blocks of every recording."""
    out = []
    for l in series.legs:
        f = np.zeros(len(l.t), int)
        for g in np.unique(l.rec):
            idx = np.flatnonzero(l.rec == g)
            t = l.t[idx]
            edges = np.linspace(t.min(), t.max() + 1e-9, folds + 1)
            f[idx] = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, folds - 1)
        out.append(f)
    return out


def _std(series: LegSeries) -> list[np.ndarray]:
    fl = np.where(series.floor > 0, series.floor, 1.0)
    return [fl[l.k] for l in series.legs]


def base_linear(series: LegSeries) -> KindScore:
    """The fitted model alone on ``series`` (residual as held-out, with the small in-sample correction)."""
    sig = _std(series)
    mse = np.zeros(6)
    z = 0.0
    n = 0
    for l, s in zip(series.legs, sig):
        N = len(l.t)
        corr = N / max(N - series.n_params / 6.0, 1.0)
        mse += (l.e**2).sum(axis=0) * corr
        z += float(((l.e / s) ** 2).sum()) * corr
        n += 6 * N
    N_all = series.n
    floor = np.sqrt(np.mean(np.square(series.floor[[l.k for l in series.legs]]), axis=0))
    return base_score(series.kind, mse / N_all, floor, z, z, n)


def score_linear(series: LegSeries, face: LinearFace | None, folds: int, after: LegSeries | None = None) -> tuple[KindScore, np.ndarray]:
    """Held-out and in-sample scores of ``face`` on ``series``; returns (score, beta on all data).

    ``after``: the same samples with the residual of a changed calibration (the standing
    fit with the effect added moves the transducer rotations that a swing leg's weight
    is predicted with); the face is then fitted to it, and the score compares it with
    ``series``. ``face`` None: nothing fitted (``after`` alone).
    """
    base = base_linear(series)
    after = series if after is None else after
    K = max(l.k for l in series.legs) + 1
    if face is None:
        face = LinearFace([np.zeros((len(l.t), 6, 1)) for l in after.legs], (), False)
    q = face.blocks[0].shape[2]
    m = face.size(K)
    fidx = time_folds(series, folds)
    sig = _std(series)
    nl = len(series.legs)
    A = np.zeros((folds, nl, 6, m, m))
    b = np.zeros((folds, nl, 6, m))
    yy = np.zeros((folds, nl, 6))
    for i, (l, X, s, fi) in enumerate(zip(after.legs, face.blocks, sig, fidx)):
        # stacked faces (``LinearFace.cols``) place the block's columns by index, one face by its layout
        sl: np.ndarray | slice
        ix: tuple[np.ndarray | slice, ...]
        if face.cols is not None:
            sl = face.index(i, l.k)
            ix = np.ix_(sl, sl)
        else:
            sl = slice(l.k * q, (l.k + 1) * q) if face.per_leg else slice(0, q)
            ix = (sl, sl)
        Xs = X / s[None, :, None]
        ys = l.e / s[None, :]
        for f in range(folds):
            sel = fi == f
            if not sel.any():
                continue
            Xf, yf = Xs[sel], ys[sel]
            A[f, i][(slice(None), *ix)] = np.einsum("nca,ncb->cab", Xf, Xf)
            b[f, i][:, sl] = np.einsum("nca,nc->ca", Xf, yf)
            yy[f, i] = (yf**2).sum(axis=0)
    A_tot, b_tot = A.sum(axis=(0, 1, 2)), b.sum(axis=(0, 1, 2))
    reg = RIDGE * max(np.trace(A_tot) / m, 1e-300) * np.eye(m) + (1e-300 if np.trace(A_tot) > 0 else 1.0) * np.eye(m)
    ss_phys = np.zeros(6)
    z_after = 0.0
    blocks = np.zeros((folds, nl))
    for f in range(folds):
        Af, bf = A[f].sum(axis=(0, 1)), b[f].sum(axis=(0, 1))
        beta = np.linalg.solve(A_tot - Af + reg, b_tot - bf)
        ss = yy[f] - 2 * np.einsum("icm,m->ic", b[f], beta) + np.einsum("m,icmn,n->ic", beta, A[f], beta)  # (nl, 6)
        z_after += float(ss.sum())
        blocks[f] = ss.sum(axis=1)
        for i, s in enumerate(sig):
            ss_phys += ss[i] * s**2
    beta_all = np.linalg.solve(A_tot + reg, b_tot)
    rss_after = float(yy.sum() - beta_all @ b_tot)
    lam = np.linalg.eigvalsh(A_tot / max(np.abs(np.diag(A_tot)).max(), 1e-300))
    dof = int(np.sum(lam > 1e-8 * lam.max())) if np.abs(A_tot).max() > 0 else 0
    n_all = series.n
    rss_before = float(sum(((l.e / s) ** 2).sum() for l, s in zip(series.legs, sig)))
    score = KindScore(series.kind, base.mse_before, ss_phys / n_all, base.floor, base.z_before, z_after, rss_before,
                      rss_after, base.n, dof, None, blocks.ravel())
    return score, beta_all


def rebase(score: KindScore, base: KindScore) -> KindScore:
    """``score`` (a face stacked on ``base``'s, both against the fitted model alone) against ``base``: before is
    what ``base`` leaves held out (and in sample), the dof those the stacked face adds (the chain, ``hexchain.py``)."""
    return KindScore(score.kind, base.mse_after, score.mse_after, score.floor, base.z_after, score.z_after, base.rss_after,
                     score.rss_after, score.n, score.dof - base.dof, base.blocks_after, score.blocks_after)


def recalibrate(series: LegSeries, R_new: np.ndarray, off_new: np.ndarray | None, off_old: np.ndarray | None,
                mg_new: np.ndarray | None = None) -> LegSeries:
    """Swing residuals with other transducer rotations ``R_new`` (K, 3, 3) (and offsets, and leg weights
    ``mg_new`` (K,) N).

    ``e = w - w_o - [f; r x f]`` with ``f = m R_k^T u``; the gravity direction ``u`` in B
    is ``R_cal f / m``, so ``f' = (m' / m) R_new^T R_cal f`` and ``e' = e + [f - f'; r x (f - f')]``.
    """
    out = []
    for l in series.legs:
        scale = 1.0 if mg_new is None else float(mg_new[l.k]) / l.mg
        f_new = scale * (R_new[l.k].T @ (l.R_cal @ l.f.T)).T
        df = l.f - f_new
        e = l.e + np.hstack([df, np.cross(l.r, df)])
        if off_new is not None and off_old is not None:
            e = e - (off_new[l.k] - off_old[l.k])
        out.append(replace(l, e=e, f=f_new, R_cal=R_new[l.k], mg=l.mg * scale))
    return replace(series, legs=out)
