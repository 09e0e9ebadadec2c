"""Cramer-Rao bounds of the free loads of ``shared/DATA_FORMAT.md`` section 5 (issue 22): a rigid payload on a
wrist transducer and a load of URDF links grouped by the joints that move them.

Independent of the estimator: the reading model is written here in numpy with its
analytic Jacobian (checked against finite differences of ``sim/free/physics.py``,
the simulator's forward model, in ``tests/test_crb_loads.py``), and the bound
comes from the generic pieces of :mod:`ftcal_nlp.crb.bound` (``fisher_information``,
``crb``, ``named_bound``: directions of ``F`` below ``REL_EIG_TOL`` of the largest are reported
as not identifiable and removed).

Reading of sample i in the TRUE ft frame, about its origin (``sim/free/physics.py``):

    f_i = M g_i + f_o,      t_i = S_i x g_i + t_o,

``g_i`` gravity in ft (m/s^2, pointing down), ``M`` the load's mass and ``S_i``
its first moment (kg m) in ft:

* payload:   ``M = m``, ``S = m c`` (c the CoM in ft);
* URDF load: groups k (the links whose nearest movable joint below the sensor
  is joint k, each group in the frame of that joint's child link; the links
  rigid with the sensor form the group named after the sensor link), group k
  at ``(R_k,i, p_k,i)`` in ft for sample i's joint angles, with mass ``m_k`` and
  first moment ``s_k`` in its own frame: ``M = sum_k m_k``,
  ``S_i = sum_k (m_k p_k,i + R_k,i s_k)``; linear in ``(m_k, s_k)``.

Mounting rotation: ``R_B,ft(true) = R_B,ft(nom) exp([r]x)``; the bound is for
a perturbation ``delta`` in the true ft axes, ``g -> exp(-[delta]x) g = g + [g]x delta``
(first order; equal to ``r``'s own coordinates to O(|r|) for the small
rotations of a mount). Jacobian rows per sample (6 x p):

    d/d(f_o, t_o) = I6,
    payload:  d/dm = [g; c x g],  d/dc = [0; -m [g]x],
    URDF:     d/dm_k = [g; p_k x g],  d/ds_k = [0; -[g]x R_k],
    d/ddelta  = [M [g]x; [S]x [g]x],
    d/dtilt_k = [M dg_k; S x dg_k]      (optional: a world tilt of the orientation stream, ``freeload``),

``dg_k = R_B,ft^T g R_WB^T du/dtilt_k`` at the tilt (``u = R_y(ty) R_x(tx) (0, 0, -1)``; at 0:
``du/dtx = (0, 1, 0)``, ``du/dty = (-1, 0, 0)``): given per sample as ``tilt_dirs`` (N, 3, 2). The two columns sit
between the load's and the mount's (``TILT_NAMES``), as in the estimator's parameter vector.

Noise: white readings ``diag(s_f^2 I3, s_t^2 I3)``; optionally an orientation
stream with white jitter of ``s_R`` rad per axis (errors in variables: the
recorded gravity is off by ``[g]x e``, e ~ N(0, s_R^2 I3)), which adds
``s_R^2 A_i A_i^T`` to sample i's covariance, ``A_i`` the ``delta`` rows above.

    F = sum_i J_i^T Sigma_i^-1 J_i,      Cov(theta_hat) >= F^-1.

For a known mounting (``mount=False``) and no jitter the model is linear in
``(f_o, t_o, m, m c)`` and the weighted least squares attains the bound; the
peers' unweighted LS (kth ft_calib) solves force and torque rows apart, which is
the same estimator when each block's channels share one noise level.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..core.geometry import rotvec_to_rotation, skew
from ..core.solver import REL_EIG_TOL
from .bound import LoadBound, named_bound

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
OFFSET_NAMES = tuple(f"offset_{c}" for c in WRENCH)
ROT_NAMES = ("mount_rx", "mount_ry", "mount_rz")
TILT_NAMES = ("tilt_rx", "tilt_ry")


def tilt_directions(R_WB: np.ndarray, g: float) -> np.ndarray:
    """``d g_B / d tilt`` (N, 3, 2) at no tilt, in B: ``g R_WB^T du/dtilt``; map to ft like gravity (linear)."""
    du = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 0.0]])
    return g * np.einsum("nkj,kt->njt", np.asarray(R_WB, float), du)


def _with_tilt(J: np.ndarray, tilt_dirs: np.ndarray | None, M: float, S: np.ndarray, mount: bool) -> np.ndarray:
    """``J`` with the tilt's columns ``[M dg; S x dg]`` inserted before the mount's (module docstring)."""
    if tilt_dirs is None:
        return J
    dg = np.asarray(tilt_dirs, float)
    S = np.broadcast_to(S, (len(J), 3))
    T = np.concatenate([M * dg, np.cross(S[:, :, None], dg, axis=1)], axis=1)
    at = J.shape[2] - (3 if mount else 0)
    return np.concatenate([J[:, :, :at], T, J[:, :, at:]], axis=2)


def reading_covariance(sigma: np.ndarray, A: np.ndarray | None = None, orientation_sd_rad: float = 0.0) -> np.ndarray:
    """Per-sample covariance (N, 6, 6) (or (6, 6) without jitter): ``diag(sigma^2) + s_R^2 A A^T``."""
    S = np.diag(np.asarray(sigma, float) ** 2)
    if not orientation_sd_rad or A is None:
        return S
    return S + orientation_sd_rad**2 * np.einsum("nik,njk->nij", A, A)


def _rotation_rows(g: np.ndarray, M: float, S: np.ndarray) -> np.ndarray:
    """``[M [g]x; [S]x [g]x]`` (N, 6, 3): the readings' derivative along a small rotation of ft (or of gravity)."""
    G = skew(g)
    return np.concatenate([M * G, skew(S) @ G], axis=1)


# ----------------------------------------------------------------------------- rigid payload


def payload_names(mount: bool = True, tilt: bool = False) -> tuple[str, ...]:
    return OFFSET_NAMES + ("mass_kg", "com_x", "com_y", "com_z") + (TILT_NAMES if tilt else ()) + (ROT_NAMES if mount else ())


def payload_jacobian(g_ft: np.ndarray, mass_kg: float, com_m: np.ndarray, mount: bool = True) -> np.ndarray:
    """``d w_i / d theta`` (N, 6, p), theta = (offset 6, mass, com 3[, mount rotation 3]); ``g_ft`` (N, 3) true ft."""
    g = np.asarray(g_ft, float)
    c = np.asarray(com_m, float)
    n = len(g)
    J = np.zeros((n, 6, 13 if mount else 10))
    J[:, :, :6] = np.eye(6)
    J[:, :3, 6] = g
    J[:, 3:, 6] = np.cross(c, g)
    J[:, 3:, 7:10] = -mass_kg * skew(g)
    if mount:
        J[:, :, 10:13] = _rotation_rows(g, mass_kg, mass_kg * np.broadcast_to(c, (n, 3)))
    return J


def payload_bound(g_ft: np.ndarray, mass_kg: float, com_m: np.ndarray, sigma: np.ndarray, *, mount: bool = True,
                  orientation_sd_rad: float = 0.0, offset: np.ndarray | None = None, rel_tol: float = REL_EIG_TOL,
                  tilt_dirs: np.ndarray | None = None) -> LoadBound:
    """The bound of a rigid payload for gravity ``g_ft`` (N, 3) in the true ft frame and reading noise ``sigma`` (6,);
    ``tilt_dirs`` (N, 3, 2) ``d g_ft / d tilt``: the world tilt of the orientation stream estimated too (at 0)."""
    g = np.asarray(g_ft, float)
    S = mass_kg * np.broadcast_to(np.asarray(com_m, float), g.shape)
    J = _with_tilt(payload_jacobian(g, mass_kg, com_m, mount), tilt_dirs, mass_kg, S, mount)
    A = _rotation_rows(g, mass_kg, S)
    tilt = tilt_dirs is not None
    theta = np.concatenate([np.zeros(6) if offset is None else offset, [mass_kg], com_m, np.zeros(2) if tilt else [],
                            np.zeros(3) if mount else []])
    return named_bound(J, reading_covariance(sigma, A, orientation_sd_rad), payload_names(mount, tilt), theta, rel_tol)


# ----------------------------------------------------------------------------- URDF load: joint groups


@dataclass(frozen=True)
class JointGroup:
    """Links moved together: ``name`` (the movable joint above them, or the sensor link for the links rigid
    with it), ``frame`` (the link whose frame the group's first moment is in), ``links`` (massive links)."""

    name: str
    frame: str
    links: tuple[str, ...]


def joint_groups(tree, ft_link: str) -> tuple[JointGroup, ...]:
    """The load of ``ft_link`` in ``tree`` (sim.free.kinematics.KinematicTree) grouped by the nearest movable
    joint on each massive link's path from the sensor; in tree order."""
    groups: dict[str, tuple[str, list[str]]] = {}
    for link in tree.below(ft_link):
        if link not in tree.bodies:
            continue
        movable = [j for j in tree.joints_between(ft_link, link) if j.type != "fixed"]
        key, frame = (movable[-1].name, movable[-1].child) if movable else (ft_link, ft_link)
        groups.setdefault(key, (frame, []))[1].append(link)
    return tuple(JointGroup(k, f, tuple(ls)) for k, (f, ls) in groups.items())


def group_truth(tree, groups: tuple[JointGroup, ...], bodies: Mapping[str, tuple[float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Masses (G,) and first moments (G, 3) kg m, each in its group's frame, from bodies' (mass, CoM in own link)."""
    masses, moments = [], []
    for grp in groups:
        m_k, s_k = 0.0, np.zeros(3)
        for link in grp.links:
            m, c = bodies[link]
            R, p = tree.pose(grp.frame, link, {}, 1)       # rigid within the group: any q
            m_k += float(m)
            s_k += float(m) * (p[0] + R[0] @ np.asarray(c, float))
        masses.append(m_k)
        moments.append(s_k)
    return np.array(masses), np.array(moments)


def group_poses(tree, ft_link: str, groups: tuple[JointGroup, ...], q: Mapping[str, np.ndarray], n: int):
    """Each group frame in ft for every sample: ``R`` (G, N, 3, 3), ``p`` (G, N, 3) (vectorised FK)."""
    poses = [tree.pose(ft_link, grp.frame, q, n) for grp in groups]
    return np.stack([R for R, _ in poses]), np.stack([p for _, p in poses])


def urdf_names(groups: tuple[JointGroup, ...], mount: bool = True, tilt: bool = False) -> tuple[str, ...]:
    names = list(OFFSET_NAMES)
    for grp in groups:
        names += [f"{grp.name}.mass_kg", f"{grp.name}.moment_x", f"{grp.name}.moment_y", f"{grp.name}.moment_z"]
    return tuple(names) + (TILT_NAMES if tilt else ()) + (ROT_NAMES if mount else ())


def urdf_first_moment(R: np.ndarray, p: np.ndarray, masses: np.ndarray, moments: np.ndarray) -> np.ndarray:
    """``S_i = sum_k (m_k p_k,i + R_k,i s_k)`` (N, 3), kg m, in ft."""
    return np.einsum("k,kni->ni", masses, p) + np.einsum("knij,kj->ni", R, moments)


def urdf_jacobian(g_ft: np.ndarray, R: np.ndarray, p: np.ndarray, masses: np.ndarray, moments: np.ndarray,
                  mount: bool = True) -> np.ndarray:
    """``d w_i / d theta`` (N, 6, 6 + 4G [+ 3]), theta = (offset 6, per group (m_k, s_k 3)[, mount rotation 3])."""
    g = np.asarray(g_ft, float)
    n, G = len(g), len(masses)
    J = np.zeros((n, 6, 6 + 4 * G + (3 if mount else 0)))
    J[:, :, :6] = np.eye(6)
    Gx = skew(g)
    for k in range(G):
        col = 6 + 4 * k
        J[:, :3, col] = g
        J[:, 3:, col] = np.cross(p[k], g)
        J[:, 3:, col + 1:col + 4] = -Gx @ R[k]
    if mount:
        J[:, :, -3:] = _rotation_rows(g, float(np.sum(masses)), urdf_first_moment(R, p, masses, moments))
    return J


def urdf_gravity_in_ft(tree, ft_link: str, q: Mapping[str, np.ndarray], g_B: np.ndarray,
                       mount_rotvec: np.ndarray = np.zeros(3)) -> np.ndarray:
    """Gravity (N, 3) in the TRUE ft frame of ``ft_link``: ``R_B,ft(q)^T g_B`` with the mounting rotation."""
    g_B = np.asarray(g_B, float)
    R_B_ft, _ = tree.pose(tree.root, ft_link, q, len(g_B), {ft_link: rotvec_to_rotation(np.asarray(mount_rotvec, float))})
    return np.einsum("nji,nj->ni", R_B_ft, g_B)


def urdf_bound(tree, ft_link: str, q: Mapping[str, np.ndarray], g_ft: np.ndarray, bodies: Mapping[str, tuple[float, np.ndarray]],
               sigma: np.ndarray, *, mount: bool = True, orientation_sd_rad: float = 0.0, offset: np.ndarray | None = None,
               rel_tol: float = REL_EIG_TOL, tilt_dirs: np.ndarray | None = None,
               group_theta: np.ndarray | None = None) -> tuple[LoadBound, tuple[JointGroup, ...]]:
    """The bound of the URDF load below ``ft_link`` for joint angles ``q`` (N,) each, gravity ``g_ft`` (N, 3) in
    the true ft frame and the true bodies ``{link: (mass, CoM in own link)}``; returns it and the groups.
    ``tilt_dirs`` (N, 3, 2) ``d g_ft / d tilt``: the world tilt estimated too (module docstring). ``group_theta``
    (G, 4): each group's mass and first moment (in its frame) instead of the bodies' (an estimate's)."""
    groups = joint_groups(tree, ft_link)
    if group_theta is None:
        masses, moments = group_truth(tree, groups, bodies)
    else:
        masses, moments = np.asarray(group_theta, float)[:, 0], np.asarray(group_theta, float)[:, 1:]
    g = np.asarray(g_ft, float)
    R, p = group_poses(tree, ft_link, groups, q, len(g))
    S = urdf_first_moment(R, p, masses, moments)
    J = _with_tilt(urdf_jacobian(g, R, p, masses, moments, mount), tilt_dirs, float(masses.sum()), S, mount)
    A = _rotation_rows(g, float(masses.sum()), S)
    tilt = tilt_dirs is not None
    theta = np.concatenate([np.zeros(6) if offset is None else offset,
                            np.column_stack([masses, moments]).ravel(), np.zeros(2) if tilt else [], np.zeros(3) if mount else []])
    return (named_bound(J, reading_covariance(sigma, A, orientation_sd_rad), urdf_names(groups, mount, tilt), theta, rel_tol),
            groups)


# ----------------------------------------------------------------------------- a simulated dataset's bound


def free_load_bound(res, *, mount: bool = True, held_only: bool = True, rel_tol: float = REL_EIG_TOL,
                    tilt: bool = False) -> LoadBound:
    """The bound of a ``sim.free.simulate_free`` result at its truth, from its held (quasi-static) samples, its
    reading noise and its orientation jitter (a URDF result: ``LoadBound`` of the joint groups); ``tilt``: the
    world tilt of the orientation stream estimated too (the simulation has none: the bound at 0)."""
    from ..sim.free import gravity_in_body, gravity_in_ft, load_tree, true_rotation
    from ..sim.free.simulate import rpy_to_rotation

    cfg, truth = res.config, res.truth
    sel = res.held if held_only else np.ones(len(res.held), bool)
    sigma = np.asarray(truth["noise"], float)
    jitter = np.radians(cfg.mocap_jitter_deg)
    rv = np.asarray(truth["mount_rotvec"], float)
    off = np.asarray(truth["offset"], float)
    dB = tilt_directions(res.R_WB[sel], cfg.g) if tilt else None
    if cfg.kind == "payload":
        R_true = true_rotation(rpy_to_rotation(cfg.rotation_rpy), rv)
        g_ft = gravity_in_ft(res.R_WB[sel], R_true, cfg.g)
        return payload_bound(g_ft, truth["mass_kg"], np.asarray(truth["com_m"]), sigma, mount=mount,
                             orientation_sd_rad=jitter, offset=off, rel_tol=rel_tol,
                             tilt_dirs=None if dB is None else np.einsum("ji,njt->nit", R_true, dB))
    tree = load_tree(cfg.urdf_path)
    q = {j: np.asarray(v)[sel] for j, v in res.q.items()}
    g_ft = urdf_gravity_in_ft(tree, cfg.ft_link, q, gravity_in_body(res.R_WB[sel], cfg.g), rv)
    bodies = {l: (b["mass_kg"], np.asarray(b["com_m"])) for l, b in truth["bodies"].items()}
    dg = None if dB is None else np.stack([urdf_gravity_in_ft(tree, cfg.ft_link, q, dB[:, :, k], rv) for k in range(2)], axis=2)
    return urdf_bound(tree, cfg.ft_link, q, g_ft, bodies, sigma, mount=mount, orientation_sd_rad=jitter, offset=off,
                      rel_tol=rel_tol, tilt_dirs=dg)[0]
