"""A rigid payload on a wrist transducer (a tool, a gripper): mass ``m`` and first moment ``h = m c``.

``theta = [m, h_x, h_y, h_z]`` (kg, kg m), ``c`` the CoM in ft (m). Reading
(``loads.base``): ``f = m g_ft + f_o``, ``t = h x g_ft + t_o``: linear in
``theta``, ``mu = [1, 0, 0, 0]``, ``K = [0 | I]`` for every sample. The nominal
ft orientation in B is the ``rotation`` of ``robot.toml`` (constant). What
kth ``ft_calib`` and Robotlib ``calibForce`` estimate (``peers.py``), here with
the mounting rotation and standard errors.

On an arm whose URDF leaves the tool out (``DATA_FORMAT.md`` section 5: no
``<inertial>`` below the sensor link), the payload is the same four parameters
but its nominal orientation comes from the joints: built with ``tree`` and
``ft_link``, ``R_nom(q)`` is the URDF's pose of the sensor link for each sample's
joint angles (``base_joints``, the movable joints above it), as a URDF load's
(``loads.urdf_subtree``); the lever stays ``[0 | I]`` (the tool is fixed to the
sensor). There is no prior: mass and CoM come from the readings alone.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from .base import LinearLoad, se_of


class RigidPayload(LinearLoad):
    """A rigid payload (module docstring). ``rotation``: nominal ``R_B,ft`` (3, 3)."""

    name = "rigid_payload"
    kind = "rigid_payload"

    load_joints: tuple[str, ...] = ()

    def __init__(self, rotation: np.ndarray | None = None, prior: np.ndarray | None = None, *, tree=None,
                 ft_link: str | None = None):
        if (tree is None) != (ft_link is None):
            raise ValueError("RigidPayload: give both tree and ft_link (a payload oriented through the URDF) or neither")
        self.rotation = np.eye(3) if rotation is None else np.asarray(rotation, float)
        self._prior = prior
        self.tree, self.ft_link = tree, ft_link
        if tree is not None:
            from ..core.kinematics import MOVABLE

            self.base_joints = tuple(j.name for j in tree.path_to_root(ft_link) if j.type in MOVABLE)
        else:
            self.base_joints = ()

    @property
    def through_urdf(self) -> bool:
        """Whether the nominal orientation comes from the joints through the URDF (an arm's tool)."""
        return self.tree is not None

    @property
    def param_names(self) -> tuple[str, ...]:
        return ("mass_kg", "h_x", "h_y", "h_z")

    @property
    def mass_row(self) -> np.ndarray:
        return np.array([1.0, 0.0, 0.0, 0.0])

    def lever(self, q: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        K = np.zeros((3, 4))
        K[:, 1:] = np.eye(3)
        return np.broadcast_to(K, (n, 3, 4))

    def varying(self) -> bool:
        return False

    def nominal_rotation(self, q: Mapping[str, np.ndarray], n: int) -> np.ndarray:
        if self.tree is not None:
            return self.tree.pose(self.tree.root, self.ft_link, q, n)[0]
        return np.broadcast_to(self.rotation, (n, 3, 3))

    def prior(self) -> np.ndarray | None:
        return self._prior

    def symbolic_lever(self, theta: np.ndarray, q: dict):
        """The first moment ``h`` (3,) as a CasADi constant (fixed to the sensor: ``q`` unused), what ``export``
        compiles."""
        import casadi as ca

        return ca.DM(self.lever({}, 1)[0] @ theta)

    def description(self) -> str:
        if self.tree is None:
            return "rigid payload"
        return f"rigid payload oriented by the joints through {self.ft_link}"

    def com(self, theta: np.ndarray, cov: np.ndarray, null: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """CoM ``c = h / m`` (m, in the true ft frame) and its se (delta method)."""
        m, h = theta[0], theta[1:]
        J = np.zeros((3, 4))
        J[:, 0] = -h / m**2
        J[:, 1:] = np.eye(3) / m
        return h / m, se_of(cov, J, null)

    def report(self, theta: np.ndarray, cov: np.ndarray, null: np.ndarray | None = None) -> dict:
        c, c_se = self.com(theta, cov, null)
        return {"load_kind": self.kind, "load_mass_kg": float(theta[0]), "load_mass_se_kg": float(se_of(cov, np.eye(4)[:1], null)[0]),
                "load_com_m": c.tolist(), "load_com_se_m": c_se.tolist()}
