"""Plan a calibration session: the standard error each parameter group will have, before recording.

``python -m ftcal_nlp.plan [PROTOCOL.toml | ROBOT.toml | DATASET.toml] [--protocol FILE] [-o plan.json] [--search]
[--no-detection | --detect NAME ...] [--temperature-target N_PER_DEGC]``

One command for every load (:mod:`.command`): the input read and classified once (:mod:`.reading`), then planned by
the part of its load, each a ``plan_for`` returning a plan that writes ``plan.json`` and prints itself:

* :mod:`.hexapod` -- hexapod legs: a protocol of hanging turns and standing poses (or a pilot dataset) predicted by
  the Cramer-Rao bounds of the hanging model and the standing balance (:mod:`ftcal_nlp.crb`), ``--search`` for the
  shortest protocol meeting ``[targets]``, and the detection sizes of the diagnosis' library effects
  (:mod:`.detection`);
* :mod:`.free_load` -- free loads (``DATA_FORMAT.md`` section 5): a section-5 pilot dataset, a section-5 ``robot.toml``
  with ``--protocol HOLDS.toml``, or a protocol TOML whose ``[protocol]`` names a ``robot`` (or has
  ``kind = "payload"``): the se of the load parameters from the free-load bound (from a pilot, widened as the run
  widens them for serially correlated residuals), and what the holds leave undetermined, named; with a temperature
  (a pilot's column, a protocol's ``temperature_range_C``) the se of the temperature coefficients and the range a
  session needs (:mod:`.temperature`, ``--temperature-target``). A robot.toml is a
  free-load one when it has a ``urdf``, a transducer ``link`` or no ``mass_kg`` (a hexapod's has it, section 2), or
  when ``--protocol`` gives holds; alone it is an error saying what to add. ``--search`` and the detection sizes
  are the hexapod's (an error with a free load, saying so).
"""

from __future__ import annotations

from .command import PARTS, main, plan_inputs
from .detection import Detection, DetectionSize, detection_sizes
from .free_load import FreeLoadPlan, LoadPlan, pilot_widening, plan_from_dataset, plan_from_protocol, plan_from_robot
from .hexapod import (GRID_POSES, GROUPS, HANGING_GROUPS, HANGING_RECORDINGS, STANDING_GROUPS, Pilot, Prediction,
                      Protocol, load_input, predict, protocol_from_pilot, reported_se, search, smoothed_com_sd)
from .reading import PlanError, PlanInput, read_input

__all__ = [
    "PARTS", "main", "plan_inputs", "Detection", "DetectionSize", "detection_sizes", "FreeLoadPlan", "LoadPlan",
    "pilot_widening", "plan_from_dataset", "plan_from_protocol", "plan_from_robot", "GRID_POSES", "GROUPS",
    "HANGING_GROUPS", "HANGING_RECORDINGS", "STANDING_GROUPS", "Pilot", "Prediction", "Protocol", "load_input",
    "predict", "protocol_from_pilot", "reported_se", "search", "smoothed_com_sd", "PlanError", "PlanInput", "read_input",
]
