"""``simulate_free(cfg)``: one ``hanging`` recording of a free load (DATA_FORMAT.md section 5), with its truth.

Motion: ``n`` held states (orientation of B, and for a URDF leg the joint
angles) joined by minimum-jerk moves ``s(u) = 10u^3 - 15u^4 + 6u^5`` of
``move_s`` (orientation along the geodesic ``R_a exp(s log(R_a^T R_b))``,
joints linearly in ``s``): the samples of a move are not quasi-static in a
real rig; by default they carry the static wrench of their instantaneous
pose (``physics.py``; as the shared samples do), with ``inertial_load = s``
also ``s`` times the load's inertial wrench (``physics.inertial_wrench``; zero
on held samples, which are at rest; ``truth.json`` lists it as the effect
``inertial_load``).

Readings (frames and equations in ``physics.py``):

    w_m = inject(w_load + w_o) + n,    n ~ N(0, diag(s_f^2 I3, s_t^2 I3))

``inject`` is the library's reading injectors that need no hexapod
(units whose ``applies_to`` names "free": drift, gain crosstalk, nonlinearity, clock
offset, creep, the load's inertia, joint-limit contact, temperature) through
``effects.apply_readings``; they see ``FreeLoadTruth`` (joint angles and limits, the
load's inertial wrench when one asks for it) and may add recording columns
(a temperature ``{X}_temp_C`` from an injector's ``temperature(ctx)``); the recorded orientation is ``R_WB exp([delta]x)``
(``delta`` white, ``mocap_jitter_deg``) through ``effects.apply_orientation``
(mocap bias). Randomness: one ``np.random.SeedSequence(seed)`` split into
truth, motion, sensor, mocap and effect streams, so a seed fixes every array.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from ...core.geometry import quat_to_rotation, rotation_to_quat, rotation_to_rotvec, rotvec_to_rotation
from ..effects import apply_orientation, apply_readings
from .config import PayloadConfig, UrdfLegConfig
from ...core.kinematics import KinematicTree, load_tree
from .physics import gravity_in_body, gravity_in_ft, inertial_wrench, payload_readings, true_rotation, urdf_load_readings

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
MOUNT_CONVENTION = "R_B,ft(true) = R_B,ft(nominal) @ expm(skew(mount_rotvec)); mount_rotvec in the nominal ft axes, rad"


@dataclass(frozen=True)
class FreeLoadTruth:
    """What an injector's context carries as ``truth`` (the library's drift/gain/nonlinearity use none of it).

    ``q``: joint angles (N,) per URDF joint (empty for a payload); ``limits``: ``(lower, upper)`` of each
    movable joint with limits; ``inertial``: the load's physical inertial wrench (N, 6) in the true ft
    frame (``physics.inertial_wrench``; zero on held samples), or None when no injector asks for it
    (``needs_inertial``)."""

    legs: tuple[str, ...]
    offsets: np.ndarray          # (1, 6)
    g: float
    q: dict = field(default_factory=dict)
    limits: dict = field(default_factory=dict)
    inertial: np.ndarray | None = None


@dataclass(frozen=True)
class FreeLoadResult:
    """One simulated free-load dataset.

    ``frame``: the recording's columns as written (``t``, ``{X}_fx..tz``,
    ``q_{joint}``, ``qw..qz`` or ``gx..gz``). ``held`` (N,) samples of a hold
    (quasi-static); ``hold_index`` (N,) the hold, -1 in moves. ``clean`` (N, 6)
    noise-free readings before injectors (load wrench + offset). ``R_WB`` (N, 3, 3)
    true orientation. ``truth``: ``truth.json``; ``robot``: ``robot.toml``;
    ``manifest``: ``dataset.toml`` (plain dicts); ``urdf_text`` the URDF to copy
    beside them (``urdf_leg``).
    """

    config: Any
    frame: pd.DataFrame
    held: np.ndarray
    hold_index: np.ndarray
    clean: np.ndarray
    R_WB: np.ndarray
    truth: dict
    robot: dict
    manifest: dict
    urdf_text: str | None = None
    q: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- motion


def min_jerk(u: np.ndarray) -> np.ndarray:
    """``10u^3 - 15u^4 + 6u^5`` on [0, 1]: zero speed and acceleration at both ends."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10 - 15 * u + 6 * u**2)


def schedule(n_holds: int, hold_s: float, move_s: float, rate_hz: float, t0_s: float):
    """Sample times (N,) and, per sample, the hold it leaves ``a``, the one it goes to ``b``, the fraction ``s``
    of the move (0 while held) and ``hold_index`` (-1 in moves)."""
    period = hold_s + move_s
    n = int(round((n_holds * hold_s + (n_holds - 1) * move_s) * rate_hz))
    tau = np.arange(n) / rate_hz
    k = np.minimum((tau // period).astype(int), n_holds - 1)
    within = tau - k * period
    moving = (within >= hold_s) & (k < n_holds - 1)
    s = np.where(moving, min_jerk((within - hold_s) / max(move_s, 1e-12)), 0.0)
    b = np.where(moving, k + 1, k)
    return t0_s + tau, k, b, s, np.where(moving, -1, k)


def interpolate_rotations(R_holds: np.ndarray, a: np.ndarray, b: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``R_a exp(s log(R_a^T R_b))`` per sample (N, 3, 3): the geodesic between held orientations."""
    rel = rotation_to_rotvec(np.einsum("hji,hjk->hik", R_holds[:-1], R_holds[1:]))     # (H-1, 3)
    step = np.zeros((len(a), 3))
    m = b > a
    step[m] = s[m, None] * rel[a[m]]
    return R_holds[a] @ rotvec_to_rotation(step)


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` rotations uniform on SO(3) (normalised Gaussian quaternions)."""
    q = rng.standard_normal((n, 4))
    return quat_to_rotation(q / np.linalg.norm(q, axis=1, keepdims=True))


def tilted_rotations(n: int, max_tilt_deg: float, rng: np.random.Generator) -> np.ndarray:
    """``Rz(heading) exp(tilt [cos a, sin a, 0])``: tilts uniform over the spherical cap up to ``max_tilt_deg``
    (``cos tilt`` uniform), any heading (it does not change gravity in B)."""
    cos_t = 1 - rng.uniform(0, 1, n) * (1 - np.cos(np.radians(max_tilt_deg)))
    tilt = np.arccos(cos_t)
    a = rng.uniform(-np.pi, np.pi, n)
    yaw = rng.uniform(-np.pi, np.pi, n)
    R_tilt = rotvec_to_rotation(tilt[:, None] * np.stack([np.cos(a), np.sin(a), np.zeros(n)], axis=1))
    return rotvec_to_rotation(yaw[:, None] * np.array([0.0, 0.0, 1.0])) @ R_tilt


# ----------------------------------------------------------------------------- shared parts


def _streams(seed: int):
    return np.random.SeedSequence(seed).spawn(5)  # truth, motion, sensor, mocap, effects


def _draw_offset_mount(cfg, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    sd = np.array([cfg.offset_force_N] * 3 + [cfg.offset_torque_Nm] * 3)
    off = rng.normal(0.0, 1.0, 6) * sd                               # drawn even when given: streams stay aligned
    rv = rng.normal(0.0, np.radians(cfg.mount_rot_deg) / np.sqrt(3.0), 3)
    off = np.asarray(cfg.offset, dtype=float) if cfg.offset else off
    rv = np.asarray(cfg.mount_rotvec, dtype=float) if cfg.mount_rotvec else rv
    return off, rv


def _needs_inertial(cfg) -> bool:
    """Whether an injector reads the load's inertial wrench (``needs_inertial``; ``truth.inertial``)."""
    return any(getattr(e, "needs_inertial", False) for e in cfg.effects)


def _context(cfg, name: str, t: np.ndarray, R_WB: np.ndarray, hold_index: np.ndarray, clean: np.ndarray,
             offset: np.ndarray, q: dict | None = None, limits: dict | None = None, inertial: np.ndarray | None = None) -> dict:
    """The injectors' context (``effects.InjectionContext`` without its generator)."""
    truth = FreeLoadTruth((cfg.transducer,), offset[None], cfg.g, dict(q or {}), dict(limits or {}), inertial)
    return dict(kind="hanging", name=name, t=t, phi=np.zeros((len(t), 1)), R_WB=R_WB, applied=(clean - offset)[:, None, :],
                pose_index=hold_index, truth=truth)


def _effect_columns(cfg, ctx: dict) -> dict[str, np.ndarray]:
    """Recording columns the injectors add: a transducer temperature ``{X}_temp_C`` (an injector's
    ``temperature(ctx)`` (N, K) degC; ``DATA_FORMAT.md`` proposal ``docs/proposals/temperature.md``)."""
    from ...effects import InjectionContext

    out: dict[str, np.ndarray] = {}
    for e in cfg.effects:
        if hasattr(e, "temperature"):
            out[f"{cfg.transducer}_temp_C"] = e.temperature(InjectionContext(rng=np.random.default_rng(0), **ctx))[:, 0]
    return out


def _sense(cfg, name: str, t: np.ndarray, R_WB: np.ndarray, hold_index: np.ndarray, clean: np.ndarray,
           offset: np.ndarray, streams, ctx: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Readings (N, 6) and recorded orientation (N, 3, 3) through the injectors and the noise."""
    _, _, s_sensor, s_mocap, s_effect = streams
    ctx = _context(cfg, name, t, R_WB, hold_index, clean, offset) if ctx is None else ctx
    rngs = [np.random.default_rng(s) for s in s_effect.spawn(len(cfg.effects))]
    w = apply_readings(cfg.effects, ctx, clean[:, None, :].copy(), rngs)[:, 0, :]
    sigma = np.array([cfg.noise_force_N] * 3 + [cfg.noise_torque_Nm] * 3)
    w = w + np.random.default_rng(s_sensor).standard_normal(w.shape) * sigma
    delta = np.random.default_rng(s_mocap).normal(0.0, np.radians(cfg.mocap_jitter_deg), (len(t), 3))
    R_meas = apply_orientation(cfg.effects, ctx, R_WB @ rotvec_to_rotation(delta) if cfg.mocap_jitter_deg > 0 else R_WB.copy(), rngs)
    return w, R_meas


def _frame(cfg, t: np.ndarray, w: np.ndarray, q: dict, R_meas: np.ndarray, extra: dict | None = None) -> pd.DataFrame:
    cols: dict[str, np.ndarray] = {"t": t}
    for i, c in enumerate(WRENCH):
        cols[f"{cfg.transducer}_{c}"] = w[:, i]
    for j, v in q.items():
        cols[f"q_{j}"] = v
    if cfg.orientation == "quat":
        quat = rotation_to_quat(R_meas)
        for i, c in enumerate(("qw", "qx", "qy", "qz")):
            cols[c] = quat[:, i]
    else:  # gravity direction (pointing down) in B, unit length
        gd = gravity_in_body(R_meas, 1.0)
        for i, c in enumerate(("gx", "gy", "gz")):
            cols[c] = gd[:, i]
    cols.update(extra or {})
    return pd.DataFrame(cols)


def _common_truth(cfg, offset: np.ndarray, rotvec: np.ndarray, n: int, held: np.ndarray) -> dict:
    return {
        "offset": [float(x) for x in offset],
        "mount_rotvec": [float(x) for x in rotvec],
        "mount_convention": MOUNT_CONVENTION,
        "noise": [cfg.noise_force_N] * 3 + [cfg.noise_torque_Nm] * 3,
        "effects": [{"name": e.name, "scale": float(getattr(e, "scale", 1.0)), "seed": int(getattr(e, "seed", 0))} for e in cfg.effects]
                   + ([{"name": "inertial_load", "scale": float(cfg.inertial_load)}] if cfg.inertial_load > 0 else []),
        "n": int(n),
        "n_held": int(held.sum()),
        "seed": int(cfg.seed),
        "kind": cfg.kind,
        "transducer": cfg.transducer,
    }


def _manifest(cfg) -> dict:
    return {"robot": "robot.toml", "recording": [{"file": f"{cfg.recording}.csv", "kind": "hanging"}]}


# ----------------------------------------------------------------------------- payload


def rpy_to_rotation(rpy) -> np.ndarray:
    """URDF ``rpy``: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (float(v) for v in rpy)
    ez, ey, ex = np.eye(3)[2], np.eye(3)[1], np.eye(3)[0]
    return rotvec_to_rotation(y * ez) @ rotvec_to_rotation(p * ey) @ rotvec_to_rotation(r * ex)


def simulate_payload(cfg: PayloadConfig = PayloadConfig()) -> FreeLoadResult:
    """A wrist transducer with a rigid tool, moved through ``n_orientations`` held orientations."""
    streams = _streams(cfg.seed)
    offset, rotvec = _draw_offset_mount(cfg, np.random.default_rng(streams[0]))
    R_holds = random_rotations(cfg.n_orientations, np.random.default_rng(streams[1]))
    t, a, b, s, hold_index = schedule(cfg.n_orientations, cfg.hold_s, cfg.move_s, cfg.rate_hz, cfg.t0_s)
    R_WB = interpolate_rotations(R_holds, a, b, s)
    R_nom = rpy_to_rotation(cfg.rotation_rpy)
    R_ft = true_rotation(R_nom, rotvec)
    clean = payload_readings(gravity_in_ft(R_WB, R_ft, cfg.g), cfg.mass_kg, np.asarray(cfg.com_m), offset)
    inertial = None
    if cfg.inertial_load > 0 or _needs_inertial(cfg):
        p_ft = np.asarray(cfg.position_m, dtype=float)
        tool = (cfg.mass_kg, np.broadcast_to(p_ft + R_ft @ np.asarray(cfg.com_m), (len(t), 3)),
                np.broadcast_to(R_ft, (len(t), 3, 3)), cfg.mass_kg * cfg.gyration_radius_m**2 * np.eye(3))
        inertial = (hold_index < 0)[:, None] * inertial_wrench(t, R_WB, p_ft, R_ft, [tool])  # held: at rest
        clean = clean + cfg.inertial_load * inertial
    ctx = _context(cfg, cfg.recording, t, R_WB, hold_index, clean, offset, inertial=inertial)
    w, R_meas = _sense(cfg, cfg.recording, t, R_WB, hold_index, clean, offset, streams, ctx)
    held = hold_index >= 0
    truth = {"mass_kg": float(cfg.mass_kg), "com_m": [float(x) for x in cfg.com_m],
             **_common_truth(cfg, offset, rotvec, len(t), held),
             "nominal_rotation": R_nom.tolist(), "com_frame": "true ft frame"}
    robot = {"name": "arm_with_tool", "g": float(cfg.g), "legs": [cfg.transducer],
             "transducers": {cfg.transducer: {"position_m": [float(x) for x in cfg.position_m],
                                              "rotation": [[float(x) for x in row] for row in R_nom]}}}
    return FreeLoadResult(cfg, _frame(cfg, t, w, {}, R_meas, _effect_columns(cfg, ctx)), held, hold_index, clean, R_WB, truth, robot, _manifest(cfg))


# ----------------------------------------------------------------------------- URDF leg


def joint_poses(tree: KinematicTree, n: int, frac: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` poses (per movable joint, (n,)) uniform within ``frac`` of each joint's limits about their middle
    (a joint without limits: +-frac*pi)."""
    out = {}
    for name in tree.movable:
        j = tree.joint(name)
        lo, hi = (j.lower, j.upper) if j.lower is not None and j.upper is not None and j.upper > j.lower else (-np.pi, np.pi)
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * frac
        out[name] = rng.uniform(mid - half, mid + half, n)
    return out


def joint_limits(tree: KinematicTree) -> dict[str, tuple[float, float]]:
    """``(lower, upper)`` of every movable joint with limits (``lower < upper``)."""
    out = {}
    for name in tree.movable:
        j = tree.joint(name)
        if j.lower is not None and j.upper is not None and j.upper > j.lower:
            out[name] = (float(j.lower), float(j.upper))
    return out


def draw_bodies(tree: KinematicTree, links: tuple[str, ...], cfg: UrdfLegConfig, rng: np.random.Generator) -> dict[str, tuple[float, np.ndarray]]:
    """True (mass, CoM in the link's own frame) of ``links``: nominal x (1 + N(0, mass_spread)), + N(0, com_spread_mm)."""
    out = {}
    for link in links:
        b = tree.bodies[link]
        m = b.mass_kg * max(0.5, 1.0 + cfg.mass_spread * rng.standard_normal())
        out[link] = (float(m), b.com_m + rng.normal(0.0, cfg.com_spread_mm * 1e-3, 3))
    return out


def _leg_inertial(tree: KinematicTree, ft_link: str, q: dict, t: np.ndarray, R_WB: np.ndarray,
                  bodies: dict, rotvec: np.ndarray) -> np.ndarray:
    """The leg's inertial wrench in the true ft frame (``physics.inertial_wrench``), bodies through the true mount."""
    n = len(t)
    extra = {ft_link: rotvec_to_rotation(rotvec)}
    R_ft, p_ft = tree.pose(tree.root, ft_link, q, n, extra)
    parts = []
    for link, (m, c) in bodies.items():
        R, p = tree.pose(tree.root, link, q, n, extra)
        parts.append((m, p + np.einsum("nij,j->ni", R, c), R, tree.bodies[link].inertia))
    return inertial_wrench(t, R_WB, p_ft, R_ft, parts)


def simulate_urdf_leg(cfg: UrdfLegConfig = UrdfLegConfig()) -> FreeLoadResult:
    """A leg of URDF links below ``cfg.ft_link``; the body tilts through held orientations while the joints move."""
    tree = load_tree(cfg.urdf_path)
    if cfg.ft_link not in tree.links:
        raise ValueError(f"UrdfLegConfig.ft_link = '{cfg.ft_link}' is not a link of {cfg.urdf_path} (links: {list(tree.links)})")
    ft_joint = tree.joints.get(cfg.ft_link)
    if ft_joint is None or ft_joint.type != "fixed":
        raise ValueError(f"UrdfLegConfig.ft_link = '{cfg.ft_link}': a sensor is the child link of a fixed joint")
    load = tuple(l for l in tree.below(cfg.ft_link) if l in tree.bodies)
    if not load:
        raise ValueError(f"{cfg.urdf_path}: no link with mass below '{cfg.ft_link}'")
    streams = _streams(cfg.seed)
    rng_truth = np.random.default_rng(streams[0])
    offset, rotvec = _draw_offset_mount(cfg, rng_truth)
    bodies = draw_bodies(tree, load, cfg, rng_truth)
    rng_motion = np.random.default_rng(streams[1])
    n_holds = cfg.n_orientations * cfg.poses_per_orientation
    R_orient = tilted_rotations(cfg.n_orientations, cfg.max_tilt_deg, rng_motion)
    R_holds = np.repeat(R_orient, cfg.poses_per_orientation, axis=0)
    q_holds = joint_poses(tree, n_holds, cfg.joint_range, rng_motion)
    t, a, b, s, hold_index = schedule(n_holds, cfg.hold_s, cfg.move_s, cfg.rate_hz, cfg.t0_s)
    R_WB = interpolate_rotations(R_holds, a, b, s)
    q = {j: v[a] + s * (v[b] - v[a]) for j, v in q_holds.items()}
    clean = urdf_load_readings(tree, cfg.ft_link, q, gravity_in_body(R_WB, cfg.g), bodies, offset, rotvec)
    inertial = None
    if cfg.inertial_load > 0 or _needs_inertial(cfg):
        inertial = (hold_index < 0)[:, None] * _leg_inertial(tree, cfg.ft_link, q, t, R_WB, bodies, rotvec)
        clean = clean + cfg.inertial_load * inertial
    ctx = _context(cfg, cfg.recording, t, R_WB, hold_index, clean, offset, q, joint_limits(tree), inertial)
    w, R_meas = _sense(cfg, cfg.recording, t, R_WB, hold_index, clean, offset, streams, ctx)
    held = hold_index >= 0
    truth = {**_common_truth(cfg, offset, rotvec, len(t), held),
             "ft_link": cfg.ft_link,
             "load_mass_kg": float(sum(m for m, _ in bodies.values())),
             "bodies": {l: {"mass_kg": m, "com_m": [float(x) for x in c]} for l, (m, c) in bodies.items()},
             "nominal_bodies": {l: {"mass_kg": tree.bodies[l].mass_kg, "com_m": [float(x) for x in tree.bodies[l].com_m]} for l in load},
             "com_frame": "each body's own link frame"}
    robot = {"name": tree.name, "g": float(cfg.g), "legs": [cfg.transducer], "urdf": "robot.urdf",
             "transducers": {cfg.transducer: {"link": cfg.ft_link}}}
    return FreeLoadResult(cfg, _frame(cfg, t, w, q, R_meas, _effect_columns(cfg, ctx)), held, hold_index, clean, R_WB, truth, robot, _manifest(cfg),
                          urdf_text=cfg.urdf_path.read_text(), q=q)


def simulate_free(cfg: PayloadConfig | UrdfLegConfig) -> FreeLoadResult:
    """Dispatch on ``cfg.kind``."""
    if isinstance(cfg, PayloadConfig):
        return simulate_payload(cfg)
    if isinstance(cfg, UrdfLegConfig):
        return simulate_urdf_leg(cfg)
    raise TypeError(f"simulate_free: expected PayloadConfig or UrdfLegConfig, got {type(cfg).__name__}")
