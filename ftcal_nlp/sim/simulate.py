"""``simulate(cfg)``: a whole calibration session of a BigAnt-like hexapod, with its truth.

Order on one session clock (like ``shared/sample``): hanging +x, -x, +z, -z
(report Sec. III-A), standing through the pose grid (Sec. I-B), a tripod walk
(Sec. IV-3). Readings follow the report's sensing model (eq. 1)

    w_m = w_a + w_o + n,     n ~ N(0, diag(s_f^2 I, s_t^2 I))

with effect injectors (``effects.py``) applied to ``w_a + w_o`` before the
noise; motion capture reports ``R_WB exp([delta])``, ``delta`` white jitter
plus, while standing, an error constant through each pose (so a pose's median
keeps it, as in ``shared/sample``), with NaN rows where tracking is lost.
Randomness comes from one ``np.random.SeedSequence(seed)`` split into
independent streams (robot, hanging, standing, walking, sensors, effects, the
held mocap error), so a seed fixes every array.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..core.calibration import Calibration
from ..core.data import Dataset, Recording, ground_wrench_frame
from ..core.geometry import rotation_to_quat, rotvec_to_rotation
from .config import SimConfig
from .effects import apply_orientation, apply_readings, apply_robot, effect_label
from .recordings import TrueSeries, hanging_series, standing_series, walking_series
from .robot_model import TrueRobot, draw_true_robot

HANGING = (("hang_xpos", (1.0, 0.0, 0.0)), ("hang_xneg", (-1.0, 0.0, 0.0)),
           ("hang_zpos", (0.0, 0.0, 1.0)), ("hang_zneg", (0.0, 0.0, -1.0)))


@dataclass(frozen=True)
class SimResult:
    """A simulated session and everything true about it.

    ``dataset``: recordings hang_xpos, hang_xneg, hang_zpos, hang_zneg, standing,
    walk (nominal robot of ``robot.toml``). ``truth``: the true calibration
    (model ``truth``, ``com_body_m`` set). ``truth_positions_m``: true ft_k
    origins in B. ``walk_truth``: per-foot ground contact wrench of the walk in
    the heading frame about the instantaneous CoM (columns ``t``, ``{leg}_fx``..,
    ``total_fx``..). ``pose_windows`` (P, 2): first and last sample time of each
    standing pose's nominally steady part. ``pose_phi`` (P, K) and
    ``skipped_pose_phi`` (S, K): kept and tipping (or slipping) poses. ``true_robot``: every
    true parameter; ``hanging_tilt``: the hanging tilt rotation per recording.
    ``pose_on_board`` (P,): poses on the tilted board; ``pose_ground_N`` (P, K, 3):
    true ground force on each foot, N, in world axes up to the pose's heading (z up);
    ``pose_mocap_error`` (P, 3): the motion-capture error rotation vector (rad,
    body axes) held through each pose, white jitter aside.
    """

    dataset: Dataset
    truth: Calibration
    truth_positions_m: dict[str, np.ndarray]
    walk_truth: pd.DataFrame
    pose_windows: np.ndarray
    true_robot: TrueRobot
    config: SimConfig = field(default_factory=SimConfig)
    pose_phi: np.ndarray | None = None
    skipped_pose_phi: np.ndarray | None = None
    hanging_tilt: dict = field(default_factory=dict)
    pose_on_board: np.ndarray | None = None
    pose_ground_N: np.ndarray | None = None
    pose_mocap_error: np.ndarray | None = None

    def truth_json_dict(self) -> dict:
        """``truth.json`` content, in the layout of ``shared/sample/truth.json``."""
        effect, scale, in_lib = effect_label(self.config.effects)
        return self.true_robot.truth_json_dict(seed=self.config.seed, effect=effect, scale=scale, in_library=in_lib)


def _sensor_readings(ser: TrueSeries, truth: TrueRobot, cfg: SimConfig, rng: np.random.Generator,
                     effect_rngs: list, pose_error: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Readings (N, K, 6) and quaternions (N, 4) (None when hanging) of one recording;
    ``pose_error`` (P, 3) mocap error held through each standing pose (rotation vectors, rad)."""
    ctx = dict(kind=ser.kind, name=ser.name, t=ser.t, phi=ser.phi, R_WB=ser.R_WB, applied=ser.applied,
               pose_index=ser.pose_index, truth=truth)
    clean = apply_readings(cfg.effects, ctx, ser.applied + truth.offsets, effect_rngs)
    sigma = np.array([cfg.noise_force_N] * 3 + [cfg.noise_torque_Nm] * 3)
    w_m = clean + rng.standard_normal(clean.shape) * sigma
    if ser.kind == "hanging":
        return w_m, None
    delta = rng.normal(0.0, np.radians(cfg.mocap_jitter_deg), (len(ser.t), 3))
    if pose_error is not None:
        delta += pose_error[ser.pose_index]
    R_meas = apply_orientation(cfg.effects, ctx, ser.R_WB @ rotvec_to_rotation(delta), effect_rngs)
    quat = rotation_to_quat(R_meas)
    if ser.mocap_lost is not None:
        quat[ser.mocap_lost] = np.nan
    return w_m, quat


def _recording(ser: TrueSeries, legs: tuple[str, ...], w_m: np.ndarray, quat: np.ndarray | None,
               temperature: np.ndarray | None = None) -> Recording:
    return Recording(
        name=ser.name, kind=ser.kind, t=ser.t,
        phi={k: ser.phi[:, i].copy() for i, k in enumerate(legs)},
        wrench={k: np.ascontiguousarray(w_m[:, i]) for i, k in enumerate(legs)},
        quat=quat, gravity_body=ser.gravity_body,
        temperature={} if temperature is None else {k: temperature[:, i].copy() for i, k in enumerate(legs)},
    )


def _temperature(ser: TrueSeries, truth: TrueRobot, cfg: SimConfig) -> np.ndarray | None:
    """The transducers' temperatures (N, K) degC of an injector that has them (``temperature(ctx)``), else None."""
    from ..effects import InjectionContext

    for e in cfg.effects:
        if hasattr(e, "temperature"):
            return e.temperature(InjectionContext(kind=ser.kind, name=ser.name, t=ser.t, phi=ser.phi, R_WB=ser.R_WB,
                                                  applied=ser.applied, pose_index=ser.pose_index, truth=truth,
                                                  rng=np.random.default_rng(0)))
    return None


def simulate(cfg: SimConfig = SimConfig()) -> SimResult:
    """Simulate a session (hanging x4, standing, walking) and its truth; deterministic in ``cfg.seed``."""
    ss = np.random.SeedSequence(cfg.seed)
    s_robot, s_hang, s_stand, s_walk, s_sensor, s_effect, s_mocap = ss.spawn(7)
    truth = draw_true_robot(cfg, np.random.default_rng(s_robot))
    legs = truth.legs
    rng_hang = np.random.default_rng(s_hang)
    series: list[TrueSeries] = []
    t0 = cfg.t0_s
    for name, gb in HANGING:
        ser = hanging_series(truth, cfg, gb, t0, rng_hang, name)
        series.append(ser)
        t0 = ser.t[-1] + cfg.gap_s
    stand, poses, windows = standing_series(truth, cfg, t0, np.random.default_rng(s_stand))
    series.append(stand)
    walk, ground = walking_series(truth, cfg, stand.t[-1] + cfg.gap_s, np.random.default_rng(s_walk)) if cfg.walk_cycles > 0 else (None, None)
    if walk is not None:
        series.append(walk)

    rng_sensor = np.random.default_rng(s_sensor)
    # Its own stream: the readings' noise stays that of a seed whatever this error's size.
    pose_error = np.random.default_rng(s_mocap).normal(0.0, np.radians(cfg.mocap_pose_error_deg), (len(poses.phi), 3))
    effect_seeds = s_effect.spawn(len(series))
    recs = []
    for ser, es in zip(series, effect_seeds):
        effect_rngs = [np.random.default_rng(s) for s in es.spawn(len(cfg.effects))]
        w_m, quat = _sensor_readings(ser, truth, cfg, rng_sensor, effect_rngs, pose_error if ser.kind == "standing" else None)
        recs.append(_recording(ser, legs, w_m, quat, _temperature(ser, truth, cfg)))
    ds = Dataset(apply_robot(cfg.effects, truth.robot), tuple(recs))
    wt = ground_wrench_frame(walk.t, ground, legs) if walk is not None and ground is not None else ground_wrench_frame(np.zeros(0), np.zeros((0, len(legs), 6)), legs)
    return SimResult(
        dataset=ds,
        truth=truth.calibration(),
        truth_positions_m={k: truth.p[i].copy() for i, k in enumerate(legs)},
        walk_truth=wt,
        pose_windows=windows,
        config=cfg,
        true_robot=truth,
        pose_phi=poses.phi,
        skipped_pose_phi=poses.skipped,
        hanging_tilt={s.name: s.extra["R_tilt"] for s in series if s.kind == "hanging"},
        pose_on_board=poses.on_board,
        pose_ground_N=poses.ground_W0,
        pose_mocap_error=pose_error,
    )
