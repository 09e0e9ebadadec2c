"""Settings of the BigAnt simulator: one frozen dataclass, every knob with a realistic default.

The defaults reproduce the experiment of the report (Wu & Revzen, Sec. I-B,
III-A, IV-3): hanging in +-x and +-z with ten slow leg turns at 100 Hz, the
3^6 grid of standing poses {0, +-36 deg} held 5 s each (about 8 % of them on a
board tilted 38 deg, like ``shared/sample``), and a quasi-static tripod walk on
a 0.08 Hz Buehler clock turning ~9 deg per cycle; ATI Gamma noise; motion
capture with white jitter plus an orientation error constant within each
standing pose; BigAnt's mass (8.18 kg) and Table II offsets and leg weights;
compliant PARF legs (3-5 mm deflection under the 15-25 N a foot carries) on a
four-bar toe loop whose flat-ish bottom rises ~7.5 mm at +-36 deg, on a floor
with ~1 mm bumps. Tuned to the sample's standing poses: every leg carries load
in most poses (a leg at 0 deg nearly always, at +-36 deg in ~70 %), 4-6 feet
loaded, level-ground tilt 0.3-2 deg.

``SimConfig.from_dict`` reads a TOML ``[simulate]`` table: keys are the field
names, lists become tuples, an unknown key is an error naming the known ones;
``kind = "hexapod"`` is accepted (other kinds: ``ftcal_nlp.sim.free``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from ..core.errors import ConfigError


@dataclass(frozen=True)
class SimConfig:
    """Every setting of :func:`ftcal_nlp.sim.simulate` (SI units unless the name says otherwise)."""

    seed: int = 0
    rate_hz: float = 100.0
    t0_s: float = 30.0                    # session time of the first sample
    gap_s: float = 30.0                   # idle time between recordings

    # hanging (report Sec. III-A)
    hanging_cycles: float = 10.0          # leg turns per recording
    hanging_cycle_s: float = 20.0         # nominal duration of one turn
    hanging_speed_spread: float = 0.05    # each leg's speed differs by up to this fraction
    hanging_tilt_deg: float = 2.0         # whole-robot hanging tilt, random axis per recording

    # standing (report Sec. I-B)
    pose_angles_deg: tuple = (-36.0, 0.0, 36.0)
    n_poses: int | None = None            # None: whole grid; else a seeded random subset
    pose_s: float = 5.0                   # time per pose, transition included
    move_s: float = 0.3                   # shaft motion between poses
    settle_s: float = 2.0                 # pose change -> start of the nominally steady part
    transient_decay_per_s: float = 5.0    # envelope exp(-a t) of the overshoot
    transient_freq_hz: float = 2.0        # its ringing frequency
    heading_step_deg: float = 1.0         # feet shuffle the heading a little at each pose change
    internal_force_N: float = 2.0         # size of friction-locked self-equilibrated foot forces
    friction_mu: float = 0.5
    max_tilt_deg: float = 5.0             # a pose needing more tilt than this (relative to its ground) has tipped over
                                          # (grid poses on level ground need < 3 deg)
    ground_roughness_mm: float = 1.0      # sd of the floor (or board) height under each foot, drawn afresh per pose
    board_pose_fraction: float = 0.08     # share of the requested poses taken on a tilted board (the sample: 9 of 108)
    board_tilt_deg: float = 38.0          # the board's slope; its downhill direction is random per pose
    board_friction_mu: float = 1.0        # rubber feet on the board: above tan(board_tilt_deg), else every board pose slips

    # walking (report Sec. IV-3)
    walk_cycles: float = 2.0
    walk_freq_hz: float = 0.08            # Buehler clock
    walk_duty: float = 0.6                # stance fraction of a cycle
    walk_sweep_deg: float = 57.3          # stance sweep of the shaft angle (+-half about 0)
    walk_turn_deg_per_cycle: float = -9.0 # heading change per cycle (negative = right turn)
    walk_internal_force_N: float = 1.5

    # sensors
    noise_force_N: float = 0.05
    noise_torque_Nm: float = 0.003
    mocap_jitter_deg: float = 0.05        # white, per axis, every sample (standing and walking)
    mocap_pose_error_deg: float = 0.05    # per axis, constant through each standing pose (the marker model's error
                                          # for that placement): the pose median does not average it away
    mocap_dropout_rate: float = 0.03      # probability that a pose loses mocap through its steady part
    mocap_blip_rate_hz: float = 0.01      # short tracking losses per second (standing and walking)
    mocap_blip_s: tuple = (0.1, 1.0)      # their duration range

    # robot truth
    mass_kg: float = 8.18
    g: float = 9.81
    mounting_rot_deg: float = 1.5         # rms size of each transducer's mounting rotation error
    mounting_trans_mm: float = 3.0        # rms size of each transducer's mounting translation error
    leg_weight_spread_N: float = 0.05     # spread of leg weights about Table II
    com_body_range_m: tuple = (0.025, 0.012, 0.02)  # body-without-legs CoM drawn uniformly within +- this
    foot_stiffness_N_per_m: float = 5000.0   # compliant PARF leg and foot: 3-5 mm under 15-25 N; 4-6 feet loaded
    toe_depth_m: float = 0.17             # foot below the hip at phi = 0
    toe_depth_spread_mm: float = 1.0
    toe_reach_m: float = 0.10             # foot x = -reach sin(phi)
    toe_lift_m: float = 0.08              # foot raised this much at phi = pi
    toe_stance_rise_mm: float = 7.5       # foot higher at phi = +-36 deg than at 0 (flat-ish stance arc) ...
    toe_rise_spread_mm: float = 1.5       # ... by this much more or less, uniformly, per leg

    # effect injectors (issue 7): objects following ftcal_nlp.sim.effects.Injector
    effects: tuple = ()

    def __post_init__(self) -> None:
        if any(not hasattr(e, "readings") for e in self.effects):  # names or tables -> injectors
            from .effects import make_effects

            object.__setattr__(self, "effects", make_effects(tuple(self.effects), where="SimConfig.effects"))
        from ..effects import applies_to

        bad = [e.name for e in self.effects if "hexapod" not in applies_to(getattr(e, "name", ""))]
        if bad:  # e.g. a joint-limit contact or a free load's inertia: the hexapod simulator has neither
            raise ConfigError(f"SimConfig.effects: {bad} act on a free load, not on a hexapod", key="simulate.effects")
        positive = ("rate_hz", "hanging_cycles", "hanging_cycle_s", "pose_s", "walk_freq_hz", "mass_kg", "g",
                    "foot_stiffness_N_per_m", "toe_depth_m", "transient_decay_per_s", "transient_freq_hz", "toe_lift_m")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"SimConfig.{name} must be > 0, got {getattr(self, name)!r}", key=f"simulate.{name}")
        nonneg = ("noise_force_N", "noise_torque_Nm", "mocap_jitter_deg", "mocap_dropout_rate", "mocap_blip_rate_hz",
                  "walk_cycles", "gap_s", "move_s", "settle_s", "internal_force_N", "walk_internal_force_N",
                  "mounting_rot_deg", "mounting_trans_mm", "hanging_tilt_deg", "mocap_pose_error_deg",
                  "board_tilt_deg", "board_friction_mu", "toe_rise_spread_mm", "friction_mu", "ground_roughness_mm")
        for name in nonneg:
            if getattr(self, name) < 0:
                raise ConfigError(f"SimConfig.{name} must be >= 0, got {getattr(self, name)!r}", key=f"simulate.{name}")
        if not 0 < self.walk_duty < 1:
            raise ConfigError(f"SimConfig.walk_duty must be in (0, 1), got {self.walk_duty}")
        if self.move_s + self.settle_s >= self.pose_s:
            raise ConfigError(f"SimConfig: move_s + settle_s ({self.move_s + self.settle_s}) must be shorter than pose_s ({self.pose_s})")
        if self.n_poses is not None and self.n_poses < 1:
            raise ConfigError(f"SimConfig.n_poses must be None or >= 1, got {self.n_poses}")
        if not self.pose_angles_deg:
            raise ConfigError("SimConfig.pose_angles_deg must hold at least one angle")
        if len(self.com_body_range_m) != 3 or len(self.mocap_blip_s) != 2:
            raise ConfigError("SimConfig.com_body_range_m needs 3 numbers and mocap_blip_s 2")
        if not 0 <= self.mocap_dropout_rate <= 1:
            raise ConfigError(f"SimConfig.mocap_dropout_rate is a probability, got {self.mocap_dropout_rate}")
        if not 0 <= self.board_pose_fraction <= 1:
            raise ConfigError(f"SimConfig.board_pose_fraction is a fraction in [0, 1], got {self.board_pose_fraction}")
        if not self.board_tilt_deg < 80:
            raise ConfigError(f"SimConfig.board_tilt_deg must be below 80 deg, got {self.board_tilt_deg}")

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    @classmethod
    def from_dict(cls, d: dict[str, Any], *, where: str = "[simulate]") -> "SimConfig":
        """Build from a TOML table; lists become tuples; unknown keys are errors.

        ``effects`` is a list of effect names resolved in
        :data:`ftcal_nlp.sim.effects.EFFECTS` (or tables ``{name = ..., ...kwargs}``).
        """
        if d.get("kind", "hexapod") != "hexapod":  # payload / urdf_leg: ftcal_nlp.sim.free (sim.simulate_to_folder)
            raise ConfigError(f"{where}: kind = {d['kind']!r} is not the hexapod; simulate it with ftcal_nlp.sim.simulate_to_folder")
        d = {k: v for k, v in d.items() if k != "kind"}
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(d) - set(known))
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {unknown}; known keys: {sorted(known)}", key=unknown[0])
        kw: dict[str, Any] = {}
        for key, value in d.items():
            typ = str(known[key].type)
            if key == "effects":
                from .effects import make_effects

                try:
                    kw[key] = make_effects(value, where=f"{where}.effects")
                except ValueError as exc:  # the effect registry's own checks: a config error here
                    raise ConfigError(str(exc), key="effects") from exc
            elif typ == "tuple":
                if not isinstance(value, (list, tuple)) or not all(_is_number(v) for v in value):
                    raise ConfigError(f"{where}: key '{key}' should be a list of numbers, got {value!r}", key=key)
                kw[key] = tuple(float(v) for v in value)
            elif typ.startswith("int"):
                if not (isinstance(value, int) and not isinstance(value, bool)) and not (value is None and "None" in typ):
                    raise ConfigError(f"{where}: key '{key}' should be an integer, got {value!r}", key=key)
                kw[key] = value
            else:
                if not _is_number(value):
                    raise ConfigError(f"{where}: key '{key}' should be a number, got {value!r}", key=key)
                kw[key] = float(value)
        try:
            return cls(**kw)
        except ConfigError as exc:  # the ranges checked by __post_init__: name where they were set
            raise ConfigError(f"{where}: {exc}", key=exc.key) from exc

    def to_dict(self) -> dict[str, Any]:
        """Plain values (effects by name), e.g. for logging."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["effects"] = [getattr(e, "name", type(e).__name__) for e in self.effects]
        return d


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)
