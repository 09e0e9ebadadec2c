"""Robot description: legs, nominal transducer poses, masses (``robot.toml``).

Frames follow ``shared/DATA_FORMAT.md`` section 1: ``B`` is the body frame at the
chassis' geometric centre; ``ft_k`` the k-th transducer frame, whose nominal pose
in B is ``T_ftk^B = (rotation, position_m)`` (report eq. 2, step 1).

Section 5: a robot may name a URDF (``urdf``, parsed into ``tree``, a
:class:`~ftcal_nlp.core.kinematics.KinematicTree` whose root link is B) and a
transducer its sensor ``link``; its nominal pose in B is then the URDF's, for
each sample's joint angles (``position_m`` / ``rotation`` may be None), and its
load is every link below ``link``. ``mass_kg`` is None when the robot.toml has
none (allowed without standing or walking recordings).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Transducer:
    """Nominal pose of one transducer in B: ``rotation`` (3x3, ft_k -> B) and
    ``position_m`` (3,), the origin of ft_k in B, metres."""

    leg: str
    position_m: np.ndarray | None
    rotation: np.ndarray | None
    model: str | None = None
    link: str | None = None          # the URDF link whose frame is ft_k (section 5)
    load_mass_kg: float | None = None   # the load's mass as weighed (section 5): a measurement, not a guess

    def given_rotation(self) -> np.ndarray:
        """``rotation``, which robot.toml gives for every transducer without a URDF ``link`` (hexapod legs, payloads)."""
        if self.rotation is None:
            raise _no_pose(self, "rotation")
        return self.rotation

    def given_position(self) -> np.ndarray:
        """``position_m``, which robot.toml gives for every transducer without a URDF ``link``."""
        if self.position_m is None:
            raise _no_pose(self, "position_m")
        return self.position_m


def _no_pose(t: Transducer, key: str) -> Exception:
    from .errors import DataFormatError

    return DataFormatError(f"robot.toml [transducers.{t.leg}]: no '{key}'; its nominal pose is the URDF link "
                           f"'{t.link}' per sample, and this step needs one fixed pose", column=key)


@dataclass(frozen=True)
class Robot:
    """A legged robot with one six-axis transducer per leg.

    ``mass_kg`` is the weighed total (legs included); ``legs`` gives the column
    order of every recording; ``leg_mass_kg`` is an optional nominal per-leg
    mass, used only as a starting guess.
    """

    name: str
    mass_kg: float | None
    g: float
    legs: tuple[str, ...]
    transducers: dict[str, Transducer]
    leg_mass_kg: dict[str, float] | None = field(default=None)
    urdf: Path | None = None         # the URDF file (section 5)
    tree: Any = None                 # its parsed kinematics.KinematicTree

    @property
    def weight_N(self) -> float:
        if self.mass_kg is None:
            from .errors import DataFormatError

            raise DataFormatError(f"robot '{self.name}': key 'mass_kg' missing from robot.toml; it is needed with standing "
                                  "or walking recordings", column="mass_kg")
        return self.mass_kg * self.g

    @property
    def n_legs(self) -> int:
        return len(self.legs)

    def nominal_rotations(self) -> np.ndarray:
        """Nominal ``R_ftk^B`` stacked in leg order, shape (K, 3, 3)."""
        return np.stack([self.transducers[k].given_rotation() for k in self.legs])

    def nominal_positions(self) -> np.ndarray:
        """Nominal transducer origins in B stacked in leg order, shape (K, 3), m."""
        return np.stack([self.transducers[k].given_position() for k in self.legs])

    def to_toml_dict(self) -> dict:
        out: dict = {"name": self.name}
        if self.mass_kg is not None:
            out["mass_kg"] = float(self.mass_kg)
        out.update({"g": float(self.g), "legs": list(self.legs)})
        if self.urdf is not None:
            out["urdf"] = self.urdf.name
        if self.leg_mass_kg is not None:
            out["leg_mass_kg"] = {k: float(v) for k, v in self.leg_mass_kg.items()}
        out["transducers"] = {}
        for k in self.legs:
            t = self.transducers[k]
            d: dict = {}
            if t.position_m is not None:
                d["position_m"] = [float(x) for x in t.position_m]
            if t.rotation is not None:
                d["rotation"] = [[float(x) for x in r] for r in t.rotation]
            if t.link is not None:
                d["link"] = t.link
            if t.model is not None:
                d["model"] = t.model
            if t.load_mass_kg is not None:
                d["load_mass_kg"] = float(t.load_mass_kg)
            out["transducers"][k] = d
        return out
