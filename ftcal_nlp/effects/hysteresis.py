"""hysteresis: a standing reading keeps a fraction of the previous pose's load.

Injected (``HysteresisInjector``, standing only): ``w = w_a + h (w_a,prev pose - w_a)``.

Model face: standing ``c_k = w - h (w_prev - w)``, 1 parameter.

Correction: the standing face on each sample, with no previous pose (the sample itself): none.
"""

from __future__ import annotations

import numpy as np

from .faces import ParamBlock
from .injection import EffectInjector, Magnitude
from .unit import Effect


class HysteresisInjector(EffectInjector):
    """A standing reading keeps the fraction ``scale`` of the previous pose's load."""

    name = "hysteresis"
    magnitude = Magnitude("fraction of the previous pose's load kept", (0.005, 0.02), 0.02)

    def readings(self, ctx, w):
        if ctx.kind != "standing":
            return w
        idx = ctx.pose_index
        P = int(idx.max()) + 1
        last = np.searchsorted(idx, np.arange(P), side="right") - 1  # poses come in order: last sample of each
        prev_load = np.zeros_like(ctx.applied)
        has = idx >= 1
        prev_load[has] = ctx.applied[last[idx[has] - 1]]
        out = w.copy()
        out[has] += self.scale * (prev_load[has] - ctx.applied[has])
        return out


class Hysteresis(Effect):
    name = "hysteresis"
    description = "a reading keeps a fraction of the previous pose's load"
    explains = "pose_history"
    kind = "sensor"
    injector_cls = HysteresisInjector

    def standing_params(self, ctx):
        return ParamBlock.bounded(("h [%]",), 10.0)

    def standing(self, eta, pose, ctx):
        h = 0.01 * eta[0]
        return [w - h * (p - w) for w, p in zip(pose.w, pose.prev)], None, None


EFFECT = Hysteresis()
