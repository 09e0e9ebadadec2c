"""The links below a sensor in a URDF tree, grouped by the joints that move them.

Links joined by fixed joints move together, so the readings see only their
sum: a **group** is the set of massive links whose nearest movable joint above
them (below the sensor link) is the same, with the frame of that joint's child
link (links fixed to the sensor itself form a group in the ft frame). Per group
``G``: mass ``M_G`` and first moment ``H_G = sum_i m_i (p_i + R_i c_i)`` in the
group frame (``c_i`` each link's CoM in its own frame, ``(R_i, p_i)`` the link in
the group frame). With the group frame at ``(R_G(q), p_G(q))`` in ft (the
URDF's kinematics, ``ftcal_nlp.core.kinematics``), the load's first moment about the
ft origin is

    s(q) = sum_G  M_G p_G(q) + R_G(q) H_G,

linear in ``theta = [M_G, H_G]_G`` (4 per group): ``K = [p_G | R_G]_G`` and
``mu = [1, 0, 0, 0]_G`` (``loads.base``). The URDF's masses and CoMs give the
starting point and the weak prior of what the data leave undetermined (never
the answer: every determined combination comes from the readings). The nominal
ft orientation in B is the URDF's for each sample's joint angles above the sensor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np

from ..core.errors import DataFormatError
from ..core.kinematics import MOVABLE, KinematicTree
from .base import LinearLoad, se_of


@dataclass(frozen=True)
class Group:
    """Massive links moved by one joint: ``name`` (the joint, or ``"fixed"``), ``frame`` (its child link, or the
    sensor link), ``links`` (massive links in it), ``joint`` (None for the group fixed to the sensor)."""

    name: str
    frame: str
    links: tuple[str, ...]
    joint: str | None


def groups_below(tree: KinematicTree, ft_link: str) -> tuple[Group, ...]:
    """The groups of the massive links below ``ft_link`` (module docstring), in URDF link order."""
    by_frame: dict[str, list[str]] = {}
    joint_of: dict[str, str | None] = {}
    for link in tree.below(ft_link):
        if link not in tree.bodies:
            continue
        moving = [j for j in tree.joints_between(ft_link, link) if j.type in MOVABLE]
        frame = moving[-1].child if moving else ft_link
        by_frame.setdefault(frame, []).append(link)
        joint_of[frame] = moving[-1].name if moving else None
    return tuple(Group(joint_of[f] or "fixed", f, tuple(ls), joint_of[f]) for f, ls in by_frame.items())


def _skew(a: np.ndarray):
    return ca.DM([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _joint(j, q):
    """``T_child^parent(q)`` of URDF joint ``j`` as ``(R, p)`` (CasADi), ``kinematics.joint_transform``."""
    R0, p0 = ca.DM(j.origin[:3, :3]), ca.DM(j.origin[:3, 3])
    if j.type == "fixed" or q is None:
        return R0, p0
    if j.type == "prismatic":
        return R0, p0 + ca.mtimes(R0, q * ca.DM(j.axis))
    if j.type in ("revolute", "continuous"):
        A = _skew(j.axis)
        return ca.mtimes(R0, ca.DM.eye(3) + ca.sin(q) * A + (1 - ca.cos(q)) * ca.mtimes(A, A)), p0
    raise DataFormatError(f"joint '{j.name}': type '{j.type}' is not supported (fixed, revolute, continuous, prismatic)")


def symbolic_pose(tree, ref: str, link: str, q: dict):
    """Pose of ``link`` in ``ref`` (``ref`` above ``link`` in the tree): ``R`` (3, 3), ``p`` (3,), CasADi
    (``KinematicTree.pose`` for one symbolic sample; joints without an entry held at 0): what ``export`` compiles."""
    R, p = ca.DM.eye(3), ca.DM.zeros(3)
    for j in tree.joints_between(ref, link):
        Rj, pj = _joint(j, q.get(j.name))
        p = p + ca.mtimes(R, pj)
        R = ca.mtimes(R, Rj)
    return R, p



class UrdfSubtree(LinearLoad):
    """The URDF links below ``ft_link`` (module docstring)."""

    name = "urdf_subtree"
    kind = "urdf_subtree"

    def __init__(self, tree: KinematicTree, ft_link: str):
        self.tree, self.ft_link = tree, ft_link
        self.groups = groups_below(tree, ft_link)
        if not self.groups:
            raise ValueError(f"URDF {tree.name!r}: no link with mass below '{ft_link}'")
        # joints that move the load relative to ft, and those that move ft in B
        self.load_joints = tuple(sorted({j.name for l in tree.below(ft_link) for j in tree.joints_between(ft_link, l) if j.type in MOVABLE}))
        self.base_joints = tuple(j.name for j in tree.path_to_root(ft_link) if j.type in MOVABLE)

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(f"{g.name}.{c}" for g in self.groups for c in ("mass_kg", "h_x", "h_y", "h_z"))

    @property
    def mass_row(self) -> np.ndarray:
        return np.tile([1.0, 0.0, 0.0, 0.0], len(self.groups))

    def _link_in_group(self, g: Group, link: str) -> tuple[np.ndarray, np.ndarray]:
        R, p = self.tree.pose(g.frame, link, {}, 1)   # fixed joints only between them
        return R[0], p[0]

    def lever(self, q: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        K = np.zeros((n, 3, 4 * len(self.groups)))
        for i, g in enumerate(self.groups):
            if g.frame == self.ft_link:
                K[:, :, 4 * i + 1: 4 * i + 4] = np.eye(3)
                continue
            R, p = self.tree.pose(self.ft_link, g.frame, q, n)
            K[:, :, 4 * i] = p
            K[:, :, 4 * i + 1: 4 * i + 4] = R
        return K

    def nominal_rotation(self, q: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        return self.tree.pose(self.tree.root, self.ft_link, q, n)[0]

    def symbolic_lever(self, theta: np.ndarray, q: dict) -> ca.MX | ca.DM:
        """``s(q) = sum_G M_G p_G(q) + R_G(q) H_G`` (3,) for joint angles ``q`` (CasADi symbols by joint; what
        :meth:`lever` gives numerically, :func:`symbolic_pose`), ``theta`` fixed: what ``export`` compiles."""
        s: ca.MX | ca.DM = ca.DM.zeros(3)   # a constant until a group moves with the joints
        for gi, grp in enumerate(self.groups):
            M_G, H_G = float(theta[4 * gi]), ca.DM(theta[4 * gi + 1: 4 * gi + 4])
            if grp.frame == self.ft_link:
                s = s + H_G
                continue
            R_G, p_G = symbolic_pose(self.tree, self.ft_link, grp.frame, q)
            s = s + M_G * p_G + ca.mtimes(R_G, H_G)
        return s

    def description(self) -> str:
        return f"URDF links below {self.ft_link}"

    def prior(self) -> np.ndarray:
        """The URDF's nominal ``[M_G, H_G]`` per group."""
        out = []
        for g in self.groups:
            M, H = 0.0, np.zeros(3)
            for link in g.links:
                b = self.tree.bodies[link]
                R, p = self._link_in_group(g, link)
                M += b.mass_kg
                H += b.mass_kg * (p + R @ b.com_m)
            out += [M, *H]
        return np.array(out)

    def report(self, theta: np.ndarray, cov: np.ndarray, null: np.ndarray | None = None) -> dict:
        """Total mass, and per group its mass, first moment and CoM (group frame) with se; a group of one link
        also as that link's mass and CoM in its own frame (``links``), with the URDF's nominal beside them."""
        p = len(theta)
        mass = float(self.mass_row @ theta)
        groups, links = {}, {}
        for i, g in enumerate(self.groups):
            sl = slice(4 * i, 4 * i + 4)
            M, H = theta[4 * i], theta[4 * i + 1: 4 * i + 4]
            Jc = np.zeros((3, p))
            Jc[:, 4 * i] = -H / M**2
            Jc[:, 4 * i + 1: 4 * i + 4] = np.eye(3) / M
            c, c_se = H / M, se_of(cov, Jc, null)
            se = se_of(cov, np.eye(p)[sl], null)
            groups[g.name] = {"frame": g.frame, "links": list(g.links), "mass_kg": float(M), "mass_se_kg": float(se[0]),
                              "first_moment_kgm": H.tolist(), "first_moment_se_kgm": se[1:].tolist(),
                              "com_m": c.tolist(), "com_se_m": c_se.tolist()}
            if len(g.links) == 1:
                (link,) = g.links
                R, pp = self._link_in_group(g, link)   # CoM in the link's own frame: R^T (c - p)
                b = self.tree.bodies[link]
                links[link] = {"mass_kg": float(M), "mass_se_kg": float(se[0]), "com_m": (R.T @ (c - pp)).tolist(),
                               "com_se_m": se_of(cov, R.T @ Jc, null).tolist(), "group": g.name,
                               "nominal_mass_kg": b.mass_kg, "nominal_com_m": b.com_m.tolist()}
        return {"load_kind": self.kind, "load_mass_kg": mass, "load_mass_se_kg": float(se_of(cov, self.mass_row, null)[0]),
                "urdf_groups": groups, "urdf_links": links}
