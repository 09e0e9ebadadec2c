"""The generic Cramer-Rao bound: Fisher information, the bound on the directions it determines, named parameters.

Any Gaussian model ``y = h(theta) + n``, ``n ~ N(0, Sigma)``:

    F = sum J^T Sigma^-1 J,     Cov(theta_hat) >= F^-1        (J = dh/dtheta at the truth)

Directions the data do not determine (tiny eigenvalues of ``F``) are removed:
``F`` is scaled to unit diagonal (so parameters of different units compare),
eigen-decomposed, and directions whose eigenvalue is below ``rel_tol`` times
the largest are projected out of both the bound (pseudo-inverse on the kept
subspace) and the errors compared with it (:class:`Bound`). The tolerance is
the standing stage's own (``standing.result.REL_EIG_TOL``), so "identifiable"
means what the estimator reports. :class:`LoadBound` names the parameters and
says, one line per dropped direction, what cannot be separated from what
(:func:`describe_dropped`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..core.solver import REL_EIG_TOL


def fisher_information(J: np.ndarray, Sigma: np.ndarray) -> np.ndarray:
    """``sum_p J_p^T Sigma_p^-1 J_p``; ``J`` (P, m, n) or (m, n), ``Sigma`` (P, m, m) or (m, m)."""
    J = np.asarray(J, float)
    Sigma = np.asarray(Sigma, float)
    if J.ndim == 2:
        J = J[None]
    if Sigma.ndim == 2:
        Sigma = np.broadcast_to(Sigma, (J.shape[0],) + Sigma.shape)
    SiJ = np.linalg.solve(Sigma, J)
    return np.einsum("pmi,pmj->ij", J, SiJ)


@dataclass(frozen=True)
class Bound:
    """A Cramer-Rao bound on the identifiable subspace of ``F``.

    ``cov`` (n, n): pseudo-inverse of ``F`` on the kept directions; ``basis``
    (n, r) their orthonormal basis in scaled coordinates ``theta * scale``;
    ``n_dropped`` the directions removed (unidentifiable); ``eig_ratio`` every
    eigenvalue of the scaled ``F`` over the largest.
    """

    cov: np.ndarray
    basis: np.ndarray
    scale: np.ndarray
    n_dropped: int
    eig_ratio: np.ndarray

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    def project(self, e: np.ndarray) -> np.ndarray:
        """Errors ``e`` (..., n) with the unidentifiable directions removed (same coordinates)."""
        es = np.asarray(e, float) * self.scale
        return (es @ self.basis) @ self.basis.T / self.scale


def crb(F: np.ndarray, rel_tol: float = REL_EIG_TOL) -> Bound:
    """The bound ``F^-1`` on the directions ``F`` determines (module docstring)."""
    F = 0.5 * (np.asarray(F, float) + np.asarray(F, float).T)
    s = np.sqrt(np.clip(np.diag(F), 0.0, None))
    s = np.where(s > 0, s, 1.0)
    lam, V = np.linalg.eigh(F / np.outer(s, s))
    ratio = lam / lam.max()
    keep = ratio >= rel_tol
    Vk = V[:, keep]
    cov = (Vk / lam[keep]) @ Vk.T / np.outer(s, s)
    return Bound(cov, Vk, s, int((~keep).sum()), ratio)


def marginal(bound: Bound, idx) -> np.ndarray:
    """Covariance block of the parameters ``idx``."""
    idx = np.asarray(idx)
    return bound.cov[np.ix_(idx, idx)]


# ----------------------------------------------------------------------------- the bound with names


@dataclass(frozen=True)
class LoadBound:
    """A bound on named parameters: ``bound`` (crb.Bound), ``F`` the Fisher information, ``names`` (p,),
    ``theta`` (p,) the truth it was evaluated at, ``unidentified`` one note per dropped direction."""

    names: tuple[str, ...]
    theta: np.ndarray
    F: np.ndarray
    bound: Bound
    unidentified: tuple[str, ...]

    @property
    def se(self) -> dict[str, float]:
        """Bound on the standard error of each parameter (on the identifiable subspace)."""
        return dict(zip(self.names, self.bound.sd))

    def sd(self, names) -> np.ndarray:
        idx = [self.names.index(n) for n in names]
        return self.bound.sd[idx]

    def cov(self, names) -> np.ndarray:
        idx = [self.names.index(n) for n in names]
        return self.bound.cov[np.ix_(idx, idx)]

    def sd_of(self, weights: Mapping[str, float]) -> float:
        """Bound on the sd of a linear combination ``sum_n weights[n] theta_n`` (e.g. a URDF load's total mass)."""
        a = np.zeros(len(self.names))
        for n, w in weights.items():
            a[self.names.index(n)] = w
        return float(np.sqrt(max(a @ self.bound.cov @ a, 0.0)))

    @property
    def identifiable(self) -> bool:
        return self.bound.n_dropped == 0


def describe_dropped(bound: Bound, names: tuple[str, ...], tol: float = 0.05) -> tuple[str, ...]:
    """One note per direction that ``F`` does not determine, as "``a`` is not separable from ``b``, ``c``".

    The null space (scaled coordinates) is put in a reduced echelon form (column-pivoted QR picks one
    parameter per direction, the basis is then 1 at its own pivot and 0 at the others'), so each note
    names one parameter and the others that move with it (weight >= ``tol`` of the pivot's)."""
    N = dropped_directions(bound)
    if N.shape[1] == 0:
        return ()
    from scipy.linalg import qr

    _, _, piv = qr(N.T, pivoting=True)
    piv = piv[: N.shape[1]]
    B = N @ np.linalg.inv(N[piv, :])              # (n, d): B[piv[j], i] = delta_ij
    notes = []
    for j, pj in enumerate(piv):
        others = [i for i in np.argsort(-np.abs(B[:, j])) if i != pj and abs(B[i, j]) >= tol]
        with_ = ", ".join(names[i] for i in others) if others else "anything: no reading depends on it"
        notes.append(f"{names[pj]} is not separable from {with_}")
    return tuple(notes)


def dropped_directions(bound: Bound) -> np.ndarray:
    """Orthonormal basis (n, d) of the scaled coordinates the bound left out (complement of ``bound.basis``)."""
    n = bound.basis.shape[0]
    if bound.n_dropped == 0:
        return np.zeros((n, 0))
    lam, V = np.linalg.eigh(np.eye(n) - bound.basis @ bound.basis.T)
    return V[:, lam > 0.5]


def named_bound(J: np.ndarray, Sigma: np.ndarray, names: tuple[str, ...], theta: np.ndarray,
                rel_tol: float = REL_EIG_TOL) -> LoadBound:
    """``LoadBound`` from per-sample Jacobians ``J`` (N, 6, p) and covariances ``Sigma`` (N, 6, 6) or (6, 6)."""
    F = fisher_information(J, Sigma)
    b = crb(F, rel_tol)
    return LoadBound(tuple(names), np.asarray(theta, float), F, b, describe_dropped(b, tuple(names)))
