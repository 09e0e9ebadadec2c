"""The solver layer every estimation problem shares: IPOPT options, one error, identifiability.

* :func:`ipopt` builds a CasADi ``nlpsol`` with the package's IPOPT options
  (:data:`IPOPT_OPTIONS`: silent, tight tolerance) plus the few a problem
  overrides (the hanging NLP accepts at 1e-6 because its gradient's rounding
  floor with stiff smoothing is ~1e-7).
* :func:`solve_checked` runs it and raises :class:`SolverError`, carrying the
  solver's own status text, whenever IPOPT does not report success; every
  problem (hanging, standing, the diagnosis' augmented fits) and the report's
  baseline solvers raise this one error.
* :func:`identifiability`: which directions of an information matrix
  ``A = J^T W J`` the data determine. ``A`` is scaled to unit diagonal
  (parameters of different units compare), its eigenvalues are taken relative to
  the largest, and directions below ``rel_tol`` are undetermined. The
  pseudo-inverse on the determined subspace is the covariance (up to the noise
  scale); the undetermined directions are returned for naming.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from .errors import SolverError

__all__ = ["REL_EIG_TOL", "IPOPT_OPTIONS", "SolverError", "ipopt", "solve_checked", "Identifiability", "identifiability"]

# Identifiability threshold: a direction whose scaled information is below this fraction of the
# best-determined one's has a standard error > ~300 times larger: the data do not determine it.
REL_EIG_TOL = 1e-5

IPOPT_OPTIONS: dict[str, Any] = {
    "ipopt.print_level": 0,
    "print_time": False,
    "ipopt.sb": "yes",
    "ipopt.tol": 1e-10,
    "ipopt.max_iter": 1000,
}




def ipopt(name: str, nlp: dict, *, verbose: bool = False, **overrides: Any) -> ca.Function:
    """``casadi.nlpsol(name, "ipopt", nlp, opts)`` with :data:`IPOPT_OPTIONS` and ``overrides``
    (IPOPT's own option names without the ``ipopt.`` prefix, e.g. ``tol=1e-8``)."""
    opts = dict(IPOPT_OPTIONS)
    opts.update({f"ipopt.{k}": v for k, v in overrides.items()})
    if verbose:
        opts.update({"ipopt.print_level": 5, "print_time": True})
    return ca.nlpsol(name, "ipopt", nlp, opts)


def solve_checked(solver: ca.Function, what: str, **args: Any) -> tuple[dict, dict]:
    """Call ``solver(**args)``; return ``(solution, stats)`` or raise :class:`SolverError`
    naming ``what`` (the problem: model, leg, recordings), the status and the iteration count."""
    sol = solver(**args)
    st = solver.stats()
    if not st.get("success", False):
        status = str(st.get("return_status", "unknown"))
        raise SolverError(f"IPOPT did not converge on {what}: {status} after {st.get('iter_count', '?')} iterations", status)
    return sol, st


@dataclass(frozen=True)
class Identifiability:
    """Eigen-decomposition of the unit-diagonal scaled information matrix ``A_s = A / (s s^T)``.

    ``scale`` (n,) the ``s``; ``eigenvalues``, ``vectors`` of ``A_s``; ``ratio`` eigenvalues /
    the largest; ``determined`` the directions with ratio >= ``rel_tol``."""

    scale: np.ndarray
    eigenvalues: np.ndarray
    vectors: np.ndarray
    ratio: np.ndarray
    determined: np.ndarray

    @property
    def rank(self) -> int:
        return int(self.determined.sum())

    def pinv(self) -> np.ndarray:
        """``A^+`` restricted to the determined subspace, in the original (unscaled) parameters."""
        V, lam, ok, s = self.vectors, self.eigenvalues, self.determined, self.scale
        Ainv_s = (V[:, ok] / lam[ok]) @ V[:, ok].T
        return Ainv_s / np.outer(s, s)

    def undetermined_directions(self) -> list[tuple[np.ndarray, float]]:
        """Each undetermined direction in the original parameters, with its eigenvalue ratio."""
        return [(self.vectors[:, j] / self.scale, float(self.ratio[j])) for j in np.flatnonzero(~self.determined)]


def identifiability(A: np.ndarray, rel_tol: float) -> Identifiability:
    """Scaled eigen-analysis of a symmetric positive semi-definite information matrix (module docstring)."""
    A = np.asarray(A, float)
    s = np.sqrt(np.clip(np.diag(A), 0.0, None))
    s = np.where(s > 0, s, 1.0)
    lam, V = np.linalg.eigh(A / np.outer(s, s))
    top = lam.max() if lam.size and lam.max() > 0 else 1.0
    ratio = lam / top
    return Identifiability(s, lam, V, ratio, ratio >= rel_tol)
