"""What the free-load diagnosis looks at: every sample of a free load, the fit's model there, its Jacobian and the
noise floor from held, still stretches of the readings.

* :func:`context_for`: a :class:`~ftcal_nlp.effects.free_faces.FreeLoadContext` of one transducer over every
  ``hanging`` recording in which its load hangs free, ALL samples (moving ones included; samples whose gravity
  direction is unknown, orientation not tracked, are left out and counted);
* :func:`model_face` (its channel blocks; :func:`model_jacobian` the dense (N, 6, P) array): ``J_n = d h(x; s_n) / d x``
  at the fit, ``x = [w_o (6), theta (p), tilts (2 each), r (3)]``
  (the world tilt of the orientation stream and each ``gravity_body``-only recording's tilt, where the fit has them)
  with ``E = E* expm([r]x)`` (``freeload/problem.py``: ``f = M E^T b + f_o``, ``t = (K theta) x (E^T b) + t_o``,
  ``b = A_n u(tilt)``, ``A_n = g R_nom^T F_n``, ``F_n = R_WB^T`` for an orientation stream, the frame of the
  recording's nominal gravity for ``gravity_body`` (``problem.gravity_frame``), ``u = R_y(ty) R_x(tx) (0, 0, -1)``):
  offsets the identity, ``theta`` exact (the model is linear in it), the tilts and ``r`` to first order (closed
  form; a tilt's columns are zero on the samples of other groups);
* :func:`hold_floor`: the readings' noise sd per channel from held, still stretches: within every window of
  ``FLOOR_WINDOW_S`` (at least ``FLOOR_MIN_SAMPLES`` samples) of a quasi-static hold, the scatter about the
  window's own mean and slope (what no model of a free load can explain: a creep or drift is smooth over the
  window), pooled with its degrees of freedom; windows across which gravity's direction or a joint moves by
  ``STILL_RAD`` or more are not still (a list of single-row poses has no still window: no floor is known). It
  comes from the readings, not from any fit's residual.
"""

from __future__ import annotations

import numpy as np

from ..core.data import Dataset
from ..effects.free_faces import FreeFace, FreeLoadContext, make_context
from ..estimate.freeload.problem import gravity_frame, predict, tilt_derivative, tilt_gravity
from ..core.geometry import quat_to_rotation
from ..loads.base import joint_limits

#: the windows over which the floor's scatter is taken (s) and their least number of samples
FLOOR_WINDOW_S = 0.5
FLOOR_MIN_SAMPLES = 6
#: a floor window is still when gravity's direction in ft and every joint move less than this (rad) across it
STILL_RAD = 3e-3


def context_for(ds: Dataset, leg: str, fit) -> tuple[FreeLoadContext, list[str]]:
    """``(context, notes)``: transducer ``leg``'s free-load samples over every recording in which it hangs free,
    with the fit's predictions (``fit``: its :class:`~ftcal_nlp.estimate.freeload.FreeLoadResult`), module docstring."""
    load = fit.load
    joints = tuple(getattr(load, "load_joints", ())) + tuple(getattr(load, "base_joints", ()))
    g = ds.robot.g
    parts, notes = [], []
    recs = [r for r in ds.hanging if r.hangs_free(leg)]
    for i, rec in enumerate(recs):
        grav = rec.gravity_directions()
        ok = np.all(np.isfinite(grav), axis=1)
        if not ok.all():
            notes.append(f"{rec.path or rec.name}: {int((~ok).sum())} of {rec.n} samples without a gravity direction "
                         "(orientation not tracked) are left out of the diagnosis")
        q = {j: (rec.q[j] if j in rec.q else np.zeros(rec.n))[ok] for j in joints}
        used = fit.used.get(rec.name)
        still = used[ok] if used is not None and len(used) == rec.n else None
        temp = rec.temperature.get(leg)   # the optional {leg}_temp_C / temp_C column (docs/proposals/temperature.md)
        # the frame the sample's gravity is tilted in and the fit's tilt block (freeload.estimate.free_load_data)
        if rec.quat is not None:
            F, block = np.swapaxes(quat_to_rotation(rec.quat[ok]), 1, 2), ("world" if fit.tilt is not None else None)
        elif rec.gravity is not None:
            F, block = gravity_frame(grav[ok]), None
        else:
            F = np.broadcast_to(gravity_frame(grav[:1])[0], (int(ok.sum()), 3, 3))
            block = rec.name if rec.name in getattr(fit, "recording_tilts", {}) else None
        blocks = (["world"] if fit.tilt is not None else []) + list(getattr(fit, "recording_tilts", {}))
        tilt = np.zeros(2) if block is None else (fit.tilt if block == "world" else fit.recording_tilts[block])
        parts.append(dict(t=rec.t[ok], y=rec.wrench[leg][ok], gB=g * F @ tilt_gravity(tilt), q=q, still=still,
                          index=np.flatnonzero(ok), F=F, block=np.full(int(ok.sum()), -1 if block is None else blocks.index(block)),
                          rec=np.full(int(ok.sum()), i), quat=None if rec.quat is None else rec.quat[ok],
                          temp=None if temp is None else np.asarray(temp, float)[ok]))
    cat = lambda k: np.concatenate([p[k] for p in parts])  # noqa: E731
    n = sum(len(p["t"]) for p in parts)
    q = {j: np.concatenate([p["q"][j] for p in parts]) for j in joints}
    g_B = cat("gB")                                      # with the fit's tilts: g F_n u(tilt of the sample's group)
    R_nom = load.nominal_rotation(q, n)
    a = g * np.einsum("nji,njk->nik", R_nom, cat("F"))     # b = a u (freeload docstring)
    b = np.einsum("nji,nj->ni", R_nom, g_B)
    K = load.lever(q, n)
    pred = predict(b, K, fit.theta, load.mass_row, fit.rotation, fit.offset)
    still = None if any(p["still"] is None for p in parts) else cat("still")
    quat = None if any(p["quat"] is None for p in parts) else cat("quat")
    temp = None if any(p["temp"] is None for p in parts) else cat("temp")
    # joints that never move carry no information on where a gap lies
    moving_q = {j: v for j, v in q.items() if np.ptp(v) > 1e-6}
    ctx = make_context(leg, cat("t"), cat("y"), pred, b @ fit.rotation, rec=cat("rec"), names=tuple(r.name for r in recs),
                       still=still, g_B=g_B, q=moving_q, joint_limits=joint_limits(load), quat=quat, temperature=temp,
                       index=cat("index"), load=load, theta=fit.theta, rotation=fit.rotation, offset=fit.offset)
    pos = ds.robot.transducers[leg].position_m
    ctx.extra.update(b=b, K=K, **({} if pos is None else {"position_m": np.asarray(pos, float)}))  # inertial_load's O in B
    ctx.extra.update(a=a, tilt_block=cat("block"))         # b = a u(tilt of block), the tilts' columns
    return ctx, notes


def model_face(ctx: FreeLoadContext, fit) -> FreeFace:
    """The model Jacobian ``J_n = d h / d x`` (module docstring) as a :class:`FreeFace` of channel blocks: per
    channel its columns not identically zero (those :meth:`FreeFace.channel_blocks` finds in the dense ``J``),
    built straight from the closed form (no mostly-zero (N, 6, P) array); names those of ``fit.names``. With ``g = E^T
    b`` and ``s = K theta``: ``d f / d theta_l = mu_l g``, ``d t / d theta_l = K_l x g``; ``E expm([r]x)`` turns
    ``g`` into ``g + g x r`` to first order, so ``d f / d r = (mu.theta) [g]x`` and ``d t / d r = [s]x [g]x``
    (``(i, j)``: ``g_i s_j``, ``-(s_j g_j + s_k g_k)`` on the diagonal); with a tilt (``ctx.extra["a"]``)
    ``d g / d tilt = E^T A_n du/dtilt``, ``d f / d tilt = (mu.theta) dg``, ``d t / d tilt = s x dg`` on its group's
    samples, zero on the others'. Each block is filled a column at a time as contiguous rows of (m_c, N) and
    transposed once."""
    b, K = ctx.extra["b"], ctx.extra["K"]
    load, E = fit.load, fit.rotation
    mu = np.asarray(load.mass_row, float)
    theta = np.asarray(fit.theta, float)
    mt = float(mu @ theta)
    p = len(theta)
    n = ctx.n
    g = b @ E                                                    # (N, 3): (E^T b_n)^T
    s = K @ theta                                                # (N, 3) (or (3,)) first moment in ft
    gT = np.ascontiguousarray(g.T)                               # (3, N) rows: contiguous column writes
    sT = np.ascontiguousarray(np.broadcast_to(s, (n, 3)).T)
    KT = np.moveaxis(K, 0, -1) if K.ndim == 3 else K[:, :, None]  # (3, p, N) or (3, p, 1)
    tilts = ([] if getattr(fit, "tilt", None) is None else [fit.tilt]) + list(getattr(fit, "recording_tilts", {}).values())
    nt = 2 * len(tilts)
    r0 = 6 + p + nt
    groups = []                                                  # (first column, rows, dg (3, 2, n_k), s (3, n_k))
    for k, tilt in enumerate(tilts):   # each tilt moves the samples of its group only
        rows = _rows(ctx.extra["tilt_block"] == k)
        ak = ctx.extra["a"][rows]
        nk = len(ak)
        # dg[n] = E^T A_n du/dtilt (3, 2): two products over the stacked rows
        aD = (ak.reshape(3 * nk, 3) @ tilt_derivative(tilt)).reshape(nk, 3, 2)
        dg = (aD.transpose(0, 2, 1).reshape(2 * nk, 3) @ E).reshape(nk, 2, 3)   # (n_k, t, j)
        groups.append((6 + p + 2 * k, rows, np.ascontiguousarray(dg.transpose(2, 1, 0)), sT[:, rows]))
    blocks = []
    for c in range(6):
        i, torque = c % 3, c >= 3
        j, k = (i + 1) % 3, (i + 2) % 3
        cols = ([c] + [6 + m for m in range(p) if torque or mu[m] != 0] + [cg + t for cg, *_ in groups for t in (0, 1)]
                + [r0 + m for m in range(3) if torque or m != i])
        Bt = np.empty((len(cols), n))
        Bt[0] = 1.0                                              # the offset
        row = 1
        for m in range(p):
            if torque:                                           # (K_m x g)_i, np.cross's products and order
                np.multiply(KT[j, m], gT[k], out=Bt[row])
                Bt[row] -= KT[k, m] * gT[j]
                row += 1
            elif mu[m] != 0:
                np.multiply(gT[i], mu[m], out=Bt[row])
                row += 1
        for _, rows, dg, sk in groups:
            for t in (0, 1):
                out = Bt[row]
                if not (isinstance(rows, slice) and rows == slice(0, n)):
                    out[:] = 0.0
                if torque:                                       # (s x dg)_i
                    v = sk[j] * dg[k, t]
                    v -= sk[k] * dg[j, t]
                    out[rows] = v
                else:
                    out[rows] = dg[i, t] * mt
                row += 1
        for m in range(3):
            if torque and m == i:                                # [s]x [g]x diagonal
                np.multiply(sT[j], gT[j], out=Bt[row])
                Bt[row] += sT[k] * gT[k]
                np.negative(Bt[row], out=Bt[row])
            elif torque:                                         # [s]x [g]x off the diagonal: g_i s_m
                np.multiply(gT[i], sT[m], out=Bt[row])
            elif m != i:                                         # (mu.theta) [g]x: +-g of the third index
                np.multiply(gT[3 - i - m], (1.0 if (m - i) % 3 == 2 else -1.0) * mt, out=Bt[row])
            else:
                continue
            row += 1
        keep = np.array([True] + [bool(np.any(Bt[q])) for q in range(1, len(cols))])
        blocks.append((c, np.asarray(cols)[keep], np.ascontiguousarray((Bt if keep.all() else Bt[keep]).T)))
    return FreeFace(None, tuple(fit.names), blocks=tuple(blocks))


def model_jacobian(ctx: FreeLoadContext, fit) -> tuple[np.ndarray, tuple[str, ...]]:
    """``(J (N, 6, P), names)``: :func:`model_face` as its dense array (module docstring), columns
    ``[w_o (6), theta (p), tilts (2 each), r (3)]``, ``names`` those of ``fit.names``."""
    face = model_face(ctx, fit)
    return face.X, face.names


def _rows(mask: np.ndarray) -> slice | np.ndarray:
    """The rows of ``mask`` as a slice when they are one run (a view, no gathered copy), else their indices."""
    i = np.flatnonzero(mask)
    if len(i) and i[-1] - i[0] + 1 == len(i):
        return slice(int(i[0]), int(i[-1]) + 1)
    return i


def hold_floor(ctx: FreeLoadContext) -> tuple[np.ndarray, int]:
    """``(floor (6,), samples)``: the noise sd per channel from held, still stretches (module docstring); NaN when
    the data hold no still stretch of ``FLOOR_MIN_SAMPLES`` samples."""
    dt = ctx.dt
    m = max(FLOOR_MIN_SAMPLES, int(round(FLOOR_WINDOW_S / max(dt, 1e-9))))
    ss, dof, used = np.zeros(6), 0, 0
    for h in np.unique(ctx.hold[ctx.hold >= 0]):
        i = np.flatnonzero(ctx.hold == h)
        nw = len(i) // m
        if nw == 0:
            continue
        idx = i[: nw * m].reshape(nw, m)
        # a window is still when gravity in ft and the joints stay put across it (a list of single-row poses has none)
        still = np.ptp(ctx.g_ft[idx] / np.linalg.norm(ctx.g_ft[idx], axis=2, keepdims=True), axis=1).max(axis=1) < STILL_RAD
        for q in ctx.q.values():
            still &= np.ptp(q[idx], axis=1) < STILL_RAD
        idx = idx[still]
        nw = len(idx)
        if nw == 0:
            continue
        y = ctx.y[idx]                                   # (nw, m, 6)
        tt = ctx.t[idx] - ctx.t[idx].mean(axis=1, keepdims=True)
        yc = y - y.mean(axis=1, keepdims=True)
        slope = (tt[..., None] * yc).sum(axis=1, keepdims=True) / np.clip((tt**2).sum(axis=1), 1e-300, None)[:, None, None]
        e = yc - slope * tt[..., None]
        ss += (e**2).sum(axis=(0, 1))
        dof += nw * (m - 2)
        used += nw * m
    if dof == 0:
        return np.full(6, np.nan), 0
    return np.sqrt(ss / dof), used
