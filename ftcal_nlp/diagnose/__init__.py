"""Sim-to-real gap diagnosis (issue 7): where the gap between the calibrated model and the
robot lies, which unmodelled effect causes it, and how far it shrinks once that effect is added.

Map of the package (``diagnose(...)``, ``diagnose_run(run)`` in ``core.py`` run them in this order):

* ``views.py``: what the diagnosis looks at, per recording kind (standing poses, hanging
  legs, walking swing and stance): residuals, their correlates, data-derived noise floors;
  ``floor.py``: the standing floor (a variance-component model, REML).
* ``standing_fit.py``: the calibration model with one effect's standing face added
  (:class:`AugmentedProblem`, CasADi + IPOPT, k-fold cross-validated);
  ``linear_fit.py``: the hanging and swing faces, cross-validated regressions;
  ``scores.py``: :class:`KindScore` (held-out excess over the floor, ``delta_bic``).
* ``attribute.py``: every candidate effect scored in turn, ranking and verdict (``decide``).
* ``localise.py``: where the residual lies (legs, components) and what it follows.
* ``perleg.py``: per-leg checks that need no effect library (a free linear map per leg,
  each leg's weight refit on its swing phases).
* ``joint.py``: the named effect(s) refit with the whole calibration (``calibration_with_effect.json`` holds the
  chain's last joint refit).
* ``evidence.py``: the chain of several effects, one loop for every kind of evidence (name the strongest by held-out
  evidence, refit jointly, look again; thresholds ``DiagnoseSettings.hexapod`` / ``.free_loads``,
  :class:`~ftcal_nlp.core.settings.ChainThresholds`); each kind behind :class:`~.evidence.EvidenceKind`:
* ``hexchain.py``: the hexapod's kind (issue 23): while a gap is left after the joint refit, the remaining candidates
  are scored with the named effects in the base model (``attribute(..., base_effect=Combined(named))``,
  ``effects/combined.py``), the best is added when it passes a stated paired fold-wise held-out test and the joint
  refit with the named ones predicts better (else up to two candidates by their held-out evidence where the joint
  refit left its gap are tried so); ``effects`` in ``diagnosis.json`` lists the chain.
* ``result.py``: :class:`DiagnosisResult` (``diagnosis.json`` content, summary); ``report/`` renders it.
* ``core.py``: ``diagnose`` and ``diagnose_run``: views -> attribution -> localisation -> joint refit -> chain -> result.

Free loads (``DATA_FORMAT.md`` section 5: payloads, URDF loads; issue 23), ``diagnose_free(dataset, free_loads)``
in ``free.py``, which the pipeline runs for them:

* ``free_model.py``: every sample of the free load (moving ones included), the fit's model and its Jacobian,
  the noise floor from held, still stretches of the readings;
* ``free_cv.py``: blocked cross-validation (holds or time blocks) of the model linearised around the fit plus
  effect faces (``effects/free_faces.py``), cached per-fold normal equations;
* ``chain.py``: the free loads' kind of evidence for ``evidence.py``: the strongest by held-out evidence, refit
  jointly, look again, stop by a stated paired block-wise test; the joint refit's parameters with se;
* ``correlates.py``: where the gap lies: time, each joint angle, motion, the load's history, temperature.

On hexapod datasets the first effect is the single-effect diagnosis above, unchanged (its name, parameters and
joint refit); ``hexchain.py`` looks again only when the joint refit leaves a gap (or a common tilt of the frames).

The candidate effects are not here: each is one unit of :mod:`ftcal_nlp.effects` (its
injector, model faces and their variants, correction and off-face shapes), read from
the registry ``ftcal_nlp.effects.EFFECTS`` (or a ``registry`` argument). The
withheld-effect validation of the diagnosis, for both kinds of evidence, is ``validation.py``
(``python -m ftcal_nlp.run problems/diagnose_validation.toml``; ``calibrate`` passed in by ``run.py``).
"""

from .core import diagnose, diagnose_run
from .result import DiagnosisResult

__all__ = ["DiagnosisResult", "diagnose", "diagnose_run"]
