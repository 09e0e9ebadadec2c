"""Registry of numpy/CasADi twins and one checker for all of them (used by ``test_twins.py``).

A twin is a computation the package states twice, once for numpy arrays and once
for CasADi expressions, or once with dual-backend helpers (``geometry.skew`` and
friends look at their argument). Each :class:`TwinCase` names

* ``numpy(*const, *args)``: the numpy side (arrays in, array or list of arrays out);
* ``casadi(*const, *args)``: the CasADi side, or None when ``numpy`` is itself the
  dual-backend function. It receives every ``arg`` as a CasADi matrix of the numpy
  array's shape (a 1-D array of length n as an n x 1 column, a 0-D array as a scalar,
  a 3-D array (K, m, n) as a list of K m x n matrices) and must return the numpy
  side's output in the same layout (a 1-D output as a column);
* ``inputs(rng)``: random differentiable arguments (numpy arrays of fixed shapes);
* ``const(rng)``: optional numeric arguments that stay numpy on both sides (data,
  or the numpy half of a mixed numpy/CasADi call).

:func:`check_twin` draws ``n_points`` random points from an explicit
``numpy.random.Generator``, compares the numpy value with the CasADi one for every
backend in ``backends`` (SX and MX through a ``casadi.Function``, DM by calling the
CasADi side on numbers) to ``rtol`` relative to the output's magnitude, and, with
``jacobian=True``, compares CasADi's symbolic Jacobian with central finite
differences of the numpy side.

Adding a twin: append a ``TwinCase`` to ``TWINS`` (a list of dataclass instances).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

from ftcal_nlp.core import geometry as G
from ftcal_nlp.estimate.hanging import model as hanging_model
from ftcal_nlp.estimate.standing import problem as standing_problem

# Central differences with the step h * max(1, |x_i|): truncation O(h^2) ~ 1e-12 and
# rounding O(eps / h) ~ 2e-10, relative to the output's scale; a derivative that is
# wrong is wrong by O(1). The step itself is therefore a safe, still sharp, tolerance.
FD_STEP = 1e-6
FD_RTOL = FD_STEP
VALUE_RTOL = 1e-12


@dataclass(frozen=True)
class TwinCase:
    name: str
    numpy: Callable[..., Any]
    inputs: Callable[[np.random.Generator], Sequence[np.ndarray]]
    casadi: Callable[..., Any] | None = None
    const: Callable[[np.random.Generator], Sequence[Any]] | None = None
    backends: tuple[str, ...] = ("SX", "DM")
    jacobian: bool = True
    n_points: int = 3
    rtol: float = VALUE_RTOL

    def __str__(self) -> str:  # pytest ids
        return self.name

    @property
    def seed(self) -> int:
        """A fixed seed per case (stable across runs and Python processes)."""
        return zlib.crc32(self.name.encode())


# ----------------------------------------------------------------------------- packing


def _shapes(args: Sequence[np.ndarray]) -> list[tuple[int, ...]]:
    return [np.shape(a) for a in args]


def _pack(args: Sequence[np.ndarray]) -> np.ndarray:
    return np.concatenate([np.ravel(np.asarray(a, float)) for a in args]) if args else np.zeros(0)


def _unpack_numpy(x: np.ndarray, shapes) -> list[np.ndarray]:
    out, i = [], 0
    for s in shapes:
        n = int(np.prod(s, dtype=int))
        out.append(x[i : i + n].reshape(s))
        i += n
    return out


def _row_major(v, m: int, n: int):
    """CasADi m x n matrix from its row-major entries ``v`` (a column)."""
    return ca.reshape(v, n, m).T


def _unpack_casadi(x, shapes) -> list:
    """The numpy layout of :func:`_unpack_numpy` as CasADi matrices (see the module docstring)."""
    out, i = [], 0
    for s in shapes:
        n = int(np.prod(s, dtype=int))
        v = x[i : i + n]
        if len(s) == 0:
            out.append(v)
        elif len(s) == 1:
            out.append(v)
        elif len(s) == 2:
            out.append(_row_major(v, *s))
        elif len(s) == 3:
            k, m, c = s
            out.append([_row_major(v[j * m * c : (j + 1) * m * c], m, c) for j in range(k)])
        else:  # pragma: no cover - no twin takes 4-D arrays
            raise ValueError(f"no CasADi layout for shape {s}")
        i += n
    return out


def _flat_numpy(y) -> np.ndarray:
    if isinstance(y, (list, tuple)):
        return np.concatenate([_flat_numpy(v) for v in y]) if y else np.zeros(0)
    return np.ravel(np.asarray(y, float))


def _flat_casadi(y, numpy_out, where: str):
    """Row-major column of a CasADi output laid out like ``numpy_out``."""
    if isinstance(y, (list, tuple)):
        assert isinstance(numpy_out, (list, tuple)) and len(y) == len(numpy_out), f"{where}: {len(y)} outputs, numpy has {len(numpy_out)}"
        return ca.vertcat(*[_flat_casadi(a, b, where) for a, b in zip(y, numpy_out)])
    assert not isinstance(y, np.ndarray), f"{where}: the CasADi side returned a numpy array (its numpy branch was taken)"
    if not isinstance(y, (ca.SX, ca.MX, ca.DM)):
        y = ca.DM(y)
    ref = np.asarray(numpy_out)
    assert y.numel() == ref.size, f"{where}: CasADi output {y.shape}, numpy output {ref.shape}"
    if ref.ndim == 2:
        assert y.shape == ref.shape, f"{where}: CasADi output {y.shape}, numpy output {ref.shape}"
    return ca.vec(y.T)


def _to_dense(v) -> np.ndarray:
    if isinstance(v, ca.SX):  # a constant SX (a function that builds SX from numbers)
        v = ca.evalf(v)
    return np.asarray(ca.DM(v).full(), float).ravel()


# ----------------------------------------------------------------------------- the check


def _assert_close(got: np.ndarray, ref: np.ndarray, tol: float, what: str) -> None:
    assert got.shape == ref.shape, f"{what}: shape {got.shape} vs {ref.shape}"
    assert np.all(np.isfinite(ref)), f"{what}: non-finite numpy value at a random point"
    err = np.abs(got - ref)
    i = int(np.argmax(err)) if err.size else 0
    assert err.size == 0 or err[i] <= tol, f"{what}: max |difference| {err[i]:.3e} at entry {i} > {tol:.3e} ({got[i]!r} vs {ref[i]!r})"


def check_twin(case: TwinCase, rng: np.random.Generator) -> None:
    """Values of both sides at ``case.n_points`` random points; CasADi Jacobian vs central differences."""
    cas = case.casadi or case.numpy
    for point in range(case.n_points):
        const = tuple(case.const(rng)) if case.const else ()
        args = [np.asarray(a, float) for a in case.inputs(rng)]
        shapes = _shapes(args)
        x0 = _pack(args)
        n = x0.size

        def numpy_at(x):
            return case.numpy(*const, *_unpack_numpy(x, shapes))

        out_np = numpy_at(x0)
        ref = _flat_numpy(out_np)
        scale = max(1.0, float(np.abs(ref).max(initial=0.0)))
        where = f"{case.name} (point {point})"

        for backend in case.backends:
            if backend == "DM":
                y = _flat_casadi(cas(*const, *_unpack_casadi(ca.DM(x0), shapes)), out_np, f"{where} [DM]")
                got = _to_dense(y)
            else:
                sym = getattr(ca, backend).sym("x", n)
                y = _flat_casadi(cas(*const, *_unpack_casadi(sym, shapes)), out_np, f"{where} [{backend}]")
                got = _to_dense(ca.Function("twin", [sym], [y])(x0))
            _assert_close(got, ref, case.rtol * scale, f"{where} [{backend}] value")

        if not case.jacobian:
            continue
        kind = "SX" if "SX" in case.backends else "MX"
        sym = getattr(ca, kind).sym("x", n)
        y = _flat_casadi(cas(*const, *_unpack_casadi(sym, shapes)), out_np, f"{where} [{kind}]")
        J = np.asarray(ca.Function("twin_jac", [sym], [ca.jacobian(y, sym)])(x0).full(), float)
        fd = np.empty((ref.size, n))
        for i in range(n):
            h = FD_STEP * max(1.0, abs(x0[i]))
            e = np.zeros(n)
            e[i] = h
            fd[:, i] = (_flat_numpy(numpy_at(x0 + e)) - _flat_numpy(numpy_at(x0 - e))) / (2 * h)
        jscale = max(scale, float(np.abs(J).max(initial=0.0)))
        _assert_close(J.ravel(), fd.ravel(), FD_RTOL * jscale, f"{where} [{kind}] Jacobian vs central differences (h={FD_STEP:g})")


# ----------------------------------------------------------------------------- random inputs


def rotations(rng: np.random.Generator, n: int | None = None, max_angle: float = np.pi) -> np.ndarray:
    """Random rotation matrices (scipy, independent of geometry.py), angle below ``max_angle``."""
    m = 1 if n is None else n
    axis = rng.normal(size=(m, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    R = Rotation.from_rotvec(axis * rng.uniform(0.0, max_angle, (m, 1))).as_matrix()
    return R[0] if n is None else R


def _normal(*shape, scale=1.0):
    return lambda rng: (rng.normal(scale=scale, size=shape),)


# ----------------------------------------------------------------------------- hanging fixtures

HANGING_GRID = 12


@lru_cache(maxsize=None)
def hanging_problem():
    """A small one-leg ``LegProblem`` (4 recordings, two gravity axes, G = 12) from random readings."""
    from ftcal_nlp.core.data import Recording
    from ftcal_nlp.estimate.hanging.problem import build_leg_problem, check_recordings
    from ftcal_nlp.core.robot import Robot, Transducer

    rng = np.random.default_rng(20240611)
    robot = Robot("twin", 3.0, 9.81, ("L",), {"L": Transducer("L", np.zeros(3), np.eye(3))})
    recs = []
    for j, gb in enumerate(((1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, 0, -1))):
        n = 400
        phi = rng.uniform(0, 2 * np.pi) + np.linspace(0, 4 * np.pi, n)
        w = rng.normal(size=(n, 6)) * [5, 5, 5, 0.5, 0.5, 0.5]
        recs.append(Recording(f"rec{j}", "hanging", 100.0 * j + 0.01 * np.arange(n), {"L": phi}, {"L": w}, None, np.array(gb, float)))
    return build_leg_problem("L", recs, robot, check_recordings(recs, robot), HANGING_GRID)


def _hanging_inputs(rng):
    pb = hanging_problem()
    return (rotations(rng, pb.n_rec, 0.2), np.asarray(6.0 + rng.normal(scale=0.3)), rng.normal(size=6),
            rng.normal(scale=0.05, size=(pb.n_grid, 3)))


def _hanging_residuals_np(R, mg, w_o, r):
    return hanging_model.pseudo_residuals(hanging_problem(), hanging_model.LegState(R, mg, w_o, r))


def _hanging_residuals_sx(R, mg, w_o, r):
    """The CasADi side as ``hanging/nlp.py`` feeds it: forces ``m g R_j a_j``, CoM grid interpolated by ``X~_j``."""
    pb = hanging_problem()
    forces = [mg * ca.mtimes(R[j], ca.DM(pb.a[j])) for j in range(pb.n_rec)]
    res = hanging_model.pseudo_residuals_sx([ca.DM(st.Y.T) for st in pb.stats], [ca.DM(st.x1).T for st in pb.stats], forces, w_o,
                                            [ca.mtimes(r.T, ca.DM(st.X).T) for st in pb.stats])
    return [e.T for e in res]  # (6, K_j) -> the numpy layout (K_j, 6)


def _hanging_rss_np(R, mg, w_o, r, W):
    pb = hanging_problem()
    pure = sum(st.pure_rss for st in pb.stats)
    return W @ (hanging_model.rss(pb, hanging_model.LegState(R, mg, w_o, r)) - pure)


def _hanging_rss_sx(R, mg, w_o, r, W):
    res = [e.T for e in _hanging_residuals_sx(R, mg, w_o, r)]
    return hanging_model.weighted_sumsq_sx(res, W)


# ----------------------------------------------------------------------------- standing fixtures


@lru_cache(maxsize=None)
def standing_prior():
    """A ``Calibration`` prior of the simulated BigAnt (ftcal_nlp.sim truth; no shared sample needed)."""
    from ftcal_nlp.sim import SimConfig, draw_true_robot

    return draw_true_robot(SimConfig(seed=5), np.random.default_rng(5)).calibration()


def _standing_inputs(rng):
    prior = standing_prior()
    K = len(prior.leg_names)
    return rotations(rng, K), rng.normal(scale=0.2, size=(K, 3)), rng.normal(size=(K, 6)) * [2, 2, 2, 0.2, 0.2, 0.2]


def _L_numpy(balance):
    def f(R, p, off):
        prior = standing_prior()
        return standing_problem.L_numpy(R, p, off, prior, prior.leg_names, balance)

    return f


def _L_casadi(balance):
    def f(R, p, off):
        prior = standing_prior()
        K = len(prior.leg_names)
        return standing_problem.L_casadi(R, [p[k, :].T for k in range(K)], [off[k, :].T for k in range(K)], prior, prior.leg_names, balance)

    return f


def _n_xi(balance):
    return standing_problem.n_features(len(standing_prior().leg_names), balance)


def _objective_const(rng):
    return (rng.normal(size=(9, _n_xi("exact"))),)  # xi: 9 poses of features


def _objective_np(xi, L):
    return standing_problem.knorm2(standing_problem.residuals_B(L, xi)).mean()


def _objective_sx(xi, L):
    return standing_problem.objective_casadi(L, ca.DM(standing_problem.moments(xi)))


def _spd6(rng):
    A = rng.normal(size=(6, 6))
    return A @ A.T / 6 + np.eye(6)


def _objective_w_np(xi, L, W):
    r = standing_problem.residuals_B(L, xi)
    return np.einsum("pi,ij,pj->p", r, W, r).mean()


def _objective_w_sx(xi, L, W):
    return standing_problem.objective_casadi(L, ca.DM(standing_problem.moments(xi)), W)


def _balance_residual_inputs(balance):
    def f(rng):
        return (rng.normal(size=_n_xi(balance)),) + _standing_inputs(rng)

    return f


def _balance_residual_np(balance):
    def f(xi, R, p, off):
        from ftcal_nlp.core import balance as B

        m, Mg = B.weights(standing_prior(), standing_prior().leg_names)
        return B.residual(xi[None, :], R, p, off, m, Mg, balance)[0]

    return f


def _balance_residual_sx(balance):
    def f(xi, R, p, off):
        from ftcal_nlp.core import balance as B

        m, Mg = B.weights(standing_prior(), standing_prior().leg_names)
        K = len(R)
        return B.residual(xi, R, [p[k, :].T for k in range(K)], [off[k, :].T for k in range(K)], m, Mg, balance)

    return f


def _balance_residual_mixed_np(balance):
    def f(R, p, off, xi):
        return _balance_residual_np(balance)(xi, R, p, off)

    return f


def _balance_residual_mixed_sx(balance):
    """numpy theta (R (K, 3, 3), p (K, 3), offsets (K, 6)) with a CasADi feature column."""
    def f(R, p, off, xi):
        from ftcal_nlp.core import balance as B

        m, Mg = B.weights(standing_prior(), standing_prior().leg_names)
        return B.residual(xi, R, p, off, m, Mg, balance)

    return f


# ----------------------------------------------------------------------------- the registry

_ALL = ("SX", "MX", "DM")

TWINS: list[TwinCase] = [
    # geometry.py: one definition, numpy or CasADi by the argument's type
    TwinCase("geometry.skew", G.skew, _normal(3, scale=2.0), backends=_ALL),
    TwinCase("geometry.unskew", G.unskew, _normal(3, 3, scale=2.0), backends=_ALL),
    TwinCase("geometry.cayley", G.cayley, _normal(3), backends=_ALL),
    TwinCase("geometry.cayley_inv", G.cayley_inv, lambda rng: (rotations(rng, max_angle=2.5),), backends=_ALL),
    TwinCase("geometry.transform_wrench", G.transform_wrench,
             lambda rng: (rotations(rng), rng.normal(scale=0.3, size=3), rng.normal(scale=5.0, size=6)), backends=_ALL),
    TwinCase("geometry.transform_wrench[numpy pose, CasADi wrench]", G.transform_wrench, _normal(6, scale=5.0),
             const=lambda rng: (rotations(rng), rng.normal(scale=0.3, size=3)), backends=_ALL),
    TwinCase("geometry.cross", G.cross, lambda rng: (rng.normal(size=3), rng.normal(size=3)), backends=_ALL),
    TwinCase("geometry.cross[numpy a, CasADi b]", G.cross, _normal(3), const=lambda rng: (rng.normal(size=3),), backends=_ALL),
    TwinCase("geometry.cross[CasADi a, numpy b]", lambda b, a: G.cross(a, b), _normal(3), const=lambda rng: (np.eye(3)[rng.integers(3)],),
             backends=_ALL),
    TwinCase("geometry.stack_wrench", G.stack_wrench, lambda rng: (rng.normal(size=3), rng.normal(size=3)), backends=_ALL),
    # hanging/model.py: pseudo-residuals of the compressed recordings and their weighted sum of squares
    TwinCase("hanging.pseudo_residuals", _hanging_residuals_np, _hanging_inputs, _hanging_residuals_sx),
    TwinCase("hanging.rss/weighted_sumsq_sx", _hanging_rss_np, lambda rng: _hanging_inputs(rng) + (rng.uniform(0.5, 2.0, 6),),
             _hanging_rss_sx),
    # standing: L(theta) of the balance, both balances; the eq. 8 objective from the moments
    TwinCase("standing.L[exact]", _L_numpy("exact"), _standing_inputs, _L_casadi("exact")),
    TwinCase("standing.L[report]", _L_numpy("report"), _standing_inputs, _L_casadi("report")),
    TwinCase("standing.objective_casadi[K]", _objective_np, lambda rng: (rng.normal(size=(6, _n_xi("exact"))),), _objective_sx,
             const=_objective_const, backends=_ALL),
    TwinCase("standing.objective_casadi[W]", _objective_w_np, lambda rng: (rng.normal(size=(6, _n_xi("exact"))), _spd6(rng)),
             _objective_w_sx, const=_objective_const, backends=_ALL),
    # balance.py: the residual both L's are read off
    TwinCase("balance.residual[exact]", _balance_residual_np("exact"), _balance_residual_inputs("exact"), _balance_residual_sx("exact")),
    TwinCase("balance.residual[report]", _balance_residual_np("report"), _balance_residual_inputs("report"), _balance_residual_sx("report")),
    TwinCase("balance.residual[exact, numpy theta]", _balance_residual_mixed_np("exact"), lambda rng: (rng.normal(size=_n_xi("exact")),),
             _balance_residual_mixed_sx("exact"), const=_standing_inputs),
    TwinCase("balance.residual[report, numpy theta]", _balance_residual_mixed_np("report"), lambda rng: (rng.normal(size=_n_xi("report")),),
             _balance_residual_mixed_sx("report"), const=_standing_inputs),
]
