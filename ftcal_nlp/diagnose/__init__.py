"""Sim-to-real gap diagnosis (issue 7): where the gap between the calibrated model and the
robot lies, which unmodelled effect causes it, and how far it shrinks once that effect is added.

* ``effects/``: the effect library, one plug-in per canonical effect of
  ``OUTPUT_FORMAT.md``: the augmentation of the calibration model, paired with the
  simulator's injector of the same effect (``ftcal_nlp.sim.injectors``, which the
  simulator registers itself; nothing here is needed to simulate an effect).
* ``views.py``: residuals per recording kind and data-derived noise floors.
* ``standing_fit.py``, ``linear_fit.py``: the model with an effect added, cross-validated.
* ``attribute.py``: scores, ranking, verdict; ``localise.py``: where and what it follows.
* ``result.py``: :class:`DiagnosisResult` (``diagnosis.json`` content, summary); ``report/`` renders it.
* ``validate.py``: the withheld-effect validation
  (``python -m ftcal_nlp.diagnose.validate problems/diagnose_validation.toml``).
"""

from .core import diagnose, diagnose_run
from .effects import LIBRARY
from .result import DiagnosisResult

__all__ = ["LIBRARY", "DiagnosisResult", "diagnose", "diagnose_run"]
