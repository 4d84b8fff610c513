"""Differential inverse kinematics of an arm slave (:mod:`app.slave.arm`), compiled with numba.

Damped least squares, hand-written rather than taken from a library (mink solves a quadratic
program per tick with daqp: some hundred microseconds on this machine, against the 40 us budget
of a whole slave step; here a 6 x 6 solve and an eigenvalue problem per pass cost about 2 us).
Each tick, for a Jacobian ``J`` (6, n) at the joint set-point:

1. Desired twist ``V = V_ref + k_ik e`` with ``e`` the pose error of the set-point against the
   Cartesian reference (``[dp; rotation log]``, m and rad, {w}).
2. Velocity limits: ``qd = J^T (J J^T + lambda^2 I)^-1 (V - J z) + z`` is scaled down uniformly
   until every ``|qd_i| <= qd_max_i`` (the Cartesian direction is kept: the command is limited
   smoothly, never bent). ``z`` is the secondary goal (joint-limit avoidance toward the middle of
   each range) for a redundant arm, zero for a 6-dof one; the first term removes what ``z`` does
   to the tool, so it acts in the null space of ``J``.
3. Joint limits: each joint's rate is bounded by ``k_limit`` times its distance to the soft limit
   (it slows exponentially as it nears the limit and never crosses it). A joint that would
   violate its bound is clamped there and the rest solve again for what it no longer provides
   (the arm slides along the limit rather than stopping), at most n passes.
4. Singularity robustness: the damping ``lambda^2 = lambda_max^2 (1 - (sigma_min / eps)^2)`` turns
   on only where the smallest singular value of ``J`` drops below ``eps`` (Nakamura and Hanafusa
   1986; Maciejewski and Klein 1988), so joint rates stay bounded through a wrist flip.
5. What the set-point cannot reach beyond a dead band is reflected as the limit wrench
   (:func:`limit_wrench`), the wall the operator feels.

The small dense linear algebra (Cholesky of a 6 x 6 Gram matrix, loops instead of numba's BLAS
calls, whose overhead dwarfs these sizes) is written out beside its only user. The rest of the
tick around MuJoCo is :mod:`app.slave.arm_kernel`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from app.spatial import Array, norm3, rotation_log

BoolArray = NDArray[np.bool_]

# Status bits of :func:`ik_step`, :func:`app.slave.arm_kernel.control` and the arm (see :class:`app.slave.arm.ArmStatus`).
SINGULAR, JOINT_LIMIT, VELOCITY, TRACKING, TORQUE = 1, 2, 4, 8, 16
# Slots of the IK parameter vector.
K_IK, LAMBDA_MAX, EPS_SING, K_LIMIT, K_NULL = range(5)


@njit(cache=True)
def pose_error(T_ref: Array, p: Array, R: Array, out: Array) -> None:
    """``[p_ref - p; log(R_ref R^T)]`` (m, rad; {w}) of the pose ``(p, R)`` against ``T_ref`` (4, 4), into ``out`` (6,)."""
    Rr = T_ref[0:3, 0:3]
    M = np.empty((3, 3))
    for i in range(3):
        out[i] = T_ref[i, 3] - p[i]
        for j in range(3):
            M[i, j] = Rr[i, 0] * R[j, 0] + Rr[i, 1] * R[j, 1] + Rr[i, 2] * R[j, 2]
    w = rotation_log(M)
    out[3:6] = w


@njit(cache=True)
def matvec(A: Array, x: Array) -> Array:
    """``A @ x`` by loops (numba's ``@`` calls BLAS, whose overhead dwarfs a 6 x 7 product)."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            out[i] += A[i, j] * x[j]
    return out


@njit(cache=True)
def matTvec(A: Array, x: Array) -> Array:
    """``A.T @ x`` by loops."""
    return matvec(A.T, x)


@njit(cache=True)
def gram_cholesky(J: Array, w: Array, lam2: float) -> Array:
    """Lower Cholesky factor L (6, 6) of ``J W J^T + lam2 I``, ``W = diag(w)`` (n,): a column
    weight of 0 leaves that column of J out (a joint not free), 1 takes it as it is, ``1 / kp``
    gives the compliance of joint servos at the tool (:func:`~app.slave.arm_kernel.bound_lead`)."""
    A = np.zeros((6, 6))
    for i in range(6):
        for j in range(i + 1):
            acc = 0.0
            for k in range(J.shape[1]):
                if w[k] != 0.0:
                    acc += J[i, k] * J[j, k] * w[k]
            A[i, j] = acc
        A[i, i] += lam2
    return cholesky(A)


@njit(cache=True)
def cholesky(A: Array) -> Array:
    """Lower Cholesky factor L (n, n) of a symmetric positive definite ``A`` (n, n) (its lower
    triangle is read; pivots floored at 1e-300 so a singular A gives a finite, huge solve)."""
    L = np.zeros(A.shape)
    cholesky_into(A, L)
    return L


@njit(cache=True)
def cholesky_into(A: Array, L: Array) -> None:
    """:func:`cholesky` of ``A`` written into the lower triangle and diagonal of ``L`` (n, n),
    which :func:`cholesky_solve` alone reads (its upper triangle is left as it was)."""
    n = A.shape[0]
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        L[j, j] = math.sqrt(max(d, 1e-300))
        for i in range(j + 1, n):
            acc = A[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]


@njit(cache=True)
def cholesky_solve(L: Array, b: Array) -> Array:
    """``x`` with ``L L^T x = b`` (n,), L from :func:`cholesky`."""
    n = L.shape[0]
    y = np.empty(n)
    x = np.empty(n)
    cholesky_solve_into(L, b, y, x)
    return x


@njit(cache=True)
def cholesky_solve_into(L: Array, b: Array, y: Array, x: Array) -> None:
    """:func:`cholesky_solve` into ``x`` (n,), with ``y`` (n,) as scratch (neither may be ``b``)."""
    n = L.shape[0]
    for i in range(n):
        acc = b[i]
        for k in range(i):
            acc -= L[i, k] * y[k]
        y[i] = acc / L[i, i]
    for i in range(n - 1, -1, -1):
        acc = y[i]
        for k in range(i + 1, n):
            acc -= L[k, i] * x[k]
        x[i] = acc / L[i, i]


@njit(cache=True)
def smallest_singular_value(J: Array, v: Array) -> float:
    """Smallest singular value of J (6, n), n >= 6, by inverse iteration on ``J J^T`` warm-started
    from ``v`` (6,, updated in place): the servo calls it every tick, so a few iterations track it.

    A tiny regularisation keeps the factorisation defined at an exact singularity.
    """
    L = gram_cholesky(J, np.ones(J.shape[1]), 1e-12)
    x = v.copy()
    rq = 0.0
    for _ in range(4):
        n = math.sqrt(np.sum(x * x))
        x = x / n if n > 0.0 else np.ones(6) / math.sqrt(6.0)
        y = cholesky_solve(L, x)
        rq = np.sum(x * y)  # x^T A^-1 x -> 1 / lambda_min
        x = y
    v[:] = x / math.sqrt(np.sum(x * x))
    return math.sqrt(max(1.0 / rq - 1e-12, 0.0))


@njit(cache=True)
def _dls(J: Array, free: BoolArray, V: Array, z: Array, lam2: float) -> Array:
    """``J_f^T (J_f J_f^T + lam2 I)^-1 (V - J_f z) + z`` on the free joints (zero elsewhere), (n,).

    ``lam2`` includes a tiny floor so that fewer than six free joints still factorise; the part of
    ``V`` they cannot produce then maps to nothing (``J_f^T`` annihilates it).
    """
    n = J.shape[1]
    zf = z.copy()
    for k in range(n):
        if not free[k]:
            zf[k] = 0.0
    r = V - matvec(J, zf)
    w = np.zeros(n)
    for k in range(n):
        if free[k]:
            w[k] = 1.0
    L = gram_cholesky(J, w, lam2 + 1e-9)
    qd = matTvec(J, cholesky_solve(L, r))
    for k in range(n):
        qd[k] = qd[k] + zf[k] if free[k] else 0.0
    return qd


@njit(cache=True)
def ik_rates(
    J: Array,
    e: Array,
    V_ref: Array,
    q_c: Array,
    lo: Array,
    hi: Array,
    qd_max: Array,
    mid: Array,
    p: Array,
    sv: Array,
    qd_out: Array,
    dt: float,
) -> int:
    """Joint rates (rad/s) that move the set-point ``q_c`` toward the reference (module docstring).

    Args:
        J: Jacobian (6, n) of the {MRF} origin and the tool's rotation at ``q_c``, rows ``[v; w]`` in {w}.
        e: Pose error of the set-point against the reference (6,), see :func:`pose_error`.
        V_ref: Reference twist ``[v; w]`` in {w} (6,).
        q_c: Joint set-point (rad), (n,). ``lo``, ``hi``: soft joint limits (rad), (n,).
        qd_max: Joint velocity limits (rad/s), (n,).
        mid: Joint configuration the secondary goal pulls toward (rad), (n,).
        p: ``[k_ik (1/s), lambda_max (-), eps (-), k_limit (1/s), k_null (1/s)]``; ``k_null = 0`` turns
            the secondary goal off.
        sv: ``[sigma_min, v (6)]``: the smallest singular value of J, written, and the warm start
            of its estimate (:func:`smallest_singular_value`), updated.
        qd_out: Output (n,).
        dt: Servo period (s): the error's gain is at most ``1 / dt``, the whole error in one tick.

    Returns:
        Status bits: ``SINGULAR``, ``JOINT_LIMIT``, ``VELOCITY``.
    """
    n = J.shape[1]
    status = 0
    # Above 1/dt the set-point overshoots the reference every tick and from 2/dt it diverges,
    # held only by the velocity limits: k_ik = 500/s at a 100 Hz servo (5 errors a tick) sent the
    # PUMA, asked along x and z only, 57 mm sideways (measured); at 1 kHz and faster this is k_ik.
    V = V_ref + min(p[K_IK], 1.0 / dt) * e
    z = -p[K_NULL] * (q_c - mid)
    sigma_min = smallest_singular_value(J, sv[1:7])
    sv[0] = sigma_min
    lam2 = 0.0
    if sigma_min < p[EPS_SING]:
        status |= SINGULAR
        lam2 = p[LAMBDA_MAX] ** 2 * (1.0 - (sigma_min / p[EPS_SING]) ** 2)
    free = np.ones(n, dtype=np.bool_)
    qd = _dls(J, free, V, z, lam2)
    scale = 1.0
    for k in range(n):
        if abs(qd[k]) * scale > qd_max[k]:
            scale = qd_max[k] / abs(qd[k])
    if scale < 1.0:
        status |= VELOCITY
        V = V * scale
        qd = qd * scale
    # Joint limits: clamp the joints that would overrun their bound, re-solve the rest.
    fixed = np.zeros(n)
    for _ in range(n):
        worst, worst_k, bound = 0.0, -1, 0.0
        for k in range(n):
            if not free[k]:
                continue
            up = min(qd_max[k], p[K_LIMIT] * (hi[k] - q_c[k]))
            down = max(-qd_max[k], p[K_LIMIT] * (lo[k] - q_c[k]))
            over = max(qd[k] - up, down - qd[k])
            if over > worst:
                worst, worst_k, bound = over, k, up if qd[k] > up else down
        if worst_k < 0:
            break
        status |= JOINT_LIMIT
        free[worst_k] = False
        fixed[worst_k] = bound
        qd = _dls(J, free, V - matvec(J, fixed), z, lam2) + fixed
    qd_out[:] = qd
    return status


@njit(cache=True)
def ik_step(
    J: Array,
    T_ref: Array,
    V_ref: Array,
    T_w_MRF: Array,
    q: Array,
    q_c: Array,
    qd_c: Array,
    lo: Array,
    hi: Array,
    qd_max: Array,
    mid: Array,
    p: Array,
    sv: Array,
    feel: Array,
    dt: float,
    e: Array,
    W_limit: Array,
) -> int:
    """One tick of the set-point: pose error, limit wrench, :func:`ik_rates`, integration.

    Args:
        J: Jacobian (6, n) at the measured joints ``q`` (n,); ``T_w_MRF`` the measured {MRF} pose.
        T_ref, V_ref: Cartesian reference pose (4, 4) and twist (6,) in {w}.
        q_c, qd_c: Joint set-point (rad) and its rate (rad/s), (n,), updated in place.
        lo, hi, qd_max, mid, p, sv: As :func:`ik_rates`.
        feel: ``[dead_lin, dead_rot, kp_lin, kp_rot, f_max, t_max]`` of :func:`limit_wrench`.
        dt: Servo period (s).
        e, W_limit: Outputs: the set-point's pose error (6,) and the limit wrench (6,) in {w} at {MRF}.

    Returns:
        Status bits (``TRACKING`` when the limit wrench is non-zero, and those of :func:`ik_rates`).
    """
    pose_error(T_ref, T_w_MRF[0:3, 3], T_w_MRF[0:3, 0:3], e)
    # The set-point's error, linearised about the measured state (see app.slave.arm).
    e -= matvec(J, q_c - q)
    W_limit[:] = limit_wrench(e, feel[0], feel[1], feel[2], feel[3], feel[4], feel[5])
    status = 0
    for i in range(6):
        if W_limit[i] != 0.0:
            status = TRACKING
    status |= ik_rates(J, e, V_ref, q_c, lo, hi, qd_max, mid, p, sv, qd_c, dt)
    for k in range(q_c.shape[0]):
        q_c[k] = min(max(q_c[k] + qd_c[k] * dt, lo[k]), hi[k])
    return status


@njit(cache=True)
def _spring(e: Array, dead: float, k: float, limit: float, out: Array) -> None:
    """``-min(k (|e| - dead), limit) e / |e|`` for a 3-vector beyond the dead band, into ``out`` (3,)."""
    n = norm3(e)
    if n > dead:
        mag = min(k * (n - dead), limit)
        for i in range(3):
            out[i] = -mag * e[i] / n


@njit(cache=True)
def limit_wrench(
    e: Array, dead_lin: float, dead_rot: float, kp_lin: float, kp_rot: float, f_max: float, t_max: float
) -> Array:
    """The wrench (6,) ``[f; m]`` in {w} at {MRF} the operator feels when the arm cannot follow.

    A spring on the part of the pose error ``e`` (6,) (reference ahead of what the arm reaches)
    beyond a dead band ``dead_lin`` (m) / ``dead_rot`` (rad), pulling the tool back toward what it
    can reach, like a wall at the limit; stiffnesses ``kp_lin`` (N/m), ``kp_rot`` (N m/rad),
    saturated at ``f_max`` (N) and ``t_max`` (N m). Zero while the arm tracks.
    """
    out = np.zeros(6)
    _spring(e[0:3], dead_lin, kp_lin, f_max, out[0:3])
    _spring(e[3:6], dead_rot, kp_rot, t_max, out[3:6])
    return out
