"""The truth beside a simulated dataset (``truth.json``), read for the run's report, the benches and the tests.

Two layouts, told apart by the file itself:

* the hexapod's (``sim/writer.py``, ``shared/sample/truth.json``): a calibration in the
  ``calibration.json`` layout, read by :meth:`Calibration.load`;
* a free load's (``sim/free``, ``shared/sample_payload``, ``shared/sample_urdf``): ``offset``
  ``[fx..tz]`` and per-channel ``noise``; a payload's ``mass_kg`` and ``com_m`` (true ft frame), a URDF
  load's ``load_mass_kg`` and ``bodies`` ``{link: {mass_kg, com_m}}`` (CoM in each link's own frame);
  optional ``mount_rotvec`` (``R_B,ft(true) = R_B,ft(nominal) exp([r]x)``; absent: not stated),
  ``kind``, ``transducer`` and ``ft_link`` (absent: from the dataset's ``robot.toml``, when given).
  The kind is ``kind`` when present, else told by the keys (``bodies`` + ``load_mass_kg``: a URDF load;
  ``mass_kg`` + ``com_m`` without ``legs``: a payload). Read into :class:`LoadTruth`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from .core.errors import DataFormatError

if TYPE_CHECKING:  # calibration.py is read only for a hexapod's truth (imported there)
    from .core.calibration import Calibration

#: the simulated free loads' kinds (``sim/free/config.py`` FREE_SIM_KINDS), spelled here: truth files are read
#: without the simulator
FREE_SIM_KINDS = ("payload", "urdf_leg")


@dataclass(frozen=True)
class LoadTruth:
    """The true free load of one transducer (module docstring); ``raw`` the whole file."""

    kind: str
    transducer: str | None   # None: the file names none and robot.toml has more than one transducer
    offset: np.ndarray
    mount_rotvec: np.ndarray | None
    noise: np.ndarray
    mass_kg: float
    com_m: np.ndarray | None = None
    ft_link: str | None = None
    bodies: dict = field(default_factory=dict)
    effects: tuple[str, ...] = ()
    raw: dict = field(default_factory=dict)

    def body_tuples(self) -> dict[str, tuple[float, np.ndarray]]:
        """``{link: (mass_kg, com_m in the link's frame)}`` of a URDF load (as ``sim.free.physics`` takes them)."""
        return {l: (float(b["mass_kg"]), np.asarray(b["com_m"], float)) for l, b in self.bodies.items()}


class _CommonKeys(TypedDict):
    """The fields of :class:`LoadTruth` both kinds of free load read alike."""

    kind: str
    transducer: str | None
    offset: np.ndarray
    noise: np.ndarray
    mount_rotvec: np.ndarray | None
    effects: tuple[str, ...]
    raw: dict


def free_load_kind(d: dict) -> str | None:
    """``"payload"``, ``"urdf_leg"`` or None (not a free load's truth)."""
    if not isinstance(d, dict):
        return None
    if d.get("kind") in FREE_SIM_KINDS:
        return d["kind"]
    if "bodies" in d and "load_mass_kg" in d:
        return "urdf_leg"
    if "mass_kg" in d and "com_m" in d and "legs" not in d:
        return "payload"
    return None


def load_truth_from_dict(d: dict, path: str | Path = "truth.json", robot=None) -> LoadTruth:
    """A free load's truth from the parsed ``truth.json``; ``robot`` (``robot.toml`` as read, optional) names the
    transducer and its link when the file does not. A missing key is a DataFormatError naming it."""
    kind = free_load_kind(d)
    if kind is None:
        raise DataFormatError(f"{path}: not a free load's truth (no kind, bodies or mass_kg/com_m)", path=path)
    legs = list(getattr(robot, "legs", []) or [])
    transducer = d.get("transducer", legs[0] if len(legs) == 1 else None)
    try:
        common = _CommonKeys(kind=kind, transducer=None if transducer is None else str(transducer),
                      offset=np.asarray(d["offset"], float), noise=np.asarray(d["noise"], float),
                      mount_rotvec=_mount_rotvec(d),
                      effects=tuple(e["name"] if isinstance(e, dict) else str(e) for e in d.get("effects", ())), raw=d)
        if kind == "payload":
            return LoadTruth(mass_kg=float(d["mass_kg"]), com_m=np.asarray(d["com_m"], float), **common)
        ft_link = d.get("ft_link") or _robot_link(robot, transducer)
        return LoadTruth(mass_kg=float(d["load_mass_kg"]), ft_link=ft_link, bodies=dict(d["bodies"]), **common)
    except KeyError as exc:
        raise DataFormatError(f"{path}: a {kind} truth needs key {exc.args[0]!r}", path=path, column=str(exc.args[0])) from None


def _mount_rotvec(d: dict) -> np.ndarray | None:
    """The true mounting rotation vector: ``mount_rotvec``, or ``mount_rotvec_rad`` (the shared arm samples' name)."""
    v = d.get("mount_rotvec", d.get("mount_rotvec_rad"))
    return None if v is None else np.asarray(v, float)


def _robot_link(robot, transducer) -> str | None:
    tr = getattr(robot, "transducers", None)
    if not tr or transducer not in tr:
        return None
    t = tr[transducer]
    return t.get("link") if isinstance(t, dict) else getattr(t, "link", None)


def load_truth(path: str | Path, *, mass_kg: float | None = None, g: float = 9.81, robot=None) -> LoadTruth | Calibration:
    """The truth in ``path``: a :class:`LoadTruth` for a free load, else a :class:`Calibration` (hexapod)."""
    path = Path(path)
    d = json.loads(path.read_text())
    if free_load_kind(d) is not None:
        return load_truth_from_dict(d, path, robot)
    from .core.calibration import Calibration

    return Calibration.load(path, mass_kg=mass_kg, g=g)
