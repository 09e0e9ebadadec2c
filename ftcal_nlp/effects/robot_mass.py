"""robot_mass: the weighed mass in ``robot.toml`` is wrong.

Injected (``RobotMassInjector``): ``robot.toml`` says ``mass_kg +- scale`` (the simulation keeps
the true mass).

Model face: standing ``e_p = dM g [z; 0]``, 1 parameter.

Correction: none per foot (a body effect).
"""

from __future__ import annotations

from dataclasses import replace

import casadi as ca

from .faces import ParamBlock
from .injection import EffectInjector, Magnitude
from .unit import Effect


class RobotMassInjector(EffectInjector):
    """The weighed mass in ``robot.toml`` is off by ``scale`` kg (sign drawn from the seed)."""

    name = "robot_mass"
    magnitude = Magnitude("kg of weighing error", (0.05, 0.2), 0.15)

    def robot(self, robot):
        if not hasattr(self, "_sign"):
            self._sign = float(self.rng.choice([-1.0, 1.0]))
        return replace(robot, mass_kg=float(robot.mass_kg + self._sign * self.scale))


class RobotMass(Effect):
    name = "robot_mass"
    description = "the weighed mass is wrong"
    explains = None
    kind = "body"
    injector_cls = RobotMassInjector

    def standing_params(self, ctx):
        return ParamBlock.bounded(("dM [0.1 kg]",), 20.0)

    def standing(self, eta, pose, ctx):
        return pose.w, None, ca.vertcat(0.1 * eta[0] * ctx.g * pose.z, ca.DM.zeros(3))


EFFECT = RobotMass()
