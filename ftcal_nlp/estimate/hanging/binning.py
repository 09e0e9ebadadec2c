"""Exact sample reduction for the hanging fit: sufficient statistics per phi bin.

Every hanging model of this package is linear in a per-sample feature vector
``x_i = w_i(phi_i)`` of length ``G``, the periodic linear-interpolation
weights of the CoM grid ``r_1..r_G`` at ``phi_i`` (two non-zero entries,
``1 - t`` and ``t``, adding up to one, so constants need no extra feature).
For recording ``j`` the reading (report eqs. 4-7 with an exact rotation) is

    w_m,i = M_j x_i + n_i,
    M_j[:, g] = [f_j + f_o; r_g x f_j + tau_o],   f_j = m_k g R_j a_j,

so every weighted least-squares objective of the fit only needs, per recording,
``S_xx = sum_i x_i x_i^T``, ``S_xy = sum_i x_i y_i^T`` and ``diag(S_yy)``:

    sum_i ||y_i - M x_i||^2_W = sum_c W_c (S_yy,cc - 2 (M S_xy)_cc + (M S_xx M^T)_cc).

With the bins equal to the grid intervals, each sample adds to one 2x2 block
of ``S_xx``: the statistics are accumulated by
``bincount`` in one pass, and nothing is lost (no approximation of phi within
a bin, unlike averaging readings per bin).

Compression. With a factor ``S_xx = X~^T X~`` (Cholesky, ``X~ = L^T``) the
``K <= G`` pseudo-samples ``X~`` (rows) with pseudo-readings
``Y~ = L^-1 S_xy`` reproduce the objective for every ``M``:

    sum_i ||y_i - M x_i||^2_W = sum_k ||Y~_k - M X~_k||^2_W + sum_c W_c e_c,

with the pure error ``e_c = S_yy,cc - ||Y~[:, c]||^2`` (the residual of a free
``M`` per recording). The fit then runs on ~72 rows per recording instead of
~20 000 samples, and ``e_c / (n - K)`` is a model-free noise variance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * np.pi


def periodic_grid(n_grid: int) -> np.ndarray:
    """``n_grid`` equally spaced shaft angles on [0, 2pi), rad."""
    return np.arange(n_grid) * (TWO_PI / n_grid)


def interp_weights(phi: np.ndarray, n_grid: int) -> tuple[np.ndarray, np.ndarray]:
    """Bin index ``b`` (N,) and fraction ``t`` (N,) of the periodic linear interpolation.

    ``r(phi) = (1 - t) r_b + t r_{(b+1) mod G}``; ``phi`` unwrapped, rad.
    """
    x = np.mod(np.asarray(phi, float), TWO_PI) * (n_grid / TWO_PI)
    b = np.floor(x).astype(int)
    t = x - b
    return np.mod(b, n_grid), t


def interp_matrix(phi: np.ndarray, n_grid: int) -> np.ndarray:
    """Dense interpolation weights (N, G): ``r(phi_i) = W[i] @ r_grid``."""
    b, t = interp_weights(phi, n_grid)
    W = np.zeros((len(b), n_grid))
    rows = np.arange(len(b))
    W[rows, b] = 1.0 - t
    np.add.at(W, (rows, np.mod(b + 1, n_grid)), t)
    return W


@dataclass(frozen=True)
class RecordingStats:
    """Compressed hanging recording of one leg (see module docstring).

    ``X`` (K, G) pseudo-features, ``Y`` (K, 6) pseudo-readings (N, N*m),
    ``pure_rss`` (6,) the pure-error sum of squares per component, ``n`` the
    number of samples, ``support`` (G,) the interpolation weight each grid
    point receives (0 where no sample is near it), ``phi_span`` the range of
    the unwrapped shaft angle, rad.
    """

    name: str
    n: int
    X: np.ndarray
    Y: np.ndarray
    pure_rss: np.ndarray
    support: np.ndarray
    phi_span: float

    @property
    def k(self) -> int:
        return self.X.shape[0]

    @property
    def x1(self) -> np.ndarray:
        """Pseudo-feature of the constants (K,): ``X~ 1`` (interpolation weights sum to one)."""
        return self.X.sum(axis=1)


def sufficient_stats(phi: np.ndarray, y: np.ndarray, n_grid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``S_xx`` (G, G), ``S_xy`` (G, 6) and ``diag(S_yy)`` (6,) of one recording."""
    G = n_grid
    b, t = interp_weights(phi, G)
    b1 = np.mod(b + 1, G)
    u = 1.0 - t

    def acc(idx, wts):
        return np.bincount(idx, weights=wts, minlength=G)

    g = np.arange(G)
    S_xx = np.zeros((G, G))
    S_xx[g, g] = acc(b, u * u) + acc(b1, t * t)
    off = acc(b, u * t)  # between grid points b and b+1
    S_xx[g, (g + 1) % G] += off
    S_xx[(g + 1) % G, g] += off
    S_xy = np.stack([acc(b, u * y[:, c]) + acc(b1, t * y[:, c]) for c in range(y.shape[1])], axis=1)
    return S_xx, S_xy, np.einsum("ic,ic->c", y, y)


def compress_recording(name: str, phi: np.ndarray, y: np.ndarray, n_grid: int) -> RecordingStats:
    """Exact compression of one recording of one leg; ``y`` (N, 6) readings, ``phi`` (N,) rad.

    The factor is the Cholesky factor ``S_xx = L L^T`` over the grid points
    with data, so ``X~ = L^T`` keeps the (periodic) band structure of
    ``S_xx`` and the models built on it stay sparse. Grid points without data
    get zero columns.
    """
    S_xx, S_xy, S_yy = sufficient_stats(phi, y, n_grid)
    support = S_xx.sum(axis=1)  # sum_i w_ig: the weights of a sample add up to 1
    idx = np.flatnonzero(support > 1e-9 * len(phi))
    S = S_xx[np.ix_(idx, idx)]
    try:
        L = np.linalg.cholesky(S)
        X = np.zeros((len(idx), n_grid))
        X[:, idx] = L.T
        Y = np.linalg.solve(L, S_xy[idx])
    except np.linalg.LinAlgError:
        # Fewer samples than supported grid points nearby (a fast shaft): S_xx is singular. The
        # symmetric square root on its range is exact too (X~^T X~ = S_xx, X~^T Y~ = S_xy), only dense.
        lam, V = np.linalg.eigh(S)
        keep = lam > 1e-12 * lam.max()
        X = np.zeros((int(keep.sum()), n_grid))
        X[:, idx] = np.sqrt(lam[keep])[:, None] * V[:, keep].T
        Y = (V[:, keep].T @ S_xy[idx]) / np.sqrt(lam[keep])[:, None]
    pure = np.maximum(S_yy - np.einsum("kc,kc->c", Y, Y), 0.0)
    return RecordingStats(name, len(phi), X, Y, pure, support, float(np.ptp(phi)))
