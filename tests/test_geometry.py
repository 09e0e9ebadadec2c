"""Property tests of the geometry module: group axioms, power invariance, Cayley, numpy/CasADi twins."""

import casadi as ca
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ftcal_nlp import geometry as G

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
