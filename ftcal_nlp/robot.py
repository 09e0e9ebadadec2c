"""Robot description: legs, nominal transducer poses, masses (``robot.toml``).

Frames follow ``shared/DATA_FORMAT.md`` section 1: ``B`` is the body frame at the
chassis' geometric centre; ``ft_k`` the k-th transducer frame, whose nominal pose
in B is ``T_ftk^B = (rotation, position_m)`` (report eq. 2, step 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Transducer:
    """Nominal pose of one transducer in B: ``rotation`` (3x3, ft_k -> B) and
    ``position_m`` (3,), the origin of ft_k in B, metres."""

    leg: str
    position_m: np.ndarray
    rotation: np.ndarray
    model: str | None = None


@dataclass(frozen=True)
class Robot:
    """A legged robot with one six-axis transducer per leg.

    ``mass_kg`` is the weighed total (legs included); ``legs`` gives the column
    order of every recording; ``leg_mass_kg`` is an optional nominal per-leg
    mass, used only as a starting guess.
    """

    name: str
    mass_kg: float
    g: float
    legs: tuple[str, ...]
    transducers: dict[str, Transducer]
    leg_mass_kg: dict[str, float] | None = field(default=None)

    @property
    def weight_N(self) -> float:
        return self.mass_kg * self.g

    @property
    def n_legs(self) -> int:
        return len(self.legs)

    def nominal_rotations(self) -> np.ndarray:
        """Nominal ``R_ftk^B`` stacked in leg order, shape (K, 3, 3)."""
        return np.stack([self.transducers[k].rotation for k in self.legs])

    def nominal_positions(self) -> np.ndarray:
        """Nominal transducer origins in B stacked in leg order, shape (K, 3), m."""
        return np.stack([self.transducers[k].position_m for k in self.legs])

    def to_toml_dict(self) -> dict:
        out: dict = {"name": self.name, "mass_kg": float(self.mass_kg), "g": float(self.g), "legs": list(self.legs)}
        if self.leg_mass_kg is not None:
            out["leg_mass_kg"] = {k: float(v) for k, v in self.leg_mass_kg.items()}
        out["transducers"] = {}
        for k in self.legs:
            t = self.transducers[k]
            d = {"position_m": [float(x) for x in t.position_m], "rotation": [[float(x) for x in r] for r in t.rotation]}
            if t.model is not None:
                d["model"] = t.model
            out["transducers"][k] = d
        return out
