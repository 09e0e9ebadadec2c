"""The free-load NLP (CasADi SX + IPOPT, ``solver.ipopt``): offsets, load parameters, exact mounting rotation.

Unknowns ``x = [w_o (6), theta (p), tilt_1..tilt_G (2 each), E (3x3)]``: one tilt per group of samples (the world
tilt of the orientation stream, one per ``gravity_body``-only recording, a fixed group), each held at 0 by its
bounds unless estimated. With the channel moments of ``problem.compress_tilted`` per group (lifted
``[w_o; u_g (x) z_r]``, ``u_g = R_t,g (0, 0, -1)``) and weights ``W_c = 1 / sigma_c^2``:

    min  1/(2N) [ sum_g ||R_g z_g(x) - c_g||^2  +  sum_i r_i (x_i - x0_i)^2  +  e^T P_N e ]
    s.t. E^T E = I   (6 equations),   det E >= 0,

with ``Q_W = U L U^T``, ``R = L^1/2 U^T``, ``c = L^-1/2 U^T v_W`` (the positive
eigenvalues): ``z^T Q_W z - 2 v_W^T z + s_W = ||R z - c||^2 + (s_W - ||c||^2)``
exactly (``v_W`` lies in the range of ``Q_W``), and the constant is left out.
Written as a sum of squares the objective has no cancellation between terms of
size ``N |y|^2 / sigma^2`` (the moment form would lose ~6 digits to it).

``z(x) = [w_o; vec_r(M E); theta (x) vec_r(E)]``, ``M = mu . theta``. ``E`` is an
exact rotation (as the hanging NLP's ``R_j``): orthonormality as equalities and
``det E >= 0`` as an inactive inequality that selects the SO(3) sheet (an
equality there would be dependent on the orthonormality constraints). The
ridge ``r_i = prior_weight * A_ii`` (``A`` the information at the start)
pulls toward ``x0`` (the load's nominal values, ``E = I``) only where the data
say nothing: for a determined direction of scaled information ``lambda`` it
moves the estimate by a fraction ``prior_weight / lambda`` (<= 1e-3 at the
identifiability threshold). Where the information at the start already has
undetermined directions (``N``, scaled), ``P_N = S N N^T S`` (``S`` the
scaling, unit weight in scaled units) holds the local deviation
``e = [w_o - w_o0, theta - theta0, vee(E - E^T) / 2]`` at the prior along them
only: without it IPOPT wanders along a flat valley (one gravity direction
leaves the rotation about it and mass vs offset free).

The Jacobian of ``z`` in local coordinates ``[w_o, theta, delta]`` with
``E = E* (I + [delta]x)`` gives the Gauss-Newton information ``J^T Q_W J`` at
the optimum (``result.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from ...core.geometry import skew
from ...core.solver import ipopt, solve_checked
from .problem import n_tilted

_IPOPT: dict[str, Any] = {"tol": 1e-8, "acceptable_tol": 1e-6, "acceptable_iter": 3, "max_iter": 500}  # rounding floor of the gradient ~1e-9


def _lifted(w_o, theta, E, mu):
    eR = ca.vec(E.T)                                  # row-major vec of E
    M = ca.dot(ca.DM(mu), theta)
    return ca.vertcat(w_o, M * eR, *[theta[l] * eR for l in range(theta.shape[0])])


def _lifted_mx(w_o, theta, E, mu):
    """:func:`_lifted` for MX: ``theta (x) vec_r(E)`` as the columns of ``vec_r(E) theta^T``."""
    eR = ca.vec(E.T)
    M = ca.dot(ca.DM(mu), theta)
    return ca.vertcat(w_o, M * eR, ca.vec(ca.mtimes(eR, theta.T)))


def _u(tilt):
    """``R_y(tilt[1]) R_x(tilt[0]) (0, 0, -1)`` (``problem.tilt_gravity``)."""
    return ca.vertcat(-ca.cos(tilt[0]) * ca.sin(tilt[1]), ca.sin(tilt[0]), -ca.cos(tilt[0]) * ca.cos(tilt[1]))


def _tilted(z, tilt):
    """``[w_o; u (x) z_r]`` of ``problem.compress_tilted``."""
    u = _u(tilt)
    return ca.vertcat(z[:6], u[0] * z[6:], u[1] * z[6:], u[2] * z[6:])


@dataclass
class FreeLoadNLP:
    """The solver and the local Jacobian for loads with ``p`` parameters and mass row ``mu`` (built once, reused)."""

    p: int
    mu: np.ndarray
    G: int
    solver: ca.Function
    jac: ca.Function
    lifted: ca.Function
    lifted_t: ca.Function

    @classmethod
    def build(cls, mu: np.ndarray, G: int = 1) -> "FreeLoadNLP":
        p = len(mu)
        d = n_tilted(p)
        # the solver in MX: the data matrix R (d x d) enters as one matrix-vector product, so building the NLP and
        # its exact Hessian costs milliseconds at any size (SX would expand the d^2 products: seconds at d ~ 200)
        w_o, theta, E, tilt = ca.MX.sym("w_o", 6), ca.MX.sym("theta", p), ca.MX.sym("E", 3, 3), ca.MX.sym("tilt", 2 * G)
        Rqs, cs = [ca.MX.sym(f"R{k}", d, d) for k in range(G)], [ca.MX.sym(f"c{k}", d) for k in range(G)]
        nx = 6 + p + 2 * G + 9
        nl = 9 + p + 2 * G
        r, x0, inv_n = ca.MX.sym("r", nx), ca.MX.sym("x0", nx), ca.MX.sym("inv_n")
        Pn = ca.MX.sym("Pn", nl, nl)
        x = ca.vertcat(w_o, theta, tilt, ca.vec(E))
        z0 = _lifted_mx(w_o, theta, E, mu)
        fit = sum(ca.sumsqr(ca.mtimes(Rqs[k], _tilted(z0, tilt[2 * k:2 * k + 2])) - cs[k]) for k in range(G))
        e = ca.vertcat(w_o - x0[:6], theta - x0[6:6 + p], tilt - x0[6 + p:6 + p + 2 * G],
                       0.5 * ca.vertcat(E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]))
        obj = 0.5 * inv_n * (fit + ca.dot(r, (x - x0) ** 2) + ca.dot(e, ca.mtimes(Pn, e)))
        EtE = ca.mtimes(E.T, E) - ca.DM.eye(3)
        g = ca.vertcat(*[EtE[i, k] for i in range(3) for k in range(i, 3)], ca.det(E))
        P = ca.vertcat(*[ca.vertcat(ca.vec(Rqs[k]), cs[k]) for k in range(G)], r, x0, inv_n, ca.vec(Pn))
        solver = ipopt(f"freeload_nlp_p{p}_g{G}", {"x": x, "p": P, "f": obj, "g": g}, **_IPOPT)
        w_s, th_s, E_s = ca.SX.sym("w_o", 6), ca.SX.sym("theta", p), ca.SX.sym("E", 3, 3)
        delta, Es, t_s = ca.SX.sym("delta", 3), ca.SX.sym("Es", 3, 3), ca.SX.sym("tilt", 2)
        z_loc = _tilted(_lifted(w_s, th_s, ca.mtimes(Es, ca.SX.eye(3) + skew(delta)), mu), t_s)
        xl = ca.vertcat(w_s, th_s, t_s, delta)
        jac = ca.Function(f"freeload_jac_p{p}", [xl, Es], [ca.jacobian(z_loc, xl)])
        lifted = ca.Function(f"freeload_z_p{p}", [ca.vertcat(w_s, th_s, ca.vec(E_s))], [_lifted(w_s, th_s, E_s, mu)])
        lifted_t = ca.Function(f"freeload_zt_p{p}", [ca.vertcat(w_s, th_s, t_s, ca.vec(E_s))],
                               [_tilted(_lifted(w_s, th_s, E_s, mu), t_s)])
        return cls(p, np.asarray(mu, float), G, solver, jac, lifted, lifted_t)

    @property
    def lbg(self) -> np.ndarray:
        return np.r_[np.zeros(6), 0.0]

    @property
    def ubg(self) -> np.ndarray:
        return np.r_[np.zeros(6), np.inf]

    def solve(self, Q, v, n: int, ridge: np.ndarray, x0: np.ndarray, start: np.ndarray,
              *, mount_rotation: bool, tilt, what: str, null_penalty: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
        """The optimum ``x`` and IPOPT's stats; raises :class:`~ftcal_nlp.core.errors.SolverError` naming ``what``. ``Q``,
        ``v``: one weighted moment pair per group (a single pair: one group); ``tilt`` (G,) which groups' tilts are
        free (a bool: all or none)."""
        Qs, vs = (Q, v) if isinstance(Q, (list, tuple)) else ([Q], [v])
        parts = []
        for Qg, vg in zip(Qs, vs):
            R, c = square_root(Qg, vg)
            parts += [R.ravel(order="F"), c]
        nl = 9 + self.p + 2 * self.G
        Pn = np.zeros((nl, nl)) if null_penalty is None else null_penalty
        P = np.concatenate(parts + [ridge, x0, [1.0 / n], Pn.ravel(order="F")])
        lbx, ubx = np.full(len(start), -np.inf), np.full(len(start), np.inf)
        if not mount_rotation:  # E held at the nominal (identity)
            lbx[-9:] = ubx[-9:] = np.eye(3).ravel(order="F")
        free = np.broadcast_to(np.asarray(tilt, bool), (self.G,))
        for k in np.flatnonzero(~free):  # a tilt not estimated: held at 0
            lbx[6 + self.p + 2 * k:8 + self.p + 2 * k] = ubx[6 + self.p + 2 * k:8 + self.p + 2 * k] = 0.0
        sol, st = solve_checked(self.solver, what, x0=start, p=P, lbg=self.lbg, ubg=self.ubg, lbx=lbx, ubx=ubx)
        return np.asarray(sol["x"]).ravel(), st

    def z(self, x: np.ndarray) -> np.ndarray:
        """``z`` of ``problem.compress`` at ``x = [w_o, theta, vec(E)]``."""
        return np.asarray(self.lifted(x)).ravel()

    def z_tilted(self, x: np.ndarray) -> np.ndarray:
        """``[w_o; u (x) z_r]`` of ``problem.compress_tilted`` at ``x = [w_o, theta, tilt, vec(E)]``."""
        return np.asarray(self.lifted_t(x)).ravel()

    def jacobian(self, w_o: np.ndarray, theta: np.ndarray, tilt: np.ndarray, E: np.ndarray) -> np.ndarray:
        """``dz / d[w_o, theta, tilt, delta]`` (D, 11 + p) at ``E* = E``, ``delta = 0``."""
        return np.asarray(self.jac(np.concatenate([w_o, theta, tilt, np.zeros(3)]), E))


def square_root(Q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, c)`` with ``z^T Q z - 2 v^T z = ||R z - c||^2 - ||c||^2`` (module docstring; positive eigenvalues of ``Q``)."""
    lam, U = np.linalg.eigh(Q)
    ok = lam > 1e-13 * max(lam.max(), 1e-300)
    R = np.zeros_like(Q)
    R[: ok.sum()] = np.sqrt(lam[ok])[:, None] * U[:, ok].T
    c = np.zeros(len(v))
    c[: ok.sum()] = (U[:, ok].T @ v) / np.sqrt(lam[ok])
    return R, c


_CACHE: dict[tuple, FreeLoadNLP] = {}


def nlp_for(mu: np.ndarray, G: int = 1) -> FreeLoadNLP:
    """The NLP for mass row ``mu`` and ``G`` tilt groups (cached: loads of one shape share it)."""
    key = (tuple(np.asarray(mu, float).tolist()), int(G))
    if key not in _CACHE:
        _CACHE[key] = FreeLoadNLP.build(np.asarray(mu, float), int(G))
    return _CACHE[key]
