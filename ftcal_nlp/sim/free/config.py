"""Settings of the free-load simulator: frozen dataclasses, one per ``kind``, built from a TOML ``[simulate]`` table.

``kind = "payload"``: a wrist transducer carrying a rigid tool, moved by an arm
between held orientations. ``kind = "urdf_leg"``: a leg of URDF links below a
sensor link (default: the bundled ``assets/leg4.urdf``), the body tilted
through held orientations while the joints move between held poses.

Keys are the field names (``config_from_dict``); lists become tuples; an
unknown key is an error naming the known ones. Sizes: SI units unless the name
says otherwise. Every random draw comes from ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

ASSETS = Path(__file__).resolve().parent.parent / "assets"
LEG4_URDF = ASSETS / "leg4.urdf"

FREE = "free"   # what an effect unit's ``applies_to`` names when its injector works on a free load


@dataclass(frozen=True)
class _Common:
    """Settings shared by every kind."""

    seed: int = 0
    rate_hz: float = 100.0
    t0_s: float = 1000.0                 # session time of the first sample
    n_orientations: int = 14             # held orientations of B
    hold_s: float = 12.0                 # each hold
    move_s: float = 5.0                  # smooth (minimum-jerk) move between holds
    g: float = 9.81
    # sensor
    noise_force_N: float = 0.02          # white, per channel (ATI Gamma-like)
    noise_torque_Nm: float = 0.0006
    offset_force_N: float = 3.0          # sd of the drawn offsets (when ``offset`` is empty)
    offset_torque_Nm: float = 0.1
    offset: tuple = ()                   # 6 numbers: the offsets exactly (N, N*m)
    mount_rot_deg: float = 1.0           # rms size of the drawn mounting rotation (when ``mount_rotvec`` is empty)
    mount_rotvec: tuple = ()             # 3 numbers, rad: true ft relative to nominal, R_true = R_nom @ exp([r]x)
    # orientation stream
    orientation: str = "quat"            # "quat": qw..qz columns; "gravity": gx..gz (gravity direction in B)
    mocap_jitter_deg: float = 0.0        # white, per axis, on the recorded orientation (the samples have none)
    effects: tuple = ()                  # names or {name = ..., ...} tables of effects whose unit applies_to "free"
    inertial_load: float = 0.0           # x the load's inertial wrench during moves (1 = physical; 0 = quasi-static, as the samples)
    recording: str = "hang"              # recording (file) name

    def _check(self) -> None:
        for name in ("rate_hz", "hold_s", "g"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{type(self).__name__}.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("move_s", "inertial_load", "noise_force_N", "noise_torque_Nm", "offset_force_N", "offset_torque_Nm",
                     "mount_rot_deg", "mocap_jitter_deg"):
            if getattr(self, name) < 0:
                raise ValueError(f"{type(self).__name__}.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.n_orientations < 1:
            raise ValueError(f"{type(self).__name__}.n_orientations must be >= 1, got {self.n_orientations}")
        if len(self.offset) not in (0, 6) or len(self.mount_rotvec) not in (0, 3):
            raise ValueError(f"{type(self).__name__}: offset needs 6 numbers and mount_rotvec 3 (or none)")
        if self.orientation not in ("quat", "gravity"):
            raise ValueError(f"{type(self).__name__}.orientation must be 'quat' or 'gravity', got {self.orientation!r}")
        if any(not hasattr(e, "readings") for e in self.effects):
            from ..effects import make_effects

            object.__setattr__(self, "effects", make_effects(tuple(self.effects), where=f"{type(self).__name__}.effects"))
        from ...effects import EFFECTS, applies_to

        bad = [e.name for e in self.effects if FREE not in applies_to(e.name)]
        if bad:
            raise ValueError(f"{type(self).__name__}.effects: {bad} need a hexapod (shaft angles, feet, a body on legs); "
                             f"a free load takes {[n for n, u in EFFECTS.items() if FREE in u.applies_to]}")


@dataclass(frozen=True)
class PayloadConfig(_Common):
    """A wrist transducer ``transducer`` carrying a rigid tool (no ``{leg}_phi`` column).

    The held orientations of B (the arm's flange) are drawn uniformly on SO(3).
    """

    kind: ClassVar[str] = "payload"
    transducer: str = "wrist"
    recording: str = "wrist"
    mass_kg: float = 1.5                       # the tool's true mass
    com_m: tuple = (0.006, -0.004, 0.08)       # its true CoM in ft
    position_m: tuple = (0.0, 0.0, 0.03)       # nominal ft origin in B (written to robot.toml; no effect on readings)
    rotation_rpy: tuple = (0.0, 0.0, 1.5707963267948966)  # nominal R_B,ft as URDF rpy (Rz(y) Ry(p) Rx(r))
    gyration_radius_m: float = 0.04            # the tool's inertia about its CoM: m k^2 I (only with inertial_load)

    def __post_init__(self) -> None:
        self._check()
        if not self.mass_kg > 0 or len(self.com_m) != 3 or len(self.position_m) != 3 or len(self.rotation_rpy) != 3:
            raise ValueError("PayloadConfig: mass_kg > 0, com_m, position_m and rotation_rpy of 3 numbers")


@dataclass(frozen=True)
class UrdfLegConfig(_Common):
    """A leg of URDF links below the sensor link ``ft_link`` of transducer ``transducer``.

    Held states: ``n_orientations`` body tilts (up to ``max_tilt_deg`` about a random
    horizontal axis, random heading), each with ``poses_per_orientation`` joint
    poses drawn uniformly within ``joint_range`` of every movable joint's limits
    (joints above the sensor too). True bodies: nominal mass x (1 + N(0, mass_spread)),
    nominal CoM + N(0, com_spread_mm) per axis, in each link's own frame.
    """

    kind: ClassVar[str] = "urdf_leg"
    urdf: str = ""                             # "" -> the bundled assets/leg4.urdf
    transducer: str = "r_leg"
    ft_link: str = "r_leg_ft"
    recording: str = "leg"
    n_orientations: int = 12
    poses_per_orientation: int = 3
    hold_s: float = 6.0
    move_s: float = 3.0
    max_tilt_deg: float = 60.0
    joint_range: float = 0.9                   # fraction of each joint's limit range used
    mass_spread: float = 0.10
    com_spread_mm: float = 5.0
    noise_force_N: float = 0.05
    noise_torque_Nm: float = 0.003

    def __post_init__(self) -> None:
        self._check()
        if self.poses_per_orientation < 1 or not 0 < self.joint_range <= 1 or not 0 <= self.max_tilt_deg <= 180:
            raise ValueError("UrdfLegConfig: poses_per_orientation >= 1, 0 < joint_range <= 1, 0 <= max_tilt_deg <= 180")
        if self.mass_spread < 0 or self.com_spread_mm < 0:
            raise ValueError("UrdfLegConfig: mass_spread and com_spread_mm must be >= 0")

    @property
    def urdf_path(self) -> Path:
        return Path(self.urdf) if self.urdf else LEG4_URDF


CONFIG_OF_KIND: dict[str, type] = {"payload": PayloadConfig, "urdf_leg": UrdfLegConfig}
FREE_SIM_KINDS: tuple[str, ...] = tuple(CONFIG_OF_KIND)   # = truth.FREE_SIM_KINDS (tests/test_sim_freeload.py)


def config_from_dict(d: dict[str, Any], *, where: str = "[simulate]") -> PayloadConfig | UrdfLegConfig:
    """A config from a TOML table with ``kind = "payload" | "urdf_leg"``; unknown keys are errors."""
    d = dict(d)
    kind = d.pop("kind", None)
    if kind not in FREE_SIM_KINDS:
        raise ValueError(f"{where}: kind = {kind!r}; free-load kinds: {sorted(FREE_SIM_KINDS)}")
    cls = CONFIG_OF_KIND[kind]
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(d) - set(known))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown} for kind '{kind}'; known keys: {sorted(known)}")
    kw: dict[str, Any] = {}
    for key, value in d.items():
        typ = str(known[key].type)
        if key == "effects":
            from ..effects import make_effects

            kw[key] = make_effects(value, where=f"{where}.effects")
        elif typ == "tuple":
            if not isinstance(value, (list, tuple)) or not all(_is_number(v) for v in value):
                raise ValueError(f"{where}: key '{key}' should be a list of numbers, got {value!r}")
            kw[key] = tuple(float(v) for v in value)
        elif typ == "int":
            if not (isinstance(value, int) and not isinstance(value, bool)):
                raise ValueError(f"{where}: key '{key}' should be an integer, got {value!r}")
            kw[key] = value
        elif typ == "str":
            if not isinstance(value, str):
                raise ValueError(f"{where}: key '{key}' should be a string, got {value!r}")
            kw[key] = value
        else:
            if not _is_number(value):
                raise ValueError(f"{where}: key '{key}' should be a number, got {value!r}")
            kw[key] = float(value)
    return cls(**kw)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)
