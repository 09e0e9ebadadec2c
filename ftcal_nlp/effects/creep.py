"""creep: a reading that relaxes after each change of load (the strain gauges' anelastic creep).

After a change ``dL`` of the load on channel ``c`` the reading first moves by ``(1 - g_c) dL`` and then
relaxes to ``dL`` with time constant ``tau``; for any load history ``L(t)`` (a superposition of steps):

    w_m,c(t) = L_c(t) - g_c [L_c - lowpass_tau(L_c)](t)         (injected, ``CreepInjector``)

``lowpass_tau`` the first-order lag ``tau y' + y = L`` (``signals.lowpass``; at rest when the
recording starts), so the creep term ``-g_c dL exp(-s / tau)`` a time ``s`` after a step and zero at
rest: a constant load (and the offsets) creep nothing. ``g_c`` per channel: ``scale`` x U(0.6, 1.4)
(positive: the reading lags the load), ``tau`` 3 s by default. It needs nothing of a hexapod (the load
is the true applied wrench of each transducer): the hexapod and the free-load simulators take it.

Off-face shapes (the validation sweep; a correct diagnosis still says ``creep``):

* creep_two_tau   two relaxations, half the gain each, tau 1 s and 12 s
* creep_log       logarithmic creep: eight relaxations of equal gain, tau log-spaced 0.3 .. 100 s
                  (a Prony series of ``log(1 + s / s_0)``), total gain ``g_c``

Free face (``free_faces.py``): per channel the column ``-[pred_c - lowpass_tau(pred_c)]`` (each
recording apart; ``pred`` the model readings: the offsets relax nothing), parameter ``c.creep`` [1]
(the fraction ``g_c`` of a load change that relaxes), and its derivative in ``ln tau``, parameter
``c.creep_dlntau`` [1] (``g_c d ln tau``: the channel's time constant is ``tau exp(dlntau / creep)``
to first order); or, shapes ``(tau, tau2)`` (``PAIRS_S``), two relaxations at once (``c.creep``,
``c.creep2`` [1]: a fast and a slow creep, which a single tau leaves as a delay-like rest). The shape is
``tau`` on a grid (``TAUS_S``, factor 2 apart) or a pair, chosen by held-out residual; ``free_refine``
then searches ``ln tau`` within a factor 2 of the best single tau, or both of a pair (Nelder-Mead), on the
residual regressed on each channel's relaxation(s) (weighted by the floor), kept when it predicts held-out
data better.

Correction: ``y - X beta`` (the creep the face predicts, removed); on a hexapod recording (no hexapod
face fits it) the block's ``<c>.creep [1]`` gains and ``tau_s`` applied to the readings themselves
(``y + g [y - lowpass(y)]``, first order in ``g``), if it has them.
"""

from __future__ import annotations

import logging

import numpy as np

from .free_faces import WRENCH, FreeFace
from .free_refine import refine_scalar, refine_simplex
from .injection import HOUR_S, EffectInjector, Magnitude, OffFaceInjector
from .signals import relaxation
from .unit import Effect

log = logging.getLogger(__name__)


def creep_term(t: np.ndarray, load: np.ndarray, gains: np.ndarray, taus, weights=(1.0,)) -> np.ndarray:
    """``-gains sum_i weights_i [load - lowpass_tau_i(load)]`` (same shape as ``load``, time along axis 0;
    ``gains`` broadcast against one sample of ``load``)."""
    out = np.zeros_like(np.asarray(load, float))
    for tau, wgt in zip(taus, weights):
        out -= wgt * relaxation(t, load, tau)
    return out * gains


class CreepInjector(EffectInjector):
    """Creep of ``scale`` x U(0.6, 1.4) of each load change per channel, relaxing with ``tau_s`` (default 3 s)."""

    name = "creep"
    magnitude = Magnitude("fraction of a load change that relaxes (per channel, on average)", (0.003, 0.02), 0.01)
    taus: tuple = (3.0,)
    weights: tuple = (1.0,)

    def __init__(self, scale: float | None = None, seed: int = 0, tau_s: float | None = None):
        super().__init__(scale, seed)
        if tau_s is not None:
            if not tau_s > 0:
                raise ValueError(f"{self.name}.tau_s: expected a positive time constant in s, got {tau_s!r}")
            self.taus = (float(tau_s),)

    def gains(self, K: int) -> np.ndarray:
        return self.scale * self.drawn("_g", K, lambda K: self.rng.uniform(0.6, 1.4, (K, 6)))

    def readings(self, ctx, w):
        return w + creep_term(ctx.t, ctx.applied, self.gains(w.shape[1])[None], self.taus, self.weights)


class CreepTwoTauInjector(OffFaceInjector, CreepInjector):
    """Two relaxations of half the gain each, tau 1 s and 12 s."""

    name = "creep_two_tau"
    expect = "creep"
    magnitude = Magnitude("fraction of a load change that relaxes (two time constants)", (0.003, 0.02), 0.01)
    taus = (1.0, 12.0)
    weights = (0.5, 0.5)


class CreepLogInjector(OffFaceInjector, CreepInjector):
    """Logarithmic creep: eight relaxations of equal gain with tau log-spaced over 0.3 .. 100 s."""

    name = "creep_log"
    expect = "creep"
    magnitude = Magnitude("fraction of a load change that relaxes (logarithmic creep)", (0.003, 0.02), 0.01)
    taus = tuple(np.geomspace(0.3, 100.0, 8))
    weights = (1.0 / 8,) * 8


def _relaxation_columns(ctx, taus) -> FreeFace:
    """Per tau each channel's own relaxation (``creep_term(t, pred, 1, (tau,))`` per recording): a channel-wise face
    whose columns are tau-major, as the dense (N, 6, 6 x taus) array of one diagonal block per tau was (the
    refinement's columns)."""
    # (N, 6) views of channel-major arrays; a trial's time constants are not kept in the context's cache (used once)
    xs = [ctx.relaxation(float(tau), negated=True, keep=False) for tau in taus]
    m = len(xs)
    if m == 1:     # each channel's column is a contiguous row of the cached array: used in place, no copy
        blocks = tuple((c, np.array([c]), xs[0][:, c:c + 1]) for c in range(6))
    else:          # column-major channel blocks: a channel's relaxations are contiguous rows of one (6, m, N) array
        slab = np.empty((6, m, ctx.n))
        for j, x in enumerate(xs):
            slab[:, j] = x.T
        blocks = tuple((c, np.arange(m) * 6 + c, slab[c].T) for c in range(6))
    return FreeFace(None, tuple(f"x{j}" for j in range(6 * m)), blocks=blocks)


def _nonzero(x: np.ndarray) -> bool:
    """Whether any element of ``x`` is non-zero and not NaN (``np.any(np.abs(x) > 0)`` without its temporaries)."""
    flat = x.T.reshape(-1) if x.T.flags.c_contiguous else x.reshape(-1)
    return bool(flat.size) and bool(np.fmax.reduce(flat) > 0 or np.fmin.reduce(flat) < 0)


class Creep(Effect):
    name = "creep"
    description = "a reading that relaxes after each change of load"
    explains = "pose_history"
    kind = "sensor"
    injector_cls = CreepInjector
    shapes = (CreepTwoTauInjector, CreepLogInjector)
    applies_to = frozenset({"hexapod", "free"})
    diagnosed_on = frozenset({"free"})
    free_explains = "pose_history"
    TAUS_S = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    PAIRS_S = ((0.5, 4.0), (1.0, 8.0), (2.0, 16.0), (4.0, 32.0))   # a fast and a slow relaxation at once
    DLN = 0.05     # the step of ln tau for the derivative column (central difference)
    follows_stream_clock = True   # the relaxation after each change of load runs on the stream's clock

    def free_shapes(self, ctx):
        return tuple({"tau_s": tau} for tau in self.TAUS_S) + tuple({"tau_s": a, "tau2_s": b} for a, b in self.PAIRS_S)

    def free_face(self, ctx, shape):
        # per channel the part of each change of the model readings that has not yet relaxed (each recording apart),
        # and either its derivative in ln tau (a tau between grid points, to first order) or a second, slower relaxation
        tau = float(shape["tau_s"])
        tau2 = shape.get("tau2_s")
        taus = (tau, tau * np.exp(-self.DLN), tau * np.exp(self.DLN)) if tau2 is None else (tau, float(tau2))
        NR0 = ctx.relaxation(tau, negated=True)   # the columns -R: creep_term(t, pred, 1, (tk,)) per recording
        if not _nonzero(NR0):
            return None
        # each channel's own two columns (a channel-wise face: no mostly-zero (N, 6, 12) array), written in place into
        # one (6, 2, N) array (one allocation; a channel's two columns contiguous rows): -R0, and
        # (-R2 - -R1) / (2 DLN) (the central difference in ln tau), or -R1 (the second relaxation); a derivative's two
        # neighbours are filtered into the face's own column and one temporary (not kept in the context's cache)
        slab = np.empty((6, 2, ctx.n))
        slab[:, 0] = NR0.T
        if tau2 is None:
            ctx.relaxation_into(taus[1], slab[:, 1])
            np.subtract(ctx.relaxation(taus[2], negated=True, keep=False).T, slab[:, 1], out=slab[:, 1])
            slab[:, 1] /= 2 * self.DLN
        else:
            slab[:, 1] = ctx.relaxation(taus[1], negated=True).T
        bases = [slab[c].T for c in range(6)]     # (N, 2) column-major views
        second_name = "creep_dlntau" if tau2 is None else "creep2"
        names = tuple(n for c in WRENCH for n in (f"{c}.creep [1]", f"{c}.{second_name} [1]"))
        return FreeFace.channelwise(bases, names, dict(shape))

    def free_refine(self, ctx, shape, resid):
        # The time constant(s) by a search in ln tau on the residual beside the free-load model's own columns
        # (free_refine.py): within a factor 2 of the grid's best single tau, or a pair by Nelder-Mead from its grid point
        columns = self._refine_columns(ctx)
        if "tau2_s" not in shape:
            lt = np.log(float(shape["tau_s"]))
            v = refine_scalar(ctx, resid, columns, lt - np.log(2.0), lt + np.log(2.0))
            return None if v is None else {"tau_s": float(np.round(np.exp(v), 3))}
        x = refine_simplex(ctx, resid, columns, np.log([float(shape["tau_s"]), float(shape["tau2_s"])]))
        if x is None:
            return None
        t1, t2 = sorted(float(np.round(np.exp(v), 3)) for v in x)
        return {"tau_s": t1, "tau2_s": t2} if t2 > 1.05 * t1 else None

    #: per-fold tuning (``free_refine_near``): points per single tau over its refinement's range, steps of a pair's
    NEAR_POINTS = 5
    NEAR_PAIR_STEP = 0.5 * np.log(2.0)

    def free_refine_near(self, ctx, shape):
        # the shapes free_refine searches among: single tau within a factor 2 (NEAR_POINTS evenly in ln tau: the grid's
        # neighbours and the half-octaves between; a face's d/d ln tau column takes up what lies between), a pair on a
        # 3 x 3 grid of half-octave steps about its grid point
        if "tau2_s" not in shape:
            lt = np.log(float(shape["tau_s"]))
            pts = [(v,) for v in np.linspace(lt - np.log(2.0), lt + np.log(2.0), self.NEAR_POINTS)]
        else:
            l1, l2 = np.log(float(shape["tau_s"])), np.log(float(shape["tau2_s"]))
            d = self.NEAR_PAIR_STEP * np.arange(-1, 2)
            pts = [(l1 + a, l2 + b) for a in d for b in d if l2 + b > l1 + a + np.log(1.05)]
        out = []
        for p in pts:
            taus = [float(np.round(np.exp(v), 3)) for v in p]
            out.append({"tau_s": taus[0]} if len(taus) == 1 else {"tau_s": taus[0], "tau2_s": taus[1]})
        return tuple(out)

    @staticmethod
    def _refine_columns(ctx):
        return lambda ln_taus: _relaxation_columns(ctx, [float(np.exp(v)) for v in np.atleast_1d(ln_taus)])

    def correct(self, cal, block, ctx, w, phi, R_WB, t_h, *, with_cov=True, source="calibration"):
        par = block.get("parameters", {})
        g = [par.get(f"{c}.creep [1]") for c in WRENCH]
        tau = block.get("shape", {}).get("tau_s")
        if tau is None or any(v is None for v in g):
            log.info("%s: creep: no creep gains / tau_s in the calibration's effect block; readings unchanged", source)
            return w, R_WB, None
        g = np.array([v["value"] if isinstance(v, dict) else v for v in g], float)
        return w - creep_term(np.asarray(t_h, float) * HOUR_S, w, g, (float(tau),)), R_WB, None


EFFECT = Creep()
