"""Free loads below a transducer (``shared/DATA_FORMAT.md`` section 5, issue 22): a simulator of datasets
in the interchange format.

* ``kind = "payload"``: a wrist transducer carrying a rigid tool (no ``{X}_phi``), an
  arm moving it between held orientations (``qw..qz`` per sample, one ``hanging``
  recording without ``gravity_body`` or an opposite partner).
* ``kind = "urdf_leg"``: the links below a sensor link of a URDF (default
  ``sim/assets/leg4.urdf``, four joints below the sensor, two above it),
  ``q_{joint}`` columns, the body tilted through held orientations while the
  joints move between held poses; ``orientation = "gravity"`` writes ``gx..gz``
  instead of ``qw..qz``.

Readings: the wrench the load exerts on the transducer, in the true ft frame
about its origin, plus offset plus noise: ``f = m g_ft``, ``t = c x f`` (summed
over bodies for a URDF load), ``g_ft`` gravity (pointing down, magnitude g) in
ft; equations and frames in :mod:`.physics`. Modules: ``config`` (frozen
settings, ``config_from_dict``), ``physics`` (noise-free readings), ``simulate`` (motion, sensing),
``writer`` (files; ``simulate_to_folder`` for a ``[simulate]`` table). The vectorised URDF
forward kinematics are :mod:`ftcal_nlp.core.kinematics`, shared with the free-load estimator.
"""

from .config import FREE_SIM_KINDS, LEG4_URDF, PayloadConfig, UrdfLegConfig, config_from_dict
from ...core.kinematics import KinematicTree, load_tree
from .physics import gravity_in_body, gravity_in_ft, payload_readings, true_rotation, urdf_load_readings
from .simulate import FreeLoadResult, simulate_free, simulate_payload, simulate_urdf_leg
from .writer import simulate_to_folder, write_free_load

__all__ = [
    "FREE_SIM_KINDS", "LEG4_URDF", "FreeLoadResult", "KinematicTree", "PayloadConfig", "UrdfLegConfig",
    "config_from_dict", "gravity_in_body", "gravity_in_ft", "load_tree", "payload_readings", "simulate_free",
    "simulate_payload", "simulate_to_folder", "simulate_urdf_leg", "true_rotation", "urdf_load_readings",
    "write_free_load",
]
