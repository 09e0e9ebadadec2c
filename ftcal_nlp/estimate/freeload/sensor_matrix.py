"""The sensor's own 6x6 matrix recalibrated in situ on a free load (issue 33; Andrade Chavez, Traversaro et al.,
Humanoids 2016: the in-situ re-estimation of a six-axis F/T sensor's calibration matrix, ridge-regularised
towards the factory matrix, the ridge weight chosen on data it was not fitted to).

Reading model (``OUTPUT_FORMAT.md``, ``sensor_matrix``): the raw reading ``r_n`` less its offset ``o`` (raw units),
mapped by the correction ``C``, is the load's wrench of ``loads.base``::

    C (r_n - o) = w_n(theta, E),   w_n = [ M E^T b_n ;  (K_n theta) x (E^T b_n) ],   M = mu . theta,

so ``r_n = o + C^-1 w_n`` (the model readings of :meth:`FreeLoadResult.predict` with a matrix). ``C = I + D``:
``FreeLoadSettings.sensor_matrix = "force"`` frees the 3x3 force block of ``D`` (9 entries; the torques keep the
factory calibration), ``"full"`` all 36; ``"none"`` (the default) leaves ``C = I`` and this module unused: every
number of a run is then the same as without it. The identity is the factory ("workbench") matrix, since the
readings are already in N and N*m through it.

Fit (:func:`fit_sensor_matrix`, after the free-load fit of ``estimate.py`` / ``shared_tilt.py``, from its estimate):
Gauss-Newton on the per-sample residual in raw units ``e_n = r_n - o - C^-1 w_n`` (where the readings' noise is;
the corrected residual ``C (r_n - o) - w_n`` would shrink with ``C`` and the load together, a trivial minimum at
``C = 0``), weighted by ``W_c = 1 / sigma_c^2`` (the residual sd per channel of a first matrix fit without ridge, or the
factory fit's where smaller),
over ``x = [o (6), theta (p), tilts (2 per estimated group), delta (3), D (9 | 36)]`` with ``E = E* expm([delta]x)``
and ``d C^-1 = -C^-1 dC C^-1``, minimising

    sum_n e_n^T W e_n  +  N lambda ||D||_F^2  +  ((mu . theta - m_w) / (rel_sd m_w))^2  +  tiny ridge,

the third term only where the transducer gives ``load_mass_kg`` (``DATA_FORMAT.md`` section 5: the mass as weighed,
a measurement; ``sensor_matrix_mass_rel_sd`` its relative sd). The tiny ridge (``prior_weight`` times each
parameter's information, toward the first fit; ``D_FLOOR`` times the mean information of ``D``'s entries, toward
0) pins only what the data leave undetermined, and there it keeps the factory matrix: an undetermined direction
that moves ``D`` and the load moves the load. A ridge holds a line, not a curve: the exact symmetries of the model
are curves (``C_ff -> a C_ff`` with ``M -> a M``; with ``"full"`` ``C_tt -> b C_tt`` with the first moment, ``C ->
blockdiag(R, R) C`` with the mount ``E -> E R^T``, ``C_t. -> C_t. + [k]x C_f.`` with the CoM), and Gauss-Newton walks
along them (on the iCub foot's recording the force block fell to 0.0016 with the mass at -0.11 kg). Those the data
and the load leave exactly undetermined (:func:`gauge`: without ``load_mass_kg`` the force scale, ...) are held
exactly at the factory value: every step's ``D`` is orthogonal to their directions at ``C = I`` (the trace of
``D_ff`` stays 0, ...; the load takes what they would move). The steps are Levenberg-Marquardt's (a full
Gauss-Newton step far from the minimum overshoots). The world tilt and each recording's tilt are re-estimated where
the first fit estimated them (a gain error biases them there), held elsewhere; transducers fitted together for a
shared recording tilt (``shared_tilt.py``) are refitted one by one, so that tilt becomes each one's own. Each pass
forms the normal equations chunk by chunk (no sample loop); the model is bilinear, a few passes converge (on a
short arc with a model error, tens).

Ridge weight (``sensor_matrix_ridge``, a grid of ``lambda``, dimensionless: per sample, per unit ``D^2``, in the
whitened residual's units; ``inf`` is the factory matrix kept): ``sensor_matrix_folds`` contiguous blocks of the
samples in time order (recording by recording), each held out in turn, the fit on the others converged
(:func:`choose_ridge`); the score of a fold is the mean over channels of the held-out mean square residual (raw
units) over ``sigma_c^2`` (``sigma_c`` no larger than the factory fit's residual sd: a fit that trades one channel
for another cannot make its channels cheap). The weight kept is the largest whose mean score exceeds the least
one's by no more than the se of their fold-by-fold difference (the one-se rule: on clean data the held-out scores
tie and the largest weight, the factory matrix, is kept).

What the data determine: the eigen-analysis of the data-only information ``J^T W J`` (``W`` shrunk by the
residuals' serial correlation, as ``estimate.py``) over ``[o, theta, delta, D]`` (``solver.identifiability``),
the covariance on its determined subspace (the ridge is a prior of the undetermined part, not of the se). For a
rigid payload: the trace of the force block is the load's mass (``D_ff = a I`` scales every force as ``M (1 +
a)`` does) unless the mass is weighed; with ``"full"`` the trace of the torque block is the first moment's scale,
a common antisymmetric part of both diagonal blocks is the mounting rotation (``E``), and the skew part of the
torque-from-force block ``C_tf`` is a shift of the CoM (``[k]x M E^T b``); with the torques of a payload off
its sensor's origin the force block's own antisymmetric part is determined (a rotation of the forces only is
not a mounting rotation). Undetermined parameters get se = inf and the directions are named; the determined
combinations of those parameters come with se (``estimate._covariance``), and :func:`named_combinations`
gives the blocks' scale, rotation and shear with se, each marked determined or not.

:func:`apply_sensor_matrix` is the correction that ``correct`` and ``export`` apply to raw readings:
``C (r - o)``. Keys written to the transducer's entry of ``calibration.json`` (:meth:`SensorMatrixResult.report`):
``sensor_matrix`` (6x6, ``C``), ``sensor_matrix_se`` (6x6; 0 where held at the factory value, by the mode or
because the ridge choice kept the factory matrix (``inf``), null where undetermined), ``sensor_matrix_mode``, ``sensor_matrix_ridge`` (the weight kept), ``sensor_matrix_heldout``
(the grid's held-out scores and per-axis RMS), ``sensor_matrix_combinations`` (:func:`named_combinations`).
``calibration_cov.npz`` holds ``D``'s entries (``{X}.C.<row>.<col>``, ``C - I``) with their covariance with the
load's parameters (``SensorMatrixResult.joint_cov``; ``estimate/uncertainty.py``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from ...core.geometry import rotation_to_rotvec, rotvec_to_rotation, skew
from .estimate import _covariance, free_load_data
from .problem import serial_inflation, tilt_derivative, tilt_gravity

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
MODES = ("none", "force", "full")
#: ridge of D's entries that holds them at the factory value where the data leave them undetermined, relative to the
#: mean information of an entry (the load's parameters get ``prior_weight``, 100x less: they take the undetermined part)
D_FLOOR = 1e-6
#: a refitted block whose gain (a singular value of the force or torque block of ``C``) departs from 1 by more than
#: this is said to be implausible for a drift of a factory-calibrated sensor (in-situ recalibrations report a few per
#: cent; the ATI sessions of ``REAL_DATA.md`` 6-12 %): on a real iCub thigh the held-out choice kept a matrix of
#: diagonal 0.43 1.37 1.21 that took an unmodelled ~20 N pose-dependent load (the diagnosis names it)
PLAUSIBLE_GAIN_DEPARTURE = 0.2
_CHUNK = 8192
_MAX_ITER = 100
_DAMPINGS = 40
#: a held-out fold's fit converged where an iteration lowers the objective by less than this share (a
#: whitened chi-square of ~1e4: ~1e-3, far below the scores' differences)
_CV_TOL = 1e-5
#: share of a symmetry's information (:func:`gauge`) that the load, mount, offsets and tilts leave to it, below which it is
#: exact (held at the factory value): on the iCub leg and foot recordings exact ones give < 1e-18, the least determined one 1e-8
GAUGE_TOL = 1e-12


@dataclass(frozen=True)
class SensorMatrixOptions:
    """``FreeLoadSettings``' sensor-matrix keys, checked: ``mode`` ``"none" | "force" | "full"``; ``ridge`` the grid
    of ``lambda`` (module docstring; ``inf``: the factory matrix); ``folds`` contiguous held-out blocks;
    ``mass_rel_sd`` the weighed mass' relative sd; ``prior_weight`` and ``rel_eig_tol`` as ``FreeLoadSettings``'."""

    mode: str
    ridge: tuple[float, ...]
    folds: int
    mass_rel_sd: float
    prior_weight: float
    rel_eig_tol: float

    @property
    def on(self) -> bool:
        return self.mode != "none"


def options(s) -> SensorMatrixOptions:
    """The sensor-matrix options of a :class:`~ftcal_nlp.core.settings.FreeLoadSettings` (every key read, whether on or not)."""
    return SensorMatrixOptions(str(s.sensor_matrix), tuple(float(v) for v in s.sensor_matrix_ridge), int(s.sensor_matrix_folds),
                               float(s.sensor_matrix_mass_rel_sd), float(s.prior_weight), float(s.rel_eig_tol))


def pairs_of(mode: str) -> list[tuple[int, int]]:
    """The ``(row, column)`` entries of ``D`` a mode frees, row-major."""
    n = {"force": 3, "full": 6}.get(mode, 0)
    return [(i, j) for i in range(n) for j in range(n)]


def matrix_of(d: np.ndarray, pairs: list[tuple[int, int]]) -> np.ndarray:
    """``C = I + D`` (6, 6) from the free entries ``d`` of ``D``."""
    C = np.eye(6)
    for v, (i, j) in zip(d, pairs):
        C[i, j] += v
    return C


def apply_sensor_matrix(readings: np.ndarray, C: np.ndarray | None, offset: np.ndarray | None = None) -> np.ndarray:
    """The corrected wrench ``C (r - offset)`` of raw readings ``readings`` (N, 6) (or (6,)), rows samples as
    ``Recording.wrench[leg]``; ``C`` the 6x6 ``sensor_matrix`` of ``calibration.json`` (None: the identity, the
    factory matrix kept); ``offset`` (6,) the raw offset (``offset`` of ``calibration.json``; None: none taken off).
    NaN rows stay NaN."""
    r = np.asarray(readings, float)
    if r.shape[-1] != 6:
        raise ValueError(f"apply_sensor_matrix: readings of shape {r.shape}; expected (N, 6) (fx..tz per row)")
    d = r if offset is None else r - np.asarray(offset, float)
    if C is None:
        return d.copy() if offset is None else d
    C = np.asarray(C, float)
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        raise ValueError(f"apply_sensor_matrix: sensor_matrix of shape {C.shape}; expected a finite 6x6 matrix")
    return d @ C.T


def sensor_matrix_of(entry: dict) -> np.ndarray | None:
    """``C`` (6, 6) of a transducer's ``calibration.json`` entry (its ``load`` dict once read), None where absent."""
    C = entry.get("sensor_matrix") if entry else None
    if C is None:
        return None
    C = np.asarray(C, float)
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        raise ValueError(f"sensor_matrix: expected a finite 6x6 matrix (rows fx..tz), got shape {C.shape}")
    return C


# ----------------------------------------------------------------------------------------------- the model


@dataclass
class Problem:
    """The samples: ``y`` (N, 6) raw readings; ``a`` (N, 3, 3) and ``group`` (N,) with gravity in nominal ft
    ``b_n = a_n u_g``, ``u_g = tilt_gravity(tilt_g)`` of the sample's tilt group (``problem.FreeLoadData``); ``K``
    (N, 3, p); the load's mass row ``mu``; the mode's ``pairs``; ``tilts`` the groups whose tilt is estimated; whether
    the mount is; a weighed mass."""

    y: np.ndarray
    a: np.ndarray
    group: np.ndarray
    K: np.ndarray
    mu: np.ndarray
    pairs: list[tuple[int, int]]
    mount: bool
    tilts: tuple[int, ...] = ()
    weighed_kg: float | None = None
    mass_rel_sd: float = 1e-3
    #: (n_D, n_D - k) orthonormal basis of the ``D`` steps allowed (:func:`gauge`): ``None`` every entry free
    gauge: np.ndarray | None = None
    #: the names of the exact symmetries held at the factory value (:func:`gauge`)
    held: tuple[str, ...] = ()

    @property
    def p(self) -> int:
        return len(self.mu)

    @property
    def n_params(self) -> int:
        return self.d_at + len(self.pairs)

    @property
    def tilt_at(self) -> int:
        return 6 + self.p

    @property
    def mount_at(self) -> int:
        return 6 + self.p + 2 * len(self.tilts)

    @property
    def d_at(self) -> int:
        return self.mount_at + (3 if self.mount else 0)

    def subset(self, idx: np.ndarray) -> "Problem":
        return dataclasses.replace(self, y=self.y[idx], a=self.a[idx], group=self.group[idx], K=self.K[idx])


@dataclass
class State:
    """``o`` (6,), ``theta`` (p,), ``tilt`` (G, 2) every group's tilt (rad; those not estimated held), ``E`` (3, 3),
    ``d`` (free entries of ``D``)."""

    o: np.ndarray
    theta: np.ndarray
    tilt: np.ndarray
    E: np.ndarray
    d: np.ndarray

    def C(self, pairs) -> np.ndarray:
        return matrix_of(self.d, pairs)

    def copy(self, d: np.ndarray | None = None) -> "State":
        return State(self.o.copy(), self.theta.copy(), self.tilt.copy(), self.E.copy(), self.d.copy() if d is None else d)


def gravity(pr: Problem, st: State, sl: np.ndarray | slice = slice(None)) -> np.ndarray:
    """``b_n = a_n u_g`` (n, 3) of samples ``sl``."""
    U = np.stack([tilt_gravity(t) for t in st.tilt])
    return np.einsum("nik,nk->ni", pr.a[sl], U[pr.group[sl]])


def model_wrench(b: np.ndarray, K: np.ndarray, theta: np.ndarray, mu: np.ndarray, E: np.ndarray) -> np.ndarray:
    """``w_n`` (N, 6) of the module docstring (the load's wrench in the true ft, no offset)."""
    g = b @ E
    s = np.einsum("nip,p->ni", K, theta)
    return np.concatenate([float(mu @ theta) * g, np.cross(s, g)], axis=1)


def residual(pr: Problem, st: State, idx: np.ndarray | slice = slice(None)) -> np.ndarray:
    """``e_n = r_n - o - C^-1 w_n`` (N, 6) in raw units (the readings' noise is there); ``e_n @ C.T`` is the
    corrected residual ``C (r_n - o) - w_n``."""
    Ci = np.linalg.inv(st.C(pr.pairs))
    return (pr.y[idx] - st.o) - model_wrench(gravity(pr, st, idx), pr.K[idx], st.theta, pr.mu, st.E) @ Ci.T


def _jacobian(pr: Problem, st: State, sl: slice) -> tuple[np.ndarray, np.ndarray]:
    """``(e, J)``: residual (n, 6) and ``de / d[o, theta, tilts, delta, d]`` (n, 6, P) of samples ``sl``; with
    ``d C^-1 = -C^-1 dC C^-1``, ``de / dD_ij = C^-1[:, i] (C^-1 w)_j``."""
    y, K = pr.y[sl], pr.K[sl]
    n, p = len(y), pr.p
    Ci = np.linalg.inv(st.C(pr.pairs))
    g = gravity(pr, st, sl) @ st.E
    s = np.einsum("nip,p->ni", K, st.theta)
    M = float(pr.mu @ st.theta)
    v = np.concatenate([M * g, np.cross(s, g)], axis=1) @ Ci.T
    e = (y - st.o) - v
    at = pr.d_at
    dw = np.zeros((n, 6, at - 6))            # d w / d[theta, tilts, delta]
    dw[:, :3, :p] = g[:, :, None] * pr.mu[None, None, :]
    dw[:, 3:, :p] = np.cross(K, g[:, :, None], axisa=1, axisb=1, axisc=1)
    grp = pr.group[sl]
    Ss = skew(s)
    for k, gi in enumerate(pr.tilts):   # d(E^T a u)/d tilt = E^T a du/dtilt, on the group's samples only
        dg = np.einsum("ji,njk,kl->nil", st.E, pr.a[sl], tilt_derivative(st.tilt[gi])) * (grp == gi)[:, None, None]
        c = pr.tilt_at + 2 * k - 6
        dw[:, :3, c:c + 2] = M * dg
        dw[:, 3:, c:c + 2] = Ss @ dg
    if pr.mount:   # E = E* (I + [delta]x): E^T b = g + g x delta, d(E^T b)/d delta = [g]x
        Sg = skew(g)
        c = pr.mount_at - 6
        dw[:, :3, c:c + 3] = M * Sg
        dw[:, 3:, c:c + 3] = Ss @ Sg
    J = np.zeros((n, 6, pr.n_params))
    J[:, :, :6] = -np.eye(6)
    J[:, :, 6:at] = -np.einsum("ij,njk->nik", Ci, dw)
    for k, (i, j) in enumerate(pr.pairs):
        J[:, :, at + k] = Ci[None, :, i] * v[:, j, None]
    return e, J


def normal_equations(pr: Problem, st: State, W: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(J^T W J, J^T W e, rss per channel)`` over every sample of ``pr``, chunk by chunk."""
    P = pr.n_params
    A, gv, rss = np.zeros((P, P)), np.zeros(P), np.zeros(6)
    sw = np.sqrt(W)
    for a in range(0, len(pr.y), _CHUNK):
        e, J = _jacobian(pr, st, slice(a, a + _CHUNK))
        Jw = (J * sw[None, :, None]).reshape(-1, P)
        A += Jw.T @ Jw
        gv += Jw.T @ (e * sw).ravel()
        rss += (e**2).sum(axis=0)
    return A, gv, rss


def _vector(pr: Problem, st: State, E0: np.ndarray) -> np.ndarray:
    """The parameters ``[o, theta, tilts, rotvec(E0^T E), d]`` (module docstring's order)."""
    parts = [st.o, st.theta, *[st.tilt[g] for g in pr.tilts]] + ([rotation_to_rotvec(E0.T @ st.E)] if pr.mount else []) + [st.d]
    return np.concatenate(parts)


def _mass_row(pr: Problem) -> tuple[np.ndarray, float, float] | None:
    """The weighed mass' row ``a`` (over the parameters), its sd and the weighed mass (kg), or None."""
    if pr.weighed_kg is None:
        return None
    a = np.zeros(pr.n_params)
    a[6:6 + pr.p] = pr.mu
    return a, pr.mass_rel_sd * pr.weighed_kg, pr.weighed_kg


def _system(pr: Problem, st: State, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton ``(A, g)`` at ``st``: the normal equations and the weighed mass' term."""
    A, gv, _rss = normal_equations(pr, st, W)
    mrow = _mass_row(pr)
    if mrow is not None:
        a, sd, kg = mrow
        A = A + np.outer(a, a) / sd**2
        gv = gv + a * (float(pr.mu @ st.theta) - kg) / sd**2
    return A, gv


def _ridge(pr: Problem, A: np.ndarray, lam: float, prior_weight: float) -> np.ndarray:
    """The ridge's diagonal: ``prior_weight`` times each parameter's information, ``D_FLOOR`` times ``D``'s mean
    information plus ``N lam`` on ``D``'s entries."""
    dg = np.clip(np.diag(A), 0.0, None)
    fill = dg[dg > 0].mean() if np.any(dg > 0) else 1.0
    ridge = prior_weight * np.where(dg > 0, dg, fill)
    if len(pr.pairs):
        ridge[pr.d_at:] = D_FLOOR * dg[pr.d_at:].mean() + (len(pr.y) * lam if np.isfinite(lam) else 0.0)   # inf: D's columns left out
    return ridge


def _direction(pr: Problem, st: State, A: np.ndarray, gv: np.ndarray, ridge: np.ndarray, centre: State,
               lam: float, damping: float = 0.0) -> np.ndarray:
    """The Gauss-Newton step from ``st`` (``inf``: ``D`` held at 0, its columns left out); ``D``'s part within the
    gauge (``pr.gauge``: the exact symmetries held at the factory value, :func:`gauge`); ``damping``: Levenberg-
    Marquardt's, relative to the diagonal (0: Gauss-Newton)."""
    x0 = _vector(pr, centre.copy(np.zeros(len(pr.pairs))), centre.E)
    x = _vector(pr, st, centre.E)
    at = pr.d_at
    k = np.arange(at if not np.isfinite(lam) else pr.n_params)
    step = np.zeros(pr.n_params)
    if not np.isfinite(lam):
        x = x.copy()
        x[at:] = 0.0
    rhs = gv[k] + ridge[k] * (x - x0)[k]
    if not np.isfinite(lam):   # the gradient at D = 0, to first order from st's D
        rhs = rhs - A[np.ix_(k, np.arange(at, pr.n_params))] @ st.d
    H = A[np.ix_(k, k)] + np.diag(ridge[k])
    if damping > 0:
        H = H + damping * np.diag(np.diag(H))
    if np.isfinite(lam) and pr.gauge is not None:
        # D's step within the gauge: D = B z (B orthonormal, D_FLOOR and lambda are the same on every entry)
        Q = np.zeros((len(k), at + pr.gauge.shape[1]))
        Q[:at, :at] = np.eye(at)
        Q[at:, at:] = pr.gauge
        step[k] = Q @ -np.linalg.solve(Q.T @ H @ Q, Q.T @ rhs)
    else:
        step[k] = -np.linalg.solve(H, rhs)
    return step


def _apply(pr: Problem, st: State, step: np.ndarray, lam: float) -> State:
    """``st`` moved by ``step`` (``inf``: ``D`` = 0)."""
    new = st.copy(np.zeros(len(pr.pairs)) if not np.isfinite(lam) else None)
    ta = pr.tilt_at
    new.o = new.o + step[:6]
    new.theta = new.theta + step[6:6 + pr.p]
    for j, gi in enumerate(pr.tilts):
        new.tilt[gi] = new.tilt[gi] + step[ta + 2 * j:ta + 2 * j + 2]
    if pr.mount:
        new.E = new.E @ rotvec_to_rotation(step[pr.mount_at:pr.mount_at + 3])
    new.d = new.d + step[pr.d_at:]
    return new


def _objective(pr: Problem, st: State, W: np.ndarray, ridge: np.ndarray, centre: State, lam: float) -> float:
    """The objective of the module docstring at ``st`` (the ridge's diagonal ``ridge``; ``inf``: ``D`` out)."""
    e = residual(pr, st)
    x0 = _vector(pr, centre.copy(np.zeros(len(pr.pairs))), centre.E)
    dx = _vector(pr, st, centre.E) - x0
    k = slice(None) if np.isfinite(lam) else slice(0, pr.d_at)
    out = float(((e**2) * W).sum() + (ridge[k] * dx[k] ** 2).sum())
    mrow = _mass_row(pr)
    if mrow is not None:
        _, sd, kg = mrow
        out += ((float(pr.mu @ st.theta) - kg) / sd) ** 2
    return out


def solve(pr: Problem, start: State, W: np.ndarray, lam: float, prior_weight: float, centre: State | None = None,
          ridge: np.ndarray | None = None, rel_tol: float = 1e-12) -> State:
    """The minimum of the module docstring's objective for ridge weight ``lam`` (``inf``: ``D = 0``) by Gauss-Newton
    from ``start``; ``centre`` (default ``start``): the tiny ridge's ``o, theta, tilts, E`` (``D``'s centre is 0, the
    factory matrix). Levenberg-Marquardt: a step that raises the objective is damped (the model is bilinear: a full
    Gauss-Newton step far from the minimum overshoots, on the iCub foot onto a collapse of ``C``); no step lowering it
    ends the iterations.
    ``ridge``: the ridge's diagonal (:func:`_ridge`; default: from the information at ``start``). Converged where
    the step is below 1e-6 of every parameter's scale or lowers the objective by no more than ``rel_tol`` of it."""
    centre = start if centre is None else centre
    st = start.copy(None if np.isfinite(lam) else np.zeros(len(pr.pairs)))
    obj = None
    damping, grow = 1e-9, 2.0
    for _ in range(_MAX_ITER):
        A, gv = _system(pr, st, W)
        if ridge is None:   # fixed over the iterations: the objective does not move under the solver
            ridge = _ridge(pr, A, lam, prior_weight)
        if obj is None:
            obj = _objective(pr, st, W, ridge, centre, lam)
        # the objective's gradient / 2 and Gauss-Newton Hessian / 2 (ridge included; D's part 0 with inf)
        dx = _vector(pr, st, centre.E) - _vector(pr, centre.copy(np.zeros(len(pr.pairs))), centre.E)
        g, H = gv + ridge * dx, A + np.diag(ridge)
        new = None
        for _h in range(_DAMPINGS):
            step = _direction(pr, st, A, gv, ridge, centre, lam, damping)
            cand = _apply(pr, st, step, lam)
            f = _objective(pr, cand, W, ridge, centre, lam)
            pred = -(2.0 * step @ g + step @ H @ step)
            if np.isfinite(f) and f <= obj:
                rho = (obj - f) / pred if pred > 0 else 1.0
                damping = max(damping * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12)
                grow = 2.0
                new = cand
                break
            damping, grow = damping * grow, 2.0 * grow
        if new is None:   # no step lowers the objective: st is the minimum to rounding
            break
        st, drop, obj = new, obj - f, f
        if np.all(np.abs(step) * np.sqrt(np.diag(A) + ridge) < 1e-6) or drop <= rel_tol * obj:
            break
    return st


def _generators(mode: str) -> list[tuple[str, np.ndarray]]:
    """The exact symmetries a load may leave in ``C`` (module docstring): 6x6 ``X`` with ``C -> (I + eps X) C`` and the
    load moved so that ``C^-1 w`` stays: the force block's scale (the mass), and with ``"full"`` the torque block's
    (the first moment), a rotation common to both diagonal blocks (the mount) and the skew part of ``C_tf`` (a shift
    of the CoM)."""
    F = np.zeros((6, 6))
    F[:3, :3] = np.eye(3)
    out = [("force.scale", F)]
    if mode == "full":
        out.append(("torque.scale", np.eye(6) - F))
        for i, ax in enumerate("xyz"):
            e = np.zeros(3)
            e[i] = 1.0
            R = np.zeros((6, 6))
            R[:3, :3] = R[3:, 3:] = skew(e)
            out.append((f"rotation.{ax} (force and torque blocks together)", R))
        for i, ax in enumerate("xyz"):
            e = np.zeros(3)
            e[i] = 1.0
            T = np.zeros((6, 6))
            T[3:, :3] = skew(e)
            out.append((f"torque_from_force.skew.{ax}", T))
    return out


def _r_factor(M: np.ndarray) -> np.ndarray:
    """The triangular factor ``R`` of ``M = Q R`` (``min(rows, cols)`` rows)."""
    return cast(np.ndarray, np.linalg.qr(M, mode="r"))


def gauge(pr: Problem, st: State, W: np.ndarray) -> tuple[np.ndarray | None, tuple[str, ...]]:
    """The exact symmetries of the model at ``st`` and the ``D`` steps that keep them at the factory value: ``(B,
    held)``, ``B`` (n_D, n_D - k) an orthonormal basis of the steps orthogonal to the held symmetries' directions
    in ``D`` (None: none held), ``held`` their names.

    A symmetry (:func:`_generators`, ``C -> (I + eps X) C``) is exact where its direction in ``D``, ``(X C)``'s free
    entries, is reached by the other parameters' (load, mount, offsets, tilts) to rounding: the share of its
    information that the Schur complement of ``J^T W J`` (the weighed mass' row included: a weighed mass fixes the
    force scale) keeps below ``GAUGE_TOL``. The model is not linear along such a direction (scaling ``C_ff`` with
    the mass is a curve), so the tiny ridge cannot hold it: a Gauss-Newton step walks along it. Held by every
    step's ``D`` being orthogonal to it, its combination (the trace of ``D_ff`` for the scale, ...) stays exactly at
    the factory value."""
    nd = len(pr.pairs)
    if nd == 0:
        return None, ()
    C = st.C(pr.pairs)
    cands, names = [], []
    free = np.zeros((6, 6), bool)
    for i, j in pr.pairs:
        free[i, j] = True
    for nm, X in _generators("full" if nd == 36 else "force"):
        XC = X @ C
        if np.any(np.abs(XC[~free]) > 0):   # leaves the mode's entries: not a direction of this D
            continue
        cands.append(np.array([XC[i, j] for i, j in pr.pairs]))
        names.append(nm)
    if not cands:
        return None, ()
    U = np.array(cands)                                          # (m, n_D) the candidates' directions in D
    at, m = pr.d_at, len(U)
    # the whitened Jacobian of the other parameters and of the candidates' directions, reduced chunk by chunk to its
    # triangular factor (orthogonal transformations: no squared condition number, unlike J^T W J)
    sw = np.sqrt(W)
    Rf = np.zeros((0, at + m))
    for a in range(0, len(pr.y), _CHUNK):
        _e, J = _jacobian(pr, st, slice(a, a + _CHUNK))
        Jw = J * sw[None, :, None]
        block = np.concatenate([Jw[:, :, :at].reshape(-1, at), (Jw[:, :, at:] @ U.T).reshape(-1, m)], axis=1)
        Rf = _r_factor(np.concatenate([Rf, block]))
    mrow = _mass_row(pr)
    if mrow is not None:   # the weighed mass: one more observation of the load's parameters
        extra = np.concatenate([mrow[0][:at] / mrow[1], np.zeros(m)])[None, :]
        Rf = _r_factor(np.concatenate([Rf, extra]))
    Ro, Ry = Rf[:, :at], Rf[:, at:]
    cs = np.linalg.norm(Ro, axis=0)
    cs = np.where(cs > 0, cs, 1.0)
    X = np.linalg.lstsq(Ro / cs, Ry, rcond=1e-10)[0]
    E = Ry - (Ro / cs) @ X                                       # what the other parameters cannot reach
    Ms, Rm = E.T @ E, Ry.T @ Ry
    # Ms v = l Rm v: l the share of a combination's information that the other parameters leave to it (a combination
    # without information of its own, l = 0: it does not move C^-1 w at all)
    Lr, Ur = np.linalg.eigh(Rm)
    Rh = Ur / np.sqrt(np.maximum(Lr, 0.0) + 1e-12 * max(Lr.max(), 1e-300))
    lv, Vv = np.linalg.eigh(Rh.T @ Ms @ Rh)
    null = lv < GAUGE_TOL
    if not np.any(null):
        return None, ()
    Hd = U.T @ (Rh @ Vv[:, null])                                # the held directions in D's own entries
    _u, sv, Vh = np.linalg.svd((Hd / np.linalg.norm(Hd, axis=0, keepdims=True)).T, full_matrices=True)
    rank = int((sv > 1e-10 * sv.max()).sum())
    held = tuple(nm for nm, c in zip(names, np.abs(U @ Vh[:rank].T).max(axis=1)) if c > 1e-8 * np.linalg.norm(U, axis=1).max())
    return Vh[rank:].T, held


# ------------------------------------------------------------------------------------ ridge by held-out error


def folds_of(n: int, k: int) -> list[np.ndarray]:
    """``k`` contiguous blocks of ``range(n)`` (the samples in time order, recording by recording)."""
    k = max(2, min(int(k), n // 2))
    edges = np.linspace(0, n, k + 1).round().astype(int)
    return [np.arange(edges[i], edges[i + 1]) for i in range(k)]


@dataclass(frozen=True)
class RidgeChoice:
    """The grid, per weight the mean held-out score and per-axis held-out RMS (raw units), the paired se
    against the least score, and the weight kept."""

    grid: tuple[float, ...]
    score: np.ndarray           # (L,)
    score_se: np.ndarray        # (L,) se of the fold-by-fold difference to the least score
    rms: np.ndarray             # (L, 6)
    chosen: float

    def report(self) -> dict:
        def num(v):
            return float(v) if np.isfinite(v) else "inf"

        return {"grid": [num(v) for v in self.grid], "score": self.score.tolist(), "score_se": self.score_se.tolist(),
                "heldout_rms": self.rms.tolist(), "chosen": num(self.chosen)}


def choose_ridge(pr: Problem, centre: State, W: np.ndarray, grid: tuple[float, ...], k: int,
                 prior_weight: float) -> RidgeChoice:
    """Held-out score of every weight of ``grid`` over ``k`` contiguous folds; the one-se choice (module docstring).
    Each fold's fits are the converged minima (:func:`solve`) on the fold's training samples, down the grid from
    ``centre`` (the factory matrix's fit), each weight's fit started from the previous (larger) one's, with the same
    ridge (the tiny ridge's information at ``centre``). One Gauss-Newton step from the fit on every sample
    without ridge was not enough: that fit has seen the held-out block, and where a model error pulls ``C`` far
    from the factory matrix one step barely leaves it, so the held-out score rewarded the collapse (the iCub thigh,
    part A: 178 against 784 for the factory matrix, C's force gains 0.04 0.61 0.80; converged: ridge 0 106, 10 75,
    the factory matrix 84). The path starts at the factory matrix: a weight whose minimum only the fit without ridge
    reaches is scored at the path's, the higher, training objective (a bias to the factory matrix)."""
    folds = folds_of(len(pr.y), k)
    L = len(grid)
    scores = np.zeros((L, len(folds)))
    sq = np.zeros((L, 6))
    at_centre = centre.copy(np.zeros(len(pr.pairs)))
    down = np.argsort(grid, kind="stable")[::-1]
    for f, held in enumerate(folds):
        sub = pr.subset(np.setdiff1d(np.arange(len(pr.y)), held))
        A, _gv = _system(sub, at_centre, W)
        fits: dict[int, State] = {}
        p = at_centre
        for i in down:
            ridge = _ridge(sub, A, grid[i], prior_weight)
            p = solve(sub, p, W, grid[i], prior_weight, centre, ridge, _CV_TOL)
            if not np.isfinite(_objective(sub, p, W, ridge, centre, grid[i])):
                raise ValueError(f"sensor_matrix ridge choice: fold {f}, weight {grid[i]:g}: the fit has no finite training "
                                 "objective (non-finite readings or a singular system?)")
            fits[i] = p
        for i, lam in enumerate(grid):
            st = fits[i]
            e = residual(pr, st, held)
            scores[i, f] = float(np.mean((e**2).mean(axis=0) * W))
            sq[i] += (e**2).sum(axis=0)     # raw units
    mean = scores.mean(axis=1)
    best = int(np.argmin(mean))
    diff = scores - scores[best]
    se = diff.std(axis=1, ddof=1) / np.sqrt(len(folds))
    ok = mean <= mean[best] + se
    order = np.argsort(grid)
    chosen = float(np.asarray(grid)[order][ok[order]][-1])   # the largest weight within one se of the least score
    return RidgeChoice(tuple(grid), mean, se, np.sqrt(sq / len(pr.y)), chosen)


# ------------------------------------------------------------------------------------------- what is determined


def block_values(C: np.ndarray, mode: str) -> dict[str, float]:
    """The named parts of ``C`` (module docstring): each row block normalised by its own scale ``s = trace / 3`` of
    its diagonal block (forces' rows by ``s_f``, torques' by ``s_t``: a gain common to a row block is what a load's
    mass or first moment absorbs), ``N = C_block / s - I`` (diagonal blocks) or ``C_block / s`` (``C_tf``, torques
    read from forces); per diagonal block its ``scale`` (``s - 1``), ``rotation`` (vee of ``N``'s antisymmetric
    part) and ``shear`` (``N``'s symmetric part: ``xx``, ``yy``, ``xy``, ``xz``, ``yz``; ``zz = -xx - yy``); for
    ``C_tf`` its ``skew`` (vee of its antisymmetric part: a shift of the CoM) and its symmetric part."""
    out: dict[str, float] = {}

    def parts(N: np.ndarray, what: str, skew_name: str = "rotation", sym_all: bool = False) -> None:
        A = 0.5 * (N - N.T)
        for ax, v in zip("xyz", (A[2, 1], A[0, 2], A[1, 0])):
            out[f"{what}.{skew_name}.{ax}"] = float(v)
        S = 0.5 * (N + N.T)
        keys = (("xx", 0, 0), ("yy", 1, 1)) + ((("zz", 2, 2),) if sym_all else ()) + (("xy", 0, 1), ("xz", 0, 2), ("yz", 1, 2))
        for nm, i, j in keys:
            out[f"{what}.{'sym' if sym_all else 'shear'}.{nm}"] = float(S[i, j])

    sf = np.trace(C[:3, :3]) / 3
    out["force.scale"] = float(sf - 1)
    parts(C[:3, :3] / sf - np.eye(3), "force")
    if mode == "full":
        st = np.trace(C[3:, 3:]) / 3
        out["torque.scale"] = float(st - 1)
        parts(C[3:, 3:] / st - np.eye(3), "torque")
        parts(C[3:, :3] / st, "torque_from_force", "skew", sym_all=True)
    return out


def named_combinations(mode: str, C: np.ndarray, at: int, cov: np.ndarray, null: np.ndarray, leg: str) -> list[dict]:
    """:func:`block_values` of ``C`` with se from ``cov`` (over every parameter; ``D``'s entries from column ``at``)
    through their gradient (central differences: they are rational in ``C``), ``determined`` where the gradient is
    orthogonal to every undetermined direction (``null``, the parameters' own units)."""
    pairs = pairs_of(mode)
    names = list(block_values(C, mode))
    G = np.zeros((len(names), cov.shape[0]))
    h = 1e-6
    for k, (i, j) in enumerate(pairs):
        Cp, Cm = C.copy(), C.copy()
        Cp[i, j] += h
        Cm[i, j] -= h
        vp, vm = block_values(Cp, mode), block_values(Cm, mode)
        G[:, at + k] = [(vp[n] - vm[n]) / (2 * h) for n in names]
    vals = block_values(C, mode)
    out = []
    for n, a in zip(names, G):
        moved = (np.abs(a @ null) / (np.linalg.norm(a) * np.maximum(np.linalg.norm(null, axis=0), 1e-300))
                 if null.size and np.linalg.norm(a) > 0 else np.zeros(0))
        det = not np.any(moved > 1e-6)
        se = float(np.sqrt(max(a @ cov @ a, 0.0))) if det else float("inf")
        out.append({"combination": f"{leg}.C.{n}", "value": vals[n], "se": se, "determined": bool(det)})
    return out


# --------------------------------------------------------------------------------------------- the result


@dataclass
class SensorMatrixResult:
    """The recalibrated matrix of one transducer: ``C`` (6, 6), ``C_se`` (6, 6: 0 where held at the factory value by
    the mode or by the ridge choice ``inf``, inf where undetermined), ``mode``, the ridge choice, the named combinations (:func:`named_combinations`),
    the per-axis residual RMS of the factory matrix and of ``C`` on the fit's samples."""

    mode: str
    C: np.ndarray
    C_se: np.ndarray
    ridge: RidgeChoice
    combinations: list[dict]
    rms_factory: np.ndarray
    rms: np.ndarray
    weighed_kg: float | None = None
    notes: list[str] = field(default_factory=list)
    #: the joint fit's ``(names, cov, null, se)`` over every parameter it estimated, ``D``'s entries (``{X}.C.<row>.<col>``)
    #: last: what ``calibration_cov.npz`` carries of the matrix (None when the factory matrix was kept)
    joint_cov: tuple | None = None

    def report(self) -> dict:
        """The keys of ``calibration.json`` (module docstring; null for inf by the writer)."""
        return {"sensor_matrix": self.C.tolist(), "sensor_matrix_se": np.where(np.isfinite(self.C_se), self.C_se, np.nan).tolist(),
                "sensor_matrix_mode": self.mode, "sensor_matrix_ridge": float(self.ridge.chosen) if np.isfinite(self.ridge.chosen) else "inf",
                "sensor_matrix_heldout": self.ridge.report(),
                "sensor_matrix_combinations": [{**c, "se": c["se"] if np.isfinite(c["se"]) else None} for c in self.combinations],
                "sensor_matrix_residual_rms_factory": self.rms_factory.tolist(), "sensor_matrix_residual_rms": self.rms.tolist()}


def _tilt_names(leg: str, groups) -> list[list[str]]:
    """Each tilt group's parameter names, as ``estimate.fit_free_load`` names them."""
    return [[f"{leg}.tilt.r{c}" for c in "xy"] if kd == "world" else [f"{leg}.{nm}.tilt.r{c}" for c in "xy"]
            if kd == "recording" else [f"{leg}.fixed.tilt.r{c}" for c in "xy"] for kd, nm in groups]


def fit_sensor_matrix(ds, res, s):
    """The free-load fit ``res`` (:class:`~ftcal_nlp.estimate.freeload.result.FreeLoadResult`) of dataset ``ds`` refitted with
    the sensor's matrix (``s.sensor_matrix``; module docstring): a new result whose offsets, load, tilts, mount, se
    and identifiability are the joint fit's, with ``sensor_matrix`` the :class:`SensorMatrixResult`; ``res`` itself
    with ``"none"``."""
    opt = options(s)
    if not opt.on:
        return res
    if opt.mode not in MODES:
        raise ValueError(f"sensor_matrix = {opt.mode!r}; expected one of {list(MODES)}")
    leg, load = res.leg, res.load
    data = free_load_data(ds, leg, s, load)
    t = ds.robot.transducers.get(leg)
    weighed = None if t is None else t.load_mass_kg
    pairs = pairs_of(opt.mode)
    at = {nm: i for i, nm in enumerate(res.names)}
    tnames = _tilt_names(leg, data.groups)
    # the tilts the first fit estimated (finite se) are estimated again: a gain error biases them there
    tilts = tuple(k for k, nm in enumerate(tnames) if nm[0] in at and np.isfinite(res.se[at[nm[0]]]))
    tilt0 = np.zeros((len(data.groups), 2))
    for k, (kd, nm) in enumerate(data.groups):
        v = res.tilt if kd == "world" else res.recording_tilts.get(nm) if kd == "recording" else None
        tilt0[k] = 0.0 if v is None else np.asarray(v, float)
    pr = Problem(data.y, data.a, data.group, data.K, np.asarray(load.mass_row, float), pairs, bool(s.mount_rotation), tilts,
                 weighed, opt.mass_rel_sd)
    start = State(res.offset.copy(), res.theta.copy(), tilt0, res.rotation.copy(), np.zeros(len(pairs)))
    W = 1.0 / np.asarray(res.sigma, float) ** 2
    # the exact symmetries (a gain common to the forces and the load's mass, ...) held at the factory value
    B, held = gauge(pr, start, W)
    pr = dataclasses.replace(pr, gauge=B, held=held)
    n, P = len(pr.y), pr.n_params
    # a first fit without ridge gives the weights: the factory fit's residual sd holds the very gain error fitted
    # here. No channel is weighted less than by the factory fit's sd: a first fit that trades one channel's residual
    # for another's (a collapse of C, on a model error) must not make its own channels cheap in the held-out score
    first = solve(pr, start, W, 0.0, opt.prior_weight)
    e = residual(pr, first)
    W = 1.0 / np.maximum(np.minimum((e**2).sum(axis=0) / max(n - P / 6.0, 1.0), 1.0 / W), 1e-300)
    choice = choose_ridge(pr, start, W, opt.ridge, opt.folds, opt.prior_weight)
    # the weight's fit from the fit without ridge and from the factory fit, the lower objective (one ridge): where the
    # load has undetermined directions only the tiny ridge moves, the factory fit's start keeps them at its values
    A0, _g0 = _system(pr, start, W)
    ridge = _ridge(pr, A0, choice.chosen, opt.prior_weight)
    ends = [solve(pr, p0, W, choice.chosen, opt.prior_weight, start, ridge) for p0 in (first, start)]
    st = min(ends, key=lambda q: _objective(pr, q, W, ridge, start, choice.chosen))
    e = residual(pr, st)
    rms = np.sqrt((e**2).mean(axis=0))
    rms_factory = np.sqrt((residual(pr, start) ** 2).mean(axis=0))
    # data-only information at the estimate (weights shrunk by the residuals' serial correlation, as estimate.py)
    _rho, inflation = serial_inflation(e, data.source, data.index)
    info, _g, _r = normal_equations(pr, st, W / inflation)
    mrow = _mass_row(pr)
    if mrow is not None:
        info = info + np.outer(mrow[0], mrow[0]) / mrow[1] ** 2
    names = ([f"{leg}.offset.{c}" for c in WRENCH] + [f"{leg}.{nm}" for nm in load.param_names]
             + [nm for k in tilts for nm in tnames[k]] + ([f"{leg}.mount.r{c}" for c in "xyz"] if pr.mount else [])
             + [f"{leg}.C.{WRENCH[i]}.{WRENCH[j]}" for i, j in pairs])
    x = _vector(pr, st, np.eye(3))
    cov, se, null, undetermined, determined, _ident = _covariance(info, np.ones(P, bool), names, x, s)
    C = st.C(pairs)
    C_se = np.zeros((6, 6))
    for k, (i, j) in enumerate(pairs):
        C_se[i, j] = se[pr.d_at + k]
    combos = named_combinations(opt.mode, C, pr.d_at, cov, null, leg)
    if not np.isfinite(choice.chosen):
        # the factory matrix kept: D is not a parameter of the calibration; the load's se are those without it (the
        # named combinations and their se above still say what the data could resolve)
        C_se[:] = 0.0
        k = pr.d_at
        cov, se, null, undetermined, determined, _ident = _covariance(info[:k, :k], np.ones(k, bool), names[:k], x[:k], s)
    lam = "inf (the factory matrix kept)" if not np.isfinite(choice.chosen) else f"{choice.chosen:g}"
    notes = [f"{leg}: sensor matrix ({opt.mode}) refitted in situ: ridge weight {lam} by {len(folds_of(n, opt.folds))}-fold "
             f"held-out error; residual RMS {np.array2string(rms_factory, precision=3)} with the factory matrix -> "
             f"{np.array2string(rms, precision=3)}"]
    und = [c["combination"] for c in combos if not c["determined"]]
    if und:
        why = "" if weighed is not None else " (no load_mass_kg: a gain common to the forces is the load's mass)"
        exact = f" (exactly: {', '.join(pr.held)}, symmetries of the model with the load)" if pr.held else ""
        notes.append(f"{leg}: sensor matrix: not determined by these data{why}: {', '.join(und)}; held at the factory "
                     f"value{exact}")
    if np.isfinite(choice.chosen):
        dev = block_gain_departure(C)
        if dev > PLAUSIBLE_GAIN_DEPARTURE:
            notes.append(f"{leg}: sensor matrix: the refitted matrix reads a block's gain {100 * dev:.0f} % off the "
                         f"factory's (C diagonal {np.array2string(np.diag(C), precision=3)}): more than a factory-calibrated "
                         "sensor drifts; more likely the matrix absorbs a load or effect the model lacks. Run the diagnosis "
                         "and check the matrix on another session (`holdout`) before using it")
    if not np.isfinite(choice.chosen):
        # the factory matrix kept: the calibration is the plain fit's, to the last digit (re-solving with C = I under
        # the first fit's residual weights would move the load and mount by up to 2 se on real data)
        smr = SensorMatrixResult(opt.mode, np.eye(6), C_se, choice, combos, rms_factory, rms_factory, weighed, notes)
        return dataclasses.replace(res, notes=list(res.notes) + notes, sensor_matrix=smr)
    smr = SensorMatrixResult(opt.mode, C, C_se, choice, combos, rms_factory, rms, weighed, notes,
                             (tuple(names), cov.copy(), null.copy(), se.copy()))
    return _merged(res, st, data.groups, names, cov, se, null, undetermined, determined, rms, np.sqrt(1.0 / W), smr)


def block_gain_departure(C: np.ndarray) -> float:
    """The largest ``|sigma - 1|`` over the singular values of ``C``'s force and torque diagonal blocks (a gain or shear
    of the readings; a rotation has singular values 1)."""
    sv = np.concatenate([np.linalg.svd(C[sl, sl], compute_uv=False) for sl in (slice(0, 3), slice(3, 6))])
    return float(np.max(np.abs(sv - 1.0)))


def _merged(res, st: State, groups, names, cov, se, null, undetermined, determined, rms, sigma, smr):
    """``res`` with the joint fit's values, their covariance block (by name; parameters of ``res`` the joint fit did
    not estimate keep theirs), the joint fit's identifiability, and ``sensor_matrix``."""
    at = {nm: i for i, nm in enumerate(res.names)}
    mine = np.array([i for i, nm in enumerate(names) if nm in at], int)
    theirs = np.array([at[names[i]] for i in mine], int)
    cov_n = res.cov.copy()
    cov_n[theirs, :] = 0.0
    cov_n[:, theirs] = 0.0
    cov_n[np.ix_(theirs, theirs)] = cov[np.ix_(mine, mine)]
    se_n = res.se.copy()
    se_n[theirs] = se[mine]
    null_n = np.zeros((len(res.names), null.shape[1]))
    null_n[theirs] = null[mine]
    tilt = res.tilt
    rec_tilts = dict(res.recording_tilts)
    for k, (kd, nm) in enumerate(groups):
        if kd == "world" and tilt is not None:
            tilt = st.tilt[k].copy()
        elif kd == "recording" and nm in rec_tilts:
            rec_tilts[nm] = st.tilt[k].copy()
    kept = [u for u in res.undetermined if "tilt" in u and not any(n in u for n in names)]
    return dataclasses.replace(res, offset=st.o.copy(), theta=st.theta.copy(), rotation=st.E.copy(), cov=cov_n, se=se_n,
                               null=null_n, undetermined=tuple(list(undetermined) + kept), determined=tuple(determined),
                               rms=rms, sigma=sigma, notes=list(res.notes) + smr.notes, sensor_matrix=smr, tilt=tilt,
                               recording_tilts=rec_tilts)


# ------------------------------------------------------------------------------------ validation across sessions


def session_rms(res, ds, s) -> np.ndarray:
    """Per-axis RMS (6,) of the residual in raw units ``r - o - C^-1 w`` of fit ``res`` (with its matrix, if any) on
    the quasi-static samples of another session ``ds`` of the same transducer and load (raw units: where the
    readings' noise is; the corrected residual ``C (r - o) - w`` shrinks with ``C``, and a matrix shrunk on a model
    error looked better than the factory's); the session's offset is its own (the mean residual taken off: offsets
    move between sessions, the matrix and the load do not); gravity with ``res``'s world tilt."""
    sm = res.sensor_matrix
    mode = "none" if sm is None else sm.mode
    data = free_load_data(ds, res.leg, s, res.load)
    pairs = pairs_of(mode)
    C = np.eye(6) if sm is None else sm.C
    tilt = np.zeros((len(data.groups), 2))
    for k, (kd, _nm) in enumerate(data.groups):
        if kd == "world" and res.tilt is not None:
            tilt[k] = res.tilt
    pr = Problem(data.y, data.a, data.group, data.K, np.asarray(res.load.mass_row, float), pairs, False)
    st = State(res.offset, res.theta, tilt, res.rotation, np.array([C[i, j] - (i == j) for i, j in pairs]))
    e = residual(pr, st)
    e = e - e.mean(axis=0)
    return np.sqrt((e**2).mean(axis=0))


def validate_across_sessions(base, matrix, test_ds, s):
    """Their Table III (Andrade Chavez et al. 2016): ``base`` and ``matrix``, one transducer's fits on one session
    (``fit_free_loads`` with ``sensor_matrix = "none"`` and with a mode), and per axis the RMS error of each on
    ``test_ds`` (another recording or dataset; :func:`session_rms`), the matrix's as a percentage of the factory's
    (factory = 100 %). A :class:`pandas.DataFrame` indexed by axis (``fx``..``tz``); :func:`table_text` writes it."""
    import pandas as pd

    mode = "none" if matrix.sensor_matrix is None else matrix.sensor_matrix.mode
    a, b = session_rms(base, test_ds, s), session_rms(matrix, test_ds, s)
    return pd.DataFrame({"factory_rms": a, f"{mode}_rms": b, f"{mode}_percent": 100.0 * b / a},
                        index=pd.Index(list(WRENCH), name="axis"))


def table_text(df) -> str:
    """A markdown table of :func:`validate_across_sessions` (N for forces, N*m for torques; factory = 100 %)."""
    cols = list(df.columns)
    lines = ["| axis | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for ax, row in df.iterrows():
        lines.append(f"| {ax} | " + " | ".join(f"{v:.1f}" if c.endswith("percent") else f"{v:.4g}" for c, v in row.items()) + " |")
    return "\n".join(lines)
