"""Spatial maths of the paper: poses, Z-Y-X angles, Eq 2-6.

Conventions (see ``docs/conventions.md``):

* ``T_a_b`` is the 4x4 pose of frame b in frame a (the paper's ^aT_b); ``R_a_b`` and
  ``p_a_b`` are its rotation (3x3) and translation (3,) in metres.
* Wrenches are ``[f; m]`` (N, N m), twists ``[v; w]`` (m/s, rad/s). ``F_S`` is a wrench
  applied at the origin of {S} and expressed in {S} coordinates.
* Delta X is ``[x, y, z, gamma, beta, alpha]`` (Eq 4) with ``R = Rz(alpha) Ry(beta) Rx(gamma)``.
* Quaternions are ``wxyz`` (MuJoCo, viser).

Scalar work uses :mod:`math` rather than numpy: for 3-vectors and single angles the
numpy call overhead dominates, and these functions sit in the servo tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def rot_x(angle: float) -> Array:
    """Rotation about x by ``angle`` (rad), shape (3, 3)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> Array:
    """Rotation about y by ``angle`` (rad), shape (3, 3)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> Array:
    """Rotation about z by ``angle`` (rad), shape (3, 3)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def zyx_to_matrix(gamma: float, beta: float, alpha: float) -> Array:
    """``Rz(alpha) @ Ry(beta) @ Rx(gamma)`` (angles in rad), shape (3, 3)."""
    ca, sa = math.cos(alpha), math.sin(alpha)
    cb, sb = math.cos(beta), math.sin(beta)
    cg, sg = math.cos(gamma), math.sin(gamma)
    return np.array(
        [
            [ca * cb, ca * sb * sg - sa * cg, ca * sb * cg + sa * sg],
            [sa * cb, sa * sb * sg + ca * cg, sa * sb * cg - ca * sg],
            [-sb, cb * sg, cb * cg],
        ]
    )


def matrix_to_zyx(R: Array | Sequence[Sequence[float]]) -> tuple[float, float, float]:
    """Z-Y-X angles ``(gamma, beta, alpha)`` (rad) of rotation ``R`` (Craig 1989).

    ``R`` may be a (3, 3) array or nested lists (``R.tolist()``, faster in the servo tick).
    ``beta`` is in [-pi/2, pi/2]. At gimbal lock (cos(beta) = 0) only ``alpha -+ gamma`` is
    defined; there ``gamma`` is set to 0 so the result still reproduces ``R``.
    """
    (r00, r01, _), (r10, r11, _), (r20, r21, r22) = R
    cb = math.hypot(r00, r10)
    beta = math.atan2(-r20, cb)
    if cb > 1e-9:
        return math.atan2(r21, r22), beta, math.atan2(r10, r00)
    return 0.0, beta, math.atan2(-r01, r11)


def tmat_difference(T_0_G0: Array, T_0_G: Array) -> list[float]:
    """Eq 2-4: Delta X of grip {G} relative to the reference {G0}, ``[x, y, z, gamma, beta, alpha]``.

    Translation is ``p_0_G - p_0_G0`` in base {0} coordinates (Eq 2). Orientation is
    ``R_G0_G = R_0_G0^T R_0_G`` (Eq 3 read with the sign of Eq 2; the paper's printed right-hand
    side is its transpose), expressed as Z-Y-X angles (Eq 4).
    """
    x, y, z = (T_0_G[0:3, 3] - T_0_G0[0:3, 3]).tolist()
    return [x, y, z, *matrix_to_zyx((T_0_G0[0:3, 0:3].T @ T_0_G[0:3, 0:3]).tolist())]


def body_rate_from_euler(gamma: float, beta: float, rates: tuple[float, float, float]) -> tuple[float, float, float]:
    """Eq 5: body angular velocity (rad/s) from Z-Y-X angle rates ``(gamma', beta', alpha')``.

    ``w = E(gamma, beta) @ rates`` with ``E = [[1, 0, -sb], [0, cg, cb sg], [0, -sg, cb cg]]``;
    w is expressed in the rotating frame. ``det(E) = cos(beta)``: the map loses rank at
    beta = +-90 deg, where distinct angle rates give the same rotation.
    """
    cg, sg = math.cos(gamma), math.sin(gamma)
    cb, sb = math.cos(beta), math.sin(beta)
    gd, bd, ad = rates
    return gd - sb * ad, cg * bd + cb * sg * ad, -sg * bd + cb * cg * ad


def skew(p: Array) -> Array:
    """Cross-product matrix of ``p`` (3,): ``skew(p) @ v == cross(p, v)``."""
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


def wrench_transform(R_a_b: Array, p_a_b: Array) -> Array:
    """Eq 6: the (6, 6) matrix taking a wrench at {b} in {b} to the equivalent at {a} in {a}.

    ``F_a = X @ F_b`` with ``X = [[R, 0], [skew(p) R, R]]``, ``R = R_a_b`` and ``p = p_a_b``
    the position of {b}'s origin in {a}. For Eq 6 itself, a = {MRF} and b = {S}.
    """
    X = np.zeros((6, 6))
    X[0:3, 0:3] = R_a_b
    X[3:6, 3:6] = R_a_b
    X[3:6, 0:3] = skew(p_a_b) @ R_a_b
    return X


def move_wrench(R_a_b: Sequence[Sequence[float]], p_a_b: Sequence[float], F_b: Sequence[float]) -> list[float]:
    """Eq 6 on plain floats: the wrench ``F_b`` at {b} in {b} as the equivalent at {a} in {a}.

    Same as ``wrench_transform(R_a_b, p_a_b) @ F_b``, i.e. ``[R f; R m + p x (R f)]``, written
    out in scalars because in the servo tick this is several times faster than numpy calls.
    """
    f0, f1, f2, m0, m1, m2 = F_b
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R_a_b
    fx = r00 * f0 + r01 * f1 + r02 * f2
    fy = r10 * f0 + r11 * f1 + r12 * f2
    fz = r20 * f0 + r21 * f1 + r22 * f2
    px, py, pz = p_a_b
    return [
        fx,
        fy,
        fz,
        r00 * m0 + r01 * m1 + r02 * m2 + py * fz - pz * fy,
        r10 * m0 + r11 * m1 + r12 * m2 + pz * fx - px * fz,
        r20 * m0 + r21 * m1 + r22 * m2 + px * fy - py * fx,
    ]


def twist_transform(R_a_b: Array, p_a_b: Array) -> Array:
    """The (6, 6) adjoint taking a rigid-body twist at {b} in {b} to the same motion at {a} in {a}.

    ``V_a = A @ V_b`` with ``A = [[R, skew(p) R], [0, R]]``. With :func:`wrench_transform`
    it keeps power invariant: ``V_a . F_a == V_b . F_b`` for ``F_a = X @ F_b``.
    """
    A = np.zeros((6, 6))
    A[0:3, 0:3] = R_a_b
    A[3:6, 3:6] = R_a_b
    A[0:3, 3:6] = skew(p_a_b) @ R_a_b
    return A


def make_pose(R: Array, p: Array) -> Array:
    """Homogeneous 4x4 pose from rotation (3, 3) and translation (3,)."""
    T = np.eye(4)
    T[0:3, 0:3] = R
    T[0:3, 3] = p
    return T


def invert_pose(T_a_b: Array) -> Array:
    """``T_b_a`` from ``T_a_b`` using the rotation transpose."""
    R = T_a_b[0:3, 0:3]
    return make_pose(R.T, -R.T @ T_a_b[0:3, 3])


def quat_to_matrix(q_wxyz: Array) -> Array:
    """Rotation (3, 3) of a unit quaternion ``[w, x, y, z]``."""
    w, x, y, z = (float(v) for v in q_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R: Array) -> Array:
    """Unit quaternion ``[w, x, y, z]`` (w >= 0) of rotation ``R`` (3, 3)."""
    tr = float(R[0, 0] + R[1, 1] + R[2, 2])
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    out = np.array(q, dtype=float)
    out /= np.linalg.norm(out)
    return out if out[0] >= 0 else -out


def rotation_log(R: Array) -> Array:
    """Rotation vector (3,) (axis times angle, rad) of ``R``; the SO(3) log map."""
    cos_t = max(-1.0, min(1.0, (float(R[0, 0] + R[1, 1] + R[2, 2]) - 1.0) * 0.5))
    theta = math.acos(cos_t)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-6:
        return 0.5 * v
    if math.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes; take the axis from the symmetric part.
        M = (R + np.eye(3)) * 0.5
        k = int(np.argmax(np.diag(M)))
        axis = M[:, k] / math.sqrt(max(M[k, k], 1e-300))
        if float(axis @ v) < 0:
            axis = -axis
        return axis / np.linalg.norm(axis) * theta
    return v * (theta / (2.0 * math.sin(theta)))


def rotation_exp(w: Array) -> Array:
    """Rotation (3, 3) of rotation vector ``w`` (3,); the SO(3) exp map (Rodrigues)."""
    theta = math.sqrt(float(w @ w))
    K = skew(w)
    if theta < 1e-9:
        return np.eye(3) + K
    return np.eye(3) + (math.sin(theta) / theta) * K + ((1 - math.cos(theta)) / theta**2) * (K @ K)


def wrap_angle(a: Array) -> Array:
    """Wrap angles (rad) into [-pi, pi), elementwise."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi
