"""Blocked cross-validation of linear augmentations of the free-load model (issue 23).

Around the free-load fit ``x*`` the model is linear: ``y_n - h(x*; s_n) = J_n dx + X_n beta + e_n``
(``J`` (N, 6, P) the model's Jacobian in ``x = [w_o, theta, r]``, ``X`` the chosen effects' face columns).
Rows are weighted by the noise floor per channel, ``1 / floor_c``, so that a residual at the floor has
unit variance in every channel; the weighted least squares

    [dx; beta] = argmin sum_n || W (r_n - J_n dx - X_n beta) ||^2

is solved on the determined subspace (a scaled eigen-decomposition of the normal matrix; directions
below ``REL_EIG`` of its largest eigenvalue are left at zero: what the data cannot separate).

Held-out evidence: the samples are cut into blocks (:func:`cv_blocks`: each quasi-static hold with the
move that follows it; without holds, time blocks), the blocks dealt to ``folds`` folds by a seeded
permutation; each fold is predicted from the normal equations of the others
(``G - G_f, v - v_f``: one pass over the data per design). :class:`CVFit` holds the held-out residual of
every sample, so scores per channel (RMS in the readings' units) and per block (for paired tests) come
from one fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: eigenvalues of the scaled normal matrix below this fraction of the largest are undetermined directions
REL_EIG = 1e-10
#: blocks per fold at least (fewer holds: time blocks instead)
MIN_BLOCKS_PER_FOLD = 2


def cv_blocks(hold: np.ndarray, rec: np.ndarray, folds: int, n_time_blocks: int | None = None) -> np.ndarray:
    """Block id (N,) per sample: a hold and the move that follows it (samples before the first hold of a recording
    join it); with fewer than ``MIN_BLOCKS_PER_FOLD * folds`` holds, ``n_time_blocks`` (default ``5 folds``) blocks of
    equal sample count per recording (in time order)."""
    n = len(hold)
    hold = np.asarray(hold)
    rec = np.asarray(rec)
    starts = np.r_[hold[0] >= 0, (hold[1:] >= 0) & (hold[1:] != hold[:-1])]
    new_rec = np.r_[True, rec[1:] != rec[:-1]]
    if int(starts.sum()) >= MIN_BLOCKS_PER_FOLD * folds:
        seg = np.cumsum(starts | new_rec) - 1
        # a recording's samples before its first hold belong to that hold's block
        return np.unique(seg, return_inverse=True)[1]
    m = n_time_blocks or 5 * folds
    out = np.zeros(n, int)
    base = 0
    for r in np.unique(rec):
        i = np.flatnonzero(rec == r)
        k = max(1, min(m, len(i) // 10))
        out[i] = base + (np.arange(len(i)) * k) // len(i)
        base += k
    return out


def fold_of_blocks(block: np.ndarray, folds: int, seed: int) -> np.ndarray:
    """Fold id (N,) per sample: the blocks dealt to ``folds`` folds by a permutation drawn from ``seed``."""
    nb = int(block.max()) + 1
    perm = np.random.default_rng(seed).permutation(nb)
    return (perm % folds)[block]


def solve(G: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``G^+ v`` on the determined subspace (module docstring)."""
    d = np.sqrt(np.clip(np.diag(G), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    Gs = G / np.outer(d, d)
    lam, U = np.linalg.eigh(Gs)
    keep = lam > REL_EIG * max(lam.max(), 1e-300)
    return (U[:, keep] @ ((U[:, keep].T @ (v / d)) / lam[keep])) / d


def pinv(G: np.ndarray) -> np.ndarray:
    """``G^+`` on the determined subspace; undetermined directions give 0 (their se is reported as inf by the caller)."""
    d = np.sqrt(np.clip(np.diag(G), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    lam, U = np.linalg.eigh(G / np.outer(d, d))
    keep = lam > REL_EIG * max(lam.max(), 1e-300)
    return (U[:, keep] / lam[keep]) @ U[:, keep].T / np.outer(d, d)


@dataclass(frozen=True)
class CVFit:
    """One design's blocked cross-validation: ``heldout`` (N, 6) held-out residual in the readings' units;
    ``block_sse`` (B,) weighted held-out sum of squares per block; ``beta`` (k,) the fit on all samples,
    ``resid`` (N, 6) its residual (readings' units), ``G`` the weighted normal matrix (all samples)."""

    heldout: np.ndarray
    block_sse: np.ndarray
    beta: np.ndarray
    resid: np.ndarray
    G: np.ndarray
    k: int

    @property
    def sse(self) -> float:
        return float(self.block_sse.sum())

    def rms(self) -> np.ndarray:
        return np.sqrt(np.mean(self.heldout**2, axis=0))


class Design:
    """The weighted residual and fold structure shared by every design of one transducer's diagnosis.

    A design is a list of parts (:class:`~ftcal_nlp.effects.free_faces.FreeFace`: the Jacobian, the faces named
    so far, a candidate). Per fold, the weighted normal matrix's block of every pair of parts and the weighted
    right-hand side of every part are computed once and cached (a part keeps its identity across designs); a
    per-channel face meets only its channels' rows, so its blocks cost ``N m`` per channel, not ``6 N k``."""

    def __init__(self, r: np.ndarray, weight: np.ndarray, block: np.ndarray, fold: np.ndarray):
        self.r = np.asarray(r, float)
        self.w = np.asarray(weight, float)
        self.w2 = self.w**2
        self.block = block
        self.fold = fold
        self.folds = int(fold.max()) + 1
        self.nb = int(block.max()) + 1
        self.rw = (self.r * self.w).reshape(-1)
        self._rows = [np.flatnonzero(fold == f) for f in range(self.folds)]
        self._gram: dict = {}
        self._vec: dict = {}
        self._keep: dict = {}   # parts by id, so that an id is not reused while its blocks are cached

    @property
    def n(self) -> int:
        return len(self.r)

    def weighted(self, X: np.ndarray) -> np.ndarray:
        """(N*6, k) weighted rows of face columns ``X`` (N, 6, k)."""
        return (X * self.w[None, :, None]).reshape(-1, X.shape[2])

    # ---- per-fold blocks
    def _pair(self, a, b, rows) -> np.ndarray:
        w2 = self.w2
        if a.dense and b.dense:
            Xa = a.X[rows] * w2[None, :, None]
            return Xa.reshape(-1, a.k).T @ b.X[rows].reshape(-1, b.k)
        if not a.dense and not b.dense:
            Ba, Bb = a.basis[rows], b.basis[rows]
            ma, mb = Ba.shape[1], Bb.shape[1]
            BtB = Ba.T @ Bb
            out = np.zeros((a.k, b.k))
            for i, c in enumerate(a.channels):
                if c in b.channels:
                    j = b.channels.index(c)
                    out[i * ma:(i + 1) * ma, j * mb:(j + 1) * mb] = w2[c] * BtB
            return out
        if a.dense:
            return self._pair(b, a, rows).T
        Ba, Xb = a.basis[rows], b.X[rows]
        m = Ba.shape[1]
        out = np.zeros((a.k, b.k))
        for i, c in enumerate(a.channels):
            out[i * m:(i + 1) * m] = w2[c] * (Ba.T @ Xb[:, c, :])
        return out

    def _rhs(self, a, rows) -> np.ndarray:
        rr = self.r[rows] * self.w2
        if a.dense:
            return a.X[rows].reshape(-1, a.k).T @ rr.reshape(-1)
        B = a.basis[rows]
        return np.concatenate([B.T @ rr[:, c] for c in a.channels])

    def _blocks(self, a, b) -> np.ndarray:
        key = (id(a), id(b))
        if key not in self._gram:
            if (id(b), id(a)) in self._gram:
                return self._gram[(id(b), id(a))].transpose(0, 2, 1)
            self._keep[id(a)], self._keep[id(b)] = a, b
            self._gram[key] = np.stack([self._pair(a, b, rows) for rows in self._rows])
        return self._gram[key]

    def _vecs(self, a) -> np.ndarray:
        if id(a) not in self._vec:
            self._keep[id(a)] = a
            self._vec[id(a)] = np.stack([self._rhs(a, rows) for rows in self._rows])
        return self._vec[id(a)]

    def forget(self, part) -> None:
        """Drop the cached blocks of ``part`` (a candidate that was not kept)."""
        i = id(part)
        for key in [k for k in self._gram if i in k]:
            del self._gram[key]
        self._vec.pop(i, None)
        self._keep.pop(i, None)

    def fit(self, parts) -> CVFit:
        """Blocked cross-validation of the design of ``parts`` (FreeFace list, or one (N, 6, k) array) (module docstring)."""
        from ..effects.free_faces import FreeFace

        if isinstance(parts, np.ndarray):
            parts = [FreeFace(parts, tuple(f"c{j}" for j in range(parts.shape[2])))]
        parts = list(parts)
        ks = [p.k for p in parts]
        off = np.r_[0, np.cumsum(ks)]
        k = int(off[-1])
        Gf = np.zeros((self.folds, k, k))
        vf = np.zeros((self.folds, k))
        for i, a in enumerate(parts):
            vf[:, off[i]:off[i + 1]] = self._vecs(a)
            for j in range(i, len(parts)):
                blk = self._blocks(a, parts[j])
                Gf[:, off[i]:off[i + 1], off[j]:off[j + 1]] = blk
                if j != i:
                    Gf[:, off[j]:off[j + 1], off[i]:off[i + 1]] = blk.transpose(0, 2, 1)
        G, v = Gf.sum(axis=0), vf.sum(axis=0)

        def model(beta, rows):
            return sum(p.wrench(beta[off[i]:off[i + 1]], rows) for i, p in enumerate(parts))

        ho = np.empty((self.n, 6))
        for f, rows in enumerate(self._rows):
            if len(rows):
                b = solve(G - Gf[f], v - vf[f])
                ho[rows] = self.r[rows] - model(b, rows)
        beta = solve(G, v)
        resid = self.r - model(beta, slice(None))
        bs = np.bincount(self.block, weights=(ho**2 * self.w2).sum(axis=1), minlength=self.nb)
        return CVFit(ho, bs, beta, resid, G, k)


def paired_gain(before: CVFit, after: CVFit) -> tuple[float, float]:
    """``(gain, z)``: the held-out weighted sum of squares ``after`` saves over ``before``, as a fraction of
    ``before``'s, and the paired z of the per-block log ratios ``d_b = log(SSE_before,b / SSE_after,b)`` (mean over
    blocks / its se). Log ratios, not differences: a real effect shrinks most blocks by a similar factor while its
    absolute saving is concentrated where the load moves most, which would make the differences heavy-tailed."""
    ok = (before.block_sse > 0) & (after.block_sse > 0)
    d = np.log(before.block_sse[ok]) - np.log(after.block_sse[ok])
    B = len(d)
    sd = float(np.std(d, ddof=1)) if B > 1 else np.inf
    z = float(d.mean() / (sd / np.sqrt(B))) if sd > 0 else (np.inf if d.sum() > 0 else 0.0)
    return float((before.sse - after.sse) / max(before.sse, 1e-300)), z
