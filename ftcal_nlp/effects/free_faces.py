"""The free-load face of an effect (issue 23): how an effect shows in a free load's readings.

A free load (``DATA_FORMAT.md`` section 5: a rigid payload, the URDF links below a transducer) is
calibrated by ``ftcal_nlp/freeload`` from its quasi-static samples: ``y_n = h(x; s_n) + e_n`` with
``x = [w_o, theta, r]`` (offsets, the load's parameters, the mounting rotation vector). The diagnosis
(``diagnose/free.py``) looks at EVERY sample of every recording in which the load hangs free, moving
ones included, and asks which effect closes the gap ``r_n = y_n - h(x*; s_n)``.

Contract of a unit's free face (methods of :class:`~.unit.Effect`; a unit without them is simply
not a candidate on free-load data):

* ``free_shapes(ctx) -> tuple[dict, ...]``: a small grid of the face's NONLINEAR shape parameters
  (a delay, a time constant, which joint and where its limit is, a polynomial degree), each a dict of
  JSON-able values; ``()`` (the default) means "no free face". The diagnosis fits every shape and keeps
  the one with the smallest held-out (blocked cross-validated) residual; keep the grid small (<= ~12:
  each costs one linear fit per fold).
* ``free_face(ctx, shape) -> FreeFace | None``: design columns LINEAR in the effect's parameters
  ``beta``: the effect adds ``X_n beta`` (6,) to the readings of sample ``n`` (``X``: (N, 6, k),
  ``names``: k labels with units, e.g. ``"fx.P1 [N]"``). None: the shape does not apply to these data
  (e.g. no joint, no temperature column): the diagnosis skips it, never an error. Do NOT include a
  constant per channel: the offsets ``w_o`` are refit with the face (the joint refit linearises ``h``
  around ``x*``: ``r ~ J_x dx + X beta``, ``J_x`` the free-load model's Jacobian), so a constant column
  is not identifiable and is dropped by the rank check. A face is evaluated on all N samples; columns
  that are zero on the quasi-static samples are fine (an inertial or a contact wrench lives where the
  load moves or nears a stop).
* ``free_correct(ctx, shape, beta) -> (N, 6)``: the readings corrected for the effect with the fitted
  parameters (what ``correct`` applies). Default: ``y - X beta``. Override when the correction is not
  the subtraction of the face (e.g. a clock offset: re-sample the readings ``delay_s`` later).
* ``free_refine(ctx, shape, resid) -> dict | None`` (optional; define it only when useful): after the grid, the
  diagnosis hands the unit its best grid shape and the current model's residual ``resid`` (N, 6) on all samples
  (the free-load model and the effects named so far refit; channels weighted by ``1 / ctx.sigma``, the floor);
  the unit may return a refined shape (e.g. the exact delay by Gauss-Newton, a time constant by a 1-D search),
  which is scored like any grid shape and kept when its held-out residual is smaller.
* ``free_refine_near(ctx, shape) -> tuple[dict, ...]`` (optional, with ``free_refine``): shapes near the grid's best
  spanning what ``free_refine`` searches (e.g. creep: taus a half-octave apart within a factor 2). The refined shape's
  held-out score then tunes the shape per cross-validation fold among these, on the fold's training blocks alone
  (``diagnose/chain.py``), instead of scoring the shape tuned on every sample (optimistic).
* ``free_explains`` (class attribute, default the unit's ``explains``): the correlate a residual of this
  effect lies along (``"time"``, ``"motion"``, ``"load"``, ``"joint:<name>"`` via ``"joint"``,
  ``"temperature"``, ``"pose_history"``) - what ``where.explains`` should say when it is named.

:class:`FreeLoadContext` is what every face reads: per recording and per sample, the free-load fit's
predictions and the signals the data carry, all with the samples in recording order (recording after
recording; ``rec`` the recording index, ``seg`` the contiguous run of samples). Build it from arrays with
:func:`make_context` (tests, the simulator's truth) or from a dataset and a fit with
``diagnose.free.context_for``. Quantities derived here (rates by central differences within a recording,
holds, time since the last change of load) are defined once so that every face agrees on them:

* ``hold`` (N,) int: index of the quasi-static hold a sample belongs to (runs of consecutive ``still``
  samples of at least ``MIN_HOLD`` samples), -1 for moving samples;
* ``since_change`` (N,) s: time since the load last changed (the end of the last moving stretch before
  this sample; the recording's start for the first hold; 0 while moving);
* ``load_step`` (N, 6): the predicted wrench's change at that change, ``pred(now) - pred(previous hold's
  mean)`` held over the hold (zero before the first change; during motion the step is the running change
  since the previous hold);
* ``pred_rate`` (N, 6) per s, ``g_rate`` (N, 3) m/s^3, ``qd``/``qdd`` (joint -> (N,)) rad/s, rad/s^2,
  ``omega`` (N,) rad/s the rate of turn of gravity in ft (the body's rate of turn about horizontal axes;
  with ``quat`` the full body rate ``omega_B`` (N, 3) too).

The worked example is ``offset_drift`` (a Legendre polynomial of the session time per channel; shapes:
its degree) with its test ``tests/test_free_faces.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
#: fewer consecutive quasi-static samples than this are not a hold (a pause in a motion)
MIN_HOLD = 5
#: the memory a context's cache of relaxations may take (bytes; :meth:`FreeLoadContext.relaxation`): 40 time
#: constants of 10^5 samples (a creep grid, its refinements and each fold's shapes), fewer of longer recordings
RELAXATION_CACHE_BYTES = 200e6


class FreeFace:
    """An effect's free face for one shape: ``X`` (N, 6, k) design columns (the effect adds ``X beta`` to the
    readings), ``names`` (k,) parameter labels with units, ``shape`` the shape parameters that built it.

    Most faces are sparse in the channels: a column acts on a few channels only. Two forms keep that structure
    instead of the mostly-zero ``X`` (which is then built on demand):

    * :meth:`per_channel`: one ``basis`` (N, m) shared by each of ``channels`` (columns channel-major);
    * :meth:`channelwise`: per channel its own basis (N, m_c) and the columns it fills (e.g. creep: each channel's
      own relaxation).

    :meth:`channel_blocks` gives every form as ``(channel, columns, B)`` triples, ``B`` (N, m_c) the channel's
    non-zero columns (for a dense ``X``: the columns not identically zero on that channel, found once); the
    diagnosis' sums use only these (a channel's columns meet only that channel's rows)."""

    def __init__(self, X: np.ndarray | None, names, shape: dict | None = None, *, basis: np.ndarray | None = None,
                 channels: tuple[int, ...] = (), blocks: tuple | None = None):
        self.names = tuple(names)
        self.shape = dict(shape or {})
        self.basis = None if basis is None else np.asarray(basis, float)
        self.channels = tuple(int(c) for c in channels)
        self._X = None if X is None else np.asarray(X, float)
        self._blocks = None
        # a fixed part of the face's wrench (N, 6) not scaled by its parameters, or None: a nonlinear face linearised
        # about its shape (clock_offset's exact delay); the diagnosis' designs fit ``r - offset`` (``free_cv.Design``)
        self.offset: np.ndarray | None = None
        if blocks is not None:
            self._blocks = tuple((int(c), np.asarray(cols, int), np.asarray(B, float)) for c, cols, B in blocks)
            if self._X is not None or self.basis is not None:
                raise ValueError("FreeFace: give X, basis or blocks, not several")
            chans = [c for c, _, _ in self._blocks]
            bad = [c for c, cols, B in self._blocks if B.ndim != 2 or B.shape[1] != len(cols) or not 0 <= c < 6
                   or len(set(cols.tolist())) != len(cols) or (len(cols) and (cols.min() < 0 or cols.max() >= len(self.names)))]
            if bad or len(set(chans)) != len(chans):
                raise ValueError(f"FreeFace: blocks must be (channel 0..5, distinct columns of the {len(self.names)}, "
                                 "B (N, len(columns))), one block per channel")
            if len({len(B) for _, _, B in self._blocks}) > 1:
                raise ValueError("FreeFace: every block's B must have the same number of samples")
        elif self._X is None:
            if self.basis is None or self.basis.ndim != 2 or self.basis.shape[1] * len(self.channels) != len(self.names):
                raise ValueError(f"FreeFace: a per-channel face needs basis (N, m) with m x {len(self.channels)} channels = "
                                 f"{len(self.names)} names")
        elif self._X.ndim != 3 or self._X.shape[1] != 6 or self._X.shape[2] != len(self.names):
            raise ValueError(f"FreeFace: X must be (N, 6, {len(self.names)}), got {self._X.shape}")

    @property
    def k(self) -> int:
        return len(self.names)

    @property
    def n(self) -> int:
        if self._X is not None:
            return len(self._X)
        if self.basis is not None:
            return len(self.basis)
        return len(self._blocks[0][2]) if self._blocks else 0

    @property
    def dense(self) -> bool:
        return self._X is not None

    def channel_blocks(self) -> tuple:
        """``((channel, columns (m_c,), B (N, m_c)), ...)``: each channel's non-zero columns (class docstring)."""
        if self._blocks is None:
            if self.basis is not None:
                m = self.basis.shape[1]
                self._blocks = tuple((c, np.arange(i * m, (i + 1) * m), self.basis) for i, c in enumerate(self.channels))
            else:
                X = self._X
                assert X is not None  # one of X, basis and blocks (__init__)
                nz = np.any(X != 0, axis=0)                            # (6, k): columns not identically zero per channel
                self._blocks = tuple((c, np.flatnonzero(nz[c]), np.ascontiguousarray(X[:, c, nz[c]]))
                                     for c in range(6) if nz[c].any())
        return self._blocks

    def any(self) -> bool:
        """Whether any column is non-zero anywhere."""
        if self._X is not None:
            return bool(np.any(self._X))
        if self.basis is not None:
            return bool(np.any(self.basis))
        return any(bool(np.any(B)) for _, _, B in self.channel_blocks())

    @property
    def X(self) -> np.ndarray:
        if self._X is not None:
            return self._X
        X = np.zeros((self.n, 6, self.k))
        for c, cols, B in self.channel_blocks():
            X[:, c, cols] = B
        return X

    def wrench(self, beta: np.ndarray, rows=slice(None)) -> np.ndarray:
        """The effect's wrench (N, 6) (of ``rows``) for parameters ``beta`` (k,)."""
        beta = np.asarray(beta, float)
        if self._X is not None and self._blocks is None:
            return self._X[rows] @ beta
        if self.basis is not None:
            B = self.basis[rows]
            out = np.zeros((len(B), 6))
            out[:, list(self.channels)] = B @ beta.reshape(len(self.channels), -1).T
            return out
        # channel blocks (a dense face once the diagnosis has found them): each channel's non-zero columns only
        n = len(np.arange(self.n)[rows]) if not isinstance(rows, slice) or rows != slice(None) else self.n
        out = np.zeros((n, 6))
        for c, cols, B in self.channel_blocks():
            out[:, c] = B[rows] @ beta[cols]
        return out

    @staticmethod
    def per_channel(basis: np.ndarray, labels: tuple[str, ...], unit_f: str = "N", unit_t: str = "N*m",
                    shape: dict | None = None, channels=range(6)) -> "FreeFace":
        """A face whose columns act one channel each: ``basis`` (N, m) per channel of ``channels``, labels
        ``"<channel>.<label> [unit]"`` (column order: channel-major)."""
        basis = np.asarray(basis, float)
        chans = tuple(channels)
        names = [f"{WRENCH[c]}.{lab} [{unit_f if c < 3 else unit_t}]" for c in chans for lab in labels]
        return FreeFace(None, tuple(names), shape, basis=basis, channels=chans)

    @staticmethod
    def channelwise(bases, names, shape: dict | None = None, channels=range(6)) -> "FreeFace":
        """A face whose channel ``channels[i]`` has its own columns ``bases[i]`` (N, m) (column order channel-major:
        channel ``i``'s are ``i m .. (i + 1) m - 1``; ``names`` k = m x channels labels)."""
        chans = tuple(channels)
        bases = [np.asarray(B, float) for B in bases]
        bases = [B[:, None] if B.ndim == 1 else B for B in bases]
        m = bases[0].shape[1] if bases else 0
        return FreeFace(None, names, shape, blocks=tuple((c, np.arange(i * m, (i + 1) * m), B)
                                                         for i, (c, B) in enumerate(zip(chans, bases))))


@dataclass(frozen=True)
class FreeLoadContext:
    """One transducer's free-load samples, all recordings in which it hangs free, in recording order (module
    docstring). Arrays are over the N samples; ``q``/``qd``/``qdd`` joint -> (N,); optional fields None when the
    data lack them (a face that needs one returns None)."""

    leg: str
    names: tuple[str, ...]                 # recordings
    rec: np.ndarray                        # (N,) recording index into names
    index: np.ndarray                      # (N,) row of the sample in its recording
    t: np.ndarray                          # (N,) s, session clock
    y: np.ndarray                          # (N, 6) readings, N and N*m in ft
    pred: np.ndarray                       # (N, 6) the free-load fit's model readings
    g_ft: np.ndarray                       # (N, 3) gravity in ft (m/s^2; with the fitted mounting rotation)
    g_B: np.ndarray                        # (N, 3) gravity in B (m/s^2)
    still: np.ndarray                      # (N,) bool: quasi-static (what the fit selected)
    hold: np.ndarray                       # (N,) int hold id, -1 moving
    since_change: np.ndarray               # (N,) s since the load last changed
    load_step: np.ndarray                  # (N, 6) the predicted wrench's change at that change
    pred_rate: np.ndarray                  # (N, 6) d pred / dt
    g_rate: np.ndarray                     # (N, 3) d g_ft / dt
    omega: np.ndarray                      # (N,) rad/s rate of turn of gravity in ft
    q: dict[str, np.ndarray] = field(default_factory=dict)
    qd: dict[str, np.ndarray] = field(default_factory=dict)
    qdd: dict[str, np.ndarray] = field(default_factory=dict)
    joint_limits: dict[str, tuple[float, float]] = field(default_factory=dict)   # URDF limits, where known
    quat: np.ndarray | None = None         # (N, 4) [qw, qx, qy, qz] of B in the world, if recorded
    omega_B: np.ndarray | None = None      # (N, 3) rad/s body rate of turn in B, from quat
    temperature: np.ndarray | None = None  # (N,) degC, if the recordings carry a `temperature` column
    sigma: np.ndarray | None = None        # (6,) noise sd per channel (the diagnosis' floor)
    load: Any = None                       # the loads.LinearLoad (inertia for inertial_load)
    theta: np.ndarray | None = None        # its fitted parameters
    rotation: np.ndarray | None = None     # (3, 3) fitted mounting rotation E
    offset: np.ndarray | None = None       # (6,) the fitted offsets w_o: ``pred - offset`` is the load's own wrench
    extra: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def load_wrench(self) -> np.ndarray | None:
        """The load's own wrench in ft (N, 6), ``pred - offset`` (what a gain or crosstalk of the sensor multiplies);
        None when the offsets are not known."""
        return None if self.offset is None else self.pred - self.offset

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self.q)

    @property
    def dt(self) -> float:
        """The median sample period (s) within recordings."""
        d = np.diff(self.t)[np.diff(self.rec) == 0]
        return float(np.median(d)) if d.size else 1.0

    def relaxation(self, tau: float, negated: bool = False, keep: bool = True) -> np.ndarray:
        """``pred - lowpass_tau(pred)`` (N, 6), each recording apart (``signals.relaxation``: what of each change of the
        model readings is still to relax): the column every relaxation face (creep) is built of; ``negated``: its
        negative ``lowpass_tau(pred) - pred`` (creep's columns: exactly the negation, formed as that difference), the
        cached array itself (read-only), otherwise a new array. ``keep``: cache a new result (False: a time constant
        asked for once, e.g. a refinement's trial or a derivative's neighbour, is not kept: the cache's memory is
        fresh memory, paid for in page faults). The recordings' rows and their channel-major copies of ``pred`` are
        found once (a face's grid and its refinement ask for it many times); the result is a channel-major array seen
        as (N, 6) (a channel's column is contiguous)."""
        done = self._relaxation_cache()[5]     # the last few time constants' results (a grid's pairs reuse its single ones)
        tau = float(tau)
        if tau in done:
            out = done[tau]
        else:
            out = self.relaxation_into(tau, np.empty((6, self.n))).T
            out.flags.writeable = False
            if keep:
                if len(done) >= max(4, int(RELAXATION_CACHE_BYTES // max(out.nbytes, 1))):
                    del done[next(iter(done))]
                done[tau] = out
        return out if negated else -out

    def relaxation_into(self, tau: float, out: np.ndarray) -> np.ndarray:
        """The negated relaxation (:meth:`relaxation` with ``negated``) written into ``out`` (6, N) (channel-major; e.g.
        a face's column block), from the cache when it holds ``tau``; returns ``out``."""
        c = self._relaxation_cache()
        tau = float(tau)
        if tau in c[5]:
            out[...] = c[5][tau].T
            return out
        from .signals import relaxation

        for i, xt, clock in zip(c[3], c[4], c[6]):
            if xt.shape[1] <= 1:
                out[:, i] = -relaxation(self.t[i], xt.T, tau).T
            elif isinstance(i, slice):          # a recording's run of samples: filtered straight into its columns
                _relax_rows(self.t[i], xt, tau, out=out[:, i], clock=clock, negated=True)
            else:
                out[:, i] = _relax_rows(self.t[i], xt, tau, clock=clock, negated=True)
        return out

    def forget_relaxations(self) -> None:
        """Drop the cached relaxations (the faces built of them hold their own columns): the chain's later rounds
        reuse its faces, not these arrays."""
        self.extra.pop("_relaxation", None)

    def _relaxation_cache(self) -> tuple:
        c = self.extra.get("_relaxation")
        # the cache is this context's (``select`` and ``dataclasses.replace`` share ``extra``): same arrays or rebuilt
        if c is None or c[0] is not self.t or c[1] is not self.rec or c[2] is not self.pred:
            idx = [np.flatnonzero(self.rec == r) for r in np.unique(self.rec)]
            # a recording's samples are one run (recording after recording): a slice, no gather
            rows: list[slice | np.ndarray] = [slice(int(i[0]), int(i[-1]) + 1) if len(i) and i[-1] - i[0] + 1 == len(i) else i for i in idx]
            c = self.extra["_relaxation"] = (self.t, self.rec, self.pred, rows,
                                             [np.ascontiguousarray(self.pred[i].T) for i in rows], {},
                                             [_clock(self.t[i]) for i in rows])
        return c

    def select(self, mask: np.ndarray) -> "FreeLoadContext":
        """The context restricted to the samples of ``mask`` (derived quantities as computed on all)."""
        m = np.asarray(mask, bool)
        out = {}
        for k, v in self.__dict__.items():
            if isinstance(v, np.ndarray) and v.ndim >= 1 and len(v) == self.n and k not in ("sigma", "offset", "theta", "rotation"):
                out[k] = v[m]
            elif isinstance(v, dict) and k in ("q", "qd", "qdd"):
                out[k] = {j: a[m] for j, a in v.items()}
            else:
                out[k] = v
        return FreeLoadContext(**out)


def _clock(t: np.ndarray) -> tuple[bool, np.ndarray]:
    """``(regular, dt[:1])`` of a recording's clock: whether its sample period is constant (to 1e-9 relative)."""
    dt = np.diff(t)
    return (bool(len(dt)) and not np.ptp(dt) > 1e-9 * max(float(np.mean(dt)), 1e-12)), dt[:1]


def _relax_rows(t: np.ndarray, xt: np.ndarray, tau: float, out: np.ndarray | None = None,
                clock: tuple | None = None, negated: bool = False) -> np.ndarray:
    """``signals.relaxation(t, xt.T, tau).T`` of channel-major (c, n) ``xt`` (into ``out`` (c, n) if given): the same
    recurrence filtered along each channel's contiguous row (faster than along axis 0; bit-identical); an irregular
    clock or ``tau == 0``: ``signals.relaxation`` itself. ``clock``: :func:`_clock` of ``t`` if known. ``negated``: its
    negative (``lowpass - x``, the same differences the other way round: exactly the negation)."""
    from scipy.signal import lfilter

    from .signals import relaxation

    regular, dt1 = _clock(t) if clock is None else clock
    if tau <= 0 or not regular:
        r = relaxation(t, xt.T, tau).T
        if negated:
            r = -r
        if out is not None:
            out[...] = r
        return r
    a0 = float(1.0 - np.exp(-dt1 / tau)[0])
    # the low-pass at sample k is the filter's output at k - 1 (its own first sample at k = 0): filtering the whole
    # row gives the same outputs (a causal filter), and the relaxation is formed in place, without the low-pass array
    y = lfilter([a0], [1.0, -(1.0 - a0)], xt, axis=1, zi=((1.0 - a0) * xt[:, 0])[:, None])[0]
    out = np.empty_like(xt) if out is None else out
    if negated:
        out[:, 0] = -(xt[:, 0] - xt[:, 0])
        np.subtract(y[:, :-1], xt[:, 1:], out=out[:, 1:])
    else:
        out[:, 0] = xt[:, 0] - xt[:, 0]
        np.subtract(xt[:, 1:], y[:, :-1], out=out[:, 1:])
    return out


def rate(x: np.ndarray, t: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """``dx/dt`` by central differences within each recording (one-sided at its ends), any trailing shape."""
    x = np.asarray(x, float)
    out = np.zeros_like(x)
    for i in recording_rows(rec):
        if (i.stop - i.start if isinstance(i, slice) else len(i)) >= 2:
            out[i] = np.gradient(x[i], t[i], axis=0)
    return out


def recording_rows(rec: np.ndarray) -> list:
    """Each recording's rows in recording order (``np.unique(rec)``): a slice when they are one run, else their indices.
    Samples in recording order (non-decreasing ``rec``, recording after recording): the runs' bounds, no search."""
    rec = np.asarray(rec)
    if len(rec) and np.all(rec[1:] >= rec[:-1]):
        b = np.r_[0, np.flatnonzero(rec[1:] != rec[:-1]) + 1, len(rec)]
        return [slice(int(b[k]), int(b[k + 1])) for k in range(len(b) - 1)]
    out = []
    for r in np.unique(rec):
        i = np.flatnonzero(rec == r)
        out.append(slice(int(i[0]), int(i[-1]) + 1) if i[-1] - i[0] + 1 == len(i) else i)
    return out


def holds(still: np.ndarray, rec: np.ndarray, min_hold: int = MIN_HOLD) -> np.ndarray:
    """Hold id (N,) per sample: runs of at least ``min_hold`` consecutive ``still`` samples of one recording
    (numbered in order), -1 elsewhere."""
    still = np.asarray(still, bool)
    out = np.full(len(still), -1)
    start = np.r_[True, (np.diff(still.astype(int)) != 0) | (np.diff(rec) != 0)]
    run = np.cumsum(start) - 1
    h = 0
    for r in np.unique(run[still]):
        i = np.flatnonzero(run == r)
        if len(i) >= min_hold:
            out[i] = h
            h += 1
    return out


def load_history(t: np.ndarray, rec: np.ndarray, hold: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(since_change (N,) s, load_step (N, 6))`` of the module docstring (vectorised over samples)."""
    n = len(t)
    since = np.zeros(n)
    step = np.zeros((n, 6))
    H = int(hold.max()) + 1 if n and hold.max() >= 0 else 0
    if H == 0:
        return since, step
    inh = hold >= 0
    cnt = np.bincount(hold[inh], minlength=H).astype(float)
    mean = np.stack([np.bincount(hold[inh], weights=pred[inh, c], minlength=H) for c in range(6)], axis=1) / cnt[:, None]
    first = np.full(H, n)
    np.minimum.at(first, hold[inh], np.flatnonzero(inh))
    last = np.full(H, -1)
    np.maximum.at(last, hold[inh], np.flatnonzero(inh))
    hold_rec = rec[first]
    # the previous hold of each sample: the last hold that ended before it, in its recording
    mark = np.full(n, -1)
    mark[last[last + 1 < n] + 1] = np.flatnonzero(last + 1 < n)
    prev = np.maximum.accumulate(mark)
    prev = np.where((prev >= 0) & (hold_rec[np.clip(prev, 0, None)] == rec), prev, -1)
    has = prev >= 0
    step[has] = pred[has] - mean[prev[has]]
    # the change ends where the hold starts: the last moving sample before it (the recording's start for a first hold)
    s0 = first[hold[inh]]
    before = np.clip(s0 - 1, 0, None)
    t0 = np.where((s0 > 0) & (rec[before] == rec[inh]), t[before], t[s0])
    since[inh] = t[inh] - t0
    return since, step


def body_rate(quat: np.ndarray, t: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """Body rate of turn in B (N, 3) rad/s from unit quaternions ``[qw, qx, qy, qz]``: ``omega = 2 vec(q* dq/dt)``."""
    q = np.asarray(quat, float)
    dq = rate(q, t, rec)
    w, v = q[:, :1], q[:, 1:]
    dw, dv = dq[:, :1], dq[:, 1:]
    # vector part of conj(q) * dq
    return 2.0 * (w * dv - dw * v - np.cross(v, dv))


def make_context(leg: str, t: np.ndarray, y: np.ndarray, pred: np.ndarray, g_ft: np.ndarray, *,
                 rec: np.ndarray | None = None, names: tuple[str, ...] | None = None, still: np.ndarray | None = None,
                 g_B: np.ndarray | None = None, q: dict | None = None, joint_limits: dict | None = None,
                 quat: np.ndarray | None = None, temperature: np.ndarray | None = None, sigma: np.ndarray | None = None,
                 index: np.ndarray | None = None, load=None, theta=None, rotation=None, offset=None,
                 min_hold: int = MIN_HOLD, still_rate: float | None = None) -> FreeLoadContext:
    """A :class:`FreeLoadContext` from arrays (module docstring). ``still`` None: samples whose gravity in ft
    turns slower than ``still_rate`` rad/s (default 0.02) and whose joints move slower than it."""
    t = np.asarray(t, float)
    n = len(t)
    rec = np.zeros(n, int) if rec is None else np.asarray(rec, int)
    names = tuple(names) if names is not None else tuple(f"recording{i}" for i in range(int(rec.max()) + 1))
    y = np.asarray(y, float)
    pred = np.asarray(pred, float)
    g_ft = np.asarray(g_ft, float)
    q = {j: np.asarray(v, float) for j, v in (q or {}).items()}
    qd = {j: rate(v, t, rec) for j, v in q.items()}
    qdd = {j: rate(v, t, rec) for j, v in qd.items()}
    g_rate = rate(g_ft, t, rec)
    gn = np.linalg.norm(g_ft, axis=1)
    omega = np.linalg.norm(np.cross(g_ft, g_rate), axis=1) / np.clip(gn**2, 1e-12, None)
    if still is None:
        thr = 0.02 if still_rate is None else still_rate
        still = omega < thr
        for v in qd.values():
            still &= np.abs(v) < thr
    still = np.asarray(still, bool)
    hold = holds(still, rec, min_hold)
    since, step = load_history(t, rec, hold, pred)
    omega_B = body_rate(quat, t, rec) if quat is not None else None
    return FreeLoadContext(
        leg=leg, names=names, rec=rec, index=np.arange(n) if index is None else np.asarray(index), t=t, y=y, pred=pred,
        g_ft=g_ft, g_B=g_ft.copy() if g_B is None else np.asarray(g_B, float), still=still, hold=hold,
        since_change=since, load_step=step, pred_rate=rate(pred, t, rec), g_rate=g_rate, omega=omega, q=q, qd=qd, qdd=qdd,
        joint_limits=dict(joint_limits or {}), quat=None if quat is None else np.asarray(quat, float), omega_B=omega_B,
        temperature=None if temperature is None else np.asarray(temperature, float),
        sigma=None if sigma is None else np.asarray(sigma, float), load=load, theta=theta, rotation=rotation,
        offset=None if offset is None else np.asarray(offset, float))


def session_time_basis(ctx: FreeLoadContext, degree: int) -> np.ndarray:
    """Legendre ``P_1..P_degree`` of the session time scaled to [-1, 1] over the context's span, or the calibration
    session's (``ctx.extra["t_span"]``, a correction of a new recording) (N, degree); each
    ``P_j`` formed once per context (the drift face's degrees and the time correlate share them)."""
    from .faces import legendre_time

    # a correction on a new recording keeps the calibration session's span (ctx.extra["t_span"]: effects/correction.py)
    span = ctx.extra.get("t_span")
    lo, hi = (float(v) for v in span) if span is not None else (float(ctx.t.min()), float(ctx.t.max()))
    c = ctx.extra.get("_legendre")
    if c is None or c[0] is not ctx.t or c[1:3] != (lo, hi):   # the cache is of one clock over one span
        c = ctx.extra["_legendre"] = (ctx.t, lo, hi, {})
    cols: dict[int, np.ndarray] = c[3]
    for j in range(1, degree + 1):
        if j not in cols:
            cols[j] = legendre_time(ctx.t, c[1], c[2], [j])[:, 0]
    return np.stack([cols[j] for j in range(1, degree + 1)], axis=1) if degree > 0 else np.zeros((ctx.n, 0))
