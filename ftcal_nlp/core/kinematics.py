"""Forward kinematics of a URDF tree, vectorised over samples (numpy; the tree parsed by ``yourdfpy``).

A URDF joint's ``<origin>`` is the pose of its child link's frame in its parent
link's frame at zero joint position; the joint then moves the child about
(revolute, continuous) or along (prismatic) ``axis``, expressed in the joint
frame (= the child frame):

    T_child^parent(q) = T_origin @ [exp(q [axis]x), 0; 0, 1]        (revolute)
    T_child^parent(q) = T_origin @ [I, q axis; 0, 1]                 (prismatic)

Shared by the free-load simulator (``sim/free``) and the free-load estimator
(``freeload``, ``loads``): one implementation, no copy.

Poses of links relative to any other link of the tree follow by composing these
along the tree path (``pose(ref, link, q)``: ``R`` (N, 3, 3) maps ``link``
vectors to ``ref`` vectors, ``p`` (N, 3) m the origin of ``link`` in ``ref``).
An inertial's ``origin xyz`` is the body's CoM in its own link frame (its
``rpy`` only orients the inertia tensor, which statics never needs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from .errors import DataFormatError
from .geometry import rotvec_to_rotation

MOVABLE = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class Joint:
    """One URDF joint: ``origin`` (4, 4) child frame in parent frame at q = 0; ``axis`` (3,) unit, joint frame."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float | None = None
    upper: float | None = None


@dataclass(frozen=True)
class Body:
    """A link's nominal inertial: ``mass_kg``, ``com_m`` (3,) in the link's own frame and ``inertia`` (3, 3),
    kg m^2, about the CoM in the link's axes (the URDF's ``<inertia>`` turned by the inertial ``rpy``)."""

    mass_kg: float
    com_m: np.ndarray
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))


@dataclass(frozen=True)
class KinematicTree:
    """The joints (by child link) and the links with mass of a URDF; ``root`` is the link of frame B."""

    name: str
    root: str
    joints: Mapping[str, Joint]      # child link -> the joint that carries it
    bodies: Mapping[str, Body]       # links with an <inertial> of positive mass
    links: tuple[str, ...]

    @property
    def movable(self) -> tuple[str, ...]:
        """Names of the movable joints, in file order."""
        return tuple(j.name for j in self.joints.values() if j.type in MOVABLE)

    def joint(self, name: str) -> Joint:
        for j in self.joints.values():
            if j.name == name:
                return j
        raise KeyError(f"URDF '{self.name}' has no joint '{name}' (joints: {[j.name for j in self.joints.values()]})")

    def path_to_root(self, link: str) -> list[Joint]:
        """Joints from ``link`` up to the root, nearest first."""
        if link not in self.links:
            raise KeyError(f"URDF '{self.name}' has no link '{link}' (links: {list(self.links)})")
        out = []
        while link in self.joints:
            out.append(self.joints[link])
            link = out[-1].parent
        return out

    def below(self, link: str) -> tuple[str, ...]:
        """Every link strictly below ``link`` in the tree (its load, when ``link`` is a sensor's)."""
        return tuple(l for l in self.links if l != link and any(j.parent == link for j in self.path_to_root(l)))

    def joints_between(self, upper: str, lower: str) -> list[Joint]:
        """Joints on the path from ``upper`` down to ``lower`` (``upper`` must be an ancestor), top first."""
        path = self.path_to_root(lower)
        idx = next((i for i, j in enumerate(path) if j.parent == upper), None)
        if lower == upper:
            return []
        if idx is None:
            raise ValueError(f"link '{upper}' is not above '{lower}' in URDF '{self.name}'")
        return list(reversed(path[: idx + 1]))

    def pose(self, ref: str, link: str, q: Mapping[str, np.ndarray], n: int,
             extra: Mapping[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Pose of ``link`` in ``ref`` for each of ``n`` samples: ``R`` (n, 3, 3), ``p`` (n, 3).

        ``q[joint]`` (n,) rad or m; a movable joint without an entry is held at 0.
        ``extra[child link]`` (3, 3): a rotation appended to that child's joint
        (``T_child^parent = T_joint(q) @ [extra, 0; 0, 1]``), e.g. a sensor's true
        mounting rotation relative to its nominal fixed joint.
        ``ref`` must lie on the path from the root to ``link`` or be the root.
        """
        up = self.path_to_root(link)
        chain_links = [link] + [j.parent for j in up]
        if ref not in chain_links:
            R_l, p_l = self.pose(self.root, link, q, n, extra)
            R_r, p_r = self.pose(self.root, ref, q, n, extra)
            R = np.einsum("nji,njk->nik", R_r, R_l)
            return R, np.einsum("nji,nj->ni", R_r, p_l - p_r)
        R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        p = np.zeros((n, 3))
        for j in self.joints_between(ref, link):
            Rj, pj = joint_transform(j, q.get(j.name), n)
            if extra is not None and j.child in extra:
                Rj = Rj @ extra[j.child]
            p = p + np.einsum("nij,nj->ni", R, pj)
            R = R @ Rj
        return R, p


def joint_transform(j: Joint, q: np.ndarray | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``T_child^parent(q)`` of joint ``j`` as ``R`` (n, 3, 3), ``p`` (n, 3)."""
    R0, p0 = j.origin[:3, :3], j.origin[:3, 3]
    if j.type == "fixed" or q is None:
        return np.broadcast_to(R0, (n, 3, 3)).copy(), np.broadcast_to(p0, (n, 3)).copy()
    q = np.broadcast_to(np.asarray(q, dtype=float), (n,))
    if j.type == "prismatic":
        return np.broadcast_to(R0, (n, 3, 3)).copy(), p0 + (q[:, None] * j.axis) @ R0.T
    if j.type in ("revolute", "continuous"):
        return R0 @ rotvec_to_rotation(q[:, None] * j.axis), np.broadcast_to(p0, (n, 3)).copy()
    raise ValueError(f"joint '{j.name}': type '{j.type}' is not supported (fixed, revolute, continuous, prismatic)")


def load_urdf(path: str | Path):
    """Parse a URDF without building scene graphs or loading meshes."""
    import yourdfpy

    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: URDF file not found")
    try:
        return yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False, build_collision_scene_graph=False)
    except Exception as exc:  # lxml and yourdfpy raise many types for a broken file
        raise DataFormatError(f"{path}: cannot parse as URDF ({type(exc).__name__}: {exc})") from exc


def load_tree(path: str | Path) -> KinematicTree:
    """Parse a URDF file into a :class:`KinematicTree` (no meshes, no scene graph)."""

    u = load_urdf(path)
    joints = {}
    for j in u.robot.joints:
        if j.type not in MOVABLE + ("fixed",):
            raise DataFormatError(f"{path}: joint '{j.name}' of type '{j.type}' is not supported")
        if j.mimic is not None:
            raise DataFormatError(f"{path}: joint '{j.name}' mimics another joint; mimic joints are not supported")
        axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=float)
        lim = j.limit
        joints[j.child] = Joint(j.name, j.type, j.parent, j.child,
                                np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float),
                                axis / np.linalg.norm(axis),
                                None if lim is None or lim.lower is None else float(lim.lower),
                                None if lim is None or lim.upper is None else float(lim.upper))
    links = tuple(l.name for l in u.robot.links)
    roots = [l for l in links if l not in joints]
    if len(roots) != 1:
        raise DataFormatError(f"{path}: a URDF tree has one root link, found {roots}")
    bodies = {}
    for l in u.robot.links:
        if l.inertial is not None and l.inertial.mass is not None and l.inertial.mass > 0:
            org = np.eye(4) if l.inertial.origin is None else np.asarray(l.inertial.origin, dtype=float)
            I = np.zeros((3, 3)) if l.inertial.inertia is None else np.asarray(l.inertial.inertia, dtype=float)
            bodies[l.name] = Body(float(l.inertial.mass), org[:3, 3].copy(), org[:3, :3] @ I @ org[:3, :3].T)
    return KinematicTree(u.robot.name or Path(path).stem, roots[0], joints, bodies, links)
