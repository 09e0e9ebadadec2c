"""Transducer offsets tracked through a walk from its swing phases (report Sec. V: offsets drift).

A foot in the air carries no ground wrench, so its reading is its own leg's
weight wrench plus the offset plus noise (report eqs. 1 and 3):

    y_k(t) = w_m,k(t) - [m_k g u_k; r_k(phi) x m_k g u_k] = w_o,k(t) + n,      t in swing of foot k

which sees all six offsets of leg k (standing poses see only the 6 combinations
of the 36 that the balance sums). Swing intervals are shortened by
``SWING_MARGIN_S`` at both ends: next to touch-down and lift-off a foot may
already carry a load below the contact threshold. Each leg's offset is a smooth function of
time, a cubic B-spline with knots every ``knot_s`` seconds over the recording,
``w_o,k(t) = b(t)^T beta_k`` (beta_k (n_b, 6)), fitted to the swing samples by
penalised least squares (a P-spline: second differences of the coefficients,
weight ``penalty`` times the mean diagonal of ``B^T B``, which bridges long
stances):

    A = B^T B + lam D^T D,   beta = A^-1 B^T Y,   Cov(vec beta) = Sigma_k (x) A^-1 B^T B A^-1,

``Sigma_k`` (6, 6) the residual covariance of the swing fit (``n - edf`` dof, so
leg vibration in swing counts as the noise it is). The offset's covariance at
time t is ``(b^T A^-1 B^T B A^-1 b) Sigma_k + G_k C G_k^T``: the second term is
the calibration's error of the leg weight wrench that ``y`` subtracts (``m_k g``,
``r_k``, ``R_k``; ``C`` their joint covariance), which the fit takes for offset,
with ``G_k`` the mean over the leg's swing samples of

    d g / d (m g) = [u; r x u],   d g / d r = [0; -m g [u]],   d g / d rho = [m g; m g [r]] R_k^T [u_B]

(``r`` interpolating two CoM grid points, as in ``uncertainty.py``).

Change since calibration, per leg: the time-mean tracked offset less the
calibrated one, ``d`` (6,), with ``Cov(d) = Cov(mean) + J C J^T`` (``J = G_k`` with
the offsets' own columns beside it: ``d`` errs by ``-(G_k d_theta + d_w_o)``, and the
hanging fit correlates the two; without the calibration's covariance the offsets'
se alone); ``chi2 = d^T Cov(d)^-1 d`` on 6 dof; significant when
its p-value is below ``SIGNIFICANCE`` (0.001). The drift within the recording
(last sample less first) is reported beside it.

What the swing phases support (issue 24): a recording whose shafts are all still in more than
``MAX_STILL_SHARE`` of its samples is a standing session and is refused (its feet lift only between poses);
a swing phase counts only when its shaft turns ``MIN_SWING_TRAVEL_RAD`` or more (a foot carried forward, not
held up); ``t`` must be in seconds (``checks.MAX_SAMPLE_INTERVAL_S``); no leg with a usable swing is an error.
What differs from one swing phase to the next is not noise that averages out: ``Sigma_k``'s component c is
scaled by ``max(1, sum_phases S_pc^2 / sum_samples e_c^2)`` (``S_pc`` the residual sum of phase p; 1 in
expectation for independent residuals). Size on drift-free simulated walks: ``python -m
ftcal_nlp.bench.tracking_size`` (README).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.interpolate import BSpline
from scipy.ndimage import binary_erosion
from scipy.stats import chi2

from ..core.calibration import Calibration, interp_cells
from ..core.checks import MAX_SAMPLE_INTERVAL_S
from ..core.data import WRENCH_COMPONENTS, DataFormatError
from ..core.geometry import skew
from ..core.physics import gravity_dir_in_ft, leg_gravity_wrench
from ..core.settings import CorrectSettings

__all__ = ["TrackedOffsets", "swing_offset_readings", "track_offsets", "SIGNIFICANCE"]

log = logging.getLogger(__name__)

SIGNIFICANCE = 1e-3
DEGREE = 3
MIN_SWING = 20          # swing samples a leg needs before its offsets are tracked
MIN_PHASES = 1          # swing phases a leg needs (with two or more, their scatter enters the change's uncertainty)
MAX_STILL_SHARE = 0.5   # a recording whose shafts are all still in more of its samples is a standing session
MIN_SWING_TRAVEL_RAD = 1.0  # a swing phase turns the shaft this far (the sample's walk: 4.7-5 rad; its standing poses: < 0.6)
SWING_MARGIN_S = 0.3    # swing samples this close to a stance sample are left out of the fit


@dataclass(frozen=True)
class TrackedOffsets:
    """Each leg's offsets as a cubic B-spline in time (module docstring).

    ``legs`` (K,); ``knots`` the spline's full knot vector (s); ``coef`` (K, n_b, 6); ``unit_cov``
    (K, n_b, n_b) ``A^-1 B^T B A^-1``; ``sigma`` (K, 6, 6) residual covariance of the swing fit;
    ``tracked`` (K,) False where a leg had too few swing samples (it keeps the calibration's offsets);
    ``n_swing`` (K,); ``calibrated`` (K, 6) and ``calibrated_se`` (K, 6) the calibration's offsets;
    ``calibration_cov`` (K, 6, 6) the leg weight wrench's calibration error taken for offset.
    """

    legs: tuple[str, ...]
    knots: np.ndarray
    coef: np.ndarray
    unit_cov: np.ndarray
    sigma: np.ndarray
    tracked: np.ndarray
    n_swing: np.ndarray
    calibrated: np.ndarray
    calibrated_se: np.ndarray
    t_range: tuple[float, float]
    calibration_cov: np.ndarray | None = None
    change_cov: np.ndarray | None = None

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Offsets (N, K, 6) in ft_k at times ``t`` and their covariances (N, K, 6, 6)."""
        t = np.clip(np.asarray(t, float), *self.t_range)
        B = BSpline.design_matrix(t, self.knots, DEGREE).toarray()
        off = np.einsum("nb,kbc->nkc", B, self.coef)
        scale = np.einsum("nb,kbd,nd->nk", B, self.unit_cov, B)
        cov = scale[..., None, None] * self.sigma[None]
        if self.calibration_cov is not None:
            cov = cov + self.calibration_cov[None]
        keep = ~self.tracked
        off[:, keep] = self.calibrated[keep]
        cov[:, keep] = 0.0  # the calibration's own offset covariance stays with the calibration
        return off, cov

    def change_table(self) -> pd.DataFrame:
        """Per leg: the change since calibration (time mean), its se, chi^2 and p-value, significance,
        and the drift within the recording (last less first), components in N and N*m."""
        t0, t1 = self.t_range
        tt = np.linspace(t0, t1, 201)
        B = BSpline.design_matrix(tt, self.knots, DEGREE).toarray()
        bm = B.mean(axis=0)
        bd = B[-1] - B[0]
        rows = []
        for i, k in enumerate(self.legs):
            if not self.tracked[i]:
                rows.append({"leg": k, "tracked": False, "n_swing": int(self.n_swing[i])})
                continue
            d = bm @ self.coef[i] - self.calibrated[i]
            C = float(bm @ self.unit_cov[i] @ bm) * self.sigma[i]
            if self.change_cov is not None:  # the calibration's offsets and leg weight wrench, correlated as fitted
                C = C + self.change_cov[i]
            else:
                C = C + np.diag(np.nan_to_num(self.calibrated_se[i]) ** 2)
                if self.calibration_cov is not None:
                    C = C + self.calibration_cov[i]
            x2 = float(d @ np.linalg.solve(C, d))
            p = float(chi2.sf(x2, 6))
            drift = bd @ self.coef[i]
            dse = np.sqrt(float(bd @ self.unit_cov[i] @ bd) * np.diag(self.sigma[i]))
            row = {"leg": k, "tracked": True, "n_swing": int(self.n_swing[i]), "chi2": x2, "p": p, "significant": p < SIGNIFICANCE}
            row.update({f"change_{c}": v for c, v in zip(WRENCH_COMPONENTS, d)})
            row.update({f"change_{c}_se": v for c, v in zip(WRENCH_COMPONENTS, np.sqrt(np.diag(C)))})
            row.update({f"drift_{c}": v for c, v in zip(WRENCH_COMPONENTS, drift)})
            row.update({f"drift_{c}_se": v for c, v in zip(WRENCH_COMPONENTS, dse)})
            rows.append(row)
        return pd.DataFrame(rows).set_index("leg")


def swing_offset_readings(w_m: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, cal: Calibration) -> np.ndarray:
    """``y`` (N, K, 6) in ft_k: readings less each leg's weight wrench (module docstring); the offset where
    the foot is in the air."""
    _, weights, rotations, _ = cal.stacked()
    u = gravity_dir_in_ft(R_WB[:, None], rotations[None])
    r = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(cal.leg_names)], axis=1)
    return w_m - leg_gravity_wrench(u, r, weights)


def _knots(t0: float, t1: float, knot_s: float) -> np.ndarray:
    n_int = max(1, int(np.ceil((t1 - t0) / knot_s - 1e-9)))
    inner = np.linspace(t0, t1, n_int + 1)
    return np.r_[[t0] * DEGREE, inner, [t1] * DEGREE]


def _leg_weight_jacobian_mean(phi: np.ndarray, R_WB: np.ndarray, cal: Calibration, leg: str, cov) -> np.ndarray:
    """``G_k`` (6, P): the mean over the given samples of the leg weight wrench's derivative with respect to
    the calibration's parameters (labels ``cov.names``; module docstring)."""
    l = cal.legs[leg]
    mg, Rk = l.leg_weight_N, l.rotation_to_body
    u_B = -R_WB[:, 2, :]
    u = u_B @ Rk                                                     # R_k^T u_B
    r = l.com(phi)
    G = np.zeros((6, len(cov.names)))
    pos = {n: i for i, n in enumerate(cov.names)}

    def put(name: str, col: np.ndarray) -> None:
        if name in pos:
            G[:, pos[name]] += col

    put(f"{leg}.mg", np.concatenate([u, np.cross(r, u)], axis=1).mean(axis=0))
    du = np.einsum("ji,njl->nil", Rk, skew(u_B))                    # (n, 3, 3)
    drho = np.concatenate([mg * du, mg * skew(r) @ du], axis=1).mean(axis=0)   # (6, 3)
    for j, c in enumerate("xyz"):
        put(f"{leg}.R_tilde.{c}", drho[:, j])
    dr = np.zeros((len(phi), 6, 3))
    dr[:, 3:] = -mg * skew(u)
    G_grid = np.zeros((len(l.com_phi), 6, 3))
    i0, i1, a = interp_cells(phi, l.com_phi)
    np.add.at(G_grid, i0, (1 - a)[:, None, None] * dr / len(phi))
    np.add.at(G_grid, i1, a[:, None, None] * dr / len(phi))
    for i in range(len(l.com_phi)):
        for j, c in enumerate("xyz"):
            put(f"{leg}.com[{i}].{c}", G_grid[i, :, j])
    return G


def track_offsets(t: np.ndarray, y: np.ndarray, swing: np.ndarray, cal: Calibration,
                  settings: CorrectSettings = CorrectSettings(), *, phi: np.ndarray | None = None,
                  R_WB: np.ndarray | None = None, cov=None) -> TrackedOffsets:
    """Fit each leg's offsets over time to its swing samples (module docstring).

    ``t`` (N,) s, increasing; ``y`` (N, K, 6) from :func:`swing_offset_readings`; ``swing`` (N, K) bool;
    with ``phi`` (N, K), ``R_WB`` (N, 3, 3) and the calibration's ``cov`` (``uncertainty.CalibrationCovariance``)
    the leg weight wrench's calibration error is added to the offsets' covariance.
    """
    legs = cal.leg_names
    K = len(legs)
    t = np.asarray(t, float)
    if len(t) < 2 or not np.all(np.diff(t) > 0):
        raise ValueError("track_offsets: sample times must be increasing, with at least two samples")
    dt_med = float(np.median(np.diff(t)))
    if dt_med > MAX_SAMPLE_INTERVAL_S:  # knot_s and the swing margin are seconds
        raise DataFormatError(f"column t: median sampling interval {dt_med:.4g}; expected seconds (at most "
                              f"{MAX_SAMPLE_INTERVAL_S:g}): is t in milliseconds? Offsets are tracked on a time axis in s")
    knots = _knots(float(t[0]), float(t[-1]), settings.knot_s)
    nb = len(knots) - DEGREE - 1
    Dm = np.diff(np.eye(nb), n=2, axis=0)
    P = Dm.T @ Dm
    off_cal = np.stack([cal.legs[k].offset for k in legs])
    off_se = np.stack([se if (se := cal.legs[k].offset_se) is not None else np.full(6, np.nan) for k in legs])
    coef = np.repeat(off_cal[:, None, :], nb, axis=1)
    unit = np.zeros((K, nb, nb))
    sigma = np.zeros((K, 6, 6))
    tracked = np.zeros(K, bool)
    cal_cov = np.zeros((K, 6, 6)) if cov is not None and phi is not None and R_WB is not None else None
    change_cov = np.zeros((K, 6, 6))
    inflation = np.ones((K, 6))
    if phi is not None:
        check_walking(t, phi)
        swing = walking_swing(swing, phi)
    dt = float(np.median(np.diff(t)))
    margin = int(round(SWING_MARGIN_S / dt))
    if margin > 0:
        swing = binary_erosion(swing, structure=np.ones((2 * margin + 1, 1), bool), border_value=1)
    n_sw = swing.sum(axis=0).astype(int)
    for i, k in enumerate(legs):  # legs, not samples
        m = swing[:, i]
        phase = np.cumsum(np.r_[True, np.diff(np.flatnonzero(m)) > 1]) if n_sw[i] else np.zeros(0, int)
        n_phase = int(phase[-1]) if len(phase) else 0
        if n_sw[i] < MIN_SWING or n_phase < MIN_PHASES:
            log.warning("track offsets: leg %s has %d swing samples in %d swing phase(s) (needs %d in %d or more); its "
                        "calibrated offsets are kept", k, n_sw[i], n_phase, MIN_SWING, MIN_PHASES)
            continue
        B = BSpline.design_matrix(t[m], knots, DEGREE)
        BtB = (B.T @ B).toarray()
        lam = settings.penalty * np.trace(BtB) / nb
        A = BtB + lam * P + 1e-12 * np.trace(BtB) / nb * np.eye(nb)
        Ai = np.linalg.inv(A)
        beta = Ai @ (B.T @ y[m, i])
        res = y[m, i] - B @ beta
        edf = float(np.trace(Ai @ BtB))
        sigma[i] = res.T @ res / max(n_sw[i] - edf, 1.0)
        # what differs from one swing phase to the next (a load left at lift-off, the leg's dynamics) is no noise
        # that averages out: the phases' residual sums against the samples' (1 for independent residuals)
        sums = np.zeros((n_phase, 6))
        np.add.at(sums, phase - 1, res)
        infl = np.sqrt(np.maximum(1.0, (sums**2).sum(axis=0) / np.maximum((res**2).sum(axis=0), 1e-300)))
        sigma[i] = sigma[i] * np.outer(infl, infl)
        inflation[i] = infl
        unit[i] = Ai @ BtB @ Ai
        coef[i] = beta
        tracked[i] = True
        if cal_cov is not None and phi is not None and R_WB is not None:   # (cal_cov is set only with both)
            G = _leg_weight_jacobian_mean(phi[m, i], R_WB[m], cal, k, cov)
            cal_cov[i] = G @ cov.cov @ G.T
            # the change since calibration, tracked - calibrated, errs by -(G d_theta + d_w_o): the same parameters'
            # joint covariance with the offsets' own columns beside G (their errors are correlated in the hanging fit)
            J = G.copy()
            for j, c in enumerate(WRENCH_COMPONENTS):
                if f"{k}.w_o.{c}" in pos_of(cov):
                    J[j, pos_of(cov)[f"{k}.w_o.{c}"]] += 1.0
            change_cov[i] = J @ cov.cov @ J.T
    if not tracked.any():
        raise DataFormatError(
            f"no leg has {MIN_PHASES} swing phases of {MIN_SWING} samples or more (swing samples per leg "
            f"{n_sw.tolist()}); expected a walking recording whose feet leave the ground: offsets are tracked from the "
            "swing phases (a standing session has none to track them from)")
    log.info("track offsets: phase-to-phase scatter inflates the swing noise by %s (per leg, largest component; 1: none)",
             dict(zip(legs, np.round(inflation.max(axis=1), 2).tolist())))
    return TrackedOffsets(legs, knots, coef, unit, sigma, tracked, n_sw, off_cal, off_se, (float(t[0]), float(t[-1])), cal_cov,
                          change_cov if cal_cov is not None else None)


def pos_of(cov) -> dict[str, int]:
    """Parameter name -> column of the calibration covariance (cached on the object)."""
    got = getattr(cov, "_ftcal_pos", None)
    if got is None:
        got = {n: i for i, n in enumerate(cov.names)}
        try:
            object.__setattr__(cov, "_ftcal_pos", got)
        except (AttributeError, TypeError):
            pass
    return got


def check_walking(t: np.ndarray, phi: np.ndarray) -> None:
    """Refuse a standing session: every shaft still (``checks.STILL_RAD_S``) in more than ``MAX_STILL_SHARE`` of
    the samples. Its feet lift only between poses, where a leg turning in the air is no walking swing."""
    from ..core.checks import STILL_RAD_S

    if len(t) < 3:
        return
    still = np.all(np.abs(np.diff(phi, axis=0)) <= STILL_RAD_S * np.diff(t)[:, None], axis=1)
    share = float(still.mean())
    if share > MAX_STILL_SHARE:
        raise DataFormatError(
            f"columns {{leg}}_phi: every shaft is still in {100 * share:.0f} % of the samples: a standing session, not a walk; "
            f"expected a walking recording (shafts still in at most {100 * MAX_STILL_SHARE:.0f} %) to track offsets from its "
            "swing phases (for a standing session, re-estimate offsets with [offsets_only] in a run)")


def walking_swing(swing: np.ndarray, phi: np.ndarray, min_travel: float = MIN_SWING_TRAVEL_RAD) -> np.ndarray:
    """The swing phases (N, K) in which the leg's shaft turns by ``min_travel`` rad or more: a foot carried
    forward. A foot held up in a standing pose (its shaft still; a standing session's tilted poses) may still
    touch or pull, and is not a swing to take offsets from."""
    out = swing.copy()
    for i in range(swing.shape[1]):
        idx = np.flatnonzero(swing[:, i])
        if not len(idx):
            continue
        phase = np.cumsum(np.r_[True, np.diff(idx) > 1]) - 1
        p = phi[idx, i]
        lo = np.full(phase[-1] + 1, np.inf)
        hi = np.full(phase[-1] + 1, -np.inf)
        np.minimum.at(lo, phase, p)
        np.maximum.at(hi, phase, p)
        out[idx[(hi - lo)[phase] < min_travel], i] = False
    return out


def log_changes(tr: TrackedOffsets) -> list[str]:
    """One line per leg: change since calibration (forces N, torques N*m) with se, p-value, significance."""
    tab = tr.change_table()
    lines = []
    for k, r in tab.iterrows():
        if not r["tracked"]:
            lines.append(f"{k}: not tracked ({int(r['n_swing'])} swing samples); calibrated offsets kept")
            continue
        ch = " ".join(f"{c} {r[f'change_{c}']:+.3g}±{r[f'change_{c}_se']:.2g}" for c in WRENCH_COMPONENTS)
        dr = " ".join(f"{r[f'drift_{c}']:+.3g}" for c in WRENCH_COMPONENTS)
        sig = "significant" if r["significant"] else "not significant"
        lines.append(f"{k}: offset change since calibration {ch}; chi2 {r['chi2']:.1f} on 6 dof, p {r['p']:.2g} ({sig}); "
                     f"drift within the recording {dr}")
    for line in lines:
        log.info("tracked offsets: %s", line)
    return lines
