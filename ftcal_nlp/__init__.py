"""ftcal_nlp: in-situ calibration of the hip force/torque transducers of a legged robot.

``calibrate(dataset, settings) -> CalibrationRun`` runs the whole method (Wu & Revzen:
hanging, standing poses, model selection, standing, per-foot ground wrenches, and the
sim-to-real gap diagnosis); :mod:`ftcal_nlp.core.settings` holds every setting with its default.
Datasets of any robot (``DATA_FORMAT.md`` section 5: payloads, URDF loads) go through the same
``calibrate`` to the free-load estimator (:mod:`ftcal_nlp.estimate.freeload`, loads in :mod:`ftcal_nlp.loads`).
"""

from typing import TYPE_CHECKING

from .core.settings import (
    CalibrationSettings,
    DiagnoseSettings,
    FreeLoadSettings,
    HangingSettings,
    PoseExtraction,
    SelectionSettings,
    StandingSettings,
)

if TYPE_CHECKING:
    from .calibration_run import CalibrationRun
    from .pipeline import calibrate


def __getattr__(name: str):
    # imported on first use, so that ``python -m ftcal_nlp.correct`` (which the pipeline imports) does not
    # find its own module already loaded by the package (runpy's RuntimeWarning)
    if name == "calibrate":
        from .pipeline import calibrate

        return calibrate
    if name == "CalibrationRun":
        from .calibration_run import CalibrationRun

        return CalibrationRun
    raise AttributeError(f"module 'ftcal_nlp' has no attribute {name!r}")


__all__ = ["calibrate", "CalibrationRun", "CalibrationSettings", "HangingSettings", "StandingSettings",
           "SelectionSettings", "DiagnoseSettings", "PoseExtraction", "FreeLoadSettings"]
