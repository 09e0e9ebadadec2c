"""inertial_load: the load's own accelerations, which a quasi-static model leaves out.

While a load moves, the transducer carries besides its weight the reaction of its momentum change
(``sim/free/physics.py``, :func:`~ftcal_nlp.sim.free.physics.inertial_wrench`; B's origin fixed in W):

    f_in = -sum_i m_i r_i'',   t_in = -sum_i [ (r_i - O) x m_i r_i'' + I_i w_i' + w_i x I_i w_i ]

Injected (``InertialLoadInjector``): ``w += scale * [f_in; t_in]`` in ft, computed by the free-load
simulator from the true motion and bodies (``FreeLoadTruth.inertial``; zero on held samples).
``scale`` 1 is physical. A hexapod's legs have ``leg_inertia``; this one is for free loads.

Off-face shape (the validation sweep; a correct diagnosis still says ``inertial_load``):

* inertial_load_ringing   the inertial wrench plus the ringing of the arm after each move stops,
                          which no pose stream at 100 Hz resolves: ``scale A_c v_c exp(-s / 0.4 s)
                          sin(2 pi 7 Hz s)`` per channel, ``s`` the time since the hold began, ``A_c`` half
                          the peak of the inertial wrench on that channel, ``v_c`` random signs

Free faces (``free_faces.py``; need the orientation stream ``qw..qz``):

* ``rigid`` (a load that does not move relative to ft: a payload): the rigid-body regressor of a body
  turning about the fixed point P (B's origin: the pose stream records no translation), linear in
  ``pi = [h, I_P]`` (9: the first moment ``h = m (c + p)`` about P and the inertia about P, ft axes;
  ``p`` the ft origin O relative to P, from ``position_m`` in B, ``ctx.extra["position_m"]``, 0 if not
  given; the mass alone is not seen: P does not accelerate). With ``w, alpha`` the ft frame's rate of
  turn and its derivative (ft axes; ``R_W,ft = R_WB R_B,ft E``) and the moment carried to O:

      f = -(alpha x h + w x (w x h)),   t = -(I_P alpha + w x I_P w) - p x f

  (parameters ``h_x [kg*m]``.., ``I_xx [kg*m^2]``..; for a physical effect ``h`` is the static fit's
  first moment plus ``m p``);
* ``points`` (any load, URDF links too): the inertial wrench of the fitted load's groups as point
  masses (``M_G`` at its CoM ``s_G / M_G``, from ``ctx.load``/``ctx.theta``: their rotational inertia is
  left out) with one gain per channel (``<c>.gain [1]``), 1 for a physical effect.

Correction: ``y - X beta``.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import DataFormatError
from ..core.geometry import quat_to_rotation, unskew
from .free_faces import WRENCH, FreeFace, rate
from .injection import EffectInjector, Magnitude, OffFaceInjector
from .unit import Effect

RIGID_NAMES = ("h_x [kg*m]", "h_y [kg*m]", "h_z [kg*m]",
               "I_xx [kg*m^2]", "I_xy [kg*m^2]", "I_xz [kg*m^2]", "I_yy [kg*m^2]", "I_yz [kg*m^2]", "I_zz [kg*m^2]")


class InertialLoadInjector(EffectInjector):
    """``scale`` times the load's inertial wrench (1: physical), from the free-load simulator's truth."""

    name = "inertial_load"
    magnitude = Magnitude("x the load's physical inertial wrench", (0.5, 1.0), 1.0)
    needs_inertial = True      # the free-load simulator computes FreeLoadTruth.inertial for it

    def inertial(self, ctx) -> np.ndarray:
        w_in = getattr(ctx.truth, "inertial", None)
        if w_in is None:
            raise ValueError(f"{self.name}: the simulator gave no inertial wrench (a free-load simulator computes it "
                             "for injectors with needs_inertial)")
        return np.asarray(w_in, float)

    def readings(self, ctx, w):
        return w + self.scale * self.inertial(ctx)[:, None, :]


class InertialLoadRingingInjector(OffFaceInjector, InertialLoadInjector):
    """The inertial wrench plus a 7 Hz ringing (decay 0.4 s) after each move, half the inertial peak per channel."""

    name = "inertial_load_ringing"
    expect = "inertial_load"
    magnitude = Magnitude("x the load's inertial wrench (with the arm's ringing after each move)", (0.5, 1.0), 1.0)
    FREQ_HZ, DECAY_S = 7.0, 0.4

    def readings(self, ctx, w):
        w_in = self.inertial(ctx)
        hold = np.asarray(ctx.pose_index)
        t = np.asarray(ctx.t, float)
        start = np.r_[True, hold[1:] != hold[:-1]]
        t_start = np.maximum.accumulate(np.where(start, t, -np.inf))
        s = np.where(hold >= 0, t - t_start, np.inf)            # time since the hold began; moving: no ringing
        ring = np.where(np.isfinite(s), np.exp(-np.minimum(s, 1e3) / self.DECAY_S) * np.sin(2 * np.pi * self.FREQ_HZ * np.where(np.isfinite(s), s, 0.0)), 0.0)
        signs = self.drawn("_v", 6, lambda k: self.rng.choice([-1.0, 1.0], k))
        amp = 0.5 * np.abs(w_in).max(axis=0) * signs
        return w + self.scale * (w_in + ring[:, None] * amp[None, :])[:, None, :]


def frame_motion(t: np.ndarray, rec: np.ndarray, R_W_ft: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(w, alpha)`` (N, 3) each, in ft axes: the ft frame's rate of turn and its derivative, by central
    differences within each recording (``[w_W]x = R' R^T``, ``w = R^T w_W``, ``alpha = w'``)."""
    dR = rate(R_W_ft, t, rec)
    w = np.einsum("nji,nj->ni", R_W_ft, unskew(dR @ np.swapaxes(R_W_ft, 1, 2)))
    return w, rate(w, t, rec)


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def _inertia_map(v: np.ndarray) -> np.ndarray:
    """``L(v)`` (N, 3, 6) with ``I v = L(v) [Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``."""
    L = np.zeros(v.shape[:-1] + (3, 6))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    L[..., 0, 0], L[..., 0, 1], L[..., 0, 2] = x, y, z
    L[..., 1, 1], L[..., 1, 3], L[..., 1, 4] = x, y, z
    L[..., 2, 2], L[..., 2, 4], L[..., 2, 5] = x, y, z
    return L


def rigid_regressor(w: np.ndarray, alpha: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``Y`` (N, 6, 9): the inertial wrench on the transducer ``Y pi`` of a rigid load turning about P (module
    docstring), ft axes; ``p`` (3,) or (N, 3) the ft origin relative to P in ft axes."""
    F, T, R = _rigid_parts(w, alpha, p)
    Y = np.zeros((len(w), 6, 9))
    Y[:, :3, 0:3] = F
    Y[:, 3:, 0:3] = T
    Y[:, 3:, 3:9] = R
    return Y


def _rigid_parts(w, alpha, p) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The non-zero blocks of :func:`rigid_regressor`: forces on ``h`` (N, 3, 3), torques on ``h`` (N, 3, 3) and on
    the inertia (N, 3, 6)."""
    n = len(w)
    W, A = _skew(w), _skew(alpha)
    F = -(A + W @ W)
    return F, -_skew(np.broadcast_to(p, (n, 3))) @ F, -(_inertia_map(alpha) + W @ _inertia_map(w))   # -p x f


def _skew_entries(v: np.ndarray) -> list:
    """``[v]x`` as a 3 x 3 list of (N,) arrays (None for the zero diagonal)."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return [[None, -z, y], [z, None, -x], [-y, x, None]]


def _inertia_entries(v: np.ndarray) -> list:
    """``L(v)`` of :func:`_inertia_map` as a 3 x 6 list of (N,) arrays (None for its zeros)."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return [[x, y, z, None, None, None], [None, x, None, y, z, None], [None, None, x, None, y, z]]


def _mul(A: list, B: list, n: int) -> list:
    """The product of two matrices of (N,) arrays (None: zero), entry by entry (no (N, 3, k) stacks)."""
    out = []
    for i in range(len(A)):
        row = []
        for j in range(len(B[0])):
            acc = None
            for k in range(len(B)):
                if A[i][k] is not None and B[k][j] is not None:
                    term = A[i][k] * B[k][j]
                    acc = term if acc is None else acc + term
            row.append(np.zeros(n) if acc is None else acc)
        out.append(row)
    return out


def rigid_face(w: np.ndarray, alpha: np.ndarray, p: np.ndarray, shape: dict | None = None) -> FreeFace:
    """:func:`rigid_regressor` as a channel-wise :class:`FreeFace` (each channel's columns not identically zero),
    formed entry by entry from the 3 x 3 and 3 x 6 blocks (no (N, 3, k) stacks, no (N, 6, 9) array); a torque
    channel's entries are formed when its block is (a few (N,) arrays alive at a time, not the whole regressor's:
    fresh memory is paid for in page faults)."""
    n = len(w)
    W = _skew_entries(w)
    WW = _mul(W, W, n)
    A = _skew_entries(alpha)
    F = [[-(WW[i][j] if A[i][j] is None else A[i][j] + WW[i][j]) for j in range(3)] for i in range(3)]
    del WW
    P = _skew_entries(np.broadcast_to(np.asarray(p, float), (n, 3)).copy())
    Lw = _inertia_entries(w)
    La = _inertia_entries(alpha)
    blocks = []
    for c in range(6):
        if c < 3:
            cols = F[c]
        else:
            i = c - 3
            T = _mul([P[i]], F, n)[0]                                     # p x f (row i); -p x f below
            WL = _mul([W[i]], Lw, n)[0]
            R = [-(WL[j] if La[i][j] is None else La[i][j] + WL[j]) for j in range(6)]
            cols = [-v for v in T] + R
        nz = [j for j, v in enumerate(cols) if np.any(v != 0)]
        if nz:
            blocks.append((c, np.array(nz), np.stack([cols[j] for j in nz], axis=0).T))   # column-major: no strided copy
    return FreeFace(None, RIGID_NAMES, shape, blocks=tuple(blocks))


def rigid_parameters(mass_kg: float, com_m, inertia_com, p=np.zeros(3)) -> np.ndarray:
    """``pi`` (9,) of a rigid body with CoM ``com_m`` relative to O: ``[h, I_P]``, ``h = m (c + p)``,
    ``I_P = I_c + m (|c + p|^2 1 - (c + p)(c + p)^T)`` (ft axes; ``p`` O relative to P)."""
    r = np.asarray(com_m, float) + np.asarray(p, float)
    I = np.asarray(inertia_com, float) + mass_kg * (r @ r * np.eye(3) - np.outer(r, r))
    return np.r_[mass_kg * r, I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2]]


def _ft_pose(ctx) -> tuple[np.ndarray, np.ndarray] | None:
    """``(R_W,ft (N, 3, 3), p_O (N, 3) in W)`` of the context, or None without an orientation stream (kept in the
    context's ``extra`` for its other shapes)."""
    if ctx.quat is None or not np.all(np.isfinite(ctx.quat)):
        return None
    key = (ctx.quat, ctx.rotation, ctx.q, ctx.load)
    c = ctx.extra.get("_ft_pose")
    if c is None or any(a is not b for a, b in zip(c[0], key)):
        c = ctx.extra["_ft_pose"] = (key, _ft_pose_of(ctx))
    return c[1]


def _ft_pose_of(ctx) -> tuple[np.ndarray, np.ndarray]:
    R_WB = quat_to_rotation(ctx.quat)
    n = ctx.n
    E = np.eye(3) if ctx.rotation is None else np.asarray(ctx.rotation, float)
    load = ctx.load
    q = ctx.q
    if getattr(load, "tree", None) is not None and getattr(load, "ft_link", None) is not None:
        R_B_ft, p_B = load.tree.pose(load.tree.root, load.ft_link, q, n)
    else:
        R_B_ft = load.nominal_rotation(q, n) if load is not None else np.broadcast_to(np.eye(3), (n, 3, 3))
        p_B = np.broadcast_to(np.asarray(ctx.extra.get("position_m", np.zeros(3)), float), (n, 3))
    R_W_ft = R_WB @ R_B_ft @ E
    return R_W_ft, np.einsum("nij,nj->ni", R_WB, p_B)


def point_mass_wrench(ctx, R_W_ft: np.ndarray, p_O: np.ndarray) -> np.ndarray | None:
    """The inertial wrench (N, 6) in ft of the fitted load's groups as point masses (``points`` face), or None
    without a fitted load."""
    load, theta = ctx.load, ctx.theta
    if load is None or theta is None:
        return None
    theta = np.asarray(theta, float)
    K = ctx.extra.get("K")
    if K is None:
        K = load.lever(ctx.q, ctx.n)
    G = len(theta) // 4
    f = np.zeros((ctx.n, 3))
    tau = np.zeros((ctx.n, 3))
    for g in range(G):
        sl = slice(4 * g, 4 * g + 4)
        M = float(theta[4 * g])
        if not M > 0:
            continue
        s = np.einsum("nij,j->ni", np.broadcast_to(K[:, :, sl], (ctx.n, 3, 4)), theta[sl])      # first moment in ft
        lever_W = np.einsum("nij,nj->ni", R_W_ft, s / M)
        acc = rate(rate(p_O + lever_W, ctx.t, ctx.rec), ctx.t, ctx.rec)
        f -= M * acc
        tau -= np.cross(lever_W, M * acc)
    return np.concatenate([np.einsum("nji,nj->ni", R_W_ft, f), np.einsum("nji,nj->ni", R_W_ft, tau)], axis=1)


class InertialLoad(Effect):
    name = "inertial_load"
    description = "accelerations of the load (its inertial wrench while it moves)"
    explains = "motion"
    kind = "sensor"
    injector_cls = InertialLoadInjector
    shapes = (InertialLoadRingingInjector,)
    applies_to = frozenset({"free"})
    diagnosed_on = frozenset({"free"})
    free_explains = "motion"
    follows_stream_clock = True   # a rate of turn differentiates the orientation over the stream's clock

    def free_require(self, ctx, shape, leg, where):
        if ctx.quat is None:
            raise DataFormatError(f"{where}: the calibration's effect inertial_load of transducer {leg} needs the "
                                  "orientation stream: columns qw, qx, qy, qz (gx..gz give no rate of turn)",
                                  path=where, column="qw")

    def free_shapes(self, ctx):
        if ctx.quat is None:
            return ()
        rigid = ctx.load is None or not ctx.load.varying() or not ctx.q
        return ({"model": "rigid"},) * rigid + ({"model": "points"},) * (ctx.load is not None and ctx.theta is not None)

    def free_face(self, ctx, shape):
        pose = _ft_pose(ctx)
        if pose is None:
            return None
        R_W_ft, p_O = pose
        if shape["model"] == "rigid":
            p = np.einsum("nji,nj->ni", R_W_ft, p_O)           # O relative to P (W's origin), ft axes
            return rigid_face(*frame_motion(ctx.t, ctx.rec, R_W_ft), p, dict(shape))
        w_in = point_mass_wrench(ctx, R_W_ft, p_O)
        if w_in is None or not np.any(np.abs(w_in) > 0):
            return None
        return FreeFace.channelwise([w_in[:, c] for c in range(6)], tuple(f"{c}.gain [1]" for c in WRENCH), dict(shape))


EFFECT = InertialLoad()
