"""``CalibrationRun``: everything :func:`ftcal_nlp.calibrate` produced, in memory.

It holds the stage results (hanging, pose extraction, model selection,
standing, the report's baselines beside them, the diagnosis), the
:class:`~ftcal_nlp.core.calibration.Calibration` they make, the per-foot ground
wrenches of the walking recordings, stage times and notes. Reports render from
it; ``run.py`` writes it to files. It follows the results protocol of
``results.py``: ``params``, ``bse``, ``cov_params()``, ``conf_int()`` and
``summary()`` over every calibrated parameter, hanging and standing together.

Joint covariance. The standing fit conditions on the hanging estimates (offsets
``w_o`` and leg weights ``m_k g`` enter its balance). Its estimates therefore
move with them, ``theta_s = theta_s(theta_h)``, and the standing block of the
joint covariance is the conditional one plus the propagated hanging part,

    Cov(theta_s) = Cov(theta_s | theta_h) + G Cov(theta_h) G^T,   Cov(theta_s, theta_h) = G Cov(theta_h),

with ``G = d theta_s / d theta_h`` from the implicit-function theorem at the
standing optimum (``StandingResult.sensitivity``). When the standing result
carries no sensitivity (baseline solver) the blocks are joined as independent
and ``joint_covariance`` says so.

Built once. A run is frozen and every field is set when it is made
(:func:`ftcal_nlp.calibrate` builds the parts first); what derives from its
fields (the joint covariance, :attr:`CalibrationRun.joint`) is a cached property
of the object, so it cannot go stale. To add to a finished run (the command
line adds the dataset's truth and its load time) ``dataclasses.replace`` makes
a new run, whose derived quantities are computed afresh.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Mapping

import numpy as np
import pandas as pd

from .estimate import naive
from .core.calibration import Calibration
from .core.data import Dataset, Recording
from .estimate.hanging.result import HangingResult
from .core.results import ResultsMixin, Summary, fmt_pm
from .estimate.selection import SelectionResult
from .core.settings import CalibrationSettings
from .estimate.standing.poses import Poses
from .estimate.standing.result import StandingResult
from .correct.tracking import TrackedOffsets
from .truth import LoadTruth
from .estimate.uncertainty import CalibrationCovariance

if TYPE_CHECKING:  # the diagnosis reads a CalibrationRun (diagnose_run): a run-time import here would be a cycle
    from .diagnose.result import DiagnosisResult
    from .estimate.freeload import FreeLoadResults

__all__ = ["CalibrationRun", "JointCovariance", "joint_covariance"]


@dataclass(frozen=True)
class JointCovariance(ResultsMixin):
    """Hanging and standing parameters with their joint covariance (module docstring), in the
    results protocol; ``how`` says how the two blocks were joined."""

    values: pd.Series
    cov: np.ndarray
    se: np.ndarray
    how: str

    @property
    def params(self) -> pd.Series:
        return self.values

    def _bse_array(self) -> np.ndarray:
        return self.se

    def _cov_array(self) -> np.ndarray:
        return self.cov


def joint_covariance(hanging: HangingResult | None, standing: StandingResult | None,
                     free_loads: FreeLoadResults | None = None) -> JointCovariance:
    """The parameters of both stages and their joint covariance: the standing block conditional on the
    hanging estimates plus ``G Cov(theta_h) G^T`` when the standing result has the sensitivity ``G``,
    else the blocks side by side as independent (module docstring)."""
    stages = [r for r in (hanging, standing, free_loads) if r is not None]
    params = pd.concat([s.params for s in stages]) if stages else pd.Series(dtype=float)
    n = len(params)
    cov = np.zeros((n, n))
    bse = np.concatenate([s._bse_array() for s in stages]) if stages else np.zeros(0)
    i = 0
    for s in stages:
        m = len(s.params)
        cov[i : i + m, i : i + m] = np.nan_to_num(s._cov_array(), nan=0.0, posinf=0.0)
        i += m
    how = "free loads (independent blocks)" if free_loads is not None else "hanging only" if standing is None else "standing only (offsets-only run)" if hanging is None else "independent blocks"
    if standing is not None and hanging is not None and standing.sensitivity is not None:
        G = standing.sensitivity
        nh = len(hanging.params)
        Gm = G.reindex(index=standing.params.index, columns=hanging.params.index).fillna(0.0).to_numpy()
        hb = hanging._bse_array()
        Gm[:, ~np.isfinite(hb)] = 0.0  # undetermined hanging parameters carry no finite covariance to pass on
        Ch = cov[:nh, :nh]
        cov[nh:, nh:] += Gm @ Ch @ Gm.T
        cov[nh:, :nh] = Gm @ Ch
        cov[:nh, nh:] = cov[nh:, :nh].T
        sb = bse[nh:]
        fin = np.isfinite(sb)
        sb[fin] = np.sqrt(np.clip(np.diag(cov[nh:, nh:])[fin], 0, None))
        bse[nh:] = sb
        how = "standing conditional on hanging plus the propagated hanging covariance"
    return JointCovariance(params, cov, bse, how)


@dataclass(frozen=True)
class CalibrationRun(ResultsMixin):
    """The result of :func:`ftcal_nlp.calibrate` (module docstring): frozen, built once.

    ``hanging``/``hanging_baseline``: None in an offsets-only run (the baseline also when it was not
    asked for or could not run); ``selection``: None for a fixed model; ``standing_baseline``: None
    unless asked for; ``diagnosis``: None when disabled or skipped; ``truth``: the dataset's
    ``truth.json`` when it has one (a :class:`~ftcal_nlp.core.calibration.Calibration` for hexapod legs, a
    :class:`~ftcal_nlp.truth.LoadTruth` for a free load, as :func:`~ftcal_nlp.truth.load_truth` reads it); ``corrected``: recording name -> ground-wrench table
    (``OUTPUT_FORMAT.md`` columns, then se and contact columns); ``timings``/``cpu_timings``: stage
    -> wall / CPU seconds (read-only: a stage timed after the run is built makes a new run with ``replace``); ``notes``: what was skipped or noticed, for the report; ``uncertainty``:
    the covariance and sensor noise the se columns come from; ``tracked_offsets``: per walking
    recording the offsets tracked from its swing phases (``[correct] track_offsets``).
    """

    settings: CalibrationSettings
    dataset: Dataset
    calibration: Calibration
    hanging: HangingResult | None = None
    hanging_baseline: HangingResult | None = None
    poses: Poses | None = None
    selection: SelectionResult | None = None
    standing: StandingResult | None = None
    standing_baseline: StandingResult | None = None
    diagnosis: DiagnosisResult | None = None
    truth: Calibration | LoadTruth | None = None
    corrected: dict[str, pd.DataFrame] = field(default_factory=dict)
    timings: Mapping[str, float] = field(default_factory=dict)
    cpu_timings: Mapping[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    uncertainty: CalibrationCovariance | None = None
    tracked_offsets: dict[str, TrackedOffsets] = field(default_factory=dict)
    free_loads: FreeLoadResults | None = None   # the loads of DATA_FORMAT.md section 5 (issue 22)

    # ------------------------------------------------------------------ results protocol

    def _stages(self) -> list[HangingResult | StandingResult | FreeLoadResults]:
        return [r for r in (self.hanging, self.standing, self.free_loads) if r is not None]

    @cached_property
    def joint(self) -> JointCovariance:
        """Hanging and standing parameters with their joint covariance (module docstring)."""
        return joint_covariance(self.hanging, self.standing, self.free_loads)

    def joint_covariance(self) -> tuple[pd.Series, np.ndarray, np.ndarray, str]:
        """``(params, cov, bse, how)`` of :attr:`joint`."""
        j = self.joint
        return j.values, j.cov, j.se, j.how

    @property
    def params(self) -> pd.Series:
        return self.joint.values

    def _bse_array(self) -> np.ndarray:
        return self.joint.se

    def _cov_array(self) -> np.ndarray:
        return self.joint.cov

    def summary(self) -> Summary:
        """Key facts of the run, then the stage summaries' tables."""
        mass = self.dataset.robot.mass_kg
        facts = [("robot", f"{len(self.dataset.robot.legs)} legs" + ("" if mass is None else f", {mass:g} kg")),
                 ("recordings", f"{len(self.dataset.hanging)} hanging, {len(self.dataset.standing)} standing, "
                                f"{len(self.dataset.walking)} walking"),
                 ("model", str(self.calibration.model))]
        if self.poses is not None:
            facts.append(("poses", " -> ".join(f"{v} {k}" for k, v in self.poses.counts.items())))
        if self.selection is not None:
            facts.append(("model selection", f"{self.selection.folds}-fold CV and BIC chose {self.selection.best}"))
        facts.append(("covariance", self.joint.how))
        if self.diagnosis is not None:
            facts.append(("diagnosis", f"{self.diagnosis.verdict}" + (f" ({self.diagnosis.effect})" if self.diagnosis.effect else "")))
        s = Summary("ftcal_nlp calibration run", facts)
        for stage in self._stages():
            sub = stage.summary()
            s.tables += sub.tables
            s.notes += sub.notes
        s.notes += list(self.notes)
        return s

    # ------------------------------------------------------------------ what the robot reads without the calibration

    def naive_total_residuals(self) -> np.ndarray:
        """(P, 6) naive-tare total-wrench residual at the poses, W axes about B (``naive.py``)."""
        robot, poses = self.dataset.robot, self._poses()
        return naive.naive_total_residuals(poses.w_m, poses.R_WB, naive.naive_bias(self.dataset.hanging, robot), robot)

    def no_transformation_error_residuals(self) -> np.ndarray:
        """(P, 6) exact-balance residual with nominal transducer poses and one CoM shift (``naive.py``)."""
        robot = self.dataset.robot
        offsets, weights, _, _ = self.calibration.stacked(robot.legs)
        poses = self._poses()
        return naive.no_transformation_error_residuals(poses.w_m, poses.R_WB, offsets, weights, robot)

    def _poses(self) -> Poses:
        if self.poses is None:
            raise ValueError("a free-load run has no standing poses: the naive baselines compare hexapod poses")
        return self.poses

    def naive_ground_wrenches(self, rec: Recording) -> tuple[np.ndarray, np.ndarray]:
        """Naive-tare per-foot wrenches of recording ``rec`` and its row mask (``naive.py``)."""
        robot = self.dataset.robot
        return naive.naive_ground_wrenches(rec, naive.naive_bias(self.dataset.hanging, robot), robot)

    def format_param(self, name: str, scale: float = 1.0) -> str:
        """One parameter as ``value ± se`` (times ``scale``)."""
        return fmt_pm(float(self.params[name]), float(self.bse[name]), scale=scale)
