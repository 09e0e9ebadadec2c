"""mocap_bias: a constant rotation between the motion-capture body and B.

Injected (``MocapBiasInjector``): motion capture reports ``R_WB R_b``, ``R_b`` a ``scale`` degree
tilt about a horizontal axis (a heading component would be invisible and harmless).

Model faces:

* standing   z~ = Cay(q) z, 3 parameters (exactly absorbed by free transducer rotations and
             translations: then the design face tests for a common rotation of the fitted frames)
* design: a common tilt of the fitted frames (``faces.design_check``)

Correction: the measured orientation, ``R_WB' = R_WB Z(eta)^T`` (the standing face's up-vector
map; readings unchanged). Kind ``body``: it acts on the measured body orientation.
"""

from __future__ import annotations

import numpy as np

from ..core.geometry import cayley, rotvec_to_rotation
from .faces import ParamBlock, correct_by_face
from .injection import EffectInjector, Magnitude
from .unit import Effect


class MocapBiasInjector(EffectInjector):
    """Motion capture reports ``R_WB R_b``: ``R_b`` tilts by ``scale`` degrees about a horizontal axis
    (a heading component would be invisible and harmless: the heading never enters)."""

    name = "mocap_bias"
    magnitude = Magnitude("deg of tilt between the mocap body and B", (2.0, 3.0), 3.0)

    def rotation(self) -> np.ndarray:
        if not hasattr(self, "_Rb"):
            ang = self.rng.uniform(0, 2 * np.pi)
            self._Rb = rotvec_to_rotation(np.radians(self.scale) * np.array([np.cos(ang), np.sin(ang), 0.0]))
        return self._Rb

    def orientation(self, ctx, R_meas):
        return R_meas @ self.rotation()


class MocapBias(Effect):
    name = "mocap_bias"
    description = "a constant rotation between the motion-capture body and B"
    explains = "body_tilt"
    kind = "body"
    injector_cls = MocapBiasInjector
    applies_to = frozenset({"hexapod", "free"})   # it needs nothing of a hexapod
    design_face = True

    def standing_params(self, ctx):
        return ParamBlock.bounded(("q.x [~deg/1.15]", "q.y", "q.z"), 20.0)

    def standing(self, eta, pose, ctx):
        return pose.w, cayley(0.01 * eta), None

    def correct(self, cal, block, ctx, w, phi, R_WB, t_h, *, with_cov=True, source="calibration"):
        # the measured orientation, through the standing face's up-vector map (readings unchanged)
        return correct_by_face(self, cal, block, ctx, w, phi, R_WB, t_h, with_cov=with_cov, source=source)


EFFECT = MocapBias()
