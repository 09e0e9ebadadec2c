"""Results of the hanging calibration (report Sec. III-A, Table II), with standard errors.

``LegHangingResult`` holds one leg's estimates in ft_k: offset ``w_o``
(report eq. 1), weight ``m_k g``, the CoM curve ``r_k(phi)`` on a periodic
grid (NaN where the data do not identify it), one misalignment rotation per
hanging recording (``u_j = R_j a_j``, ``a_j`` the nominal gravity axis in
ft_k), residual RMS per component and any warnings. ``HangingResult`` renders
them like the report's Table II (``summary()``, ``table()``) and turns them into
a :class:`~ftcal_nlp.calibration.Calibration` with nominal transducer poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..calibration import Calibration, LegCalibration
from ..geometry import rotation_to_rotvec
from ..robot import Robot

ROWS = ("F_offset x [N]", "F_offset y [N]", "F_offset z [N]", "T_offset x [Nm]", "T_offset y [Nm]", "T_offset z [Nm]", "mg [N]")


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
    com_mask: np.ndarray = field(default=None)
    com_xyz_fit: np.ndarray = field(default=None)
    offset_fit: np.ndarray = field(default=None)
    noise_sd: np.ndarray = field(default=None)
    smoothing: float = float("nan")
    n_rounds: int = 0
    objective: float = float("nan")

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


def _fmt(v: float, se: float) -> str:
    """``value ± se`` with the value rounded to the first significant digit of se (Table II style)."""
    if not np.isfinite(v):
        return "nan"
    if not np.isfinite(se) or se <= 0:
        return f"{v:.4g}"
    d = max(0, -int(np.floor(np.log10(se))))
    return f"{v:.{d}f} ± {se:.{d}f}"


@dataclass(frozen=True)
class HangingResult:
    """All legs of one hanging calibration; ``method`` is ``"nlp"`` or ``"baseline"``."""

    legs: dict[str, LegHangingResult]
    method: str

    def table(self) -> pd.DataFrame:
        """Table II of the report: offsets and leg weights, columns (leg, value|se)."""
        cols = pd.MultiIndex.from_product([list(self.legs), ["value", "se"]], names=["leg", ""])
        data = np.empty((len(ROWS), len(cols)))
        for i, l in enumerate(self.legs.values()):
            data[:, 2 * i] = np.append(l.offset, l.leg_weight_N)
            data[:, 2 * i + 1] = np.append(l.offset_se, l.leg_weight_se_N)
        return pd.DataFrame(data, index=list(ROWS), columns=cols)

    def summary(self) -> str:
        """Text summary: Table II (value ± se), then per leg fit quality, tilts and warnings."""
        legs = list(self.legs.values())
        head = f"Hanging calibration ({self.method}), {len(legs)} legs"
        cells = [[_fmt(v, s) for v, s in zip(np.append(l.offset, l.leg_weight_N), np.append(l.offset_se, l.leg_weight_se_N))] for l in legs]
        w0 = max(len(r) for r in ROWS)
        w = max(max(len(c) for col in cells for c in col), max(len(l.leg) for l in legs)) + 2
        lines = [head, "=" * len(head), " " * w0 + "".join(f"{l.leg:>{w}}" for l in legs)]
        for i, r in enumerate(ROWS):
            lines.append(f"{r:<{w0}}" + "".join(f"{col[i]:>{w}}" for col in cells))
        lines.append("")
        for l in legs:
            rms = " ".join(f"{x:.3g}" for x in l.residual_rms)
            state = "converged" if l.converged else "NOT CONVERGED"
            lines.append(f"{l.leg}: {state}, {l.solve_time_s:.2f} s, residual RMS [N, N, N, Nm, Nm, Nm] {rms}")
            if l.n_rounds:
                lines.append(f"    {l.n_rounds} NLP/QP rounds, smoothing lam = {l.smoothing:.3g} /m^2")
            tilts = ", ".join(f"{k} {_fmt(a, s)} deg" for k, (a, s) in l.misalignment_deg().items())
            lines.append(f"    misalignment: {tilts}")
            n_id = int(np.isfinite(l.com_xyz).all(axis=1).sum())
            lines.append(f"    CoM grid: {n_id} of {len(l.com_phi)} angles fully identified; "
                         f"median se {np.nanmedian(l.com_xyz_se) * 1e3 if np.isfinite(l.com_xyz_se).any() else float('nan'):.3g} mm")
            for msg in l.warnings:
                lines.append(f"    warning: {msg}")
        return "\n".join(lines)

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
                rotation_to_body=t.rotation.copy(),
                position_from_com_m=t.position_m.copy(),
                offset_se=l.offset_se.copy(),
                leg_weight_se_N=float(l.leg_weight_se_N),
                com_xyz_se=l.com_xyz_se.copy(),
            )
        return Calibration(legs, robot.mass_kg, robot.g, model=f"hanging-{self.method}", com_body_m=None)
