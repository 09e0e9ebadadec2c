"""Exact-rotation NLP of the hanging fit (CasADi SX + IPOPT), one leg at a time.

Unknowns of leg k: one rotation matrix ``R_j`` per hanging recording, the leg
weight ``m_k g``, the offset ``w_o = [f_o; tau_o]`` and the CoM grid
``r_1..r_G`` (ft_k, m). The NLP minimises the joint objective of estimate.py,
the noise-weighted residual of eqs. 4-7 (model.py) over all samples of the
leg (through their exact compression, binning.py) plus the CoM smoothness
penalty and weak prior of com_qp.py:

    min  1/N [ 1/2 sum_j sum_c W_c ||Y~_j,c - (X~_j M_j(R_j, m g, w_o, r)^T)_c||^2
               + lam/2 ||D2 r||^2 + 1/(2 s_p^2) ||r||^2 ]
    s.t. f_j = m g R_j a_j        (3 equations per recording)
         R_j^T R_j = I            (6 equations per recording)
         det R_j >= 0             (with orthogonality this is det R_j = +1)
         a_j . vee(R_j - R_j^T) = 0   (gauge, 1 equation per recording)
         B_p^T (f_down + f_up) = 0    (only with a single gravity axis: each pair's
                                       common tilt, see LegProblem.pins_common_tilt)

Why these constraints:

* ``R_j`` is an exact rotation, not the report's ``I + [s_j]``: the
  first-order direction ``(I + [s]) a`` has length ``sqrt(1 + |s x a|^2)``, so
  with a ~2 deg tilt plus a few degrees of mounting error it misstates the
  weight by 0.1-0.4 % (several standard errors with 10^4 samples), and the
  report's ``s^+``/``s^-`` split of the pair is exact only to first order.
* ``det R_j = +1`` as an *equality* would be linearly dependent on the
  orthogonality constraints on O(3) (its gradient ``R`` lies in their normal
  space ``{R S : S symmetric}``), which breaks IPOPT's constraint
  qualification; as an inactive inequality it only selects the SO(3) sheet.
* Gauge: the data see ``R_j`` only through ``u_j = R_j a_j``. Rotating about
  ``a_j`` first (``R_j -> R_j Rot(a_j, alpha)``) changes nothing, so every
  recording has a flat direction. ``vee(R - R^T) = 2 sin(theta) n`` for the
  rotation axis ``n``; the equality makes ``n`` perpendicular to ``a_j``, which
  picks the smallest rotation taking ``a_j`` to ``u_j`` (the report's ``s``
  likewise has no effect along ``e_1``). Two degrees of freedom per recording
  remain, the tilt of the gravity direction.
* The weight vectors ``f_j`` are auxiliary variables: the residuals depend on
  ``R_j`` and ``m g`` only through them, so the objective's Hessian couples
  the 3G CoM unknowns with 3 numbers per recording instead of 10 (a smaller
  dense block to build and factorise); the constraints are bilinear.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from scipy import sparse

from ...core.geometry import skew, unskew
from ...core.solver import SolverError, ipopt
from .com_qp import second_difference
from .model import LegState, pseudo_residuals_sx, weighted_sumsq_sx
from .problem import LegProblem


# With a stiff smoothing weight the gradient's rounding floor is ~1e-7; IPOPT's own
# "acceptable" level then ends the solve as converged (success) instead of stalling.
_IPOPT: dict[str, Any] = {"tol": 1e-8, "acceptable_tol": 1e-6, "acceptable_iter": 3, "max_iter": 300}


def structure_key(problem: LegProblem) -> tuple:
    """What fixes the symbolic problem: grid size and the sparsity of every recording's pseudo-features."""
    return (problem.n_grid, problem.pairs, problem.pins_common_tilt) + tuple((st.k, np.flatnonzero(st.X.ravel()).tobytes()) for st in problem.stats)


def _sparse_sym(name: str, X: np.ndarray) -> tuple[ca.SX, ca.Sparsity]:
    sp = ca.DM(sparse.csc_matrix(X)).sparsity()
    return ca.SX.sym(name, sp), sp


@dataclass
class HangingNLP:
    """The NLP of every leg whose compressed recordings share one sparsity structure.

    The data (pseudo-features, pseudo-readings, gravity axes) are parameters,
    so the SX expressions and their exact Hessian are built once per structure
    (``structure_key``) and serve every such leg; legs with full coverage of the
    shaft angle all share one. Also holds the Jacobian used for the Fisher
    information (uncertainty.py), built on the same expressions.
    """

    key: tuple
    solver: ca.Function
    jac: ca.Function
    sparsity: list
    lbg: np.ndarray
    ubg: np.ndarray
    n_g_per_rec: int = 11

    @classmethod
    def build(cls, problem: LegProblem) -> "HangingNLP":
        J, G = problem.n_rec, problem.n_grid
        Rs = [ca.SX.sym(f"R{j}", 3, 3) for j in range(J)]
        mg = ca.SX.sym("mg")
        fs = [ca.SX.sym(f"f{j}", 3) for j in range(J)]
        w_o = ca.SX.sym("w_o", 6)
        r = ca.SX.sym("r", 3 * G)
        W = ca.SX.sym("W", 6)
        lam = ca.SX.sym("lam")
        inv_n = ca.SX.sym("inv_n")
        Pi = ca.SX.sym("Pi", 3, 3)  # prior precision per CoM grid point
        Bp = [ca.SX.sym(f"Bp{k}", 3, 2) for k in range(len(problem.pairs))]
        a = [ca.SX.sym(f"a{j}", 3) for j in range(J)]
        Xs, sps = zip(*[_sparse_sym(f"X{j}", st.X) for j, st in enumerate(problem.stats)])
        Ys = [ca.SX.sym(f"Y{j}", 6, st.k) for j, st in enumerate(problem.stats)]
        x1s = [ca.sum2(X).T for X in Xs]
        Rg = ca.reshape(r, G, 3)  # column d: CoM component d over the grid
        r_interp = [ca.mtimes(Rg.T, X.T) for X in Xs]
        data = ca.vertcat(*a, *[ca.vertcat(*X.nonzeros()) for X in Xs], *[ca.vec(Y) for Y in Ys], *[ca.vec(b) for b in Bp])

        def tilt_gauge(forces):
            return ca.vertcat(*[ca.mtimes(b.T, forces[d] + forces[u]) for b, (d, u) in zip(Bp, problem.pairs)])

        res = pseudo_residuals_sx(Ys, x1s, fs, w_o, r_interp)
        D = ca.DM(sparse.csc_matrix(second_difference(G)))
        obj = 0.5 * weighted_sumsq_sx(res, W) + 0.5 * lam * ca.sumsqr(ca.mtimes(D, Rg)) + 0.5 * ca.sum1(ca.sum2(ca.mtimes(Rg, Pi) * Rg))
        g, lbg, ubg = [], [], []
        iu = np.triu_indices(3)
        for j, R in enumerate(Rs):
            E = ca.mtimes(R.T, R) - ca.DM.eye(3)
            g += [E[int(i), int(k)] for i, k in zip(*iu)]
            g.append(ca.dot(a[j], unskew(R - R.T)))
            g.append(fs[j] - mg * ca.mtimes(R, a[j]))
            g.append(ca.det(R))
            lbg += [0.0] * 10 + [0.0]
            ubg += [0.0] * 10 + [np.inf]
        if problem.pins_common_tilt:  # gauge of a single gravity axis (problem.pins_common_tilt)
            g.append(tilt_gauge(fs))
            lbg += [0.0] * (2 * len(problem.pairs))
            ubg += [0.0] * (2 * len(problem.pairs))
        x = ca.vertcat(*[ca.vec(R) for R in Rs], mg, *fs, w_o, r)
        p = ca.vertcat(W, lam, inv_n, ca.vec(Pi), data)
        nlp = {"x": x, "p": p, "f": obj * inv_n, "g": ca.vertcat(*g)}
        solver = ipopt(f"hanging_nlp_{J}x{G}", nlp, **_IPOPT)
        # Jacobian of the standardised residuals in local coordinates (uncertainty.py):
        # R_j = R_j* exp([B_j eta_j]), to first order R_j* (I + [B_j eta_j]).
        eta = ca.SX.sym("eta", 2 * J)
        Rstar = [ca.SX.sym(f"Rs{j}", 3, 3) for j in range(J)]
        B = [ca.SX.sym(f"B{j}", 3, 2) for j in range(J)]
        f_loc = [mg * ca.mtimes(ca.mtimes(Rstar[j], ca.SX.eye(3) + skew(ca.mtimes(B[j], eta[2 * j : 2 * j + 2]))), a[j]) for j in range(J)]
        res_loc = pseudo_residuals_sx(Ys, x1s, f_loc, w_o, r_interp)
        sw = ca.sqrt(W)
        e = ca.vertcat(*[ca.vec(ca.mtimes(ca.diag(sw), rj)) for rj in res_loc])
        c = tilt_gauge(f_loc) if problem.pins_common_tilt else ca.SX(0, 1)
        theta = ca.vertcat(eta, mg, w_o, r)
        jac = ca.Function(
            f"hanging_jacobian_{J}x{G}",
            [theta, ca.vertcat(*[ca.vec(R) for R in Rstar], *[ca.vec(b) for b in B]), W, data],
            [ca.jacobian(e, theta), ca.jacobian(c, theta)],
        )
        return cls(structure_key(problem), solver, jac, list(sps), np.array(lbg), np.array(ubg))

    def data(self, problem: LegProblem) -> np.ndarray:
        """The parameter vector of ``problem``'s data, in the order of ``build``."""
        if structure_key(problem) != self.key:
            raise ValueError(f"leg {problem.leg}: the NLP was built for another data structure")
        nz = []
        for sp, st in zip(self.sparsity, problem.stats):
            rows, cols = sp.get_triplet()
            nz.append(st.X[np.asarray(rows), np.asarray(cols)])
        return np.concatenate(
            [problem.a.ravel()] + nz + [st.Y.T.ravel(order="F") for st in problem.stats] + [b.ravel(order="F") for b in problem.pair_bases()]
        )

    def solve(self, problem: LegProblem, state: LegState, W: np.ndarray, lam: float) -> LegState:
        """Joint optimum from ``state``; raises :class:`HangingSolveError` naming leg and recording."""
        J = problem.n_rec
        x0 = np.concatenate([R.ravel(order="F") for R in state.R] + [[state.mg], state.forces(problem.a).ravel(), state.w_o, state.r.T.ravel()])
        p = np.concatenate([W, [lam, 1.0 / problem.n_samples], problem.prior_precision.ravel(order="F"), self.data(problem)])
        sol = self.solver(x0=x0, p=p, lbg=self.lbg, ubg=self.ubg)
        st = self.solver.stats()
        x = np.asarray(sol["x"]).ravel()
        if not st["success"]:
            g = np.asarray(sol["g"]).ravel()
            viol = np.maximum(np.maximum(self.lbg - g, g - self.ubg), 0)[: J * self.n_g_per_rec].reshape(J, self.n_g_per_rec).max(axis=1)
            worst = problem.names[int(np.argmax(viol))]
            raise SolverError(
                f"leg {problem.leg}: IPOPT failed on the hanging NLP ({st['return_status']}) for recordings {list(problem.names)}; "
                f"largest constraint violation {viol.max():.3g} in recording '{worst}'", str(st["return_status"]))
        R = x[: 9 * J].reshape(J, 3, 3).transpose(0, 2, 1)  # undo column-major vec
        n0 = 9 * J + 1 + 3 * J
        return LegState(R, float(x[9 * J]), x[n0 : n0 + 6].copy(), x[n0 + 6 :].reshape(3, -1).T.copy())

    def jacobian(self, problem: LegProblem, state: LegState, W: np.ndarray, bases: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians, in local coordinates (2J + 7 + 3G columns) at ``state``, of the standardised
        pseudo-residuals and of the gauge constraints (no rows unless ``problem.pins_common_tilt``)."""
        J = problem.n_rec
        th0 = np.concatenate([np.zeros(2 * J), [state.mg], state.w_o, state.r.T.ravel()])
        rb = np.concatenate([R.ravel(order="F") for R in state.R] + [b.ravel(order="F") for b in bases])
        Jr, Jc = self.jac(th0, rb, W, self.data(problem))
        return np.asarray(Jr), np.asarray(Jc).reshape(-1, len(th0))
