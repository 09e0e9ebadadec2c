"""The model face of an effect: the building blocks every unit's augmentation is made of.

An effect's model face adds a few parameters ``eta`` to the calibration model so that
it can absorb the effect:

* standing (report eq. 8 with the balance of physics.py (E) or eq. 9): the
  balance residual of pose p becomes

      r_p = sum_k Ad_k (c_k(w_m,pk; eta) - w_o,k) - M_b g [z~_p(eta); 0] + e_p(eta)     (A)

  with corrected readings ``c_k``, a corrected up-vector ``z~`` and an extra
  wrench ``e_p`` (B axes, about the reference point); ``eta = 0`` gives back the
  calibration model. ``Effect.standing`` returns ``(c_k, z~, e_p)`` as CasADi
  expressions of ``eta`` and of one pose's features (:class:`PoseSym`; numbers:
  :meth:`StandingData.features`, symbols: :func:`pose_symbols`, column for column).
* hanging (report eqs. 4-7) and walking swing (a foot in the air reads only its
  leg's weight): the effect is linear in ``eta`` to first order, so it enters
  as features ``X`` (N, 6, m) regressed on the residuals of the fitted model
  (``Effect.hanging_features``, ``Effect.swing_features``: a :class:`LinearFace`
  over :class:`HangingLeg` samples).
* design: with free transducer rotations a common tilt of all fitted frames
  (:func:`design_check`) is how a motion-capture bias or a cable's horizontal pull shows.

This module holds those blocks (:class:`PoseSym`, :class:`AugContext`,
:class:`ParamBlock`, :class:`HangingLeg`, :class:`LinearFace`, :func:`per_leg_face`,
:class:`StandingData`, :func:`pose_symbols`, :func:`legendre_time`,
:func:`design_check`); the diagnosis (``ftcal_nlp.diagnose``) fits them, the
correction evaluates them (:func:`correct_by_face`, below: a sensor effect's standing face on recorded samples,
``Effect.correct``'s default; ``effects/correction.py`` reads the calibration's block and calls it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from scipy.linalg import block_diag

from ..core.errors import DataFormatError
from ..core.geometry import remove_yaw, rotation_to_rotvec

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
TIME_BASIS = 4      # smooth time basis of the standing features (flexible drift faces choose how many terms)
HARMONICS = 6       # harmonics of the shaft angle in the standing features (flexible shaft-angle faces)


def legendre_time(t: np.ndarray, lo: float, hi: float, degrees) -> np.ndarray:
    """Legendre polynomials ``P_j`` (j in ``degrees``) of the time ``t`` scaled to [-1, 1] over [lo, hi],
    (N, len(degrees)); zeros when the span is empty. The smooth time basis of the drift faces, the
    standing features (``PoseSym.tb``) and the floor's structure columns."""
    t = np.asarray(t, float)
    tau = 2.0 * (t - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros(len(t))
    degrees = list(degrees)
    return np.stack([np.polynomial.legendre.legval(tau, np.eye(j + 1)[j]) for j in degrees], axis=1) if degrees else np.zeros((len(t), 0))


@dataclass(frozen=True)
class PoseSym:
    """One standing pose as CasADi symbols of its *features*, legs in order.

    A standing face must be linear in these symbols (products it needs are
    features of their own), so that the residual is ``r_p = M(theta) phi_p`` and
    eq. 8 reduces to moments of ``phi`` (see ``standing_fit.py``, which checks it).

    ``w`` K raw readings (6,) in ft_k; ``z`` (3,) measured up direction in B
    (``R_WB^T e_z``); ``R_HB`` (3, 3) measured orientation without heading;
    ``t_h`` and ``t_h2`` hours since the hanging recordings (where the offsets
    were estimated) and its square; ``prev`` K raw readings of the previous pose
    (equal to ``w`` when there is none); ``cphi``/``sphi`` (K,) cos and sin of
    the shaft angles; ``w2`` K squared readings (6,); ``nfw`` K products
    ``(n_k . f_k) w_k`` with ``n_k`` the design-vertical ft axis; ``rcom`` K leg
    CoMs (3,) at the shaft angles (hanging curves, ft_k, m); ``rz`` K 3x3
    products ``r_a z_l``; ``tb`` (TIME_BASIS,) a smooth basis of time over the standing
    session (Legendre P_1.. of the scaled time); ``harm`` per harmonic m = 1..HARMONICS the
    pair (cos m phi, sin m phi), each (K,); ``step`` (1,) 1 after the change point of the
    calibration's standing residual (``views.change_point``), else 0.
    """

    w: list
    z: Any
    R_HB: Any
    t_h: Any
    t_h2: Any
    prev: list
    cphi: Any
    sphi: Any
    w2: list
    nfw: list
    rcom: list
    rz: list
    tb: Any = None
    harm: list | None = None
    step: Any = None


@dataclass(frozen=True)
class AugContext:
    """What an augmentation may use: legs, the model's offsets ``w_o`` (K expressions
    or DM), nominal transducer rotations (K, 3, 3), leg weights ``m_k g`` (K,) N,
    ``g``, and the hanging CoM curves (for inertial effects)."""

    legs: tuple[str, ...]
    w_o: list
    R_nominal: np.ndarray
    leg_weight_N: np.ndarray
    g: float

    @classmethod
    def from_calibration(cls, cal, legs: tuple[str, ...], R_nominal: np.ndarray) -> AugContext:
        """The context of a finished calibration: its offsets (numbers) and leg weights."""
        import casadi as ca

        return cls(legs, [ca.DM(np.asarray(cal.legs[k].offset, float)) for k in legs], np.asarray(R_nominal, float),
                   np.array([cal.legs[k].leg_weight_N for k in legs]), cal.g)

    @property
    def K(self) -> int:
        return len(self.legs)

    def vertical_axis(self, k: int) -> np.ndarray:
        """The ft_k axis that is vertical in the design (``R_nom^T e_z``)."""
        return self.R_nominal[k].T @ np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class ParamBlock:
    """Parameters of an augmentation: ``names`` (m,), start ``x0`` (zeros: no effect) and
    bounds. Bounds are physical plausibility (several times the largest realistic
    size): without them a face can mimic another effect with absurd values, e.g.
    a chassis flex of 70 degrees reproducing a constant force."""

    @classmethod
    def bounded(cls, names, bound: float) -> ParamBlock:
        names = tuple(names)
        return cls(names, np.zeros(len(names)), np.full(len(names), -float(bound)), np.full(len(names), float(bound)))

    names: tuple[str, ...]
    x0: np.ndarray = None  # type: ignore[assignment]  # None: filled in __post_init__ (zeros)
    lb: np.ndarray = None  # type: ignore[assignment]  # None: -inf, filled in __post_init__
    ub: np.ndarray = None  # type: ignore[assignment]  # None: +inf, filled in __post_init__

    def __post_init__(self):
        m = len(self.names)
        if self.x0 is None:
            object.__setattr__(self, "x0", np.zeros(m))
        if self.lb is None:
            object.__setattr__(self, "lb", np.full(m, -np.inf))
        if self.ub is None:
            object.__setattr__(self, "ub", np.full(m, np.inf))

    @property
    def m(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class HangingLeg:
    """One leg's hanging (or walking swing) samples for the linear faces.

    ``e`` (N, 6) residual of the fitted model; ``t`` (N,) s; ``phi`` (N,) rad;
    ``omega`` (N,) shaft speed rad/s; ``rec`` (N,) recording index; ``f`` (N, 3)
    the fitted leg weight vector in ft_k (N); ``r`` (N, 3) leg CoM at phi (m);
    ``r_dd`` (N, 3) its second derivative in phi (m/rad^2); ``mg`` leg weight N;
    ``t_ref`` s, time the offsets refer to; ``k`` leg index; ``n_vert`` (3,) the
    design-vertical ft axis; ``R_cal`` (3, 3) the calibration's ft_k -> B rotation
    (walking swing; None for hanging, which never uses it).
    """

    leg: str
    k: int
    e: np.ndarray
    t: np.ndarray
    phi: np.ndarray
    omega: np.ndarray
    rec: np.ndarray
    f: np.ndarray
    r: np.ndarray
    r_dd: np.ndarray
    mg: float
    g: float
    t_ref: float
    n_vert: np.ndarray
    R_cal: np.ndarray | None = None

    @property
    def applied(self) -> np.ndarray:
        """The modelled applied wrench ``[f; r x f]`` (N, 6)."""
        return np.hstack([self.f, np.cross(self.r, self.f)])

@dataclass(frozen=True)
class LinearFace:
    """Features of a linear face: ``blocks[i]`` (N_i, 6, q) for ``legs[i]``; ``per_leg``: each
    leg has its own q parameters (m = K q), else the q parameters are shared (m = q). ``cols``: several
    faces stacked (:func:`stack_faces`): per block the indices (q,) of its columns in the parameter vector
    (``len(names)`` parameters); None: the layout ``per_leg`` says. ``determined`` (m, r): the combinations of the
    parameters the kind fixes apart from the nuisance fitted beside it (columns over the face's parameters), what a
    joint refit may carry to another kind (``refit.hanging_joint``'s information is projected on them); None: every
    combination it has information on."""

    blocks: list
    names: tuple
    per_leg: bool
    cols: tuple | None = None
    determined: np.ndarray | None = None

    def size(self, K: int) -> int:
        """The number of parameters with ``K`` legs."""
        q = self.blocks[0].shape[2]
        return len(self.names) if self.cols is not None else (K * q if self.per_leg else q)

    def index(self, i: int, k: int) -> np.ndarray:
        """The parameter indices (q,) of ``blocks[i]``'s columns, the block of leg index ``k``."""
        if self.cols is not None:
            return np.asarray(self.cols[i], int)
        q = self.blocks[0].shape[2]
        return np.arange(k * q, (k + 1) * q) if self.per_leg else np.arange(q)


def stack_faces(faces: list[tuple[str, LinearFace]], legs: list[HangingLeg]) -> LinearFace | None:
    """Several linear faces of the same ``legs`` as one (``(prefix, face)``, None faces left out): per leg the
    blocks side by side, each face's parameters after the previous ones' (names ``prefix:name``); None when no face
    is left."""
    faces = [(p, f) for p, f in faces if f is not None]
    if not faces:
        return None
    K = max(l.k for l in legs) + 1 if legs else 0
    blocks, names, off = [], [], 0
    cols: list[list] = [[] for _ in legs]
    for p, f in faces:
        if len(f.names) != f.size(K):
            raise ValueError(f"face {p!r}: {len(f.names)} names for {f.size(K)} parameters")
        for i, l in enumerate(legs):
            cols[i].append(off + f.index(i, l.k))
        names += [f"{p}:{n}" for n in f.names]
        off += f.size(K)
    for i in range(len(legs)):
        blocks.append(np.concatenate([f.blocks[i] for _, f in faces], axis=2))
    det = None
    if any(f.determined is not None for _, f in faces):   # block-diagonal: a face without one keeps all of its own
        det = block_diag(*[f.determined if f.determined is not None else np.eye(f.size(K)) for _, f in faces])
    return LinearFace(blocks, tuple(names), False, tuple(np.concatenate(c) for c in cols), det)


def per_leg_face(legs: list[HangingLeg], make, labels) -> LinearFace:
    """``make(leg) -> (N, 6, q)``; parameters separate per leg, named ``leg.label``."""
    K = max(l.k for l in legs) + 1 if legs else 0
    names = [""] * K
    for l in legs:
        names[l.k] = l.leg
    return LinearFace([make(l) for l in legs], tuple(f"{n or k}.{c}" for k, n in enumerate(names) for c in labels), True)


@dataclass(frozen=True)
class StandingData:
    """Per-pose data of the standing poses (P poses, K legs), numpy.

    ``w`` (P, K, 6) raw readings; ``z`` (P, 3) up in B; ``R_HB`` (P, 3, 3) orientation
    without heading; ``t_h`` (P,) hours since the hanging reference time; ``prev``
    (P, K, 6) previous pose's raw readings (= ``w`` where unknown); ``phi`` (P, K);
    ``rcom`` (P, K, 3) leg CoMs at phi (hanging curves, ft_k, m); ``n_vert`` (K, 3)
    the design-vertical ft axes; ``t_span`` (first, last) hours of the smooth time basis
    (None: the range of ``t_h``; subsets keep their parent's); ``t_step`` hours, the change
    point of the calibration's residual (``views.change_point``; the feature ``step`` is
    ``t_h > t_step``; None: no step feature, zeros).
    """

    w: np.ndarray
    z: np.ndarray
    R_HB: np.ndarray
    t_h: np.ndarray
    prev: np.ndarray
    phi: np.ndarray
    rcom: np.ndarray
    n_vert: np.ndarray
    t_span: tuple[float, float] | None = None
    t_step: float | None = None

    def __post_init__(self):
        if self.t_span is None:
            t = np.asarray(self.t_h, float)
            object.__setattr__(self, "t_span", (float(t.min()), float(t.max())) if len(t) else (0.0, 1.0))

    def time_basis(self) -> np.ndarray:
        """Legendre polynomials P_1..P_TIME_BASIS of the time scaled to [-1, 1] over ``t_span`` (P, TIME_BASIS)."""
        assert self.t_span is not None  # set in __post_init__
        return legendre_time(self.t_h, *self.t_span, range(1, TIME_BASIS + 1))

    @property
    def P(self) -> int:
        return len(self.t_h)

    @property
    def K(self) -> int:
        return self.w.shape[1]

    def subset(self, idx) -> StandingData:
        return StandingData(self.w[idx], self.z[idx], self.R_HB[idx], self.t_h[idx], self.prev[idx], self.phi[idx],
                            self.rcom[idx], self.n_vert, self.t_span, self.t_step)

    def features(self) -> np.ndarray:
        """``phi_p`` (P, n_phi) in the order of :func:`pose_symbols`."""
        P = self.P
        nf = np.einsum("ki,pki->pk", self.n_vert, self.w[..., :3])
        rz = self.rcom[:, :, :, None] * self.z[:, None, None, :]
        return np.concatenate([
            self.w.reshape(P, -1), self.z, self.R_HB.reshape(P, 9), self.t_h[:, None], self.t_h[:, None] ** 2,
            self.prev.reshape(P, -1), np.cos(self.phi), np.sin(self.phi), (self.w**2).reshape(P, -1),
            (nf[..., None] * self.w).reshape(P, -1), self.rcom.reshape(P, -1), rz.reshape(P, -1),
            self.time_basis(), *[f(m * self.phi) for m in range(2, HARMONICS + 1) for f in (np.cos, np.sin)],
            (self.t_h > self.t_step)[:, None].astype(float) if self.t_step is not None else np.zeros((P, 1)),
        ], axis=1)


def pose_symbols(K: int) -> tuple[ca.SX, PoseSym]:
    """One pose's features as an SX vector and its named views (columns of :meth:`StandingData.features`)."""
    n = 6 * K + 3 + 9 + 2 + 6 * K + 2 * K + 6 * K + 6 * K + 3 * K + 9 * K + TIME_BASIS + 2 * K * (HARMONICS - 1) + 1
    d = ca.SX.sym("phi", n)
    i = 0

    def take(m):
        nonlocal i
        out = d[i : i + m]
        i += m
        return out

    def legs6(v):
        return [v[6 * k : 6 * k + 6] for k in range(K)]

    w = take(6 * K)
    z = take(3)
    R = ca.reshape(take(9), 3, 3).T  # stored row by row
    t_h = take(1)
    t_h2 = take(1)
    prev = take(6 * K)
    cphi = take(K)
    sphi = take(K)
    w2 = take(6 * K)
    nfw = take(6 * K)
    rcom = take(3 * K)
    rz = take(9 * K)
    tb = take(TIME_BASIS)
    harm = [(cphi, sphi)] + [(take(K), take(K)) for _ in range(2, HARMONICS + 1)]
    step = take(1)
    return d, PoseSym(
        w=legs6(w), z=z, R_HB=R, t_h=t_h, t_h2=t_h2, prev=legs6(prev), cphi=cphi, sphi=sphi, w2=legs6(w2),
        nfw=legs6(nfw), rcom=[rcom[3 * k : 3 * k + 3] for k in range(K)],
        rz=[ca.reshape(rz[9 * k : 9 * k + 9], 3, 3).T for k in range(K)], tb=tb, harm=harm, step=step,
    )


def design_check(R_fitted: np.ndarray, R_nominal: np.ndarray) -> dict:
    """Design face of mocap_bias: do the fitted transducer frames share a common tilt?

    With free rotations the standing fit absorbs a mocap bias exactly (every
    ``R_k`` turns by ``R_b^T``), so it shows only against the design: the mounting
    errors ``delta_k = log(R_k R_nom,k^T)`` (B axes) are independent per leg, a
    bias adds one common tilt. Likelihood ratio of "common tilt + scatter" against
    "scatter" on the x, y components (heading components are not determined by
    level poses): ``dBIC = n ln(SS_1/SS_0) + 2 ln n``, n = 2K.

    Returns the mean tilt (deg), its se, ``delta_bic``, and ``n``.
    """
    d = np.degrees(rotation_to_rotvec(R_fitted @ np.swapaxes(R_nominal, 1, 2)))[:, :2]  # (K, 2)
    K = len(d)
    mean = d.mean(axis=0)
    ss0 = float((d**2).sum())
    ss1 = float(((d - mean) ** 2).sum())
    n = 2 * K
    sd = np.sqrt(ss1 / max(n - 2, 1))
    dbic = n * np.log(max(ss1, 1e-300) / max(ss0, 1e-300)) + 2 * np.log(n)
    return {"tilt_deg": mean, "tilt_se_deg": sd / np.sqrt(K), "delta_bic": float(dbic), "n": n,
            "scatter_deg": float(sd), "rms_before": float(np.sqrt(ss0 / n)), "rms_after": float(np.sqrt(ss1 / n))}


# ---------------------------------------------------------------------------------------------------------------------
# A sensor effect's correction for ``correct``: its standing face evaluated on recorded samples.
#
# A calibration written with the diagnosis' named effect carries in ``meta["effect"]`` (the *block*) the effect's
# standing-face parameters ``eta`` (the scaled units of ``Effect.standing_params``), their covariance ``eta_cov``, the
# hanging-face parameters, ``t_ref_s`` and the design rotations. A sensor effect corrects each sample by what its
# standing face does to one transducer's readings and to the measured orientation (eq. (A)):
#
#     c_k = c_k(w_k; eta)          corrected readings, per leg (the previous pose is the sample itself)
#     R_WB' = R_WB Z(eta)^T        so that the up vector R_WB'^T e_z = Z(eta) z
#
# with the covariance ``J_k Sigma_eta J_k^T``, ``J_k = d c_k / d eta`` (first order). The same CasADi expressions the
# diagnosis fitted are evaluated over all samples at once, in blocks of ``CHUNK`` samples (the standing features are a
# few hundred columns per sample). Several effects fitted together (``combined.Combined``, a block with ``members``):
# each member's block (:func:`member_block`) is a single effect's, its ``eta`` the member's slice of the joint one.

CHUNK = 4096        # samples per block of the effect's correction


def correct_by_face(effect, cal, block: dict, ctx: AugContext, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray,
                    t_h: np.ndarray, *, with_cov: bool = True, source: str = "calibration"):
    """``(w', R_WB', cov)``: readings (N, K, 6) and orientations (N, 3, 3) corrected by ``effect``'s standing face
    with the block's ``eta``, and the covariance (N, K, 6, 6) of the corrected readings (None without ``eta_cov``
    or ``with_cov``). ``t_h`` (N,) hours since ``t_ref_s``."""
    K, N = ctx.K, len(t_h)
    eta = face_eta(effect, ctx, block, source)
    m = len(eta)
    C = face_eta_cov(block, m, source) if with_cov else None
    und = face_undetermined(block, m, source) if C is not None else None
    d, pose = pose_symbols(K)
    e = ca.SX.sym("eta", m)
    c, zmap, _ = effect.standing(e, pose, ctx)
    Z = zmap if zmap is not None else ca.SX.eye(3)
    outs = [ca.vertcat(*c), ca.reshape(Z, 9, 1)] + ([ca.jacobian(ca.vertcat(*c), e)] if C is not None else [])
    fn = ca.Function("effect", [d, e], outs)
    w_new, R_new = np.empty_like(w, dtype=float), np.empty_like(R_WB, dtype=float)
    cov = np.zeros((N, K, 6, 6)) if C is not None else None
    for a in range(0, N, CHUNK):
        s = slice(a, min(N, a + CHUNK))
        n = s.stop - s.start
        res = fn(sample_features(cal, ctx, w[s], phi[s], R_WB[s], t_h[s]).T, eta)
        w_new[s] = np.asarray(res[0], float).T.reshape(n, K, 6)
        Zs = np.asarray(res[1], float).T.reshape(n, 3, 3).transpose(0, 2, 1)   # columns of Z were stacked (CasADi is column-major)
        R_new[s] = np.einsum("nij,nkj->nik", R_WB[s], Zs)
        if cov is not None and C is not None:   # cov is made exactly when C is given
            J = np.asarray(res[2], float).reshape(6 * K, n, m).transpose(1, 0, 2).reshape(n, K, 6, m)   # samples side by side
            cov[s] = np.einsum("nkam,mq,nkbq->nkab", J, C, J)
            if und is not None:   # a component an undetermined parameter moves has no finite variance
                touched = np.abs(J[..., und]).max(-1) > 0
                ii = np.arange(6)
                diag = cov[s][:, :, ii, ii]
                diag[touched] = np.inf
                cov[s][:, :, ii, ii] = diag
    return w_new, R_new, cov


def face_eta(effect, ctx: AugContext, block: dict, source: str) -> np.ndarray:
    """The standing face's parameters from ``meta.effect.eta`` (as many as the face has)."""
    block_p = effect.standing_params(ctx)
    m = block_p.m if block_p is not None else 0
    eta = np.asarray(block.get("eta", []), float)[:m]
    if len(eta) != m:
        raise DataFormatError(f"{source}: meta.effect.eta has {len(eta)} values, {effect.name} needs {m}")
    return eta


def face_eta_cov(block: dict, m: int, source: str) -> np.ndarray | None:
    """The covariance of the face's ``m`` parameters from ``meta.effect.eta_cov`` (None: not stored); the offset shift
    that follows the face's parameters is the calibration's, not the effect's."""
    return None if "eta_cov" not in block else joint_eta_cov(block, m, source)[:m, :m]


def face_undetermined(block: dict, m: int, source: str) -> np.ndarray | None:
    """Which of the face's ``m`` parameters the standing poses do not determine (``meta.effect.eta_undetermined``;
    None when none is, or the block predates the key)."""
    u = block.get("eta_undetermined")
    if u is None:
        return None
    u = np.asarray(u)
    if u.ndim != 1 or u.dtype != bool or len(u) < m:
        raise DataFormatError(f"{source}: meta.effect.eta_undetermined must be a list of booleans, one per meta.effect.eta "
                         f"value (at least {m}), got {block['eta_undetermined']!r}")
    return u[:m] if u[:m].any() else None


def sample_features(cal, ctx: AugContext, w, phi, R_WB, t_h) -> np.ndarray:
    """The standing features of every sample (``StandingData.features``; the previous pose is the sample itself)."""
    rcom = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(ctx.legs)], axis=1)
    n_vert = np.einsum("kji,j->ki", ctx.R_nominal, np.array([0.0, 0.0, 1.0]))
    return StandingData(w, R_WB[:, 2, :], remove_yaw(R_WB), t_h, w, phi, np.nan_to_num(rcom), n_vert).features()


#: the keys of a block that are the joint fit's, replaced by the member's own in :func:`member_block`
JOINT_KEYS = ("name", "variant", "eta", "eta_cov", "eta_undetermined", "parameters", "members")


def member_block(block: dict, i: int, source: str = "calibration") -> dict:
    """Member ``i`` of a block of several effects (``meta.effect.members[i]``) as a single effect's block: the block's
    shared keys (``t_ref_s``, ``R_nominal``), the member's name, variant, parameters, its ``eta`` and the diagonal block
    of ``eta_cov`` of its ``eta_slice``. Checks the slice against the joint ``eta`` (a DataFormatError naming the key)."""
    mb = block["members"][i]
    key = f"meta.effect.members[{i}]"
    if not isinstance(mb, dict) or not isinstance(mb.get("name"), str):
        raise DataFormatError(f"{source}: {key} must be a table with a name (the effect's), got {mb!r}")
    eta_all = np.asarray(block.get("eta", []), float)
    sl = mb.get("eta_slice")
    if not (isinstance(sl, (list, tuple)) and len(sl) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in sl)
            and 0 <= sl[0] <= sl[1] <= len(eta_all)):
        raise DataFormatError(f"{source}: {key}.eta_slice must be [start, stop] within meta.effect.eta ({len(eta_all)} values), got {sl!r}")
    eta = np.asarray(mb.get("eta", eta_all[sl[0]:sl[1]].tolist()), float)
    if eta.shape != (sl[1] - sl[0],) or not np.array_equal(eta, eta_all[sl[0]:sl[1]]):
        raise DataFormatError(f"{source}: {key}.eta must be meta.effect.eta[{sl[0]}:{sl[1]}] ({sl[1] - sl[0]} values), got "
                         f"{eta.size} values{' that differ from them' if eta.size == sl[1] - sl[0] else ''}")
    out = {k: v for k, v in block.items() if k not in JOINT_KEYS}
    out.update({k: v for k, v in mb.items() if k != "eta_slice"})
    out["eta"] = eta.tolist()
    out.setdefault("variant", {})
    out.setdefault("parameters", {})
    if "eta_cov" in block:
        C = joint_eta_cov(block, len(eta_all), source)
        out["eta_cov"] = C[sl[0]:sl[1], sl[0]:sl[1]].tolist()
    if "eta_undetermined" in block:
        out["eta_undetermined"] = list(block["eta_undetermined"])[sl[0]:sl[1]]
    return out


def joint_eta_cov(block: dict, m: int, source: str = "calibration") -> np.ndarray:
    """``meta.effect.eta_cov`` checked square with at least ``m`` rows (a DataFormatError naming the key)."""
    C = np.asarray(block["eta_cov"], float)
    if C.ndim != 2 or C.shape[0] != C.shape[1] or C.shape[0] < m:
        raise DataFormatError(f"{source}: meta.effect.eta_cov must be square with at least {m} rows (the members' parameters "
                         f"first), got {C.shape}")
    return C
