"""Standing-stage results: uncertainty at the optimum, identifiability, the result object.

Uncertainty (Gauss-Newton at the optimum of eq. 8). With per-pose residual
Jacobians ``J_p = d r_p / d x`` (6 x n) and the model's equations ``g_eq(x) = 0``,
the admissible perturbations are ``dx = T t``, ``T`` an orthonormal basis of the
null space of ``d g_eq / dx`` (for a 9-entry rotation: the tangent space of
SO(3), 3 directions). In tangent coordinates

    A = sum_p (J_p T)^T K (J_p T),     sigma^2 = RSS / (6P - d),     Cov_t = sigma^2 A^-1

(``covariance="sandwich"``: ``A^-1 (sum_p g_p g_p^T) A^-1``, ``g_p = (J_p T)^T K r_p``,
robust to unequal force/torque noise). For the feasible GLS fit (``problem.py``)
K is replaced by ``W = C^-1`` and ``Cov_t = A^-1`` (no sigma^2: W is already the
inverse residual covariance). Standard errors of what the model
determines follow by the chain rule: rotations as rotation vectors ``delta_k``
of ``R_k = exp([delta_k]) R_k*`` (B axes, rad), translations ``p'_k`` (m),
offsets, ``com_body``.

Identifiability. ``A`` is scaled to unit diagonal (parameters of different
units compare) and its eigenvalues are taken relative to the largest; directions
with ratio below ``rel_eig_tol`` (default 1e-8: a standard error 10^4 times the
best-determined direction's, i.e. numerically singular) are not determined by
the poses. They are named (the quantities they move, with weights), left out of
the covariance (pseudo-inverse on the determined subspace), and every quantity
they move gets se = inf. "Move" is judged in physical units (a direction's
change of each quantity divided by 1 deg, 1 mm, 0.1 N or 0.01 N*m): quantities
changing by at least 5 % of the direction's largest normalised change are
flagged, so tiny couplings between units do not spread the flag. Typical cases: all p'_k along the vertical when every
pose has the same tilt (sum of forces ~ M_b g z); 6K - 6 offset combinations in
the offsets-only model.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import pandas as pd
from scipy.linalg import null_space

from ...core.calibration import Calibration
from ...core.geometry import rotation_to_rotvec, unskew
from ...core.results import ResultsMixin, Summary, bic, fmt_pm
from ...core.solver import identifiability
from .problem import K_DIAG, knorm2

FLAG_FRACTION = 0.05
# Physical scales used to compare how much an undetermined direction moves quantities of different units.
_UNIT = {"rot": np.radians(1.0), "p_prime": 1e-3, "com_body": 1e-3, "w_o_f": 0.1, "w_o_t": 0.01}


def _unit_scale(label: str) -> float:
    head = label.split("[")[0].split(".")[0]
    if head == "w_o":
        return _UNIT["w_o_f"] if label.endswith(("fx", "fy", "fz")) else _UNIT["w_o_t"]
    return _UNIT.get(head, 1.0)
_WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass(frozen=True)
class Physical:
    """The transforms a model's x gives: rotations (K,3,3), p' (K,3), offsets (K,6) | None, com (3,) | None,
    and the Jacobian ``D`` of the stacked quantities (``labels``) w.r.t. x (rotations as rotation vectors)."""

    R: np.ndarray
    p_prime: np.ndarray
    offsets: np.ndarray | None
    com_body: np.ndarray | None
    D: np.ndarray
    labels: tuple[str, ...]


def physical(spec, x: np.ndarray, legs) -> Physical:
    """Evaluate the model's maps at ``x`` and their Jacobian (rotations on the tangent space)."""
    K = len(legs)
    parts = [ca.reshape(R.T, 9, 1) for R in spec.R] + [ca.reshape(p, 3, 1) for p in spec.p_prime]
    if spec.offsets is not None:
        parts += [ca.reshape(o, 6, 1) for o in spec.offsets]
    if spec.com_body is not None:
        parts.append(ca.reshape(spec.com_body, 3, 1))
    v = ca.vertcat(*parts)
    f = ca.Function("phys", [spec.x], [v, ca.jacobian(v, spec.x)])
    val, jac = (np.array(a) for a in f(x))
    val, n = val.ravel(), spec.x.numel()
    jac = jac.reshape(-1, n)
    R = val[: 9 * K].reshape(K, 3, 3)
    dR = jac[: 9 * K].reshape(K, 3, 3, n)
    # delta_k = unskew(dR_k R_k^T): left perturbation in B axes.
    drot = unskew(np.moveaxis(np.einsum("kijn,klj->kiln", dR, R), -1, 1)).transpose(0, 2, 1).reshape(3 * K, n)
    i = 9 * K
    p = val[i : i + 3 * K].reshape(K, 3)
    D = [drot, jac[i : i + 3 * K]]
    labels = [f"rot[{k}].{c}" for k in legs for c in "xyz"] + [f"p_prime[{k}].{c}" for k in legs for c in "xyz"]
    i += 3 * K
    off = None
    if spec.offsets is not None:
        off = val[i : i + 6 * K].reshape(K, 6)
        D.append(jac[i : i + 6 * K])
        labels += [f"w_o[{k}].{c}" for k in legs for c in _WRENCH]
        i += 6 * K
    com = None
    if spec.com_body is not None:
        com = val[i : i + 3]
        D.append(jac[i : i + 3])
        labels += [f"com_body.{c}" for c in "xyz"]
    return Physical(R, p, off, com, np.concatenate(D, axis=0), tuple(labels))


@dataclass(frozen=True)
class Uncertainty:
    se: np.ndarray                 # (n_phys,) standard errors of Physical.labels; inf where undetermined
    cov: np.ndarray                # (n_phys, n_phys) covariance (undetermined directions left out)
    sigma2: float
    eig_ratio: np.ndarray          # eigenvalues of the scaled information matrix / the largest
    unidentified: tuple[str, ...]  # one description per undetermined direction
    unidentified_params: tuple[str, ...]
    dof: int
    sensitivity: np.ndarray | None = None  # (n_phys, n_h) d(quantities)/d(prior parameters) at the optimum


def _describe(c: np.ndarray, labels, ratio: float, top: int = 12) -> tuple[str, np.ndarray]:
    """Text of a direction: its largest components (``c`` already in normalised units), and the flagged ones."""
    a = np.abs(c)
    big = a >= FLAG_FRACTION * a.max()
    idx = np.argsort(-a)[: min(top, int(big.sum()))]
    cn = c / np.linalg.norm(c[big])
    terms = " ".join(f"{cn[i]:+.2f} {labels[i]}" for i in idx)
    more = f" (+{int(big.sum()) - len(idx)} more)" if big.sum() > len(idx) else ""
    return f"{terms}{more} [eigenvalue ratio {max(ratio, 0.0):.1e}]", big


def uncertainty(cp, x: np.ndarray, xi: np.ndarray, phys: Physical, *, rel_eig_tol: float,
                covariance: str, W: np.ndarray | None = None, J_h: np.ndarray | None = None) -> Uncertainty:
    """Standard errors and undetermined directions at the optimum ``x`` (module docstring).

    ``W`` (6x6): the fit was weighted by W = (residual covariance)^-1 (feasible GLS) instead of K:
    ``A = sum_p (J_p T)^T W (J_p T)`` and the Gauss-Newton covariance is ``A^-1`` with no sigma^2
    factor (W already holds the noise scale); ``sigma2`` stays the K-norm one (reporting)."""
    if covariance not in ("gauss_newton", "sandwich"):
        raise ValueError(f"covariance: expected 'gauss_newton' or 'sandwich', got {covariance!r}")
    spec = cp.spec
    n = spec.x.numel()
    P = len(xi)
    J = np.einsum("pj,ijn->pin", xi, cp.dL(x))  # (P, 6, n)
    r = xi @ cp.L(x).T
    eq = np.asarray(spec.lbg) == np.asarray(spec.ubg)
    if eq.any():
        G = np.array(ca.Function("G", [spec.x], [ca.jacobian(spec.g, spec.x)])(x)).reshape(-1, n)[eq]
        T = null_space(G)
    else:
        T = np.eye(n)
    d = T.shape[1]
    Jt = J @ T
    Wm = np.diag(K_DIAG) if W is None else np.asarray(W, float)
    A = np.einsum("pin,ij,pjm->nm", Jt, Wm, Jt)
    rss = float(knorm2(r).sum())
    sigma2 = rss / max(6 * P - d, 1)
    ident = identifiability(A, rel_eig_tol)
    s, lam, V, ratio, ok = ident.scale, ident.eigenvalues, ident.vectors, ident.ratio, ident.determined
    Ainv = (V[:, ok] / lam[ok]) @ V[:, ok].T
    if covariance == "gauss_newton":
        Cs = (sigma2 if W is None else 1.0) * Ainv
    else:
        g = np.einsum("pin,ij,pj->pn", Jt, Wm, r) / s
        Cs = Ainv @ (g.T @ g) @ Ainv * P / max(P - d, 1)
    Cx = T @ (Cs / np.outer(s, s)) @ T.T
    D = phys.D
    cov = D @ Cx @ D.T
    sens = None
    if J_h is not None:  # implicit-function theorem at the (Gauss-Newton) optimum: dt/dh = -A^+ sum_p Jt^T W J_h
        B = np.einsum("pin,ij,pjm->nm", Jt, Wm, J_h)
        sens = D @ T @ (-ident.pinv() @ B)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    descs, flagged = [], np.zeros(len(se), bool)
    units = np.array([_unit_scale(l) for l in phys.labels])
    for j in np.flatnonzero(~ok):
        nx = T @ (V[:, j] / s)
        c = (D @ nx) / units
        if np.abs(c).max() <= 1e-9 * np.abs(nx).max():
            # A redundancy of the parametrisation: the transforms do not move.
            desc, _ = _describe(nx, spec.names or [f"x[{i}]" for i in range(n)], ratio[j])
            descs.append("redundant parameters: " + desc)
            continue
        desc, big = _describe(c, phys.labels, ratio[j])
        descs.append(desc)
        flagged |= big
    se = np.where(flagged, np.inf, se)
    # quantities the model does not estimate (fixed at nominal or prior values) have no se
    se = np.where(np.all(D == 0, axis=1), np.nan, se)
    params = tuple(l for l, f in zip(phys.labels, flagged) if f)
    return Uncertainty(se, cov, sigma2, ratio, tuple(descs), params, d, sens)


_PARAM_NAMES = {"rot": "R_tilde"}


def param_label(phys_label: str) -> str:
    """``rot[FL].x`` -> ``FL.R_tilde.x`` (rad), ``p_prime[FL].x`` -> ``FL.p_prime.x`` (m),
    ``w_o[FL].fx`` -> ``FL.w_o.fx``; ``com_body.x`` stays."""
    if "[" not in phys_label:
        return phys_label
    head, rest = phys_label.split("[", 1)
    leg, comp = rest.split("].", 1)
    return f"{leg}.{_PARAM_NAMES.get(head, head)}.{comp}"


@dataclass(frozen=True)
class StandingResult(ResultsMixin):
    """Result of the standing stage (report Sec. III-B) for one model, balance and solver.

    ``rotations`` (K, 3, 3) estimated ``R_k`` (ft_k -> B) = ``R_tilde_k R_nominal_k``;
    ``rotvec_se`` (K, 3) rad, se of ``delta_k`` in ``R_k = exp([delta_k]) R_k*`` (B axes);
    ``p_prime`` (K, 3) m: ft_k origin relative to the body-without-legs CoM, B axes
    (for ``balance="report"``: relative to the fixed point C of eq. 9, converted in
    ``calibration``); ``p_prime_se`` (K, 3); ``com_body_m`` (3,) in B or None;
    se are inf where the poses do not determine a quantity and NaN where the model
    does not estimate it (nominal or prior value kept);
    ``residuals`` (P, 6) eq. (E) or (9) residual per pose in W axes (N, N*m);
    ``rss`` the K-norm residual sum of squares; ``dof`` the model's degrees of freedom;
    ``unidentified`` descriptions of directions the poses do not determine;
    ``weighting`` the fit's weight (the se follow it; ``rss`` is the K-norm either way).
    """

    calibration: Calibration
    rotations: np.ndarray
    rotvec_se: np.ndarray
    p_prime: np.ndarray
    p_prime_se: np.ndarray
    com_body_m: np.ndarray | None
    residuals: np.ndarray
    rss: float
    dof: int
    n_poses: int
    unidentified: tuple[str, ...]
    solver_status: str
    solve_time_s: float
    model: str                           # what the fit used (StandingSettings or the caller), recorded
    balance: str
    solver: str
    legs: tuple[str, ...]
    R_nominal: np.ndarray
    com_body_se_m: np.ndarray | None = None
    offsets: np.ndarray | None = None
    offsets_se: np.ndarray | None = None
    unidentified_params: tuple[str, ...] = ()
    sigma2: float = float("nan")
    eig_ratio: np.ndarray | None = None
    x: np.ndarray | None = field(default=None, repr=False)
    iterations: int = -1
    total_time_s: float = float("nan")   # compile + solve + uncertainty
    weighting: str = field(kw_only=True)  # "knorm" (eq. 8's K) or "fgls" (W = residual covariance^-1)
    weight: np.ndarray | None = field(default=None, repr=False)  # the fgls W (6x6, B axes)
    param_labels: tuple[str, ...] = ()                           # physical labels of ``cov`` (``Physical.labels``)
    cov: np.ndarray | None = field(default=None, repr=False)      # covariance of those, conditional on the prior
    se: np.ndarray | None = field(default=None, repr=False)       # their se (inf: undetermined, NaN: not estimated)
    sensitivity: pd.DataFrame | None = field(default=None, repr=False)  # d params / d prior (hanging) parameters

    # results protocol (results.py); rotations as R_tilde rotation vectors (rad), translations m
    @property
    def params(self) -> pd.Series:
        vals = [self.rotation_errors.ravel(), self.p_prime.ravel()]
        if self.offsets is not None:
            vals.append(np.asarray(self.offsets).ravel())
        if any(l.startswith("com_body") for l in self.param_labels):
            vals.append(np.asarray(self.com_body_m if self.com_body_m is not None else np.full(3, np.nan), float))
        v = np.concatenate(vals)
        names = [param_label(l) for l in self.param_labels] if self.param_labels else [
            f"{k}.{q}.{c}" for q in ("R_tilde", "p_prime") for k in self.legs for c in "xyz"][: len(v)]
        if len(names) != len(v):
            raise ValueError(f"standing result: {len(names)} parameter labels for {len(v)} values")
        return pd.Series(v, index=names, name="params")

    def _bse_array(self) -> np.ndarray:
        if self.se is not None:
            return np.asarray(self.se, float)
        return np.concatenate([self.rotvec_se.ravel(), self.p_prime_se.ravel()])

    def _cov_array(self) -> np.ndarray:
        if self.cov is not None:
            return self.cov
        b = self._bse_array()
        return np.diag(np.where(np.isfinite(b), b, 0.0) ** 2)

    @property
    def rotation_errors(self) -> np.ndarray:
        """``R_tilde_k = R_k R_nominal_k^T`` as rotation vectors (K, 3), rad."""
        return rotation_to_rotvec(self.rotations @ np.swapaxes(self.R_nominal, 1, 2))

    @property
    def bic(self) -> float:
        """``P ln(RSS/P) + DOF ln P`` (Sec. IV-2)."""
        return bic(self.rss, self.n_poses, self.dof)

    def table(self) -> pd.DataFrame:
        """Table II-like: per leg, ``R_tilde`` (deg) and ``p'`` (mm) (and offsets if fitted), ``value ± se``."""
        rows: dict[str, list[str]] = {}
        rv, rse = self.rotation_errors, self.rotvec_se
        for j, c in enumerate("xyz"):
            rows[f"R_tilde {c} [deg]"] = [fmt_pm(rv[k, j], rse[k, j], scale=180 / np.pi) for k in range(len(self.legs))]
        for j, c in enumerate("xyz"):
            rows[f"p' {c} [mm]"] = [fmt_pm(self.p_prime[k, j], self.p_prime_se[k, j], scale=1e3) for k in range(len(self.legs))]
        if self.offsets is not None and self.offsets_se is not None:   # (fitted together)
            for j, c in enumerate(_WRENCH):
                unit = "N" if j < 3 else "N*m"
                rows[f"w_o {c} [{unit}]"] = [fmt_pm(self.offsets[k, j], self.offsets_se[k, j]) for k in range(len(self.legs))]
        df = pd.DataFrame(rows, index=list(self.legs)).T
        df.index.name = "parameter"
        return df

    def summary(self) -> Summary:
        """Model, fit statistics, the parameter table, CoM and undetermined directions."""
        rms = np.sqrt((self.residuals**2).mean(axis=0))
        facts = [
            ("model", f"{self.model} ({self.balance} balance, {self.weighting} weighting)"),
            ("solver", f"{self.solver}: {self.solver_status}, {self.solve_time_s * 1e3:.0f} ms"),
            ("poses / DOF", f"{self.n_poses} / {self.dof}"),
            ("RSS (K-norm), BIC", f"{self.rss:.5g}, {self.bic:.2f}"),
            ("residual RMS f [N]", " ".join(f"{v:.3g}" for v in rms[:3])),
            ("residual RMS tau [N*m]", " ".join(f"{v:.3g}" for v in rms[3:])),
        ]
        if self.com_body_m is not None:
            se = self.com_body_se_m if self.com_body_se_m is not None else np.full(3, np.nan)  # NaN: kept from the prior
            facts.append(("CoM of body without legs in B [mm]", ", ".join(fmt_pm(v, s_, scale=1e3) for v, s_ in zip(self.com_body_m, se))))
        else:
            facts.append(("CoM of body without legs", "not identifiable with this model (every transducer translation free)"))
        out = Summary(f"Standing calibration: model {self.model}", facts)
        out.tables.append(("Mounting errors R_tilde (rotation vector of R_k R_nominal_k^T) and p' (ft_k origin from the body CoM), "
                           "value ± standard error", self.table()))
        if self.unidentified:
            out.notes.append(f"{len(self.unidentified)} direction(s) not determined by the poses (se = inf):")
            out.notes += list(self.unidentified)
        return out
