"""The standing noise floor: a variance-component model of the pose-level balance residual.

What the diagnosis compares a held-out standing residual with must come from
what cannot be the gap, never from the residual it is compared with (issue 13,
item 2). For pose p let ``r_p`` (6,) be the calibrated fit's balance residual
(physics.py (E) or report eq. 9, ``balance.residual``) in W axes (heading
removed), N and N*m. Under "no gap" it is measurement noise around a few fixed
unknowns:

    r_p = X_p beta + e_p,        Cov(e_p) = C_p = Sigma_read,p + s_theta^2 G_p G_p^T          (N)

* ``Sigma_read,p`` (6, 6): the readings' part (sensor noise and motion-capture
  jitter: everything white within a steady run), from the within-segment
  scatter. The medians ``m_1``, ``m_2`` of the two halves of each steady run of
  the per-sample residual (already carried through the calibrated ``Ad_k``) give
  ``var(pose median) ~ E[d d^T] / 4``, ``d = m_1 - m_2``. Pooled in B axes (the
  sensors are fixed in B) and scaled by each run's length,
  ``S_0 = mean_p n_p d_p d_p^T / 4``, ``Sigma_read,p = T_p (S_0 / n_p) T_p^T``
  with ``T_p = blockdiag(R_p, R_p)`` (``crb/hexapod.py``'s ``sum_k Ad_k Sigma_w,p Ad_k^T``).
* ``G_p`` (6, 2): the residual's sensitivity to a small tilt ``eps`` (rad, about
  the horizontal W axes) of the measured body orientation. With ``R_true =
  exp([eps]) R_meas`` the measured up vector is ``z_meas = z + R_meas^T (eps x e_z)``,
  so ``G_p = T_p (d r / d z) R_p^T [e_y, -e_x]``, ``d r / d z`` read off
  ``balance.residual`` (linear in ``z``: unit differences are exact). Exact
  balance: ``G_p = M_b g [I_2; 0]`` (the weight rotating; no torque about the
  body CoM); report balance: also the torque of that force about C. This is the
  ``(M_b g)^2 s_z^2 (I - z z^T)`` term of ``crb/hexapod.py``.
* ``s_theta``: the per-pose motion-capture tilt error (rad per axis, constant
  through a pose, so the within-run scatter cannot see it). ONE scalar.
* ``X_p beta``: fixed effects, i.e. whatever is not noise: the calibration's own
  parameters (``J_p``, the residual's Jacobian on the error model's tangent
  space: the fit absorbed these directions), the hanging offsets it used
  (``J_h,p``: their errors are one fixed vector), and the structure a gap could
  have (intercept, a smooth time polynomial, each
  leg's force readings, its load change since the previous pose, its shaft
  angle and squared load: what the library's effects and the localisation's
  families follow), per component in B axes (where the sensors are; turned into
  W with the pose's orientation), and constants in W (a cable's pull) but along
  z. Neither the body tilt nor a W z constant (nor the leg weights' column, one):
  the measured tilt contains the very error ``s_theta`` measures, and a W z
  constant with the readings among the columns rebuilds the weight along it.
  Only what none of them predicts, and only in the components where ``G_p``
  acts, can raise ``s_theta``.

``s_theta^2`` is fitted by restricted maximum likelihood (REML, the fixed effects
integrated out) on the calibrated fit's own residuals: the residuals of the poses
the calibration was fitted to (its training residuals), never the held-out
residuals of the diagnosis' cross-validation. REML contrasts are orthogonal to
``J``, so what the fit absorbed is accounted for exactly whatever its weighting.
Computation: whitening by ``Sigma_read,p`` and rotating each pose onto the left
singular vectors of the whitened ``G_p`` makes every ``C_p`` diagonal,
``1 + s^2 d_pi^2``, with a basis that does not depend on ``s``. Standard error:
the observed REML information (second difference in ``s^2``), plus the sampling
error of ``Sigma_read`` carried through; ``s_theta = sqrt(max(s^2, 0))`` with
``se(s) = se(s^2) / (2 s)``, and a one-sided 95 % upper bound
``sqrt(s^2 + 1.645 se(s^2))``. It is identified when ``s^2 > 2 se(s^2)``;
otherwise it is reported as "below the upper bound".

Floor: the expected held-out RMS per component of the diagnosis' k-fold refit
(eq. 8's K-norm, ``standing_fit.py``; folds of ``selection.fold_indices`` with
the diagnosis' seed) under the noise model, pose p held out in fold f:

    floor_c^2 = mean_p [ C_p + J_p Cov_f(theta) J_p^T + E_p,f C_h E_p,f^T ]_cc
    Cov_f(theta) = A_f^-1 (sum_{q not in f} J_q^T K C_q K J_q) A_f^-1,   A_f = sum_{q not in f} J_q^T K J_q
    E_p,f = J_h,p - J_p A_f^-1 sum_{q not in f} J_q^T K J_h,q

the pose's own noise, the training fit's parameter error (the sandwich of
``crb/hexapod.py``; with K weights a large horizontal-force noise moves the frames
and shows in the torques, which the scalar ``1 + d / (6 P_train)`` does not
say, nor a pose's own leverage), and the hanging offsets' and leg weights'
standard errors ``C_h`` (diagonal) carried through the refit. ``cv_inflation``
(6,) is the resulting factor over ``mean_p C_p + E_p C_h E_p^T``; without a
model Jacobian the floor is ``(mean_p C_p + J_h C_h J_h^T) (1 + d / (6 P_train))``.
``spread`` (6,): the relative sd of a held-out RMS about the floor, by a seeded
Monte Carlo of the same model (what "within its sampling spread" means).

Check (is there MORE than this noise model explains? that, and only that, is a gap):

* structure: the GLS drop of ``r^T C^-1 r`` when the structure columns enter
  (chi^2, their number of columns), and whether they predict poses they were
  not fitted to (k-fold over poses, whitened held-out sum of squares with them
  over without, after the calibration's columns; about ``1 + q / P_train``
  under noise alone, below 1 for real structure). A gap needs both;
* variance: per component the ratio of the GLS residual's mean square to its
  expectation; the likelihood ratio of a free variance scale ``kappa_c >= 1``
  per component, ``P (k - 1 - ln k)``, summed (chi-bar^2 of 6 halves).

Both p-values above ``CHECK_ALPHA``: the per-pose scatter is measurement noise,
said so with its sizes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import chi2

from ..core.balance import K_DIAG, check_balance, features, residual
from ..core.calibration import Calibration
from ..core.data import WRENCH_COMPONENTS
from ..core.geometry import skew, transform_wrench
from ..models import ModelContext, resolve
from ..estimate.selection import fold_indices
from ..estimate.standing.result import physical
from ..effects.faces import legendre_time

CHECK_ALPHA = 1e-3             # p-value below which the residual has more than the noise model
IDENTIFIED_Z = 2.0             # s_theta^2 identified when it exceeds this many of its standard errors
UPPER_Z = 1.645                # one-sided 95 % upper bound
TIME_DEGREE = 3                # smooth time trend of the fixed effects: Legendre polynomials up to this degree
MIN_RESIDUAL_DOF_PER_COL = 4   # keep P >= this times the number of structure columns (drop families otherwise)
RANK_TOL = 1e-9                # relative singular value below which a fixed-effect direction is a repeat
SPREAD_DRAWS = 200             # Monte Carlo draws for the held-out RMS's sampling spread
SPREAD_SEED = 0               # of the Monte Carlo draws (the folds follow the diagnosis' seed)

__all__ = ["ReadingsNoise", "NoiseFloor", "calibrated_residual_B", "tilt_sensitivity", "physical_jacobian",
           "physical_columns", "model_jacobian", "readings_noise", "structure_basis", "fit_noise_floor", "CHECK_ALPHA"]


# ----------------------------------------------------------------------------- the residual and its sensitivities


def _report_reference(cal: Calibration, legs, R: np.ndarray, p: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The body CoM relative to eq. 9's fixed point C (B axes): the calibration stores ``p'`` about
    the body CoM (``standing/fit.py`` converts), the report balance needs it about C."""
    m = np.array([cal.legs[k].leg_weight_N for k in legs])
    r_mean = np.stack([cal.legs[k].com(phi[:, i]).mean(axis=0) for i, k in enumerate(legs)])
    Mb = cal.mass_kg * cal.g - m.sum()
    return -np.einsum("k,ki->i", m, np.einsum("kij,kj->ki", R, r_mean) + p) / Mb


def _residual_fn(w_m: np.ndarray, phi: np.ndarray, cal: Calibration, legs, balance: str):
    """``z (P, 3) -> r (P, 6)``, the calibrated balance residual in B axes at up vectors ``z``."""
    check_balance(balance)
    off, m, R, p = cal.stacked(legs)
    if balance == "report":
        p = p + _report_reference(cal, legs, R, p, phi)
    P = len(w_m)

    def fn(z: np.ndarray) -> np.ndarray:
        R_up = np.zeros((P, 3, 3))
        R_up[:, 2, :] = z  # ``features`` reads the up vector from the third row
        xi = features(w_m, phi, R_up, cal, legs, balance)
        return residual(xi, R, p, off, m, cal.mass_kg * cal.g, balance)

    return fn


def _to_world6(R_HB: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``blockdiag(R_p, R_p) M_p`` for M (P, 6, n)."""
    return np.concatenate([R_HB @ M[:, :3], R_HB @ M[:, 3:]], axis=1)


def calibrated_residual_B(w_m: np.ndarray, phi: np.ndarray, R_HB: np.ndarray, cal: Calibration, legs,
                          balance: str = "exact") -> np.ndarray:
    """The calibrated fit's balance residual (P, 6), B axes (N, N*m), of poses with readings ``w_m``
    (P, K, 6) in ft_k, shaft angles ``phi`` (P, K) rad and orientations ``R_HB`` (P, 3, 3) (B -> W)."""
    return _residual_fn(w_m, phi, cal, legs, balance)(R_HB[:, 2, :])


def tilt_sensitivity(w_m: np.ndarray, phi: np.ndarray, R_HB: np.ndarray, cal: Calibration, legs,
                     balance: str = "exact") -> np.ndarray:
    """``G_p`` (P, 6, 2), W axes: residual (N, N*m) per rad of orientation error about the horizontal
    W axes x and y (module docstring)."""
    fn = _residual_fn(w_m, phi, cal, legs, balance)
    z = R_HB[:, 2, :]
    r0 = fn(z)
    Jz = np.stack([fn(z + np.eye(3)[i]) - r0 for i in range(3)], axis=2)     # (P, 6, 3) d r_B / d z
    A = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, 0.0]])                     # eps -> eps x e_z, eps = (eps_x, eps_y, 0)
    return _to_world6(R_HB, Jz @ (np.transpose(R_HB, (0, 2, 1)) @ A))


def physical_jacobian(w_m: np.ndarray, R_HB: np.ndarray, cal: Calibration, legs) -> np.ndarray:
    """``d r_p / d h`` (P, 6, 13 K), W axes, of the exact balance residual with respect to, per leg
    k in order, the rotation ``delta_k`` (3, rad, ``R_k -> exp([delta_k]) R_k``, B axes), the
    translation ``p'_k`` (3, m), the offset ``w_o,k`` (6, ft_k) and the leg weight ``m_k g`` (1, N):

        d f / d delta_k = -[f_k],   d tau / d delta_k = -[tau'_k] - [p'_k][f_k],   d tau / d p'_k = -[f_k],
        d r / d w_o,k = -Ad_k,      d f / d (m_k g) = z,

    ``f_k = R_k (f_m - f_o)``, ``tau'_k = R_k (tau_m - tau_o)``."""
    off, _, R, p = cal.stacked(legs)
    P, K = len(w_m), len(legs)
    v = w_m - off[None]
    f = np.einsum("kij,pkj->pki", R, v[..., :3])
    tq = np.einsum("kij,pkj->pki", R, v[..., 3:])
    Sf = skew(f)                                                             # (P, K, 3, 3)
    J = np.zeros((P, 6, 13 * K))
    z = R_HB[:, 2, :]
    for k in range(K):
        c = 13 * k
        J[:, :3, c : c + 3] = -Sf[:, k]
        J[:, 3:, c : c + 3] = -skew(tq[:, k]) - skew(p[k])[None] @ Sf[:, k]
        J[:, 3:, c + 3 : c + 6] = -Sf[:, k]
        J[:, :, c + 6 : c + 12] = -transform_wrench(R[k], p[k], np.eye(6)).T[None]  # -Ad_k
        J[:, :3, c + 12] = z
    return _to_world6(R_HB, J)


def physical_columns(K: int, rotations: bool = True, translations: bool = True, offsets: bool = False,
                     weights: bool = False) -> np.ndarray:
    """Indices into :func:`physical_jacobian`'s columns of the named parameter kinds, leg by leg."""
    keep = [rotations] * 3 + [translations] * 3 + [offsets] * 6 + [weights]
    return np.concatenate([13 * k + np.flatnonzero(keep) for k in range(K)])


def model_jacobian(model, ctx: ModelContext, J_phys: np.ndarray) -> np.ndarray | None:
    """``d r_p / d x`` (P, 6, n), W axes, of the error model ``model`` (a name or plug-in, built in
    ``ctx``) from :func:`physical_jacobian`: its rotations, translations and (if it fits them)
    offsets as functions of its variables (``standing.result.physical`` at the model's start
    point; only their span matters here). None when the model cannot be built."""
    try:
        spec = resolve(model).build(ctx)
        ph = physical(spec, np.asarray(spec.x0, float), ctx.legs)
    except (ValueError, TypeError, RuntimeError, ImportError, AttributeError):
        return None
    K = ctx.K
    n = ph.D.shape[1]
    D = np.zeros((13 * K, n))
    rows = np.arange(13 * K).reshape(K, 13)
    D[rows[:, 0:3].ravel()] = ph.D[: 3 * K]
    D[rows[:, 3:6].ravel()] = ph.D[3 * K : 6 * K]
    if ph.offsets is not None:
        D[rows[:, 6:12].ravel()] = ph.D[6 * K : 12 * K]
    return J_phys @ D


# ----------------------------------------------------------------------------- readings


@dataclass(frozen=True)
class ReadingsNoise:
    """Readings' contribution to the pose-level residual.

    ``S0_B`` (6, 6) per-sample-equivalent covariance in B axes (``n_p`` times a pose median's);
    ``sigma_W`` (P, 6, 6) each pose's ``Sigma_read,p`` in W axes; ``n_used`` poses whose
    steady run gave a half-run difference; ``rel_se`` (6,) relative standard error of the pooled
    variances (from the differences' fourth moments); ``measured`` False when too few steady runs
    were found (then ``sigma_W`` is NaN).
    """

    S0_B: np.ndarray
    sigma_W: np.ndarray
    n_used: int
    rel_se: np.ndarray
    measured: bool = True


def readings_noise(dd_B: np.ndarray, n_run: np.ndarray, R_HB: np.ndarray, min_poses: int = 5) -> ReadingsNoise:
    """``Sigma_read,p`` from the half-run median differences ``dd_B`` (P, 6) (B axes, NaN where the
    run was not found), the runs' sample counts ``n_run`` (P,) and the orientations ``R_HB`` (P, 3, 3)."""
    P = len(dd_B)
    n = np.asarray(n_run, float)
    ok = np.all(np.isfinite(dd_B), axis=1) & (n > 0)
    if ok.sum() < min_poses:
        return ReadingsNoise(np.full((6, 6), np.nan), np.full((P, 6, 6), np.nan), int(ok.sum()), np.full(6, np.nan), False)
    n_ref = float(np.median(n[ok]))
    # A median's variance goes as 1 / n, within reason: a run much shorter or longer than the others
    # is not taken to be that much noisier or quieter.
    n_eff = np.clip(np.where(n > 0, n, n_ref), 0.25 * n_ref, 4.0 * n_ref)
    d = dd_B[ok] * np.sqrt(n_eff[ok])[:, None]
    S0 = np.einsum("pi,pj->ij", d, d) / (4.0 * ok.sum())
    d2 = d**2
    rel_se = np.sqrt(np.var(d2, axis=0) / ok.sum()) / np.maximum(np.mean(d2, axis=0), 1e-300)
    S_W = _to_world6(R_HB, np.transpose(_to_world6(R_HB, np.broadcast_to(S0, (P, 6, 6)) / n_eff[:, None, None]), (0, 2, 1)))
    return ReadingsNoise(S0, S_W, int(ok.sum()), rel_se, True)


# ----------------------------------------------------------------------------- fixed effects: what a gap could follow


def structure_basis(t_h: np.ndarray, phi: np.ndarray, force: np.ndarray, history: np.ndarray | None = None,
                    max_cols: int | None = None) -> tuple[np.ndarray, list[str]]:
    """Structure columns (P, q), intercept first, and their names: what an effect of the library
    follows (the localisation's families): Legendre polynomials of time (degree <= ``TIME_DEGREE``),
    each leg's force reading less its offset (``force`` (P, K, 3), ft_k axes: crosstalk, load
    effects), the change of its vertical load since the previous pose (``history`` (P, K), None:
    unknown), ``cos, sin`` of its shaft angle and its squared vertical load; standardised.
    Families are dropped from the end when there would be more than ``max_cols`` columns (few
    poses); constant columns are left out."""
    P, K = phi.shape
    time = legendre_time(t_h, *((float(t_h.min()), float(t_h.max())) if P else (0.0, 0.0)), range(1, TIME_DEGREE + 1))
    fam = [(time, [f"time P{i}" for i in range(1, TIME_DEGREE + 1)]),
           (force.reshape(P, 3 * K), [f"force {k}.{c}" for k in range(K) for c in "xyz"])]
    if history is not None:
        fam.append((history, [f"load change {k}" for k in range(K)]))
    fam += [(np.concatenate([np.cos(phi), np.sin(phi)], axis=1), [f"cos phi {k}" for k in range(K)] + [f"sin phi {k}" for k in range(K)]),
            (force[:, :, 2] ** 2, [f"load^2 {k}" for k in range(K)])]
    cols, names = [np.ones((P, 1))], ["intercept"]
    for F, nm in fam:
        keep = np.ptp(F, axis=0) > 1e-9 if P else np.zeros(F.shape[1], bool)
        if not keep.any():
            continue
        if max_cols is not None and len(names) + int(keep.sum()) > max_cols:
            break
        F = F[:, keep]
        cols.append((F - F.mean(axis=0)) / F.std(axis=0))
        names += [x for x, k in zip(nm, keep) if k]
    return np.concatenate(cols, axis=1), names


def _span(M: np.ndarray) -> np.ndarray:
    """Orthonormal basis (n, r) of the column span of ``M`` (n, m)."""
    if M.shape[1] == 0:
        return M
    U, s, _ = np.linalg.svd(M, full_matrices=False)
    return U[:, s > RANK_TOL * s[0]] if s.size and s[0] > 0 else U[:, :0]


# ----------------------------------------------------------------------------- REML


class _Reml:
    """REML of ``r = X beta + e``, ``Cov(e_p) = S_p + s2 H_p``, in whitened, per-pose rotated coordinates
    where every covariance is ``diag(1 + s2 d_pi^2)`` (module docstring). ``X`` (6P, m) W axes, pose-major."""

    def __init__(self, r: np.ndarray, X: np.ndarray, S: np.ndarray, G: np.ndarray):
        P = len(r)
        L = np.linalg.cholesky(S)
        Li = np.linalg.inv(L)
        Gt = Li @ G                                                          # (P, 6, 2)
        U, d, _ = np.linalg.svd(Gt, full_matrices=True)                      # U (P, 6, 6), d (P, 2)
        Q = np.transpose(U, (0, 2, 1)) @ Li                                  # (P, 6, 6): r -> rotated white coordinates
        self.P = P
        self.logdetS = 2.0 * float(np.log(np.diagonal(L, axis1=1, axis2=2)).sum())
        self.d2 = np.zeros((P, 6))
        self.d2[:, : d.shape[1]] = d**2
        self.Q = Q
        self.y = np.einsum("pij,pj->pi", Q, r).ravel()
        self.r, self.S, self.G = r, S, G
        self.set_design(X)
        dmax = float(self.d2.max()) if self.d2.size else 0.0
        self.s2_min = -0.9 / dmax if dmax > 0 else -np.inf

    def set_design(self, X: np.ndarray) -> None:
        self.X = X
        Xp = X.reshape(self.P, 6, -1)
        self.Xt = np.einsum("pij,pjm->pim", self.Q, Xp).reshape(6 * self.P, -1)

    def _lam(self, s2: float) -> np.ndarray:
        return (1.0 + s2 * self.d2).ravel()

    def solve(self, s2: float, X: np.ndarray | None = None) -> tuple[float, float, float, float, np.ndarray, np.ndarray]:
        """(sum log lambda, log|A|, y' L^-1 y, b' A^-1 b, beta, A^-1) at ``s2`` for design ``X`` (rotated; None: the set one)."""
        Xt = self.Xt if X is None else X
        lam = self._lam(s2)
        wy = self.y / lam
        A = Xt.T @ (Xt / lam[:, None])
        b = Xt.T @ wy
        cA = np.linalg.cholesky(A)
        u = np.linalg.solve(cA, b)
        Ai = np.linalg.inv(A)
        return (float(np.log(lam).sum()), 2.0 * float(np.log(np.diag(cA)).sum()), float(self.y @ wy), float(u @ u), Ai @ b, Ai)

    def loglik(self, s2: float) -> float:
        if s2 <= self.s2_min:
            return -np.inf
        try:
            ll, la, q, pr, _, _ = self.solve(s2)
        except np.linalg.LinAlgError:
            return -np.inf
        return -0.5 * (self.logdetS + ll + la + q - pr)


def _curvature(f, x: float, h: float, lo: float) -> float:
    """``-f''(x)`` by a second difference (one-sided when ``x - h`` is below ``lo``)."""
    if x - h > lo:
        return -(f(x + h) - 2.0 * f(x) + f(x - h)) / h**2
    return -(f(x + 2 * h) - 2.0 * f(x + h) + f(x)) / h**2


# ----------------------------------------------------------------------------- the floor


@dataclass(frozen=True)
class NoiseFloor:
    """The standing noise floor and its parts (module docstring); W axes, N and N*m.

    ``floor`` (6,) expected held-out RMS per component; ``readings``, ``mocap``, ``calibration``
    (hanging se carried through the refit), ``fit`` (the training fit's parameter error) (6,) each
    part's RMS per component; ``cv_inflation`` (6,) ``floor^2`` over its no-refit part; ``spread``
    (6,) relative sd of a held-out RMS about the floor under the noise model (Monte Carlo);
    ``s_theta_rad``, ``s_theta_se_rad``, ``s_theta_upper_rad`` the fitted per-pose tilt error, its
    se and one-sided 95 % upper bound; ``s2``, ``s2_se`` the variance component (rad^2),
    unconstrained; ``identified`` whether the residual has the tilt structure; ``check`` the
    structure and variance tests; ``gap`` whether the residual has more than this model explains;
    ``statement`` one plain-language sentence.
    """

    floor: np.ndarray
    readings: np.ndarray
    mocap: np.ndarray
    calibration: np.ndarray
    fit: np.ndarray
    cv_inflation: np.ndarray
    spread: np.ndarray
    s_theta_rad: float
    s_theta_se_rad: float
    s_theta_upper_rad: float
    s2: float
    s2_se: float
    identified: bool
    check: dict
    gap: bool
    statement: str
    n_poses: int
    n_readings: int
    fixed_effects: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def s_theta_deg(self) -> float:
        return float(np.degrees(self.s_theta_rad))

    def parts(self) -> dict:
        """JSON-ready parts for ``diagnosis.json`` (lists, floats, strings)."""
        lst = lambda a: [float(x) for x in np.asarray(a, float)]
        deg = lambda x: float(np.degrees(x)) if np.isfinite(x) else None
        return {
            "floor": lst(self.floor),
            "readings": lst(self.readings),
            "mocap": {"s_theta_deg": deg(self.s_theta_rad), "se_deg": deg(self.s_theta_se_rad),
                      "upper_deg": deg(self.s_theta_upper_rad), "identified": bool(self.identified), "rms": lst(self.mocap)},
            "calibration": lst(self.calibration),
            "fit": lst(self.fit),
            "cv_inflation": lst(self.cv_inflation),
            "spread": lst(self.spread),
            "check": {k: (lst(v) if isinstance(v, np.ndarray) else v) for k, v in self.check.items()},
            "gap": bool(self.gap),
            "statement": self.statement,
            "n_poses": int(self.n_poses),
            "poses_with_run": int(self.n_readings),
            "fixed_effects": list(self.fixed_effects),
            "notes": list(self.notes),
        }


def fit_noise_floor(r_W: np.ndarray, readings: ReadingsNoise, G: np.ndarray, structure: np.ndarray, *,
                    J: np.ndarray | None = None, J_h: np.ndarray | None = None, C_h: np.ndarray | None = None,
                    model_dof: int = 0, folds: int, names: list[str] | None = None,
                    R_HB: np.ndarray | None = None, J_h_fixed: np.ndarray | None = None, seed: int) -> NoiseFloor:
    """Fit the noise model to the calibrated fit's own residuals and derive the floor (module docstring).

    ``r_W`` (P, 6) the calibrated fit's residuals, W axes; ``readings`` (:func:`readings_noise`);
    ``G`` (P, 6, 2) (:func:`tilt_sensitivity`); ``structure`` (P, q) intercept first
    (:func:`structure_basis`); ``J`` (P, 6, d) the residual's Jacobian on the error model's
    tangent space (None: unknown; then the scalar inflation ``1 + model_dof / (6 P_train)``);
    ``J_h`` (P, 6, h) and ``C_h`` (h,) the hanging parameters' Jacobian and variances, ``J_h_fixed``
    the indices of its columns that are fixed effects of the REML (None: all; see the code);
    ``folds``/``seed`` of the diagnosis' cross-validation; ``names`` of the structure columns; ``R_HB``
    (P, 3, 3) the poses' orientations (B -> W): the structure columns act in B axes (None: in W).
    """
    P = len(r_W)
    notes: list[str] = []
    P_train = P * (1.0 - 1.0 / max(folds, 2))
    S = readings.sigma_W
    Gm = G
    if not readings.measured:
        # No steady run found again: nothing independent of the residual measures the readings. The
        # floor falls back on the residual's own spread, and says so (the only case it does).
        notes.append("no steady runs found: the readings' part of the floor is the residual's own spread (not independent of it)")
        v = np.maximum(np.mean((r_W - r_W.mean(axis=0)) ** 2, axis=0), 1e-12)
        S = np.broadcast_to(np.diag(v), (P, 6, 6)).copy()
        Gm = np.zeros_like(G)
    d = J.shape[2] if J is not None else 0
    h = J_h.shape[2] if J_h is not None else 0
    if h and C_h is None:
        raise ValueError(f"fit_noise_floor: J_h has {h} hanging parameters but no C_h (their variances) was given")
    # Fixed effects: the calibration's parameters and the hanging offsets (constants in B). Not the
    # leg weights: their column is a constant along W z, which together with the readings would
    # rebuild the weight along the measured up vector (see the structure columns below); the B
    # constant stands in for it, and their se enter the floor.
    J_off = J_h[:, :, J_h_fixed] if (J_h is not None and J_h_fixed is not None) else J_h
    fixed = [m.reshape(6 * P, -1) for m in (J, J_off) if m is not None and m.shape[2]]
    # Structure per component in B axes (what is fixed to the sensors: offsets, their drift, load
    # and angle effects), turned into W axes with the pose's orientation, and a constant in W
    # except along z: with the readings among the columns a W z constant would rebuild the weight
    # along the measured up vector, and with it the very tilt error s_theta measures (the B
    # constant stands in for it: most poses are nearly level).
    Xs = np.einsum("pa,ij->piaj", structure, np.eye(6))                       # (P, 6, q, 6)
    if R_HB is not None:
        Xs = np.concatenate([R_HB @ Xs[:, :3].reshape(P, 3, -1), R_HB @ Xs[:, 3:].reshape(P, 3, -1)], axis=1)
    Xs = Xs.reshape(6 * P, -1)
    Xw = np.tile(np.eye(6)[:, [0, 1, 3, 4, 5]], (P, 1))                    # W constants but fz
    X_red = _span(np.concatenate(fixed + [Xw, Xs[:, :6]], axis=1))          # calibration + intercepts
    X_full = _span(np.concatenate(fixed + [Xw, Xs], axis=1))
    if 6 * P - X_full.shape[1] < 12:
        notes.append("too few poses for the structure columns: intercept only")
        X_full = X_red
    reml = _Reml(r_W, X_full, S, Gm)

    # ---- s_theta^2 by REML
    trH = float(np.mean(np.einsum("pia,pia->p", Gm, Gm)))
    s2, s2_se = 0.0, np.inf
    if trH > 0:
        Gp = np.linalg.pinv(Gm)                                                 # (P, 2, 6)
        s2_read = float(np.mean(np.einsum("pai,pij,paj->p", Gp, S, Gp)) / 2.0)  # readings' variance as tilt, rad^2 per axis
        s2_tot = max(float(np.mean(np.einsum("pai,pi->pa", Gp, r_W) ** 2)), s2_read)
        lo = max(reml.s2_min, -s2_read)
        res = minimize_scalar(lambda x: -reml.loglik(x), bounds=(lo, 4.0 * s2_tot), method="bounded",
                              options={"xatol": 1e-5 * (s2_tot + s2_read)})
        s2 = float(res.x)
        step = 0.05 * max(abs(s2), s2_read)
        info = _curvature(reml.loglik, s2, step, reml.s2_min)
        se_reml = 1.0 / np.sqrt(info) if info > 0 else np.inf
        # the pooled readings' variance is an estimate too: its error moves s2 by its tilt equivalent
        rel = float(np.sqrt(np.mean(readings.rel_se[:3] ** 2))) if readings.measured else 0.0
        s2_se = float(np.hypot(se_reml, rel * s2_read))
    else:
        notes.append("the residual does not depend on the body orientation: no motion-capture term")
    identified = bool(np.isfinite(s2_se) and s2 > IDENTIFIED_Z * s2_se)
    s = float(np.sqrt(max(s2, 0.0)))
    if identified:
        s_se = float(s2_se / (2.0 * s))
    else:
        s_se = float(np.sqrt(s2_se)) if np.isfinite(s2_se) else np.inf
    s_up = float(np.sqrt(max(s2 + UPPER_Z * s2_se, 0.0))) if np.isfinite(s2_se) else np.inf

    # ---- the floor: expected held-out mean square of the K-norm refit
    s2f = max(s2, 0.0)
    C = S + s2f * np.einsum("pia,pja->pij", Gm, Gm)
    read_ms = np.einsum("pii->i", S) / P
    moc_ms = s2f * np.einsum("pia,pia->i", Gm, Gm) / P
    fit_ms = np.zeros(6)
    cal_ms = np.zeros(6)
    if J is not None and d:
        Jf = J.reshape(6 * P, d)
        V = _span(Jf)                                        # residual-space basis of what the fit moves
        coef = np.linalg.lstsq(Jf, V, rcond=None)[0]         # (d, r): J coef = V
        Jr = np.einsum("pid,dr->pir", J, coef)
        Jh = J_h if (J_h is not None and h) else np.zeros((P, 6, 0))
        Ch = C_h if (C_h is not None and h) else np.zeros(0)
        fit_ms, cal_ms = _refit_terms(Jr, C, Jh, Ch, folds, seed)
        base = read_ms + moc_ms + cal_ms
        floor2 = base + fit_ms
        spread = _heldout_spread(C, Jr, Jh, Ch, folds, seed=seed)
    else:
        if J_h is not None and C_h is not None and h:
            cal_ms = np.einsum("pih,h,pih->i", J_h, C_h, J_h) / P
        base = read_ms + moc_ms + cal_ms
        floor2 = base * (1.0 + model_dof / max(6.0 * P_train, 1.0))
        fit_ms = floor2 - base
        spread = _heldout_spread(C, None, J_h if (J_h is not None and h) else None, C_h, folds, seed=seed)
    floor = np.sqrt(floor2)
    inflation = floor2 / np.where(base > 0, base, 1.0)

    check = _check(reml, max(s2, 0.0), X_red, folds, seed)
    structured = check["structure_p"] < CHECK_ALPHA and check["structure_cv_ratio"] < 1.0
    gap = bool(structured or check["variance_p"] < CHECK_ALPHA)
    st = _statement(gap, identified, s, s_se, s_up, np.sqrt(read_ms), check)
    return NoiseFloor(floor, np.sqrt(read_ms), np.sqrt(moc_ms), np.sqrt(cal_ms), np.sqrt(np.maximum(fit_ms, 0.0)), inflation, spread,
                      s, s_se, s_up, s2, s2_se, identified, check, gap, st, P, readings.n_used, tuple(names or ()), tuple(notes))


def _refit_terms(Jr: np.ndarray, C: np.ndarray, J_h: np.ndarray, C_h: np.ndarray, folds: int,
                 seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean squares (6,) a held-out pose gets from the K-norm refit on the other folds: the refit's
    parameter error (sandwich ``A_f^-1 B_f A_f^-1`` of the training poses) and the hanging errors
    (``J_h`` (P, 6, h), variances ``C_h``) less what the refit absorbs of them; fold by fold, so a
    pose of high leverage gets the error of a fit that did not see it."""
    P = len(Jr)
    JK = Jr * K_DIAG[None, :, None]
    fit_ms, cal_ms = np.zeros(6), np.zeros(6)
    nf = max(folds, 2)
    tests = fold_indices(P, nf, seed) if P >= 2 * nf else [np.arange(P)]
    for test in tests:
        train = np.ones(P, bool)
        if len(tests) > 1:
            train[test] = False
        Ai = np.linalg.pinv(np.einsum("pir,pis->rs", JK[train], Jr[train]))
        B = np.einsum("pir,pij,pjs->rs", JK[train], C[train], JK[train])
        scale = 1.0 if len(tests) > 1 else 1.0 + 1.0 / (nf - 1)   # too few poses for folds: P / P_train
        fit_ms += scale * np.einsum("pir,rs,pis->i", Jr[test], Ai @ B @ Ai, Jr[test])
        if J_h.shape[2]:
            Gh = Ai @ np.einsum("pir,pih->rh", JK[train], J_h[train])
            E = J_h[test] - np.einsum("pir,rh->pih", Jr[test], Gh)
            cal_ms += np.einsum("pih,h,pih->i", E, C_h, E)
    return fit_ms / P, cal_ms / P


def _heldout_spread(C: np.ndarray, Jr: np.ndarray | None, J_h: np.ndarray | None, C_h: np.ndarray | None, folds: int,
                    n_draws: int = SPREAD_DRAWS, *, seed: int) -> np.ndarray:
    """Relative sd (6,) of the held-out RMS per component under the noise model: ``n_draws`` seeded
    draws of the pose noise (``C`` (P, 6, 6)) and the hanging errors (``J_h`` (P, 6, h), ``C_h``),
    the K-norm refit on the training folds (``Jr`` (P, 6, r); None: no refit), RMS of the rest."""
    P = len(C)
    rng = np.random.default_rng(SPREAD_SEED)
    e = np.einsum("pij,dpj->dpi", np.linalg.cholesky(C), rng.standard_normal((n_draws, P, 6)))
    if J_h is not None and C_h is not None and J_h.shape[2]:
        e = e + np.einsum("pih,dh->dpi", J_h, rng.standard_normal((n_draws, len(C_h))) * np.sqrt(C_h))
    held = e
    if Jr is not None and P >= 2 * max(folds, 2):
        held = e.copy()
        JK = Jr * K_DIAG[None, :, None]
        for test in fold_indices(P, max(folds, 2), seed):
            train = np.ones(P, bool)
            train[test] = False
            A = np.einsum("pir,pis->rs", JK[train], Jr[train])
            b = np.einsum("pir,dpi->dr", JK[train], e[:, train])
            dth = b @ np.linalg.pinv(A).T
            held[:, test] = e[:, test] - np.einsum("pir,dr->dpi", Jr[test], dth)
    rms = np.sqrt(np.mean(held**2, axis=1))
    return rms.std(axis=0) / np.maximum(rms.mean(axis=0), 1e-300)


def _chibar_sf(x: float, n: int) -> float:
    """Survival function of the chi-bar^2 mixture ``sum_k C(n, k) / 2^n chi^2_k`` (n one-sided tests)."""
    if x <= 0:
        return 1.0
    return float(sum(comb(n, k) / 2.0**n * chi2.sf(x, k) for k in range(1, n + 1)))


def _structure_cv(reml: _Reml, s2: float, Xt_red: np.ndarray, folds: int, seed: int) -> float:
    """Held-out whitened sum of squares with the structure columns over without (k-fold over poses,
    after the calibration and intercept columns are projected out): below 1 when the structure
    predicts poses it was not fitted to."""
    P = reml.P
    w = 1.0 / np.sqrt(reml._lam(s2))
    y, Xr, Xf = reml.y * w, Xt_red * w[:, None], reml.Xt * w[:, None]
    U = _span(Xr)
    Sx = Xf - U @ (U.T @ Xf)
    Sx = _span(Sx)                                   # the structure directions beyond the reduced design
    if Sx.shape[1] == 0 or P < 2 * max(folds, 2):
        return 1.0
    y = y - U @ (U.T @ y)
    ss0 = ss1 = 0.0
    for test in fold_indices(P, max(folds, 2), seed):
        rows = (test[:, None] * 6 + np.arange(6)).ravel()
        train = np.ones(6 * P, bool)
        train[rows] = False
        b = np.linalg.lstsq(Sx[train], y[train], rcond=None)[0]
        ss1 += float(((y[rows] - Sx[rows] @ b) ** 2).sum())
        ss0 += float((y[rows] ** 2).sum())
    return ss1 / ss0 if ss0 > 0 else 1.0


def _check(reml: _Reml, s2: float, X_red: np.ndarray, folds: int, seed: int) -> dict:
    """Structure and variance tests of the fitted noise model (module docstring)."""
    P = reml.P
    _, _, _, pr_full, beta, Ai = reml.solve(s2)
    Xt_red = np.einsum("pij,pjm->pim", reml.Q, X_red.reshape(P, 6, -1)).reshape(6 * P, -1)
    _, _, _, pr_red, _, _ = reml.solve(s2, Xt_red)
    chi_s = max(pr_full - pr_red, 0.0)
    dof_s = reml.Xt.shape[1] - Xt_red.shape[1]
    p_s = float(chi2.sf(chi_s, dof_s)) if dof_s > 0 else 1.0
    cv = _structure_cv(reml, s2, Xt_red, folds, seed)
    # GLS residual in W axes and its expected covariance's diagonal, V - X A^-1 X'
    e = reml.r - (reml.X @ beta).reshape(P, 6)
    Cdiag = np.einsum("pii->pi", reml.S) + s2 * np.einsum("pia,pia->pi", reml.G, reml.G)
    hdiag = np.einsum("nm,mk,nk->n", reml.X, Ai, reml.X).reshape(P, 6)
    expct = np.maximum(Cdiag - hdiag, 1e-300)
    ratio = (e**2).sum(axis=0) / expct.sum(axis=0)
    lr_c = np.where(ratio > 1.0, P * (ratio - 1.0 - np.log(ratio)), 0.0)
    lr = float(lr_c.sum())
    return {"structure_chi2": float(chi_s), "structure_dof": int(dof_s), "structure_p": p_s, "structure_cv_ratio": cv,
            "variance_lr": lr, "variance_p": _chibar_sf(lr, 6), "excess_ratio": ratio}


def _statement(gap: bool, identified: bool, s: float, s_se: float, s_up: float, read_sd: np.ndarray, check: dict) -> str:
    f_sd = float(np.sqrt(np.mean(read_sd[:3] ** 2)))
    t_sd = float(np.sqrt(np.mean(read_sd[3:] ** 2)))
    reads = f"readings ~{f_sd:.2g} N / {t_sd:.2g} N*m per pose"
    if identified:
        moc = f"motion capture ~{np.degrees(s):.2g} deg per pose (+- {np.degrees(s_se):.1g})"
    elif np.isfinite(s_up):
        moc = f"motion capture below {np.degrees(s_up):.2g} deg per pose (not distinguishable from 0)"
    else:
        moc = "no motion-capture term"
    if not gap:
        return f"per-pose scatter is measurement noise: {moc}, {reads}."
    why = []
    if check["structure_p"] < CHECK_ALPHA and check["structure_cv_ratio"] < 1.0:
        why.append(f"it follows time, the legs' loads or shaft angles (chi2 {check['structure_chi2']:.0f} on {check['structure_dof']} dof; "
                   f"held-out share left {check['structure_cv_ratio']:.2f})")
    if check["variance_p"] < CHECK_ALPHA:
        ex = np.asarray(check["excess_ratio"])
        comps = [f"{WRENCH_COMPONENTS[c]} x{ex[c]:.1f}" for c in range(6) if ex[c] > 1.25]
        why.append("its variance exceeds the noise model's" + (f" ({', '.join(comps)})" if comps else "")
                   + f", LR {check['variance_lr']:.0f}")
    return f"the per-pose residual has more than measurement noise ({moc}, {reads}): " + "; ".join(why) + "."
