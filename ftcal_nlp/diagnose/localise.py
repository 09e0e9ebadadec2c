"""Localisation: where the held-out residual lies and what it follows.

Per recording kind the residual (standing: held-out from the cross-validation
folds of the selected model; hanging: of the hanging fit; walking: swing legs
against zero, stance totals against the weight) is broken down by leg and
wrench component, and regressed, family by family, on what it might follow:

    time          t_h, t_h^2 (hours since the hanging recordings)
    shaft_angle   cos phi_k, sin phi_k (hanging and swing: also 2 phi)
    load          the transducer's load along its design-vertical axis, and its square
                  (hanging: which way gravity loads it, one indicator per recording)
    body_tilt     the up direction in B (z_x, z_y)
    shaft_speed   phi_dot^2, phi_dot^2 cos phi, phi_dot^2 sin phi (moving legs only)
    pose_history  the change of each transducer's load since the previous pose

Each family's share is a cross-validated R^2 against the intercept alone
(``1 - SS_family / SS_intercept``, held-out, in units of the floor); the
constant's share is ``1 - SS_intercept / SS_zero``. The strongest family is
what the gap "explains" when its share is material (``EXPLAINS_MIN``).

The standing noise floor gets a data-derived nugget: the held-out residual
left after regressing on all families together (what no measured variable can
predict, e.g. a motion-capture error that is constant within each pose, which
the within-pose scatter cannot see). The floor is the larger of the two.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.data import WRENCH_COMPONENTS
from .views import LegSeries, StandingView

EXPLAINS_MIN = 0.3
LEG_SHARE_MIN = 0.25
RIDGE = 1e-6
FAMILIES = ("time", "shaft_angle", "load", "body_tilt", "shaft_speed", "pose_history")


@dataclass(frozen=True)
class KindLocal:
    """One kind: RMS per component (6,), floor (6,), per-leg excess (K,) (NaN where not
    separable), family shares, constant share, the top family and the plotting data."""

    kind: str
    rms: np.ndarray
    floor: np.ndarray
    leg_excess: np.ndarray
    shares: dict
    constant_share: float
    top: str | None
    plot: dict = field(default_factory=dict)

    @property
    def excess_by_component(self) -> np.ndarray:
        return (self.rms / np.where(self.floor > 0, self.floor, 1.0)) ** 2 - 1.0


def _cv_ss(Y: np.ndarray, F: np.ndarray | None, folds: list[np.ndarray], intercept: bool = True) -> np.ndarray:
    """Held-out sum of squares per column of Y (n, c) of a ridge regression on [1, F]."""
    n = len(Y)
    cols = [np.ones((n, 1))] if intercept else []
    if F is not None and F.shape[1]:
        s = F.std(axis=0)
        cols.append((F - F.mean(axis=0)) / np.where(s > 0, s, 1.0))
    if not cols:
        return (Y**2).sum(axis=0)
    X = np.concatenate(cols, axis=1)
    ss = np.zeros(Y.shape[1])
    for test in folds:
        train = np.ones(n, bool)  # a mask: setdiff1d sorts on every call and dominated this loop
        train[test] = False
        A = X[train].T @ X[train] + RIDGE * len(train) * np.eye(X.shape[1])
        beta = np.linalg.solve(A, X[train].T @ Y[train])
        ss += ((Y[test] - X[test] @ beta) ** 2).sum(axis=0)
    return ss


def _shares(Y: np.ndarray, families: dict, folds) -> tuple[dict, float, np.ndarray]:
    ss0 = _cv_ss(Y, None, folds, intercept=False).sum()
    ss_int = _cv_ss(Y, None, folds).sum()
    shares = {name: float(1.0 - _cv_ss(Y, F, folds).sum() / ss_int) if ss_int > 0 else 0.0 for name, F in families.items()}
    allF = np.concatenate([F for F in families.values()], axis=1) if families else None
    ss_all = _cv_ss(Y, allF, folds)
    return shares, float(1.0 - ss_int / ss0) if ss0 > 0 else 0.0, ss_all


def _top(shares: dict) -> str | None:
    if not shares:
        return None
    name = max(shares, key=lambda k: shares[k])
    return name if shares[name] >= EXPLAINS_MIN else None


# ----------------------------------------------------------------------------- standing


def standing_families(view: StandingView, offsets: np.ndarray) -> dict:
    """Explanatory families (P, q) of the standing poses (module docstring); ``offsets`` (K, 6)."""
    d = view.data
    load = np.einsum("ki,pki->pk", d.n_vert, d.w[..., :3] - offsets[None, :, :3]) / 20.0
    dprev = np.einsum("ki,pki->pk", d.n_vert, d.w[..., :3] - d.prev[..., :3]) / 20.0
    fam = {
        "time": np.stack([d.t_h, d.t_h**2], axis=1),
        "shaft_angle": np.concatenate([np.cos(d.phi), np.sin(d.phi)], axis=1),
        "load": np.concatenate([load, load**2], axis=1),
        "body_tilt": d.z[:, :2].copy(),
    }
    if view.has_prev.any() and np.ptp(dprev) > 0:
        fam["pose_history"] = dprev
    return {k: v for k, v in fam.items() if np.ptp(v, axis=0).max() > 0}


def standing_nugget(view: StandingView, heldout_W: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per-component sd (6,) of the held-out residual that no family predicts (module docstring):
    least squares on the intercept and every family, ``sqrt(RSS / (P - q))`` (unbiased for a
    white remainder)."""
    fam = standing_families(view, offsets)
    P = len(heldout_W)
    d = view.data
    # Interactions with the tilt: on strongly tilted poses (a board) an effect's residual is not
    # linear in the families, and what is left of it must not pass for noise.
    tilt = d.z[:, :2]
    inter = [(np.concatenate([np.cos(d.phi), np.sin(d.phi), fam["load"][:, : d.K]], axis=1)[:, :, None] * tilt[:, None, :]).reshape(P, -1)] \
        if "load" in fam and np.ptp(tilt) > 0 else []
    X = np.concatenate([np.ones((P, 1))] + list(fam.values()) + inter, axis=1)
    if X.shape[1] > P // 2:  # too few poses for the interactions: families alone
        X = np.concatenate([np.ones((P, 1))] + list(fam.values()), axis=1)
    q = np.linalg.matrix_rank(X)
    beta, *_ = np.linalg.lstsq(X, heldout_W, rcond=None)
    rss = ((heldout_W - X @ beta) ** 2).sum(axis=0)
    return np.sqrt(rss / max(P - q, 1))


def localise_standing(view: StandingView, heldout_W: np.ndarray, offsets: np.ndarray, folds, legs) -> KindLocal:
    fl = np.where(view.floor > 0, view.floor, 1.0)
    Y = heldout_W / fl
    fam = standing_families(view, offsets)
    shares, const, _ = _shares(Y, fam, folds)
    # Per leg: the share of that leg's own variables (angle, load, history).
    K = view.data.K
    leg_share = np.zeros(K)
    d = view.data
    load = np.einsum("ki,pki->pk", d.n_vert, d.w[..., :3] - offsets[None, :, :3]) / 20.0
    ss_int = _cv_ss(Y, None, folds).sum()
    for k in range(K):
        F = np.stack([np.cos(d.phi[:, k]), np.sin(d.phi[:, k]), load[:, k], load[:, k] ** 2], axis=1)
        leg_share[k] = 1.0 - _cv_ss(Y, F, folds).sum() / ss_int if ss_int > 0 else 0.0
    top = _top(shares)
    comp = int(np.argmax((heldout_W**2).mean(axis=0) / fl**2))
    plot = {"y": heldout_W[:, comp], "component": WRENCH_COMPONENTS[comp], "floor": view.floor[comp]}
    x = _standing_axis(view, offsets, top, Y[:, comp])
    plot.update(x)
    return KindLocal("standing", np.sqrt((heldout_W**2).mean(axis=0)), view.floor, leg_share, shares, const, top, plot)


def _standing_axis(view: StandingView, offsets, family: str | None, y: np.ndarray) -> dict:
    d = view.data
    if family == "time" or family is None:
        return {"x": d.t_h * 60.0, "xlabel": "time since the hanging recordings [min]"}
    if family == "body_tilt":
        return {"x": np.degrees(np.arccos(np.clip(d.z[:, 2], -1, 1))), "xlabel": "body tilt [deg]"}
    per_leg = {
        "shaft_angle": (np.degrees(np.angle(np.exp(1j * d.phi))), "shaft angle of leg {} [deg]"),
        "load": (np.einsum("ki,pki->pk", d.n_vert, d.w[..., :3] - offsets[None, :, :3]), "vertical load on transducer {} [N]"),
        "pose_history": (np.einsum("ki,pki->pk", d.n_vert, d.prev[..., :3] - d.w[..., :3]), "load change since the previous pose, leg {} [N]"),
    }
    X, label = per_leg[family]
    c = [abs(np.corrcoef(X[:, k], y)[0, 1]) if np.ptp(X[:, k]) > 0 else 0.0 for k in range(X.shape[1])]
    k = int(np.nanargmax(c))
    return {"x": X[:, k], "xlabel": label.format(k), "leg_index": k}


# ----------------------------------------------------------------------------- hanging and walking swing


def series_families(l) -> dict:
    t = (l.t - l.t_ref) / 3600.0
    fam = {
        "time": t[:, None],
        "shaft_angle": np.stack([np.cos(l.phi), np.sin(l.phi), np.cos(2 * l.phi), np.sin(2 * l.phi)], axis=1),
        "shaft_speed": (l.omega**2)[:, None] * np.stack([np.ones_like(l.phi), np.cos(l.phi), np.sin(l.phi)], axis=1),
    }
    recs = np.unique(l.rec)
    if len(recs) > 1:
        fam["load"] = (l.rec[:, None] == recs[None, 1:]).astype(float)
    return {k: v for k, v in fam.items() if np.ptp(v, axis=0).max() > 1e-12}


def localise_series(series: LegSeries, n_legs: int, folds: int) -> KindLocal:
    from .linear_fit import time_folds

    fidx = time_folds(series, folds)
    ss_fam: dict = {}
    ss_int_tot = ss0_tot = 0.0
    leg_excess = np.full(n_legs, np.nan)
    mse = np.zeros(6)
    n = 0
    best_leg, best_ex = None, -np.inf
    for l, fi in zip(series.legs, fidx):
        fl = np.where(series.floor[l.k] > 0, series.floor[l.k], 1.0)
        Y = l.e / fl
        fold_list = [np.flatnonzero(fi == f) for f in range(folds) if np.any(fi == f)]
        fam = series_families(l)
        ss0_tot += _cv_ss(Y, None, fold_list, intercept=False).sum()
        ss_int_tot += _cv_ss(Y, None, fold_list).sum()
        for name, F in fam.items():
            ss_fam[name] = ss_fam.get(name, 0.0) + _cv_ss(Y, F, fold_list).sum()
        leg_excess[l.k] = float((Y**2).mean() - 1.0)
        mse += (l.e**2).sum(axis=0)
        n += len(l.t)
        if leg_excess[l.k] > best_ex:
            best_leg, best_ex = l, leg_excess[l.k]
    shares = {k: float(1.0 - v / ss_int_tot) for k, v in ss_fam.items()} if ss_int_tot > 0 else {}
    const = float(1.0 - ss_int_tot / ss0_tot) if ss0_tot > 0 else 0.0
    floor = np.sqrt(np.nanmean(series.floor[[l.k for l in series.legs]] ** 2, axis=0))
    rms = np.sqrt(mse / max(n, 1))
    top = _top(shares)
    plot = {}
    if best_leg is not None:
        fl = np.where(series.floor[best_leg.k] > 0, series.floor[best_leg.k], 1.0)
        comp = int(np.argmax((best_leg.e**2).mean(axis=0) / fl**2))
        if top == "time":
            x, xl = (best_leg.t - best_leg.t_ref) / 60.0, "time since the hanging reference [min]"
        elif top == "shaft_speed":
            x, xl = best_leg.omega, f"shaft speed of leg {best_leg.leg} [rad/s]"
        else:
            x, xl = np.degrees(np.mod(best_leg.phi, 2 * np.pi)), f"shaft angle of leg {best_leg.leg} [deg]"
        plot = {"x": x, "y": best_leg.e[:, comp], "xlabel": xl, "component": WRENCH_COMPONENTS[comp], "leg": best_leg.leg,
                "floor": float(series.floor[best_leg.k][comp])}
    return KindLocal(series.kind, rms, floor, leg_excess, shares, const, top, plot)


# ----------------------------------------------------------------------------- plain language


def legs_with_gap(loc: KindLocal, legs: tuple[str, ...], threshold: float) -> list[str]:
    """Legs that carry the gap; empty when it is common to all (or not separable by leg)."""
    ex = loc.leg_excess
    if not np.isfinite(ex).any():
        return []
    top = np.nanmax(ex)
    if top <= threshold:
        return []
    sel = [legs[k] for k in range(len(ex)) if np.isfinite(ex[k]) and ex[k] >= max(threshold, LEG_SHARE_MIN * top)]
    return [] if len(sel) == np.isfinite(ex).sum() else sel


def standing_legs(loc: KindLocal, legs: tuple[str, ...]) -> list[str]:
    sh = loc.leg_excess
    if not np.isfinite(sh).any() or np.nanmax(sh) < EXPLAINS_MIN:
        return []
    sel = [legs[k] for k in range(len(sh)) if sh[k] >= 0.5 * np.nanmax(sh)]
    return [] if len(sel) == len(legs) else sel


def components_with_gap(loc: KindLocal, ratio_min: float = np.sqrt(2.0)) -> list[str]:
    """Components whose held-out RMS exceeds ``ratio_min`` times the floor and a quarter of the
    largest such ratio."""
    ratio = loc.rms / np.where(loc.floor > 0, loc.floor, 1.0)
    top = ratio.max()
    if top <= ratio_min:
        return []
    return [WRENCH_COMPONENTS[c] for c in range(6) if ratio[c] > max(ratio_min, 0.25 * top)]


def strongest_dependence(locs: dict) -> str | None:
    """The family that explains the largest part of the whole residual over the kinds with a gap:
    ``share x (1 - constant share)`` (a family's share is of what varies), if it is material."""
    best, val = None, EXPLAINS_MIN
    for L in locs.values():
        for name, sh in L.shares.items():
            v = sh * (1.0 - max(L.constant_share, 0.0))
            if v > val:
                best, val = name, v
    return best


def describe(loc: KindLocal) -> str:
    """One plain-language sentence about a kind's residual."""
    unit = lambda c: "N" if c < 3 else "N*m"
    ratio = loc.rms / np.where(loc.floor > 0, loc.floor, 1.0)
    worst = np.argsort(-ratio)[:3]
    parts = ", ".join(f"{WRENCH_COMPONENTS[c]} {loc.rms[c]:.3g} {unit(c)} (floor {loc.floor[c]:.2g}, x{ratio[c]:.1f})" for c in worst)
    s = f"{loc.kind}: held-out RMS {parts}"
    if loc.constant_share > 0.1:
        s += f"; {100 * loc.constant_share:.0f}% of it is a constant bias"
    ranked = sorted(((v, k) for k, v in loc.shares.items() if v > 0.05), reverse=True)
    if ranked:
        s += "; of what varies, " + ", ".join(f"{k.replace('_', ' ')} explains {100 * v:.0f}%" for v, k in ranked[:3])
    else:
        s += "; nothing measured explains what varies"
    return s + "."
