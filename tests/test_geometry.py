"""Property tests of the geometry module: group axioms, power invariance, Cayley, numpy/CasADi twins."""

from dataclasses import dataclass
from typing import Callable

import casadi as ca
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from ftcal_nlp.core import geometry as G

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
vec3 = arrays(np.float64, 3, elements=finite)
small3 = arrays(np.float64, 3, elements=st.floats(-3, 3, allow_nan=False))
vec6 = arrays(np.float64, 6, elements=finite)


def _pose(rv, p):
    return G.rotvec_to_rotation(rv), p


@given(small3, vec3, small3, vec3, vec6)
def test_wrench_transform_composes(rv1, p1, rv2, p2, w):
    # a -> b by (R1, p1), then b -> c by (R2, p2) equals a -> c by the composed pose
    R1, R2 = G.rotvec_to_rotation(rv1), G.rotvec_to_rotation(rv2)
    step = G.transform_wrench(R2, p2, G.transform_wrench(R1, p1, w))
    direct = G.transform_wrench(R2 @ R1, R2 @ p1 + p2, w)
    np.testing.assert_allclose(step, direct, atol=1e-9 * (1 + np.abs(w).max() * (1 + np.abs(p1).max()) * (1 + np.abs(p2).max())))


@given(small3, vec3, vec6)
def test_wrench_transform_inverse(rv, p, w):
    R = G.rotvec_to_rotation(rv)
    back = G.transform_wrench(R.T, -R.T @ p, G.transform_wrench(R, p, w))
    np.testing.assert_allclose(back, w, atol=1e-9 * (1 + np.abs(w).max()) * (1 + np.abs(p).max()))


@given(small3, vec3, vec6, vec6)
def test_power_invariance(rv, p, w, twist):
    # a twist moves with Ad, a wrench with Ad^-T: their pairing (power) is frame independent
    T = G.se3(G.rotvec_to_rotation(rv), p)           # T_B^A: pose of B in A
    Ad = G.adjoint_transpose(T).T                    # Ad_{T_B^A}: twist in B -> twist in A
    w_A = w
    w_B = G.adjoint_transpose(T) @ w_A
    # twists ordered [v; omega] to pair with [f; tau]
    V_B = twist
    V_A = Ad @ V_B
    assert np.isclose(w_B @ V_B, w_A @ V_A, atol=1e-7 * (1 + np.abs(w).max() * np.abs(twist).max() * (1 + np.abs(p).max())))


@given(small3, vec3, vec6)
def test_adjoint_matches_transform_wrench(rv, p, w):
    R = G.rotvec_to_rotation(rv)
    T_A_from_B = G.se3(R, p)                       # pose of source frame s=A... in target t
    # transform_wrench(R, p, w) == [Ad_{T_t^s}]^T w with T_t^s = (R, p)^-1
    np.testing.assert_allclose(
        G.adjoint_transpose(G.se3_inv(T_A_from_B)) @ w, G.transform_wrench(R, p, w), atol=1e-9 * (1 + np.abs(w).max() * (1 + np.abs(p).max()))
    )


@given(arrays(np.float64, 3, elements=st.floats(-100, 100, allow_nan=False)))
def test_cayley_is_proper_rotation_and_inverts(q):
    R = G.cayley(q)
    assert G.is_rotation(R, tol=1e-9)
    np.testing.assert_allclose(G.cayley_inv(R), q, atol=1e-7 * (1 + np.abs(q).max() ** 2))


@given(vec3)
def test_skew_is_cross_product(v):
    u = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(G.skew(v) @ u, np.cross(v, u), atol=1e-12)
    np.testing.assert_allclose(G.unskew(G.skew(v)), v, atol=1e-12)


@settings(max_examples=25)
@given(small3, vec3, vec6)
def test_casadi_twins_agree(q, p, w):
    qs, ps, ws = ca.SX.sym("q", 3), ca.SX.sym("p", 3), ca.SX.sym("w", 6)
    f = ca.Function("f", [qs, ps, ws], [G.transform_wrench(G.cayley(qs), ps, ws), G.cayley_inv(G.cayley(qs)), G.skew(qs)])
    tw, qi, sk = (np.array(x) for x in f(q, p, w))
    np.testing.assert_allclose(tw.ravel(), G.transform_wrench(G.cayley(q), p, w), atol=1e-10 * (1 + np.abs(w).max() * (1 + np.abs(p).max())))
    np.testing.assert_allclose(qi.ravel(), q, atol=1e-8)
    np.testing.assert_allclose(sk, G.skew(q), atol=1e-12)


@given(arrays(np.float64, 4, elements=st.floats(-1, 1, allow_nan=False)).filter(lambda q: np.linalg.norm(q) > 0.1))
def test_quaternion_roundtrip(q):
    R = G.quat_to_rotation(q)
    assert G.is_rotation(R, tol=1e-9)
    q2 = G.rotation_to_quat(R)
    qn = q / np.linalg.norm(q)
    assert np.isclose(abs(q2 @ qn), 1.0, atol=1e-9)


@given(small3, st.floats(-np.pi, np.pi))
def test_remove_yaw_drops_heading_only(rv, yaw):
    R = G.rotvec_to_rotation(rv)
    Rz = G.rotvec_to_rotation(np.array([0, 0, yaw]))
    H1, H2 = G.remove_yaw(R), G.remove_yaw(Rz @ R)
    np.testing.assert_allclose(H1, H2, atol=1e-9)
    # z up is kept: gravity direction in B is the same before and after
    np.testing.assert_allclose(H1[2], R[2], atol=1e-12)
    # the heading frame's x is the body x projected on the horizontal plane
    assert abs(H1[1, 0]) < 1e-9 and H1[0, 0] >= -1e-12


def test_quat_convention_maps_body_to_world():
    # 90 deg about z: body x points along world y
    q = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(G.quat_to_rotation(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


# ----------------------------------------------------------------------------- group axioms of the rotation charts
#
# One test body per property, parametrised over the charts of SO(3) in geometry.py (as jaxlie's
# tests/test_group_axioms.py does over its groups): rotation vector (exp/log), Cayley (cayley/cayley_inv),
# unit quaternion (quat_to_rotation/rotation_to_quat). Reference rotations come from scipy, not from
# geometry.py. Tolerances: rotvec and quaternion are well conditioned everywhere (1e-12); the Cayley
# chart q = -tan(theta/2) n blows up at theta = pi (geometry.cayley_inv: "undefined for 180 degree
# rotations"), and both cayley (a linear solve with I + [q], condition ~|q|) and cayley_inv (with I + R)
# lose accuracy in proportion to |q| ~ 2 / (pi - theta): its matrix errors may grow as 16 eps (1 + |q|),
# its parameter errors as 16 eps (1 + |q|)^2, and it is tested down to 1e-9 from pi (|q| ~ 2e9).

EPS = np.finfo(float).eps


@dataclass(frozen=True)
class Chart:
    name: str
    to_matrix: Callable[[np.ndarray], np.ndarray]          # param (..., d) -> (..., 3, 3)
    from_matrix: Callable[[np.ndarray], np.ndarray]        # (..., 3, 3) -> param (..., d)
    from_axis_angle: Callable[[np.ndarray, float], np.ndarray]
    identity: np.ndarray
    inverse: Callable[[np.ndarray], np.ndarray]            # param of R^T
    param_tol: Callable[[np.ndarray], float]               # round trip param -> R -> param
    matrix_tol: Callable[[np.ndarray], float]              # round trip R -> param -> R, given the param
    double_cover: bool = False                             # p and -p name the same rotation
    near_pi_min: float = 0.0                               # smallest pi - angle tested (Cayley: pi is outside the chart)

    def __str__(self) -> str:
        return self.name

    def same_param(self, a: np.ndarray, b: np.ndarray) -> float:
        d = np.abs(a - b).max()
        return min(d, np.abs(a + b).max()) if self.double_cover else d


CHARTS = [
    Chart("rotvec", G.rotvec_to_rotation, G.rotation_to_rotvec, lambda n, th: th * n, np.zeros(3), lambda v: -v,
          param_tol=lambda v: 1e-12, matrix_tol=lambda v: 1e-12),
    Chart("cayley", G.cayley, G.cayley_inv, lambda n, th: -np.tan(th / 2) * n, np.zeros(3), lambda q: -q,
          param_tol=lambda q: 16 * EPS * (1 + np.linalg.norm(q)) ** 2, matrix_tol=lambda q: 16 * EPS * (1 + np.linalg.norm(q)),
          near_pi_min=1e-9),
    Chart("quaternion", G.quat_to_rotation, G.rotation_to_quat, lambda n, th: np.r_[np.cos(th / 2), np.sin(th / 2) * n],
          np.array([1.0, 0, 0, 0]), lambda q: q * [1, -1, -1, -1], param_tol=lambda q: 1e-12, matrix_tol=lambda q: 1e-12,
          double_cover=True),
]
charts = pytest.mark.parametrize("chart", CHARTS, ids=str)
axiom = settings(deadline=None, max_examples=50)

unit3 = arrays(np.float64, 3, elements=st.floats(-1, 1, allow_nan=False)).filter(lambda v: np.linalg.norm(v) > 0.1).map(
    lambda v: v / np.linalg.norm(v))
angles = st.floats(0.0, np.pi - 1e-3)  # away from pi: there the charts are unique (rotvec) or finite (Cayley)


def _scipy(axis, angle):
    return Rotation.from_rotvec(angle * np.asarray(axis)).as_matrix()


def _assert_rotation(R, tol=1e-12):
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=tol)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=tol)


@charts
def test_identity_maps_to_zero_and_back(chart):
    np.testing.assert_array_equal(chart.to_matrix(chart.identity), np.eye(3))
    np.testing.assert_array_equal(chart.from_matrix(np.eye(3)), chart.identity)


@charts
@axiom
@given(unit3, st.floats(0.0, np.pi))
def test_chart_convention_matches_scipy(chart, n, th):
    # exp: the parameter of (axis n, angle th) is the rotation by th about n (right-handed, active)
    assume(np.pi - th >= chart.near_pi_min)  # pi itself is outside the Cayley chart
    p = chart.from_axis_angle(n, th)
    np.testing.assert_allclose(chart.to_matrix(p), _scipy(n, th), atol=max(1e-12, chart.matrix_tol(p)))


@charts
@axiom
@given(unit3, angles)
def test_exp_log_round_trip(chart, n, th):
    p = chart.from_axis_angle(n, th)
    back = chart.from_matrix(chart.to_matrix(p))
    assert chart.same_param(back, p) <= chart.param_tol(p), (p, back)


@charts
@axiom
@given(unit3, st.floats(0.0, np.pi))
def test_log_exp_round_trip(chart, n, th):
    # every rotation (angle up to pi) back to itself; the Cayley chart only to its conditioning
    assume(np.pi - th >= chart.near_pi_min)  # pi itself is outside the Cayley chart
    R = _scipy(n, th)
    p = chart.from_matrix(R)
    assert np.all(np.isfinite(p))
    np.testing.assert_allclose(chart.to_matrix(p), R, atol=chart.matrix_tol(p))


@charts
@axiom
@given(unit3, angles)
def test_inverse_is_transpose_with_det_one(chart, n, th):
    p = chart.from_axis_angle(n, th)
    R = chart.to_matrix(p)
    tol = max(1e-12, chart.matrix_tol(p))
    _assert_rotation(R, tol)
    np.testing.assert_allclose(chart.to_matrix(chart.inverse(p)), R.T, atol=tol)
    np.testing.assert_allclose(R @ chart.to_matrix(chart.inverse(p)), np.eye(3), atol=tol)
    assert chart.same_param(chart.from_matrix(R.T), chart.inverse(p)) <= chart.param_tol(p)


@charts
@axiom
@given(unit3, angles, unit3, angles)
def test_composition_closes(chart, n1, th1, n2, th2):
    # the product of two rotations is a rotation (scipy's composition), and the chart represents it
    p1, p2 = chart.from_axis_angle(n1, th1), chart.from_axis_angle(n2, th2)
    R = chart.to_matrix(p1) @ chart.to_matrix(p2)
    tol = max(1e-12, 2 * chart.matrix_tol(p1), 2 * chart.matrix_tol(p2))
    _assert_rotation(R, tol)
    np.testing.assert_allclose(R, (Rotation.from_rotvec(th1 * n1) * Rotation.from_rotvec(th2 * n2)).as_matrix(), atol=tol)
    p = chart.from_matrix(R)
    np.testing.assert_allclose(chart.to_matrix(p), R, atol=chart.matrix_tol(p))


@charts
@axiom
@given(unit3, st.floats(0.0, 1e-6))
def test_near_pi_round_trip_up_to_sign(chart, n, delta):
    # within 1e-6 of pi the parameter may come back with the other sign (rotvec: the axis -n; quaternion:
    # w ~ 0); the rotation must not change
    delta = chart.near_pi_min + delta * (1 - chart.near_pi_min / 1e-6)  # Cayley: [1e-9, 1e-6], where its tolerance still bites
    th = np.pi - delta
    R = _scipy(n, th)
    p = chart.from_matrix(R)
    assert np.all(np.isfinite(p)), p
    R2 = chart.to_matrix(p)
    _assert_rotation(R2, max(1e-12, chart.matrix_tol(p)))  # Cayley: orthonormal only to ~eps |q|, |q| ~ 2 / delta
    np.testing.assert_allclose(R2, R, atol=chart.matrix_tol(p))
    if chart.name == "rotvec":
        assert abs(np.linalg.norm(p) - th) <= 1e-12
        assert min(np.abs(p - th * n).max(), np.abs(p + th * n).max()) <= 1e-7  # the axis, either sign


@charts
@axiom
@given(unit3, st.floats(0.0, 1e-12))
def test_tiny_angles(chart, n, th):
    p = chart.from_axis_angle(n, th)
    R = chart.to_matrix(p)
    # first order: R = I + th [n] up to the second-order term (<= th^2 / 2) and rounding (no cancellation, no 0/0)
    np.testing.assert_allclose(R - np.eye(3), th * G.skew(n), rtol=0, atol=th**2 + 4 * EPS * th + 1e-300)
    back = chart.from_matrix(R)
    np.testing.assert_allclose(back - chart.identity, p - chart.identity, rtol=0, atol=1e-9 * np.abs(p - chart.identity).max() + 1e-300)


# batched helpers: leading shapes (), (N,), (N, M) give what a loop over single inputs gives

def _rotation_params(shape):
    return arrays(np.float64, shape + (3,), elements=st.floats(-3, 3, allow_nan=False))


BATCHED = {
    "rotvec_to_rotation": (G.rotvec_to_rotation, lambda v: v, 1),
    "rotation_to_rotvec": (G.rotation_to_rotvec, lambda v: G.rotvec_to_rotation(v), 2),
    "cayley": (G.cayley, lambda v: v, 1),
    "cayley_inv": (G.cayley_inv, lambda v: G.rotvec_to_rotation(v * (2.5 / np.pi)), 2),
    "quat_to_rotation": (G.quat_to_rotation, lambda v: np.concatenate([np.cos(np.linalg.norm(v, axis=-1, keepdims=True)), v], -1), 1),
    "rotation_to_quat": (G.rotation_to_quat, lambda v: G.rotvec_to_rotation(v), 2),
    "remove_yaw": (G.remove_yaw, lambda v: G.rotvec_to_rotation(v), 2),
    "yaw_of": (G.yaw_of, lambda v: G.rotvec_to_rotation(v), 2),
}
leading = st.sampled_from([(), (1,), (4,), (2, 3)])


@pytest.mark.parametrize("name", list(BATCHED))
@axiom
@given(st.data())
def test_batched_shapes_match_a_loop(name, data):
    f, make, core_ndim = BATCHED[name]
    lead = data.draw(leading)
    x = make(data.draw(_rotation_params(lead)))
    assert x.shape[: x.ndim - core_ndim] == lead
    out = f(x)
    flat = x.reshape((-1,) + x.shape[x.ndim - core_ndim :])
    loop = np.stack([f(xi) for xi in flat])
    assert out.shape == lead + loop.shape[1:]
    np.testing.assert_allclose(out.reshape(loop.shape), loop, rtol=0, atol=1e-15)


@axiom
@given(small3)
def test_remove_yaw_is_an_idempotent_rotation_that_splits_off_the_heading(rv):
    R = G.rotvec_to_rotation(rv)
    H = G.remove_yaw(R)
    _assert_rotation(H)
    np.testing.assert_allclose(G.remove_yaw(H), H, atol=1e-12)
    assert abs(G.yaw_of(H)) <= 1e-12 or abs(H[0, 0]) + abs(H[1, 0]) < 1e-12
    np.testing.assert_allclose(G.rotvec_to_rotation(np.array([0, 0, G.yaw_of(R)])) @ H, R, atol=1e-12)
