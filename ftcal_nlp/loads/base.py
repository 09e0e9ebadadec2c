"""The load below a transducer as a plug-in (beside the error models of ``models/``).

A free load (``DATA_FORMAT.md`` section 5) is linear in its parameters ``theta``
(p,): a total mass ``mu . theta`` and, for each sample, a first moment about the
ft origin ``s_n = K_n theta`` (kg m, in ft axes), so that the reading is

    f_n = (mu . theta) g_ft,n + f_o,      t_n = s_n x g_ft,n + t_o,
    g_ft,n = E^T R_nom,n^T g_B,n                                   (m/s^2)

with ``g_B,n`` gravity in B, ``R_nom,n`` the nominal ft orientation in B (from
``robot.toml`` or the URDF for the sample's joint angles) and ``E`` the
transducer's mounting rotation (true ft relative to nominal, ``R_true = R_nom E``).
A :class:`LinearLoad` supplies ``mu``, ``K_n`` (:meth:`LinearLoad.lever`), the
nominal rotation, parameter names, a starting point / prior and the quantities
``calibration.json`` reports. The free-load estimator (``freeload``) serves
every such load.

The hexapod leg (:class:`~ftcal_nlp.loads.leg_com_curve.LegComCurve`) is not
linear in this sense (its CoM is a curve over ``phi``); it delegates to the
hanging calibration.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np


class LinearLoad:
    """Base of the loads linear in their parameters (module docstring). Subclasses set ``name`` and implement
    the methods below; ``kind`` is the ``Dataset.load_kind`` it serves."""

    name: str = ""
    kind: str = ""

    @property
    def param_names(self) -> tuple[str, ...]:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def mass_row(self) -> np.ndarray:
        """``mu`` (p,): total mass = ``mu . theta`` (kg)."""
        raise NotImplementedError  # pragma: no cover

    def lever(self, q: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        """``K`` (n, 3, p): the first moment about the ft origin, ``s_n = K_n theta`` (kg m, ft axes)."""
        raise NotImplementedError  # pragma: no cover

    def nominal_rotation(self, q: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        """Nominal ``R_B,ft`` (n, 3, 3) for the samples' joint angles."""
        raise NotImplementedError  # pragma: no cover

    def prior(self) -> np.ndarray | None:
        """A starting point and weak prior for ``theta`` (p,), or None (then the estimator's own start)."""
        return None

    def varying(self) -> bool:
        """Whether ``lever`` depends on the joint angles (else one row serves every sample)."""
        return True

    def report(self, theta: np.ndarray, cov: np.ndarray, null: np.ndarray | None = None) -> dict:
        """The ``calibration.json`` keys of this load (``OUTPUT_FORMAT.md``), from ``theta``, its covariance on the
        determined subspace and the undetermined directions ``null`` (p, r) (:func:`se_of`)."""
        raise NotImplementedError  # pragma: no cover


def se_of(cov: np.ndarray, J: np.ndarray, null: np.ndarray | None = None, tol: float = 1e-3) -> np.ndarray:
    """Standard errors of ``J theta`` (delta method) from ``cov`` (finite: the covariance on the determined
    subspace). ``null`` (p, r): the directions the data leave undetermined; a row of ``J`` that changes along one
    of them (relative size over ``tol``) is undetermined (se inf), any other (a total mass, a determined
    combination) gets its finite se even when the single parameters it sums are undetermined."""
    J = np.atleast_2d(np.asarray(J, float))
    C = np.where(np.isfinite(cov), cov, 0.0)
    out = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", J, C, J), 0.0, None))
    if null is not None and null.size:
        nn = null / np.linalg.norm(null, axis=0, keepdims=True)
        along = np.abs(J @ nn).max(axis=1)
        out[along > tol * np.linalg.norm(J, axis=1)] = np.inf
    return out


def joint_limits(load) -> dict[str, tuple[float, float]]:
    """``(lower, upper)`` of the URDF joints of ``load`` (below and above its sensor) that have limits
    (``lower < upper``): where a joint's end stop lies, for an effect's face (``joint_limit_contact``)."""
    tree = getattr(load, "tree", None)
    out = {}
    for j in tuple(getattr(load, "load_joints", ())) + tuple(getattr(load, "base_joints", ())):
        jt = tree.joint(j) if tree is not None else None
        if jt is not None and jt.lower is not None and jt.upper is not None and jt.upper > jt.lower:
            out[j] = (float(jt.lower), float(jt.upper))
    return out


def calibration_variance(p, J: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    """``diag(J C J^T)`` (N, 6): the calibration's part of the variance of a correction (``p`` a free-load
    calibration: ``cov``, ``null``, ``undetermined``; ``correct``, ``effects/correction.py``). Inf where ``J`` has a component along an
    undetermined direction (``p.null``, relative size over ``tol``, as :func:`se_of`) or, without the
    directions, where it touches an undetermined parameter at all."""
    var = np.einsum("nij,jk,nik->ni", J, p.cov, J)
    if p.null is not None and p.null.size:
        nn = p.null / np.linalg.norm(p.null, axis=0, keepdims=True)
        along = np.abs(J @ nn).max(axis=-1)
        var = np.where(along > tol * np.linalg.norm(J, axis=-1), np.inf, var)
    elif p.undetermined is not None and p.undetermined.any():
        var = np.where(np.abs(J[:, :, p.undetermined]).max(axis=-1) > 0, np.inf, var)
    return var
