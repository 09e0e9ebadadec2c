"""Results of the free-load estimator, in the results protocol of ``results.py``.

:class:`FreeLoadResult` (one transducer) has ``params`` (labelled: offsets
``{leg}.offset.fx..tz`` N / N*m; the load's ``{leg}.<param>`` (kg, kg m); where estimated the world tilt of
the orientation stream ``{leg}.tilt.rx, .ry`` rad (``calibration.json`` ``gravity_tilt_rad``) and the tilt of each
``gravity_body``-only recording ``{leg}.{recording}.tilt.rx, .ry`` rad (``recording_tilt_rad``); the
mounting rotation vector ``{leg}.mount.rx..rz`` rad, ``R_true = R_nom expm(r)``; where the sensor's matrix is
refitted (``sensor_matrix.py``), ``sensor_matrix`` its result and the model readings ``o + C^-1 w``),
``bse`` (inf where undetermined), ``cov_params()``, ``conf_int()``,
``summary()``, and :meth:`FreeLoadResult.identifiability`, the notes naming what
the data leave undetermined and the combinations they do determine.
:class:`FreeLoadResults` stacks the transducers (independent blocks).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from ...core.geometry import quat_to_rotation, rotation_to_rotvec, rotvec_to_rotation
from ...core.results import ResultsMixin, StackedResults, Summary, fmt_pm
from .problem import gravity_frame, predict, tilt_gravity

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass
class FreeLoadResult(ResultsMixin):
    """One transducer's free-load fit (module docstring).

    ``load``: the :class:`~ftcal_nlp.loads.LinearLoad`; ``offset`` (6,), ``theta`` (p,), ``rotation`` ``E`` (3, 3)
    the mounting rotation (true ft relative to nominal); ``sigma`` (6,) residual sd per channel (the weights);
    ``rms`` (6,) residual RMS; ``n_used``; ``selection`` recording -> quasi-static counts and thresholds;
    ``undetermined`` one description per undetermined direction; ``determined`` the determined combinations
    of parameters that enter undetermined directions (``{"combination", "value", "se"}``); ``notes``."""

    leg: str
    load: Any
    offset: np.ndarray
    theta: np.ndarray
    rotation: np.ndarray
    names: tuple[str, ...]
    cov: np.ndarray
    se: np.ndarray
    sigma: np.ndarray
    rms: np.ndarray
    n_used: int
    selection: dict[str, dict]
    undetermined: tuple[str, ...] = ()
    determined: tuple[dict, ...] = ()
    notes: list[str] = field(default_factory=list)
    iterations: int = 0
    solve_time_s: float = 0.0
    eig_ratio: np.ndarray | None = None
    null: np.ndarray | None = None       # (n_params, r) undetermined directions in the parameters' own units
    used: dict[str, np.ndarray] = field(default_factory=dict)   # recording -> (N_rec,) samples the fit used
    tilt: np.ndarray | None = None   # world tilt of the orientation stream (rad, about x then y); None: not estimated
    recording_tilts: dict[str, np.ndarray] = field(default_factory=dict)   # gravity_body recording -> its tilt (rad)
    sensor_matrix: Any = None   # sensor_matrix.SensorMatrixResult where the sensor's matrix was refitted; None: factory

    # ------------------------------------------------------------------ results protocol

    @property
    def params(self) -> pd.Series:
        tilt = np.zeros(0) if self.tilt is None else self.tilt
        vals = np.concatenate([self.offset, self.theta, tilt, *self.recording_tilts.values(), rotation_to_rotvec(self.rotation)])
        return pd.Series(vals, index=list(self.names), name="params")

    def moved(self, dx: np.ndarray) -> "FreeLoadResult":
        """This fit with its parameters moved by ``dx`` (over ``names``: the model Jacobian's columns,
        ``diagnose/free_model.py``): offsets, load parameters and tilts add, the mount turns ``E = E* expm([dr]x)``
        (one Gauss-Newton step of a refit linearised around this fit); covariance and notes unchanged."""
        dx = np.asarray(dx, float)
        if dx.shape != (len(self.names),):
            raise ValueError(f"{self.leg}: a move of {len(self.names)} parameters expected, got shape {dx.shape}")
        p = len(self.theta)
        at = 6 + p
        tilt = None
        if self.tilt is not None:
            tilt, at = np.asarray(self.tilt, float) + dx[at: at + 2], at + 2
        rec_tilts = {}
        for r, v in self.recording_tilts.items():
            rec_tilts[r], at = np.asarray(v, float) + dx[at: at + 2], at + 2
        return replace(self, offset=np.asarray(self.offset, float) + dx[:6], theta=np.asarray(self.theta, float) + dx[6: 6 + p],
                       rotation=np.asarray(self.rotation, float) @ rotvec_to_rotation(dx[-3:]), tilt=tilt,
                       recording_tilts=rec_tilts)

    def _bse_array(self) -> np.ndarray:
        return self.se

    def _cov_array(self) -> np.ndarray:
        return self.cov

    @property
    def mount_rotvec(self) -> np.ndarray:
        return rotation_to_rotvec(self.rotation)

    def _theta_blocks(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Covariance of ``theta`` on the determined subspace and the undetermined directions restricted to it."""
        p = len(self.theta)
        null = None if self.null is None or not self.null.size else self.null[6: 6 + p]
        return self.cov[6: 6 + p, 6: 6 + p], null

    def se_of(self, J: np.ndarray) -> np.ndarray:
        """se of linear combinations ``J params`` (rows over ``params``): inf where a row changes along an
        undetermined direction, finite otherwise (a determined combination of undetermined parameters)."""
        from ...loads.base import se_of

        return se_of(self.cov, J, self.null)

    def load_report(self) -> dict:
        """The load's ``calibration.json`` keys (``OUTPUT_FORMAT.md``) and the identifiability notes."""
        out = self.load.report(self.theta, *self._theta_blocks())
        out.update({"mount_rotvec": self.mount_rotvec.tolist(), "mount_rotvec_se": self.se[-3:].tolist(),
                    "undetermined": list(self.undetermined), "determined_combinations": list(self.determined),
                    "samples_used": int(self.n_used), "selection": self.selection,
                    "residual_rms": self.rms.tolist(), "noise_sd": self.sigma.tolist()})
        if self.tilt is not None:   # the world tilt of the orientation stream (rad, about x then y; se inf: held at 0)
            p = len(self.theta)
            out.update({"gravity_tilt_rad": self.tilt.tolist(), "gravity_tilt_se_rad": self.se[6 + p:8 + p].tolist()})
        if self.recording_tilts:    # a tilt per gravity_body-only recording (rad, about the axes of its gravity frame)
            at = {n: i for i, n in enumerate(self.names)}
            out["recording_tilt_rad"] = {r: t.tolist() for r, t in self.recording_tilts.items()}
            out["recording_tilt_se_rad"] = {r: [float(self.se[at[f"{self.leg}.{r}.tilt.r{c}"]]) for c in "xy"]
                                            for r in self.recording_tilts}
        if self.sensor_matrix is not None:   # the recalibrated matrix C of w = C (r - offset) (OUTPUT_FORMAT.md)
            out.update(self.sensor_matrix.report())
        return out

    def identifiability(self) -> list[str]:
        """What the data leave undetermined (one line per direction, then the determined combinations), or
        an empty list when they determine every parameter."""
        out = [f"{self.leg}: not determined by the data: {d}" for d in self.undetermined]
        out += [f"{self.leg}: determined: {c['combination']} = {fmt_pm(c['value'], c['se'])}" for c in self.determined]
        return out + [n for n in self.notes if n not in out]

    # ------------------------------------------------------------------ the model

    def predict(self, gravity_B: np.ndarray, q: dict[str, np.ndarray]) -> np.ndarray:
        """Model readings (N, 6) for gravity in B (N, 3, m/s^2) and joint angles ``q`` (joint -> (N,))."""
        n = len(gravity_B)
        R = self.load.nominal_rotation(q, n)
        b = np.einsum("nji,nj->ni", R, gravity_B)
        K = self.load.lever(q, n)
        if self.sensor_matrix is None:
            return predict(b, K, self.theta, self.load.mass_row, self.rotation, self.offset)
        # raw readings r = o + C^-1 w (sensor_matrix.py): the model wrench through the inverse of the correction
        w = predict(b, K, self.theta, self.load.mass_row, self.rotation, np.zeros(6))
        return np.linalg.solve(self.sensor_matrix.C, w.T).T + self.offset

    def predict_recording(self, rec, g: float) -> np.ndarray:
        """Model readings (N, 6) of every sample of recording ``rec`` (NaN where its gravity is unknown)."""
        grav = rec.gravity_directions()
        if rec.name in self.recording_tilts and rec.quat is None and rec.gravity is None:   # its own tilt
            grav = np.broadcast_to(gravity_frame(grav[:1])[0] @ tilt_gravity(self.recording_tilts[rec.name]), grav.shape).copy()
        if rec.quat is not None and self.tilt is not None:  # the stream's world is tilted: true g_B = R_WB'^T R_t (0,0,-1)
            grav = np.einsum("nji,j->ni", quat_to_rotation(np.nan_to_num(rec.quat, nan=1.0)), tilt_gravity(self.tilt))
            grav[~np.all(np.isfinite(rec.quat), axis=1)] = np.nan
        return self.predict(g * grav, rec.q)

    def summary(self) -> Summary:
        p = self.params
        facts = [("transducer", f"{self.leg} ({self.load.kind})"),
                 ("samples", f"{self.n_used} quasi-static used; " + "; ".join(
                     f"{k}: {v['kept']} kept, {v['dropped']} dropped" for k, v in self.selection.items())),
                 ("residual RMS / sd", " ".join(f"{r:.3g}/{s:.3g}" for r, s in zip(self.rms, self.sigma))),
                 ("IPOPT", f"{self.iterations} iterations, {self.solve_time_s:.2f} s")]
        rows = [(n, fmt_pm(float(p[n]), float(s))) for n, s in zip(self.names, self.se)]
        table = pd.DataFrame({"estimate": [r[1] for r in rows]}, index=pd.Index([r[0] for r in rows], name="parameter"))
        rep = self.load.report(self.theta, *self._theta_blocks())
        s = Summary(f"Free load of {self.leg}", facts, [("parameters (SI; mount: rotation vector, rad)", table)])
        s.facts.insert(1, ("load mass", fmt_pm(rep["load_mass_kg"], rep["load_mass_se_kg"]) + " kg"))
        if "load_com_m" in rep:
            s.facts.insert(2, ("load CoM (ft)", ", ".join(fmt_pm(c, e) for c, e in zip(rep["load_com_m"], rep["load_com_se_m"])) + " m"))
        s.notes += self.identifiability()
        return s


@dataclass
class FreeLoadResults(StackedResults):
    """Every free-load transducer's fit (independent blocks), by transducer name."""

    legs: dict[str, FreeLoadResult]

    def _parts(self) -> list:
        return list(self.legs.values())

    def identifiability(self) -> list[str]:
        return [n for r in self.legs.values() for n in r.identifiability()]

    def summary(self) -> Summary:
        s = Summary("Free loads", [(k, f"{r.load.kind}, {r.n_used} samples") for k, r in self.legs.items()])
        for r in self.legs.values():
            sub = r.summary()
            s.facts += sub.facts
            s.tables += sub.tables
            s.notes += sub.notes
        return s
