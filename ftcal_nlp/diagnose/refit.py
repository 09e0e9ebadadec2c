"""Joint refit: the named effect added to the whole calibration problem, cross-validated.

Attribution (``attribute.py``) scores each candidate face by face; this module
refits the calibration *with* the effect, so that "how far it shrinks" is the
held-out residual of one joint model on every recording kind, beside its floor.

* hanging (report eqs. 4-7): the fitted model's residual ``e_i`` of a sample is
  regressed on the effect's hanging features ``X_i`` together with the
  calibration's own first-order directions (a Gauss-Newton step from the
  calibrated optimum, exact for the parameters that enter linearly):

      e_i ~ J_i dtheta_h + X_i beta,   per leg  J_i = [ I_6 | -a_i / m g | T_ij | C_i(phi) ]

  with ``a_i = [f; r x f]`` the modelled applied wrench, ``I_6`` the offsets,
  ``-a_i / m g`` the leg weight, ``T_ij = [[f]x; [r]x [f]x]`` the hanging tilt of
  recording j (``delta x f``) and ``C_i = [0; [f]x h(phi)^T]`` the CoM curve's
  correction in a few harmonics ``h = (1, cos phi, sin phi, cos 2phi, sin 2phi)``.
  Floor-standardised, accumulated per fold (contiguous time blocks, as
  ``linear_fit.py``); the "before" is the same regression without ``X``, so both
  sides spend the calibration's parameters on the same folds. With the effect, the
  step is iterated first (Gauss-Newton, :func:`relinearise`): each step moves the
  offsets, the leg weight (``m g <- m g - b_m``), the recording's tilt (``f <- exp([-b_j]) f``)
  and the CoM curve exactly, and recomputes the residual, until nothing moves by
  more than ``GN_TOL`` floors. An effect the calibrated fit absorbed (a warm-up of a
  few N reads as tilts of tens of degrees) leaves the one-step leg weights off by
  a few percent of its size; the iterated ones are at truth (``tests/test_joint.py``).
  The effect's flexible hanging faces (``Effect.joint_variants``) are chosen here by
  the held-out residual.
* standing (eq. 8 with the balance of ``balance.py``): the selected error model
  plus the effect's standing face (``standing_fit.py``) refit on the poses with
  the offsets and leg weights of the joint hanging fit as its prior; the same
  k-fold poses as the attribution. "Before" is the calibration model alone. Parameters the hanging face
  estimated too (``Effect.standing_prior_from_hanging``: one sensor matrix read on the leg's weight and on the
  ground's force) may enter with the hanging fit's information on the combinations its face says the hanging fixes
  (``LinearFace.determined``) as a prior (``standing_fit.EtaPrior``); the standing fit is made with and without it
  and the one whose held-out standing and swing residuals (floor units) are smaller is kept: a hanging estimate a few
  se off along a direction its nuisance nearly takes can pull the poses, and without it few poses may leave the
  rotations loose. An effect whose hanging face moves the offsets as they are (``Effect.joint_holds_offset_shift``)
  has the forces of the standing offset shift held at zero: free, that constant force in B turns with a rotation
  common to every transducer.
* walking swing: a foot in the air predicted with the joint calibration (the
  standing fit's rotations, the joint offsets and weights; ``linear_fit.recalibrate``)
  plus the effect's swing face, time-block folds.

The result carries, per kind and component, the held-out RMS before and after
and the floor of ``views.py`` (never estimated from these residuals), the joint
calibration (``Calibration``, writable as ``calibration.json``) and the effect's
parameters with standard errors, so that :mod:`ftcal_nlp.effects.correction`
can apply the effect's reading corrections when correcting a recording.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..core.calibration import Calibration
from ..core.geometry import rotvec_to_rotation, skew
from ..estimate.selection import fold_indices
from ..core.solver import SolverError
from ..effects.combined import Combined
from ..effects.faces import AugContext, HangingLeg
from ..effects.unit import Effect
from .linear_fit import RIDGE, recalibrate, score_linear, time_folds
from ..core.balance import K_DIAG
from .standing_fit import AugmentedProblem, EtaPrior
from .views import LegSeries, Views

log = logging.getLogger(__name__)

FULL_MODEL = "full"    # the most flexible built-in error model (rotations, translations free)
WORSE_RATIO = 1.2      # a kind the joint model predicts this much worse than the calibration alone (and than its floor)
COM_HARMONICS = 2       # the CoM curve's correction: constant plus this many harmonics of phi
GN_ITERATIONS = 8       # Gauss-Newton steps of the joint hanging fit (relinearise)
GN_TOL = 1e-3           # ... until no residual moves by more than this many floors
GN_SAMPLES = 20000      # ... taken on about this many hanging samples (every n-th)


@dataclass(frozen=True)
class KindRefit:
    """One recording kind under the joint refit: held-out RMS (6,) before / after, floor (6,), samples.

    ``blocks``: the held-out sum of squares after, in floor units, block by block (standing: each pose, in the
    calibration's floor ``views.standing.floor``, the same for every joint refit, not the refit's own ``floor``;
    hanging: each fold's time block of each leg), so that two joint refits on the same folds can be compared pairwise
    (``hexchain.swap_better``); None where not kept (the swing legs)."""

    kind: str
    rms_before: np.ndarray
    rms_after: np.ndarray
    floor: np.ndarray
    n: int
    blocks: np.ndarray | None = None

    def to_json_dict(self) -> dict:
        return {"heldout_rms_before": [float(v) for v in self.rms_before], "heldout_rms_after": [float(v) for v in self.rms_after],
                "noise_floor": [float(v) for v in self.floor], "n": int(self.n)}


@dataclass(frozen=True)
class JointRefit:
    """The joint calibration with the effect: per-kind shrinkage, the calibration, the effect's parameters.

    ``parameters``: name -> (value, se) of the effect (standing face names as in
    ``effect_parameters``; hanging-face names prefixed ``hanging:``); ``calibration`` the
    refit calibration (offsets and leg weights from the joint hanging fit, or the standing
    model's offsets where it fits them; rotations and, with the exact balance, positions
    from the joint standing fit); ``eta`` the standing face's parameter vector (scaled units
    of ``Effect.standing_params``), what :mod:`ftcal_nlp.effects.correction` evaluates, and
    ``eta_cov`` its covariance (what the correction's standard errors carry).
    """

    effect: str
    kinds: dict
    calibration: Calibration | None
    parameters: dict
    eta: np.ndarray | None
    t_ref: float
    notes: tuple = ()
    variant: dict = field(default_factory=dict)
    eta_cov: np.ndarray | None = None
    members: tuple = ()          # several effects (a Combined): per member (name, variant, eta slice, parameters)
    eta_undetermined: np.ndarray | None = None   # (len(eta),) bool: an eta entry the standing poses do not determine

    def to_json_dict(self) -> dict:
        return {"effect": self.effect, "variant": dict(self.variant), "kinds": {k: v.to_json_dict() for k, v in self.kinds.items()},
                "parameters": {n: {"value": float(v), "se": float(s) if np.isfinite(s) else None} for n, (v, s) in self.parameters.items()},
                **({"notes": list(self.notes)} if self.notes else {})}

    def effect_block(self) -> dict:
        """What ``calibration.json`` carries about the effect (``effects/correction.py`` reads it).

        Several effects fitted together (``effects.combined.Combined``, the hexapod chain's links): the name is
        ``"a+b"``, ``variant`` per member, ``eta`` / ``eta_cov`` / ``parameters`` the joint ones (names
        ``<member>:<name>``), and ``members`` lists each member as a single effect's block would hold it: its
        name, variant, its slice of the joint ``eta`` (``eta_slice`` [start, stop) and the values, ``eta``) and its
        parameters with se, prefix taken off (hanging ones ``hanging:<name>``), as ``Combined.split`` and
        ``Combined.member_parameters`` give them. ``eta_undetermined`` (when any): the ``eta`` entries the standing
        poses do not determine (se inf), whose ``eta_cov`` rows are the pseudo-inverse's, not a variance: a
        correction they enter has no finite se (``effects/correction.py``)."""
        cov = {} if self.eta_cov is None else {"eta_cov": np.nan_to_num(np.asarray(self.eta_cov, float)).tolist()}
        eta = [float(v) for v in (self.eta if self.eta is not None else [])]
        par = lambda d: {n: {"value": float(v), "se": float(s) if np.isfinite(s) else None} for n, (v, s) in d.items()}  # noqa: E731
        out = {"name": self.effect, "variant": dict(self.variant), "eta": eta, "t_ref_s": float(self.t_ref), **cov,
               "parameters": par(self.parameters)}
        if self.eta_undetermined is not None and np.any(self.eta_undetermined):
            out["eta_undetermined"] = [bool(u) for u in self.eta_undetermined]
        if self.members:
            out["members"] = [{"name": n, "variant": dict(v), "eta_slice": [sl.start, sl.stop], "eta": eta[sl.start : sl.stop],
                               "parameters": par(pm)} for n, v, sl, pm in self.members]
        return out


def combined_members(effect: Effect, actx: AugContext, params: dict) -> tuple:
    """Per member of a :class:`Combined` ``effect`` ``(name, variant, its slice of eta, its parameters)``, as
    ``Combined.split`` and ``Combined.member_parameters`` give them (``JointRefit.members``); () for one effect."""
    if not isinstance(effect, Combined):
        return ()
    return tuple((m.name, dict(m.variant), sl, pm) for m, sl, pm in zip(effect.members, effect.split(actx), effect.member_parameters(params)))


# ----------------------------------------------------------------------------- hanging


def com_harmonics(phi: np.ndarray, harmonics: int = COM_HARMONICS) -> np.ndarray:
    """``h(phi)`` (N, 1 + 2 harmonics): ``1, cos phi, sin phi, cos 2 phi, ...`` (the CoM curve's correction basis)."""
    h = [np.ones(len(phi))]
    for m in range(1, harmonics + 1):
        h += [np.cos(m * phi), np.sin(m * phi)]
    return np.stack(h, axis=1)


def hanging_nuisance(l: HangingLeg, n_rec: int, harmonics: int = COM_HARMONICS, extra: np.ndarray | None = None
                     ) -> np.ndarray:
    """``J_i`` of the module docstring for one leg, channels first (columns: offsets, weight, each recording's tilt,
    the CoM curve's harmonics), (6, q, N) with the samples contiguous (then ``extra`` (N, 6, m), a face's columns):
    filled in place, since the joint refit forms it for every leg at every Gauss-Newton step and its per-fold
    products are then batched BLAS on views (no copy of the (N, 6, q) array per fold)."""
    N = len(l.t)
    Ft = skew(l.f).transpose(1, 2, 0)                                   # (3, 3, N) [f]x
    rFt = np.einsum("nij,njk->ikn", skew(l.r), skew(l.f))               # (3, 3, N) [r]x [f]x
    H = com_harmonics(l.phi, harmonics).T
    qn = 7 + 3 * n_rec + 3 * len(H)
    J = np.zeros((6, qn + (0 if extra is None else extra.shape[2]), N))
    J[np.arange(6), np.arange(6), :] = 1.0
    J[:, 6, :] = (-l.applied / l.mg).T
    for j in range(n_rec):
        m = l.rec == j
        c = 7 + 3 * j
        J[:3, c : c + 3, :] = Ft * m
        J[3:, c : c + 3, :] = rFt * m
    c0 = 7 + 3 * n_rec
    for j, hj in enumerate(H):
        J[3:, c0 + 3 * j : c0 + 3 * j + 3, :] = Ft * hj
    if extra is not None:
        J[:, qn:, :] = extra.transpose(1, 2, 0)
    return J


def _nuisance_update(l: HangingLeg, b: np.ndarray, n_rec: int, harmonics: int = COM_HARMONICS) -> HangingLeg:
    """``l`` moved by the nuisance step ``b`` (the columns of :func:`hanging_nuisance`), exactly.

    The regression says the model should add ``J b``: offsets ``+ b_o``; leg weight ``- b_m``
    (column ``-a / m g``); tilt of recording j ``f <- exp([-b_j]) f`` (column ``[f]x``:
    ``f + f x b_j``); CoM curve ``r <- r - h(phi) b_r`` (column ``[f]x h``: ``(r - h b_r) x f``).
    The residual ``e`` follows the new model exactly (no linearisation left in it)."""
    mg_new = l.mg - b[6]
    f = l.f * (mg_new / l.mg)
    for j in range(n_rec):
        sel = l.rec == j
        if sel.any():
            f[sel] = f[sel] @ rotvec_to_rotation(-b[7 + 3 * j : 10 + 3 * j]).T
    c0 = 7 + 3 * n_rec
    r = moved_com(l.r, l.phi, b[c0: c0 + 3 * (1 + 2 * harmonics)].reshape(-1, 3))
    a_new = np.hstack([f, np.cross(r, f)])
    e = l.e - (a_new - l.applied) - b[:6][None, :]
    return replace(l, e=e, f=f, r=r, mg=float(mg_new))


def moved_com(r: np.ndarray, phi: np.ndarray, d_r: np.ndarray) -> np.ndarray:
    """The leg CoM ``r`` (..., 3) at shaft angles ``phi`` (...) moved by the joint hanging fit's correction ``d_r``
    (1 + 2 harmonics, 3) of one leg: ``r - h(phi) d_r`` (:func:`_nuisance_update`'s move of the curve)."""
    h = com_harmonics(np.ravel(phi), len(d_r) // 2)
    return r - (h @ d_r).reshape(np.shape(r))


def relinearise(series: LegSeries, face_fn) -> tuple[LegSeries, np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton on the hanging model with the effect's face: the series at the joint optimum.

    The calibrated hanging fit absorbed the effect (a warm-up of a few N reads as tilts of
    tens of degrees and a biased leg weight); one linear step from there leaves that
    nonlinearity in the leg weights, which the opposite-pair differences then carry into the
    standing balance. Returns the moved series and the accumulated offset (K, 6), leg
    weight (K,) and CoM curve (K, 1 + 2 harmonics, 3; :func:`moved_com`) shifts."""
    legs = list(series.legs)
    K = max(l.k for l in legs) + 1
    n_rec = int(max(l.rec.max() for l in legs)) + 1
    d_off, d_mg = np.zeros((K, 6)), np.zeros(K)
    d_r = np.zeros((K, 1 + 2 * COM_HARMONICS, 3))
    c0 = 7 + 3 * n_rec
    fl = np.where(series.floor > 0, series.floor, 1.0)
    # The steps are taken on every stride-th sample (the nonlinearity is in a few parameters, not in
    # the noise); the full series follows each step, and the held-out fit uses all of it
    stride = max(1, series.n // GN_SAMPLES)
    sub = [_every(l, stride) for l in legs]
    for _ in range(GN_ITERATIONS):
        face = face_fn(sub) if face_fn is not None else None
        A, b, _, qn, _ = _normal_equations(sub, face, [np.zeros(len(l.t), int) for l in sub], 1, fl, True)
        reg = RIDGE * max(np.trace(A[0]) / len(A[0]), 1e-300) * np.eye(len(A[0]))
        beta = np.linalg.solve(A[0] + reg, b[0])
        step = 0.0
        for i, l in enumerate(sub):
            bl = beta[l.k * qn : (l.k + 1) * qn]
            moved = _nuisance_update(l, bl, n_rec)
            step = max(step, float(np.max(np.abs(moved.e - l.e) / fl[l.k])))
            sub[i] = moved
            legs[i] = _nuisance_update(legs[i], bl, n_rec)
            d_off[l.k] += bl[:6]
            d_mg[l.k] -= bl[6]
            d_r[l.k] += bl[c0: c0 + d_r.shape[1] * 3].reshape(-1, 3)
        if step < GN_TOL:
            break
    return replace(series, legs=legs), d_off, d_mg, d_r


def _every(l: HangingLeg, stride: int) -> HangingLeg:
    """Every ``stride``-th sample of ``l``."""
    if stride == 1:
        return l
    cut = slice(None, None, stride)
    return replace(l, e=l.e[cut], t=l.t[cut], phi=l.phi[cut], omega=l.omega[cut], rec=l.rec[cut], f=l.f[cut], r=l.r[cut],
                   r_dd=l.r_dd[cut])


def _normal_equations(legs, face, fidx, folds: int, fl: np.ndarray, with_effect: bool):
    """Per-fold normal equations of the floor-standardised joint regression (nuisance ``J`` of every
    leg, then the face's parameters): ``A`` (folds, n, n), ``b`` (folds, n), the per-leg parts the
    held-out sums need, ``qn`` nuisance columns per leg and ``n`` in all."""
    K = max(l.k for l in legs) + 1
    n_rec = int(max(l.rec.max() for l in legs)) + 1
    qn = 7 + 3 * n_rec + 3 * (1 + 2 * COM_HARMONICS)
    q = face.blocks[0].shape[2] if face is not None else 0
    m_eff = face.size(K) if face is not None else 0
    n_tot = K * qn + m_eff
    A = np.zeros((folds, n_tot, n_tot))
    b = np.zeros((folds, n_tot))
    parts = []
    for i, l in enumerate(legs):
        use_face = with_effect and face is not None
        Xt = hanging_nuisance(l, n_rec, extra=face.blocks[i] if use_face else None)     # (6, q, N)
        cols = list(range(l.k * qn, (l.k + 1) * qn))
        if use_face:
            if face.cols is not None:   # stacked faces (``LinearFace.cols``)
                cols += list(K * qn + face.index(i, l.k))
            else:
                off = K * qn + (l.k * q if face.per_leg else 0)
                cols += list(range(off, off + q))
        idx = np.asarray(cols)
        s = fl[l.k]
        yt = np.ascontiguousarray(l.e.T)                                            # (6, N)
        Af = np.zeros((folds, 6, len(idx), len(idx)))
        bf = np.zeros((folds, 6, len(idx)))
        yy = np.zeros((folds, 6))
        # each run of samples of one fold (a fold is a time block of every recording) is a view
        fi = np.asarray(fidx[i])
        cut = np.r_[0, np.flatnonzero(np.diff(fi) != 0) + 1, len(fi)]
        for lo, hi in zip(cut[:-1], cut[1:]):
            f, Xf = fi[lo], Xt[:, :, lo:hi]
            Af[f] += Xf @ Xf.transpose(0, 2, 1)
            bf[f] += (Xf @ yt[:, lo:hi, None])[..., 0]
            yy[f] += (yt[:, lo:hi] ** 2).sum(axis=1)
        # floor-standardised per channel afterwards (the products are linear in each channel's scale)
        Af /= (s**2)[None, :, None, None]
        bf /= (s**2)[None, :, None]
        yy /= (s**2)[None, :]
        A[:, idx[:, None], idx[None, :]] += Af.sum(axis=1)
        b[:, idx] += bf.sum(axis=1)
        parts.append((idx, Af, bf, yy, s))
    return A, b, parts, qn, n_tot


def hanging_joint(series: LegSeries, face_fn, folds: int, before: np.ndarray | None = None
                  ) -> tuple[KindRefit, dict, np.ndarray, np.ndarray, int, np.ndarray, np.ndarray | None]:
    """Joint hanging regression (module docstring) with and without the effect's face.

    ``face_fn(legs) -> LinearFace`` (``Effect.hanging_features``) or None. With the face, the
    series is first moved to the joint optimum (:func:`relinearise`); the held-out residual is
    then that of the regression at the optimum. Returns the kind's refit, the effect's hanging
    parameters ``name -> (value, se)``, the offsets' shifts (K, 6), the leg weights' shifts (K,) N
    (both from the joint fit with the effect, on all samples), the per-leg number of
    nuisance parameters, the CoM curves' shifts (K, 1 + 2 harmonics, 3; :func:`moved_com`) and the information of the
    effect's hanging parameters (in the order of ``params``, the nuisance marginalised: the Schur complement of the
    normal equations, over the residual variance ratio; None without a face), what the standing fit takes as their
    prior (``standing_fit.EtaPrior``). ``before``: the held-out RMS (6,) without the face, if known (it is the same for
    every face).
    """
    moved, d_off0, d_mg0, d_r0 = relinearise(series, face_fn) if face_fn is not None else (series, 0.0, 0.0, 0.0)
    legs0 = series.legs
    legs = moved.legs
    face = face_fn(legs) if face_fn is not None else None
    K = max(l.k for l in legs) + 1
    fl = np.where(series.floor > 0, series.floor, 1.0)
    fidx = time_folds(series, folds)

    def cv(A, b, parts, active, n_tot):
        A_tot, b_tot = A.sum(0), b.sum(0)
        scale = max(np.trace(A_tot[np.ix_(active, active)]) / max(len(active), 1), 1e-300)
        reg = RIDGE * scale * np.eye(n_tot)
        ss = np.zeros(6)
        blocks = np.zeros((folds, len(parts)))   # floor units, per fold and leg (KindRefit.blocks)
        for f in range(folds):
            beta = np.zeros(n_tot)
            Af, bf = A_tot - A[f] + reg, b_tot - b[f]
            beta[active] = np.linalg.solve(Af[np.ix_(active, active)], bf[active])
            for i, (idx, Afl, bfl, yy, s) in enumerate(parts):
                bl = beta[idx]
                ssf = yy[f] - 2 * bfl[f] @ bl + np.einsum("m,cmn,n->c", bl, Afl[f], bl)
                ss += ssf * s**2
                blocks[f, i] = ssf.sum()
        beta = np.zeros(n_tot)
        M = (A_tot + reg)[np.ix_(active, active)]
        beta[active] = np.linalg.solve(M, b_tot[active])
        cov = np.full((n_tot, n_tot), np.nan)
        cov[np.ix_(active, active)] = np.linalg.inv(M)
        return ss, beta, cov, blocks.ravel()

    n_all = series.n
    if before is None:
        A0, b0, p0, qn, n0 = _normal_equations(legs0, None, fidx, folds, fl, False)
        before = np.sqrt(cv(A0, b0, p0, np.arange(n0), n0)[0] / series.n)
    A1, b1, p1, qn, n_tot = _normal_equations(legs, face, fidx, folds, fl, True)
    ss1, beta, cov, blocks = cv(A1, b1, p1, np.arange(n_tot), n_tot)
    floor = np.sqrt(np.mean(np.square(series.floor[[l.k for l in legs]]), axis=0))
    kind = KindRefit(series.kind, before, np.sqrt(ss1 / n_all), floor, n_all, blocks)
    params = {}
    info = None
    if face is not None:
        # floor-standardised regression: the parameters' covariance is (X^T X)^-1 up to the
        # residual variance ratio, which the held-out excess measures
        ratio = max(float(np.mean(ss1 / n_all / np.where(floor > 0, floor, 1.0) ** 2)), 1.0)
        for j, name in enumerate(face.names):
            c = K * qn + j
            params[f"hanging:{name}"] = (float(beta[c]), float(np.sqrt(cov[c, c] * ratio)))
        # the face's information with the nuisance marginalised (no ridge on the face: what the hanging legs do not
        # determine stays zero; the nuisance's own ridge only keeps its solve defined)
        A_tot, nn = A1.sum(0), K * qn
        A_nn = A_tot[:nn, :nn] + RIDGE * max(np.trace(A_tot) / n_tot, 1e-300) * np.eye(nn)
        info = (A_tot[nn:, nn:] - A_tot[nn:, :nn] @ np.linalg.solve(A_nn, A_tot[:nn, nn:])) / ratio
        if face.determined is not None:   # only what the face says the hanging fixes apart from the nuisance
            Q = face.determined
            info = Q @ (Q.T @ info @ Q) @ Q.T
    d_off = np.zeros((K, 6)) + d_off0
    d_mg = np.zeros(K) + d_mg0
    d_r = np.zeros((K, 1 + 2 * COM_HARMONICS, 3)) + d_r0
    c0 = 7 + 3 * (int(max(l.rec.max() for l in legs)) + 1)
    for l in legs:
        d_off[l.k] += beta[l.k * qn : l.k * qn + 6]
        d_mg[l.k] -= beta[l.k * qn + 6]   # the column is -a / m g: the model's derivative is +a / m g
        d_r[l.k] += beta[l.k * qn + c0 : l.k * qn + c0 + d_r.shape[1] * 3].reshape(-1, 3)
    return kind, params, d_off, d_mg, qn, d_r, info


# ----------------------------------------------------------------------------- standing


def _hold_shared(prob: AugmentedProblem, effect: Effect, prior: Calibration, robot, hanging: dict) -> None:
    """Hold the standing-face parameters that the hanging face estimated at those values (one parameter,
    one value across faces: ``Effect.standing_from_hanging``)."""
    if not hanging or prob.params is None:
        return
    ctx = AugContext.from_calibration(prior, tuple(robot.legs), robot.nominal_rotations())
    for i, v in effect.standing_from_hanging(hanging, ctx).items():
        j = prob.n_model + i
        v = float(np.clip(v, prob.lbx[j], prob.ubx[j]))
        prob.lbx[j] = prob.ubx[j] = prob.x0[j] = v


def _hold_offset_shift(prob: AugmentedProblem) -> None:
    """Hold the forces of the standing fit's offset shift ``dw_o`` at zero (``Effect.joint_holds_offset_shift``): the
    joint hanging fit's offsets, fitted beside the effect's hanging face, already hold what it did while hanging.
    Free, that constant force in B is one with a rotation common to every transducer (it turns ``sum_k R_k f_k = M g
    z`` by a constant): on the shared sample with a gain matrix the joint rotations went 0.15-0.25 deg off together
    and a swing leg's torques stayed 1.4-2.1x their floor; held, 1.0-1.06x."""
    if prob.params is None:
        return
    for j, n in enumerate(prob.params.names):
        if n.startswith(("dw_o.fx", "dw_o.fy", "dw_o.fz")):
            i = prob.n_model + j
            prob.lbx[i] = prob.ubx[i] = prob.x0[i] = 0.0


def hanging_eta_prior(effect: Effect, prior: Calibration, robot, hanging: dict, info: np.ndarray | None,
                      sv) -> EtaPrior | None:
    """The joint hanging fit's estimate of the standing-face parameters it shares (``Effect.standing_prior_from_hanging``)
    as the standing fit's prior (``standing_fit.EtaPrior``): its information ``info`` (order of ``hanging``) scaled by
    the standing noise per K-weighted component, ``mean_i K_ii s_i^2`` with ``s`` the floor without its
    cross-validation inflation (``views.py``)."""
    if info is None or not hanging:
        return None
    ctx = AugContext.from_calibration(prior, tuple(robot.legs), robot.nominal_rotations())
    names = list(hanging)
    pairs = [(i, names.index(n)) for i, n in sorted(effect.standing_prior_from_hanging(ctx).items()) if n in hanging]
    if not pairs:
        return None
    idx, hj = np.array([i for i, _ in pairs]), np.array([j for _, j in pairs])
    infl = np.asarray(sv.floor_parts.get("cv_inflation", np.ones(6)), float)
    s2 = np.asarray(sv.floor, float) ** 2 / np.where(infl > 0, infl, 1.0)
    sigma2 = float(np.mean(K_DIAG * s2))
    return EtaPrior(idx, np.array([hanging[names[j]] for j in hj]), sigma2 * info[np.ix_(hj, hj)])


def shifted_prior(prior: Calibration, d_off: np.ndarray, d_mg: np.ndarray, d_r: np.ndarray | None = None) -> Calibration:
    """``prior`` with the offsets, leg weights and (``d_r``, :func:`moved_com`) CoM curves moved by the joint hanging
    fit."""
    legs = {}
    for k, leg in enumerate(prior.leg_names):
        l = prior.legs[leg]
        com = np.asarray(l.com_xyz, float)
        if d_r is not None and np.any(d_r[k]) and len(l.com_phi) > 1:
            com = moved_com(com, np.asarray(l.com_phi, float), d_r[k])
        legs[leg] = replace(l, offset=np.asarray(l.offset, float) + d_off[k], leg_weight_N=float(l.leg_weight_N + d_mg[k]),
                            com_xyz=com)
    return replace(prior, legs=legs)


# ----------------------------------------------------------------------------- the joint refit


def joint_refit(views: Views, effect: Effect, model: Any, prior: Calibration, calibration: Calibration, robot,
                balance: str, *, folds: int, seed: int, x_start: np.ndarray | None = None) -> JointRefit:
    """The calibration refit with ``effect`` on every recording kind of ``views`` (module docstring).

    ``prior``: the hanging calibration the standing fit starts from; ``calibration``: the
    finished calibration (what the joint calibration replaces values of).
    """
    legs = tuple(robot.legs)
    kinds: dict[str, KindRefit] = {}
    params: dict[str, tuple[float, float]] = {}   # name -> (value, se)
    notes: list[str] = []
    hang_values: dict = {}
    d_off, d_mg = np.zeros((len(legs), 6)), np.zeros(len(legs))
    d_r = h_info = None
    cands = effect.joint_variants()
    effect = cands[0]
    if views.hanging is not None:
        best_h = None
        for v in cands:   # the face's flexibility, chosen by the hanging held-out residual (in floor units)
            res = hanging_joint(views.hanging, v.hanging_features, folds, None if best_h is None else best_h[2][0].rms_before)
            z = float(np.sum((res[0].rms_after / np.where(res[0].floor > 0, res[0].floor, 1.0)) ** 2))
            if best_h is None or z < best_h[0]:
                best_h = (z, v, res)
        assert best_h is not None, "joint_variants() is never empty (cands[0] above)"
        _, effect, (kinds["hanging"], hp, d_off, d_mg, _, d_r, h_info) = best_h
        params.update(hp)
        hang_values = {n[len("hanging:"):]: v for n, (v, _) in hp.items()}
    # the joint hanging fit's offsets, leg weights and CoM curves carry into the standing and swing kinds (an effect
    # the calibrated hanging fit absorbed, e.g. a gain matrix on the leg's weight read as tilt, bent the CoM curve:
    # a swing leg's torques then kept 2.6x their floor)
    prior_j = shifted_prior(prior, d_off, d_mg, d_r)
    cal = shifted_prior(calibration, d_off, d_mg, d_r)
    sv = views.standing
    st: _StandingJoint | None = None
    if sv is not None:
        eta_prior = hanging_eta_prior(effect, prior_j, robot, hang_values, h_info, sv)
        cand_st = []
        for ep in [None] + ([eta_prior] if eta_prior is not None else []):
            c = _standing_joint(sv, effect, model, prior, prior_j, cal, robot, balance, hang_values, ep, d_r, folds, seed,
                                x_start)
            if c.kind is not None and views.swing is not None:
                c = replace(c, swing=_swing_joint(views.swing, effect, calibration, c.cal, legs, folds, hang_values, d_r))
            cand_st.append(c)
        # With a prior (the hanging fit's estimate of the same matrix) or without, chosen by the held-out residual of
        # the kinds it did not see fitted to it, standing and swing (floor units): a hanging estimate a few se off
        # along a direction the hanging nuisance nearly takes pulls the standing poses (the shared sample: standing tx
        # 1.06 -> 1.3x with it), while without it the poses may not fix the rotations (100 poses: swing ty 1.8x)
        st = min((c for c in cand_st if c.kind is not None), key=lambda c: c.z, default=cand_st[0])
        notes += list(st.notes)
        if len(cand_st) > 1 and st.kind is not None:
            other = [c for c in cand_st if c is not st and c.kind is not None]
            zs = ", ".join(f"{'with' if c.prior else 'without'} it {c.z:.1f}" for c in [st, *other])
            notes.append(f"the joint hanging fit's estimate of {effect.name}'s parameters it fixes "
                         f"({'taken' if st.prior else 'not taken'} as the standing fit's prior: held-out standing + swing, "
                         f"sum of squares over the floor, {zs})")
        if st.kind is not None:
            kinds["standing"] = st.kind
            params.update(st.params)
            cal = st.cal
    if views.swing is not None:
        kinds["walking swing"] = st.swing if st is not None and st.swing is not None else \
            _swing_joint(views.swing, effect, calibration, cal, legs, folds, hang_values, d_r)
    worse = [k for k, v in kinds.items() if np.any(v.rms_after > WORSE_RATIO * np.maximum(v.rms_before, v.floor))]
    if worse:
        # the effect's face does not fit these recordings' shape (issue 13, item 4): say so rather
        # than hand `correct` a calibration that is worse there
        notes.append(f"the joint model predicts the {', '.join(worse)} recordings worse than the calibration alone: the "
                     f"effect's face does not follow the data there; correcting with calibration_with_effect.json is not advised")
    cal = replace(cal, model=st.model if st is not None and st.kind is not None else cal.model)
    out = JointRefit(effect.name, kinds, cal, params, st.eta if st else None, float(views.t_ref), tuple(notes), dict(effect.variant),
                     st.eta_cov if st else None, st.members if st else (), st.eta_und if st else None)
    meta = dict(cal.meta)
    meta["effect"] = {**out.effect_block(), "R_nominal": np.asarray(robot.nominal_rotations(), float).tolist()}
    return replace(out, calibration=replace(cal, meta=meta))


@dataclass(frozen=True)
class _StandingJoint:
    """One joint standing fit (``_standing_joint``) and the swing it predicts: the kind (None: the fit failed), the
    calibration with its rotations, positions, offsets, the effect's standing parameters, and ``z`` the held-out sum of
    squares over the floor of standing and swing (what chooses between fits)."""

    kind: KindRefit | None
    cal: Calibration
    params: dict
    eta: np.ndarray | None
    eta_cov: np.ndarray | None
    eta_und: np.ndarray | None
    members: tuple
    model: Any
    notes: tuple
    prior: bool
    swing: KindRefit | None = None

    @property
    def z(self) -> float:
        kinds = [k for k in (self.kind, self.swing) if k is not None]
        return float(sum(np.sum((k.rms_after / np.where(k.floor > 0, k.floor, 1.0)) ** 2) for k in kinds))


def _standing_joint(sv, effect: Effect, model: Any, prior: Calibration, prior_j: Calibration, cal: Calibration, robot,
                    balance: str, hang_values: dict, eta_prior: EtaPrior | None, d_r: np.ndarray | None, folds: int,
                    seed: int, x_start: np.ndarray | None) -> _StandingJoint:
    """The standing poses refit with the effect (module docstring), from ``prior_j`` (the joint hanging fit's offsets,
    weights and CoM curves ``d_r``; None: no joint hanging fit), with ``eta_prior`` or not; ``cal`` is the calibration
    its rotations, positions and offsets replace values of."""
    legs = tuple(robot.legs)
    notes: list[str] = []
    fidx = fold_indices(sv.P, folds, seed)
    data_j = sv.data if d_r is None else replace(
        sv.data, rcom=np.nan_to_num(np.stack([prior_j.legs[k].com(sv.data.phi[:, i]) for i, k in enumerate(legs)], axis=1)))
    base = AugmentedProblem(model, prior, robot, balance)
    x0 = base.x0 if x_start is None or len(x_start) != base.n_model else x_start
    cv0 = base.cross_validate(sv.data, sv.R_WB, fidx, x0)
    xb, held0, base_dof = cv0.x, cv0.held, cv0.dof
    # The error model is refit too: an effect the calibration did not know about can make model
    # selection settle on a smaller model (a drift taken for translations), so the joint fit
    # also tries the full model and keeps the one with the smaller held-out residual.
    best = None
    for m in dict.fromkeys([model, FULL_MODEL]):
        prob = AugmentedProblem(m, prior_j, robot, balance, effect, eta_prior=eta_prior)
        _hold_shared(prob, effect, prior_j, robot, hang_values)
        if d_r is not None and effect.joint_holds_offset_shift:
            _hold_offset_shift(prob)
        start = np.concatenate([xb, prob.x0[prob.n_model:]]) if m == model else prob.x0
        try:
            cv = prob.cross_validate(data_j, sv.R_WB, fidx, start)
        except SolverError as exc:
            notes.append(f"joint standing refit with model {m!r} failed ({exc.status})")
            continue
        z = float(((cv.held / np.where(sv.floor > 0, sv.floor, 1.0)) ** 2).sum())
        if best is None or z < best[0]:
            best = (z, m, prob, cv.x, cv.held, cv.Phi, cv.r_in)
    if best is None:
        notes.append("joint standing refit failed; the standing kind is left out")
        return _StandingJoint(None, cal, {}, None, None, None, (), model, tuple(notes), eta_prior is not None)
    _, m_used, prob, x, held1, Phi, r_in = best
    if m_used != model:
        notes.append(f"with {effect.name} the standing error model {m_used!r} predicts held-out poses better than {model!r}")
    fit = prob.result(x, Phi)
    # The floor of the joint model: the same noise model refit to the joint fit's own
    # in-sample residuals (an effect the calibration lacked inflates the calibration's floor)
    floor = sv.floor
    if sv.refloor is not None:
        floor = sv.refloor(r_in, max(fit.rank - base_dof, 0))
    # the blocks in the calibration's floor (the same for every joint refit, so two of them compare pose by pose)
    blocks = ((held1 / np.where(sv.floor > 0, sv.floor, 1.0)) ** 2).sum(axis=1)
    kind = KindRefit("standing", np.sqrt((held0**2).mean(0)), np.sqrt((held1**2).mean(0)), floor, sv.P, blocks)
    params = {n: (float(v), float(s)) for n, v, s in zip(fit.effect_params.index, fit.effect_params, fit.effect_bse)}
    eta = prob.eta(x)
    eta_cov = np.asarray(fit.cov, float)[prob.n_model :, prob.n_model :]   # held parameters: rows of zeros
    eta_und = ~np.isfinite(np.asarray(fit.effect_bse, float)) if len(fit.effect_bse) == len(eta) else None
    if eta_und is not None and eta_und.any():
        # e.g. a gain matrix per leg (54 entries) on the report's 100 poses (at 300 poses every entry has its se)
        notes.append(f"{int(eta_und.sum())} of the {len(eta_und)} parameters of {effect.name}'s standing face are not "
                     f"determined by these {sv.P} poses{' and the hanging fit' if eta_prior is not None else ''} (no finite "
                     "se: their values are one of many that fit equally well; what the held-out poses test is the "
                     "combinations they determine); more standing poses determine them (`plan`)")
    members = combined_members(effect, prob.actx, params)
    R_new, p_new, off_new = prob.transforms(x)
    new_legs = {}
    for k, leg in enumerate(legs):
        kw = {"rotation_to_body": R_new[k]}
        if prob.balance == "exact" and balance == "exact":
            kw["position_from_com_m"] = p_new[k]
        if off_new is not None:
            kw["offset"] = off_new[k]
        new_legs[leg] = replace(cal.legs[leg], **kw)
    if balance != "exact":
        notes.append("report balance: the joint calibration keeps the calibration's positions (its p' are relative to a moving CoM)")
    return _StandingJoint(kind, replace(cal, legs=new_legs), params, eta, eta_cov, eta_und, members, m_used, tuple(notes),
                          eta_prior is not None)


def _swing_joint(series: LegSeries, effect: Effect, old: Calibration, new: Calibration, legs, folds: int,
                 hanging: dict | None = None, d_r: np.ndarray | None = None) -> KindRefit:
    """Swing residuals with the joint calibration (rotations, offsets, weights) plus the swing face.

    A swing face whose parameters are the hanging face's (same names: a per-leg casing load, drift
    rate or gain matrix) takes the hanging estimates, nothing is fitted to the swing samples (so the
    residual is held-out as it is); other faces (a tether's tilts) are fitted with time-block folds."""
    stack = lambda cal, key: np.array([np.asarray(getattr(cal.legs[k], key), float) for k in legs])
    after = recalibrate(series, stack(new, "rotation_to_body"), stack(new, "offset"), stack(old, "offset"),
                        stack(new, "leg_weight_N"))
    if d_r is not None:   # the joint hanging fit's CoM curves: e = w - w_o - [f; r x f] with the moved r
        moved = []
        for l in after.legs:
            r = moved_com(l.r, l.phi, d_r[l.k])
            moved.append(replace(l, e=l.e + np.hstack([np.zeros_like(l.f), np.cross(l.r - r, l.f)]), r=r))
        after = replace(after, legs=moved)
    face = effect.swing_features(after.legs)
    if face is not None and hanging and all(n in hanging for n in face.names):
        beta = np.array([hanging[n] for n in face.names])
        q = face.blocks[0].shape[2]
        base = score_linear(series, None, folds)[0]
        ss = np.zeros(6)
        for i, (l, X) in enumerate(zip(after.legs, face.blocks)):
            b = beta[face.index(i, l.k)] if face.cols is not None else (beta[l.k * q : (l.k + 1) * q] if face.per_leg else beta)
            ss += ((l.e - X @ b) ** 2).sum(axis=0)
        return KindRefit(series.kind, np.sqrt(base.mse_before), np.sqrt(ss / series.n), base.floor, series.n)
    sc, _ = score_linear(series, face, folds, after=after)
    return KindRefit(series.kind, np.sqrt(sc.mse_before), np.sqrt(sc.mse_after), sc.floor, series.n)
