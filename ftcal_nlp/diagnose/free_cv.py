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
permutation; each fold is predicted from the normal equations of the others (``G - G_f, v - v_f``). The
normal equations are kept per block and channel (:class:`Design`, cached per pair of parts; a face's columns are
its channel blocks, ``FreeFace.channel_blocks``: each channel's non-zero columns only), so a design's held-out sums
of squares per block (for the paired tests) and per channel (RMS in the readings' units) follow without a pass over
the samples:

    SSE_bc = s_bc - 2 beta_f' v_bc + beta_f' G_bc beta_f      (block b in fold f, channel c)

:class:`CVFit` forms the held-out residual of every sample only on demand (figures).

A face may carry a fixed offset (``FreeFace.offset``, a wrench not scaled by its parameters: a nonlinear face
linearised about its shape, e.g. clock_offset's exact delay): a design with such parts fits ``r - sum offsets``
(``Design._for``: a design of that residual sharing the cached normal matrices, which do not depend on it; its own
right-hand sides and residual sums), so held-out sums of squares stay comparable block by block across designs.
"""

from __future__ import annotations

import copy
import weakref

import numpy as np

#: eigenvalues of the scaled normal matrix below this fraction of the largest are undetermined directions
REL_EIG = 1e-10
#: a parameter whose component along an undetermined direction (unit vector, scaled) exceeds this is undetermined
TOUCH = 1e-6
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
    """``G^+ v`` on the determined subspace (module docstring): :func:`solve_many` of one."""
    return solve_many(G[None], v[None])[0]


def solve_many(G: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`solve` of each ``G[i]`` (m, k, k) and ``v[i]`` (m, k): the same arithmetic, one eigen-decomposition call
    for the stack (a design's folds and its all-sample fit)."""
    d = np.sqrt(np.clip(np.diagonal(G, axis1=1, axis2=2), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    lam, U = np.linalg.eigh(G / (d[:, :, None] * d[:, None, :]))
    out = np.empty(v.shape)
    for i in range(len(G)):
        keep = lam[i] > REL_EIG * max(lam[i].max(), 1e-300)
        Uk = U[i][:, keep]
        out[i] = (Uk @ ((Uk.T @ (v[i] / d[i])) / lam[i][keep])) / d[i]
    return out


def _scaled_eigh(G: np.ndarray):
    """``G`` scaled to a unit diagonal and decomposed: ``(d, zero, lam, U, keep)``, the scales (1 where the diagonal
    is 0, ``zero``), the eigenpairs and the eigenvalues kept (above ``REL_EIG`` of the largest)."""
    d = np.sqrt(np.clip(np.diag(G), 0.0, None))
    zero = d == 0
    d = np.where(zero, 1.0, d)
    lam, U = np.linalg.eigh(G / np.outer(d, d))
    return d, zero, lam, U, lam > REL_EIG * max(lam.max(), 1e-300)


def pinv(G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(G^+, undetermined)``: the inverse on the determined subspace and, per parameter, whether it has a component
    (above ``TOUCH``) along a direction the data leave undetermined (its se is then infinite, not the 0 of ``G^+``)."""
    d, zero, lam, U, keep = _scaled_eigh(G)
    touched = zero | (np.abs(U[:, ~keep]) > TOUCH).any(axis=1)
    return (U[:, keep] / lam[keep]) @ U[:, keep].T / np.outer(d, d), touched


def null_directions(G: np.ndarray) -> np.ndarray:
    """The directions (P, r) ``G`` leaves undetermined, in the parameters' own units, unit length: the eigenvectors
    :func:`pinv` drops and the parameters with a zero diagonal."""
    d, zero, lam, U, keep = _scaled_eigh(G)
    N = np.concatenate([U[:, ~keep] / d[:, None], np.eye(len(G))[:, zero]], axis=1)
    return N / np.linalg.norm(N, axis=0, keepdims=True) if N.size else N


class CVFit:
    """One design's blocked cross-validation, from the cached normal equations alone (no pass over the samples):

    ``block_sse`` (B,) weighted held-out sum of squares per block; ``chan_sse`` (6,) held-out sum of squares per
    channel in the readings' units; ``beta`` (k,) the fit on all samples; ``G`` its weighted normal matrix;
    ``rss`` the weighted residual sum of squares of that fit. ``heldout`` and ``resid`` ((N, 6), the readings'
    units) are formed on demand (one pass over the samples each)."""

    def __init__(self, design: "Design", parts: list, off: np.ndarray, fold_beta: np.ndarray, beta: np.ndarray,
                 G: np.ndarray, block_sse: np.ndarray, chan_sse: np.ndarray, rss: float):
        self._design, self._off, self._fold_beta = design, off, fold_beta
        self._parts: list | None = parts     # None once released (``_release``)
        self.beta, self.G, self.block_sse, self.chan_sse, self.rss = beta, G, block_sse, chan_sse, float(rss)
        self.k = int(off[-1])
        self._heldout: np.ndarray | None = None
        self._resid: np.ndarray | None = None
        self._fold_parts: list | None = None      # per fold its parts (a face tuned per fold: ``Design.fit_per_fold``)

    @property
    def sse(self) -> float:
        return float(self.block_sse.sum())

    def rms(self) -> np.ndarray:
        return np.sqrt(self.chan_sse / self._design.n)

    @property
    def heldout(self) -> np.ndarray:
        if self._heldout is None:
            self._heldout = self._design.heldout(self._kept(), self._off, self._fold_beta, self._fold_parts)
        return self._heldout

    @property
    def resid(self) -> np.ndarray:
        if self._resid is None:
            parts = self._kept()
            self._resid = self._design.r - self._design.model(parts, self._off, self.beta)
        return self._resid

    def _kept(self) -> list:
        """The parts, while kept (else the error: a released fit cannot form its residuals)."""
        if self._parts is None:
            raise RuntimeError("this cross-validated fit was released with its design (Design.release): its numbers are "
                               "kept, its residuals can no longer be formed")
        return self._parts

    def _release(self) -> None:
        """Keep the numbers, drop the parts and the residuals formed (the design is being released)."""
        self._parts = self._fold_parts = self._heldout = self._resid = None


class Design:
    """The weighted residual and block structure shared by every design of one transducer's diagnosis.

    A design is a list of parts (:class:`~ftcal_nlp.effects.free_faces.FreeFace`: the Jacobian, the faces named
    so far, a candidate). Per block and channel, the weighted normal matrix's block of every pair of parts and the
    weighted right-hand side of every part are computed once and cached (a part keeps its identity across
    designs); a per-channel face meets only its channels' rows. A fold's fit and every held-out sum of squares
    then follow from these sums alone: with ``beta_f`` fitted without fold ``f``, block ``b`` of ``f`` and channel
    ``c`` have ``SSE_bc = s_bc - 2 beta_f' v_bc + beta_f' G_bc beta_f``."""

    def __init__(self, r: np.ndarray, weight: np.ndarray, block: np.ndarray, fold: np.ndarray):
        self.r = np.asarray(r, float)
        self.w = np.asarray(weight, float)
        self.w2 = self.w**2
        self.block = np.asarray(block)
        self.fold = np.asarray(fold)
        self.folds = int(fold.max()) + 1
        self.nb = int(block.max()) + 1
        self.rw = (self.r * self.w).reshape(-1)
        # samples sorted by block: a block is a slice, every part's rows a view (one copy of each part)
        self._order = np.argsort(self.block, kind="stable")
        # blocks are runs of consecutive samples (cv_blocks): then block order is sample order and a part's rows are
        # used in place (a copy of every part into block order cost more than the sums themselves)
        self._sorted = bool(np.all(self._order == np.arange(len(self._order))))
        edges = np.r_[0, np.cumsum(np.bincount(self.block, minlength=self.nb))]
        self._sl = [slice(int(edges[b]), int(edges[b + 1])) for b in range(self.nb)]
        self.block_fold = np.zeros(self.nb, int)
        self.block_fold[self.block] = self.fold
        self._rp = self.r if self._sorted else self.r[self._order]
        rr = self._rp**2 * self.w2
        self._s = np.stack([rr[sl].sum(axis=0) for sl in self._sl])          # (B, 6)
        self._rrT = np.ascontiguousarray((self._rp * self.w2).T)             # (6, N) weighted residual, channel-major
        self._gram: dict = {}
        self._vec: dict = {}
        self._perm: dict = {}   # basis id -> its rows in block order
        self._keep: dict = {}   # parts (and bases) by id, so that an id is not reused while its sums are cached
        self._n = len(self.r)
        self._fits: weakref.WeakSet[CVFit] = weakref.WeakSet()   # the fits made, released with the design
        self._shifted: dict = {}         # ids of the parts with a fixed offset -> (those parts, the design of r - offsets)
        self._derived = False            # a design of r less some parts' offsets (``_for``): its residual is final

    @property
    def n(self) -> int:
        return self._n

    def weighted(self, X: np.ndarray) -> np.ndarray:
        """(N*6, k) weighted rows of face columns ``X`` (N, 6, k)."""
        return (X * self.w[None, :, None]).reshape(-1, X.shape[2])

    def _P(self, B: np.ndarray) -> np.ndarray:
        """A face's channel basis ``B`` (N, m) with its rows in block order (cached; as is when already in order)."""
        if self._sorted:
            return B
        if id(B) not in self._perm:
            self._keep[("B", id(B))] = B
            self._perm[id(B)] = B[self._order]
        return self._perm[id(B)]

    # ---- per-block, per-channel sums (each face's channel blocks: a channel's columns meet only its rows)
    def _hcat(self, a):
        """``(H (N, sum m_c), [(channel, columns, rows of H)])``: part ``a``'s channel blocks side by side (cached)."""
        key = ("H", id(a))
        if key not in self._perm:
            self._keep[key] = a
            blocks = a.channel_blocks()
            offs = np.cumsum([0] + [B.shape[1] for _, _, B in blocks])
            H = np.concatenate([self._P(B) for _, _, B in blocks], axis=1)
            self._perm[key] = (H, [(c, cols, slice(int(offs[i]), int(offs[i + 1]))) for i, (c, cols, _) in enumerate(blocks)])
        return self._perm[key]

    def _pair(self, a, b) -> list:
        """``[(c, columns of a, columns of b, T (B, ma, mb)), ...]``: per channel ``c`` that both parts act on, the sum
        over each block's samples of channel c's weighted column products (the non-zero part of the (B, 6, ka, kb)
        array of every pair of columns)."""
        if b.basis is not None and a.basis is None and len(a.channel_blocks()) > 1:
            # one basis on every channel of b against a's own columns per channel: every channel's products in one
            # matrix product per block (b's basis read once, not once per channel)
            H, where = self._hcat(a)
            Pb = self._P(b.basis)
            T = self._per_block(H, Pb)                                           # (B, sum m_c, mb)
            mb = b.basis.shape[1]
            bch = {c: i for i, c in enumerate(b.channels)}
            return [(c, cols_a, np.arange(bch[c] * mb, (bch[c] + 1) * mb), self.w2[c] * T[:, rows])
                    for c, cols_a, rows in where if c in bch]
        if a.basis is not None and b.basis is None and len(b.channel_blocks()) > 1:
            return _transposed(self._pair(b, a))
        ab = {c: (cols, B) for c, cols, B in a.channel_blocks()}
        done: dict = {}      # a basis shared by several channels (per_channel): its products once
        out = []
        for c, cols_b, Bb in b.channel_blocks():
            if c not in ab:
                continue
            cols_a, Ba = ab[c]
            key = (id(Ba), id(Bb))
            if key not in done:
                Pa, Pb = self._P(Ba), self._P(Bb)
                done[key] = self._per_block(Pa, Pb)                                   # (B, ma, mb)
            out.append((c, cols_a, cols_b, self.w2[c] * done[key]))
        return out

    def _rhs(self, a) -> np.ndarray:
        """(B, 6, ka): sum over the block's samples of channel c's weighted column times residual."""
        out = np.zeros((self.nb, 6, a.k))
        for c, cols, B in a.channel_blocks():
            P = self._P(B)
            rc = self._rrT[c]
            out[:, c, cols] = self._per_block(P, rc)
        return out

    def _per_block(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """``(nb, ma[, mb])``: per block the product ``A_b^T B_b`` of its rows of ``A`` (N, ma) and ``B`` (N, mb) or (N,),
        each written straight into its slot (no list of small arrays to stack)."""
        out = np.empty((self.nb, A.shape[1]) + B.shape[1:])
        for b, sl in enumerate(self._sl):
            np.matmul(A[sl].T, B[sl], out=out[b])
        return out

    def _blocks(self, a, b) -> list:
        key = (id(a), id(b))
        if key not in self._gram:
            if (id(b), id(a)) in self._gram:
                return _transposed(self._gram[(id(b), id(a))])
            self._keep[id(a)], self._keep[id(b)] = a, b
            self._gram[key] = self._pair(a, b)
        return self._gram[key]

    def _vecs(self, a) -> np.ndarray:
        if id(a) not in self._vec:
            self._keep[id(a)] = a
            self._vec[id(a)] = self._rhs(a)
        return self._vec[id(a)]

    def _for(self, parts: list) -> "Design":
        """The design whose residual is ``r`` less the fixed offsets of ``parts`` (``FreeFace.offset``: a face linearised
        about its nonlinear shape); ``self`` when none has one. It shares this design's cached normal matrices (they do
        not depend on the residual) and has its own right-hand sides and residual sums."""
        offs = [p for p in parts if getattr(p, "offset", None) is not None]
        if not offs or self._derived:
            return self
        key = tuple(sorted(id(p) for p in offs))
        hit = self._shifted.get(key)
        if hit is None:
            d = copy.copy(self)      # the same blocks, folds, weights and pair caches (shared dicts)
            d.r = self.r - sum(p.offset for p in offs)
            d.rw = (d.r * d.w).reshape(-1)
            d._rp = d.r if d._sorted else d.r[d._order]
            rr = d._rp**2 * d.w2
            d._s = np.stack([rr[sl].sum(axis=0) for sl in d._sl])
            d._rrT = np.ascontiguousarray((d._rp * d.w2).T)
            d._vec, d._shifted, d._derived = {}, {}, True
            hit = self._shifted[key] = (offs, d)
        return hit[1]

    def forget(self, part) -> None:
        """Drop the cached sums of ``part`` (a candidate that was not kept)."""
        i = id(part)
        for key in [k for k in self._shifted if i in k]:
            del self._shifted[key]
        for _, d in self._shifted.values():   # its right-hand sides in the designs of r less offsets (an id is reused)
            d._vec.pop(i, None)
        for key in [k for k in self._gram if i in k]:
            del self._gram[key]
        self._vec.pop(i, None)
        self._keep.pop(i, None)
        if self._perm.pop(("H", i), None) is not None:
            self._keep.pop(("H", i), None)
        for _, _, B in part.channel_blocks():
            if self._perm.pop(id(B), None) is not None:
                self._keep.pop(("B", id(B)), None)

    def release(self) -> None:
        """Drop every cached sum, the parts kept for them, the residual arrays and, in every fit made, its parts and
        residuals (the diagnosis is done: its results keep their numbers, not the columns: hundreds of MB on 10^5
        samples otherwise kept alive by the result); a released fit's ``heldout``/``resid`` not formed before raise."""
        self._gram.clear()
        self._vec.clear()
        self._perm.clear()
        self._keep.clear()
        for _, d in self._shifted.values():   # the designs of r less offsets: their residual arrays too
            d._vec.clear()
            d.r = d.rw = d._rp = d._rrT = None
        self._shifted.clear()
        for f in list(self._fits):
            f._release()
        # released: no method of the design runs again (its fits raise in CVFit._kept), so the arrays stay typed as arrays
        self.r = self.rw = self._rp = self._rrT = None  # type: ignore[assignment]

    # ---- predictions (on demand)
    def model(self, parts, off, beta, rows=slice(None)) -> np.ndarray:
        return sum(p.wrench(beta[off[i]:off[i + 1]], rows) for i, p in enumerate(parts))

    def heldout(self, parts, off, fold_beta, fold_parts=None) -> np.ndarray:
        """(N, 6) held-out residual: each sample predicted by its fold's fit (``fold_parts``: per fold its parts)."""
        out = np.empty((self.n, 6))
        for f in range(self.folds):
            rows = np.flatnonzero(self.fold == f)
            if len(rows):
                out[rows] = self.r[rows] - self.model(parts if fold_parts is None else fold_parts[f], off, fold_beta[f], rows)
        return out

    def _assemble(self, parts: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
        """``(Gb (B, k, k), vbc (B, 6, k), off, terms)`` of the design of ``parts`` from the cached sums: the weighted
        normal matrix per block (summed over the channels), the right-hand sides per block and channel, and the
        channel terms ``(c, rows, columns, T, factor)`` of the per-channel normal matrices (:meth:`_quadratic`)."""
        ks = [p.k for p in parts]
        off = np.r_[0, np.cumsum(ks)]
        k = int(off[-1])
        Gb = np.zeros((self.nb, k, k))
        vbc = np.zeros((self.nb, 6, k))
        terms = []
        for i, a in enumerate(parts):
            vbc[:, :, off[i]:off[i + 1]] = self._vecs(a)
            for j in range(i, len(parts)):
                for c, ca, cb, T in self._blocks(a, parts[j]):     # channels in increasing order: the sum over them
                    ri, ci = off[i] + ca, off[j] + cb
                    Gb[:, ri[:, None], ci[None, :]] += T
                    if j != i:
                        Gb[:, ci[:, None], ri[None, :]] += T.transpose(0, 2, 1)
                    terms.append((c, ri, ci, T, 1.0 if j == i else 2.0))
        return Gb, vbc, off, terms

    @staticmethod
    def _quadratic(terms: list, B: np.ndarray, blocks=slice(None)) -> np.ndarray:
        """(b, 6): ``beta_b' G_bc beta_b`` per block (of ``blocks``) and channel, ``B`` (b, k) each block's
        coefficients, from the channel terms of :meth:`_assemble`."""
        q = np.zeros((len(B), 6))
        for c, ri, ci, T, f in terms:
            q[:, c] += f * np.einsum("bij,bi,bj->b", T[blocks], B[:, ri], B[:, ci])
        return q

    @staticmethod
    def _parts(parts) -> list:
        from ..effects.free_faces import FreeFace

        if isinstance(parts, np.ndarray):
            return [FreeFace(parts, tuple(f"c{j}" for j in range(parts.shape[2])))]
        return list(parts)

    def fit(self, parts) -> CVFit:
        """Blocked cross-validation of the design of ``parts`` (FreeFace list, or one (N, 6, k) array) (class docstring)."""
        parts = self._parts(parts)
        if self._for(parts) is not self:
            return self._for(parts).fit(parts)
        Gb, vbc, off, terms = self._assemble(parts)
        k = int(off[-1])
        vb = vbc.sum(axis=1)                                        # (B, k)
        G, v = Gb.sum(axis=0), vb.sum(axis=0)
        # every fold's normal equations (all blocks less the fold's) and the all-sample ones, solved as one stack
        has = [f for f in range(self.folds) if np.any(self.block_fold == f)]
        Gs = np.empty((len(has) + 1, k, k))
        vs = np.empty((len(has) + 1, k))
        for i, f in enumerate(has):
            bs = np.flatnonzero(self.block_fold == f)
            Gs[i], vs[i] = G - Gb[bs].sum(axis=0), v - vb[bs].sum(axis=0)
        Gs[-1], vs[-1] = G, v
        sol = solve_many(Gs, vs)
        fold_beta = np.zeros((self.folds, k))
        fold_beta[has] = sol[:-1]
        Bb = fold_beta[self.block_fold]                             # (B, k): each block's fold's coefficients
        sse_bc = self._s - 2 * np.einsum("bck,bk->bc", vbc, Bb) + self._quadratic(terms, Bb)
        beta = sol[-1]
        rss = float(self._s.sum() - 2 * v @ beta + beta @ G @ beta)
        sse_bc = np.clip(sse_bc, 0.0, None)
        out = CVFit(self, parts, off, fold_beta, beta, G, sse_bc.sum(axis=1), sse_bc.sum(axis=0) / self.w2, rss)
        self._fits.add(out)
        return out

    def train_sse(self, parts) -> np.ndarray:
        """(folds,) the weighted residual sum of squares of the design of ``parts`` fitted on each fold's training
        blocks (the other folds'), over those blocks: what a shape tuned per fold minimises."""
        parts = self._parts(parts)
        if self._for(parts) is not self:
            return self._for(parts).train_sse(parts)
        Gb, vbc, _, _ = self._assemble(parts)
        vb, sb = vbc.sum(axis=1), self._s.sum(axis=1)
        G, v, s = Gb.sum(axis=0), vb.sum(axis=0), float(sb.sum())
        out = np.full(self.folds, np.inf)
        folds = list(range(self.folds))
        Gf = np.stack([G - Gb[np.flatnonzero(self.block_fold == f)].sum(axis=0) for f in folds])
        vf = np.stack([v - vb[np.flatnonzero(self.block_fold == f)].sum(axis=0) for f in folds])
        b = solve_many(Gf, vf)         # every fold's training fit, one eigen-decomposition call (solve's arithmetic)
        for f in folds:
            bs = np.flatnonzero(self.block_fold == f)
            out[f] = s - float(sb[bs].sum()) - 2 * vf[f] @ b[f] + b[f] @ Gf[f] @ b[f]
        return out

    def fit_per_fold(self, parts, fold_faces: list, whole: CVFit) -> CVFit:
        """Blocked cross-validation of ``parts`` plus a face tuned per fold: fold ``f`` is predicted by the design
        ``parts + [fold_faces[f]]`` fitted on the other folds' blocks (``fold_faces[f]`` tuned on those blocks too, by
        the caller); ``whole`` the design with the face tuned on all samples, whose all-sample fit (``beta``, ``G``,
        ``rss``, ``resid``) the result carries."""
        parts = self._parts(parts)
        fold_beta = np.zeros((self.folds, whole.k))
        sse_bc = np.zeros((self.nb, 6))
        fparts = []
        for f in range(self.folds):
            pf = parts + [fold_faces[f]]
            fparts.append(pf)
            bs = np.flatnonzero(self.block_fold == f)
            if not len(bs):
                continue
            dd = self._for(pf)     # the residual less the parts' fixed offsets, if any (the folds' faces have none)
            Gb, vbc, off, terms = dd._assemble(pf)
            vb = vbc.sum(axis=1)
            b = solve(Gb.sum(axis=0) - Gb[bs].sum(axis=0), vb.sum(axis=0) - vb[bs].sum(axis=0))
            fold_beta[f] = b
            Bb = np.broadcast_to(b, (len(bs), len(b)))
            sse_bc[bs] = dd._s[bs] - 2 * vbc[bs] @ b + self._quadratic(terms, Bb, bs)
        sse_bc = np.clip(sse_bc, 0.0, None)
        out = CVFit(whole._design, whole._kept(), whole._off, fold_beta, whole.beta, whole.G, sse_bc.sum(axis=1),
                    sse_bc.sum(axis=0) / self.w2, whole.rss)
        out._fold_parts = fparts
        self._fits.add(out)
        return out


def _transposed(entries: list) -> list:
    """The channel entries of a pair ``(a, b)`` as those of ``(b, a)``."""
    return [(c, cb, ca, T.transpose(0, 2, 1)) for c, ca, cb, T in entries]


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
