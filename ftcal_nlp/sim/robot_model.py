"""The true BigAnt of the simulator: transducer poses, leg masses, leg CoM curves, toe loops.

Frames (``shared/DATA_FORMAT.md`` sec. 1): ``B`` body frame at the chassis'
geometric centre; ``ft_k`` the k-th transducer frame, whose true pose in B is
``(R_k, p_k)`` = nominal pose (``robot.toml``) composed with a mounting error
``R_tilde_k`` of ~1.5 deg and a translation error of a few mm (report eq. 2,
steps 1-2). Each leg hangs from its transducer, so its geometry is fixed in
``ft_k``:

* leg CoM ``r_k(phi)`` in ft_k (report Fig. 4 / Fig. 7): ``x, z = A sin(phi + C) + D``,
  ``y`` constant;
* toe loop (report Fig. 1, right): in the nominal leg frame (B axes at ft_k's
  origin) ``x = -reach sin(phi)``, ``y`` = an outward constant and, with
  ``u = (1 - cos phi)/2``,

      z = -depth + c u + (lift - c) u^3,   c = (rise - lift u_s^3) / (u_s - u_s^3),

  ``u_s = u(36 deg)``: straight down at ``phi = 0``, a flat-ish bottom where the
  foot stands ``rise`` (several mm, per leg) higher at +-36 deg than at 0 (the
  four-bar's stance arc, radius ~0.25 m), lifted ``lift`` clear at ``phi = pi``;
  mapped into ft_k by the nominal rotation (the mounting error then carries it
  with the transducer).

Offsets ``w_o`` and leg weights ``m_k g`` follow the report's Table II. The body
without legs has its CoM ``com_body_m`` off the geometric centre; its weight is
``M_b g = mass_kg g - sum_k m_k g`` (legs carry ~46 % of the mass).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.calibration import Calibration, LegCalibration
from ..core.geometry import rotvec_to_rotation
from ..core.robot import Robot, Transducer

LEGS = ("FL", "ML", "HL", "FR", "MR", "HR")
COM_GRID_POINTS = 72
STANCE_EDGE_RAD = np.radians(36.0)  # the report's standing grid angle, where the toe loop's rise is set

# Report Table II: offsets [fx, fy, fz, tx, ty, tz] (N, N*m) in ft_k and leg weights (N).
TABLE_II_OFFSETS = {
    "HL": (1.47, -1.30, -5.61, 0.2457, 0.002, 0.034),
    "ML": (1.419, -4.884, -0.406, -0.0136, 0.0808, 0.0144),
    "FL": (0.57, 3.71, -2.039, 0.2176, 0.0921, -0.0177),
    "HR": (-8.49, -1.448, -2.43, -0.3159, 0.3449, 0.001),
    "MR": (-0.06, -0.123, -0.07, -0.2392, -0.0982, 0.004),
    "FR": (-0.93, 0.653, -2.183, -0.3611, -0.153, 0.0222),
}
TABLE_II_WEIGHT_N = {"HL": 6.2, "ML": 6.2, "FL": 6.2, "HR": 6.1, "MR": 6.2, "FR": 6.4}


def nominal_robot(mass_kg: float = 8.18, g: float = 9.81) -> Robot:
    """BigAnt as in ``shared/sample/robot.toml``: hips at (+-0.25|0, +-0.15, 0) m,
    right-side transducers turned 180 deg about z."""
    rz180 = np.diag([-1.0, -1.0, 1.0])
    tr = {}
    for k in LEGS:
        x = {"F": 0.25, "M": 0.0, "H": -0.25}[k[0]]
        y = 0.15 if k[1] == "L" else -0.15
        tr[k] = Transducer(k, np.array([x, y, 0.0]), np.eye(3) if k[1] == "L" else rz180.copy())
    return Robot("bigant", float(mass_kg), float(g), LEGS, tr)


@dataclass(frozen=True)
class TrueRobot:
    """Every true parameter, stacked in leg order ``robot.legs`` (K legs).

    ``R`` (K, 3, 3) ft_k -> B; ``p`` (K, 3) ft_k origins in B (m); ``offsets``
    (K, 6); ``weights_N`` (K,); leg CoM in ft_k ``com_amp``, ``com_phase``,
    ``com_mean`` (K, 3) with ``r = amp sin(phi + phase) + mean`` (amp of y is 0);
    toe loop ``toe_reach``, ``toe_depth``, ``toe_lift``, ``toe_y`` (K,) in the
    nominal leg frame and ``toe_rise`` (K,), the foot's height at +-36 deg above
    its lowest point (None: the flattest loop, ``c = 0``); ``com_body_m`` (3,)
    in B; ``mass_kg`` total.
    """

    robot: Robot
    R: np.ndarray
    p: np.ndarray
    offsets: np.ndarray
    weights_N: np.ndarray
    com_amp: np.ndarray
    com_phase: np.ndarray
    com_mean: np.ndarray
    toe_reach: np.ndarray
    toe_depth: np.ndarray
    toe_lift: np.ndarray
    toe_y: np.ndarray
    com_body_m: np.ndarray
    mass_kg: float
    g: float
    toe_rise: np.ndarray | None = None

    @property
    def legs(self) -> tuple[str, ...]:
        return self.robot.legs

    @property
    def weight_N(self) -> float:
        return self.mass_kg * self.g

    @property
    def body_weight_N(self) -> float:
        """``M_b g``, the body without legs."""
        return self.weight_N - float(self.weights_N.sum())

    @property
    def p_prime(self) -> np.ndarray:
        """ft_k origins relative to the body-without-legs CoM, B axes, (K, 3) m."""
        return self.p - self.com_body_m

    def leg_com_ft(self, phi: np.ndarray) -> np.ndarray:
        """``r_k(phi)`` in ft_k, (..., K, 3) m, for shaft angles ``phi`` (..., K)."""
        phi = np.asarray(phi, float)[..., None]
        return self.com_amp * np.sin(phi + self.com_phase) + self.com_mean

    def foot_ft(self, phi: np.ndarray) -> np.ndarray:
        """Toe point in ft_k, (..., K, 3) m (the closed toe loop over ``phi`` (..., K))."""
        phi = np.asarray(phi, float)
        leg = np.stack([-self.toe_reach * np.sin(phi), np.broadcast_to(self.toe_y, phi.shape), self.toe_height(phi) - self.toe_depth],
                       axis=-1)
        R_nom = self.robot.nominal_rotations()
        return np.einsum("kji,...kj->...ki", R_nom, leg)  # R_nom^T (nominal leg frame has B axes)

    def toe_height(self, phi: np.ndarray) -> np.ndarray:
        """Height of the toe above its lowest point (phi = 0), nominal leg frame, (..., K) m."""
        u = (1.0 - np.cos(np.asarray(phi, float))) / 2.0
        return self.toe_curve * u + (self.toe_lift - self.toe_curve) * u**3

    @property
    def toe_curve(self) -> np.ndarray:
        """``c`` of the toe loop (K,): the stance arc's share of the lift."""
        if self.toe_rise is None:
            return np.zeros_like(self.toe_lift)
        us = (1.0 - np.cos(STANCE_EDGE_RAD)) / 2.0
        return (self.toe_rise - self.toe_lift * us**3) / (us - us**3)

    def ft_to_body(self, x_ft: np.ndarray) -> np.ndarray:
        """Points in ft_k (..., K, 3) -> B (..., K, 3)."""
        return np.einsum("kij,...kj->...ki", self.R, x_ft) + self.p

    def total_com_B(self, phi: np.ndarray) -> np.ndarray:
        """CoM of the whole robot (body and legs) in B, (..., 3) m, for ``phi`` (..., K)."""
        legs_B = self.ft_to_body(self.leg_com_ft(phi))
        num = self.body_weight_N * self.com_body_m + np.einsum("k,...ki->...i", self.weights_N, legs_B)
        return num / self.weight_N

    def calibration(self, n_grid: int = COM_GRID_POINTS) -> Calibration:
        """The truth as a :class:`Calibration` (model ``truth``), leg CoM on a periodic grid."""
        grid = np.arange(n_grid) * (2 * np.pi / n_grid)
        xyz = self.leg_com_ft(np.repeat(grid[:, None], len(self.legs), axis=1))  # (G, K, 3)
        legs = {
            k: LegCalibration(
                offset=self.offsets[i].copy(),
                leg_weight_N=float(self.weights_N[i]),
                com_phi=grid.copy(),
                com_xyz=xyz[:, i].copy(),
                rotation_to_body=self.R[i].copy(),
                position_from_com_m=self.p_prime[i].copy(),
            )
            for i, k in enumerate(self.legs)
        }
        return Calibration(legs, self.mass_kg, self.g, model="truth", com_body_m=self.com_body_m.copy())

    def truth_json_dict(self, *, seed: int, effect: str = "none", scale: float = 1.0, in_library: bool = False,
                        n_grid: int = COM_GRID_POINTS) -> dict:
        """``truth.json`` in the layout of ``shared/sample/truth.json``."""
        cal = self.calibration(n_grid)
        legs = {}
        for i, k in enumerate(self.legs):
            lc = cal.legs[k]
            legs[k] = {
                "offset": [float(v) for v in lc.offset],
                "leg_weight_N": float(lc.leg_weight_N),
                "rotation_to_body": lc.rotation_to_body.tolist(),
                "position_m": self.p[i].tolist(),
                "position_from_com_m": lc.position_from_com_m.tolist(),
                "leg_com_grid": {"phi": lc.com_phi.tolist(), "xyz": lc.com_xyz.tolist()},
            }
        return {
            "effect": effect,
            "scale": float(scale),
            "seed": int(seed),
            "in_library": bool(in_library),
            "legs": legs,
            "com_body_m": self.com_body_m.tolist(),
            "mass_true_kg": float(self.mass_kg),
        }


def draw_true_robot(cfg, rng: np.random.Generator) -> TrueRobot:
    """Draw the true robot for settings ``cfg`` (a :class:`~ftcal_nlp.sim.config.SimConfig`)."""
    robot = nominal_robot(cfg.mass_kg, cfg.g)
    K = robot.n_legs
    # Mounting errors: per-component normal with the configured rms norm.
    rot_err = rng.normal(0.0, np.radians(cfg.mounting_rot_deg) / np.sqrt(3), (K, 3))
    R = np.einsum("kij,kjl->kil", rotvec_to_rotation(rot_err), robot.nominal_rotations())
    p = robot.nominal_positions() + rng.normal(0.0, cfg.mounting_trans_mm * 1e-3 / np.sqrt(3), (K, 3))
    offsets = np.array([TABLE_II_OFFSETS[k] for k in robot.legs], float)
    weights = np.array([TABLE_II_WEIGHT_N[k] for k in robot.legs]) + rng.normal(0.0, cfg.leg_weight_spread_N, K)

    # Leg CoM in the nominal leg frame (B axes): x follows -sin(phi) (the leg swings
    # back as phi grows), z lowest near phi = 0, y outward; Fig. 4 sizes.
    side = np.array([1.0 if k[1] == "L" else -1.0 for k in robot.legs])
    amp_x = rng.uniform(0.022, 0.035, K)
    amp_z = rng.uniform(0.017, 0.023, K)
    ph_x = np.pi + rng.uniform(-0.4, 0.4, K)
    ph_z = -np.pi / 2 + rng.uniform(-0.4, 0.4, K)
    mean_y = side * rng.uniform(0.037, 0.045, K)
    mean_z = rng.uniform(-0.134, -0.123, K)
    # Into ft_k by the nominal rotation, a signed axis permutation here: a sign
    # flip of x becomes a phase shift of pi.
    R_nom = robot.nominal_rotations()
    sx, sy = R_nom[:, 0, 0], R_nom[:, 1, 1]
    if not np.allclose(np.abs(R_nom), np.eye(3)):
        raise ValueError("draw_true_robot: nominal rotations must be diagonal (+-1) for the sinusoid CoM model")
    com_amp = np.stack([amp_x, np.zeros(K), amp_z], axis=1)
    com_phase = np.stack([np.mod(ph_x + np.where(sx < 0, np.pi, 0.0), 2 * np.pi), np.zeros(K), ph_z], axis=1)
    com_mean = np.stack([np.zeros(K), sy * mean_y, mean_z], axis=1)

    toe_y = side * rng.uniform(0.045, 0.055, K)
    toe_depth = cfg.toe_depth_m + rng.normal(0.0, cfg.toe_depth_spread_mm * 1e-3, K)
    com_body = rng.uniform(-1.0, 1.0, 3) * np.asarray(cfg.com_body_range_m, float)
    # Drawn last, so the draws above stay those of earlier versions for a seed.
    toe_rise = (cfg.toe_stance_rise_mm + rng.uniform(-1.0, 1.0, K) * cfg.toe_rise_spread_mm) * 1e-3
    # The loop rises monotonically from phi = 0 to pi iff 0 <= c <= 1.5 lift.
    us = (1.0 - np.cos(STANCE_EDGE_RAD)) / 2.0
    lo, hi = cfg.toe_lift_m * us**3, cfg.toe_lift_m * (1.5 * (us - us**3) + us**3)
    if np.any(toe_rise < lo) or np.any(toe_rise > hi):
        raise ValueError(f"SimConfig: toe_stance_rise_mm +- toe_rise_spread_mm must keep every leg's rise within "
                         f"[{lo * 1e3:.2f}, {hi * 1e3:.1f}] mm for toe_lift_m = {cfg.toe_lift_m}: else the toe loop is "
                         f"not lowest at phi = 0 and rising to phi = pi")
    return TrueRobot(
        robot=robot, R=R, p=p, offsets=offsets, weights_N=weights,
        com_amp=com_amp, com_phase=com_phase, com_mean=com_mean,
        toe_reach=np.full(K, cfg.toe_reach_m), toe_depth=toe_depth, toe_lift=np.full(K, cfg.toe_lift_m), toe_y=toe_y,
        com_body_m=com_body, mass_kg=float(cfg.mass_kg), g=float(cfg.g), toe_rise=toe_rise,
    )
