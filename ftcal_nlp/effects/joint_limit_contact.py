"""joint_limit_contact: a wrench that appears as a joint nears its end stop.

As joint ``j`` of a load of URDF links moves past an onset ``q_s`` towards its limit, something
touches (a hard stop against the housing above the transducer, a cable pulled taut): a wrench
``W`` (fixed in ft) grows like a stiffness ramp. With ``mid``/``half`` the middle and half-width of
the joint's limits and ``side`` = +1 (upper) or -1 (lower):

    q_s = mid + side onset half,     r(q) = max(0, side (q - q_s)) / ((1 - onset) half)   (1 at the limit)
    w_m = w + W r(q_j),   W = scale [u, 0.05 m v]                        (injected)

``u``, ``v`` random unit vectors (force ``scale`` N at the limit, torque as on a 5 cm lever); the joint
(among the moving ones with limits) and the side drawn from the seed, ``onset`` 0.5 (free-load
simulator only: a hexapod's shafts turn without end stops).

Off-face shapes (the validation sweep; a correct diagnosis still says ``joint_limit_contact``):

* joint_limit_contact_smooth     ``W sigmoid(side (q - q_s) / (0.1 half))``: a soft contact that sets in
                                 gradually around the onset and saturates
* joint_limit_contact_hysteresis the contact engages past ``q_s`` and lets go only below
                                 ``q_s - 0.15 half`` (a sticking cable): ``W r(q; q_s - 0.15 half)`` while engaged

Free face (``free_faces.py``): per channel the ramp ``r(q_j)`` of one joint; the shape is which joint,
which side and where (``onset`` in ``ONSETS``), over the moving joints with limits: held-out evidence
picks it. Parameters ``<c>.at_limit [N]`` (torques N*m): ``W``. Correction: ``y - X beta``.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import DataFormatError
from .free_faces import WRENCH, FreeFace
from .injection import EffectInjector, Magnitude, OffFaceInjector
from .unit import Effect


def ramp(q: np.ndarray, lower: float, upper: float, side: int, onset: float, back: float = 0.0) -> np.ndarray:
    """``r(q)`` of the module docstring (``back``: the onset moved that many half-widths away from the limit)."""
    mid, half = 0.5 * (lower + upper), 0.5 * (upper - lower)
    q_s = mid + side * (onset - back) * half
    return np.clip(side * (np.asarray(q, float) - q_s), 0.0, None) / ((1.0 - onset + back) * half)


class JointLimitContactInjector(EffectInjector):
    """``scale`` N of force (and a 5 cm lever's torque) at a joint's limit, ramping from ``onset`` of its half-range."""

    name = "joint_limit_contact"
    magnitude = Magnitude("N of contact force at the joint's limit", (1.0, 4.0), 2.0)

    def __init__(self, scale: float | None = None, seed: int = 0, joint: str | None = None, side: int | None = None,
                 onset: float = 0.5):
        super().__init__(scale, seed)
        if side not in (None, -1, 1) or not 0.0 <= onset < 1.0:
            raise ValueError(f"{self.name}: side must be -1, 1 or None and 0 <= onset < 1, got side={side!r}, onset={onset!r}")
        self.joint, self.side, self.onset = joint, side, float(onset)
        u, v = self.rng.normal(size=3), self.rng.normal(size=3)
        self.W = self.scale * np.r_[u / np.linalg.norm(u), 0.05 * v / np.linalg.norm(v)]
        self._pick = self.rng.uniform(size=2)

    def where(self, ctx) -> tuple[str, int, float, float]:
        """``(joint, side, lower, upper)`` of the contact: the given joint or one of the moving joints with limits."""
        limits = getattr(ctx.truth, "limits", {}) or {}
        q = getattr(ctx.truth, "q", {}) or {}
        cand = sorted(j for j in limits if j in q and np.ptp(q[j]) > 0)
        if self.joint is not None:
            if self.joint not in limits or self.joint not in q:
                raise ValueError(f"{self.name}: joint {self.joint!r} has no angles or no limits here (joints with both: {cand})")
            j = self.joint
        elif not cand:
            raise ValueError(f"{self.name}: no moving joint with limits (a rigid payload has no end stop)")
        else:
            j = cand[int(self._pick[0] * len(cand))]
        side = self.side if self.side is not None else (1 if self._pick[1] >= 0.5 else -1)
        return j, side, *limits[j]

    def contact(self, ctx) -> np.ndarray:
        """``r(q_j)`` (N,) of the contact's shape."""
        j, side, lo, hi = self.where(ctx)
        return ramp(ctx.truth.q[j], lo, hi, side, self.onset)

    def readings(self, ctx, w):
        return w + self.contact(ctx)[:, None, None] * self.W[None, None, :]


class JointLimitContactSmoothInjector(OffFaceInjector, JointLimitContactInjector):
    """A soft contact: ``W sigmoid(side (q - q_s) / (0.1 half))``."""

    name = "joint_limit_contact_smooth"
    expect = "joint_limit_contact"
    magnitude = Magnitude("N of contact force when saturated (sigmoid)", (1.0, 4.0), 2.0)

    def contact(self, ctx):
        j, side, lo, hi = self.where(ctx)
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        x = side * (ctx.truth.q[j] - (mid + side * self.onset * half)) / (0.1 * half)
        return 1.0 / (1.0 + np.exp(-np.clip(x, -50, 50)))


class JointLimitContactHysteresisInjector(OffFaceInjector, JointLimitContactInjector):
    """A sticking contact: engaged past ``q_s``, released only below ``q_s - 0.15 half``; ``W r(q; q_s - 0.15 half)`` engaged."""

    name = "joint_limit_contact_hysteresis"
    expect = "joint_limit_contact"
    magnitude = Magnitude("N of contact force at the joint's limit (hysteretic)", (1.0, 4.0), 2.0)
    BACK = 0.15

    def contact(self, ctx):
        j, side, lo, hi = self.where(ctx)
        q = ctx.truth.q[j]
        into = ramp(q, lo, hi, side, self.onset) > 0
        held = ramp(q, lo, hi, side, self.onset, self.BACK) > 0
        engaged = np.zeros(len(q), bool)
        on = False
        for n in range(len(q)):       # a latch: set past the onset, reset below the release point
            on = bool(into[n] or (on and held[n]))
            engaged[n] = on
        return engaged * ramp(q, lo, hi, side, self.onset, self.BACK)


class JointLimitContact(Effect):
    name = "joint_limit_contact"
    description = "a wrench that appears as a joint nears its end stop"
    explains = "joint"
    kind = "sensor"
    injector_cls = JointLimitContactInjector
    shapes = (JointLimitContactSmoothInjector, JointLimitContactHysteresisInjector)
    applies_to = frozenset({"free"})
    diagnosed_on = frozenset({"free"})
    free_explains = "joint"
    ONSETS = (0.5, 0.7)
    MIN_SHARE = 0.01   # a side the data reach past the onset with fewer samples than this carries no evidence

    def free_require(self, ctx, shape, leg, where):
        if shape.get("joint") not in ctx.q:
            col = f"q_{shape.get('joint')}"
            raise DataFormatError(f"{where}: the calibration's effect joint_limit_contact of transducer {leg} needs "
                                  f"the joint's angle: column '{col}' (rad)", path=where, column=col)

    def free_shapes(self, ctx):
        out = []
        for j in sorted(ctx.q):
            if j not in ctx.joint_limits:
                continue
            lo, hi = ctx.joint_limits[j]
            for side in (-1, 1):
                for onset in self.ONSETS:
                    if np.mean(ramp(ctx.q[j], lo, hi, side, onset) > 0) >= self.MIN_SHARE:
                        out.append({"joint": j, "side": side, "onset": onset})
        return tuple(out)

    def free_face(self, ctx, shape):
        j = shape["joint"]
        if j not in ctx.q or j not in ctx.joint_limits:
            return None
        r = ramp(ctx.q[j], *ctx.joint_limits[j], int(shape["side"]), float(shape["onset"]))
        if not np.any(r > 0):
            return None
        names = tuple(f"{c}.at_limit [{'N' if i < 3 else 'N*m'}]" for i, c in enumerate(WRENCH))
        return FreeFace(None, names, dict(shape), basis=r[:, None], channels=tuple(range(6)))


EFFECT = JointLimitContact()
