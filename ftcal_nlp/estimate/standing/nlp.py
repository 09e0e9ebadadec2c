"""The standing calibration as one NLP, solved by IPOPT (report eq. 8 with exact SO(3)).

    min_theta  tr(W L(theta) S L(theta)^T)       S = sum_p xi_p xi_p^T / P,  W = K by default
    s.t.       the model's constraints g(theta) (R^T R = I, det R >= 0 per free rotation)

(``problem.py`` for ``L`` and ``xi``.) The moment matrix S is a parameter of the
compiled solver, so one compilation serves the full fit and every
cross-validation fold; so is the 6x6 weight W (eq. 8's K, or the feasible GLS
weight). ``L(x)`` and the constraints are SX functions (scalar
graphs, fast to evaluate); the objective wraps them in a small MX graph
(``L S L^T`` as matrix products), which keeps the exact Hessian while building in
~0.1 s instead of the ~0.5-2 s of an all-SX objective with a 40x40 to 94x94
symbolic S. IPOPT prints
nothing unless ``verbose``; a solve that does not end in success raises
:class:`SolverError` with IPOPT's return status.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ...core.calibration import Calibration
from ...models import ModelSpec
from ...core.solver import SolverError, ipopt, solve_checked
from .problem import K_DIAG, L_casadi, n_features, objective_casadi

__all__ = ["SolverError", "Solution", "CompiledProblem", "compile_problem"]


@dataclass(frozen=True)
class Solution:
    x: np.ndarray
    status: str
    iterations: int
    solve_time_s: float
    objective: float


@dataclass
class CompiledProblem:
    """One (model, balance) problem compiled once: ``L(x)``, its Jacobian, and the IPOPT solver."""

    spec: ModelSpec
    balance: str
    model_name: str
    L_fn: ca.Function
    dL_fn: ca.Function
    nlp: dict
    n_xi: int
    ipopt_options: dict
    _solver: ca.Function | None = None

    @property
    def solver(self) -> ca.Function:
        """The IPOPT solver, built on first use (the baseline path needs only L and dL)."""
        if self._solver is None:
            self._solver = ipopt(f"standing_{self.model_name or 'model'}_{self.balance}", self.nlp, **self.ipopt_options)
        return self._solver

    def L(self, x: np.ndarray) -> np.ndarray:
        """``L(x)`` (6, n_xi)."""
        return np.array(self.L_fn(x))

    def dL(self, x: np.ndarray) -> np.ndarray:
        """``dL/dx`` as (6, n_xi, n)."""
        J = np.array(self.dL_fn(x))  # rows: vec(L) column-major, index i + 6 j
        return J.reshape(self.n_xi, 6, -1).transpose(1, 0, 2)

    def solve(self, S: np.ndarray, x0: np.ndarray | None = None, W: np.ndarray | None = None) -> Solution:
        """Minimise eq. 8 for moments ``S`` from ``x0`` (the model's start by default), weight ``W`` (K by default)."""
        sp = self.spec
        x0 = sp.x0 if x0 is None else x0
        W = np.diag(K_DIAG) if W is None else np.asarray(W, float)
        p = ca.vertcat(ca.DM(S).reshape((-1, 1)), ca.DM(W).reshape((-1, 1)))
        t0 = time.perf_counter()
        sol, st = solve_checked(self.solver, f"model {self.model_name!r} ({self.balance} balance)",
                                x0=x0, p=p, lbx=sp.lbx, ubx=sp.ubx, lbg=sp.lbg, ubg=sp.ubg)
        dt = time.perf_counter() - t0
        status = str(st.get("return_status", "unknown"))
        return Solution(np.array(sol["x"]).ravel(), status, int(st.get("iter_count", -1)), dt, float(sol["f"]))


def offsets_expr(spec: ModelSpec, prior: Calibration, legs) -> list:
    """The offsets in the balance: the model's own, or the prior's as constants."""
    if spec.offsets is not None:
        return list(spec.offsets)
    return [ca.DM(prior.legs[k].offset) for k in legs]


def compile_problem(spec: ModelSpec, prior: Calibration, legs, balance: str, *, model_name: str = "",
                    verbose: bool = False, tol: float = 1e-10, max_iter: int = 500) -> CompiledProblem:
    """Build ``L(x)`` and the IPOPT solver of eq. 8 for one model spec and balance."""
    L = L_casadi(spec.R, spec.p_prime, offsets_expr(spec, prior, legs), prior, legs, balance)
    n_xi = n_features(len(legs), balance)
    L_fn = ca.Function("L", [spec.x], [L])
    x = ca.MX.sym("x", spec.x.numel())
    S = ca.MX.sym("S", n_xi, n_xi)
    W = ca.MX.sym("W", 6, 6)
    f = objective_casadi(L_fn(x), S, W)
    g = ca.Function("g", [spec.x], [spec.g])(x)
    opts = {"tol": tol, "max_iter": max_iter, "print_level": 5 if verbose else 0}
    nlp = {"x": x, "p": ca.vertcat(ca.reshape(S, -1, 1), ca.reshape(W, -1, 1)), "f": f, "g": g}
    dL_fn = ca.Function("dL", [spec.x], [ca.jacobian(ca.reshape(L, -1, 1), spec.x)])
    return CompiledProblem(spec, balance, model_name, L_fn, dL_fn, nlp, n_xi, opts)
