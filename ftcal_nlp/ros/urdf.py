"""Nominal transducer poses from a URDF (``yourdfpy``) -> :class:`~ftcal_nlp.core.robot.Robot`.

A URDF joint's ``<origin>`` is the pose of its child link's frame in its parent
link's frame, ``T_child^parent = (R, p)``. The nominal pose of ``ft_k`` in
``B`` (report eq. 2, step 1; ``rotation`` and ``position_m`` of ``robot.toml``)
is the product of the joint origins along the tree path from the link of ``B``
(``base_link``) to the transducer link:

    T_ftk^B = (T_anc^B)^-1 T_ftk^anc,   T_x^anc = prod of origins from anc down to x,

with ``anc`` their lowest common ancestor. Only ``fixed`` joints may lie on
that path: a movable joint there means the "nominal pose" depends on a joint
angle, which is an error in the map (wrong link named), not something to
evaluate at zero.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..core.errors import DataFormatError
from ..core.kinematics import load_urdf  # noqa: F401  (the one URDF parser; re-exported for the ROS modules)
from ..core.geometry import is_rotation
from ..core.robot import Robot, Transducer


def _parent_joints(urdf) -> dict[str, object]:
    """Child link name -> the joint that carries it."""
    return {j.child: j for j in urdf.robot.joints}


def _path_to_root(link: str, parent_of: dict) -> list:
    """Joints from ``link`` up to the root, nearest first."""
    joints, seen = [], {link}
    while link in parent_of:
        j = parent_of[link]
        joints.append(j)
        link = j.parent
        if link in seen:
            raise DataFormatError(f"URDF has a kinematic loop through link '{link}'")
        seen.add(link)
    return joints


def _origin(j) -> np.ndarray:
    return np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)


def fixed_pose(urdf, base_link: str, link: str, *, key: str = "link", source: str = "URDF") -> tuple[np.ndarray, np.ndarray]:
    """Pose ``(R, p)`` of ``link``'s frame in ``base_link``'s frame through fixed joints only.

    ``R`` (3, 3) maps ``link`` vectors to ``base_link`` vectors, ``p`` (3,) m is
    the origin of ``link`` in ``base_link``. ``key`` names the map entry that
    asked for ``link`` in error messages.
    """
    links = set(urdf.link_map)
    for name, k in ((base_link, "base_link"), (link, key)):
        if name not in links:
            near = sorted(links)
            raise DataFormatError(f"{source}: {k} = '{name}' is not a link of the URDF (links: {near[:40]}{' ...' if len(near) > 40 else ''})")
    parent_of = _parent_joints(urdf)
    up_link = _path_to_root(link, parent_of)
    up_base = _path_to_root(base_link, parent_of)
    anc_of_link = [link] + [j.parent for j in up_link]
    anc_of_base = [base_link] + [j.parent for j in up_base]
    common = next((a for a in anc_of_link if a in set(anc_of_base)), None)
    if common is None:
        raise DataFormatError(f"{source}: {key} = '{link}' and base_link = '{base_link}' are not in one kinematic tree")
    seg_link = up_link[: anc_of_link.index(common)]
    seg_base = up_base[: anc_of_base.index(common)]
    for j in seg_link + seg_base:
        if j.type != "fixed":
            raise DataFormatError(
                f"{source}: {key} = '{link}': joint '{j.name}' ({j.type}) lies between base_link '{base_link}' and '{link}'; "
                "a transducer's nominal pose must follow from fixed joints only (is the right link named?)"
            )
    T_link = np.eye(4)
    for j in reversed(seg_link):
        T_link = T_link @ _origin(j)
    T_base = np.eye(4)
    for j in reversed(seg_base):
        T_base = T_base @ _origin(j)
    T = np.linalg.solve(T_base, T_link)
    R, p = T[:3, :3], T[:3, 3]
    if not is_rotation(R, tol=1e-6):
        raise DataFormatError(f"{source}: {key} = '{link}': the chain from '{base_link}' is not a proper rigid transform")
    return R, p


def robot_from_urdf(
    path: str | Path,
    *,
    base_link: str,
    transducer_links: Mapping[str, str],
    legs: Sequence[str],
    mass_kg: float,
    g: float,
    name: str | None = None,
    leg_mass_kg: Mapping[str, float] | None = None,
) -> Robot:
    """A :class:`Robot` whose nominal transducer poses come from the URDF.

    ``transducer_links[leg]`` is the URDF link whose frame is ``ft_leg``;
    ``base_link`` the link whose frame is ``B``. Masses are the map's (the
    weighed total), not the URDF's inertials.
    """
    urdf = load_urdf(path)
    transducers = {}
    for k in legs:
        if k not in transducer_links:
            raise DataFormatError(f"{path}: [transducer_links] has no entry for leg '{k}'")
        R, p = fixed_pose(urdf, base_link, transducer_links[k], key=f"[transducer_links] {k}", source=str(path))
        transducers[k] = Transducer(k, p, R, None)
    return Robot(
        name or urdf.robot.name or Path(path).stem,
        float(mass_kg),
        float(g),
        tuple(legs),
        transducers,
        None if leg_mass_kg is None else {k: float(v) for k, v in leg_mass_kg.items()},
    )


def urdf_text(robot: Robot, *, base_link: str = "base_link", shaft_joint: str = "{leg}_shaft") -> str:
    """A URDF of ``robot``'s nominal transducer poses (the inverse of :func:`robot_from_urdf`).

    Links ``base_link`` (frame B), ``ft_{leg}`` (frame ft_leg, a fixed joint
    ``ft_{leg}_mount`` from B with ``origin xyz = position_m``, ``rpy`` of
    ``rotation``) and ``leg_{leg}`` on a continuous joint ``shaft_joint`` about
    the transducer's y axis. No inertials: masses come from the map.
    """
    from scipy.spatial.transform import Rotation

    def origin(p, R) -> str:
        # URDF rpy: R = Rz(yaw) Ry(pitch) Rx(roll), scipy's extrinsic "xyz"
        rpy = Rotation.from_matrix(R).as_euler("xyz")
        return f'<origin xyz="{" ".join(repr(float(x)) for x in p)}" rpy="{" ".join(repr(float(x)) for x in rpy)}"/>'

    parts = [f'<?xml version="1.0"?>\n<robot name="{robot.name}">', f'  <link name="{base_link}"/>']
    for k in robot.legs:
        tr = robot.transducers[k]
        parts += [
            f'  <link name="ft_{k}"/>',
            f'  <link name="leg_{k}"/>',
            f'  <joint name="ft_{k}_mount" type="fixed"><parent link="{base_link}"/><child link="ft_{k}"/>{origin(tr.position_m, tr.rotation)}</joint>',
            f'  <joint name="{shaft_joint.format(leg=k)}" type="continuous"><parent link="ft_{k}"/><child link="leg_{k}"/>'
            '<origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/></joint>',
        ]
    return "\n".join(parts + ["</robot>", ""])
