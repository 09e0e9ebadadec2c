"""Results of the hanging calibration (report Sec. III-A, Table II), with standard errors.

``LegHangingResult`` holds one leg's estimates in ft_k: offset ``w_o``
(report eq. 1), weight ``m_k g``, the CoM curve ``r_k(phi)`` on a periodic
grid (NaN where the data do not identify it), one misalignment rotation per
hanging recording (``u_j = R_j a_j``, ``a_j`` the nominal gravity axis in
ft_k), residual RMS per component and any warnings. ``HangingResult`` renders
them like the report's Table II (``summary()``, ``table()``) and turns them into
a :class:`~ftcal_nlp.core.calibration.Calibration` with nominal transducer poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ...core.calibration import Calibration, LegCalibration
from ...core.data import WRENCH_COMPONENTS
from ...core.geometry import rotation_to_rotvec
from ...core.results import ResultsMixin, Summary, block_diag_cov, fmt_pm
from ...core.robot import Robot

_OFFSET_ROWS = ("force offset x [N]", "force offset y [N]", "force offset z [N]",
                "torque offset x [N*m]", "torque offset y [N*m]", "torque offset z [N*m]")
ROWS = _OFFSET_ROWS + ("leg weight m g [N]",)


def leg_param_names(leg: str, n_grid: int, recordings) -> list[str]:
    """Labels of one leg's parameters (SI units): ``FL.w_o.fx`` .. ``FL.w_o.tz`` (N, N*m),
    ``FL.mg`` (N), ``FL.com[i].x`` (m, grid point i), ``FL.tilt[rec].x`` (rad, rotation vector)."""
    names = [f"{leg}.w_o.{c}" for c in WRENCH_COMPONENTS] + [f"{leg}.mg"]
    names += [f"{leg}.com[{i}].{c}" for i in range(n_grid) for c in "xyz"]
    names += [f"{leg}.tilt[{r}].{c}" for r in recordings for c in "xyz"]
    return names


@dataclass(frozen=True)
class LegHangingResult:
    """One leg. Shapes and units: ``offset``/``offset_se`` (6,) N, N*m in ft_k;
    ``com_phi`` (G,) rad; ``com_xyz``/``com_xyz_se`` (G, 3) m in ft_k, NaN where
    unsupported or unidentified (``com_mask`` False); ``com_xyz_fit`` (G, 3) the
    curve the model used, finite everywhere (unidentified parts at their gauge
    values; for residuals only), ``offset_fit`` (6,) likewise the model's offset;
    ``misalignment[name]`` 3x3 rotation, ``misalignment_se[name]`` (3,) rad
    (rotation-vector standard errors); ``residual_rms`` (6,) per component over
    every sample; ``noise_sd`` (6,) the estimated noise standard deviations."""

    leg: str
    offset: np.ndarray
    offset_se: np.ndarray
    leg_weight_N: float
    leg_weight_se_N: float
    com_phi: np.ndarray
    com_xyz: np.ndarray
    com_xyz_se: np.ndarray
    misalignment: dict[str, np.ndarray]
    misalignment_se: dict[str, np.ndarray]
    residual_rms: np.ndarray
    warnings: tuple[str, ...]
    solve_time_s: float
    converged: bool
    com_mask: np.ndarray
    com_xyz_fit: np.ndarray
    offset_fit: np.ndarray
    noise_sd: np.ndarray | None = None   # None: the baseline estimates no noise
    smoothing: float = float("nan")
    n_rounds: int = 0
    objective: float = float("nan")
    cov: np.ndarray | None = field(default=None, repr=False)  # physical covariance, order of leg_param_names

    @property
    def param_names(self) -> list[str]:
        return leg_param_names(self.leg, len(self.com_phi), list(self.misalignment))

    def param_values(self) -> np.ndarray:
        tilts = [rotation_to_rotvec(R) for R in self.misalignment.values()]
        return np.concatenate([self.offset, [self.leg_weight_N], self.com_xyz.ravel(), *tilts])

    def param_se(self) -> np.ndarray:
        """Standard errors; inf where the data do not determine a parameter (NaN value)."""
        se = np.concatenate([self.offset_se, [self.leg_weight_se_N], self.com_xyz_se.ravel(),
                             *[np.asarray(v, float) for v in self.misalignment_se.values()]])
        return np.where(np.isnan(self.param_values()), np.inf, se)

    def param_cov(self) -> np.ndarray:
        """The Fisher covariance (NLP), or the diagonal of the se where a method gives only se (baseline)."""
        if self.cov is not None:
            return self.cov
        se = self.param_se()
        return np.diag(np.where(np.isfinite(se), se, 0.0) ** 2)

    def misalignment_deg(self) -> dict[str, tuple[float, float]]:
        """Angle of each misalignment rotation and its standard error, degrees."""
        out = {}
        for k, R in self.misalignment.items():
            v = rotation_to_rotvec(R)
            th = float(np.linalg.norm(v))
            se = self.misalignment_se.get(k)
            th_se = float("nan") if se is None or th == 0 else float(np.sqrt(np.sum((v / th * se) ** 2)))
            out[k] = (np.degrees(th), np.degrees(th_se))
        return out


@dataclass(frozen=True)
class HangingResult(ResultsMixin):
    """All legs of one hanging calibration; ``method`` is ``"nlp"`` or ``"baseline"``.

    Results protocol (``results.py``): ``params`` labelled as in :func:`leg_param_names`
    for every leg; legs are independent (block-diagonal ``cov_params()``).
    """

    legs: dict[str, LegHangingResult]
    method: str

    @property
    def params(self) -> pd.Series:
        return pd.Series(np.concatenate([l.param_values() for l in self.legs.values()]),
                         index=[n for l in self.legs.values() for n in l.param_names], name="params")

    def _bse_array(self) -> np.ndarray:
        return np.concatenate([l.param_se() for l in self.legs.values()])

    def _cov_array(self) -> np.ndarray:
        frames = [pd.DataFrame(l.param_cov(), index=l.param_names, columns=l.param_names) for l in self.legs.values()]
        return block_diag_cov(frames).to_numpy()

    def table(self) -> pd.DataFrame:
        """Table II of the report: offsets and leg weight per leg as ``value ± se`` (rows with units)."""
        cols = {}
        for k, l in self.legs.items():
            cols[k] = [fmt_pm(v, s) for v, s in zip(np.append(l.offset, l.leg_weight_N), np.append(l.offset_se, l.leg_weight_se_N))]
        df = pd.DataFrame(cols, index=list(ROWS))
        df.index.name = "parameter"
        return df

    def fit_table(self) -> pd.DataFrame:
        """Per leg: convergence, rounds, smoothing, residual RMS, tilts, CoM identification."""
        rows = {}
        for k, l in self.legs.items():
            tilts = "; ".join(f"{name}: {fmt_pm(a, s)}" for name, (a, s) in l.misalignment_deg().items())
            n_id = int(np.isfinite(l.com_xyz).all(axis=1).sum())
            med = np.nanmedian(l.com_xyz_se) * 1e3 if np.isfinite(l.com_xyz_se).any() else float("nan")
            rows[k] = {
                "converged": "yes" if l.converged else "NO",
                "time [s]": f"{l.solve_time_s:.2f}",
                "rounds": str(l.n_rounds) if l.n_rounds else "",
                "smoothing lam [1/m^2]": f"{l.smoothing:.3g}" if np.isfinite(l.smoothing) else "",
                "residual RMS f [N]": " ".join(f"{x:.3g}" for x in l.residual_rms[:3]),
                "residual RMS tau [N*m]": " ".join(f"{x:.3g}" for x in l.residual_rms[3:]),
                "CoM grid identified": f"{n_id}/{len(l.com_phi)}",
                "CoM median se [mm]": f"{med:.3g}",
                "hanging tilt [deg]": tilts,
            }
        df = pd.DataFrame(rows).T
        df.index.name = "leg"
        return df

    def summary(self) -> Summary:
        """Table II (``value ± se``), then per leg fit quality, tilts and warnings."""
        legs = list(self.legs.values())
        s = Summary(f"Hanging calibration ({self.method}), {len(legs)} legs",
                    [("method", self.method), ("CoM grid", f"{len(legs[0].com_phi)} shaft angles") if legs else ("CoM grid", "-")])
        s.tables.append(("Offsets w_o (ft_k axes) and leg weights, value ± standard error", self.table()))
        s.tables.append(("Fit per leg", self.fit_table()))
        s.notes += [f"{l.leg}: {m}" for l in legs for m in l.warnings]
        return s

    def to_calibration(self, robot: Robot) -> Calibration:
        """A calibration with these offsets, weights and CoM curves and the nominal transducer poses.

        ``position_from_com_m`` is the nominal ``position_m`` (the body CoM is not
        known from hanging); ``com_body_m`` is None.
        """
        legs = {}
        for k, l in self.legs.items():
            t = robot.transducers[k]
            legs[k] = LegCalibration(
                offset=l.offset.copy(),
                leg_weight_N=float(l.leg_weight_N),
                com_phi=l.com_phi.copy(),
                com_xyz=l.com_xyz.copy(),
                rotation_to_body=t.given_rotation().copy(),
                position_from_com_m=t.given_position().copy(),
                offset_se=l.offset_se.copy(),
                leg_weight_se_N=float(l.leg_weight_se_N),
                com_xyz_se=l.com_xyz_se.copy(),
            )
        mass = np.nan if robot.mass_kg is None else robot.mass_kg   # unknown: NaN, as a free load's calibration
        return Calibration(legs, mass, robot.g, model=f"hanging-{self.method}", com_body_m=None)
