"""ftcal_nlp: in-situ calibration of the hip force/torque transducers of a legged robot.

``calibrate(dataset, settings) -> CalibrationRun`` runs the whole method (Wu & Revzen:
hanging, standing poses, model selection, standing, per-foot ground wrenches, and the
sim-to-real gap diagnosis); :mod:`ftcal_nlp.settings` holds every setting with its default.
"""

from .calibration_run import CalibrationRun
from .pipeline import calibrate
from .settings import (
    CalibrationSettings,
    DiagnoseSettings,
    HangingSettings,
    PoseExtraction,
    SelectionSettings,
    StandingSettings,
)

__all__ = ["calibrate", "CalibrationRun", "CalibrationSettings", "HangingSettings", "StandingSettings",
           "SelectionSettings", "DiagnoseSettings", "PoseExtraction"]
