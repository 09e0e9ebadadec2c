"""The calibration model with one effect added, fitted to standing poses (CasADi + IPOPT).

For pose p the residual (B axes, about the reference point) is eq. (A) of
``effects/faces.py`` on top of the calibration's balance:

    exact (physics.py (E)):  r_p = sum_k Ad_k (c_k - w_o,k) - M_b g [z~; 0] + e_p
    report (eq. 9):          r_p = sum_k Ad_k (c_k - w_o,k) + sum_k m_k g [z~; (R_k r_k(phi) + p'_k) x z~]
                                   - M g [z~; 0] + e_p

with ``Ad_k w = [R_k f; R_k tau + p'_k x R_k f]`` (``geometry.transform_wrench``),
``R_k``, ``p'_k`` (and ``w_o,k`` for models that fit offsets) the expressions of
the selected error model's :class:`~ftcal_nlp.models.ModelSpec` (the plug-in is
reused as it is: the augmented problem is ``[spec.x; eta]`` with the spec's
constraints), and ``c_k``, ``z~ = Z(eta) z``, ``e_p`` the effect's corrections
(eta = 0: none). Effects that act while hanging (``Effect.shifts_offsets``) also
shifted the hanging offsets: ``- dw_o`` (6 parameters, B axes) is added for them.

Every face is linear in the pose's features ``phi_p`` (readings, up vector,
orientation, time, previous readings, cos/sin phi, squares and products of
readings, leg CoM x up; ``effects/faces.py:PoseSym``), so

    r_p = M(theta) [1; phi_p],   M = [r(theta, 0), d r / d phi]

is read off the symbolic residual by one Jacobian (and checked not to depend on
``phi``), and eq. 8 with per-pose weights ``omega_p`` becomes, as in
``standing/problem.py``,

    sum_p omega_p ||r_p||_K^2 = sum_i K_ii (M S M^T)_ii,   S = sum_p omega_p phi~_p phi~_p^T.

One compiled IPOPT solver (S a parameter, only the features the face uses)
serves the full fit (omega = 1/P) and every cross-validation fold (omega = 0
on the held-out poses), so no candidate is scored on poses it was fitted to.

A prior on ``eta`` (``EtaPrior``): parameters the joint hanging fit also estimated (the same sensor matrix read
on the leg's weight; ``Effect.standing_prior_from_hanging``) enter with that fit's information, so the two kinds
are one fit of one parameter (Gaussian, linearised at the hanging optimum):

    sum_p omega_p ||r_p||_K^2 + omega~ (eta_J - mu)^T I_K (eta_J - mu),   I_K = sigma_K^2 I_h

``I_h`` the hanging information of ``eta_J`` (its undetermined directions zero), ``sigma_K^2`` the standing noise per
K-weighted component (``mean_i K_ii s_i^2``) and ``omega~`` the mean weight of the poses fitted: the posterior of
both kinds scaled as eq. 8. What neither kind determines stays undetermined (se inf).

Effective degrees of freedom: the rank of the residual Jacobian on the tangent
space of the constraints (columns scaled to unit norm, eigenvalues of the
information matrix above ``REL_EIG_TOL`` of the largest, as in
``standing/result.py``). An augmentation that the model already absorbs (a
mocap bias under free rotations and translations) adds no rank.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np
import pandas as pd
from scipy.linalg import null_space

from ..core.calibration import Calibration
from ..core.balance import residual
from ..models import ModelContext, resolve
from ..core.robot import Robot
from ..core.balance import K_DIAG, check_balance, to_world
from ..core.results import ResultsMixin, Summary, fmt_pm
from ..core.solver import REL_EIG_TOL, identifiability, ipopt, solve_checked
from ..effects.faces import AugContext, ParamBlock, StandingData, pose_symbols  # noqa: F401  (StandingData: importable from here)
from ..effects.unit import Effect



def balance_residual_sx(R, p, w_o, c, z, zmap, rz, leg_weight_N, Mg: float, balance: str):
    """Eq. (E) or eq. 9 for one pose as SX (6,), B axes, from corrected readings ``c`` and the
    corrected up vector ``z~ = zmap z`` (``zmap`` None: identity): ``balance.residual`` on the
    features ``[c_1 .. c_K, 1, z~, r_k (x) z~]`` (the report's products ``rz[k][a, l] = r_a z_l``
    become ``rz[k] zmap^T`` and stay linear)."""
    Z = ca.SX.eye(3) if zmap is None else zmap
    parts = [*c, ca.SX.ones(1, 1), ca.mtimes(Z, z)]
    if balance == "report":
        parts += [ca.reshape(ca.mtimes(rz_k, Z.T).T, 9, 1) for rz_k in rz]  # row-major a*3 + l, as balance.features
    return residual(ca.vertcat(*parts), R, p, w_o, leg_weight_N, Mg, balance)


@dataclass(frozen=True)
class EtaPrior:
    """What another kind's fit says of some of ``eta`` (module docstring): ``index`` (q,) into ``eta``, ``mu`` (q,)
    its estimate there, ``info`` (q, q) its information scaled to the standing objective (``I_K``)."""

    index: np.ndarray
    mu: np.ndarray
    info: np.ndarray

    @cached_property
    def root(self) -> np.ndarray:
        """``U`` (q, r) with ``U U^T = info`` (its positive eigen-directions): the prior's residual rows ``U^T (eta - mu)``."""
        lam, V = np.linalg.eigh((self.info + self.info.T) / 2)
        keep = lam > REL_EIG_TOL * max(float(lam.max()), 1e-300)
        return V[:, keep] * np.sqrt(lam[keep])


class AugmentedProblem:
    """The selected error model plus ``effect`` (None: the model alone) on standing features."""

    def __init__(self, model, prior: Calibration, robot: Robot, balance: str, effect: Effect | None = None, *,
                 ridge: float = 1e-10, eta_prior: EtaPrior | None = None):
        check_balance(balance)
        self.model = resolve(model)
        self.effect = effect
        self.base_balance = balance
        self.balance = effect.standing_balance(balance) if effect is not None else balance
        legs = tuple(robot.legs)
        K = len(legs)
        mctx = ModelContext(legs, robot.nominal_rotations(), robot.nominal_positions(), prior)
        spec = self.model.build(mctx)
        spec.validate(K, f"error model {self.model.name!r}")
        self.spec = spec
        offsets = list(spec.offsets) if spec.offsets is not None else [ca.DM(prior.legs[k].offset) for k in legs]
        m = np.array([prior.legs[k].leg_weight_N for k in legs])
        actx = AugContext(legs, offsets, robot.nominal_rotations(), m, prior.g)
        self.actx = actx   # the effect's context (``Combined.split``: each member's slice of eta)
        block = effect.standing_params(actx) if effect is not None else None
        shift = effect is not None and effect.shifts_offsets
        if shift:  # the offset shift: a constant wrench in B (``Effect.shifts_offsets``, effects/unit.py)
            names = tuple(block.names if block is not None else ()) + tuple(f"dw_o.{c} [B]" for c in ("fx", "fy", "fz", "tx", "ty", "tz"))
            lb = np.r_[block.lb if block is not None else [], np.full(6, -20.0)]
            block = ParamBlock(names, np.zeros(len(names)), lb, -lb)
        self.params = block
        m_eta = block.m if block is not None else 0
        eta = ca.SX.sym("eta", m_eta)
        d, pose = pose_symbols(K)
        m_face = m_eta - 6 if shift else m_eta
        c, zmap, extra = effect.standing(eta[:m_face], pose, actx) if effect is not None else (pose.w, None, None)
        r = balance_residual_sx(list(spec.R), list(spec.p_prime), offsets, c, pose.z, zmap, pose.rz, m,
                                prior.mass_kg * prior.g, self.balance)
        if extra is not None:
            r = r + extra
        if shift:
            r = r - eta[m_face:]
        x_all = ca.vertcat(spec.x, eta)
        self.n_model = int(spec.x.numel())
        self.n = int(x_all.numel())
        M = ca.jacobian(r, d)
        if ca.depends_on(M, d):
            raise ValueError(f"effect {self.name!r}: its standing face is not linear in the pose features (see PoseSym)")
        M0 = ca.substitute(r, d, ca.DM.zeros(d.numel()))
        Mfull = ca.horzcat(M0, M)
        # Only the features the residual uses (and the constant) enter the moments.
        used = sorted(set(np.asarray(ca.DM(ca.sparsify(Mfull).sparsity(), 1)).nonzero()[1].tolist()) | {0})
        self.used = np.array(used)
        Mu = Mfull[:, used]
        self.M_fn = ca.Function("M", [x_all], [Mu])
        self.dM_fn = ca.Function("dM", [x_all], [ca.jacobian(ca.reshape(Mu, -1, 1), x_all)])
        nu = len(used)
        X = ca.MX.sym("x", self.n)
        S = ca.MX.sym("S", nu, nu)
        x_ref = ca.MX.sym("x_ref", self.n)
        Mx = self.M_fn(X)
        f = ca.sum1(ca.sum2(ca.mtimes(ca.DM(np.diag(K_DIAG)), ca.mtimes(Mx, S)) * Mx))
        # Minimal change: along directions the poses do not determine (an offset shift against a
        # common tilt of the frames, a cable's torque against the CoM) stay nearest the reference.
        f = f + ridge * ca.sumsqr(X - x_ref)
        self.eta_prior = eta_prior
        w_prior = ca.MX.sym("w_prior")
        if eta_prior is not None:
            U = eta_prior.root
            d_eta = X[[self.n_model + int(i) for i in eta_prior.index]] - ca.DM(eta_prior.mu)
            f = f + w_prior * ca.sumsqr(ca.mtimes(ca.DM(U.T), d_eta))
        g = ca.Function("g", [spec.x], [spec.g])(X[: self.n_model])
        self._nlp = {"x": X, "p": ca.vertcat(ca.reshape(S, -1, 1), x_ref, w_prior), "f": f, "g": g}
        self.x0 = np.concatenate([np.asarray(spec.x0, float), block.x0 if block is not None else np.zeros(0)])
        self.lbx = np.concatenate([spec.lbx, block.lb if block is not None else np.zeros(0)])
        self.ubx = np.concatenate([spec.ubx, block.ub if block is not None else np.zeros(0)])
        self.lbg, self.ubg = np.asarray(spec.lbg, float), np.asarray(spec.ubg, float)
        self._solver = None
        self._G = ca.Function("G", [spec.x], [ca.jacobian(spec.g, spec.x)]) if spec.g.numel() else None

    @property
    def name(self) -> str:
        return self.effect.name if self.effect is not None else "base"

    @property
    def n_eta(self) -> int:
        return self.n - self.n_model

    def design(self, data: StandingData) -> np.ndarray:
        """``[1; phi_p]`` restricted to the used features, (P, n_used)."""
        phi = np.concatenate([np.ones((data.P, 1)), data.features()], axis=1)
        return phi[:, self.used]

    @property
    def solver(self):
        if self._solver is None:
            # (several effects, ``effects/combined.py``: "a+b" is no CasADi function name)
            self._solver = ipopt(f"diag_{self.name.replace('+', '_and_')}_{self.balance}", self._nlp)
        return self._solver

    def fit(self, Phi: np.ndarray, weights: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """Minimise ``sum_p weights_p ||r_p||_K^2 + ridge ||x - x0||^2`` (and the prior's term, module docstring)
        over the design rows ``Phi`` (P, n_used) from ``x0`` (the reference of the minimal-change ridge).

        Raises :class:`~ftcal_nlp.core.solver.SolverError` when IPOPT does not report success.
        """
        x0 = self.x0 if x0 is None else x0
        S = (Phi * weights[:, None]).T @ Phi
        w_prior = float(np.mean(weights[weights > 0])) if np.any(weights > 0) else 0.0   # EtaPrior: omega~
        p = np.concatenate([S.ravel(order="F"), x0, [w_prior]])
        sol, _ = solve_checked(self.solver, f"the standing problem with {self.name!r} ({self.balance} balance)",
                               x0=x0, p=p, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        return np.asarray(sol["x"]).ravel()

    def residuals(self, x: np.ndarray, Phi: np.ndarray) -> np.ndarray:
        """Residuals (P, 6) in B axes at ``x``."""
        return Phi @ np.asarray(self.M_fn(x)).T

    def _tangent_jacobian(self, x: np.ndarray, Phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """K-weighted residual Jacobian (6P, d) on the constraints' tangent space, and the basis T (n, d)."""
        nu = len(self.used)
        dM = np.asarray(self.dM_fn(x)).reshape(nu, 6, self.n)  # vec(M) is column-major: index i + 6 j
        J = np.einsum("pj,jin->pin", Phi, dM) * np.sqrt(K_DIAG)[None, :, None]
        J = J.reshape(-1, self.n)
        if self.eta_prior is not None:   # the prior's rows U^T (eta_J - mu): its information joins the poses'
            U = self.eta_prior.root
            Jp = np.zeros((U.shape[1], self.n))
            Jp[:, self.n_model + np.asarray(self.eta_prior.index, int)] = U.T
            J = np.vstack([J, Jp])
        eq = self.lbg == self.ubg
        if self._G is not None and eq.any():
            G = np.asarray(self._G(x[: self.n_model])).reshape(-1, self.n_model)[eq]
            Tm = null_space(G)
            T = np.zeros((self.n, Tm.shape[1] + self.n_eta))
            T[: self.n_model, : Tm.shape[1]] = Tm
            T[self.n_model :, Tm.shape[1] :] = np.eye(self.n_eta)
        else:
            T = np.eye(self.n)
        return J @ T, T

    def effective_dof(self, x: np.ndarray, Phi: np.ndarray) -> int:
        """Rank of the K-weighted residual Jacobian on the constraints' tangent space (module docstring)."""
        Jt, _ = self._tangent_jacobian(x, Phi)
        return identifiability(Jt.T @ Jt, REL_EIG_TOL).rank

    def result(self, x: np.ndarray, Phi: np.ndarray) -> AugmentedFit:
        """The fit at ``x`` on the design rows ``Phi`` as a results object (Gauss-Newton covariance,
        ``sigma^2 = RSS_K / (6P - rank)``; parameters moved by an undetermined direction get se inf)."""
        Jt, T = self._tangent_jacobian(x, Phi)
        ident = identifiability(Jt.T @ Jt, REL_EIG_TOL)
        r = self.residuals(x, Phi)
        rss = float(((r**2) @ K_DIAG).sum())
        n_rows = r.size
        if self.eta_prior is not None:
            U = self.eta_prior.root
            rss += float(np.sum((U.T @ (self.eta(x)[np.asarray(self.eta_prior.index, int)] - self.eta_prior.mu)) ** 2))
            n_rows += U.shape[1]
        sigma2 = rss / max(n_rows - ident.rank, 1)
        cov = sigma2 * T @ ident.pinv() @ T.T
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        for v, _ in ident.undetermined_directions():
            d = np.abs(T @ v)
            se[d >= 0.05 * d.max()] = np.inf
        names = tuple(self.spec.names or [f"x[{i}]" for i in range(self.n_model)])
        names += tuple(self.params.names if self.params is not None else ())
        return AugmentedFit(self.name, self.balance, names, x.copy(), se, cov, rss, len(r), ident.rank, self.n_model)

    def eta(self, x: np.ndarray) -> np.ndarray:
        return x[self.n_model :]

    def transforms(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The fitted rotations (K, 3, 3), positions ``p'`` (K, 3) and, for models that fit them, offsets (K, 6) at ``x``."""
        xm = x[: self.n_model]
        f = lambda e: np.asarray(ca.Function("f", [self.spec.x], [e])(xm), float)
        R = np.stack([f(Rk) for Rk in self.spec.R])
        p = np.stack([f(pk).ravel() for pk in self.spec.p_prime])
        off = np.stack([f(o).ravel() for o in self.spec.offsets]) if self.spec.offsets is not None else None
        return R, p, off

    def cross_validate(self, data: StandingData, R_WB: np.ndarray, folds: list, x0: np.ndarray) -> CrossValidated:
        """The fit on every pose and, per fold, the refit without the fold's poses scored on them (K-fold)."""
        Phi = self.design(data)
        P = data.P
        x = self.fit(Phi, np.full(P, 1.0 / P), x0)
        held = np.zeros((P, 6))
        for test in folds:
            w = np.full(P, 1.0 / (P - len(test)))
            w[test] = 0.0
            held[test] = self.residuals(self.fit(Phi, w, x), Phi[test])
        return CrossValidated(x, self.effective_dof(x, Phi), to_world(held, R_WB), to_world(self.residuals(x, Phi), R_WB), Phi)


@dataclass(frozen=True)
class CrossValidated:
    """A K-fold cross-validated fit: ``x`` on every pose, its effective dof, held-out and in-sample
    residuals (P, 6, W axes) and the design ``Phi`` the fit used."""

    x: np.ndarray
    dof: int
    held: np.ndarray
    r_in: np.ndarray
    Phi: np.ndarray


@dataclass(frozen=True)
class AugmentedFit(ResultsMixin):
    """The calibration model plus one effect fitted to every standing pose (results protocol,
    ``results.py``): the model's decision vector (rotations as 9 entries, translations, ...)
    then the effect's parameters ``eta``; ``effect_params`` / ``effect_bse`` are the latter alone."""

    effect: str
    balance: str
    names: tuple[str, ...]
    x: np.ndarray
    se: np.ndarray
    cov: np.ndarray
    rss: float
    n_poses: int
    rank: int
    n_model: int

    @property
    def params(self) -> pd.Series:
        return pd.Series(self.x, index=list(self.names), name="params")

    def _bse_array(self) -> np.ndarray:
        return self.se

    def _cov_array(self) -> np.ndarray:
        return self.cov

    @property
    def effect_params(self) -> pd.Series:
        return self.params.iloc[self.n_model :]

    @property
    def effect_bse(self) -> pd.Series:
        return self.bse.iloc[self.n_model :]

    def summary(self) -> Summary:
        tab = pd.DataFrame({"value ± se": [fmt_pm(v, s) for v, s in zip(self.effect_params, self.effect_bse)]},
                           index=pd.Index(self.effect_params.index, name="effect parameter"))
        return Summary(f"Standing fit with {self.effect} ({self.balance} balance)",
                       [("poses", str(self.n_poses)), ("RSS (K-norm)", f"{self.rss:.5g}"), ("effective dof", str(self.rank))],
                       [("Effect parameters", tab)])
    def eta(self, x: np.ndarray) -> np.ndarray:
        return x[self.n_model :]
