"""What the diagnosis looks at: residuals of the calibration per recording kind, their
explanatory variables, and noise floors derived from the data (never from simulator settings).

* standing: the static poses (time order kept) with, per pose, the previous
  pose's readings and the steady run it was taken from, found again in the raw
  recording (shafts still between two motions, as in ``standing/poses.py``).
  Noise floor of the pose-level total wrench (report eq. 8 residual), from what
  cannot be the gap (``floor.py``): the readings' part from the within-pose
  scatter (the medians of the two halves of each steady run,
  ``var(median) ~ E[(m_1 - m_2)^2] / 4``: a half has half the samples, so twice
  the variance; this holds for correlated noise too), a per-pose motion-capture
  tilt variance ``s_theta^2 G_p G_p^T`` fitted by REML to the calibrated fit's own
  residuals (never to the held-out residuals it is compared with), the hanging
  offsets' and leg weights' standard errors carried through, and the held-out
  refit's own parameter error (k-fold, eq. 8's K-norm).
* hanging: per leg and sample the residual of the hanging fit (report eqs.
  4-7, ``hanging_residuals``) with shaft angle, speed, time and the fitted
  weight vector. Floor: the high-frequency scatter, ``std(diff(e)) / sqrt(2)``
  within each recording (slow patterns do not enter differences).
* walking: the balance (E) residual of every sample with orientation (stance:
  the total wrench against the weight) and, per leg, the swing residual
  ``w_m - w_o - [m g u; r(phi) x m g u]`` while the foot is in the air (fast
  shaft, angle well outside the stance range), which should be zero. Floors:
  high-frequency scatter as for hanging.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from ..core.balance import residual, to_world
from ..core.calibration import Calibration, periodic_interp
from ..core.data import Dataset, Recording
from ..core.geometry import quat_to_rotation, remove_yaw
from ..models import ModelContext
from ..core.robot import Robot
from ..effects.faces import HangingLeg
from ..core.settings import PoseExtraction
from .floor import (
    MIN_RESIDUAL_DOF_PER_COL,
    calibrated_residual_B,
    fit_noise_floor,
    model_jacobian,
    physical_columns,
    physical_jacobian,
    readings_noise,
    structure_basis,
    tilt_sensitivity,
)
from .standing_fit import StandingData

PREV_WINDOW_S = 0.5        # the previous pose's readings: median over its last half second
# the pose extraction's defaults (settings.py): a shaft faster than this is moving; the Savitzky-Golay window
SHAFT_RATE_RAD_S = PoseExtraction().phi_rate_threshold_rad_s
SAVGOL_WINDOW_S = PoseExtraction().window_s
IN_AIR_MARGIN_RAD = 1.0    # a swing foot counts as in the air this far outside the stance range (compliant feet lift late)


@dataclass(frozen=True)
class StandingView:
    """Standing poses: features for the augmented fits, floors and explanatory variables.

    ``data``: :class:`StandingData`; ``t`` (P,) s; ``R_WB`` (P, 3, 3) yaw removed;
    ``floor`` (6,) N, N*m per component of the pose-level residual (W axes): the expected held-out
    RMS under the noise model of ``floor.py``; ``floor_parts`` the pieces of it (``readings``,
    ``mocap``, ``calibration``, ``fit`` (6,) RMS each; ``mocap_tilt_deg`` and its ``_se_deg``,
    ``_upper_deg``; ``cv_inflation`` (6,); ``within`` the floor; ``noise_gap`` and ``statement``: does
    the residual hold more than the noise model; ``noise_model`` all of it JSON-ready for
    ``diagnosis.json``); ``has_prev`` (P,) whether the previous pose
    was found; ``n_run`` (P,) samples in each pose's steady run (0 if not found).
    """

    data: StandingData
    t: np.ndarray
    R_WB: np.ndarray
    floor: np.ndarray
    floor_parts: dict
    has_prev: np.ndarray
    n_run: np.ndarray
    refloor: Callable[[np.ndarray, int], np.ndarray] | None = None

    @property
    def P(self) -> int:
        return self.data.P


@dataclass(frozen=True)
class LegSeries:
    """Per-leg samples (hanging or walking swing) and the floor of each leg (K, 6)."""

    legs: list[HangingLeg]
    floor: np.ndarray
    kind: str
    n_params: int = 0            # parameters the fitted model spent on these samples (in-sample correction)

    @property
    def n(self) -> int:
        return sum(len(l.t) for l in self.legs)


@dataclass(frozen=True)
class WalkingTotal:
    """Balance (E) residual of walking samples, W axes (N, 6), with time, shaft angles/speeds, floor (6,)."""

    e: np.ndarray
    t: np.ndarray
    phi: np.ndarray
    omega: np.ndarray
    floor: np.ndarray


@dataclass(frozen=True)
class Views:
    standing: StandingView | None
    hanging: LegSeries | None
    swing: LegSeries | None
    walking: WalkingTotal | None
    t_ref: float
    legs: tuple[str, ...]
    notes: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------- helpers


def _odd_window(n_samples: int, n: int) -> int:
    w = max(n_samples, 5)
    w += 1 - w % 2
    return max(3, min(w, n if n % 2 else n - 1))


def shaft_rate(t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``d phi/dt`` (N, K) by a 2nd-order Savitzky-Golay filter (as the pose extraction)."""
    if len(t) < 5:
        return np.gradient(phi, t, axis=0) if len(t) > 1 else np.zeros_like(phi)
    dt = float(np.median(np.diff(t)))
    win = _odd_window(int(round(SAVGOL_WINDOW_S / dt)), len(t))
    return savgol_filter(phi, win, 2, deriv=1, delta=dt, axis=0)


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return d[0::2], d[1::2]


def hf_floor(e: np.ndarray, groups: np.ndarray | None = None) -> np.ndarray:
    """High-frequency noise sd per column of ``e`` (N, c): ``std(diff) / sqrt(2)`` within groups."""
    if groups is None:
        groups = np.zeros(len(e), int)
    parts = [np.diff(e[groups == g], axis=0) for g in np.unique(groups)]
    d = np.concatenate([x for x in parts if len(x)], axis=0)
    return np.sqrt(np.mean(d**2, axis=0) / 2.0)


def fourier_second_derivative(grid: np.ndarray, values: np.ndarray, phi: np.ndarray, harmonics: int = 3) -> np.ndarray:
    """``d^2 r / d phi^2`` at ``phi`` from a least-squares Fourier series (``harmonics``) of the
    periodic curve ``values`` (G, 3) on ``grid`` (G,): differentiating a smooth fit, not the grid."""
    ok = np.all(np.isfinite(values), axis=1)
    n = np.arange(1, harmonics + 1)
    B = np.concatenate([np.ones((ok.sum(), 1)), np.cos(np.outer(grid[ok], n)), np.sin(np.outer(grid[ok], n))], axis=1)
    coef, *_ = np.linalg.lstsq(B, values[ok], rcond=None)
    a, b = coef[1 : 1 + harmonics], coef[1 + harmonics :]
    C, S = np.cos(np.outer(phi, n)), np.sin(np.outer(phi, n))
    return -(C * n**2) @ a - (S * n**2) @ b


def total_residual_B(w: np.ndarray, z: np.ndarray, cal: Calibration, legs) -> np.ndarray:
    """Balance (E) residual (N, 6) in B axes about the body CoM (``balance.residual``); ``w`` (N, K, 6), ``z`` (N, 3)."""
    off, m, R, p = cal.stacked(legs)
    xi = np.concatenate([w.reshape(len(w), -1), np.ones((len(w), 1)), z], axis=1)
    return residual(xi, R, p, off, m, cal.mass_kg * cal.g, "exact")


# ----------------------------------------------------------------------------- standing


def standing_view(dataset: Dataset, poses, calibration: Calibration, prior: Calibration, robot: Robot, t_ref: float,
                  model_dof: int, folds: int, balance: str | None = None, model=None, *, seed: int) -> StandingView:
    """The standing view of ``poses`` (``standing.Poses``; their ``source`` indexes ``dataset.standing``);
    ``balance`` and ``model`` the calibration's (None: from its ``meta`` (else exact) and ``model``);
    ``folds``/``seed`` the diagnosis' cross-validation (the floor is the expected held-out RMS of it)."""
    legs = tuple(robot.legs)
    P = poses.n
    prev = poses.w_m.copy()
    has_prev = np.zeros(P, bool)
    n_run = np.zeros(P, int)
    diffs = []
    src = poses.source if poses.source is not None else np.zeros(P, int)
    recs = dataset.standing
    for s in np.unique(src):
        rec = recs[int(s)]
        idx = np.flatnonzero(src == s)
        pv, hp, nr, dd = _pose_history(rec, legs, poses.t[idx], calibration)
        prev[idx] = np.where(hp[:, None, None], pv, poses.w_m[idx])  # no previous pose: no history term
        has_prev[idx], n_run[idx] = hp, nr
        diffs.append(dd)
    dd = np.concatenate(diffs, axis=0)
    off = calibration.stacked(legs)[0]
    t_h = (poses.t - t_ref) / 3600.0
    n_vert = robot.nominal_rotations()[:, 2, :]
    # The floor (floor.py): readings (within-run scatter) + a motion-capture tilt variance component
    # fitted by REML to the calibrated fit's own residuals + the hanging estimates' se carried
    # through the refit + the refit's own parameter error; nothing of it comes from the held-out
    # residuals it is compared with.
    bal = balance or _calibration_balance(calibration)
    try:
        r_B = calibrated_residual_B(poses.w_m, poses.phi, poses.R_WB, calibration, legs, bal)
    except ValueError:  # report balance with leg CoM curves undefined at some shaft angles: the exact one
        bal = "exact"
        r_B = calibrated_residual_B(poses.w_m, poses.phi, poses.R_WB, calibration, legs, bal)
    r_W = to_world(r_B, poses.R_WB)
    G = tilt_sensitivity(poses.w_m, poses.phi, poses.R_WB, calibration, legs, bal)
    reads = readings_noise(dd, n_run, poses.R_WB)
    force = poses.w_m[..., :3] - off[None, :, :3]
    history = np.einsum("ki,pki->pk", n_vert, poses.w_m[..., :3] - prev[..., :3]) if has_prev.any() else None
    X, names = structure_basis(t_h, poses.phi, force, history, max_cols=max(P // MIN_RESIDUAL_DOF_PER_COL, 1))
    J_phys = physical_jacobian(poses.w_m, poses.R_WB, calibration, legs)
    ctx = ModelContext(legs, robot.nominal_rotations(), robot.nominal_positions(), prior)
    J = model_jacobian(model if model is not None else calibration.model, ctx, J_phys)
    # Hanging offsets and leg weights are estimates: their errors enter every pose's total.
    h_cols = physical_columns(len(legs), rotations=False, translations=False, offsets=True, weights=True)
    C_h = np.concatenate([np.r_[_sq(prior.legs[k].offset_se, 6), _sq(prior.legs[k].leg_weight_se_N, 1)] for k in legs])
    offsets_only = np.flatnonzero(np.tile(np.r_[np.ones(6, bool), False], len(legs)))   # of h_cols: the offsets
    noise = fit_noise_floor(r_W, reads, G, X, J=J, J_h=J_phys[:, :, h_cols], C_h=C_h, model_dof=model_dof, folds=folds,
                            names=names, R_HB=poses.R_WB, J_h_fixed=offsets_only, seed=seed)
    floor = noise.floor

    def refloor(r_in: np.ndarray, extra_dof: int) -> np.ndarray:
        return fit_noise_floor(r_in, reads, G, X, J=J, J_h=J_phys[:, :, h_cols], C_h=C_h, model_dof=model_dof + extra_dof, folds=folds,
                               names=names, R_HB=poses.R_WB, J_h_fixed=offsets_only, seed=seed).floor

    rcom = np.stack([prior.legs[k].com(poses.phi[:, i]) for i, k in enumerate(legs)], axis=1)
    rcom = np.where(np.isfinite(rcom), rcom, 0.0)
    data = StandingData(poses.w_m, poses.R_WB[:, 2, :], poses.R_WB, t_h, prev, poses.phi, rcom, n_vert,
                        t_step=change_point(t_h, r_B))
    parts = {"pose_noise": noise.readings, "readings": noise.readings, "mocap": noise.mocap,
             "mocap_tilt_deg": noise.s_theta_deg, "mocap_tilt_se_deg": float(np.degrees(noise.s_theta_se_rad)),
             "mocap_tilt_upper_deg": float(np.degrees(noise.s_theta_upper_rad)), "mocap_identified": noise.identified,
             "calibration": noise.calibration, "fit": noise.fit, "cv_inflation": noise.cv_inflation, "poses_with_run": reads.n_used,
             "within": floor.copy(), "noise_gap": noise.gap, "statement": noise.statement, "noise_model": noise.parts()}
    return StandingView(data, poses.t.copy(), poses.R_WB.copy(), floor, parts, has_prev, n_run, refloor)


def _sq(se, n: int) -> np.ndarray:
    """Variances (n,) from standard errors (None or NaN: 0, not estimated)."""
    return np.zeros(n) if se is None else np.nan_to_num(np.broadcast_to(np.square(np.asarray(se, float)), (n,)).copy())


def _calibration_balance(cal: Calibration) -> str:
    meta = cal.meta or {}
    return meta.get("balance") or (meta.get("standing") or {}).get("balance") or "exact"


def _pose_history(rec: Recording, legs, t_pose: np.ndarray, cal: Calibration):
    """Previous-pose readings (P, K, 6), found flags, steady-run lengths and half-run median differences (P, 6)."""
    t = rec.t
    W = rec.wrench_array(legs)
    phi = rec.phi_array(legs)
    moving = np.any(np.abs(shaft_rate(t, phi)) > SHAFT_RATE_RAD_S, axis=1)
    dt = float(np.median(np.diff(t)))
    n_prev = max(int(round(PREV_WINDOW_S / dt)), 1)
    starts, ends = _runs(moving)  # moving runs [start, end)
    P = len(t_pose)
    prev = np.full((P, len(legs), 6), np.nan)
    has = np.zeros(P, bool)
    n_run = np.zeros(P, int)
    dd = np.full((P, 6), np.nan)
    R_all = quat_to_rotation(rec.quat) if rec.quat is not None else None
    for j, tp in enumerate(t_pose):
        i = int(np.clip(np.searchsorted(t, tp), 0, len(t) - 1))
        r = int(np.searchsorted(ends, i, side="right")) - 1     # last moving run ending at or before i
        left = ends[r] if r >= 0 else 0                          # first still sample of this pose
        nxt = int(np.searchsorted(starts, i, side="right"))
        right = starts[nxt] if nxt < len(starts) else len(t)     # first moving sample after the pose
        h = min(right - i, i - left)
        n_run[j] = 2 * h
        if r >= 0:
            seg_start = ends[r - 1] if r >= 1 else 0
            a = max(starts[r] - n_prev, seg_start)
            if starts[r] > a:
                prev[j] = np.median(W[a : starts[r]], axis=0)
                has[j] = True
        if h >= 4 and R_all is not None:
            sl = slice(i - h, i + h)
            Rw = R_all[sl]
            good = np.all(np.isfinite(Rw.reshape(len(Rw), -1)), axis=1)
            if good.sum() >= 4:
                r_s = total_residual_B(W[sl][good], Rw[good][:, 2, :], cal, legs)
                half = len(r_s) // 2
                dd[j] = np.median(r_s[:half], axis=0) - np.median(r_s[half:], axis=0)
    return prev, has, n_run, dd


# ----------------------------------------------------------------------------- hanging


MIN_SEGMENT_POSES = 5    # a change point leaves at least this many poses on either side


def change_point(t_h: np.ndarray, r: np.ndarray, min_segment: int = MIN_SEGMENT_POSES) -> float | None:
    """The time (hours, midway between two poses) of the likeliest single step in the residual ``r`` (P, m).

    Per component, ``r ~ a + b t + c [t > s]`` by least squares; the split ``s`` with the smallest
    residual sum, each component standardised by its own scatter (a drift of any direction counts),
    wins. A feature of the data like the time basis (what ``PoseSym.step`` indicates): whether a
    face with a step explains the poses better is for cross-validation to say. None: too few poses.
    """
    t = np.asarray(t_h, float)
    order = np.argsort(t, kind="stable")
    t, y = t[order], np.asarray(r, float)[order]
    P = len(t)
    if P < 2 * min_segment + 1:
        return None
    y = (y - y.mean(0)) / np.where(y.std(0) > 0, y.std(0), 1.0)
    tc = (t - t.mean()) / max(float(np.ptp(t)), 1e-12)
    best = (np.inf, None)
    for i in range(min_segment, P - min_segment + 1):
        if t[i] <= t[i - 1]:
            continue
        X = np.column_stack([np.ones(P), tc, (np.arange(P) >= i).astype(float)])
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        rss = float(((y - X @ coef) ** 2).sum())
        if rss < best[0]:
            best = (rss, 0.5 * (t[i - 1] + t[i]))
    return best[1]


def hanging_series(recordings, hanging, robot: Robot, t_ref: float) -> LegSeries:
    """Per-leg residuals of the hanging fit (report eqs. 4-7) with their explanatory variables."""
    from ..estimate.hanging import hanging_residuals

    legs = tuple(robot.legs)
    recs = list(recordings)
    res = hanging_residuals(hanging, recs, robot)
    out, floors = [], []
    g = robot.g
    n_par = 0
    for k, leg in enumerate(legs):
        l = hanging.legs[leg]
        R_nom = robot.transducers[leg].given_rotation()
        t = np.concatenate([r.t for r in recs])
        phi = np.concatenate([r.phi[leg] for r in recs])
        omega = np.concatenate([shaft_rate(r.t, r.phi[leg][:, None])[:, 0] for r in recs])
        rec_idx = np.concatenate([np.full(r.n, j) for j, r in enumerate(recs)])
        f = np.concatenate([
            np.broadcast_to(l.leg_weight_N * (l.misalignment[r.name] @ (R_nom.T @ (r.gravity_body / np.linalg.norm(r.gravity_body)))), (r.n, 3))
            for r in recs
        ])
        grid, xyz = l.com_phi, (l.com_xyz_fit if l.com_xyz_fit is not None else l.com_xyz)
        rr = periodic_interp(phi, grid, np.where(np.isfinite(xyz), xyz, 0.0))
        r_dd = fourier_second_derivative(grid, xyz, phi)
        e = res[leg]
        floors.append(hf_floor(e, rec_idx))
        out.append(HangingLeg(leg, k, e, t, phi, omega, rec_idx, f, rr, r_dd, float(l.leg_weight_N), g, t_ref, R_nom.T @ np.array([0, 0, 1.0])))
        n_par = 2 * len(recs) + 7 + 3 * len(grid)
    return LegSeries(out, np.array(floors), "hanging", n_par)


# ----------------------------------------------------------------------------- walking


def walking_views(recordings, cal: Calibration, robot: Robot, t_ref: float) -> tuple[LegSeries | None, WalkingTotal | None]:
    """Swing residuals per leg (feet in the air) and the balance residual of every sample with orientation."""
    legs = tuple(robot.legs)
    K = len(legs)
    off, m, R, p = cal.stacked(legs)
    swing: list[list] = [[] for _ in range(K)]
    tot_e, tot_t, tot_phi, tot_om, tot_grp = [], [], [], [], []
    for j, rec in enumerate(recordings):
        if rec.quat is None:
            continue
        ok = np.all(np.isfinite(rec.quat), axis=1)
        if ok.sum() < 10:
            continue
        r = rec.select(ok)
        R_WB = quat_to_rotation(r.quat)
        W = r.wrench_array(legs)
        phi = r.phi_array(legs)
        om = shaft_rate(r.t, phi)
        e_B = total_residual_B(W, R_WB[:, 2, :], cal, legs)
        tot_e.append(to_world(e_B, remove_yaw(R_WB)))
        tot_t.append(r.t)
        tot_phi.append(phi)
        tot_om.append(om)
        tot_grp.append(np.full(len(r.t), j))
        u_B = -R_WB[:, 2, :]
        for k, leg in enumerate(legs):
            speed = np.abs(om[:, k])
            slow = speed <= 2.0 * np.median(speed)
            ang = np.angle(np.exp(1j * phi[:, k]))
            if slow.sum() < 5 or (~slow).sum() < 5:
                continue
            centre = np.angle(np.mean(np.exp(1j * ang[slow])))
            half = np.max(np.abs(np.angle(np.exp(1j * (ang[slow] - centre)))))
            air = ~slow & (np.abs(np.angle(np.exp(1j * (ang - centre)))) > half + IN_AIR_MARGIN_RAD)
            if air.sum() < 5:
                continue
            lc = cal.legs[leg]
            u = (R[k].T @ u_B[air].T).T
            f = m[k] * u
            rr = lc.com(phi[air, k])
            rr = np.where(np.isfinite(rr), rr, 0.0)
            e = W[air, k] - off[k] - np.hstack([f, np.cross(rr, f)])
            r_dd = fourier_second_derivative(lc.com_phi, lc.com_xyz, phi[air, k])
            swing[k].append((e, r.t[air], phi[air, k], om[air, k], np.full(air.sum(), j), f, rr, r_dd))
    sw = None
    legs_out, floors = [], []
    for k, leg in enumerate(legs):
        if not swing[k]:
            continue
        cat = [np.concatenate([s[i] for s in swing[k]]) for i in range(8)]
        e, t, ph, om, grp, f, rr, r_dd = cat
        floors.append(hf_floor(e, grp))
        legs_out.append(HangingLeg(leg, k, e, t, ph, om, grp, f, rr, r_dd, float(m[k]), robot.g, t_ref, robot.nominal_rotations()[k, 2, :], R[k]))
    if legs_out:
        fl = np.full((K, 6), np.nan)
        for l, f_ in zip(legs_out, floors):
            fl[l.k] = f_
        sw = LegSeries(legs_out, fl, "walking swing", 0)
    wt = None
    if tot_e:
        e = np.concatenate(tot_e)
        grp = np.concatenate(tot_grp)
        wt = WalkingTotal(e, np.concatenate(tot_t), np.concatenate(tot_phi), np.concatenate(tot_om), hf_floor(e, grp))
    return sw, wt
