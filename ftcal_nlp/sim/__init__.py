"""BigAnt simulator: a hexapod with exact rigid-body statics, written in the interchange format.

``simulate(SimConfig(...))`` gives a :class:`SimResult` (dataset, truth, walking
truth, standing pose windows); ``write_simulation(res, folder)`` writes it like
``shared/sample``. Modules: ``config`` (settings), ``robot_model`` (true
parameters, leg CoM and toe loop), ``statics`` (compliant-foot equilibrium on
level ground or a tilted board),
``recordings`` (hanging / standing / walking time series), ``effects`` (injectors
by name: every effect unit's of :mod:`ftcal_nlp.effects`, where each effect's
injector lives beside its other faces), ``variants`` (faults outside the effect
library, for the validation sweep), ``simulate`` (sensors and assembly), ``writer``
(files); ``free`` the free-load simulator (a wrist payload or URDF links below a sensor, DATA_FORMAT.md section 5; ``simulate_to_folder``
takes a ``[simulate]`` table with ``kind``).
"""

from .config import SimConfig
from .effects import EFFECTS, InjectionContext, Injector, NoEffect, make_effects
from ..effects.injection import EffectInjector, Magnitude
from .variants import VARIANTS  # noqa: F401  (importing it registers the off-face injectors of issue 13 in EFFECTS)
from .robot_model import LEGS, TrueRobot, draw_true_robot, nominal_robot
from .simulate import SimResult, simulate
from .statics import Stance, board_rotation, contact_forces, internal_forces, solve_stance
from .writer import write_simulation
from .free import simulate_to_folder  # [simulate] kind = "payload" | "urdf_leg" (issue 22) or the hexapod

__all__ = [
    "EFFECTS", "EffectInjector", "InjectionContext", "Injector", "LEGS", "Magnitude", "NoEffect", "SimConfig", "SimResult",
    "Stance", "TrueRobot",
    "board_rotation", "contact_forces", "draw_true_robot", "internal_forces", "make_effects", "nominal_robot", "simulate",
    "simulate_to_folder", "solve_stance", "write_simulation",
]
