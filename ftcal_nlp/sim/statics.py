"""Exact rigid-body statics of the robot on compliant feet, on level ground or a tilted board (batched numpy).

The robot picks its own attitude. With the body tilted by ``R_tilt = R_y(b) R_x(a)``
and its B origin at height ``z`` (heading and horizontal position do not
matter), foot k sits at ``P_k = R_tilt f_k + z e_z`` (``f_k`` the toe in B) and
the ground pushes up on it with a penalty spring

    F_k = stiffness * max(0, -P_k,z)                       (exactly zero in the air)

Equilibrium of the whole robot (body and legs, weight ``M g`` at the total CoM
``c = R_tilt c_B + z e_z``) is three equations in ``(z, a, b)``:

    sum_k F_k = M g,   sum_k F_k (P_k - c)_y = 0,   sum_k F_k (P_k - c)_x = 0,

i.e. the stationarity of the potential energy ``sum_k stiffness/2 max(0, -P_k,z)^2
+ M g c_z``; its minimum (a stable equilibrium) is found by a safeguarded
Newton iteration for many poses at once. A pose tips over (and is reported as
such) when no stable equilibrium exists near level: the iteration fails, fewer
than three feet carry load or the attitude exceeds a limit.

On a board of slope ``theta`` (frame G: z normal to the board, ``R_WG`` to W;
``u = R_WG^T e_z`` is "up" in G) the springs push along the board's normal,
``N_k = stiffness * d_k`` with ``d_k = max(0, -P_k,z)`` (``P_k = R_GB f_k + z e_z``
now in G), and friction carries the slope component of the weight. Friction is
statically indeterminate; we share it in proportion to the normal loads,
``T_k = N_k tan(theta)`` uphill, which makes every foot force vertical in W,
``F_k = N_k / cos(theta) e_z``. Equilibrium is then the level-ground system with
feet and CoM seen in W (parallel forces: no torque about ``u``):

    sum_k F_k = M g,   sum_k F_k (P_k - c)^W_y = 0,   sum_k F_k (P_k - c)^W_x = 0,

no longer a potential's gradient (friction does no work); it is solved by
Newton steps with a finite-difference Jacobian, started from the level solve
with the CoM moved downhill by its height times ``tan(theta)`` (its projection
along gravity), and judged stable when ``diag(1, 1, -1)`` times that Jacobian
has only eigenvalues with negative real parts (near level ground it is about minus the
potential's Hessian). A board pose slips (``contact_forces``) when
``tan(theta)`` reaches the friction coefficient.

The floor is not perfectly flat: ``bumps`` (N, K) raise the ground under each
foot (drawn afresh at each standing pose), so the compression is
``d_k = max(0, bump_k - P_k,z)``.

Friction-locked internal forces: foot forces ``h_k`` in the ground's plane with
zero net force and zero net moment (``sum h = 0``, ``sum P x h = 0``); they leave
the equilibrium exact and change every transducer reading. They are random
(standing) or slowly varying (walking), scaled inside what the friction cones
leave over after the slope's share.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import rotvec_to_rotation

_E_Z = np.array([0.0, 0.0, 1.0])
_RESIDUAL_SIGN = np.array([1.0, 1.0, -1.0])  # _residual ~ diag(-1, -1, 1) grad V near level ground


def tilt_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``R_y(b) R_x(a)`` (..., 3, 3): roll ``a`` then pitch ``b``; its heading is zero."""
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    z = np.zeros_like(a)
    return np.stack(
        [
            np.stack([cb, sb * sa, sb * ca], -1),
            np.stack([z, ca, -sa], -1),
            np.stack([-sb, cb * sa, cb * ca], -1),
        ],
        -2,
    )


def board_rotation(tilt: float, direction: np.ndarray) -> np.ndarray:
    """``R_WG`` (..., 3, 3) of a board sloping by ``tilt`` rad whose downhill direction in
    its frame G is ``(cos d, sin d, 0)``, ``d = direction`` (...,): maps G's "up"
    ``u = cos(tilt) e_z - sin(tilt) (cos d, sin d, 0)`` to ``e_z``."""
    d = np.asarray(direction, float)
    axis = np.stack([np.sin(d), -np.cos(d), np.zeros_like(d)], axis=-1)  # e_z x (downhill)
    return rotvec_to_rotation(-tilt * axis)


def heading_rotation(psi: np.ndarray) -> np.ndarray:
    """``R_z(psi)`` (..., 3, 3)."""
    c, s = np.cos(psi), np.sin(psi)
    z, o = np.zeros_like(psi), np.ones_like(psi)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


@dataclass(frozen=True)
class Stance:
    """Equilibria of N poses. ``R_tilt`` (N, 3, 3) B -> W (heading arbitrary); ``z`` (N,)
    height of B's origin above the ground (m); ``feet_W`` (N, K, 3) toe points in W
    (origin below B's origin, ground through it: level, or the board); ``normal_N``
    (N, K) vertical foot forces (springs and the slope's friction share); ``ok`` (N,)
    False where the robot tips; ``residual`` (N, 3) of the equilibrium equations;
    ``R_ground`` (N, 3, 3) ground frame -> W (None: level ground everywhere)."""

    R_tilt: np.ndarray
    z: np.ndarray
    feet_W: np.ndarray
    normal_N: np.ndarray
    ok: np.ndarray
    residual: np.ndarray
    R_ground: np.ndarray | None = None

    @property
    def in_contact(self) -> np.ndarray:
        return self.normal_N > 0


def _residual(q: np.ndarray, feet_B: np.ndarray, com_B: np.ndarray, weight: float, k: float, R_WG: np.ndarray | None = None,
              bumps: np.ndarray | float = 0.0):
    """Equilibrium equations (N, 3) at ``q`` = (z, a, b) (attitude relative to the ground),
    with B -> W, feet in W and vertical foot forces; ``R_WG`` (N, 3, 3) the ground's frame,
    ``bumps`` (N, K) the ground's height under each foot (m)."""
    R = tilt_rotation(q[:, 1], q[:, 2])
    P = np.einsum("nij,nkj->nki", R, feet_B)
    P[..., 2] += q[:, None, 0]
    c = np.einsum("nij,nj->ni", R, com_B)
    c[:, 2] += q[:, 0]
    F = k * np.maximum(0.0, bumps - P[..., 2])
    if R_WG is not None:
        F = F / R_WG[:, 2, 2, None]       # N_k / cos(theta): normal load plus the slope's friction share
        P = np.einsum("nij,nkj->nki", R_WG, P)
        c = np.einsum("nij,nj->ni", R_WG, c)
        R = R_WG @ R
    r = np.stack(
        [
            F.sum(1) - weight,
            np.einsum("nk,nk->n", F, P[..., 1] - c[:, None, 1]),
            np.einsum("nk,nk->n", F, P[..., 0] - c[:, None, 0]),
        ],
        axis=1,
    )
    return r, R, P, F


def _potential(q: np.ndarray, feet_B: np.ndarray, com_B: np.ndarray, weight: float, k: float, bumps: np.ndarray | float = 0.0):
    """Potential energy V (N,), its gradient (N, 3) and Hessian (N, 3, 3) in q = (z, a, b).

    ``V = sum_k k/2 max(0, bump_k - P_k,z)^2 + M g c_z``; only the third row of R_tilt
    enters, ``R3 = [-sin b, cos b sin a, cos b cos a]``. V is C^1 and piecewise
    smooth, so Newton converges in a few steps once the contact set settles.
    """
    a, b = q[:, 1], q[:, 2]
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    zero = np.zeros_like(a)
    R3 = np.stack([-sb, cb * sa, cb * ca], -1)
    R3a = np.stack([zero, cb * ca, -cb * sa], -1)
    R3b = np.stack([-cb, -sb * sa, -sb * ca], -1)
    R3aa = np.stack([zero, -cb * sa, -cb * ca], -1)
    R3ab = np.stack([zero, -sb * ca, sb * sa], -1)
    R3bb = np.stack([sb, -cb * sa, -cb * ca], -1)
    dot = lambda r, x: np.einsum("nj,nkj->nk", r, x)  # noqa: E731
    d = np.maximum(0.0, bumps - (dot(R3, feet_B) + q[:, None, 0]))
    F = k * d
    cz = np.einsum("nj,nj->n", R3, com_B) + q[:, 0]
    V = 0.5 * k * (d * d).sum(1) + weight * cz
    dP = np.stack([np.ones_like(d), dot(R3a, feet_B), dot(R3b, feet_B)], -1)        # dP_z/dq (N, K, 3)
    dc = np.stack([np.ones_like(a), np.einsum("nj,nj->n", R3a, com_B), np.einsum("nj,nj->n", R3b, com_B)], -1)
    grad = -np.einsum("nk,nki->ni", F, dP) + weight * dc
    H = k * np.einsum("nk,nki,nkj->nij", (d > 0).astype(float), dP, dP)
    second = lambda r: -np.einsum("nk,nk->n", F, dot(r, feet_B)) + weight * np.einsum("nj,nj->n", r, com_B)  # noqa: E731
    haa, hab, hbb = second(R3aa), second(R3ab), second(R3bb)
    H[:, 1, 1] += haa
    H[:, 1, 2] += hab
    H[:, 2, 1] += hab
    H[:, 2, 2] += hbb
    return V, grad, H


def _level_height(feet_z: np.ndarray, weight: float, k: float) -> np.ndarray:
    """Height z of the level robot whose lowest feet carry the weight: solves
    ``sum_k k max(0, -(f_k,z + z)) = weight`` exactly (the starting point of the solve)."""
    fz = np.sort(feet_z, axis=1)                       # lowest first
    m = np.arange(1, fz.shape[1] + 1)
    z_m = -np.cumsum(fz, axis=1) / m - weight / (m * k)  # with the m lowest feet in contact
    nxt = np.concatenate([fz[:, 1:], np.full((len(fz), 1), np.inf)], axis=1)
    valid = nxt + z_m >= 0                             # the next foot does not touch
    return z_m[np.arange(len(fz)), np.argmax(valid, axis=1)]


def solve_stance(
    feet_B: np.ndarray,
    com_B: np.ndarray,
    weight_N: float,
    stiffness: float,
    *,
    max_tilt_deg: float = 5.0,
    tol: float = 1e-10,
    max_iter: int = 100,
    ground: np.ndarray | None = None,
    bumps: np.ndarray | None = None,
) -> Stance:
    """Stable compliant-foot equilibrium for each of N poses.

    ``feet_B`` (N, K, 3) toe points in B (m); ``com_B`` (N, 3) total CoM in B;
    ``weight_N`` = M g; ``stiffness`` N/m per foot; ``ground`` (N, 3, 3) ``R_WG``
    of each pose's ground (see :func:`board_rotation`; None: level ground) and
    ``bumps`` (N, K) its height under each foot along its normal (m; None: flat). On
    level ground the equilibrium is the minimum of the potential energy (a
    saddle, e.g. balancing on two feet, is never returned), found by Newton
    steps on an eigenvalue-clamped Hessian with an Armijo line search; on a
    board it is refined from there (module docstring). Converged means every
    equilibrium equation below ``tol`` times ``weight_N`` (N, and N*m per 0.1 m)
    and a stable equilibrium; ``max_tilt_deg`` bounds the tilt relative to the ground.
    """
    feet_B = np.asarray(feet_B, float)
    com_B = np.asarray(com_B, float)
    bumps = np.zeros(feet_B.shape[:2]) if bumps is None else np.asarray(bumps, float)
    sloped = np.zeros(len(feet_B), bool) if ground is None else np.asarray(ground, float)[:, 2, 2] < 1.0 - 1e-12
    com_level = com_B
    if sloped.any():
        # Start from the level solve with the CoM at its projection along gravity onto the board's
        # plane: moved downhill by its height above the feet times tan(theta).
        up = np.asarray(ground, float)[sloped, 2, :]                  # u in G (~B at the start)
        h = com_B[sloped, 2] - (feet_B[sloped, :, 2] - bumps[sloped]).min(axis=1)
        com_level = com_B.copy()
        com_level[sloped, :2] -= up[:, :2] / up[:, 2:] * h[:, None]
    q = np.zeros((len(feet_B), 3))
    q[:, 0] = _level_height(feet_B[..., 2] - bumps, weight_N, stiffness)
    scale = np.array([1.0, 0.1, 0.1]) * weight_N
    max_tilt = np.radians(max_tilt_deg)
    active = np.ones(len(feet_B), bool)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        qa, fa, ca, ba = q[idx], feet_B[idx], com_level[idx], bumps[idx]
        V, g, H = _potential(qa, fa, ca, weight_N, stiffness, ba)
        lam, U = np.linalg.eigh(H)
        floor = 1e-8 * np.maximum(np.abs(lam).max(1, keepdims=True), weight_N * 1e-3)
        step = -np.einsum("nij,nj,nkj,nk->ni", U, 1.0 / np.maximum(np.abs(lam), floor), U, g)
        # Shrink whole steps (a descent direction stays one) to <= 5 cm and <= 0.03 rad:
        # small attitude steps stay in the basin of the level start.
        shrink = np.minimum(1.0, np.minimum(0.05 / np.maximum(np.abs(step[:, 0]), 1e-300),
                                            0.03 / np.maximum(np.abs(step[:, 1:]).max(1), 1e-300)))
        step *= shrink[:, None]
        slope = np.einsum("ni,ni->n", g, step)
        alpha = np.ones(len(idx))
        accepted = np.zeros(len(idx), bool)
        for _ls in range(40):
            qc = qa + alpha[:, None] * step
            Vc = _potential(qc, fa, ca, weight_N, stiffness, ba)[0]
            # Near the minimum V changes below its rounding: a slack lets Newton finish.
            ok = ~accepted & (Vc <= V + 1e-4 * alpha * slope + 1e-12 * (np.abs(V) + 1.0))
            qa[ok] = qc[ok]
            accepted |= ok
            if accepted.all():
                break
            alpha = np.where(accepted, alpha, 0.5 * alpha)
        q[idx] = qa
        r = _residual(qa, fa, ca, weight_N, stiffness, None, ba)[0]
        tilted = np.abs(qa[:, 1:]).max(1) > 3 * max_tilt  # falling over: stop early, judged below
        active[idx] = (np.abs(r / scale).max(1) > tol) & accepted & ~tilted
    r, R, P, F = _residual(q, feet_B, com_level, weight_N, stiffness, None, bumps)
    lam = np.linalg.eigvalsh(_potential(q, feet_B, com_level, weight_N, stiffness, bumps)[2])
    converged = (np.abs(r / scale).max(1) <= tol) & (lam.min(1) > 0)
    tilt = np.degrees(np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0)))  # relative to the ground
    R_ground: np.ndarray | None
    if sloped.any():
        i = np.flatnonzero(sloped)
        R_WG = np.asarray(ground, float)[i]
        q[i], converged[i] = _solve_on_board(q[i], feet_B[i], com_B[i], weight_N, stiffness, R_WG, bumps[i], scale, tol, max_iter)
        tilt[i] = np.degrees(np.arccos(np.clip(tilt_rotation(q[i, 1], q[i, 2])[:, 2, 2], -1.0, 1.0)))
        R_ground = np.broadcast_to(np.eye(3), (len(q), 3, 3)).copy()
        R_ground[i] = R_WG
        r, R, P, F = _residual(q, feet_B, com_B, weight_N, stiffness, R_ground, bumps)
    else:
        R_ground = None if ground is None else np.asarray(ground, float)
    ok = converged & ((F > 0).sum(1) >= 3) & (tilt <= max_tilt_deg)
    return Stance(R, q[:, 0], P, F, ok, r, R_ground)


def _jacobian(q, feet_B, com_B, weight, k, R_WG, bumps, step=1e-7):
    """Central-difference Jacobian d residual / d q, (N, 3, 3)."""
    J = np.empty(q.shape + (3,))
    for j in range(3):
        dq = np.zeros(3)
        dq[j] = step
        J[:, :, j] = (_residual(q + dq, feet_B, com_B, weight, k, R_WG, bumps)[0]
                      - _residual(q - dq, feet_B, com_B, weight, k, R_WG, bumps)[0]) / (2 * step)
    return J


def _solve_on_board(q, feet_B, com_B, weight, k, R_WG, bumps, scale, tol, max_iter):
    """Newton on the board's equilibrium equations from ``q`` (N, 3); returns (q, converged (N,)).

    Steps are limited like the level solver's and halved until the scaled residual
    drops; converged means the residual below ``tol`` and a stable equilibrium
    (every eigenvalue of the Jacobian with a negative real part)."""
    q = q.copy()
    merit = lambda qq: (((_residual(qq, feet_B, com_B, weight, k, R_WG, bumps)[0]) / scale) ** 2).sum(1)  # noqa: E731
    for _ in range(max_iter):
        r = _residual(q, feet_B, com_B, weight, k, R_WG, bumps)[0]
        active = np.abs(r / scale).max(1) > tol
        if not active.any():
            break
        J = _jacobian(q, feet_B, com_B, weight, k, R_WG, bumps)
        step = -np.linalg.solve(J + 1e-12 * np.eye(3) * np.abs(J).max(), r[..., None])[..., 0]
        shrink = np.minimum(1.0, np.minimum(0.01 / np.maximum(np.abs(step[:, 0]), 1e-300),
                                            0.03 / np.maximum(np.abs(step[:, 1:]).max(1), 1e-300)))
        step *= (shrink * active)[:, None]
        m0, alpha, done = merit(q), np.ones(len(q)), ~active
        for _ls in range(30):
            qc = q + alpha[:, None] * step
            better = ~done & (merit(qc) < m0)
            q[better] = qc[better]
            done |= better
            if done.all():
                break
            alpha = np.where(done, alpha, 0.5 * alpha)
        if not (done & active).any():
            break
    r = _residual(q, feet_B, com_B, weight, k, R_WG, bumps)[0]
    # Near level ground the equations are ~diag(-1, -1, 1) grad V: their Jacobian so signed is ~ -Hessian.
    eig = np.linalg.eigvals(_RESIDUAL_SIGN[:, None] * _jacobian(q, feet_B, com_B, weight, k, R_WG, bumps))
    return q, (np.abs(r / scale).max(1) <= tol) & (eig.real.max(1) < 0)


def internal_forces(
    feet_W: np.ndarray, normal_N: np.ndarray, raw: np.ndarray, mu: float | np.ndarray, fraction: float = 0.5
) -> np.ndarray:
    """Self-equilibrated horizontal foot forces (N, K, 3), zero for feet in the air.

    ``raw`` (N, K, 2) random horizontal forces are projected, over the loaded
    feet, onto ``sum h = 0`` and ``sum P x h = 0`` (5 linear constraints, exact
    to rounding), then the whole set is scaled down if a foot would use more
    than ``fraction`` of its friction cone ``mu F_k`` (``mu`` a number or
    broadcastable to (N, K)).
    """
    N, K, _ = feet_W.shape
    loaded = normal_N > 0
    h = np.where(loaded[..., None], raw, 0.0).reshape(N, 2 * K)  # [hx_1, hy_1, hx_2, ...]
    x, y, z = (np.where(loaded, feet_W[..., i], 0.0) for i in range(3))
    one = loaded.astype(float)
    A = np.zeros((N, 5, 2 * K))
    A[:, 0, 0::2] = one                   # sum hx
    A[:, 1, 1::2] = one                   # sum hy
    A[:, 2, 1::2] = -z                    # moment x: -z hy
    A[:, 3, 0::2] = z                     # moment y:  z hx
    A[:, 4, 0::2], A[:, 4, 1::2] = -y, x  # moment z: x hy - y hx
    lam = np.einsum("nij,nj->ni", np.linalg.pinv(A @ np.swapaxes(A, 1, 2), rcond=1e-12), np.einsum("nij,nj->ni", A, h))
    h = (h - np.einsum("nji,nj->ni", A, lam)).reshape(N, K, 2)
    mag = np.linalg.norm(h, axis=-1)
    cap = fraction * mu * normal_N
    ratio = np.where(loaded, mag / np.maximum(cap, 1e-300), 0.0).max(1)
    h *= np.minimum(1.0, 1.0 / np.maximum(ratio, 1e-300))[:, None, None]
    return np.concatenate([h, np.zeros((N, K, 1))], axis=-1)


def contact_forces(
    stance: Stance, raw: np.ndarray, mu: float | np.ndarray, fraction: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """Foot forces in W (heading of ``stance``), (N, K, 3), and which poses slip (N,).

    Vertical ``normal_N`` (normal load plus the slope's friction share) plus
    internal forces from ``raw`` (N, K, 2) in the ground's plane, scaled inside
    ``fraction`` of what each friction cone (``mu`` (N,) or a number) leaves after
    the slope's share ``tan(theta) N_k``. A pose slips where ``tan(theta) >= mu``.
    """
    N = len(stance.normal_N)
    R_WG = np.broadcast_to(np.eye(3), (N, 3, 3)) if stance.R_ground is None else stance.R_ground
    cos = R_WG[:, 2, 2]
    tan = np.sqrt(np.maximum(1.0 - cos**2, 0.0)) / cos
    mu_left = np.broadcast_to(np.asarray(mu, float), (N,)) - tan
    slipping = mu_left <= 0
    feet_G = np.einsum("nji,nkj->nki", R_WG, stance.feet_W)
    h_G = internal_forces(feet_G, stance.normal_N * cos[:, None], raw, np.maximum(mu_left, 0.0)[:, None], fraction)
    return stance.normal_N[..., None] * _E_Z + np.einsum("nij,nkj->nki", R_WG, h_G), slipping


def ground_forces(stance: Stance, horizontal: np.ndarray | None = None) -> np.ndarray:
    """Ground forces on the feet in W (heading zero), (N, K, 3): springs plus internal forces."""
    F = stance.normal_N[..., None] * _E_Z
    return F if horizontal is None else F + horizontal


def applied_wrench(
    R_WB: np.ndarray, phi: np.ndarray, truth, F_W: np.ndarray | None
) -> np.ndarray:
    """What each leg exerts on its transducer, in ft_k about its origin, (N, K, 6) (report eq. 1's w_a).

    Leg weight ``[m_k g u; r_k(phi) x m_k g u]`` with ``u = R_k^T R_WB^T (-z)``,
    plus the ground force ``F_W`` (N, K, 3, world axes; None when hanging) acting
    at the toe. ``truth`` is a :class:`~ftcal_nlp.sim.robot_model.TrueRobot`.
    """
    u_B = -R_WB[:, 2, :]                                            # (N, 3)
    u = np.einsum("kji,nj->nki", truth.R, u_B)                      # (N, K, 3) in ft_k
    f = truth.weights_N[:, None] * u
    w = np.concatenate([f, np.cross(truth.leg_com_ft(phi), f)], axis=-1)
    if F_W is not None:
        f_g = np.einsum("kji,nlj,nkl->nki", truth.R, R_WB, F_W)    # R_k^T R_WB^T F
        w += np.concatenate([f_g, np.cross(truth.foot_ft(phi), f_g)], axis=-1)
    return w
