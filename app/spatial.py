"""Spatial maths of the paper: poses, Z-Y-X angles, Eq 2-6.

Conventions (see ``docs/conventions.md``):

* ``T_a_b`` is the 4x4 pose of frame b in frame a (the paper's ^aT_b); ``R_a_b`` and
  ``p_a_b`` are its rotation (3x3) and translation (3,) in metres.
* Wrenches are ``[f; m]`` (N, N m), twists ``[v; w]`` (m/s, rad/s). ``F_S`` is a wrench
  applied at the origin of {S} and expressed in {S} coordinates.
* Delta X is ``[x, y, z, gamma, beta, alpha]`` (Eq 4) with ``R = Rz(alpha) Ry(beta) Rx(gamma)``.
* Quaternions are ``wxyz`` (MuJoCo, viser).

The functions the servo tick uses are compiled with numba (``@njit``): for 3-vectors and single
angles the interpreter and numpy call overheads would otherwise dominate the tick. From Python
they are called like any function, with numpy arrays.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from app.compiled import F8, is_f8

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]
SHAPE_44 = (4, 4)


def zyx_to_matrix(gamma: float, beta: float, alpha: float) -> Array:
    """``Rz(alpha) @ Ry(beta) @ Rx(gamma)`` (angles in rad), shape (3, 3)."""
    R = np.empty((3, 3))
    zyx_to_matrix_into(gamma, beta, alpha, R)
    return R


@njit(cache=True)
def norm3(v: Array) -> float:
    """``|v|`` of a 3-vector without overflow: components up to ~1e308 give their finite norm
    (a sum of squares turns inf above ~1e154, and a limit divided by it turns the vector to 0)."""
    return math.hypot(math.hypot(v[0], v[1]), v[2])


@njit(cache=True)
def zyx_to_matrix_into(gamma: float, beta: float, alpha: float, R: Array) -> None:
    """:func:`zyx_to_matrix` written into ``R`` (3, 3), allocating nothing (a per-tick operator's)."""
    ca, sa = math.cos(alpha), math.sin(alpha)
    cb, sb = math.cos(beta), math.sin(beta)
    cg, sg = math.cos(gamma), math.sin(gamma)
    R[0, 0], R[0, 1], R[0, 2] = ca * cb, ca * sb * sg - sa * cg, ca * sb * cg + sa * sg
    R[1, 0], R[1, 1], R[1, 2] = sa * cb, sa * sb * sg + ca * cg, sa * sb * cg - ca * sg
    R[2, 0], R[2, 1], R[2, 2] = -sb, cb * sg, cb * cg


@njit(cache=True)
def matrix_to_zyx(R: Array) -> tuple[float, float, float]:
    """Z-Y-X angles ``(gamma, beta, alpha)`` (rad) of rotation ``R`` (3, 3) (Craig 1989).

    ``beta`` is in [-pi/2, pi/2]. At gimbal lock (cos(beta) = 0) only ``alpha -+ gamma`` is
    defined; there ``gamma`` is set to 0 so the result still reproduces ``R``.
    """
    cb = math.hypot(R[0, 0], R[1, 0])
    beta = math.atan2(-R[2, 0], cb)
    if cb > 1e-9:
        return math.atan2(R[2, 1], R[2, 2]), beta, math.atan2(R[1, 0], R[0, 0])
    return 0.0, beta, math.atan2(-R[0, 1], R[1, 1])


@njit(cache=True)
def tmat_difference(T_0_G0: Array, R_0_G: Array, p_0_G: Array, out: Array) -> Array:
    """Eq 2-4: Delta X of grip {G} relative to the reference {G0}, written into ``out`` (6,).

    Translation is ``p_0_G - p_0_G0`` in base {0} coordinates (Eq 2). Orientation is
    ``R_G0_G = R_0_G0^T R_0_G`` (Eq 3 read with the sign of Eq 2; the paper's printed right-hand
    side is its transpose), expressed as Z-Y-X angles ``[gamma, beta, alpha]`` (Eq 4).
    """
    R_rel = np.empty((3, 3))
    for i in range(3):
        out[i] = p_0_G[i] - T_0_G0[i, 3]
        for j in range(3):
            R_rel[i, j] = T_0_G0[0, i] * R_0_G[0, j] + T_0_G0[1, i] * R_0_G[1, j] + T_0_G0[2, i] * R_0_G[2, j]
    out[3], out[4], out[5] = matrix_to_zyx(R_rel)
    return out


@njit(cache=True)
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


@njit(cache=True)
def move_wrench(R_a_b: Array, p_a_b: Array, F_b: Array, out: Array) -> Array:
    """Eq 6 without forming the matrix: ``F_b`` at {b} in {b} as the wrench at {a} in {a}, into ``out``.

    Same as ``wrench_transform(R_a_b, p_a_b) @ F_b``, i.e. ``[R f; R m + p x (R f)]``.
    """
    for i in range(3):
        out[i] = R_a_b[i, 0] * F_b[0] + R_a_b[i, 1] * F_b[1] + R_a_b[i, 2] * F_b[2]
    for i in range(3):
        out[3 + i] = R_a_b[i, 0] * F_b[3] + R_a_b[i, 1] * F_b[4] + R_a_b[i, 2] * F_b[5]
    px, py, pz = p_a_b[0], p_a_b[1], p_a_b[2]
    fx, fy, fz = out[0], out[1], out[2]
    out[3] += py * fz - pz * fy
    out[4] += pz * fx - px * fz
    out[5] += px * fy - py * fx
    return out


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


@njit(cache=True)
def quat_to_matrix(q_wxyz: Array) -> Array:
    """Rotation (3, 3) of a unit quaternion ``[w, x, y, z]``."""
    R = np.empty((3, 3))
    quat_to_matrix_into(q_wxyz, R)
    return R


@njit(cache=True)
def quat_to_matrix_into(q_wxyz: Array, R: Array) -> None:
    """:func:`quat_to_matrix` of ``q_wxyz`` written into ``R`` (3, 3), allocating nothing."""
    w, x, y, z = q_wxyz[0], q_wxyz[1], q_wxyz[2], q_wxyz[3]
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)


def matrix_to_quat(R: Array) -> Array:
    """Unit quaternion ``[w, x, y, z]`` (w >= 0) of rotation ``R`` (3, 3)."""
    out = np.empty(4)
    quat_into(np.ascontiguousarray(R, dtype=float), out)
    return out


@njit(cache=True)
def quat_into(R: Array, out: Array) -> None:
    """Write the unit quaternion ``[w, x, y, z]`` (w >= 0) of rotation ``R`` (3, 3) into ``out`` (4,)
    (:func:`quat_of`)."""
    out[0], out[1], out[2], out[3] = quat_of(R)


@njit(cache=True)
def quat_of(R: Array) -> tuple[float, float, float, float]:
    """The unit quaternion ``(w, x, y, z)`` (w >= 0) of the rotation in ``R[0:3, 0:3]`` (a (3, 3)
    rotation or a (4, 4) pose; no view made) by Shepperd's method: the largest of the four squared
    components is taken from the diagonal."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0:
        norm = -norm
    return w / norm, x / norm, y / norm, z / norm


@njit(cache=True)
def cross3(a: Array, b: Array) -> Array:
    """``a x b`` for two vectors of shape (3,) (``numpy.cross`` costs microseconds on 3-vectors)."""
    out = np.empty(3)
    cross3_into(a, b, out)
    return out


@njit(cache=True)
def cross3_into(a: Array, b: Array, out: Array) -> None:
    """:func:`cross3` of ``a`` and ``b`` written into ``out`` (3,) (which may be either), allocating nothing."""
    c0, c1, c2 = a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]
    out[0], out[1], out[2] = c0, c1, c2


@njit(cache=True)
def rotation_log(R: Array) -> Array:
    """Rotation vector (3,) (axis times angle, rad) of ``R``; the SO(3) log map."""
    out = np.empty(3)
    rotation_log_into(R, out)
    return out


@njit(cache=True)
def rotation_log_into(R: Array, out: Array) -> None:
    """:func:`rotation_log` of ``R`` written into ``out`` (3,), allocating nothing (a per-tick
    reduction's)."""
    cos_t = max(-1.0, min(1.0, (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) * 0.5))
    theta = math.acos(cos_t)
    v0, v1, v2 = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    if theta < 1e-6:
        out[0], out[1], out[2] = 0.5 * v0, 0.5 * v1, 0.5 * v2
        return
    if math.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes; take the axis from the symmetric part
        # M = (R + I) / 2, column k of its largest diagonal entry.
        k = 0
        for i in (1, 2):
            if R[i, i] > R[k, k]:
                k = i
        scale = 1.0 / math.sqrt(max((R[k, k] + 1.0) * 0.5, 1e-300))
        for i in range(3):
            out[i] = (R[i, k] + (1.0 if i == k else 0.0)) * 0.5 * scale
        if out[0] * v0 + out[1] * v1 + out[2] * v2 < 0:
            for i in range(3):
                out[i] = -out[i]
        c = theta / math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)
        for i in range(3):
            out[i] *= c
        return
    c = theta / (2.0 * math.sin(theta))
    out[0], out[1], out[2] = v0 * c, v1 * c, v2 * c


@njit(cache=True)
def rotation_exp(w: Array) -> Array:
    """Rotation (3, 3) of rotation vector ``w`` (3,); the SO(3) exp map (Rodrigues)."""
    R = np.empty((3, 3))
    rotation_exp_into(w, R)
    return R


@njit(cache=True)
def rotation_exp_into(w: Array, R: Array) -> None:
    """:func:`rotation_exp` of ``w`` written into ``R`` (3, 3), allocating nothing (a per-tick blend's)."""
    theta = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    # R = I + a K + b K^2 with K = skew(w) and K^2 = w w^T - |w|^2 I.
    if theta < 1e-9:
        a, b = 1.0, 0.0
    else:
        a, b = math.sin(theta) / theta, (1 - math.cos(theta)) / theta**2
    for i in range(3):
        for j in range(3):
            R[i, j] = b * (w[i] * w[j] - (theta * theta if i == j else 0.0)) + (1.0 if i == j else 0.0)
    R[0, 1] -= a * w[2]
    R[0, 2] += a * w[1]
    R[1, 0] += a * w[2]
    R[1, 2] -= a * w[0]
    R[2, 0] -= a * w[1]
    R[2, 1] += a * w[0]


def finite(a: Array) -> bool:
    """True if every entry of ``a`` is finite.

    A float64 array is checked by compiled code (:func:`_all_finite`): once a tick on the slave
    command, where numpy's ``a.sum()`` (the check before) cost 2-4 us on the shared machine
    against ~0.3-0.5 us for the compiled call. (A sum also called huge finite entries that
    overflow it non-finite.)"""
    if a.__class__ is np.ndarray and a.dtype is F8:
        return bool(_all_finite(a))
    return bool(np.isfinite(a).all())


@njit(cache=True)
def _all_finite(a: Array) -> bool:
    """Whether every entry of ``a`` (float64, any shape and layout) is finite."""
    for v in a.flat:  # noqa: SIM110 (no generators in numba)
        if not math.isfinite(v):
            return False
    return True


#: How far (largest entry of ``R^T R - I``, and ``det R - 1``) a pose's rotation may be from a
#: rotation: a float32 orientation, as a device SDK may send, is off by ~1e-7 and rounding over a
#: tick's products by ~1e-15, while anything off by this much would turn the tool visibly (a
#: shear or scale of 1e-4 is 0.1 mm on a 1 m lever) and is no pose.
RIGID_TOLERANCE = 1e-4


def pose_error(T: Array, what: str) -> str | None:
    """Why ``T`` (4, 4) is not a rigid pose (non-finite, a rotation block that is not a rotation
    within :data:`RIGID_TOLERANCE`, or a last row other than ``[0, 0, 0, 1]``), or None."""
    if is_f8(T, SHAPE_44):  # every tick in pose mode: one compiled call and one comparison
        off = _rigid_error(T)
        if off <= RIGID_TOLERANCE:
            return None
    else:
        a = np.asarray(T)
        if a.shape != SHAPE_44 or a.dtype.kind not in "iuf":
            return None  # the command's own check (checked_command) refuses it, with its own message
        off = _rigid_error(a.astype(np.float64))
    if not math.isfinite(off):
        return f"non-finite {what}"
    if off > RIGID_TOLERANCE:
        return (
            f"{what} is not rigid: its rotation block is off a rotation by {off:.3g} (R^T R - I, det R - 1, last row)"
        )
    return None


@njit(cache=True)
def _rigid_error(T: Array) -> float:
    """The largest of ``|R^T R - I|``, ``|det R - 1|`` and the last row's distance from
    ``[0, 0, 0, 1]`` for ``T`` (4, 4); NaN if an entry is not finite."""
    if not _all_finite(T):
        return math.nan
    off = abs(T[3, 0]) + abs(T[3, 1]) + abs(T[3, 2]) + abs(T[3, 3] - 1.0)
    for i in range(3):
        for j in range(3):
            d = T[0, i] * T[0, j] + T[1, i] * T[1, j] + T[2, i] * T[2, j] - (1.0 if i == j else 0.0)
            off = max(off, abs(d))
    det = (
        T[0, 0] * (T[1, 1] * T[2, 2] - T[1, 2] * T[2, 1])
        - T[0, 1] * (T[1, 0] * T[2, 2] - T[1, 2] * T[2, 0])
        + T[0, 2] * (T[1, 0] * T[2, 1] - T[1, 1] * T[2, 0])
    )
    return max(off, abs(det - 1.0))
