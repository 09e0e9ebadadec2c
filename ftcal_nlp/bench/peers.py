"""The peers' baselines for a rigid payload: the plain least squares of kth ``ft_calib`` and of Robotlib.jl's ``calibForce``.

Convention of ``shared/DATA_FORMAT.md``: a reading is the wrench the load
exerts on the transducer, in ft about its origin, plus offset:

    f = m g_ft + f0,      t = c x (m g_ft) + t0 = -[g_ft]x (m c) + t0,

``g_ft`` (N, 3) gravity (pointing down, magnitude g, m/s^2) in ft for each
sample, ``m`` kg, ``c`` m the CoM in ft, ``f0`` N and ``t0`` N*m the offsets.

* :func:`ft_calib` -- kth-ros-pkg/force_torque_tools,
  ``force_torque_sensor_calib/src/ft_calib.cpp`` (``FTCalib::getMeasurementMatrix``,
  ``getCalib``): per measurement a 6x10 block ``H`` in ``x = [m, m c, f0, t0]``
  with ``H[0:3, 0] = a - g``, ``H[3:6, 1:4] = [a - g]x`` (static: ``a = 0``; their
  ``g`` is minus the IMU's specific force, their force sign the opposite of
  ours, so their ``a - g`` is our ``g_ft``), stacked over measurements and
  solved by SVD least squares; the CoM is ``x[1:4] / x[0]``. The orientation of
  ft is taken as known (the nominal one): no mounting rotation. The force rows
  see only ``m, f0`` and the torque rows only ``m c, t0``, so the one unweighted
  LS is two independent ones, solved so here (with their standard errors).
* :func:`calib_force` -- Robotlib.jl ``calibForce(POSES, F; offset=true)``
  (Bagge Carlson, src/calibForce.jl): forces only, model
  ``Rf F_i + offs = R_i^T [0, 0, -m g]``; first a linear LS in a free 3x3
  ``Rf`` (scaled by a mass guess) and the offset, ``Rf`` projected to SO(3)
  (``toOrthoNormal``, SVD), then a LS in ``m g`` and the offset with ``Rf``
  fixed. Here in our frames: with the nominal ``g_nom = R_B,ft(nom)^T R_WB^T g_W``
  and the true ft frame ``R_B,ft(nom) E``, ``f - f0 = m E^T g_nom``, i.e.
  ``E f + b = m g_nom``: LS in the free ``M ~ E / m`` and ``b``, ``E`` = SO(3)
  projection of ``M``, then ``m, f0`` by LS given ``E``; the torque part (not in
  ``calibForce``) is ft_calib's torque LS with the corrected ``g_ft = E^T g_nom``.

Neither weights forces against torques nor models anything beyond a rigid
payload; they are baselines, not the method. Pass held (quasi-static) samples
or pose averages, as both packages expect.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import project_to_so3, rotation_to_rotvec, skew


@dataclass(frozen=True)
class PeerFit:
    """A baseline's estimate. ``mass_kg``; ``com_m`` (3,) m in the (estimated) ft frame; ``offset`` (6,) N, N*m;
    ``rotation`` (3, 3) ``E``: true ft relative to nominal (``R_B,ft(true) = R_B,ft(nom) @ E``; identity for
    ft_calib) and ``mount_rotvec`` its rotation vector (rad); ``*_se`` standard errors from each LS's
    residual variance (the rotation's uncertainty not propagated); ``rms`` (6,) residual RMS per channel."""

    method: str
    mass_kg: float
    com_m: np.ndarray
    offset: np.ndarray
    rotation: np.ndarray
    mass_se_kg: float
    com_se_m: np.ndarray
    offset_se: np.ndarray
    rms: np.ndarray

    @property
    def mount_rotvec(self) -> np.ndarray:
        return rotation_to_rotvec(self.rotation)


def _lstsq(H: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solution, its covariance (residual variance x (H^T H)^-1) and the residual."""
    x, *_ = np.linalg.lstsq(H, z, rcond=None)
    r = z - H @ x
    s2 = float(r @ r) / max(len(z) - H.shape[1], 1)
    return x, s2 * np.linalg.pinv(H.T @ H), r


def _force_torque_ls(g_ft: np.ndarray, w: np.ndarray):
    """ft_calib's two blocks: ``f = m g_ft + f0`` and ``t = -[g_ft]x (m c) + t0``."""
    n = len(g_ft)
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    Hf = np.concatenate([g_ft[:, :, None], eye], axis=2).reshape(3 * n, 4)
    xf, Cf, rf = _lstsq(Hf, w[:, :3].reshape(-1))
    Ht = np.concatenate([-skew(g_ft), eye], axis=2).reshape(3 * n, 6)
    xt, Ct, rt = _lstsq(Ht, w[:, 3:].reshape(-1))
    m, mc = xf[0], xt[:3]
    c = mc / m
    # d c = (d(mc) - c dm) / m: first order, the two blocks independent
    com_cov = Ct[:3, :3] / m**2 + np.outer(c, c) * Cf[0, 0] / m**2
    rms = np.sqrt(np.concatenate([(rf.reshape(n, 3) ** 2).mean(0), (rt.reshape(n, 3) ** 2).mean(0)]))
    return (float(m), c, np.concatenate([xf[1:], xt[3:]]), float(np.sqrt(Cf[0, 0])), np.sqrt(np.diag(com_cov)),
            np.sqrt(np.concatenate([np.diag(Cf)[1:], np.diag(Ct)[3:]])), rms)


def ft_calib(g_ft: np.ndarray, w: np.ndarray) -> PeerFit:
    """kth ``ft_calib``: offsets, mass and CoM by linear LS given gravity in ft (no mounting rotation).

    ``g_ft`` (N, 3) m/s^2 gravity in the NOMINAL ft frame; ``w`` (N, 6) readings, N and N*m.
    """
    g_ft, w = np.asarray(g_ft, dtype=float), np.asarray(w, dtype=float)
    m, c, off, m_se, c_se, off_se, rms = _force_torque_ls(g_ft, w)
    return PeerFit("ft_calib", m, c, off, np.eye(3), m_se, c_se, off_se, rms)


def calib_force(g_nom: np.ndarray, w: np.ndarray) -> PeerFit:
    """Robotlib.jl ``calibForce``-style: a mounting rotation ``E`` too (free 3x3 LS, projected to SO(3)),
    then ``m, f0`` given ``E``, then ft_calib's torque LS with ``g_ft = E^T g_nom``.

    ``g_nom`` (N, 3) m/s^2 gravity in the NOMINAL ft frame; ``w`` (N, 6) readings.
    """
    g_nom, w = np.asarray(g_nom, dtype=float), np.asarray(w, dtype=float)
    n = len(g_nom)
    f = w[:, :3]
    # E f_i + b = m g_nom_i, with M = E / m: A [vec(M); b] = g_nom (calibForce's A = [F1 I, F2 I, F3 I, I]).
    eye = np.eye(3)
    A = np.concatenate([f[:, 0, None, None] * eye, f[:, 1, None, None] * eye, f[:, 2, None, None] * eye,
                        np.broadcast_to(eye, (n, 3, 3))], axis=2).reshape(3 * n, 12)
    x, *_ = np.linalg.lstsq(A, g_nom.reshape(-1), rcond=None)
    M = x[:9].reshape(3, 3, order="F")          # column-major, as Julia's reshape
    E = project_to_so3(M)
    g_ft = g_nom @ E                            # E^T g_nom per row
    m, c, off, m_se, c_se, off_se, rms = _force_torque_ls(g_ft, w)
    return PeerFit("calib_force", m, c, off, E, m_se, c_se, off_se, rms)
