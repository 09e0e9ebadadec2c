"""The free-load fit itself (the steps of the package docstring): data assembly over recordings, start, NLP
solves with re-weighting, information, identifiability, covariance, notes; and the Calibration it makes.

Keys it adds to a transducer's entry of ``calibration.json`` beside ``OUTPUT_FORMAT.md``'s: ``mount_rotation`` (``E``),
``urdf`` and ``link`` (where the load or its orientation comes through a URDF: what ``correct`` and ``export``
rebuild it from), and for a fixed base (every recording the fit used gives gravity by ``gravity_body`` alone, one
direction: an arm on its pedestal) ``gravity_body`` (unit, B: the direction the fit used, the recordings' estimated
tilt ``recording_tilt_rad`` applied, so that a later recording with joints only is corrected as the calibration saw
the base), ``gravity_body_nominal`` (the manifest's) and ``gravity_body_recordings`` (:func:`fixed_base_gravity`).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from ...core.calibration import Calibration
from ...core.data import Dataset
from ...core.errors import DataFormatError
from ...core.geometry import project_to_so3, quat_to_rotation, rotation_to_rotvec
from ...loads import load_for
from ...core.settings import FreeLoadSettings
from ...core.solver import identifiability
from .nlp import nlp_for
from .problem import (FreeLoadData, compress, compress_tilted, difference_noise, gravity_frame, n_lifted, predict,
                      serial_inflation, tilt_gravity)
from .quasistatic import select_quasi_static
from .result import WRENCH, FreeLoadResult, FreeLoadResults

log = logging.getLogger(__name__)

# a direction's components (unit vector, normalised units) above this fraction of its largest are named in its text
FLAG_FRACTION = 0.05
# ... and any component above this marks the parameter as undetermined (se = inf): the null space's eigenvectors are
# accurate to ~eps / (eigenvalue gap) ~ 1e-11 at the identifiability threshold, so a larger component is real
TOUCH_TOL = 1e-6
# a joint whose angle spans less than this over the samples used never moved (its group is not separable)
_STILL_JOINT_RAD = 1e-3


def free_load_data(ds: Dataset, leg: str, settings: FreeLoadSettings, load) -> FreeLoadData:
    """The quasi-static samples of ``leg``'s free load over every hanging recording in which it hangs free."""
    s = settings
    g = ds.robot.g
    joints = tuple(getattr(load, "load_joints", ())) + tuple(getattr(load, "base_joints", ()))
    ys, gs, qs, src, ts, idx, names, selection, masks, Rw = [], [], [], [], [], [], [], {}, {}, []
    recs = [r for r in ds.hanging if r.hangs_free(leg)]
    if not recs:
        raise DataFormatError(f"{ds.manifest or 'dataset'}: transducer {leg}: no hanging recording in which its load hangs free "
                              "(kind = \"hanging\"; free = [...] lists the transducers)")
    for i, rec in enumerate(recs):
        grav = rec.gravity_directions()
        q = {j: rec.q[j] for j in joints if j in rec.q}
        sel = select_quasi_static(rec.t, rec.wrench[leg][:, :3], rec.quat, rec.gravity, q, s, str(rec.path or rec.name))
        selection[rec.name] = {**sel.counts, "thresholds": sel.thresholds}
        log.info("%s, transducer %s: %d of %d samples quasi-static (%d dropped: moving, or orientation not tracked)",
                 rec.path or rec.name, leg, sel.counts["kept"], sel.counts["samples"], sel.counts["dropped"])
        m = sel.mask
        masks[rec.name] = m
        ys.append(rec.wrench[leg][m])
        gs.append(g * grav[m])
        # the frame gravity is tilted in: R_WB^T (the stream's world) where the recording has the orientation; a frame
        # of its nominal direction for gravity_body only (a tilt per recording); gx..gz: no tilt (fixed)
        if rec.quat is not None:
            Rw.append(("world", "", np.swapaxes(quat_to_rotation(rec.quat[m]), 1, 2)))
        elif rec.gravity is not None:
            Rw.append(("fixed", "", gravity_frame(grav[m])))
        else:
            Rw.append(("recording", rec.name, np.broadcast_to(gravity_frame(grav[:1])[0], (int(m.sum()), 3, 3))))
        qs.append({j: rec.q[j][m] if j in rec.q else np.zeros(int(m.sum())) for j in joints})
        src.append(np.full(int(m.sum()), i))
        ts.append(rec.t[m])
        idx.append(np.flatnonzero(m))
        names.append(rec.name)
    n = sum(len(y) for y in ys)
    n_unknown = 6 + len(load.param_names) + (3 if s.mount_rotation else 0)
    min_samples = s.min_samples or int(np.ceil(2 * n_unknown / 6))
    if n < min_samples:
        counts = "; ".join(f"{k}: {v['kept']} of {v['samples']}" for k, v in selection.items())
        raise DataFormatError(
            f"{', '.join(str(r.path or r.name) for r in recs)}: transducer {leg}: {n} quasi-static sample(s) "
            f"({counts}); expected at least "
            f"{min_samples}: samples where the body turns slower than {s.rotation_rate_threshold_rad_s:g} rad/s, the joints "
            f"slower than {s.joint_rate_threshold_rad_s:g} rad/s and the forces change slower than {s.deriv_threshold_N_s:g} N/s "
            "(thresholds rise with the noise); is the load ever held still?")
    y = np.concatenate(ys)
    g_B = np.concatenate(gs)
    q = {j: np.concatenate([qq[j] for qq in qs]) for j in joints}
    R_nom = load.nominal_rotation(q, n)
    b = np.einsum("nji,nj->ni", R_nom, g_B)
    K = load.lever(q, n)
    source = np.concatenate(src)
    index = np.concatenate(idx)
    noise0 = difference_noise(y, source, index)
    tiltable = all(k == "world" for k, _, _ in Rw)
    # b = g R_nom^T F u (F the group's frame, u = (0, 0, -1) untilted): a[n][:, k] = g R_nom^T F e_k
    a = g * np.einsum("nji,njk->nik", R_nom, np.concatenate([F for _, _, F in Rw]))
    order = ([("world", "")] if any(k == "world" for k, _, _ in Rw) else []) + [(k, nm) for k, nm, _ in Rw if k == "recording"] \
        + ([("fixed", "")] if any(k == "fixed" for k, _, _ in Rw) else [])
    group = np.concatenate([np.full(len(F), order.index((k, nm))) for k, nm, F in Rw])
    return FreeLoadData(leg, y, b, K, R_nom, source, np.concatenate(ts), tuple(names), selection, noise0, masks, q, index,
                        a, tiltable, group, tuple(order))


def _lin_map(p: int, mu: np.ndarray) -> np.ndarray:
    """``z = L [w_o; theta]`` at ``E = I`` (d, 6 + p)."""
    d = n_lifted(p)
    L = np.zeros((d, 6 + p))
    L[:6, :6] = np.eye(6)
    eI = np.eye(3).ravel()
    L[6:15, 6:] = np.outer(eI, mu)
    for l in range(p):
        L[15 + 9 * l: 24 + 9 * l, 6 + l] = eI
    return L


def _ridge(A: np.ndarray, weight: float) -> np.ndarray:
    dg = np.clip(np.diag(A), 0.0, None)
    fill = dg[dg > 0].mean() if np.any(dg > 0) else 1.0
    return weight * np.where(dg > 0, dg, fill)


def _keep(p: int, free: np.ndarray, mount: bool) -> np.ndarray:
    """Local coordinates ``[w_o, theta, tilt per group, delta]`` that are estimated."""
    return np.r_[np.ones(6 + p, bool), np.repeat(np.asarray(free, bool), 2), np.full(3, mount)]


def _local_info(nlp, Qs: list[np.ndarray], x: np.ndarray, E: np.ndarray, p: int, G: int) -> np.ndarray:
    """Gauss-Newton information ``sum_g J_g^T Q_g J_g`` (9 + p + 2G) in local coordinates, each group's tilt its own
    two columns (``nlp.jacobian`` per group)."""
    nl = 9 + p + 2 * G
    A = np.zeros((nl, nl))
    for k, Q in enumerate(Qs):
        J = nlp.jacobian(x[:6], x[6:6 + p], x[6 + p + 2 * k:8 + p + 2 * k], E)
        idx = np.r_[np.arange(6 + p), 6 + p + 2 * k, 7 + p + 2 * k, np.arange(nl - 3, nl)]
        A[np.ix_(idx, idx)] += J.T @ Q @ J
    return A


def _null_count(A: np.ndarray, s: FreeLoadSettings, keep: np.ndarray, cand: np.ndarray) -> tuple[int, np.ndarray]:
    """Undetermined directions of ``A`` over ``keep`` and, per local coordinate in ``cand``, whether one moves it."""
    ident = identifiability(A[np.ix_(keep, keep)], s.rel_eig_tol)
    moved = np.zeros(len(keep), bool)
    moved[keep] = np.any(np.abs(ident.vectors[:, ~ident.determined]) >= TOUCH_TOL, axis=1)
    return int((~ident.determined).sum()), moved & cand


def _recording_tilts_held(A: np.ndarray, s: FreeLoadSettings, p: int, free: np.ndarray, rec: np.ndarray) -> np.ndarray:
    """The per-recording tilt groups (``rec``, bool per group) held at 0 under ``recording_tilt = "auto"``: those that
    create undetermined directions the other parameters (``free`` tilts, offsets, load, mount) do not have."""
    return held_tilts(A, s, free, rec, lambda f: _keep(p, f, s.mount_rotation), 6 + p)


def held_tilts(A: np.ndarray, s: FreeLoadSettings, free: np.ndarray, rec: np.ndarray, keep_of, at: int) -> np.ndarray:
    """:func:`_recording_tilts_held` for any layout: ``keep_of(free)`` the estimated local coordinates, the tilts'
    columns from ``at`` (two per group)."""
    n0, _ = _null_count(A, s, keep_of(free & ~rec), np.zeros(len(A), bool))
    held = np.zeros(len(free), bool)
    for _ in range(2):
        trial = free & ~held
        cand = np.zeros(len(A), bool)
        for k in np.flatnonzero(trial & rec):
            cand[at + 2 * k:at + 2 * k + 2] = True
        n1, moved = _null_count(A, s, keep_of(trial), cand)
        if n1 <= n0:
            return held
        touched = moved[at:at + 2 * len(free)].reshape(-1, 2).any(axis=1) & rec
        held |= touched if touched.any() and _ == 0 else rec
    return held


def _null_penalty(A: np.ndarray, s: FreeLoadSettings, tilt) -> np.ndarray | None:
    """``S N N^T S`` over the directions the information ``A`` (local coordinates) leaves undetermined (``nlp.py``);
    ``tilt`` which groups' tilts are free (per group, or one bool for one group)."""
    G = (len(A) - 9) // 2 if np.ndim(tilt) == 0 else len(tilt)
    keep = _keep(len(A) - 9 - 2 * G, np.broadcast_to(np.asarray(tilt, bool), (G,)), s.mount_rotation)
    ident = identifiability(A[np.ix_(keep, keep)], s.rel_eig_tol)
    if ident.determined.all():
        return None
    N = ident.vectors[:, ~ident.determined] * ident.scale[:, None]
    P = np.zeros_like(A)
    P[np.ix_(keep, keep)] = N @ N.T
    return P


def _tilt_undetermined(A: np.ndarray, s: FreeLoadSettings, p: int, G: int, k: int | np.integer) -> bool:
    """Whether an undetermined direction of the information ``A`` (local coordinates) with group ``k``'s tilt free
    (the other groups' held) moves that tilt."""
    free = np.zeros(G, bool)
    free[k] = True
    cand = np.zeros(len(A), bool)
    cand[6 + p + 2 * k:8 + p + 2 * k] = True
    return bool(_null_count(A, s, _keep(p, free, s.mount_rotation), cand)[1].any())


def _describe(u: np.ndarray, names: list[str], ratio: float) -> str:
    a = np.abs(u)
    big = np.flatnonzero(a >= FLAG_FRACTION * a.max())
    big = big[np.argsort(-a[big])][:8]
    un = u / np.abs(u[big]).max()
    return " ".join(f"{un[i]:+.2f} {names[i]}" for i in big) + f" [eigenvalue ratio {max(ratio, 0.0):.1e}]"


def _rref(A: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Reduced row echelon form of the rows of ``A`` (the same row space): each row has a leading 1 and zeros in
    the other rows' leading columns; entries below ``tol`` (relative) are set to 0."""
    A = np.array(A, float)
    rows, r = A.shape[0], 0
    for col in range(A.shape[1]):
        if r == rows:
            break
        piv = r + int(np.argmax(np.abs(A[r:, col])))
        if abs(A[piv, col]) <= tol * max(np.abs(A).max(), 1e-300):
            continue
        A[[r, piv]] = A[[piv, r]]
        A[r] /= A[r, col]
        others = np.arange(rows) != r
        A[others] -= np.outer(A[others, col], A[r])
        r += 1
    A = A[:r]
    A[np.abs(A) < tol * max(np.abs(A).max(), 1e-300)] = 0.0
    return A


def _combo_text(a: np.ndarray, names: list[str]) -> str:
    idx = np.flatnonzero(np.abs(a) > 1e-6)
    return " ".join(f"{a[i]:+.3g} {names[i]}" for i in idx)


def fit_free_load(ds: Dataset, leg: str, settings: FreeLoadSettings | None = None) -> FreeLoadResult:
    """Fit transducer ``leg``'s free load (module docstring). Raises :class:`DataFormatError` for data that
    cannot (no quasi-static samples) and :class:`~ftcal_nlp.core.errors.SolverError` when IPOPT fails."""
    s = FreeLoadSettings() if settings is None else settings
    load = load_for(ds, leg, s.loads.get(leg))
    data = free_load_data(ds, leg, s, load)
    p = len(load.param_names)
    mu = load.mass_row
    mom = compress(data.y, data.b, data.K)             # at no tilt: the linear start
    G = len(data.groups)
    kinds = np.array([k for k, _ in data.groups])
    world, rec = kinds == "world", kinds == "recording"
    tilt_on = bool(s.gravity_tilt and world.any())     # the world tilt is a parameter (estimated, or held and named)
    want = (world & bool(s.gravity_tilt)) | (rec & (s.recording_tilt is not False))
    free = want.copy()
    held_recs = np.zeros(G, bool)
    # any tilt: the NLP, one set of exact moments per group (the world's, each gravity_body recording's, the fixed)
    moms = [compress_tilted(data.y[data.group == k], data.a[data.group == k], data.K[data.group == k]) for k in range(G)]
    sig = data.noise0 if np.all(np.isfinite(data.noise0)) and np.all(data.noise0 > 0) else None
    nlp = nlp_for(mu, G)
    # start: linear least squares at E = I (a little ridge toward the prior pins what it cannot see)
    L = _lin_map(p, mu)
    prior = load.prior()
    th0 = np.zeros(p) if prior is None else np.asarray(prior, float)
    if sig is None:  # no consecutive samples: unit weights for the start, the residuals give the sd
        sig = np.ones(6)
    W = 1.0 / sig**2
    Qw, vw, sw = mom.weighted(W)
    A = L.T @ Qw @ L
    r_lin = _ridge(A, s.prior_weight)
    x_prior_lin = np.r_[np.zeros(6), th0]
    x_lin = np.linalg.solve(A + np.diag(r_lin), L.T @ vw + r_lin * x_prior_lin)
    if prior is None:
        th0 = x_lin[6:]
    E = np.eye(3)
    x = np.r_[x_lin, np.zeros(2 * G), E.ravel(order="F")]
    x0 = np.r_[np.zeros(6), th0, np.zeros(2 * G), np.eye(3).ravel(order="F")]
    what = f"the free load of transducer {leg} ({load.kind}; recordings {list(data.names)})"
    t0 = time.perf_counter()
    iters = 0
    nt = 6 + p + 2 * G                                   # index of vec(E) in x
    for _ in range(2):  # noise weights, then residual-sd weights
        Qv = [m.weighted(W) for m in moms]
        Al = _local_info(nlp, [q[0] for q in Qv], x, E, p, G)
        ridge = np.r_[_ridge(Al[:nt, :nt], s.prior_weight), np.full(9, _ridge(Al[nt:, nt:], s.prior_weight).mean())]
        if _ == 0:  # a tilt the data leave undetermined stays at 0 (else it wanders along the valley)
            for k in np.flatnonzero(world & want):
                free[k] = not (_tilt_undetermined(Al, s, p, G, k) or _orientation_notes(data, leg))
            if s.recording_tilt == "auto" and (rec & free).any():
                held_recs = _recording_tilts_held(Al, s, p, free, rec)
                free &= ~held_recs
        x, st = nlp.solve([q[0] for q in Qv], [q[1] for q in Qv], mom.n, ridge, x0, x, mount_rotation=s.mount_rotation,
                          tilt=free, what=what, null_penalty=_null_penalty(Al, s, free))
        iters += int(st.get("iter_count", 0))
        E = project_to_so3(x[-9:].reshape(3, 3, order="F"))
        rss = sum(m.rss(nlp.z_tilted(np.r_[x[:6 + p], x[6 + p + 2 * k:8 + p + 2 * k], E.ravel(order="F")]))
                  for k, m in enumerate(moms))
        dof = (6 + p + (3 if s.mount_rotation else 0) + 2 * int(free.sum())) / 6.0
        sig = np.sqrt(np.clip(rss, 1e-300, None) / max(mom.n - dof, 1.0))
        W = 1.0 / sig**2
    solve_time = time.perf_counter() - t0
    w_o, theta, tilts = x[:6], x[6:6 + p], x[6 + p:nt]
    U = np.stack([tilt_gravity(tilts[2 * k:2 * k + 2]) for k in range(G)])
    b_t = np.einsum("nik,nk->ni", data.a, U[data.group])            # gravity in ft, each group's tilt
    # information in local coordinates [w_o, theta, tilts, delta]; serially correlated residuals (a model error that
    # stays through a hold) carry less information than white noise: their weight shrinks by the AR(1) inflation
    res = data.y - predict(b_t, data.K, theta, mu, E, w_o)
    rho, inflation = serial_inflation(res, data.source, data.index)
    info = _local_info(nlp, [m.weighted(W / inflation)[0] for m in moms], x, E, p, G)
    keep = _keep(p, free, s.mount_rotation)
    tilt_names = [[f"{leg}.tilt.r{c}" for c in "xy"] if kd == "world" else [f"{leg}.{nm}.tilt.r{c}" for c in "xy"]
                  if kd == "recording" else [f"{leg}.fixed.tilt.r{c}" for c in "xy"] for kd, nm in data.groups]
    names = ([f"{leg}.offset.{c}" for c in WRENCH] + [f"{leg}.{n}" for n in load.param_names]
             + [n for t in tilt_names for n in t] + [f"{leg}.mount.r{c}" for c in "xyz"])
    cov, se, null, undetermined, determined, ident = _covariance(info, keep, names, np.r_[w_o, theta, tilts,
                                                                                          rotation_to_rotvec(E)], s)
    rms = np.sqrt((res**2).mean(axis=0))
    if undetermined:
        log.warning("%s: %d direction(s) not determined by the data (se = inf): %s", leg, len(undetermined), "; ".join(undetermined))
    notes = _leg_notes(data, load, leg, rho, inflation)
    rec_names = [nm for (kd, nm) in data.groups if kd == "recording"]
    if rec.any() and s.recording_tilt is False:
        notes.append(f"{leg}: recordings {rec_names} give gravity by gravity_body only: taken as exact (recording_tilt = "
                     "false: no tilt per recording is estimated; a rig's tilt there biases the fit)")
    if held_recs.any():
        held_names = [nm for (kd, nm), h in zip(data.groups, held_recs) if h]
        why = ("one transducer's gravity_body recordings: a tilt per recording and its mounting rotation are not "
               "separable (each recording's gravity direction in ft is free; the mount and the tilts absorb one another)"
               if s.mount_rotation else "a tilt per recording is not determined by these data")
        notes.append(f"{leg}: recordings {held_names} give gravity by gravity_body only: {why}; their tilts are taken as "
                     "exact (held at 0; recording_tilt = \"auto\")")
    if (rec & free).any():
        log.info("%s: a tilt per recording estimated for %s", leg, [nm for (kd, nm), f in zip(data.groups, rec & free) if f])
    if tilt_on and not free[world].all():   # named as undetermined: se inf, held at 0
        se[6 + p:8 + p] = np.inf
        undetermined += [f"{leg}.tilt.r{c} (the world tilt of the orientation stream: gravity spans fewer than three "
                         "directions in ft; held at 0)" for c in "xy"]
        notes.append(f"{leg}: the world tilt of the orientation stream is not determined by these orientations (all about "
                     "one axis, or one orientation): held at 0")
    # the parameters reported: the world tilt where it is one (estimated or named), a recording's where estimated
    shown = (world & tilt_on) | (rec & free)
    out = np.r_[np.arange(6 + p), *[np.arange(6 + p + 2 * k, 8 + p + 2 * k) for k in np.flatnonzero(shown)],
                np.arange(nt, nt + 3)].astype(int)
    names, cov, se, null = [names[i] for i in out], cov[np.ix_(out, out)], se[out], null[out]
    tilt = tilts[:2].copy() if tilt_on else None           # the world group comes first
    rec_tilts = {nm: tilts[2 * k:2 * k + 2].copy() for k, (kd, nm) in enumerate(data.groups) if kd == "recording" and free[k]}
    notes += prior_notes(load, theta, cov[6:6 + p, 6:6 + p], null[6:6 + p], leg)
    for note in notes:
        log.warning("%s", note)
    log.info("free load %s (%s): %d samples, mass %.4g kg, mount rotation %.3g deg, residual RMS %s", leg, load.kind, mom.n,
             float(mu @ theta), np.degrees(np.linalg.norm(np.r_[E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]]) / 2),
             np.array2string(rms, precision=3))
    return FreeLoadResult(leg, load, w_o.copy(), theta.copy(), E, tuple(names), cov, se, sig, rms, mom.n, data.selection,
                          tuple(undetermined), tuple(determined), notes, iters, solve_time, ident.ratio, null, data.masks,
                          None if tilt is None else tilt.copy(), rec_tilts)


def gravity_spread(b: np.ndarray) -> np.ndarray:
    """Singular values (3,) of the centred unit gravity directions ``b`` (N, 3) over sqrt(N): the first below
    ``NARROW`` is one direction, the second a short arc (``_orientation_notes``; the world tilt is held at 0 there)."""
    u = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.linalg.svd(u - u.mean(axis=0), compute_uv=False) / np.sqrt(len(u))


NARROW = 0.02


def _covariance(info: np.ndarray, keep: np.ndarray, names: list[str], x: np.ndarray, s: FreeLoadSettings):
    """``(cov, se, null, undetermined, determined, ident)`` from the information ``info`` over the estimated local
    coordinates ``keep`` (step 4 of the package docstring): covariance on the determined subspace, se inf for
    parameters an undetermined direction moves, the directions described, the determined combinations of those
    parameters (reduced row echelon form) at the estimate ``x`` (local coordinates' values), the null space in the
    parameters' own units."""
    ident = identifiability(info[np.ix_(keep, keep)], s.rel_eig_tol)
    n_all = len(names)
    cov = np.zeros((n_all, n_all))
    cov[np.ix_(keep, keep)] = ident.pinv()
    se = np.full(n_all, np.nan)
    se[keep] = np.sqrt(np.clip(np.diag(cov)[keep], 0.0, None))
    kn = [n for n, k in zip(names, keep) if k]
    undetermined, touched = [], np.zeros(int(keep.sum()), bool)
    for j in np.flatnonzero(~ident.determined):
        u = ident.vectors[:, j]
        touched |= np.abs(u) >= TOUCH_TOL
        undetermined.append(_describe(u, kn, float(ident.ratio[j])))
    se_k = se[keep]
    se_k[touched] = np.inf
    se[keep] = se_k
    determined = []
    if touched.any():
        Nn = ident.vectors[:, ~ident.determined][touched]          # null directions on the touched parameters (scaled)
        U, sv, _ = np.linalg.svd(Nn, full_matrices=True)
        rank = int((sv > 1e-8).sum())
        comp = U[:, rank:]                                          # scaled functionals orthogonal to the null space
        tn = [n for n, t in zip(kn, touched) if t]
        xk = x[keep]
        Ck = cov[np.ix_(keep, keep)]
        for c in _rref((comp * ident.scale[touched][:, None]).T):   # sparse, readable: a leading 1 per combination
            a = np.zeros(len(kn))
            a[touched] = c
            determined.append({"combination": _combo_text(a[touched], tn), "value": float(a @ xk),
                               "se": float(np.sqrt(max(a @ Ck @ a, 0.0))),
                               "coefficients": {n: float(v) for n, v in zip(tn, a[touched]) if v != 0.0}})
    null = np.zeros((n_all, int((~ident.determined).sum())))
    null[keep] = ident.vectors[:, ~ident.determined] / ident.scale[:, None]
    return cov, se, null, undetermined, determined, ident


#: a URDF group's fitted mass this many se and this fraction from its nominal, or its CoM this many se and metres,
#: is named in a note: the URDF's inertial is off (it is only the prior; the fit keeps what the readings give)
PRIOR_NOTE_Z, PRIOR_NOTE_MASS_FRACTION, PRIOR_NOTE_COM_M = 5.0, 0.05, 0.005


def prior_notes(load, theta: np.ndarray, cov: np.ndarray, null: np.ndarray | None, leg: str) -> list[str]:
    """Notes naming the URDF groups whose fitted mass or CoM is far from the URDF's nominal (``load.prior()``; the
    thresholds ``PRIOR_NOTE_*``): the estimates come from the readings, the note tells the user the URDF is off. Loads
    without a nominal (a rigid payload) get none."""
    prior = load.prior() if hasattr(load, "prior") else None
    groups = getattr(load, "groups", None)
    if prior is None or not groups:
        return []
    fitted = load.report(theta, cov, null)["urdf_groups"]   # each group's mass and CoM with se (loads/urdf_subtree.py)
    out = []
    for i, g in enumerate(groups):
        M0, H0 = float(prior[4 * i]), np.asarray(prior[4 * i + 1: 4 * i + 4], float)
        f = fitted[g.name]
        M, se_M = f["mass_kg"], f["mass_se_kg"]
        if M0 <= 0 or M <= 0:
            continue
        dc = np.asarray(f["com_m"]) - H0 / M0
        far_m = abs(M - M0) > max(PRIOR_NOTE_Z * se_M, PRIOR_NOTE_MASS_FRACTION * M0)
        far_c = np.linalg.norm(dc) > PRIOR_NOTE_COM_M and np.any(np.abs(dc) > PRIOR_NOTE_Z * np.asarray(f["com_se_m"]))
        if far_m or far_c:
            out.append(f"{leg}: the URDF's nominal inertial of {', '.join(g.links)} (group '{g.name}') is off: mass "
                       f"{M0:.4g} kg, the readings give {M:.5g} +- {se_M:.2g} kg ({100 * (M - M0) / M0:+.1f} %); CoM "
                       f"{1e3 * np.linalg.norm(dc):.1f} mm from the URDF's (in frame {g.frame}). The calibration keeps "
                       "what the readings give (the URDF is only the prior of what they leave undetermined); correct "
                       "the URDF where other tools use it")
    return out


def _leg_notes(data: FreeLoadData, load, leg: str, rho: np.ndarray, inflation: np.ndarray) -> list[str]:
    """The notes of one transducer's data: its gravity directions, joints that never move, correlated residuals."""
    notes = _orientation_notes(data, leg)
    for g in getattr(load, "groups", ()):
        if g.joint is not None and np.ptp(data.q.get(g.joint, np.zeros(1))) < _STILL_JOINT_RAD:
            notes.append(f"{leg}: joint '{g.joint}' never moves in the samples used (range "
                         f"{np.ptp(data.q.get(g.joint, np.zeros(1))):.2g} rad): the links it carries ({', '.join(g.links)}) "
                         "cannot be told apart from the group above them; their split is the URDF's")
    if np.any(inflation > 2.0):
        notes.append(f"{leg}: residuals correlated from sample to sample (lag-1 correlation {np.array2string(rho, precision=2)} "
                     f"in fx..tz): se widened by {np.array2string(np.sqrt(inflation), precision=2)}; the model misses "
                     "something that stays through a hold (the diagnosis looks for it)")
    return notes


def _orientation_notes(data: FreeLoadData, leg: str) -> list[str]:
    """A note when the gravity directions in ft span fewer than three dimensions (all orientations about one
    axis, or one orientation): the eigen-analysis names the parameters; this says why."""
    sv = gravity_spread(data.b)
    if sv[0] < NARROW:
        return [f"{leg}: gravity stays within ~1 deg of one direction in ft over all quasi-static samples ({', '.join(data.names)}): "
                "one orientation cannot separate the offsets from the load; hang it in several"]
    if sv[1] < NARROW:
        return [f"{leg}: the gravity directions in ft vary along one line only (a short arc: small turns about one axis, "
                f"{', '.join(data.names)}): what they cannot separate is named as undetermined"]
    return []


#: gravity_body-only recordings whose fitted gravity directions agree within this angle hold one base orientation
#: (an arm on its fixed base): ``calibration.json`` keeps it for ``correct`` (:func:`fixed_base_gravity`)
BASE_GRAVITY_TOL_DEG = 1.0


def fixed_base_gravity(r: FreeLoadResult, recordings=()) -> dict:
    """The keys ``gravity_body`` (unit, in B: the direction the fit used, the recording's estimated tilt applied),
    ``gravity_body_nominal`` (the manifest's) and ``gravity_body_recordings`` of transducer ``r.leg``'s calibration
    when every hanging recording it used gives gravity by ``gravity_body`` alone (no ``qw..qz``, no ``gx..gz``: a
    fixed base, an arm on its pedestal) and their fitted directions agree within ``BASE_GRAVITY_TOL_DEG``; else {}
    (several held orientations, or gravity per sample: a later recording must then bring its own)."""
    dirs, nominal, names = [], [], []
    for rec in recordings:
        if not rec.hangs_free(r.leg) or (r.selection and rec.name not in r.selection):
            continue
        if rec.quat is not None or rec.gravity is not None or rec.gravity_body is None:
            return {}
        gb = np.asarray(rec.gravity_body, float) / np.linalg.norm(rec.gravity_body)
        tilt = r.recording_tilts.get(rec.name)
        dirs.append(gb if tilt is None else gravity_frame(gb[None])[0] @ tilt_gravity(tilt))
        nominal.append(gb)
        names.append(rec.name)
    if not dirs:
        return {}
    mean = np.mean(dirs, axis=0)
    mean /= np.linalg.norm(mean)
    spread = max(float(np.degrees(np.arccos(np.clip(d @ mean, -1.0, 1.0)))) for d in dirs)
    if spread > BASE_GRAVITY_TOL_DEG:
        return {}
    nom = np.mean(nominal, axis=0)
    return {"gravity_body": (mean / np.linalg.norm(mean)).tolist(), "gravity_body_nominal": (nom / np.linalg.norm(nom)).tolist(),
            "gravity_body_recordings": names}


def free_load_calibration(res: FreeLoadResults, robot, recordings=()) -> Calibration:
    """The :class:`~ftcal_nlp.core.calibration.Calibration` of free loads: per transducer its offsets with se, the load's
    weight, and the load's keys of ``OUTPUT_FORMAT.md`` (``load_mass_kg``, ``load_com_m``, URDF groups and links,
    with se; what is undetermined and the determined combinations), written by ``calibration.json``; with the
    hanging ``recordings`` the fit used, the fixed base's gravity where they hold one (:func:`fixed_base_gravity`)."""
    from ...core.calibration import LegCalibration

    legs = {}
    for k, r in res.legs.items():
        rep = r.load_report()
        rep.update(fixed_base_gravity(r, recordings))
        R_nom = robot.transducers[k].rotation
        com = np.asarray(rep.get("load_com_m", [np.nan] * 3), float)
        if R_nom is not None:
            rep["rotation_to_body"] = (R_nom @ r.rotation).tolist()
        rep["mount_rotation"] = r.rotation.tolist()
        if robot.transducers[k].link is not None and robot.urdf is not None:  # what `correct` needs to rebuild the load
            rep.update(urdf=str(Path(robot.urdf).resolve()), link=robot.transducers[k].link)
        legs[k] = LegCalibration(
            offset=r.offset.copy(), leg_weight_N=rep["load_mass_kg"] * robot.g, com_phi=np.zeros(1), com_xyz=com[None],
            rotation_to_body=R_nom @ r.rotation if R_nom is not None else r.rotation.copy(),
            position_from_com_m=np.zeros(3) if robot.transducers[k].position_m is None else robot.transducers[k].position_m.copy(),
            offset_se=r.se[:6].copy(), leg_weight_se_N=rep["load_mass_se_kg"] * robot.g, load=rep)
    mass = np.nan if robot.mass_kg is None else robot.mass_kg
    return Calibration(legs, mass, robot.g, model="free_load", meta={"free_load": {"identifiability": res.identifiability()}})
