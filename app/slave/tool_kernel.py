"""The arithmetic of one virtual-slave substep (:mod:`app.slave.tool`), compiled with numba.

:class:`~app.slave.tool.VirtualSlave` keeps MuJoCo for the rigid-body integration and FCL (via
:class:`~app.world.contact.ContactModel`) for contact; what lies between them, the {MRF} state of
the free joint, the rate reference, the saturated PD wrench and the F/T sensor, is here and reads
and writes preallocated arrays. In CPython these few dozen 3-vector operations cost about 100 us a
tick on a 2-core machine (numpy's per-call overhead, not the arithmetic); compiled they cost a
few microseconds, most of it numba's argument unboxing.

Frames as in :mod:`app.world.scene`, plus {C}: the MuJoCo body frame, with its origin at the
tool's centre of mass and the axes of {T}. The free joint's ``qpos`` is ``[p_w_C; q_w_C]``
(quaternion ``wxyz``), ``qvel`` is ``[v_C in {w}; omega in {C}]`` and ``qacc`` likewise.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numba.experimental import structref

from app.compiled import F8, I8, Arrays, ArraysType, array_type
from app.mjcall import call_model_data
from app.slave.arm_ik import cholesky_into, cholesky_solve_into
from app.spatial import (
    Array,
    IntArray,
    cross3_into,
    norm3,
    quat_to_matrix_into,
    rotation_exp_into,
    rotation_log_into,
)
from app.world.contact.force import V_SLIP

# Slots of the PD gain vector handed to :func:`drive_wrench` (see ``SlaveGains``).
KP_LIN, KD_LIN, KP_ROT, KD_ROT, FORCE_LIMIT, TORQUE_LIMIT = range(6)
# Slots of the rest of :func:`tool_substep`'s constant parameter vector, after the PD gains.
K_ACC, MAX_LEAD_LIN, MAX_LEAD_ROT, WEIGHT_W, GRAVITY_W, MASS, INERTIA_C = 6, 12, 13, 14, 17, 20, 21
INERTIA_INV_C, PD_MODES, N_PARAMS = 30, 39, 41
# What :func:`tool_substep` does to the reference before driving toward it.
HOLD, RATE, POSE, KEEP = range(4)
# The largest (omega h)^2 the implicit share of a substep lets a spring on the tool have
# (:func:`implicit_wrench`): omega h = 1, half the explicit step's bound of 2. A numerical choice.
SIGMA_MAX = 1.0
# Slots of the packed F/T reading (the fields of :class:`~app.controller.types.FTReading`).
R_WRENCH, R_ROT, R_ACC, R_OMEGA, N_READING = 0, 6, 15, 21, 24
# The scratch :func:`tool_substep` is handed (its ``work``): each stage writes its intermediates
# there instead of allocating them (~55 ns an allocation, fifty a substep); the stages run one
# after another, so each starts at block 0. N_WORK (3, 3) blocks, then N_WORK6 (6, 6) blocks (for
# :func:`implicit_wrench`'s gains, mass matrices and 6-vectors) in the same array, N_SCRATCH
# (3, 3) blocks in all: one array argument, unboxed once a call.
N_WORK, N_WORK6 = 5, 12
N_SCRATCH = N_WORK + 4 * N_WORK6


@njit(cache=True)
def mul3(A: Array, B: Array) -> Array:
    """``A @ B`` for (3, 3) blocks (any layout; numba's ``@`` would call BLAS)."""
    out = np.empty((3, 3))
    mul3_into(A, B, out)
    return out


@njit(cache=True)
def mul3_into(A: Array, B: Array, out: Array) -> None:
    """:func:`mul3` of ``A`` and ``B`` written into ``out`` (3, 3), which must be neither."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True)
def _mul_t_into(A: Array, B: Array, out: Array) -> None:
    """``A @ B.T`` for (3, 3) blocks, into ``out`` (3, 3), which must be neither."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[j, 0] + A[i, 1] * B[j, 1] + A[i, 2] * B[j, 2]


@njit(cache=True)
def _apply(R: Array, v: Array) -> Array:
    """``R @ v`` for a (3, 3) block and a 3-vector."""
    out = np.empty(3)
    _apply_into(R, v, out)
    return out


@njit(cache=True)
def _apply_into(R: Array, v: Array, out: Array) -> None:
    """:func:`_apply` of ``R`` and ``v`` written into ``out`` (3,) (which may be ``v``); ``R.T``
    (a view) gives ``R.T @ v``."""
    a = R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2]
    b = R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2]
    c = R[2, 0] * v[0] + R[2, 1] * v[1] + R[2, 2] * v[2]
    out[0], out[1], out[2] = a, b, c


@njit(cache=True)
def _saturate(v: Array, limit: float) -> bool:
    """Scale ``v`` (3,) in place down to norm ``limit`` if longer (direction kept); whether it was."""
    n = norm3(v)
    if n > limit:
        s = limit / n
        for i in range(3):
            v[i] *= s
        return True
    return False


@njit(cache=True)
def mrf_state(qpos: Array, qvel: Array, T_C_MRF: Array, T_w_MRF: Array, V_w_MRF: Array, work: Array) -> None:
    """Pose (4, 4) and twist ``[v; w]`` (m/s of the {MRF} origin, rad/s; {w}) of {MRF}, into the outputs.

    Args:
        qpos, qvel: The free joint's position (7,) and velocity (6,) (module docstring).
        T_C_MRF: Constant pose of {MRF} in {C}, (4, 4).
        T_w_MRF, V_w_MRF: Outputs, (4, 4) and (6,).
        work: Scratch, (2, 3, 3) at least (:data:`N_WORK`).
    """
    R_w_C = work[0]
    quat_to_matrix_into(qpos[3:7], R_w_C)
    w_w, r, v = work[1, 0], work[1, 1], work[1, 2]
    _apply_into(R_w_C, qvel[3:6], w_w)
    _apply_into(R_w_C, T_C_MRF[0:3, 3], r)  # centre of mass to {MRF} origin, {w}
    mul3_into(R_w_C, T_C_MRF[0:3, 0:3], T_w_MRF[0:3, 0:3])
    cross3_into(w_w, r, v)
    for i in range(3):
        T_w_MRF[i, 3] = qpos[i] + r[i]
        T_w_MRF[3, i] = 0.0
        V_w_MRF[i] = qvel[i] + v[i]
        V_w_MRF[3 + i] = w_w[i]
    T_w_MRF[3, 3] = 1.0


@njit(cache=True)
def rate_reference(
    twist: Array,
    F_acc: Array,
    T_w_MRF: Array,
    dt: float,
    max_lead_lin: float,
    max_lead_rot: float,
    T_ref: Array,
    V_ref_w: Array,
    work: Array,
) -> None:
    """Integrate the rate reference over ``dt`` (s) (module docstring of :mod:`app.slave.tool`, step 1).

    Args:
        twist: Commanded ``[v; w]``, v (m/s) in {w}, w (rad/s) in {MRF} axes, (6,).
        F_acc: The accommodation term ``K_acc * F_MRF`` (zeros when off), added to ``twist``, (6,).
        T_w_MRF: Current tool pose, (4, 4).
        max_lead_lin, max_lead_rot: How far (m, rad) the reference may lead the tool.
        T_ref, V_ref_w: The reference pose (4, 4), updated in place, and its twist ``[v; w]``
            in {w} (6,), written.
        work: Scratch, (4, 3, 3) at least (:data:`N_WORK`), not holding ``F_acc``.
    """
    R_w_MRF = T_w_MRF[0:3, 0:3]
    v_w, w_w, x = work[0, 0], work[0, 1], work[0, 2]
    p_ref, e_p, e_r = work[1, 0], work[1, 1], work[1, 2]
    R_step, R_ref = work[2], work[3]
    _apply_into(R_w_MRF, F_acc[0:3], v_w)
    for i in range(3):
        v_w[i] = twist[i] + v_w[i]
        x[i] = twist[3 + i] + F_acc[3 + i]
    _apply_into(R_w_MRF, x, w_w)
    for i in range(3):
        V_ref_w[i] = v_w[i]
        V_ref_w[3 + i] = w_w[i]
        p_ref[i] = T_ref[i, 3] + v_w[i] * dt
        x[i] = w_w[i] * dt
    rotation_exp_into(x, R_step)
    mul3_into(R_step, T_ref[0:3, 0:3], R_ref)
    # Following-error limit: never lead the tool by more than the PD can push against.
    for i in range(3):
        e_p[i] = p_ref[i] - T_w_MRF[i, 3]
    n = norm3(e_p)
    if n > max_lead_lin:
        s = max_lead_lin / n
        for i in range(3):
            p_ref[i] = T_w_MRF[i, 3] + e_p[i] * s
    _mul_t_into(R_ref, R_w_MRF, R_step)
    rotation_log_into(R_step, e_r)
    n = norm3(e_r)
    if n > max_lead_rot:
        s = max_lead_rot / n
        for i in range(3):
            e_r[i] = e_r[i] * s
        rotation_exp_into(e_r, R_step)
        mul3_into(R_step, R_w_MRF, R_ref)
    for i in range(3):
        T_ref[i, 3] = p_ref[i]
        for j in range(3):
            T_ref[i, j] = R_ref[i, j]


@njit(cache=True)
def _add_point(r: Array | tuple[float, float, float], n: Array, a: float, b: float, out: Array) -> None:
    """Add to ``out`` (6, 6) the matrix ``J^T (a n n^T + b I) J`` of a point at ``r`` (m, from the
    centre of mass, {w}; (3,) or a 3-tuple): J maps the body's ``[v; w]`` to the point's velocity
    ``v + w x r``."""
    # J^T n = [n; r x n], a tuple: nothing allocated.
    g = (n[0], n[1], n[2], r[1] * n[2] - r[2] * n[1], r[2] * n[0] - r[0] * n[2], r[0] * n[1] - r[1] * n[0])
    for i in range(6):
        for j in range(6):
            out[i, j] += a * g[i] * g[j]
    if b == 0.0:
        return
    # J^T J = [[I, -[r]x], [[r]x, |r|^2 I - r r^T]]
    rr = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    for i in range(3):
        out[i, i] += b
        out[3 + i, 3 + i] += b * rr
        for j in range(3):
            out[3 + i, 3 + j] -= b * r[i] * r[j]
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        # [r]x has -r_k at (i, j) and +r_k at (j, i) for the cyclic (i, j, k)
        out[3 + i, j] -= b * r[k]
        out[3 + j, i] += b * r[k]
        out[i, 3 + j] += b * r[k]
        out[j, 3 + i] -= b * r[k]


@njit(cache=True)
def body_mass(mass: float, I_w: Array, I_inv_w: Array, M: Array, M_inv: Array) -> None:
    """A rigid body's mass matrix ``diag(m, I_w)`` (6, 6) in the coordinates ``[v of the centre
    of mass; w]`` and its inverse, into ``M`` and ``M_inv``; ``I_w`` (kg m^2) its inertia about the
    centre of mass in {w}, (3, 3), ``I_inv_w`` that inverse."""
    M[:, :] = 0.0
    M_inv[:, :] = 0.0
    for i in range(3):
        M[i, i] = mass
        M_inv[i, i] = 1.0 / mass
        for j in range(3):
            M[3 + i, 3 + j] = I_w[i, j]
            M_inv[3 + i, 3 + j] = I_inv_w[i, j]


@njit(cache=True)
def _trace(X: Array, M_inv: Array) -> float:
    """``tr(M^-1 X)`` for (n, n) ``M_inv`` and ``X``."""
    t = 0.0
    for i in range(X.shape[0]):
        for j in range(X.shape[0]):
            t += M_inv[i, j] * X[j, i]
    return t


@njit(cache=True)
def _largest_mode(X: Array, M: Array, M_inv: Array) -> float:
    """The largest eigenvalue of ``M^-1 X`` (1/s^2 for a stiffness, 1/s for a damping), M a mass
    matrix (n, n) (``M_inv`` its inverse) and X symmetric positive semi-definite (n, n): power
    iteration, then the Rayleigh quotient ``x^T X x / x^T M x`` (from below, within a few per
    cent after twelve steps; the callers' margins absorb that)."""
    n = X.shape[0]
    x, y = np.empty(n), np.empty(n)
    return _largest_mode_into(X, M, M_inv, x, y)


@njit(cache=True)
def _largest_mode_into(X: Array, M: Array, M_inv: Array, x: Array, y: Array) -> float:
    """:func:`_largest_mode` with ``x`` and ``y`` (n,) as its scratch."""
    n = X.shape[0]
    for i in range(n):
        x[i] = (10 - i) / 10.0  # 1, 0.9, 0.8, ...: not orthogonal to the modes that matter
    for _ in range(12):
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += X[i, j] * x[j]
            y[i] = s
        top = 0.0
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += M_inv[i, j] * y[j]
            x[i] = s
            top = max(top, abs(s))
        if top == 0.0:
            return 0.0
        x /= top
    num = den = 0.0
    for i in range(n):
        for j in range(n):
            num += x[i] * X[i, j] * x[j]
            den += x[i] * M[i, j] * x[j]
    return num / den


@njit(cache=True)
def correction(hk: float, hc: float, K: Array, C: Array, u: Array, h: float, acc: Array) -> Array:
    """``hk K (u + h acc) + hc C acc`` (n,): how much less a stiffness K and a damping C (n, n)
    push over the substep ``h`` (s), implicit by ``hk = theta_k h`` and ``hc = theta_c h``
    (:func:`implicit_shares`), than at its start, the velocity ``u`` and acceleration ``acc``
    (n,) in the same coordinates."""
    out = np.empty(u.shape[0])
    correction_into(hk, hc, K, C, u, h, acc, out)
    return out


@njit(cache=True)
def correction_into(hk: float, hc: float, K: Array, C: Array, u: Array, h: float, acc: Array, out: Array) -> None:
    """:func:`correction` written into ``out`` (n,), which must be none of the others."""
    n = u.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += hk * K[i, j] * (u[j] + h * acc[j]) + hc * C[i, j] * acc[j]
        out[i] = s


@njit(cache=True)
def shift_wrench(w: Array, dF: Array, R: Array, p: Array, c: Array) -> None:
    """Add to the wrench ``w`` (6,), at the point ``p`` in the axes ``R`` (both {w}), the change
    ``dF`` = ``[force; torque about c]`` ({w}); allocates nothing (``w`` must not overlap the others)."""
    r0, r1, r2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    f0, f1, f2 = dF[0], dF[1], dF[2]
    m0 = dF[3] - (r1 * f2 - r2 * f1)
    m1 = dF[4] - (r2 * f0 - r0 * f2)
    m2 = dF[5] - (r0 * f1 - r1 * f0)
    for i in range(3):
        w[i] += R[0, i] * f0 + R[1, i] * f1 + R[2, i] * f2
        w[3 + i] += R[0, i] * m0 + R[1, i] * m1 + R[2, i] * m2


@njit(cache=True)
def pd_modes(pd: Array, r_C: Array, mass: float, inertia_C: Array, inertia_inv_C: Array) -> tuple[float, float]:
    """The largest modes of the PD alone on the tool, of ``M^-1 K`` (1/s^2) and ``M^-1 C`` (1/s)
    (:func:`implicit_wrench`), its {MRF} at ``r_C`` from the centre of mass (m, {C}): independent
    of the pose, so computed once."""
    K = np.zeros((6, 6))
    C = np.zeros((6, 6))
    _add_point(r_C, r_C, 0.0, pd[KP_LIN], K)
    _add_point(r_C, r_C, 0.0, pd[KD_LIN], C)
    for a in range(3, 6):
        K[a, a] += pd[KP_ROT]
        C[a, a] += pd[KD_ROT]
    M, M_inv = np.empty((6, 6)), np.empty((6, 6))
    body_mass(mass, inertia_C, inertia_inv_C, M, M_inv)
    return _largest_mode(K, M, M_inv), _largest_mode(C, M, M_inv)


@njit(cache=True)
def contact_gains(rows: Array, materials: Array, c: Array, u: Array, K: Array, C: Array) -> None:
    """Add to ``K`` and ``C`` (6, 6) each pushing contact's normal stiffness ``k n n^T``, damping
    ``b n n^T`` and its friction's secant damping ``mu f_n / max(|u_t|, V_SLIP)`` across the
    normal, at the contact point, in a body's coordinates ``[v of the point c; w]`` ({w}); a
    dynamic object taken as still over the substep (:func:`implicit_wrench`).

    Args:
        rows: Contact rows ``[p (3), n (3), depth, sphere, object]``
            (:class:`~app.world.contact.ContactResult`), (k, 9).
        materials: ``[stiffness, damping, friction]`` per object id (N/m, N s/m, -), (n, 3).
        c: The body's reference point (m, {w}), (3,). ``u``: its twist ``[v of c; w]``, (6,).
    """
    for i in range(rows.shape[0]):
        row = rows[i]
        k, b, mu = materials[int(row[8])]
        n = row[3:6]
        r = (row[0] - c[0], row[1] - c[1], row[2] - c[2])  # a tuple: nothing allocated
        # The point's velocity u[0:3] + u[3:6] x r, in scalars (nothing allocated).
        up0 = u[0] + (u[4] * r[2] - u[5] * r[1])
        up1 = u[1] + (u[5] * r[0] - u[3] * r[2])
        up2 = u[2] + (u[3] * r[1] - u[4] * r[0])
        un = up0 * n[0] + up1 * n[1] + up2 * n[2]
        fn = k * row[6] - b * un
        if fn <= 0.0:
            continue  # separating: no force, nothing to linearise
        _add_point(r, n, k, 0.0, K)
        ct = 0.0
        if mu > 0.0:
            ut0, ut1, ut2 = up0 - un * n[0], up1 - un * n[1], up2 - un * n[2]
            ct = mu * fn / max(math.sqrt(ut0 * ut0 + ut1 * ut1 + ut2 * ut2), V_SLIP)
        _add_point(r, n, b - ct, ct, C)


@njit(cache=True)
def implicit_shares(h: float, KC: Array, other_alone: Array, M: Array, M_inv: Array) -> tuple[float, float]:
    """``(theta_k h, theta_c h)`` (s) of the substep ``h`` (s) that hold the stiffest mode of the
    stiffnesses and dampings ``KC`` = ``[contact K, contact C, other K, other C]`` (4, n, n) on a
    system of mass matrix ``M`` (n, n, ``M_inv`` its inverse; any generalized coordinates) at ``(omega h)^2 <=``
    :data:`SIGMA_MAX` and make the damping's decay monotone (:func:`implicit_wrench`); ``(0, 0)``
    where the explicit step is comfortably stable. ``other_alone``: the largest modes of
    ``M^-1 K_other`` (1/s^2) and ``M^-1 C_other`` (1/s), (2,), an upper bound is enough."""
    n = M.shape[0]
    return implicit_shares_into(h, KC, other_alone, M, M_inv, np.empty((n, n)), np.empty(n), np.empty(n))


@njit(cache=True)
def implicit_shares_into(
    h: float, KC: Array, other_alone: Array, M: Array, M_inv: Array, S: Array, x: Array, y: Array
) -> tuple[float, float]:
    """:func:`implicit_shares` with ``S`` (n, n), ``x`` and ``y`` (n,) as its scratch."""
    # Weyl: the largest mode of the others + the contacts is at most the others' plus the contacts' trace.
    sigma_contacts, beta_contacts = h * h * _trace(KC[0], M_inv), h * _trace(KC[1], M_inv)
    if h * h * other_alone[0] + sigma_contacts <= SIGMA_MAX and h * other_alone[1] + beta_contacts <= 1.0:
        return 0.0, 0.0
    _sum_into(KC[0], KC[2], S)
    sigma = h * h * _largest_mode_into(S, M, M_inv, x, y)
    _sum_into(KC[1], KC[3], S)
    beta = h * _largest_mode_into(S, M, M_inv, x, y)
    hk = h * (1.0 / SIGMA_MAX - 1.0 / sigma) if sigma > SIGMA_MAX else 0.0
    hc = h * (1.0 - 1.0 / beta) if beta > 1.0 else 0.0
    return hk, hc


@njit(cache=True)
def _sum_into(A: Array, B: Array, out: Array) -> None:
    """``A + B`` (n, n) into ``out``."""
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            out[i, j] = A[i, j] + B[i, j]


@njit(cache=True)
def implicit_acceleration(h: float, hk: float, hc: float, K: Array, C: Array, M: Array, u: Array, F: Array) -> Array:
    """The acceleration (n,) that makes the substep ``h`` (s) implicit by ``hk``, ``hc``
    (:func:`implicit_shares`) in the stiffness ``K`` and damping ``C`` (n, n): it solves
    ``(M + hc C + hk h K) a = F - hk K u``, ``F`` = ``M a0`` (n,) with ``a0`` the explicit
    acceleration (every force of the substep's start), ``u`` the velocity (n,). The forces then
    change by ``-`` :func:`correction`."""
    n = u.shape[0]
    acc = np.empty(n)
    implicit_acceleration_into(h, hk, hc, K, C, M, u, F, np.empty((n, n)), np.zeros((n, n)), np.empty((2, n)), acc)
    return acc


@njit(cache=True)
def implicit_acceleration_into(
    h: float,
    hk: float,
    hc: float,
    K: Array,
    C: Array,
    M: Array,
    u: Array,
    F: Array,
    A: Array,
    L: Array,
    vectors: Array,
    acc: Array,
) -> None:
    """:func:`implicit_acceleration` into ``acc`` (n,), with ``A``, ``L`` (n, n) and ``vectors``
    (2, n) at least as its scratch."""
    n = u.shape[0]
    rhs = vectors[0]
    for i in range(n):
        hKu = 0.0
        for j in range(n):
            A[i, j] = M[i, j] + hc * C[i, j] + hk * h * K[i, j]
            hKu += hk * K[i, j] * u[j]
        rhs[i] = F[i] - hKu
    cholesky_into(A, L)
    cholesky_solve_into(L, rhs, vectors[1], acc)


@njit(cache=True)
def implicit_wrench(
    h: float,
    rows: Array,
    materials: Array,
    pd: Array,
    force_saturated: bool,
    torque_saturated: bool,
    T_w_MRF: Array,
    T_C_S: Array,
    mass: float,
    inertia_C: Array,
    inertia_inv_C: Array,
    gravity_w: Array,
    qpos: Array,
    qvel: Array,
    contact: Array,
    xfrc: Array,
    pd_alone: Array,
    work: Array,
    work6: Array,
) -> None:
    """Make MuJoCo's (semi-implicit) Euler substep of ``h`` (s) implicit in the stiffnesses and
    dampings on the tool as far as its stability needs: correct the explicit wrench ``xfrc`` and
    the contact's.

    Explicitly, a spring k on a mass m is stable only for ``sigma = (omega h)^2 = k h^2 / m < 4``
    and a damper c only for ``beta = c h / m < 2`` (monotone below 1): a dozen peg spheres of
    100 N/mm on a wall, a light tool, or the viscous band of the regularised friction (``mu f_n /
    V_SLIP``, ~2 10^4 N s/m at 40 N) break them. Linearising the forces about the substep's
    start, the body is pushed by ``F - theta_k K h v' - theta_c C h a`` (``v' = v + h a``), so
    ``(M + theta_c h C + theta_k h^2 K) a = F - theta_k h K v`` (M the mass matrix, F with
    gravity less the gyroscopic term). With semi-implicit Euler's position update a spring's
    ``sigma`` becomes ``sigma / (1 + theta_k sigma)``; ``theta_k = max(0, 1 / SIGMA_MAX - 1 /
    sigma)`` holds it at :data:`SIGMA_MAX` at any stiffness, and ``theta_c = max(0, 1 - 1 /
    beta)`` makes a damper's decay monotone; sigma and beta are those of the largest modes of
    ``h^2 M^-1 K`` and ``h M^-1 C`` (then ``sigma + 2 beta <= 3``, inside the explicit
    spring-damper's ``sigma + 2 beta < 4``). Where the explicit step is
    comfortably stable both are 0 and the step is exactly the explicit one (no numerical damping
    of a soft contact, which the haptic loop would feel); at theta 1 it is backward Euler.
    (:func:`implicit_shares`, :func:`implicit_acceleration`, :func:`correction`; the arm slave's
    substep uses them in its joints' coordinates, :func:`app.slave.arm_kernel.implicit_contacts`.)

    K and C gather, in the body's coordinates ``[v of the centre of mass; w]`` ({w}): each
    pushing contact's (:func:`contact_gains`) and the PD's gains at {MRF} and on the
    rotation, each unless saturated (then it is a constant force). The contact's share of the
    correction is taken off ``contact`` too: the wrench reported, and read by the F/T sensor, is
    the one the step applied, so the reading stays the robot's force on the tool (the sensor's
    ``contact + weight - m a``), as with the explicit step.

    Args:
        h: The substep (s).
        rows: This substep's contact rows ``[p (3), n (3), depth, sphere, object]``
            (:class:`~app.world.contact.ContactResult`), (k, 9).
        materials: ``[stiffness, damping, friction]`` per object id (N/m, N s/m, -), (n, 3).
        pd: The PD's ``[kp_lin, kd_lin, kp_rot, kd_rot, ...]`` (:func:`drive_wrench`).
        force_saturated, torque_saturated: Whether the PD's force and torque were saturated.
        T_w_MRF: The tool's {MRF} pose (4, 4). ``T_C_S``: {S} in the body frame {C}, (4, 4).
        mass, inertia_C: The tool's mass (kg) and inertia about the centre of mass in {C} axes
            (kg m^2), (3, 3); ``inertia_inv_C`` its inverse.
        gravity_w: Gravity in {w} (m/s^2), (3,).
        qpos, qvel: MuJoCo's free joint state (module docstring), (7,), (6,).
        contact: The contact result's ``w`` (``wrench_S``, ``wrench_MRF``, ``force_w``), (15,),
            corrected in place.
        xfrc: In: the explicit ``[force; torque about the centre of mass]`` (N, N m, {w}); out: the
            wrench to apply, (6,).
        pd_alone: :func:`pd_modes`, (2,): without contacts the step is explicit if they allow.
        work, work6: Scratch, (:data:`N_WORK`, 3, 3) and (:data:`N_WORK6`, 6, 6).
    """
    if rows.shape[0] == 0 and h * h * pd_alone[0] <= SIGMA_MAX and h * pd_alone[1] <= 1.0:
        return
    R = work[0]
    quat_to_matrix_into(qpos[3:7], R)
    c = qpos[0:3]
    # [contact K, contact C, PD K, PD C]
    KC, M, M_inv, K, C = work6[0:4], work6[4], work6[5], work6[6], work6[7]
    u, F, d_contact, d_other = work6[8, 0], work6[8, 1], work6[8, 2], work6[8, 3]
    u[0:3] = qvel[0:3]
    _apply_into(R, qvel[3:6], u[3:6])
    KC[:, :, :] = 0.0
    contact_gains(rows, materials, c, u, KC[0], KC[1])
    if not force_saturated:
        r_m = work[4, 2]
        for i in range(3):
            r_m[i] = T_w_MRF[i, 3] - c[i]
        _add_point(r_m, r_m, 0.0, pd[KP_LIN], KC[2])
        _add_point(r_m, r_m, 0.0, pd[KD_LIN], KC[3])
    if not torque_saturated:
        for a in range(3, 6):
            KC[2, a, a] += pd[KP_ROT]
            KC[3, a, a] += pd[KD_ROT]
    I_w, I_inv_w, X = work[1], work[2], work[3]
    mul3_into(R, inertia_C, X)
    _mul_t_into(X, R, I_w)
    mul3_into(R, inertia_inv_C, X)
    _mul_t_into(X, R, I_inv_w)
    body_mass(mass, I_w, I_inv_w, M, M_inv)
    # Blocks 9-11: the shares' and the solve's scratch (a matrix, a factor, their vectors).
    S, L, vectors = work6[9], work6[10], work6[11]
    hk, hc = implicit_shares_into(h, KC, pd_alone, M, M_inv, S, vectors[0], vectors[1])
    if hk == 0.0 and hc == 0.0:
        return  # the explicit step is stable with margin: keep it as it is
    w = u[3:6]
    gyro = work[4, 0]
    _apply_into(I_w, w, gyro)
    cross3_into(w, gyro, gyro)
    for i in range(3):
        F[i] = xfrc[i] + mass * gravity_w[i]
        F[3 + i] = xfrc[3 + i] - gyro[i]
    for i in range(6):
        for j in range(6):
            K[i, j] = KC[0, i, j] + KC[2, i, j]
            C[i, j] = KC[1, i, j] + KC[3, i, j]
    acc = work6[8, 4]
    implicit_acceleration_into(h, hk, hc, K, C, M, u, F, S, L, vectors, acc)
    correction_into(hk, hc, KC[0], KC[1], u, h, acc, d_contact)
    correction_into(hk, hc, KC[2], KC[3], u, h, acc, d_other)
    for i in range(6):
        d_contact[i] = -d_contact[i]
        xfrc[i] += d_contact[i] - d_other[i]
    if rows.shape[0] == 0:
        return
    R_w_MRF = T_w_MRF[0:3, 0:3]
    shift_wrench(contact[6:12], d_contact, R_w_MRF, T_w_MRF[0:3, 3], c)
    R_w_S, p_w_S = work[1], work[4, 1]
    mul3_into(R, T_C_S[0:3, 0:3], R_w_S)
    _apply_into(R, T_C_S[0:3, 3], p_w_S)
    for i in range(3):
        p_w_S[i] = c[i] + p_w_S[i]
    shift_wrench(contact[0:6], d_contact, R_w_S, p_w_S, c)
    for i in range(3):
        contact[12 + i] += d_contact[i]


@njit(cache=True)
def drive_wrench(
    T_w_MRF: Array,
    V_w_MRF: Array,
    T_ref: Array,
    V_ref_w: Array,
    pd: Array,
    qpos: Array,
    contact_force_w: Array,
    contact_MRF: Array,
    weight_w: Array,
    xfrc: Array,
    work: Array,
) -> tuple[bool, bool]:
    """The wrench on the body for one substep: saturated PD at {MRF}, contact, and the robot's
    gravity feedforward for its known tool and payload, into ``xfrc``; returns whether the PD's
    force and its torque were saturated.

    Args:
        T_w_MRF, V_w_MRF: Tool pose (4, 4) and twist (6,) in {w}.
        T_ref, V_ref_w: Reference pose (4, 4) and twist (6,) in {w}.
        pd: ``[kp_lin, kd_lin, kp_rot, kd_rot, force_limit, torque_limit]`` (slots above).
        qpos: The free joint's position (7,); its first three entries are the centre of mass in {w}.
        contact_force_w: Total contact force in {w} (N), (3,).
        contact_MRF: Contact wrench at the {MRF} origin in {MRF} (N, N m), (6,).
        weight_w: Weight of the tool and payload ``m g`` in {w} (N), (3,): the robot holds it up
            (applied at the centre of mass), so the PD's force limit is all for the task.
        xfrc: Output, MuJoCo's ``xfrc_applied`` row: ``[force; torque about the centre of
            mass]`` (N, N m) in {w}, (6,).
        work: Scratch, (3, 3, 3) at least (:data:`N_WORK`).
    """
    R_w_MRF = T_w_MRF[0:3, 0:3]
    E = work[0]
    e_R, f_pd, t_pd = work[1, 0], work[1, 1], work[1, 2]
    f_total, m_contact, r = work[2, 0], work[2, 1], work[2, 2]
    _mul_t_into(T_ref[0:3, 0:3], R_w_MRF, E)
    rotation_log_into(E, e_R)
    for i in range(3):
        f_pd[i] = pd[KP_LIN] * (T_ref[i, 3] - T_w_MRF[i, 3]) + pd[KD_LIN] * (V_ref_w[i] - V_w_MRF[i])
        t_pd[i] = pd[KP_ROT] * e_R[i] + pd[KD_ROT] * (V_ref_w[3 + i] - V_w_MRF[3 + i])
    f_sat = _saturate(f_pd, pd[FORCE_LIMIT])
    t_sat = _saturate(t_pd, pd[TORQUE_LIMIT])
    # Both forces act at the {MRF} origin (the contact moment is already about it); MuJoCo wants
    # the moment about the centre of mass.
    _apply_into(R_w_MRF, contact_MRF[3:6], m_contact)
    for i in range(3):
        f_total[i] = f_pd[i] + contact_force_w[i]
        r[i] = T_w_MRF[i, 3] - qpos[i]
    cross3_into(r, f_total, r)
    for i in range(3):
        xfrc[i] = f_total[i] - weight_w[i]
        xfrc[3 + i] = t_pd[i] + m_contact[i] + r[i]
    return f_sat, t_sat


@njit(cache=True)
def sensor_reading(
    T_w_MRF: Array,
    V_w_MRF: Array,
    qacc: Array,
    T_C_MRF: Array,
    T_C_S: Array,
    inertia_C: Array,
    mass: float,
    gravity_w: Array,
    contact_S: Array,
    valid: bool,
    reading: Array,
    work: Array,
) -> None:
    """F/T reading at {S}: contact + weight - inertial load of the body outboard of the sensor.

    Args:
        T_w_MRF, V_w_MRF: Tool pose (4, 4) and twist (6,) in {w} the forces were computed at.
        qacc: Accelerations ``[a_C in {w}; dw/dt in {C}]`` the body had, (6,).
        T_C_MRF, T_C_S: Constant poses of {MRF} and {S} in {C}, (4, 4).
        inertia_C: Inertia about the centre of mass in {C} axes (kg m^2), (3, 3).
        mass: Outboard mass (kg). ``gravity_w``: gravity in {w} (m/s^2), (3,).
        contact_S: Contact wrench at {S} in {S}, (6,).
        valid: False gives zero wrench and accelerations (the reading is not trustworthy).
        reading: Output, ``[wrench_S (6); R_w_S (9, row-major); acc_w (6); omega_w (3)]`` as
            :class:`~app.controller.types.FTReading` defines them, (24,).
        work: Scratch, (5, 3, 3) at least (:data:`N_WORK`).
    """
    R_w_C, R_w_S = work[0], work[1]
    _mul_t_into(T_w_MRF[0:3, 0:3], T_C_MRF[0:3, 0:3], R_w_C)
    mul3_into(R_w_C, T_C_S[0:3, 0:3], R_w_S)
    w_w = V_w_MRF[3:6]
    for i in range(3):
        reading[R_OMEGA + i] = w_w[i]
        for j in range(3):
            reading[R_ROT + 3 * i + j] = R_w_S[i, j]
    if not valid:
        reading[R_WRENCH : R_WRENCH + 6] = 0.0
        reading[R_ACC : R_ACC + 6] = 0.0
        return
    a_com = qacc[0:3]
    alpha_w, r_com_S, x = work[2, 0], work[2, 1], work[2, 2]
    I_alpha, I_w, f_body = work[3, 0], work[3, 1], work[3, 2]
    m_body, y, z = work[4, 0], work[4, 1], work[4, 2]
    _apply_into(R_w_C, qacc[3:6], alpha_w)
    _apply_into(R_w_C, T_C_S[0:3, 3], r_com_S)  # centre of mass to the {S} origin, {w}
    # I_w x = R I_C R^T x, and the gyroscopic term w x I_w w.
    _apply_into(R_w_C.T, alpha_w, x)
    _apply_into(inertia_C, x, x)
    _apply_into(R_w_C, x, I_alpha)
    _apply_into(R_w_C.T, w_w, x)
    _apply_into(inertia_C, x, x)
    _apply_into(R_w_C, x, I_w)
    for i in range(3):
        f_body[i] = mass * (gravity_w[i] - a_com[i])  # weight minus inertial force, at the centre of mass
    cross3_into(f_body, r_com_S, y)
    cross3_into(w_w, I_w, z)
    for i in range(3):
        m_body[i] = y[i] - (I_alpha[i] + z[i])  # about the {S} origin
    _apply_into(R_w_S.T, f_body, x)
    _apply_into(R_w_S.T, m_body, y)
    for i in range(3):
        reading[R_WRENCH + i] = contact_S[i] + x[i]
        reading[R_WRENCH + 3 + i] = contact_S[3 + i] + y[i]
    cross3_into(alpha_w, r_com_S, x)
    cross3_into(w_w, r_com_S, y)
    cross3_into(w_w, y, y)
    for i in range(3):
        reading[R_ACC + i] = a_com[i] + x[i] + y[i]
        reading[R_ACC + 3 + i] = alpha_w[i]


_F1, _F2, _F3 = (array_type(n, F8) for n in (1, 2, 3))
#: The fields of :func:`tool_substep`'s ``own`` bundle: the slave's own arrays, the same every call
#: (one compiled argument, where fourteen cost ~0.09 us each to unbox: :mod:`app.compiled`).
_OWN_FIELDS = {"mj": array_type(1, I8), "params": _F1, "frames": _F3, "T_w_MRF": _F2, "V_w_MRF": _F1}
_OWN_FIELDS |= {"T_ref": _F2, "V_ref_w": _F1, "qpos": _F1, "qvel": _F1, "qacc": _F1, "xfrc": _F1, "scratch": _F3}
_OWN = ArraysType([*_OWN_FIELDS.items(), ("materials", _F2), ("reading", _F1)])


@njit(cache=True)
def own_arrays(
    mj: IntArray,
    params: Array,
    frames: Array,
    T_w_MRF: Array,
    V_w_MRF: Array,
    T_ref: Array,
    V_ref_w: Array,
    qpos: Array,
    qvel: Array,
    qacc: Array,
    xfrc: Array,
    scratch: Array,
    materials: Array,
    reading: Array,
) -> Arrays:
    """:func:`tool_substep`'s ``own`` bundle of these arrays (C-contiguous: ``mj`` int64, the rest
    float64; no copy): what each is, :func:`tool_substep`."""
    own: Any = structref.new(_OWN)  # type: ignore[call-arg]  # an intrinsic, typed by numba
    own.mj = mj
    own.params = params
    own.frames = frames
    own.T_w_MRF = T_w_MRF
    own.V_w_MRF = V_w_MRF
    own.T_ref = T_ref
    own.V_ref_w = V_ref_w
    own.qpos = qpos
    own.qvel = qvel
    own.qacc = qacc
    own.xfrc = xfrc
    own.scratch = scratch
    own.materials = materials
    own.reading = reading
    return own


@njit(cache=True)
def tool_substep(
    own: Arrays,
    reference: int,
    twist: Array,
    T_cmd: Array,
    prev_contact: Array,
    dt: float,
    contact: Array,
    valid: bool,
    rows: Array,
    h: float,
) -> None:
    """One substep of the ideal tool in one call: reference, PD drive, linearly implicit
    correction (:func:`implicit_wrench`), ``mj_step``, F/T sensor, new state.

    Args:
        own: The slave's own arrays (:func:`own_arrays`):

            - ``mj``: ``[mj_step address, mjModel*, mjData*]`` (:mod:`app.mjcall`), (3,);
            - ``params``: ``[pd (6, see drive_wrench); K_acc (6); max_lead_lin; max_lead_rot;
              m g in {w} (3); g in {w} (3); mass; inertia_C (9); its inverse (9); :func:`pd_modes`
              (2)]``, (41,);
            - ``frames``: ``[T_C_MRF, T_C_S]``, (2, 4, 4);
            - ``T_w_MRF``, ``V_w_MRF``: the tool's {MRF} pose (4, 4) and twist (6,) at the
              substep's start (in), then at its end (out);
            - ``T_ref``, ``V_ref_w``: the reference pose (4, 4) and twist (6,), updated as
              ``reference`` says;
            - ``qpos``, ``qvel``, ``qacc``, ``xfrc``: MuJoCo's free joint state (7,), (6,), (6,)
              and the body's ``xfrc_applied`` row (6,);
            - ``scratch``: where the stages write their intermediates, (:data:`N_SCRATCH`, 3, 3);
            - ``materials``: the objects' materials (n, 3), for :func:`implicit_wrench`;
            - ``reading``: output, the F/T reading ``[wrench_S (6); R_w_S (9, row-major); acc_w
              (6); omega_w (3)]`` at the substep's start with the accelerations it applied, (24,).
        reference: :data:`HOLD` (inactive command: the reference stops), :data:`RATE`
            (integrate ``twist`` plus the accommodation term), :data:`POSE` (the reference is
            ``T_cmd``) or :data:`KEEP` (a later substep of the same tick: unchanged).
        twist: Commanded ``[v; w]`` for :data:`RATE` (see :func:`rate_reference`), (6,).
        T_cmd: Commanded {MRF} pose for :data:`POSE`, (4, 4).
        prev_contact: The previous contact result's ``w`` (:class:`~app.world.contact.ContactResult`),
            (15,): its {MRF} wrench drives the accommodation; all zero turns it off.
        dt: The servo period (s) the rate reference integrates over (the substep is MuJoCo's
            timestep).
        contact: This substep's contact result ``w`` at ``T_w_MRF`` (15,), turned into the wrench
            the step applied (:func:`implicit_wrench`); ``valid`` its flag.
        rows, h: Its contact rows (k, 9) and the substep (s), for :func:`implicit_wrench`.
    """
    a: Any = own
    mj, params, frames, T_w_MRF, V_w_MRF = a.mj, a.params, a.frames, a.T_w_MRF, a.V_w_MRF
    T_ref, V_ref_w, qpos, qvel, qacc, xfrc = a.T_ref, a.V_ref_w, a.qpos, a.qvel, a.qacc, a.xfrc
    scratch, materials, reading = a.scratch, a.materials, a.reading
    work = scratch[0:N_WORK]
    work6 = scratch[N_WORK:N_SCRATCH].reshape((N_WORK6, 6, 6))  # a view
    if reference == HOLD:
        V_ref_w[:] = 0.0
    elif reference == POSE:
        T_ref[:, :] = T_cmd
        V_ref_w[:] = 0.0
    elif reference == RATE:
        # The accommodation term in the last block, out of the way of rate_reference's scratch.
        F_acc = work[N_WORK - 1].reshape(9)[0:6]
        for i in range(6):
            F_acc[i] = params[K_ACC + i] * prev_contact[6 + i]
        rate_reference(twist, F_acc, T_w_MRF, dt, params[MAX_LEAD_LIN], params[MAX_LEAD_ROT], T_ref, V_ref_w, work)
    f_sat, t_sat = drive_wrench(
        T_w_MRF,
        V_w_MRF,
        T_ref,
        V_ref_w,
        params[0:6],
        qpos,
        contact[12:15],
        contact[6:12],
        params[WEIGHT_W : WEIGHT_W + 3],
        xfrc,
        work,
    )
    inertia_C = params[INERTIA_C : INERTIA_C + 9].reshape((3, 3))
    implicit_wrench(
        h,
        rows,
        materials,
        params[0:6],
        f_sat,
        t_sat,
        T_w_MRF,
        frames[1],
        params[MASS],
        inertia_C,
        params[INERTIA_INV_C : INERTIA_INV_C + 9].reshape((3, 3)),
        params[GRAVITY_W : GRAVITY_W + 3],
        qpos,
        qvel,
        contact,
        xfrc,
        params[PD_MODES:N_PARAMS],
        work,
        work6,
    )
    call_model_data(mj[0], mj[1], mj[2])
    sensor_reading(
        T_w_MRF,
        V_w_MRF,
        qacc,
        frames[0],
        frames[1],
        inertia_C,
        params[MASS],
        params[GRAVITY_W : GRAVITY_W + 3],
        contact[0:6],
        valid,
        reading,
        work,
    )
    mrf_state(qpos, qvel, frames[0], T_w_MRF, V_w_MRF, work)
