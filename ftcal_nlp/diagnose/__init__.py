"""Sim-to-real gap diagnosis (issue 7): where the gap between the calibrated model and the
robot lies, which unmodelled effect causes it, and how far it shrinks once that effect is added.

* ``effects/``: the effect library, one plug-in per canonical effect of
  ``OUTPUT_FORMAT.md`` with two faces: an injector for the simulator (registered in
  ``ftcal_nlp.sim.effects.EFFECTS`` when this package is imported) and an
  augmentation of the calibration model.
* ``views.py``: residuals per recording kind and data-derived noise floors.
* ``standing_fit.py``, ``linear_fit.py``: the model with an effect added, cross-validated.
* ``attribute.py``: scores, ranking, verdict; ``localise.py``: where and what it follows.
* ``result.py``: :class:`DiagnosisResult` (``diagnosis.json``, summary, report section).
* ``validate.py``: the withheld-effect validation
  (``python -m ftcal_nlp.diagnose.validate problems/diagnose_validation.toml``).
"""

from . import effects  # noqa: F401  (registers the injectors in ftcal_nlp.sim.effects.EFFECTS)
from .core import DiagnosisSettings, diagnose, diagnose_run
from .effects import LIBRARY
from .result import DiagnosisResult

__all__ = ["LIBRARY", "DiagnosisResult", "DiagnosisSettings", "diagnose", "diagnose_run"]
