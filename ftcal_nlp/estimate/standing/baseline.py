"""The report's standing solver (Sec. III-B): Cayley rotations, alternating least squares.

Rotations ``R_k = cayley(q_k) R_nominal_k`` with ``cayley(q) = (I - [q])(I + [q])^-1``
(unconstrained q in R^3); after the change of variable ``p'_k = R_tilde_k (p_tilde_k + p_B^C)``
eq. 8 is bilinear in (rotations, translations), and the report alternates two
``scipy.optimize.least_squares`` solves (Trust Region Reflective, cost tolerance
``ftol = 1e-3``), fixing one block while solving the other, until the largest
change of a block between successive solutions is below ``1e-3``. Built-in
models only (their ``baseline_rotations``/``baseline_translations``): rotations
``each`` (six Cayley vectors) or fixed; translations ``each`` (six p'_k),
``common`` (p'_k = p_nominal_k - c) or fixed; offsets (Sec. V) solved in one block.
The result is mapped back to the model's own variables so the same uncertainty
code serves both solvers. Non-convergence raises :class:`SolverError`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ...core.errors import ConfigError
from ...core.geometry import cayley, skew
from ...models import ErrorModel, ModelContext
from .nlp import Solution, SolverError
from .problem import K_DIAG, L_numpy, L_numpy_jacobian

_SQRT_K = np.sqrt(K_DIAG)


@dataclass(frozen=True)
class BaselineSettings:
    ftol: float = 1e-3          # the report's cost tolerance of each least_squares call
    step_tol: float = 1e-3      # the report's convergence test: max |change| of a block between passes
    max_passes: int = 200


def _unpack(model: ErrorModel, ctx: ModelContext, q, t, o):
    """Rotations, translations, offsets (numpy) from the baseline blocks."""
    K = ctx.K
    off, _, R_prior, p_prior = ctx.prior.stacked(ctx.legs)
    if model.baseline_rotations == "each":
        R = cayley(q.reshape(K, 3)) @ ctx.R_nominal
    elif model.baseline_rotations == "nominal":
        R = ctx.R_nominal
    else:
        R = R_prior
    if model.baseline_translations == "each":
        p = t.reshape(K, 3)
    elif model.baseline_translations == "common":
        p = ctx.p_nominal - t.reshape(1, 3)
    else:
        p = p_prior
    return R, p, (o.reshape(K, 6) if model.baseline_offsets else off)


def _cayley_jac(q: np.ndarray) -> np.ndarray:
    """``d cayley(q) / d q`` (K, 3, 3, 3): ``dR = -(I + R) [dq] (I + [q])^-1``."""
    R = cayley(q)
    inv = np.linalg.inv(np.eye(3) + skew(q))
    E = skew(np.eye(3))  # E[a] = [e_a]
    return -np.einsum("kij,ajl,klm->kima", np.eye(3) + R, E, inv)


def _dL(R, p, off, prior, legs, balance, which: str) -> np.ndarray:
    """``dL / d(entries of R, p' or offsets)`` (n, 6, n_xi) (``problem.L_numpy_jacobian``)."""
    return L_numpy_jacobian(R, p, off, prior, legs, balance, which)


def solve_baseline(model: ErrorModel, ctx: ModelContext, xi: np.ndarray, balance: str,
                   settings: BaselineSettings = BaselineSettings()) -> tuple[np.ndarray, np.ndarray, np.ndarray, Solution]:
    """Alternating least squares of eq. 8; returns (R (K,3,3), p' (K,3), offsets (K,6), Solution)."""
    if model.baseline_rotations is None or model.baseline_translations is None:
        raise ConfigError(f"the baseline solver supports the built-in models only, not {model.name!r}; use solver='ipopt'",
                          key="standing.solver")
    K, legs, prior = ctx.K, ctx.legs, ctx.prior
    P = len(xi)
    xi_all = xi
    # sum_p ||L xi_p||_K^2 = ||sqrt(K) L R_xi^T||_F^2 with xi = Q R_xi: the same least-squares problem
    # (same cost, same J^T J and J^T r, hence the same TRF steps) with 6 n_xi residuals instead of 6 P.
    if P > xi.shape[1]:
        xi = np.linalg.qr(xi, mode="r")  # type: ignore[assignment]  # numpy's stubs type every mode as QRResult; "r" returns R

    def res(q, t, o):
        R, p, off = _unpack(model, ctx, q, t, o)
        return ((xi @ L_numpy(R, p, off, prior, legs, balance).T) * _SQRT_K).ravel()

    def jac(q, t, o, block):
        R, p, off = _unpack(model, ctx, q, t, o)
        dL = _dL(R, p, off, prior, legs, balance, {"q": "R", "t": "p", "o": "o"}[block])
        if block == "q":  # chain through the Cayley map, leg by leg
            dR = np.einsum("kimb,kmj->kijb", _cayley_jac(q.reshape(K, 3)), ctx.R_nominal)  # R = cayley(q) R_nominal
            dL = np.einsum("kijb,kijxy->kbxy", dR, dL.reshape(K, 3, 3, 6, -1)).reshape(3 * K, 6, -1)
        elif block == "t" and model.baseline_translations == "common":
            dL = -dL.reshape(K, 3, 6, -1).sum(axis=0)
        J = np.einsum("pj,nij->pin", xi, dL) * _SQRT_K[None, :, None]
        return J.reshape(6 * len(xi), -1)

    v = {
        "q": np.zeros(3 * K) if model.baseline_rotations == "each" else np.zeros(0),
        "t": (ctx.p_nominal.ravel().copy() if model.baseline_translations == "each"
              else np.zeros(3) if model.baseline_translations == "common" else np.zeros(0)),
        "o": prior.stacked(legs)[0].ravel().copy() if model.baseline_offsets else np.zeros(0),
    }
    blocks = [b for b in ("q", "t", "o") if v[b].size]
    t0 = time.perf_counter()
    status, passes, change = "", 0, np.inf
    for passes in range(1, settings.max_passes + 1):
        change = 0.0
        for b in blocks:  # solve one block with the others fixed (the report's alternation)
            def with_block(u: np.ndarray, b: str = b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                q, t, o = (u if k == b else v[k] for k in ("q", "t", "o"))
                return q, t, o

            sol = least_squares(lambda u: res(*with_block(u)), v[b], jac=lambda u, b=b: jac(*with_block(u), b),
                                method="trf", ftol=settings.ftol)
            if sol.status <= 0:
                raise SolverError(f"baseline: least_squares on block {b!r} failed: {sol.message}", sol.message)
            change = max(change, float(np.abs(sol.x - v[b]).max()))
            v[b] = sol.x
        if len(blocks) == 1:
            status = "converged (single block)"
            break
        if change < settings.step_tol:
            status = f"converged after {passes} alternations"
            break
    else:
        raise SolverError(f"baseline: alternating least squares did not converge in {settings.max_passes} passes "
                          f"(last change {change:.3g})", "max_passes")
    q, t, o = v["q"], v["t"], v["o"]
    R, p, off = _unpack(model, ctx, q, t, o)
    r = res(q, t, o)
    return R, p, off, Solution(np.zeros(0), status, passes, time.perf_counter() - t0, float(r @ r) / len(xi_all))


def to_model_x(spec, model: ErrorModel, ctx: ModelContext, R: np.ndarray, p: np.ndarray, off: np.ndarray) -> np.ndarray:
    """The built-in model's variable vector that reproduces (R, p', offsets) from the baseline."""
    K = ctx.K
    parts: list[np.ndarray] = []
    if model.baseline_rotations == "each":
        parts += [R[k].reshape(9) for k in range(K)]
    if model.baseline_translations == "each":
        parts += [p[k] for k in range(K)]
    elif model.baseline_translations == "common":
        parts.append(ctx.p_nominal[0] - p[0])
    if model.baseline_offsets:
        parts += [off[k] for k in range(K)]
    x = np.concatenate(parts)
    if x.shape != (spec.x.numel(),):
        raise ValueError(f"baseline: model {model.name!r} variables do not match the baseline blocks")
    return x
