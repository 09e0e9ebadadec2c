"""Standard errors of the per-foot ground wrenches: calibration covariance and sensor noise, by the delta method.

The ground wrench on foot k (``physics.ground_wrenches``, report eq. 3 moved to
the heading frame H about the robot's CoM at that instant) is

    f_gc = f_m - f_o - m_k g u_k,        tau_gc = tau_m - tau_o - r_k(phi) x m_k g u_k,   u_k = R_k^T u_B
    c    = sum_j m_j g (R_j r_j(phi_j) + p'_j) / (M g)                                   (total CoM in B)
    o_f  = R f_gc,   o_tau = R tau_gc + p x o_f,        R = R_HB R_k,   p = R_HB (p'_k - c)

(``u_B = R_WB^T (-z)``). Per sample it depends on 16 quantities of every leg,
``q_k = (w_o (6), m_k g, r_k(phi_k) (3), rho_k (3), p'_k (3))``, ``rho_k`` the
rotation error ``R_k -> exp([rho_k]) R_k`` in B axes (the covariance of the
results protocol's ``{leg}.R_tilde.*`` is that perturbation's, ``StandingResult``).
Its Jacobian ``J = D + E F`` is analytic: ``D`` block-diagonal (each foot on its
own leg), ``E = d o / d c`` (``[0; [o_f] R_HB]``) and ``F = d c / d q``:

    d o / d w_o,f = -[R; [p] R],   d o / d w_o,tau = -[0; R],
    d o / d mg    = -[R u; R (r x u) + [p] R u],          d o / d r = [0; m g R [u]],
    d o_f / d rho = -R_HB [R_k f_gc] - m g R R_k^T [u_B],
    d o_tau / d rho = -R_HB [R_k tau_gc] - m g R [r] R_k^T [u_B] + [p] d o_f / d rho,
    d o_tau / d p' = -[o_f] R_HB,   d c / d (mg, r, rho, p')_j = ((R_j r_j + p'_j), m_j g R_j, -m_j g [R_j r_j], m_j g I) / (M g).

The calibrated parameters ``theta`` (CoM grid values ``r_k[i]`` among them) map
to ``q`` linearly, ``q = A(phi) theta`` (``r_k(phi)`` interpolates two grid
points), so with the joint covariance ``C`` of ``theta``
(:meth:`CalibrationRun.cov_params`, hanging uncertainty propagated into standing)

    Var(o) = diag(J A C A^T J^T) + sum_k T_k Sigma_k T_k^T + J_theta Sigma_theta J_theta^T,

``T_k = d o / d w_m,k = -d o / d w_o,k`` with ``Sigma_k`` the readings' per-sample
covariance and ``J_theta`` the sensitivity to the motion-capture rotation error
(body axes, forward differences of ``ground_wrenches``) with its covariance
``Sigma_theta`` (both from :mod:`ftcal_nlp.estimate.sensor_noise`). The sum over feet
(``total``) takes the sums of the Jacobians, so the legs' covariances enter.
Undetermined parameters (se inf) give an infinite se to every output that
depends on them. Vectorised over samples in chunks (no per-sample Python loop).

Free loads (``DATA_FORMAT.md`` section 5): :func:`free_load_covariance` is the same
file's content for a free-load run, the estimator's covariance over each transducer's
``{X}.offset.*``, load parameters and ``{X}.mount.r*`` (independent blocks), which
``loads.calibrated`` reads back with :meth:`CalibrationCovariance.block`. There ``cov`` is
the covariance on the determined subspace (the rows of parameters that enter an
undetermined direction are kept: a determined combination of them has a finite se) and
``null`` (P, r) holds the undetermined directions: an output whose derivative has a
component along one of them is undetermined (``loads.base.se_of``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse import csr_matrix

from ..core.calibration import Calibration, interp_cells
from ..core.data import WRENCH_COMPONENTS
from ..core.errors import DataFormatError
from ..core.geometry import remove_yaw, rotvec_to_rotation, skew
from ..core.physics import ground_wrenches
from .sensor_noise import SensorNoise

__all__ = ["CalibrationCovariance", "WrenchUncertainty", "free_load_covariance", "ground_wrench_jacobian", "ground_wrench_se", "NQ"]

log = logging.getLogger(__name__)

NQ = 16                         # per-leg quantities q_k (module docstring)
_STATIC = np.r_[0:7, 10:16]     # q_k positions that are parameters themselves (not the interpolated CoM)
_COM = np.r_[7:10]
CHUNK = 2048                    # samples per vectorised block (memory ~ CHUNK * 42 * 96 doubles)
ORIENTATION_STEP_RAD = 1e-6     # forward-difference step of the motion-capture sensitivity


@dataclass(frozen=True)
class CalibrationCovariance:
    """The joint covariance of a calibration's parameters (results protocol labels, SI units) and the
    sensor noise estimated at calibration. ``cov`` (P, P) is finite: rows of undetermined parameters
    are zero and ``undetermined`` (P,) marks them. ``null`` (P, r): free loads only (module docstring):
    the undetermined directions, ``cov`` then the covariance on the determined subspace."""

    names: tuple[str, ...]
    cov: np.ndarray
    undetermined: np.ndarray
    noise: SensorNoise | None = None
    null: np.ndarray | None = None

    @classmethod
    def from_results(cls, results, noise: SensorNoise | None = None) -> "CalibrationCovariance":
        """From any results-protocol object (``CalibrationRun``): its ``params`` labels, ``cov_params()``, ``bse``."""
        bse = np.asarray(results.bse, float)
        C = np.array(results.cov_params().to_numpy(), float)
        und = np.isinf(bse)
        C[~np.isfinite(C)] = 0.0
        C[und, :] = 0.0
        C[:, und] = 0.0
        return cls(tuple(results.params.index), C, und, noise)

    def without_offsets(self) -> "CalibrationCovariance":
        """The same with every offset (``*.w_o.*``) taken as exact: for offsets estimated elsewhere (tracked)."""
        off = np.array([".w_o." in n for n in self.names])
        C = self.cov.copy()
        C[off, :] = 0.0
        C[:, off] = 0.0
        return CalibrationCovariance(self.names, C, self.undetermined & ~off, self.noise)

    def save(self, path: str | Path) -> None:
        """A compressed ``.npz`` (names, cov, undetermined); the noise lives in ``calibration.json``'s meta."""
        extra: dict[str, Any] = {} if self.null is None else {"null": self.null}   # (Any: not savez's allow_pickle)
        np.savez_compressed(path, names=np.array(self.names), cov=self.cov, undetermined=self.undetermined, **extra)

    def block(self, names: list[str] | tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
        """``(cov, undetermined, null)`` of the parameters ``names`` in that order (``null``: the undetermined
        directions that touch them, restricted to them; None when the file has none), or None when one of
        ``names`` is not in the file."""
        pos = {n: i for i, n in enumerate(self.names)}
        if any(n not in pos for n in names):
            return None
        idx = np.array([pos[n] for n in names], dtype=int)
        null = None
        if self.null is not None:
            N = self.null[idx]
            null = N[:, np.abs(N).max(axis=0) > 0] if N.size else N
        return self.cov[np.ix_(idx, idx)].copy(), self.undetermined[idx].copy(), null

    @classmethod
    def load(cls, path: str | Path, noise: SensorNoise | None = None) -> "CalibrationCovariance":
        path = Path(path)
        if not path.is_file():
            raise DataFormatError(f"{path}: calibration covariance file not found", path=path)
        try:
            with np.load(path, allow_pickle=False) as z:
                names, cov, und = tuple(str(n) for n in z["names"]), np.array(z["cov"], float), np.array(z["undetermined"], bool)
                null = np.array(z["null"], float) if "null" in z.files else None
        except (KeyError, ValueError, OSError) as exc:
            raise DataFormatError(f"{path}: expected an .npz with arrays 'names', 'cov', 'undetermined' ({exc})", path=path) from exc
        if cov.shape != (len(names), len(names)) or und.shape != (len(names),):
            raise DataFormatError(f"{path}: 'cov' must be {len(names)}x{len(names)} and 'undetermined' of length {len(names)}, "
                                  f"got {cov.shape} and {und.shape}", path=path)
        if null is not None and (null.ndim != 2 or null.shape[0] != len(names)):
            raise DataFormatError(f"{path}: 'null' must have {len(names)} rows, got shape {null.shape}", path=path)
        return cls(names, cov, und, noise, null)


def free_load_covariance(free_loads) -> CalibrationCovariance | None:
    """The covariance file's content for a free-load run (``freeload.FreeLoadResults``; None gives None): every
    transducer's parameters with their covariance on the determined subspace (independent blocks), the
    undetermined ones (se inf) marked and the undetermined directions in ``null`` (module docstring); a transducer
    whose sensor matrix was refitted adds ``D``'s entries (``{X}.C.<row>.<col>``) with their covariance with its
    parameters (``sensor_matrix.SensorMatrixResult.joint_cov``)."""
    if free_loads is None:
        return None
    blocks = [_free_block(r) for r in free_loads.legs.values()]
    P = sum(len(b[0]) for b in blocks)
    cov = np.zeros((P, P))
    null = np.zeros((P, sum(b[2].shape[1] for b in blocks)))
    i = j = 0
    for names, C, N, _ in blocks:
        n = len(names)
        cov[i: i + n, i: i + n] = C
        null[i: i + n, j: j + N.shape[1]] = N
        i, j = i + n, j + N.shape[1]
    names = tuple(n for b in blocks for n in b[0])
    und = np.concatenate([b[3] for b in blocks]) if blocks else np.zeros(0, bool)
    return CalibrationCovariance(names, cov, und, None, null)


def _free_block(r) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """``(names, cov, null, undetermined)`` of one transducer's free-load fit ``r`` (with its matrix's entries)."""
    names = tuple(r.names)
    C = np.where(np.isfinite(r.cov), r.cov, 0.0)
    N = np.zeros((len(names), 0)) if r.null is None else np.asarray(r.null, float)
    und = np.isinf(np.asarray(r.se, float))
    jc = getattr(r.sensor_matrix, "joint_cov", None)
    if jc is None:
        return names, C, N, und
    jn, jcov, jnull, jse = jc
    at = {n: k for k, n in enumerate(jn)}
    extra = [n for n in jn if n not in set(names)]                    # D's entries
    allnames = names + tuple(extra)
    idx = np.array([at.get(n, -1) for n in allnames])
    mine = idx >= 0
    P = len(allnames)
    out = np.zeros((P, P))
    out[: len(names), : len(names)] = C
    J = np.where(np.isfinite(jcov), jcov, 0.0)
    rows = np.flatnonzero(mine)
    ext = np.arange(len(names), P)
    # D's rows and columns against every parameter the joint fit estimated (the rest of r's block as r has it)
    out[np.ix_(ext, rows)] = J[np.ix_(idx[ext], idx[rows])]
    out[np.ix_(rows, ext)] = J[np.ix_(idx[rows], idx[ext])]
    Nn = np.zeros((P, max(N.shape[1], jnull.shape[1] if jnull.size else 0)))
    Nn[: len(names), : N.shape[1]] = N
    if jnull.size:
        Nn[ext, : jnull.shape[1]] = jnull[idx[ext]]
    und_all = np.concatenate([und, ~np.isfinite(np.asarray(jse, float)[idx[ext]])])
    return allnames, out, Nn, und_all


@dataclass(frozen=True)
class WrenchUncertainty:
    """Standard errors (N, K + 1, 6) of each foot's ground wrench and of their total (last), heading frame,
    N and N*m: ``se`` all together, ``se_calibration`` from the calibration's parameters alone,
    ``se_noise`` from the readings' and the motion capture's noise alone."""

    se: np.ndarray
    se_calibration: np.ndarray
    se_noise: np.ndarray


@dataclass(frozen=True)
class JacobianParts:
    """``J = D + E F`` of the module docstring for n samples: ``D`` (n, K, 6, 16) each foot on its own
    leg's ``q_k``; ``E`` (n, K, 6, 3) each foot on the total CoM ``c``; ``F`` (n, 3, K, 16) ``d c / d q``."""

    D: np.ndarray
    E: np.ndarray
    F: np.ndarray

    def full(self) -> np.ndarray:
        """The dense Jacobian (n, K + 1, 6, 16 K), rows per foot and the total last."""
        n, K = self.D.shape[:2]
        J = np.zeros((n, K + 1, 6, K * NQ))
        J[:, :K] = np.einsum("nkij,njq->nkiq", self.E, self.F.reshape(n, 3, K * NQ))
        for k in range(K):  # K blocks on the diagonal (legs, not samples)
            J[:, k, :, NQ * k : NQ * (k + 1)] += self.D[:, k]
        J[:, K] = J[:, :K].sum(axis=1)
        return J


def ground_wrench_jacobian(w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, cal: Calibration) -> tuple[np.ndarray, JacobianParts]:
    """Ground wrenches (N, K, 6) and their Jacobian w.r.t. every leg's ``q_k`` (module docstring) in parts
    (:class:`JacobianParts`). ``w_m`` (N, K, 6), ``phi`` (N, K), ``R_WB`` (N, 3, 3)."""
    offsets, mg, Rk, pp = cal.stacked()
    n, K = phi.shape
    W = cal.mass_kg * cal.g
    R_HB = remove_yaw(R_WB)
    u_B = -R_WB[:, 2, :]
    u = np.einsum("kji,nj->nki", Rk, u_B)
    r = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(cal.leg_names)], axis=1)
    fg = mg[None, :, None] * u
    f_gc = w_m[..., :3] - offsets[:, :3] - fg
    t_gc = w_m[..., 3:] - offsets[:, 3:] - np.cross(r, fg)
    Rr = np.einsum("kij,nkj->nki", Rk, r)
    c = np.einsum("k,nki->ni", mg, Rr + pp) / W
    R = np.einsum("nij,kjl->nkil", R_HB, Rk)
    p = np.einsum("nij,nkj->nki", R_HB, pp[None] - c[:, None])
    o_f = np.einsum("nkij,nkj->nki", R, f_gc)
    o_t = np.einsum("nkij,nkj->nki", R, t_gc) + np.cross(p, o_f)
    gw = np.concatenate([o_f, o_t], axis=-1)

    mgb = mg[None, :, None, None]
    Sp = skew(p)
    D = np.zeros((n, K, 6, NQ))
    D[:, :, :3, 0:3] = -R
    D[:, :, 3:, 0:3] = -Sp @ R
    D[:, :, 3:, 3:6] = -R
    Ru = np.einsum("nkij,nkj->nki", R, u)
    D[:, :, :3, 6] = -Ru
    D[:, :, 3:, 6] = -np.einsum("nkij,nkj->nki", R, np.cross(r, u)) - np.einsum("nkij,nkj->nki", Sp, Ru)
    D[:, :, 3:, 7:10] = mgb * (R @ skew(u))
    du = np.einsum("kji,njl->nkil", Rk, skew(u_B))                       # d u_k / d rho_k = R_k^T [u_B]
    RHB = R_HB[:, None]
    dof = -RHB @ skew(np.einsum("kij,nkj->nki", Rk, f_gc)) - mgb * (R @ du)
    D[:, :, :3, 10:13] = dof
    D[:, :, 3:, 10:13] = -RHB @ skew(np.einsum("kij,nkj->nki", Rk, t_gc)) - mgb * (R @ skew(r) @ du) + Sp @ dof
    Sof_RHB = skew(o_f) @ RHB                                              # (n, K, 3, 3)
    D[:, :, 3:, 13:16] = -Sof_RHB
    E = np.zeros((n, K, 6, 3))
    E[:, :, 3:] = Sof_RHB                                                  # the CoM moves every foot's lever
    F = np.zeros((n, 3, K, NQ))
    F[:, :, :, 6] = np.transpose(Rr + pp, (0, 2, 1)) / W
    F[:, :, :, 7:10] = np.transpose(mgb * Rk[None], (0, 2, 1, 3)) / W
    F[:, :, :, 10:13] = np.transpose(-mgb * skew(Rr), (0, 2, 1, 3)) / W
    F[:, :, :, 13:16] = np.transpose(np.broadcast_to(mgb * np.eye(3), (n, K, 3, 3)), (0, 2, 1, 3)) / W
    return gw, JacobianParts(D, E, F)


def _qf(A: np.ndarray, M: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Row-wise ``diag(A M B^T)`` over leading (broadcast) axes."""
    return np.sum((A @ M) * B, axis=-1)


class _Gather:
    """``A C A^T`` pieces for a calibration's parameter labels: the static block (constant) and the
    interpolated CoM rows (per sample), and the variance of ``J = D + E F`` from them."""

    def __init__(self, cal: Calibration, cc: CalibrationCovariance):
        legs = cal.leg_names
        K = len(legs)
        pos = {n: i for i, n in enumerate(cc.names)}
        P = len(cc.names)
        miss = P  # index of an appended zero row/column: parameters not estimated count as exact
        static_names = [[f"{k}.w_o.{c}" for c in WRENCH_COMPONENTS] + [f"{k}.mg"]
                        + [f"{k}.R_tilde.{c}" for c in "xyz"] + [f"{k}.p_prime.{c}" for c in "xyz"] for k in legs]
        self.sidx = np.array([pos.get(nm, miss) for names in static_names for nm in names])
        self.cidx = [np.array([[pos.get(f"{k}.com[{i}].{c}", miss) for c in "xyz"] for i in range(len(cal.legs[k].com_phi))])
                     for k in legs]
        self.grids = [cal.legs[k].com_phi for k in legs]
        Cx = np.zeros((P + 1, P + 1))
        Cx[:P, :P] = cc.cov
        self.C = Cx
        self.und = np.append(cc.undetermined, False)
        self.any_und = bool(self.und.any())
        self.C_S = np.ascontiguousarray(Cx[:, self.sidx])
        self.C_SS = self.C_S[self.sidx]
        ns = len(_STATIC)
        self.C_kk = np.stack([self.C_SS[ns * k : ns * (k + 1), ns * k : ns * (k + 1)] for k in range(K)])
        self.K = K

    def com_rows(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Parameter indices (n, 3K, 2) and weights (n, 3K, 2) of the interpolated CoM rows."""
        n = len(phi)
        idx = np.empty((n, self.K, 3, 2), dtype=int)
        wt = np.empty((n, self.K, 3, 2))
        for k in range(self.K):
            i0, i1, a = interp_cells(phi[:, k], self.grids[k])
            idx[:, k, :, 0] = self.cidx[k][i0]
            idx[:, k, :, 1] = self.cidx[k][i1]
            wt[:, k, :, 0] = (1 - a)[:, None]
            wt[:, k, :, 1] = a[:, None]
        return idx.reshape(n, 3 * self.K, 2), wt.reshape(n, 3 * self.K, 2)

    def variance(self, jp: JacobianParts, phi: np.ndarray) -> np.ndarray:
        """``diag(J A C A^T J^T)`` (n, K + 1, 6); inf where J touches an undetermined parameter.

        With ``q = (s, r)`` (static parameters, interpolated CoM) and ``c = F q``, each foot's rows need
        only its own ``q_k`` and ``c``; the total's rows need ``D_tot = sum_k D_k`` over all ``q``."""
        n, K = phi.shape
        ns = len(_STATIC)
        idx, wt = self.com_rows(phi)
        m = idx.shape[0] * idx.shape[1]
        A = csr_matrix((wt.ravel(), idx.ravel(), np.arange(0, 2 * m + 1, 2)), shape=(m, self.C.shape[0]))
        C_RS = (A @ self.C_S).reshape(n, 3 * K, K * ns)                              # the two grid rows, weighted
        C_RR = np.einsum("nri,nqj,nriqj->nrq", wt, wt, self.C[idx[:, :, :, None, None], idx[:, None, None, :, :]])
        Ds, Dr = jp.D[..., _STATIC], jp.D[..., _COM]                           # (n, K, 6, 13), (n, K, 6, 3)
        Fs = jp.F[..., _STATIC].reshape(n, 3, K * ns)
        Fr = jp.F[..., _COM].reshape(n, 3, 3 * K)
        C_cs = (Fs.reshape(n * 3, -1) @ self.C_SS).reshape(n, 3, -1) + Fr @ C_RS  # Cov(c, s)
        C_cr = Fs @ np.transpose(C_RS, (0, 2, 1)) + Fr @ C_RR                     # Cov(c, r)
        C_cc = C_cs @ np.transpose(Fs, (0, 2, 1)) + C_cr @ np.transpose(Fr, (0, 2, 1))
        E = jp.E
        # each foot: own q_k and c
        kk = np.arange(K)
        C_RSk = C_RS.reshape(n, K, 3, K, ns)[:, kk, :, kk, :].transpose(1, 0, 2, 3)   # (n, K, 3, 13)
        C_RRk = C_RR.reshape(n, K, 3, K, 3)[:, kk, :, kk, :].transpose(1, 0, 2, 3)    # (n, K, 3, 3)
        C_csk = C_cs.reshape(n, 3, K, ns).transpose(0, 2, 3, 1)                        # (n, K, 13, 3) Cov(s_k, c)
        C_crk = C_cr.reshape(n, 3, K, 3).transpose(0, 2, 3, 1)                         # (n, K, 3, 3) Cov(r_k, c)
        v = np.empty((n, K + 1, 6))
        v[:, :K] = (_qf(Ds, self.C_kk[None], Ds) + 2 * _qf(Dr, C_RSk, Ds) + _qf(Dr, C_RRk, Dr)
                    + 2 * _qf(Ds, C_csk, E) + 2 * _qf(Dr, C_crk, E) + _qf(E, C_cc[:, None], E))
        # the total: D_tot over every leg's q, E_tot = sum_k E_k
        Dts = Ds.transpose(0, 2, 1, 3).reshape(n, 6, K * ns)
        Dtr = Dr.transpose(0, 2, 1, 3).reshape(n, 6, 3 * K)
        Et = E.sum(axis=1)
        v[:, K] = (np.sum((Dts.reshape(n * 6, -1) @ self.C_SS).reshape(n, 6, -1) * Dts, axis=-1)
                   + 2 * _qf(Dtr, C_RS, Dts) + _qf(Dtr, C_RR, Dtr)
                   + 2 * _qf(Dts, np.transpose(C_cs, (0, 2, 1)), Et) + 2 * _qf(Dtr, np.transpose(C_cr, (0, 2, 1)), Et)
                   + _qf(Et, C_cc, Et))
        v = np.maximum(v, 0.0)
        if self.any_und:
            J = jp.full()
            und_q = np.zeros((n, K, NQ))
            und_q[..., _STATIC] = self.und[self.sidx].reshape(K, ns)[None]
            und_q[..., _COM] = np.any(self.und[idx] & (wt > 0), axis=-1).reshape(n, K, 3)
            touch = np.einsum("nmiq,nq->nmi", np.abs(J), und_q.reshape(n, K * NQ))
            v = np.where(touch > 0, np.inf, v)
        return v


def _orientation_jacobian(w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, cal: Calibration, gw: np.ndarray) -> np.ndarray:
    """``d o / d theta`` (n, K + 1, 6, 3): ground wrenches per rad of rotation error ``R_WB exp([theta])`` (body axes)."""
    out = []
    for i in range(3):
        Rp = R_WB @ rotvec_to_rotation(ORIENTATION_STEP_RAD * np.eye(3)[i])
        d = (ground_wrenches(w_m, phi, Rp, cal) - gw) / ORIENTATION_STEP_RAD
        out.append(np.concatenate([d, d.sum(axis=1, keepdims=True)], axis=1))
    return np.stack(out, axis=-1)


def ground_wrench_se(w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, cal: Calibration,
                     cc: CalibrationCovariance | None, noise: SensorNoise | None = None,
                     offset_cov: np.ndarray | None = None) -> WrenchUncertainty:
    """Standard errors of the ground wrenches of ``physics.ground_wrenches`` and of their total (module docstring).

    ``cc`` None: no calibration part; ``noise`` None: ``cc.noise`` (None there too: no noise part);
    ``offset_cov`` (N, K, 6, 6): covariance of per-sample offsets used instead of the calibration's
    (tracked offsets, ``tracking.py``; pass ``cc.without_offsets()`` then), it enters like reading noise.
    Shapes: ``w_m`` (N, K, 6) in ft_k, ``phi`` (N, K) rad, ``R_WB`` (N, 3, 3); returns (N, K + 1, 6) arrays.
    """
    noise = noise if noise is not None else (cc.noise if cc is not None else None)
    N, K = phi.shape
    gath = _Gather(cal, cc) if cc is not None else None
    Sig = np.zeros((K, 6, 6))
    if noise is not None:
        missing = [k for k in cal.leg_names if k not in noise.readings]
        if missing:
            raise DataFormatError(f"sensor noise: no readings covariance for leg(s) {missing}; it has {sorted(noise.readings)}")
        Sig = np.stack([noise.readings[k] for k in cal.leg_names])
    v_cal = np.zeros((N, K + 1, 6))
    v_noise = np.zeros((N, K + 1, 6))
    for a in range(0, N, CHUNK):
        s = slice(a, min(N, a + CHUNK))
        gw, jp = ground_wrench_jacobian(w_m[s], phi[s], R_WB[s], cal)
        if gath is not None:
            v_cal[s] = gath.variance(jp, phi[s])
        # T_k = d o_k / d w_m,k = -d o_k / d w_o,k; the legs' noises are independent, so the total adds them
        T = -jp.D[..., 0:6]
        S = Sig[None] if offset_cov is None else Sig[None] + offset_cov[s]
        v_noise[s, :K] = _qf(T, S, T)
        v_noise[s, K] = v_noise[s, :K].sum(axis=1)
        if noise is not None and noise.orientation_rad is not None:
            Jt = _orientation_jacobian(w_m[s], phi[s], R_WB[s], cal, gw)
            v_noise[s] += _qf(Jt, noise.orientation_rad, Jt)
    return WrenchUncertainty(np.sqrt(v_cal + v_noise), np.sqrt(v_cal), np.sqrt(v_noise))
