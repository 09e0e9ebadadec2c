"""The data of one free load and their exact compression (the estimator never loops over samples).

Model (``loads.base``): with ``b_n = R_nom,n^T g_B,n`` the nominal gravity in ft
(m/s^2), ``E`` the mounting rotation, ``theta`` (p,) the load's parameters,
``M = mu . theta`` and ``K_n`` (3, p) its lever,

    f_n = M E^T b_n + f_o,      t_n = (K_n theta) x (E^T b_n) + t_o.

Both are linear in the lifted vector

    z = [ w_o (6);  vec_r(M E) (9);  theta (x) vec_r(E) (9p) ]     (vec_r: row-major)

with features that are data only: ``y_n = F_n z + noise``, where
``F_n[i, 6 + 3m + i] = b_n[m]`` (force rows) and
``F_n[3 + i, 15 + 9l + 3m + k] = sum_j eps_ijk K_n[j, l] b_n[m]`` (torque rows).
So, channel by channel (``c``), the weighted sum of squares over all samples is

    sum_n W_c (y_n,c - F_n,c z)^2 = W_c (z^T Q_c z - 2 v_c^T z + s_c),
    Q_c = sum_n F_n,c^T F_n,c,   v_c = sum_n y_n,c F_n,c,   s_c = sum_n y_n,c^2,

exact for any weights ``W``: the NLP sees (6, d, d) numbers, not N samples.
The moments are formed block by block with BLAS products, touching only the
columns a channel can reach (4 for a force channel, 1 + 6p for a torque one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EPS = np.zeros((3, 3, 3))
EPS[0, 1, 2] = EPS[1, 2, 0] = EPS[2, 0, 1] = 1.0
EPS[0, 2, 1] = EPS[2, 1, 0] = EPS[1, 0, 2] = -1.0

_CHUNK = 16384


def n_lifted(p: int) -> int:
    return 15 + 9 * p


@dataclass
class FreeLoadData:
    """Quasi-static samples of one transducer's free load, all recordings together.

    ``y`` (N, 6) readings; ``b`` (N, 3) nominal gravity in ft (m/s^2); ``K`` (N, 3, p) the load's lever (a
    broadcast view when constant); ``R_nom`` (N, 3, 3) nominal ft orientation in B; ``source`` (N,) recording
    index; ``t`` (N,) s; ``names`` the recordings; ``selection`` per recording the quasi-static counts and
    thresholds; ``noise0`` (6,) the readings' noise sd from first differences of consecutive kept samples."""

    leg: str
    y: np.ndarray
    b: np.ndarray
    K: np.ndarray
    R_nom: np.ndarray
    source: np.ndarray
    t: np.ndarray
    names: tuple[str, ...]
    selection: dict[str, dict]
    noise0: np.ndarray
    masks: dict[str, np.ndarray]        # recording -> (N_rec,) the samples used
    q: dict[str, np.ndarray]            # joint -> (N,) angles of the samples used
    index: np.ndarray                   # (N,) row of each sample in its recording
    a: np.ndarray                       # (N, 3, 3) b = a u: u the tilted gravity of the sample's group
    tiltable: bool                      # every recording has the orientation per sample
    group: np.ndarray                   # (N,) tilt group of each sample (index into groups)
    groups: tuple[tuple[str, str], ...]  # (kind, name): "world" "", "recording" name, "fixed" ""

    @property
    def n(self) -> int:
        return len(self.y)


@dataclass(frozen=True)
class Moments:
    """Per channel ``Q`` (6, d, d), ``v`` (6, d), ``s`` (6,) of the module docstring; ``n`` samples."""

    Q: np.ndarray
    v: np.ndarray
    s: np.ndarray
    n: int

    def weighted(self, W: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``(sum_c W_c Q_c, sum_c W_c v_c, sum_c W_c s_c)``."""
        W = np.asarray(W, float)
        return np.einsum("c,cij->ij", W, self.Q), W @ self.v, float(W @ self.s)

    def rss(self, z: np.ndarray) -> np.ndarray:
        """Residual sum of squares per channel (6,) at lifted ``z``."""
        return np.einsum("i,cij,j->c", z, self.Q, z) - 2 * self.v @ z + self.s


def channel_columns(p: int, nz_l: np.ndarray) -> list[np.ndarray]:
    """Lifted columns each channel reaches: force i: w_o[i] and (M E)[m, i]; torque i: w_o[3+i] and
    theta_l E[m, k] for k != i, over the lever columns ``nz_l`` that are ever nonzero."""
    cols = [np.array([i, 6 + i, 9 + i, 12 + i]) for i in range(3)]
    for i in range(3):
        tc = [15 + 9 * l + 3 * m + k for l in nz_l for m in range(3) for k in range(3) if k != i]
        cols.append(np.array([3 + i] + tc))
    return cols


def torque_features(K: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``F_n[3 + i, 15:]`` as (n, 3, 9p): ``sum_j eps_ijk K[j, l] b[m]`` at column ``9l + 3m + k``."""
    n, _, p = K.shape
    return np.einsum("ijk,njl,nm->nilmk", EPS, K, b, optimize=True).reshape(n, 3, 9 * p)


def compress(y: np.ndarray, b: np.ndarray, K: np.ndarray, chunk: int = _CHUNK) -> Moments:
    """The channel moments of the module docstring, block by block. A lever that is the same for every sample
    (a rigid payload: ``K`` a broadcast view) makes every feature linear in ``[1, b_n]``: then the 4 x 4 moments of
    ``[1, b_n]`` (and their products with ``y``) give every channel's exactly, at the cost of one pass."""
    n, _, p = K.shape
    d = n_lifted(p)
    constant = K.strides[0] == 0 or n == 1
    nz_l = np.flatnonzero(np.any(K[0] != 0, axis=0)) if constant else np.flatnonzero(np.any(K != 0, axis=(0, 1)))
    cols = channel_columns(p, nz_l)
    Qs = [np.zeros((len(c), len(c))) for c in cols]
    vs = [np.zeros(len(c)) for c in cols]
    Xf = np.concatenate([np.ones((n, 1)), b], axis=1)
    G = Xf.T @ Xf                                       # shared by the three force channels
    Gy = Xf.T @ y                                       # (4, 6)
    for i in range(3):
        Qs[i], vs[i] = G, Gy[:, i]
    s = np.einsum("nc,nc->c", y, y)
    if constant:
        A = torque_features(np.broadcast_to(K[0], (3, 3, p)), np.eye(3))        # (basis m, channel, 9p): linear in b
        for i in range(3):
            T = np.zeros((4, len(cols[3 + i])))
            T[0, 0] = 1.0
            T[1:, 1:] = A[:, i, cols[3 + i][1:] - 15]
            Qs[3 + i], vs[3 + i] = T.T @ G @ T, T.T @ Gy[:, 3 + i]
    else:
        for a in range(0, n, chunk):
            sl = slice(a, min(a + chunk, n))
            yb, bb, Kb = y[sl], b[sl], K[sl]
            ones = np.ones((len(yb), 1))
            Ft = torque_features(Kb, bb)
            for i in range(3):
                X = np.concatenate([ones, Ft[:, i, cols[3 + i][1:] - 15]], axis=1)
                Qs[3 + i] += X.T @ X
                vs[3 + i] += X.T @ yb[:, 3 + i]
    Q = np.zeros((6, d, d))
    v = np.zeros((6, d))
    for c in range(6):
        Q[c][np.ix_(cols[c], cols[c])] = Qs[c]
        v[c][cols[c]] = vs[c]
    return Moments(Q, v, s, n)


def predict(b: np.ndarray, K: np.ndarray, theta: np.ndarray, mu: np.ndarray, E: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """Model readings (N, 6) (module docstring)."""
    g_ft = b @ E                                        # (E^T b_n)^T = b_n^T E
    f = float(mu @ theta) * g_ft
    s_n = K @ theta if K.ndim == 3 else np.broadcast_to(K @ theta, g_ft.shape)
    return np.concatenate([f, np.cross(s_n, g_ft)], axis=1) + w_o


def difference_noise(y: np.ndarray, source: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Noise sd per channel (6,) from first differences of consecutive samples (``index`` their row numbers in the
    recording, ``source`` the recording): white noise of sd s has differences of sd s sqrt 2. Robust (MAD)."""
    ok = (np.diff(index) == 1) & (np.diff(source) == 0)
    if ok.sum() < 10:
        return np.full(6, np.nan)
    d = np.diff(y, axis=0)[ok]
    return 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2.0)


def serial_inflation(res: np.ndarray, source: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per channel the lag-1 correlation ``rho`` (6,) of the residuals ``res`` (N, 6) over consecutive samples and
    the variance inflation of a mean under AR(1) errors, ``(1 + rho) / (1 - rho)``, between 1 and the samples per
    run of consecutive samples (the limit of a residual that is one constant per hold: a model error, not noise).
    White residuals give ~1. In a list of poses successive rows are successive poses: a correlation there is a
    drift across the session, and widens the se likewise."""
    idx = np.asarray(index)
    ok = (np.diff(idx) == 1) & (np.diff(source) == 0)
    if ok.sum() < 10:
        return np.zeros(6), np.ones(6)
    a, b = res[:-1][ok], res[1:][ok]
    a, b = a - a.mean(0), b - b.mean(0)
    rho = np.clip((a * b).sum(0) / np.sqrt((a * a).sum(0) * (b * b).sum(0)), -0.999, 0.999)
    runs = int((~ok).sum()) + 1
    cap = max(len(res) / runs, 1.0)
    return rho, np.clip((1 + rho) / (1 - rho), 1.0, cap)


def n_tilted(p: int) -> int:
    """Size of the tilted lifted vector ``[w_o; u_0 z_r; u_1 z_r; u_2 z_r]`` (``z_r = z[6:]``)."""
    return 6 + 3 * (n_lifted(p) - 6)


def compress_tilted(y: np.ndarray, a: np.ndarray, K: np.ndarray, chunk: int = _CHUNK) -> Moments:
    """Channel moments for a tilted gravity ``b_n = A_n u`` (``a`` (N, 3, 3) = ``A_n``, ``u`` the unit gravity of the
    tilted world): every feature is linear in ``b_n``, so ``F_n z = w_o + sum_k u_k G(A_n e_k) z_r`` is linear in the
    lifted ``[w_o; u (x) z_r]`` with data-only features; the moments of those are exact for any tilt."""
    n, _, p = K.shape
    dr = n_lifted(p) - 6
    D = 6 + 3 * dr
    nz_l = np.flatnonzero(np.any(K[0] != 0, axis=0)) if K.strides[0] == 0 or n == 1 else np.flatnonzero(np.any(K != 0, axis=(0, 1)))
    cols = channel_columns(p, nz_l)
    big = [np.r_[c, *[6 + k * dr + (cols[c][1:] - 6) for k in range(3)]] for c in range(6)]
    Q = np.zeros((6, D, D))
    v = np.zeros((6, D))
    for s0 in range(0, n, chunk):
        sl = slice(s0, min(s0 + chunk, n))
        yb, ab, Kb = y[sl], a[sl], K[sl]
        ones = np.ones((len(yb), 1))
        Fts = [torque_features(Kb, ab[:, :, k]) for k in range(3)]
        for c in range(6):
            if c < 3:
                X = np.concatenate([ones] + [ab[:, :, k] for k in range(3)], axis=1)
            else:
                X = np.concatenate([ones] + [Fts[k][:, c - 3, cols[c][1:] - 15] for k in range(3)], axis=1)
            Q[c][np.ix_(big[c], big[c])] += X.T @ X
            v[c][big[c]] += X.T @ yb[:, c]
    return Moments(Q, v, np.einsum("nc,nc->c", y, y), n)


def gravity_frame(gdir: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) whose third column is ``-gdir`` (N, 3) (unit gravity directions): ``F (0, 0, -1) = gdir``.
    A recording that gives gravity by ``gravity_body`` only is tilted in this frame: ``u = F R_y(ty) R_x(tx) (0, 0, -1)``
    (the tilt about two axes normal to its nominal gravity)."""
    c2 = -np.asarray(gdir, float)
    c2 = c2 / np.linalg.norm(c2, axis=-1, keepdims=True)
    h = np.where(np.abs(c2[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    c0 = h - np.sum(h * c2, axis=-1, keepdims=True) * c2
    c0 /= np.linalg.norm(c0, axis=-1, keepdims=True)
    return np.stack([c0, np.cross(c2, c0), c2], axis=-1)


def tilt_gravity(tilt: np.ndarray) -> np.ndarray:
    """Unit gravity ``u = R_t (0, 0, -1)`` of a world tilted by ``R_t = R_y(tilt[1]) R_x(tilt[0])`` (rad)."""
    al, be = float(tilt[0]), float(tilt[1])
    return np.array([-np.cos(al) * np.sin(be), np.sin(al), -np.cos(al) * np.cos(be)])


def tilt_derivative(tilt: np.ndarray) -> np.ndarray:
    """``d u / d tilt`` (3, 2) of ``u = tilt_gravity(tilt)``."""
    al, be = float(tilt[0]), float(tilt[1])
    return np.array([[np.sin(al) * np.sin(be), -np.cos(al) * np.cos(be)],
                     [np.cos(al), 0.0],
                     [np.sin(al) * np.cos(be), np.cos(al) * np.sin(be)]])
