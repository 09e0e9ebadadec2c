"""Transducers fitted together where they share a tilt: one tilt per ``gravity_body``-only recording (the body's),
and the world tilt of the orientation stream, common to every transducer free in it (package docstring).

Transducers ``k`` (offsets ``w_k``, load ``theta_k``, mount ``E_k``) are linked when they hang free in a common
recording that gives gravity by ``gravity_body`` only (and ``recording_tilt`` is not false); a linked cluster is one
NLP (``problem.compress_tilted`` per transducer and tilt group, the groups' tilts shared):

    min  1/(2N) [ sum_k sum_g ||R_kg z_t(w_k, theta_k, E_k, tilt_g) - c_kg||^2 + ridge + e^T P_N e ],
    s.t. E_k^T E_k = I, det E_k >= 0   (each k),

the information ``sum_kg J_kg^T Q_kg J_kg`` in local coordinates ``[w_k, theta_k (each k), tilts, delta_k (each k)]``,
its identifiability, the covariance, and each transducer's :class:`FreeLoadResult` its block (its offsets, load,
the world tilt, the tilts of the recordings it hangs free in, its mount). With every gravity direction from
``gravity_body`` and the mounts free, a common turn of the body is undetermined (three directions, the tilts and
every mount together): ``"auto"`` then holds the tilts (a note); a transducer whose mount something fixes (its
orientation stream, ``gx..gz``) determines the shared tilts, and through them the mounts of those that have none.
"""

from __future__ import annotations

import logging
import time

import casadi as ca
import numpy as np

from ...core.data import Dataset
from ...core.errors import DataFormatError
from ...core.geometry import project_to_so3, rotation_to_rotvec
from ...loads import load_for
from ...core.settings import FreeLoadSettings
from ...core.solver import identifiability, ipopt, solve_checked
from .estimate import (_covariance, _leg_notes, _lin_map, _orientation_notes, _null_count, _ridge, fit_free_load,
                       free_load_data, held_tilts)
from .nlp import _IPOPT, _lifted_mx, _tilted, nlp_for, square_root
from .problem import compress, compress_tilted, n_tilted, predict, serial_inflation, tilt_gravity
from .result import WRENCH, FreeLoadResult, FreeLoadResults
from .sensor_matrix import fit_sensor_matrix
from .sensor_matrix import options as sensor_matrix_options

log = logging.getLogger(__name__)


def shares_tilt(rec) -> bool:
    """A recording whose tilt is its own (gravity by ``gravity_body`` only): the transducers free in it share it."""
    return rec.kind == "hanging" and rec.quat is None and rec.gravity is None


def clusters(ds: Dataset, legs: list[str], s: FreeLoadSettings) -> list[list[str]]:
    """The transducers linked by a shared ``gravity_body``-only recording (connected components; singletons when
    ``recording_tilt`` is false)."""
    parent = {k: k for k in legs}

    def root(k):
        while parent[k] != k:
            k = parent[k]
        return k

    if s.recording_tilt is not False:
        for rec in ds.hanging:
            if shares_tilt(rec):
                free = [k for k in legs if rec.hangs_free(k)]
                for k in free[1:]:
                    parent[root(k)] = root(free[0])
    out: dict[str, list[str]] = {}
    for k in legs:
        out.setdefault(root(k), []).append(k)
    return list(out.values())


def _build(mus: list[np.ndarray], pairs: list[tuple[int, int]], T: int) -> ca.Function:
    """The cluster's IPOPT solver (module docstring); ``pairs`` (transducer, group) with data."""
    K = len(mus)
    ps = [len(m) for m in mus]
    w = [ca.MX.sym(f"w{k}", 6) for k in range(K)]
    th = [ca.MX.sym(f"th{k}", ps[k]) for k in range(K)]
    E = [ca.MX.sym(f"E{k}", 3, 3) for k in range(K)]
    tilt = ca.MX.sym("tilt", 2 * T)
    R = {kg: ca.MX.sym(f"R{kg[0]}_{kg[1]}", n_tilted(ps[kg[0]]), n_tilted(ps[kg[0]])) for kg in pairs}
    c = {kg: ca.MX.sym(f"c{kg[0]}_{kg[1]}", n_tilted(ps[kg[0]])) for kg in pairs}
    x = ca.vertcat(*[ca.vertcat(w[k], th[k]) for k in range(K)], tilt, *[ca.vec(E[k]) for k in range(K)])
    nx, nl = x.shape[0], x.shape[0] - 6 * K
    r, x0, inv_n, Pn = ca.MX.sym("r", nx), ca.MX.sym("x0", nx), ca.MX.sym("inv_n"), ca.MX.sym("Pn", nl, nl)
    z0 = [_lifted_mx(w[k], th[k], E[k], mus[k]) for k in range(K)]
    fit = sum(ca.sumsqr(ca.mtimes(R[(k, g)], _tilted(z0[k], tilt[2 * g:2 * g + 2])) - c[(k, g)]) for k, g in pairs)
    nb = sum(6 + p for p in ps)
    rot = [0.5 * ca.vertcat(e[2, 1] - e[1, 2], e[0, 2] - e[2, 0], e[1, 0] - e[0, 1]) for e in E]
    e = ca.vertcat(x[:nb + 2 * T] - x0[:nb + 2 * T], *rot)
    obj = 0.5 * inv_n * (fit + ca.dot(r, (x - x0) ** 2) + ca.dot(e, ca.mtimes(Pn, e)))
    g = []
    for k in range(K):
        EtE = ca.mtimes(E[k].T, E[k]) - ca.DM.eye(3)
        g += [EtE[i, j] for i in range(3) for j in range(i, 3)] + [ca.det(E[k])]
    P = ca.vertcat(*[ca.vertcat(ca.vec(R[kg]), c[kg]) for kg in pairs], r, x0, inv_n, ca.vec(Pn))
    return ipopt(f"freeload_joint_k{K}_t{T}", {"x": x, "p": P, "f": obj, "g": ca.vertcat(*g)}, **_IPOPT)


def fit_joint(ds: Dataset, legs: list[str], s: FreeLoadSettings) -> dict[str, FreeLoadResult]:
    """The cluster ``legs`` fitted together (module docstring); each transducer's result."""
    K = len(legs)
    loads = [load_for(ds, k, s.loads.get(k)) for k in legs]
    datas = [free_load_data(ds, k, s, ld) for k, ld in zip(legs, loads)]
    ps = [len(ld.param_names) for ld in loads]
    mus = [np.asarray(ld.mass_row, float) for ld in loads]
    # the cluster's tilt groups: the world (shared: one stream), each gravity_body recording (shared), the fixed
    groups: list[tuple[str, str]] = []
    for kind in ("world", "recording", "fixed"):
        for d in datas:
            groups += [gr for gr in d.groups if gr[0] == kind and gr not in groups]
    T = len(groups)
    kinds = np.array([kd for kd, _ in groups])
    world, rec = kinds == "world", kinds == "recording"
    nb = sum(6 + p for p in ps)
    base = np.cumsum([0] + [6 + p for p in ps])
    # moments per transducer and group (exact, problem.compress_tilted)
    moms, gmap = {}, []
    for k, d in enumerate(datas):
        gl = np.array([groups.index(gr) for gr in d.groups])
        gmap.append(gl)
        for j, gg in enumerate(gl):
            m = d.group == j
            moms[(k, int(gg))] = compress_tilted(d.y[m], d.a[m], d.K[m])
    pairs = sorted(moms)
    solver = _build(mus, pairs, T)
    nlps = [nlp_for(mu, 1) for mu in mus]

    def keep_of(free):
        return np.r_[np.ones(nb, bool), np.repeat(np.asarray(free, bool), 2), np.full(3 * K, s.mount_rotation)]

    def local_info(x, Es, Ws):
        nl = nb + 2 * T + 3 * K
        A = np.zeros((nl, nl))
        for (k, g), mom in moms.items():
            J = nlps[k].jacobian(x[base[k]:base[k] + 6], x[base[k] + 6:base[k + 1]], x[nb + 2 * g:nb + 2 * g + 2], Es[k])
            idx = np.r_[np.arange(base[k], base[k + 1]), nb + 2 * g, nb + 2 * g + 1,
                        np.arange(nb + 2 * T + 3 * k, nb + 2 * T + 3 * k + 3)]
            A[np.ix_(idx, idx)] += J.T @ mom.weighted(Ws[k])[0] @ J
        return A

    # starts: each transducer's linear least squares at E = I, no tilt (estimate.fit_free_load)
    xs, x0s, Ws = [], [], []
    for d, ld, p, mu in zip(datas, loads, ps, mus):
        mom = compress(d.y, d.b, d.K)
        L = _lin_map(p, mu)
        prior = ld.prior()
        th0 = np.zeros(p) if prior is None else np.asarray(prior, float)
        sig = d.noise0 if np.all(np.isfinite(d.noise0)) and np.all(d.noise0 > 0) else np.ones(6)
        W = 1.0 / sig**2
        Qw, vw, _ = mom.weighted(W)
        A = L.T @ Qw @ L
        r_lin = _ridge(A, s.prior_weight)
        x_lin = np.linalg.solve(A + np.diag(r_lin), L.T @ vw + r_lin * np.r_[np.zeros(6), th0])
        if prior is None:
            th0 = x_lin[6:]
        xs.append(x_lin)
        x0s.append(np.r_[np.zeros(6), th0])
        Ws.append(W)
    Es = [np.eye(3)] * K
    x = np.r_[np.concatenate(xs), np.zeros(2 * T), np.tile(np.eye(3).ravel(order="F"), K)]
    x0 = np.r_[np.concatenate(x0s), np.zeros(2 * T), np.tile(np.eye(3).ravel(order="F"), K)]
    want = (world & bool(s.gravity_tilt)) | (rec & (s.recording_tilt is not False))
    free, held_recs = want.copy(), np.zeros(T, bool)
    n_all = sum(d.n for d in datas)
    what = f"the free loads of transducers {legs} (sharing the tilts of their gravity_body recordings)"
    t0, iters = time.perf_counter(), 0
    ne = nb + 2 * T
    for it in range(2):  # noise weights, then residual-sd weights (per transducer)
        Al = local_info(x, Es, Ws)
        ridge = np.r_[_ridge(Al[:ne, :ne], s.prior_weight), np.full(9 * K, _ridge(Al[ne:, ne:], s.prior_weight).mean())]
        if it == 0:
            for g in np.flatnonzero(world & want):   # as estimate.fit_free_load: held where undetermined or narrow
                only = np.zeros(T, bool)
                only[g] = True
                cand = np.zeros(len(Al), bool)
                cand[nb + 2 * g:nb + 2 * g + 2] = True
                free[g] = not (_null_count(Al, s, keep_of(only), cand)[1].any()
                               or all(_orientation_notes(d, k) for d, k in zip(datas, legs)))
            if s.recording_tilt == "auto" and (rec & free).any():
                held_recs = held_tilts(Al, s, free, rec, keep_of, nb)
                free &= ~held_recs
        keep = keep_of(free)
        pen = None   # S N N^T S over the directions the start leaves undetermined (nlp.py)
        ident0 = identifiability(Al[np.ix_(keep, keep)], s.rel_eig_tol)
        if not ident0.determined.all():
            Nn = ident0.vectors[:, ~ident0.determined] * ident0.scale[:, None]
            pen = np.zeros_like(Al)
            pen[np.ix_(keep, keep)] = Nn @ Nn.T
        parts = []
        for kg in pairs:
            Rm, cv = square_root(*moms[kg].weighted(Ws[kg[0]])[:2])
            parts += [Rm.ravel(order="F"), cv]
        nl = len(Al)
        P = np.concatenate(parts + [ridge, x0, [1.0 / n_all], (np.zeros((nl, nl)) if pen is None else pen).ravel(order="F")])
        lbx, ubx = np.full(len(x), -np.inf), np.full(len(x), np.inf)
        if not s.mount_rotation:
            lbx[ne:] = ubx[ne:] = np.tile(np.eye(3).ravel(order="F"), K)
        for g in np.flatnonzero(~free):
            lbx[nb + 2 * g:nb + 2 * g + 2] = ubx[nb + 2 * g:nb + 2 * g + 2] = 0.0
        lbg = np.tile(np.r_[np.zeros(6), 0.0], K)
        ubg = np.tile(np.r_[np.zeros(6), np.inf], K)
        sol, st = solve_checked(solver, what, x0=x, p=P, lbg=lbg, ubg=ubg, lbx=lbx, ubx=ubx)
        x = np.asarray(sol["x"]).ravel()
        iters += int(st.get("iter_count", 0))
        Es = [project_to_so3(x[ne + 9 * k:ne + 9 * k + 9].reshape(3, 3, order="F")) for k in range(K)]
        for k, d in enumerate(datas):
            p = ps[k]
            rss = sum(moms[(k, int(g))].rss(nlps[k].z_tilted(np.r_[x[base[k]:base[k + 1]], x[nb + 2 * g:nb + 2 * g + 2],
                                                                    Es[k].ravel(order="F")])) for g in gmap[k])
            n_tilts = sum(2 * free[g] / sum(int(g in gm) for gm in gmap) for g in set(gmap[k].tolist()))
            dof = (6 + p + (3 if s.mount_rotation else 0) + n_tilts) / 6.0
            Ws[k] = 1.0 / (np.clip(rss, 1e-300, None) / max(d.n - dof, 1.0))
    solve_time = time.perf_counter() - t0
    tilts = x[nb:ne]
    U = np.stack([tilt_gravity(tilts[2 * g:2 * g + 2]) for g in range(T)])
    res, rhos, infl = [], [], []
    for k, d in enumerate(datas):
        b_t = np.einsum("nik,nk->ni", d.a, U[gmap[k][d.group]])
        r_k = d.y - predict(b_t, d.K, x[base[k] + 6:base[k + 1]], mus[k], Es[k], x[base[k]:base[k] + 6])
        rho, inflation = serial_inflation(r_k, d.source, d.index)
        res.append(r_k)
        rhos.append(rho)
        infl.append(inflation)
    info = local_info(x, Es, [Ws[k] / infl[k] for k in range(K)])
    keep = keep_of(free)
    tnames = [[f"tilt.r{c}" for c in "xy"] if kd == "world" else [f"{nm}.tilt.r{c}" for c in "xy"] if kd == "recording"
              else [f"fixed.tilt.r{c}" for c in "xy"] for kd, nm in groups]
    names = ([n for k, ld in zip(legs, loads) for n in [f"{k}.offset.{c}" for c in WRENCH] + [f"{k}.{pn}" for pn in ld.param_names]]
             + [n for t in tnames for n in t] + [f"{k}.mount.r{c}" for k in legs for c in "xyz"])
    xl = np.r_[x[:ne], np.concatenate([rotation_to_rotvec(E) for E in Es])]
    cov, se, null, undetermined, determined, ident = _covariance(info, keep, names, xl, s)
    tilt_on = bool(s.gravity_tilt and world.any())
    if tilt_on and not free[world].all():
        se[nb:nb + 2] = np.inf
    shown = (world & tilt_on) | (rec & free)
    out: dict[str, FreeLoadResult] = {}
    for k, (leg, ld, d) in enumerate(zip(legs, loads, datas)):
        mine = [g for g in np.flatnonzero(shown) if g in gmap[k]]
        sel = np.r_[np.arange(base[k], base[k + 1]), *[np.arange(nb + 2 * g, nb + 2 * g + 2) for g in mine],
                    np.arange(ne + 3 * k, ne + 3 * k + 3)].astype(int)
        rename = {names[i]: (f"{leg}.{names[i]}" if nb <= i < ne else names[i]) for i in sel}
        nm_k = [rename[names[i]] for i in sel]
        cols = np.flatnonzero(np.any(null[sel] != 0, axis=0)) if null.size else np.zeros(0, int)
        und_k = [undetermined[j] for j in cols]
        det_k = [{**c, "coefficients": {rename[n]: v for n, v in c["coefficients"].items()}} for c in determined
                 if all(n in rename for n in c["coefficients"])]
        notes = _leg_notes(d, ld, leg, rhos[k], infl[k])
        if tilt_on and world[gmap[k]].any() and not free[world].all():
            und_k += [f"{leg}.tilt.r{c} (the world tilt of the orientation stream: gravity spans fewer than three directions "
                      "in ft; held at 0)" for c in "xy"]
            notes.append(f"{leg}: the world tilt of the orientation stream is not determined by these orientations: held at 0")
        mine_rec = [groups[g][1] for g in gmap[k] if rec[g]]
        held_k = [groups[g][1] for g in gmap[k] if held_recs[g]]
        if held_k:
            notes.append(f"{leg}: recordings {held_k} give gravity by gravity_body only: a tilt per recording, shared by "
                         f"transducers {legs}, and their mounting rotations are not separable (a common turn of the body "
                         "moves them all); their tilts are taken as exact (held at 0; recording_tilt = \"auto\")")
        est_k = [r for r in mine_rec if r not in held_k]
        if est_k:
            notes.append(f"{leg}: the tilts of recordings {est_k} are shared with transducers "
                         f"{[o for o in legs if o != leg]} and fitted jointly (one tilt per recording: the body's)")
        theta = x[base[k] + 6:base[k + 1]]
        ttl = tilts[:2].copy() if tilt_on and world[gmap[k]].any() else None
        rec_t = {groups[g][1]: tilts[2 * g:2 * g + 2].copy() for g in mine if rec[g]}
        rms = np.sqrt((res[k] ** 2).mean(axis=0))
        for note in notes:
            log.warning("%s", note)
        out[leg] = FreeLoadResult(leg, ld, x[base[k]:base[k] + 6].copy(), theta.copy(), Es[k], tuple(nm_k),
                                  cov[np.ix_(sel, sel)], se[sel], 1.0 / np.sqrt(Ws[k]), rms, d.n, d.selection, tuple(und_k),
                                  tuple(det_k), notes, iters, solve_time, ident.ratio, null[sel][:, cols], d.masks, ttl, rec_t)
    return out


def fit_free_loads(ds: Dataset, settings: FreeLoadSettings | None = None) -> FreeLoadResults:
    """Every free-load transducer of ``ds`` (``Dataset.free_load_legs``): each on its own
    (``estimate.fit_free_load``), except those that share a ``gravity_body``-only recording's tilt, fitted together
    (:func:`fit_joint`)."""
    legs = ds.free_load_legs
    if not legs:
        raise DataFormatError(f"{ds.manifest or 'dataset'}: no transducer carries a free load (every one has a {{leg}}_phi column)")
    s = FreeLoadSettings() if settings is None else settings
    out: dict[str, FreeLoadResult] = {}
    for cl in clusters(ds, list(legs), s):   # transducers sharing a gravity_body recording's tilt: fitted together
        out.update({cl[0]: fit_free_load(ds, cl[0], s)} if len(cl) == 1 else fit_joint(ds, cl, s))
    if sensor_matrix_options(s).on:   # the sensor's own matrix, refitted from each fit (sensor_matrix.py); off: untouched
        out = {k: fit_sensor_matrix(ds, r, s) for k, r in out.items()}
    return FreeLoadResults({k: out[k] for k in legs})
