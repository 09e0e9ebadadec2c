"""Per-sample sensor noise estimated at calibration: transducer readings and motion-capture tilt.

Within a steady standing run (``standing.poses.steady_runs``) the robot is still,
so what moves the readings of leg k is measurement noise (report eq. 1, ``n``),
once the pose change has rung out: only the second half of each run is used
(the steady test looks at force derivatives, and a small torque ringing can
outlast it). Each half-run's readings are detrended by a straight line in time per channel (a
slow settle or thermal creep inside a run is not noise), and the residuals
``e`` (n_run, 6) of every run are pooled into

    Sigma_k = sum_runs e^T e / sum_runs (n_run - 2)          (6, 6), ft_k axes, N and N*m

the per-sample covariance of one reading (marginal, so it holds for coloured
noise too, which first differences would underrate). The motion-capture jitter
is the same statistic of the small rotations ``log(R_med^T R_i)`` (body axes,
rad) within the runs, ``Sigma_theta`` (3, 3). ``n_samples`` counts what went in;
the relative standard error of a variance from ``n`` samples is ``sqrt(2 / n)``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..core.data import Recording
from ..core.errors import DataFormatError
from ..core.geometry import quat_to_rotation, rotation_to_rotvec
from ..core.robot import Robot
from ..core.settings import PoseExtraction
from .standing.poses import steady_runs

__all__ = ["SensorNoise", "estimate_sensor_noise"]

log = logging.getLogger(__name__)

MIN_RUN = 10   # samples; shorter steady runs carry too little to detrend


@dataclass(frozen=True)
class SensorNoise:
    """``readings`` leg -> (6, 6) per-sample covariance in ft_k (N, N*m); ``orientation_rad`` (3, 3) per-sample
    covariance of the motion-capture rotation error in body axes (rad^2), or None when not measured;
    ``n_samples`` how many samples (less the detrending's dof) the estimate rests on."""

    readings: dict[str, np.ndarray]
    orientation_rad: np.ndarray | None
    n_samples: int

    def sd(self, leg: str) -> np.ndarray:
        """Standard deviations (6,) of leg ``leg``'s readings."""
        return np.sqrt(np.diag(self.readings[leg]))

    def to_json_dict(self) -> dict:
        return {"readings": {k: v.tolist() for k, v in self.readings.items()},
                "orientation_rad": None if self.orientation_rad is None else self.orientation_rad.tolist(),
                "n_samples": int(self.n_samples)}

    @classmethod
    def from_json_dict(cls, d: dict, source: str = "sensor_noise") -> "SensorNoise":
        try:
            rd = {k: np.array(v, float) for k, v in d["readings"].items()}
        except (KeyError, TypeError, AttributeError) as exc:
            raise DataFormatError(f"{source}: expected 'readings' = {{leg: 6x6 covariance}}, got {d!r:.200}") from exc
        for k, v in rd.items():
            if v.shape != (6, 6):
                raise DataFormatError(f"{source}: readings.{k}: expected a 6x6 covariance, got shape {v.shape}")
        o = d.get("orientation_rad")
        o = None if o is None else np.array(o, float)
        if o is not None and o.shape != (3, 3):
            raise DataFormatError(f"{source}: orientation_rad: expected a 3x3 covariance, got shape {o.shape}")
        return cls(rd, o, int(d.get("n_samples", 0)))


def _detrended(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Residuals of a least-squares line in ``t`` through each column of ``x`` (n, m)."""
    A = np.stack([np.ones_like(t), t - t.mean()], axis=1)
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    return x - A @ coef


def estimate_sensor_noise(recordings: list[Recording], robot: Robot, settings: PoseExtraction = PoseExtraction()) -> SensorNoise:
    """Pooled within-run covariances of every leg's readings and of the motion-capture orientation over the
    steady runs of the standing ``recordings`` (module docstring). Raises ``ValueError`` when no steady run
    of at least ``MIN_RUN`` samples is found."""
    legs = robot.legs
    S = {k: np.zeros((6, 6)) for k in legs}
    So = np.zeros((3, 3))
    n, no = 0, 0
    for rec in recordings:
        runs, _ = steady_runs(rec, robot, settings)
        W = rec.wrench_array(legs)
        for r0, r1 in runs:
            r0 = (r0 + r1) // 2
            if r1 - r0 < MIN_RUN:
                continue
            t = rec.t[r0:r1]
            for i, k in enumerate(legs):
                e = _detrended(W[r0:r1, i], t)
                S[k] += e.T @ e
            n += r1 - r0 - 2
            if rec.quat is None:
                continue
            q = rec.quat[r0:r1]
            ok = np.all(np.isfinite(q), axis=1)
            if ok.sum() < MIN_RUN:
                continue
            R = quat_to_rotation(q[ok])
            v = rotation_to_rotvec(np.einsum("ji,njk->nik", R[len(R) // 2], R))  # body axes, about the run's middle
            e = _detrended(v, t[ok])
            So += e.T @ e
            no += int(ok.sum()) - 2
    if n <= 0:
        raise DataFormatError(f"sensor noise: no steady standing run of at least {MIN_RUN} samples in "
                              f"{[r.path or r.name for r in recordings]}")
    noise = SensorNoise({k: v / n for k, v in S.items()}, So / no if no > 0 else None, n)
    log.info("sensor noise from %d steady samples: force sd %s N, torque sd %s N*m, orientation sd %s deg", n,
             np.round(np.mean([noise.sd(k)[:3] for k in legs], axis=0), 4).tolist(),
             np.round(np.mean([noise.sd(k)[3:] for k in legs], axis=0), 5).tolist(),
             None if noise.orientation_rad is None else np.round(np.degrees(np.sqrt(np.diag(noise.orientation_rad))), 4).tolist())
    return noise
