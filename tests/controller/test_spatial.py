"""Property tests of the spatial maths (Eq 2-6) against definitions, not against the code itself."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.spatial import (
    body_rate_from_euler,
    invert_pose,
    make_pose,
    matrix_to_quat,
    matrix_to_zyx,
    move_wrench,
    quat_to_matrix,
    rotation_exp,
    rotation_log,
    tmat_difference,
    twist_transform,
    wrench_transform,
    zyx_to_matrix,
)

finite = st.floats(-10.0, 10.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
vec6 = st.tuples(*([finite] * 6)).map(np.array)
angle = st.floats(-math.pi, math.pi)
beta_ok = st.floats(-1.5, 1.5)  # away from gimbal lock
quat = st.tuples(*([st.floats(-1, 1)] * 4)).filter(lambda q: sum(v * v for v in q) > 0.1)


def rotation(q: tuple[float, float, float, float]) -> np.ndarray:
    v = np.array(q)
    return quat_to_matrix(v / np.linalg.norm(v))


@given(quat, vec3, vec6, vec6)
def test_eq6_keeps_power_invariant(q, p, F_b, V_b) -> None:
    """Eq 6 with the rigid-body twist map: V_a . F_a == V_b . F_b for the same motion and load."""
    R = rotation(q)
    F_a = wrench_transform(R, p) @ F_b
    V_a = twist_transform(R, p) @ V_b
    assert math.isclose(V_a @ F_a, V_b @ F_b, rel_tol=1e-9, abs_tol=1e-9)


@given(quat, vec3, quat, vec3, vec6)
def test_eq6_composes_and_inverts(q1, p1, q2, p2, F_c) -> None:
    T_a_b = make_pose(rotation(q1), p1)
    T_b_c = make_pose(rotation(q2), p2)
    T_a_c = T_a_b @ T_b_c
    X = lambda T: wrench_transform(T[0:3, 0:3], T[0:3, 3])  # noqa: E731
    np.testing.assert_allclose(X(T_a_b) @ X(T_b_c) @ F_c, X(T_a_c) @ F_c, atol=1e-9)
    np.testing.assert_allclose(X(invert_pose(T_a_b)) @ X(T_a_b), np.eye(6), atol=1e-9)


@given(quat, vec3, vec6)
def test_move_wrench_is_eq6(q, p, F_b) -> None:
    R = rotation(q)
    np.testing.assert_allclose(move_wrench(R, p, F_b, np.empty(6)), wrench_transform(R, p) @ F_b, atol=1e-9)


def test_eq6_pure_force_offset_gives_moment() -> None:
    """A 1 N force along x at a point 1 m along y is a -1 N m moment about z at the origin."""
    F = wrench_transform(np.eye(3), np.array([0.0, 1.0, 0.0])) @ np.array([1.0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(F, [1, 0, 0, 0, 0, -1])


@given(angle, beta_ok, angle, st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2))
def test_eq5_matches_numerical_differentiation(gamma, beta, alpha, gd, bd, ad) -> None:
    """w_body from Eq 5 equals vee(R^T dR/dt) of R(alpha, beta, gamma) differentiated numerically."""
    h = 1e-6
    R0 = zyx_to_matrix(gamma - gd * h, beta - bd * h, alpha - ad * h)
    R1 = zyx_to_matrix(gamma + gd * h, beta + bd * h, alpha + ad * h)
    w_num = rotation_log(R0.T @ R1) / (2 * h)
    np.testing.assert_allclose(body_rate_from_euler(gamma, beta, (gd, bd, ad)), w_num, atol=1e-5)


@given(angle, st.floats(-math.pi / 2, math.pi / 2), angle)
def test_zyx_round_trip_reproduces_rotation(gamma, beta, alpha) -> None:
    """matrix_to_zyx inverts zyx_to_matrix as rotations, including at gimbal lock."""
    R = zyx_to_matrix(gamma, beta, alpha)
    np.testing.assert_allclose(zyx_to_matrix(*matrix_to_zyx(R)), R, atol=1e-7)


@given(angle, beta_ok, angle)
def test_zyx_angles_recovered_away_from_gimbal_lock(gamma, beta, alpha) -> None:
    g, b, a = matrix_to_zyx(zyx_to_matrix(gamma, beta, alpha))
    assert math.isclose(b, beta, abs_tol=1e-7)
    assert math.isclose(math.remainder(g - gamma, 2 * math.pi), 0, abs_tol=1e-6)
    assert math.isclose(math.remainder(a - alpha, 2 * math.pi), 0, abs_tol=1e-6)


@settings(max_examples=200)
@given(quat, vec3, vec3, angle, beta_ok, angle)
def test_tmat_difference_round_trips(q0, p0, dp, gamma, beta, alpha) -> None:
    """Building G from G0 and a known Delta X (Eq 2-3 definitions) gives that Delta X back."""
    T_0_G0 = make_pose(rotation(q0), p0)
    T_0_G = make_pose(T_0_G0[0:3, 0:3] @ zyx_to_matrix(gamma, beta, alpha), p0 + dp)
    dx = tmat_difference(T_0_G0, T_0_G[0:3, 0:3], T_0_G[0:3, 3], np.empty(6))
    np.testing.assert_allclose(dx[0:3], dp, atol=1e-9)
    # Angles are equal modulo 2 pi (+pi and -pi are the same rotation).
    wrapped = np.remainder(dx[3:6] - np.array([gamma, beta, alpha]) + np.pi, 2 * np.pi) - np.pi
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-6)


def test_tmat_difference_sign_convention() -> None:
    """G rotated +0.3 rad about G0's z-axis reads alpha = +0.3 (Eq 3 with the sign of Eq 2)."""
    T_0_G0 = make_pose(zyx_to_matrix(0.0, 0.5, 0.0), np.zeros(3))
    T_0_G = make_pose(T_0_G0[0:3, 0:3] @ zyx_to_matrix(0.0, 0.0, 0.3), np.zeros(3))
    np.testing.assert_allclose(
        tmat_difference(T_0_G0, T_0_G[0:3, 0:3], T_0_G[0:3, 3], np.empty(6)), [0, 0, 0, 0, 0, 0.3], atol=1e-12
    )


@given(vec3.filter(lambda w: np.linalg.norm(w) < 3.1))
def test_rotation_log_exp_round_trip(w) -> None:
    np.testing.assert_allclose(rotation_log(rotation_exp(w)), w, atol=1e-7)


@given(quat)
def test_quaternion_round_trip(q) -> None:
    R = rotation(q)
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(R)), R, atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-8, 0.3, 2.0, math.pi - 1e-5, math.pi])
def test_rotation_log_near_zero_and_pi_gives_the_rotation_back(angle: float) -> None:
    """Each branch of the log map (small angle, general, near pi, where the axis comes from the
    symmetric part) returns the rotation vector of a rotation about a skew axis (the near-pi
    branch ignores the antisymmetric part: off by about pi minus the angle)."""
    axis = np.array([0.48, -0.6, 0.64])
    w = axis * angle
    got = rotation_log(rotation_exp(w))
    if angle == math.pi:  # +pi and -pi about the axis are the same rotation
        got = got * np.sign(got @ axis)
    np.testing.assert_allclose(got, w, atol=1e-7 + 2.0 * (math.pi - angle) * (math.pi - angle < 1e-4))
