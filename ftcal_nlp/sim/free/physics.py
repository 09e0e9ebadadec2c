"""Noise-free readings of a transducer carrying a free load (``shared/DATA_FORMAT.md`` section 5).

Frames: ``W`` world (z up, gravity ``g_W = [0, 0, -g]``), ``B`` body (the URDF's
root link, or the arm's base for a wrist), ``ft`` the TRUE transducer frame.
``R_WB`` (N, 3, 3) maps B vectors to W vectors (the ``qw..qz`` columns).

True transducer orientation (convention checked against the independent
``shared/sample_payload``, see ``tests/test_sim_freeload.py``): the mounting
rotation ``mount_rotvec`` r is in the NOMINAL ft frame's own axes,

    R_B,ft(true) = R_B,ft(nominal) @ exp([r]x)

(for a URDF sensor: the fixed joint's child frame is ``T_origin @ exp([r]x)``,
and everything below the sensor hangs from the true ft frame).

Gravity in ft (pointing down, magnitude g):   g_ft = R_B,ft^T R_WB^T g_W.

A reading is the wrench the load exerts on the transducer, in ft about its
origin, plus the transducer's offset ``w_o`` (and noise, added by the caller):

* rigid payload (mass m, CoM c in ft):       f = m g_ft,   t = c x f
* a load of URDF bodies i below the sensor (mass m_i, CoM c_i in link i's own
  frame; link i at ``(R_i, p_i)`` in ft for the sample's joint angles):

      f = sum_i m_i g_ft,   t = sum_i (p_i + R_i c_i) x (m_i g_ft)

Quasi-static by default: the load's accelerations are left out (as in the shared
samples, whose moves read the static wrench of each instant). With
``inertial_load = s`` the simulator adds ``s`` times the load's inertial wrench
(:func:`inertial_wrench`; B's origin fixed in W, as on a tilting rig or an arm
turning its flange in place): with bodies i of mass m_i, CoM r_i (in W),
angular velocity w_i, inertia I_i about the CoM (W axes), and ft's origin O,

    f_in = -sum_i m_i r_i'',   t_in = -sum_i [ (r_i - O) x m_i r_i'' + I_i w_i' + w_i x I_i w_i ]

(the reaction of the load's momentum change on the transducer, moment about O,
then in ft axes); derivatives by central differences on the sample clock.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ...core.geometry import rotvec_to_rotation, unskew
from ...core.kinematics import KinematicTree

G_DOWN = np.array([0.0, 0.0, -1.0])


def gravity_in_body(R_WB: np.ndarray, g: float) -> np.ndarray:
    """Gravity (N, 3), m/s^2, in B axes: ``R_WB^T [0, 0, -g]``."""
    return g * np.einsum("nji,j->ni", np.asarray(R_WB, dtype=float), G_DOWN)


def gravity_in_ft(R_WB: np.ndarray, R_B_ft: np.ndarray, g: float) -> np.ndarray:
    """Gravity (N, 3), m/s^2, in ft axes: ``R_B,ft^T R_WB^T [0, 0, -g]``; ``R_B_ft`` (3, 3) or (N, 3, 3)."""
    g_B = gravity_in_body(R_WB, g)
    R = np.asarray(R_B_ft, dtype=float)
    return np.einsum("ji,nj->ni", R, g_B) if R.ndim == 2 else np.einsum("nji,nj->ni", R, g_B)


def true_rotation(R_nominal: np.ndarray, mount_rotvec: np.ndarray) -> np.ndarray:
    """``R_B,ft(true) = R_nominal @ exp([r]x)`` (r in the nominal ft axes, rad)."""
    return np.asarray(R_nominal, dtype=float) @ rotvec_to_rotation(np.asarray(mount_rotvec, dtype=float))


def payload_readings(g_ft: np.ndarray, mass_kg: float, com_m: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Noise-free readings (N, 6), N and N*m, in ft about its origin: ``[m g_ft, c x m g_ft] + w_o``."""
    f = float(mass_kg) * np.asarray(g_ft, dtype=float)
    return np.concatenate([f, np.cross(np.asarray(com_m, dtype=float), f)], axis=-1) + np.asarray(offset, dtype=float)


def urdf_load_readings(
    tree: KinematicTree,
    ft_link: str,
    q: Mapping[str, np.ndarray],
    g_B: np.ndarray,
    bodies: Mapping[str, tuple[float, np.ndarray]],
    offset: np.ndarray,
    mount_rotvec: np.ndarray = np.zeros(3),
) -> np.ndarray:
    """Noise-free readings (N, 6) in the true ft frame of the sensor link ``ft_link``.

    ``q[joint]`` (N,) joint positions (missing joints at 0); ``g_B`` (N, 3) gravity
    in B (m/s^2, e.g. :func:`gravity_in_body`); ``bodies[link] = (mass_kg, com_m)``
    with the CoM in that link's own frame, for every massive link below
    ``ft_link`` (a link below it not named here is an error: its weight would be
    silently lost); ``mount_rotvec`` the sensor's true mounting rotation in the
    nominal ft axes.
    """
    g_B = np.asarray(g_B, dtype=float)
    n = len(g_B)
    extra = {ft_link: rotvec_to_rotation(np.asarray(mount_rotvec, dtype=float))}
    R_B_ft, _ = tree.pose(tree.root, ft_link, q, n, extra)
    g_ft = np.einsum("nji,nj->ni", R_B_ft, g_B)
    load = [l for l in tree.below(ft_link) if l in tree.bodies or l in bodies]
    missing = sorted(set(load) - set(bodies))
    if missing:
        raise ValueError(f"urdf_load_readings: no mass/CoM given for link(s) {missing} below '{ft_link}'")
    f = np.zeros((n, 3))
    t = np.zeros((n, 3))
    for link in load:
        m, c = bodies[link]
        R, p = tree.pose(ft_link, link, q, n)          # link in ft: the mounting rotation moves both alike
        r = p + np.einsum("nij,j->ni", R, np.asarray(c, dtype=float))
        fi = float(m) * g_ft
        f += fi
        t += np.cross(r, fi)
    return np.concatenate([f, t], axis=-1) + np.asarray(offset, dtype=float)


def inertial_wrench(t: np.ndarray, R_WB: np.ndarray, p_ft_B: np.ndarray, R_B_ft: np.ndarray,
                    bodies: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """The load's inertial wrench on the transducer (N, 6), in ft about its origin (equation above).

    ``t`` (N,) s; ``R_WB`` (N, 3, 3); ``p_ft_B`` (N, 3) or (3,) ft origin in B, m;
    ``R_B_ft`` (N, 3, 3) or (3, 3) true ft orientation in B; ``bodies``: per body
    ``(mass_kg, com_B (N, 3) m, R_B_link (N, 3, 3), inertia (3, 3) kg m^2 in link axes)``.
    B's origin is fixed in W.
    """
    n = len(t)
    R_WB = np.asarray(R_WB, dtype=float)
    O = np.einsum("nij,nj->ni", R_WB, np.broadcast_to(p_ft_B, (n, 3)))
    f = np.zeros((n, 3))
    tau = np.zeros((n, 3))
    for m, com_B, R_B_link, I_link in bodies:
        r = np.einsum("nij,nj->ni", R_WB, com_B)
        acc = np.gradient(np.gradient(r, t, axis=0), t, axis=0)
        R_Wi = R_WB @ R_B_link
        w = unskew(np.gradient(R_Wi, t, axis=0) @ np.swapaxes(R_Wi, 1, 2))   # [w]x = R' R^T
        dw = np.gradient(w, t, axis=0)
        I_W = R_Wi @ I_link @ np.swapaxes(R_Wi, 1, 2)
        Iw = np.einsum("nij,nj->ni", I_W, w)
        f -= m * acc
        tau -= np.cross(r - O, m * acc) + np.einsum("nij,nj->ni", I_W, dw) + np.cross(w, Iw)
    R_W_ft = R_WB @ np.broadcast_to(R_B_ft, (n, 3, 3))
    return np.concatenate([np.einsum("nji,nj->ni", R_W_ft, f), np.einsum("nji,nj->ni", R_W_ft, tau)], axis=1)
