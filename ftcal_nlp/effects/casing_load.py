"""casing_load: a parasitic load on the transducer that depends on the shaft angle, not on gravity.

Injected (``CasingLoadInjector``): ``w += [M_k (cos phi, sin phi); 0, 0, 0, 0]`` (force in the
ft xy plane, entries of M_k ~ N(0, scale^2 / 2)).

Off-face shape (the validation sweep; a correct diagnosis still says ``casing_load``):

* casing_load_harmonics  w[:2] += scale sum_h a_h M_hk (cos h phi, sin h phi),  h = (3, 5), a = (1, 0.6)

Model faces: ``c_k = w - [sum_m M_km (cos m phi, sin m phi); 0]`` (m <= 1, 2 or 3 for attribution,
up to ``HARMONICS`` for the joint refit), 4K x harmonics; the same on the hanging and swing legs.

Correction: the standing face on each sample. Acts while hanging (offset shift).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .faces import HARMONICS, HangingLeg, ParamBlock, per_leg_face
from .injection import EffectInjector, Magnitude, OffFaceInjector
from .unit import Effect


class CasingLoadInjector(EffectInjector):
    """Parasitic force in the ft xy plane, ``M_k (cos phi, sin phi)``, amplitude ~``scale`` N."""

    name = "casing_load"
    magnitude = Magnitude("N, amplitude of the shaft-angle dependent force", (0.3, 1.5), 1.0)

    def matrices(self, K: int) -> np.ndarray:
        return self.scale * self.drawn("_M", K, lambda K: self.rng.normal(0.0, 1.0 / np.sqrt(2.0), (K, 2, 2)))

    def readings(self, ctx, w):
        M = self.matrices(w.shape[1])
        cs = np.stack([np.cos(ctx.phi), np.sin(ctx.phi)], axis=-1)  # (N, K, 2)
        out = w.copy()
        out[..., :2] += np.einsum("kij,nkj->nki", M, cs)
        return out


class CasingLoadHarmonicsInjector(OffFaceInjector):
    """Parasitic force in the ft xy plane, ``scale sum_h a_h M_hk (cos h phi, sin h phi)``; entries of
    ``M_hk`` ~ N(0, 1/2) as ``casing_load``'s, harmonics ``h`` and weights ``a_h`` configurable."""

    name = "casing_load_harmonics"
    expect = "casing_load"
    magnitude = Magnitude("N, amplitude of the shaft-angle dependent force (3rd + 5th harmonic)", (0.3, 1.5), 1.0)

    def __init__(self, scale: float | None = None, seed: int = 0, harmonics: tuple = (3, 5), weights: tuple = (1.0, 0.6)):
        super().__init__(scale, seed)
        self.harmonics = tuple(int(h) for h in harmonics)
        self.weights = np.asarray(weights, float)
        if len(self.harmonics) != len(self.weights) or not self.harmonics:
            raise ValueError(f"{self.name}: harmonics {harmonics!r} and weights {weights!r} need the same non-zero length")
        self._M: np.ndarray | None = None

    def matrices(self, K: int) -> np.ndarray:
        """``scale a_h M_hk`` (H, K, 2, 2)."""
        if self._M is None or self._M.shape[1] != K:
            self._M = self.rng.normal(0.0, 1.0 / np.sqrt(2.0), (len(self.harmonics), K, 2, 2))
        return self.scale * self.weights[:, None, None, None] * self._M

    def readings(self, ctx, w):
        M = self.matrices(w.shape[1])
        hphi = np.asarray(self.harmonics, float)[:, None, None] * ctx.phi[None]      # (H, N, K)
        cs = np.stack([np.cos(hphi), np.sin(hphi)], axis=-1)                        # (H, N, K, 2)
        out = w.copy()
        out[..., :2] += np.einsum("hkij,hnkj->nki", M, cs)
        return out


class CasingLoad(Effect):
    name = "casing_load"
    description = "a parasitic load on the transducer that depends on shaft angle but not on gravity"
    explains = "shaft_angle"
    kind = "sensor"
    injector_cls = CasingLoadInjector
    shapes = (CasingLoadHarmonicsInjector,)
    shifts_offsets = True
    HARMONICS_TRIED = (1, 2, 3)   # attribution keeps the number of harmonics that predicts held-out data best

    def __init__(self, harmonics: int = 1):
        if not 1 <= harmonics <= HARMONICS:
            raise ValueError(f"casing_load: harmonics must be 1..{HARMONICS}, got {harmonics}")
        self.harmonics = int(harmonics)

    def variants(self):
        return tuple(CasingLoad(h) for h in self.HARMONICS_TRIED)

    def joint_variants(self):
        # the joint refit holds every standing harmonic at the hanging estimate, so it can afford up
        # to HARMONICS of them; the hanging face's held-out residual chooses how many
        return tuple(CasingLoad(h) for h in range(1, HARMONICS + 1))

    @property
    def variant(self):
        return {"harmonics": self.harmonics}

    def _labels(self):
        return tuple(f"{a}_{f}{m if m > 1 else ''}" for m in range(1, self.harmonics + 1) for a in "xy" for f in ("cos", "sin"))

    def standing_params(self, ctx):
        return ParamBlock.bounded((f"M[{k}].{c} [N]" for k in ctx.legs for c in self._labels()), 10.0)

    def standing_from_hanging(self, hanging, ctx):
        # same load M_km on the same leg: the hanging face's X = (cos, sin) on fx, fy is the standing c_k's
        out = {}
        for i, (k, c) in enumerate((k, c) for k in ctx.legs for c in self._labels()):
            if f"{k}.{c}" in hanging:
                out[i] = hanging[f"{k}.{c}"]
        return out

    def standing(self, eta, pose, ctx):
        out = []
        q = 4 * self.harmonics
        for k, w in enumerate(pose.w):
            a = eta[q * k : q * k + q]
            fx = fy = 0
            for m in range(self.harmonics):
                c, s = pose.harm[m][0][k], pose.harm[m][1][k]
                fx = fx + a[4 * m] * c + a[4 * m + 1] * s
                fy = fy + a[4 * m + 2] * c + a[4 * m + 3] * s
            out.append(w - ca.vertcat(fx, fy, 0, 0, 0, 0))
        return out, None, None

    def hanging_features(self, legs):
        def make(l: HangingLeg):
            X = np.zeros((len(l.t), 6, 4 * self.harmonics))
            for m in range(self.harmonics):
                c, s = np.cos((m + 1) * l.phi), np.sin((m + 1) * l.phi)
                X[:, 0, 4 * m], X[:, 0, 4 * m + 1], X[:, 1, 4 * m + 2], X[:, 1, 4 * m + 3] = c, s, c, s
            return X

        return per_leg_face(legs, make, self._labels())

    swing_features = hanging_features


EFFECT = CasingLoad()
