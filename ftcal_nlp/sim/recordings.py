"""True (noise-free) time series of the three experiments: hanging, standing, walking.

Each returns a :class:`TrueSeries`: sample times on the session clock, shaft
angles, the true orientation ``R_WB`` and the true applied wrench ``w_a`` of each
leg on its transducer (report eq. 1, in ft_k about its origin). Readings
(offsets, effects, noise) and motion capture are added in ``simulate.py``.

* Hanging (report Sec. III-A, eqs. 4-7): gravity along ``R_tilt g_body`` in B,
  ``R_tilt`` a ~2 deg rotation per recording; every leg turns at its own slow
  speed and phase, so ``w_a = [m_k g u; r_k(phi) x m_k g u]``, ``u = R_k^T R_tilt g_body``.
* Standing (report Sec. I-B): poses of the 3^6 grid, each solved for the
  compliant-foot equilibrium (``statics.py``), a share of them on a board
  sloping ``board_tilt_deg`` downhill in a random direction (with gravity then
  far from the body's z, the readings pin down the turn of all transducers about
  z, which level poses leave free); a pose that tips or slips is skipped; the
  ground force on foot k adds ``[f; foot_k(phi) x f]`` (f in ft_k). After each
  pose change, wrenches and orientation ring into the new equilibrium as an
  underdamped second-order response to the commanded shaft motion.
* Walking (report Sec. IV-3): a Buehler clock drives two tripods half a cycle
  apart (slow stance sweep, fast swing); equilibrium solved at every sample;
  the heading turns slowly. Its per-foot ground wrench in the heading frame about
  the instantaneous total CoM is the walking truth.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from ..core.geometry import remove_yaw, rotation_between, rotation_to_rotvec, rotvec_to_rotation
from .statics import applied_wrench, board_rotation, contact_forces, heading_rotation, internal_forces, solve_stance

TRIPOD_A = ("FL", "MR", "HL")


@dataclass(frozen=True)
class TrueSeries:
    """One recording before the sensors: ``t`` (N,) s; ``phi`` (N, K) rad; ``R_WB``
    (N, 3, 3) true orientation; ``applied`` (N, K, 6) in ft_k; ``pose_index`` (N,)
    (-1 outside standing); ``mocap_lost`` (N,) rows whose tracking is lost."""

    name: str
    kind: str
    t: np.ndarray
    phi: np.ndarray
    R_WB: np.ndarray
    applied: np.ndarray
    pose_index: np.ndarray
    gravity_body: np.ndarray | None = None
    mocap_lost: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


def _clock(t0: float, n: int, rate_hz: float) -> np.ndarray:
    return np.round(t0 + np.arange(n) / rate_hz, 6)  # whole microseconds: clean session times in CSV


def random_tilt(deg: float, rng: np.random.Generator) -> np.ndarray:
    """A rotation of about ``deg`` degrees (0.75..1.25 of it) about a random axis."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return rotvec_to_rotation(axis * np.radians(deg) * rng.uniform(0.75, 1.25))


def hanging_series(truth, cfg, gravity_body, t0: float, rng: np.random.Generator, name: str) -> TrueSeries:
    """Hanging with nominal gravity direction ``gravity_body`` (3,) in B."""
    K = len(truth.legs)
    n = int(round(cfg.hanging_cycles * cfg.hanging_cycle_s * cfg.rate_hz))
    t = _clock(t0, n, cfg.rate_hz)
    R_tilt = random_tilt(cfg.hanging_tilt_deg, rng)
    g_B = R_tilt @ np.asarray(gravity_body, float)
    omega = 2 * np.pi / cfg.hanging_cycle_s * (1 + rng.uniform(-cfg.hanging_speed_spread, cfg.hanging_speed_spread, K))
    phi = rng.uniform(0, 2 * np.pi, K) + np.outer(t - t0, omega)
    R_WB = np.broadcast_to(rotation_between(g_B, np.array([0.0, 0.0, -1.0])), (n, 3, 3))  # R_WB g_B = -z
    w = applied_wrench(R_WB, phi, truth, None)
    return TrueSeries(name, "hanging", t, phi, np.ascontiguousarray(R_WB), w, np.full(n, -1),
                      gravity_body=np.asarray(gravity_body, float), extra={"R_tilt": R_tilt, "gravity_true_B": g_B})


# ----------------------------------------------------------------------------- standing


def pose_grid(angles_deg, n_legs: int) -> np.ndarray:
    """All combinations of shaft angles, (A^K, K) rad."""
    return np.radians(np.array(list(itertools.product(angles_deg, repeat=n_legs)), float))


def transition_profile(cfg) -> tuple[np.ndarray, np.ndarray]:
    """Commanded shaft progress ``s`` and the ringing response ``y`` over one pose, both (n,) from 0 to 1.

    ``s`` is a smoothstep over ``move_s``; ``y`` is the underdamped second-order
    system ``y'' = w_n^2 (s - y) - 2 a y'`` (envelope ``exp(-a t)``, ringing at
    ``transient_freq_hz``) driven by ``s``, so it overshoots and settles.
    """
    n = int(round(cfg.pose_s * cfg.rate_hz))
    tau = np.arange(n) / cfg.rate_hz
    x = np.clip(tau / max(cfg.move_s, 1e-9), 0.0, 1.0)
    s = x * x * (3 - 2 * x)
    a, wd = cfg.transient_decay_per_s, 2 * np.pi * cfg.transient_freq_hz
    wn2 = a * a + wd * wd
    _, y, _ = signal.lsim(([wn2], [1.0, 2 * a, wn2]), s, tau)
    return s, y


@dataclass(frozen=True)
class StandingPoses:
    phi: np.ndarray           # (P, K) kept poses
    skipped: np.ndarray       # (S, K) poses where the robot would tip or slip
    R_tilt: np.ndarray        # (P, 3, 3) B -> W, heading arbitrary
    applied: np.ndarray       # (P, K, 6)
    ground_W0: np.ndarray     # (P, K, 3) foot forces, world axes of R_tilt
    normal_N: np.ndarray      # (P, K) vertical foot forces
    on_board: np.ndarray | None = None  # (P,) taken on the tilted board
    R_ground: np.ndarray | None = None  # (P, 3, 3) ground frame (z its normal) -> world axes of R_tilt


def solve_poses(truth, cfg, phi_req: np.ndarray, rng: np.random.Generator, board_dir: np.ndarray | None = None) -> StandingPoses:
    """Equilibrium of each requested pose (R, K); tipping or slipping poses are set aside.

    ``board_dir`` (R,): downhill direction (rad, in the board's frame, ~B) of poses
    taken on the board, NaN for level ground; None: all level.
    """
    feet_B = truth.ft_to_body(truth.foot_ft(phi_req))
    com_B = truth.total_com_B(phi_req)
    board = np.zeros(len(phi_req), bool) if board_dir is None else np.isfinite(board_dir)
    ground = None
    if board_dir is not None and board.any():   # (board is all False without board_dir)
        ground = np.broadcast_to(np.eye(3), (len(phi_req), 3, 3)).copy()
        ground[board] = board_rotation(np.radians(cfg.board_tilt_deg), board_dir[board])
    bumps = rng.normal(0.0, cfg.ground_roughness_mm * 1e-3, phi_req.shape)
    st = solve_stance(feet_B, com_B, truth.weight_N, cfg.foot_stiffness_N_per_m, max_tilt_deg=cfg.max_tilt_deg,
                      ground=ground, bumps=bumps)
    raw = rng.normal(0.0, cfg.internal_force_N, phi_req.shape + (2,))
    F, slipping = contact_forces(st, raw, np.where(board, cfg.board_friction_mu, cfg.friction_mu))
    keep = st.ok & ~slipping
    w = applied_wrench(st.R_tilt[keep], phi_req[keep], truth, F[keep])  # heading drops out of w_a
    R_ground = np.broadcast_to(np.eye(3), (len(phi_req), 3, 3)) if st.R_ground is None else st.R_ground
    return StandingPoses(phi_req[keep], phi_req[~keep], st.R_tilt[keep], w, F[keep], st.normal_N[keep], board[keep],
                         np.ascontiguousarray(R_ground[keep]))


def standing_series(truth, cfg, t0: float, rng: np.random.Generator, name: str = "standing"):
    """Standing through the pose grid. Returns ``(TrueSeries, StandingPoses, windows (P, 2))``."""
    K = len(truth.legs)
    grid = pose_grid(cfg.pose_angles_deg, K)
    order = rng.permutation(len(grid))
    if cfg.n_poses is not None:
        order = order[: cfg.n_poses]
    n_board = int(round(cfg.board_pose_fraction * len(order)))
    board_dir = np.full(len(order), np.nan)
    board_dir[rng.choice(len(order), n_board, replace=False)] = rng.uniform(0.0, 2 * np.pi, n_board)
    poses = solve_poses(truth, cfg, grid[order], rng, board_dir)
    P = len(poses.phi)
    if P == 0:
        raise ValueError("simulate: the robot tips over or slips in every requested standing pose")
    s, y = transition_profile(cfg)
    n = len(s)
    psi = rng.uniform(-np.pi, np.pi) + np.cumsum(rng.normal(0.0, np.radians(cfg.heading_step_deg), P))
    R_pose = heading_rotation(psi) @ poses.R_tilt                                     # (P, 3, 3)
    prev = np.concatenate([[0], np.arange(P - 1)])                                     # first pose starts settled
    phi = poses.phi[prev][:, None] + (poses.phi - poses.phi[prev])[:, None] * s[None, :, None]
    lag = (1.0 - y)[None, :, None, None]
    w = poses.applied[:, None] + (poses.applied[prev] - poses.applied)[:, None] * lag
    # Orientation rings along the geodesic from the previous pose's attitude.
    rv = rotation_to_rotvec(np.swapaxes(R_pose, 1, 2) @ R_pose[prev])                 # (P, 3)
    R = R_pose[:, None] @ rotvec_to_rotation(rv[:, None] * (1.0 - y)[None, :, None])
    t = _clock(t0, P * n, cfg.rate_hz)
    starts = t[::n]
    windows = np.stack([starts + cfg.settle_s, starts + (n - 1) / cfg.rate_hz], axis=1)
    lost = mocap_blips(t, cfg, rng)
    whole = rng.random(P) < cfg.mocap_dropout_rate
    for p in np.flatnonzero(whole):
        lost |= (t >= windows[p, 0] - rng.uniform(0.0, 1.5)) & (t <= windows[p, 1])
    ser = TrueSeries(
        name, "standing", t, phi.reshape(P * n, K), R.reshape(P * n, 3, 3), w.reshape(P * n, K, 6),
        np.repeat(np.arange(P), n), mocap_lost=lost, extra={"mocap_lost_poses": np.flatnonzero(whole)},
    )
    return ser, poses, windows


def mocap_blips(t: np.ndarray, cfg, rng: np.random.Generator) -> np.ndarray:
    """Short tracking losses: a Poisson number of intervals of random length."""
    lost = np.zeros(len(t), bool)
    span = t[-1] - t[0]
    for _ in range(rng.poisson(cfg.mocap_blip_rate_hz * span)):
        a = rng.uniform(t[0], t[-1])
        lost |= (t >= a) & (t < a + rng.uniform(*cfg.mocap_blip_s))
    return lost


# ----------------------------------------------------------------------------- walking


def buehler_phi(theta: np.ndarray, duty: float, sweep: float) -> np.ndarray:
    """Unwrapped shaft angle of a Buehler clock at cycle phase ``theta`` (cycles, unwrapped):
    stance from ``-sweep/2`` to ``+sweep/2`` during ``duty`` of the cycle, fast swing the rest."""
    cyc = np.floor(theta)
    fr = theta - cyc
    stance = -sweep / 2 + sweep * fr / duty
    swing = sweep / 2 + (2 * np.pi - sweep) * (fr - duty) / (1 - duty)
    return 2 * np.pi * cyc + np.where(fr < duty, stance, swing)


def walking_series(truth, cfg, t0: float, rng: np.random.Generator, name: str = "walk"):
    """Quasi-static tripod walk. Returns ``(TrueSeries, ground (N, K, 6))``, the per-foot
    ground contact wrench in the heading frame about the instantaneous total CoM."""
    K = len(truth.legs)
    n = int(round(cfg.walk_cycles / cfg.walk_freq_hz * cfg.rate_hz))
    t = _clock(t0, n, cfg.rate_hz)
    offset = np.array([0.0 if k in TRIPOD_A else 0.5 for k in truth.legs])
    theta = cfg.walk_freq_hz * (t - t0)[:, None] + offset + rng.uniform(0.0, 0.1)
    phi = buehler_phi(theta, cfg.walk_duty, np.radians(cfg.walk_sweep_deg))
    feet_B = truth.ft_to_body(truth.foot_ft(phi))
    com_B = truth.total_com_B(phi)
    st = solve_stance(feet_B, com_B, truth.weight_N, cfg.foot_stiffness_N_per_m, max_tilt_deg=cfg.max_tilt_deg)
    if not st.ok.all():
        i = int(np.argmin(st.ok))
        raise ValueError(f"simulate: the walking gait tips over at t = {t[i]:.2f} s (phi = {np.round(phi[i], 3).tolist()}); "
                         "check walk_sweep_deg / walk_duty / toe settings")
    # Slowly varying friction-locked forces (slip while turning), fading with the foot's load.
    freqs = rng.uniform(0.05, 0.3, (3, K, 2))
    phases = rng.uniform(0, 2 * np.pi, (3, K, 2))
    raw = np.sin(2 * np.pi * freqs[None] * (t - t0)[:, None, None, None] + phases[None]).sum(1)
    raw *= cfg.walk_internal_force_N / np.sqrt(1.5) * np.minimum(1.0, st.normal_N / (truth.weight_N / 6))[..., None]
    F0 = st.normal_N[..., None] * np.array([0.0, 0.0, 1.0]) + internal_forces(st.feet_W, st.normal_N, raw, cfg.friction_mu)
    psi = rng.uniform(-np.pi, np.pi) + np.radians(cfg.walk_turn_deg_per_cycle) * cfg.walk_freq_hz * (t - t0)
    R_WB = heading_rotation(psi) @ st.R_tilt
    F_W = np.einsum("nij,nkj->nki", heading_rotation(psi), F0)
    w = applied_wrench(R_WB, phi, truth, F_W)
    # Truth in the heading frame H (OUTPUT_FORMAT.md): about the total CoM c, contact torque zero at the toe.
    R_HB = remove_yaw(R_WB)
    R_HW = R_HB @ np.swapaxes(R_WB, 1, 2)
    F_H = np.einsum("nij,nkj->nki", R_HW, F_W)
    lever = np.einsum("nij,nkj->nki", R_HB, feet_B - com_B[:, None])
    ground = np.concatenate([F_H, np.cross(lever, F_H)], axis=-1)
    ser = TrueSeries(name, "walking", t, phi, R_WB, w, np.full(n, -1), mocap_lost=mocap_blips(t, cfg, rng),
                     extra={"normal_N": st.normal_N})
    return ser, ground
