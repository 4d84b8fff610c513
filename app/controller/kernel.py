"""One controller tick after MuJoCo's forward kinematics (paper Eq 2-12, Sec 3.3-3.5), compiled with numba.

:class:`~app.controller.frhc.FRHCController` runs ``mj_kinematics`` and hands the rest of the tick
to :func:`controller_tick`: input checks, gravity torques, switch edges, reference, Delta X,
commands, task wrench, assists, Jacobian-transpose torques, saturation and motor counts. In
CPython the same arithmetic costs ~150 us a tick on a 2-core machine (about 1 us per numpy call
on six-vectors); compiled it is a few microseconds, which is what a 1 kHz haptic loop needs.

Everything the tick keeps between calls (configuration, state and outputs) lives in one numpy
record, :func:`record_dtype`, passed as a one-element array: numba unboxes each argument of a
call separately (~0.2 us per array here), so one record instead of thirty arrays keeps the call
cheap. The controller reads and writes its fields through numpy views. numba compiles a function
taking the record once per record layout, i.e. per device shape, so only the thin adapters
(:func:`controller_tick`, :func:`set_reference`) take it; they pass its fields on as plain arrays
to the workers, which are compiled once for every device. Array copies and fills are element
loops: numba takes seconds to compile a slice assignment.

Gain rows of ``gains`` (shape (9, 6)), each ordered like Delta X:
``K_V, K_P, K_T, K_D, rtc_a, deadband, K_R, wall_start, k_wall``.

Rows of ``vectors`` (9, 6): ``delta_x, delta_x_cmd, F_S_task, F_MRF, G_F_T, G_F_R, G_F_D, G_F_RD,
W_F_T``. Rows of ``torques`` (7, n): ``tau_T, tau_RD, tau_RDs, tau_G, tau, tau_sat, tau_motor``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.controller.assist import constant_force_rtc, damping, deadband, hooke_rtc, saturate, uniform_scale
from app.controller.calibration import curve_counts
from app.controller.kinematics import RecordArray, gravity_torque, topology_fields, wrist_jacobian
from app.controller.types import Fault
from app.spatial import Array, IntArray, body_rate_from_euler, cross3, move_wrench, tmat_difference, zyx_to_matrix

K_V, K_P, K_T, K_D, RTC_A, DEADBAND, K_R, WALL_START, K_WALL = range(9)
RTC_OFF, RTC_CONSTANT, RTC_HOOKE = 0, 1, 2
DELTA_X, DELTA_X_CMD, F_S_TASK, F_MRF, G_F_T, G_F_R, G_F_D, G_F_RD, W_F_T = range(9)
TAU_T, TAU_RD, TAU_RDS, TAU_G, TAU, TAU_SAT, TAU_MOTOR = range(7)
# Slots of the ``scalars`` output.
ASSIST_SCALE, SATURATION_SCALE, ROT_WEIGHT = range(3)

# What :func:`controller_tick` returns: 0, a combination of these :class:`Fault` bits, or
# JOINTS_NONFINITE when even the joint angles are unusable (no gravity compensation possible).
NONFINITE_INPUT = int(Fault.NONFINITE_INPUT)
BAD_PERIOD = int(Fault.BAD_PERIOD)
FT_INVALID = int(Fault.FT_INVALID)
NONFINITE_OUTPUT = int(Fault.NONFINITE_OUTPUT)
JOINTS_NONFINITE = -1

# The pose command's rotation; the same function the rest of the app calls from Python.
_zyx_to_matrix = njit(cache=True)(zyx_to_matrix)


def record_dtype(n: int, nbody: int, n_coeffs: int) -> np.dtype:
    """The controller's record for ``n`` joints, ``nbody`` MuJoCo bodies, ``n_coeffs`` curve coefficients.

    Fields, besides :func:`~app.controller.kinematics.topology_fields`:

    Configuration (set by the controller's constructor and ``set_gains``):
        gains: The (9, 6) gain rows (module docstring). rate_mode: rate (else pose) commands.
        rtc_kind: ``RTC_OFF``, ``RTC_CONSTANT`` or ``RTC_HOOKE``. taper: ``[start, stop]`` |beta|
        (rad) of the rotational fade near gimbal lock. gravity_compensation, remove_payload,
        remove_inertia: the options of the same names. max_period: longest accepted period (s).
        assist_limit, joint_limit, gear_ratio: (n,) each (N m or N; -). horner_pos, horner_neg:
        (n, n_coeffs) torque curves, highest order first; counts_max: the amplifier's range.
        payload_mass (kg), payload_com_S (m, in {S}), payload_inertia_S (kg m^2, about the
        centre of mass, {S} axes), gravity_w (m/s^2, in {w}): the slave's payload.
        X_MRF_S: Eq 6 matrix {S} -> {MRF} (6, 6). R_W_G, p_W_G: the grip {G} in the wrist {W}.

    State:
        T_w_MRF0: The slave reference pose (4, 4). dx_prev: Delta X of the previous tick (6,).
        restart_damping: No previous Delta X on this reference (Eq 9 starts from zero).
        prev_reference, prev_deadman: Last tick's switches, for edges. J_W: wrist Jacobian (6, n).

    Outputs (see :class:`~app.controller.frhc.ControllerOutput`):
        T_0_G, T_0_G0 (4, 4); vectors (9, 6); torques (7, n); counts (n,) int64; scalars (3,)
        (``ASSIST_SCALE``, ``SATURATION_SCALE``, ``ROT_WEIGHT``); twist (6,) and T_w_MRF (4, 4):
        the slave command.
    """
    f8, i8, b1 = np.float64, np.int64, np.bool_
    return np.dtype(
        [
            *topology_fields(n, nbody),
            ("gains", f8, (9, 6)),
            ("rate_mode", b1),
            ("rtc_kind", i8),
            ("taper", f8, (2,)),
            ("gravity_compensation", b1),
            ("remove_payload", b1),
            ("remove_inertia", b1),
            ("max_period", f8),
            ("assist_limit", f8, (n,)),
            ("joint_limit", f8, (n,)),
            ("gear_ratio", f8, (n,)),
            ("horner_pos", f8, (n, n_coeffs)),
            ("horner_neg", f8, (n, n_coeffs)),
            ("counts_max", i8),
            ("payload_mass", f8),
            ("payload_com_S", f8, (3,)),
            ("payload_inertia_S", f8, (3, 3)),
            ("gravity_w", f8, (3,)),
            ("X_MRF_S", f8, (6, 6)),
            ("R_W_G", f8, (3, 3)),
            ("p_W_G", f8, (3,)),
            ("T_w_MRF0", f8, (4, 4)),
            ("dx_prev", f8, (6,)),
            ("restart_damping", b1),
            ("prev_reference", b1),
            ("prev_deadman", b1),
            ("J_W", f8, (6, n)),
            ("T_0_G", f8, (4, 4)),
            ("T_0_G0", f8, (4, 4)),
            ("vectors", f8, (9, 6)),
            ("torques", f8, (7, n)),
            ("counts", i8, (n,)),
            ("scalars", f8, (3,)),
            ("twist", f8, (6,)),
            ("T_w_MRF", f8, (4, 4)),
        ],
        align=True,
    )


@njit(cache=True)
def set_reference(rec: RecordArray) -> None:
    """Reference switch (Sec 3.1, 4.1): {G0} := {G}; the slave reference := its last command.

    In pose mode this is indexing: the new zero of Delta X maps onto where the slave was
    commanded to be, so the slave never jumps. Damping restarts from the new Delta X.
    """
    r = rec[0]
    for i in range(4):
        for j in range(4):
            r.T_0_G0[i, j] = r.T_0_G[i, j]
            r.T_w_MRF0[i, j] = r.T_w_MRF[i, j]
    r.restart_damping = True


@njit(cache=True)
def motor_commands(
    torques: Array,
    joint_limit: Array,
    gear_ratio: Array,
    horner_pos: Array,
    horner_neg: Array,
    counts_max: int,
    counts: IntArray,
) -> float:
    """Sec 3.4: uniform saturation of ``torques[TAU]``, gear ratios, torque curve -> ``counts``.

    Returns the saturation scale. The curves are :class:`~app.controller.calibration.TorqueCurve`'s
    Horner-ordered coefficient arrays.
    """
    s = saturate(torques[TAU], joint_limit, torques[TAU_SAT])
    for j in range(torques.shape[1]):
        torques[TAU_MOTOR, j] = torques[TAU_SAT, j] / gear_ratio[j]
    curve_counts(torques[TAU_MOTOR], horner_pos, horner_neg, counts_max, counts)
    return s


@njit(cache=True)
def controller_tick(
    q: Array,
    wrench_S: Array,
    R_w_S: Array,
    acc_w: Array,
    omega_w: Array,
    dt: float,
    ft_valid: bool,
    deadman: bool,
    reference: bool,
    reflection: bool,
    xaxis: Array,
    xanchor: Array,
    xipos: Array,
    site_xpos: Array,
    site_xmat: Array,
    rec: RecordArray,
) -> int:
    """One tick from MuJoCo's forward kinematics at ``q`` to motor counts and the slave command.

    Returns 0, or why the caller must use the safe output instead: ``JOINTS_NONFINITE`` (nothing
    was written), or :class:`Fault` bits (``T_0_G`` and ``torques[TAU_G]`` are then this tick's;
    after ``NONFINITE_OUTPUT`` the other outputs are partial).

    Args:
        q: Joint angles (rad or m) the kinematics were just run at, (n,); checked here.
        wrench_S, R_w_S, acc_w, omega_w, ft_valid: The F/T reading (:class:`FTReading` fields).
        dt: Servo period (s).
        deadman, reference, reflection: The switches as held this tick.
        xaxis, xanchor, xipos, site_xpos, site_xmat: MuJoCo's kinematics outputs (``MjData``).
        rec: One-element array of :func:`record_dtype`: read and updated.
    """
    r = rec[0]
    # A sum is finite only if every term is (huge finite values overflowing to inf also trip
    # it, which is the safe side).
    if not math.isfinite(_total(q)):
        return JOINTS_NONFINITE
    # The record's array fields as plain arrays (``[:]``): numba types a field by its shape,
    # which would compile every worker again for each device.
    T_0_G = r.T_0_G[:]
    torques = r.torques[:]
    vectors = r.vectors[:]
    gains = r.gains[:]
    joint_ids, slide = r.joint_ids[:], r.slide[:]
    for i in range(3):
        T_0_G[i, 3] = site_xpos[r.grip_site, i]
        for k in range(3):
            T_0_G[i, k] = site_xmat[r.grip_site, 3 * i + k]
    if r.gravity_compensation:
        gravity_torque(xaxis, xanchor, xipos, joint_ids, slide, r.moves[:], r.support[:], torques[TAU_G])
    else:
        for j in range(torques.shape[1]):
            torques[TAU_G, j] = 0.0
    faults = 0
    if not 0.0 < dt <= r.max_period:  # also catches a NaN period
        faults |= BAD_PERIOD
    if not ft_valid:
        faults |= FT_INVALID
    elif not math.isfinite(_total(wrench_S) + _total(R_w_S)):
        faults |= NONFINITE_INPUT
    if faults:
        return faults

    # Switches (Sec 4.1). A deadman press in pose mode is a clutch: re-reference, no jump.
    reference_edge = reference and not r.prev_reference
    deadman_edge = deadman and not r.prev_deadman
    r.prev_reference = reference
    r.prev_deadman = deadman
    if reference_edge or (deadman_edge and not r.rate_mode):
        set_reference(rec)

    F_S = vectors[F_S_TASK]
    for i in range(6):
        F_S[i] = wrench_S[i]
    if r.remove_inertia:
        add_inertial_load(R_w_S, acc_w, omega_w, r.payload_mass, r.payload_com_S[:], r.payload_inertia_S[:], F_S)
    p_0_W = site_xpos[r.wrist_site]
    J_W = r.J_W[:]
    wrist_jacobian(xaxis, xanchor, p_0_W, joint_ids, slide, r.moves_wrist[:], J_W)
    reflecting = deadman and reflection
    ok = cartesian_tick(
        r.T_0_G0[:],
        T_0_G[0:3, 0:3],
        T_0_G[0:3, 3],
        p_0_W,
        J_W,
        R_w_S,
        r.remove_payload,
        r.payload_mass,
        r.payload_com_S[:],
        r.gravity_w[:],
        r.X_MRF_S[:],
        r.R_W_G[:],
        r.p_W_G[:],
        gains,
        r.rate_mode,
        r.rtc_kind,
        r.taper[:],
        r.assist_limit[:],
        r.joint_limit[:],
        r.gear_ratio[:],
        r.horner_pos[:],
        r.horner_neg[:],
        r.counts_max,
        deadman,
        reflecting,
        dt,
        r.dx_prev[:],
        r.restart_damping,
        vectors,
        torques,
        r.counts[:],
        r.twist[:],
        r.scalars[:],
    )
    r.restart_damping = False
    if not ok:
        return NONFINITE_OUTPUT
    if deadman and not r.rate_mode:
        pose_command(r.T_w_MRF0[:], gains[K_P], vectors[DELTA_X_CMD], r.T_w_MRF[:])
    return 0


@njit(cache=True)
def cartesian_tick(
    T_0_G0: Array,
    R_0_G: Array,
    p_0_G: Array,
    p_0_W: Array,
    J_W: Array,
    R_w_S: Array,
    remove_payload: bool,
    payload_mass: float,
    payload_com_S: Array,
    gravity_w: Array,
    X_MRF_S: Array,
    R_W_G: Array,
    p_W_G: Array,
    gains: Array,
    rate_mode: bool,
    rtc_kind: int,
    taper: Array,
    assist_limit: Array,
    joint_limit: Array,
    gear_ratio: Array,
    horner_pos: Array,
    horner_neg: Array,
    counts_max: int,
    deadman: bool,
    reflecting: bool,
    dt: float,
    dx_prev: Array,
    restart_damping: bool,
    vectors: Array,
    torques: Array,
    counts: IntArray,
    twist: Array,
    scalars: Array,
) -> bool:
    """Eq 2-12 from the grip pose to motor counts. Returns False if a torque came out non-finite.

    Args:
        T_0_G0: Reference grip pose (4, 4). ``R_0_G``, ``p_0_G``, ``p_0_W``: grip rotation and
            position and wrist position in {0}. ``J_W``: wrist Jacobian in {0} (6, n).
        R_w_S: Sensor orientation in the slave world (3, 3).
        remove_payload, payload_mass, payload_com_S, gravity_w: Subtract the payload's weight:
            its mass (kg), centre of mass in {S} (m) and gravity in {w} (m/s^2).
        X_MRF_S: Eq 6 matrix {S} -> {MRF} (6, 6). ``R_W_G``, ``p_W_G``: grip in the wrist frame.
        gains: The (9, 6) gain rows (module docstring). ``rate_mode``, ``rtc_kind``: options.
        taper: ``[start, stop]`` |beta| (rad) of the rotational fade near gimbal lock.
        assist_limit, joint_limit, gear_ratio: (n,) each. ``horner_pos``, ``horner_neg``,
            ``counts_max``: the torque curve (see :func:`motor_commands`).
        deadman, reflecting: Switch state (reflecting = deadman and reflection switch).
        dt: Servo period (s). ``dx_prev``: Delta X of the previous tick (6,), updated here.
        restart_damping: No previous Delta X on this reference (Eq 9 starts from zero).
        vectors, torques, counts, twist, scalars: Outputs (module docstring). On entry
            ``vectors[F_S_TASK]`` holds the F/T reading at {S} in {S} (inertial load already
            handled) and ``torques[TAU_G]`` the gravity torques.
    """
    dx = vectors[DELTA_X]
    tmat_difference(T_0_G0, R_0_G, p_0_G, dx)
    if restart_damping:
        for i in range(6):
            dx_prev[i] = dx[i]
    dxc = vectors[DELTA_X_CMD]
    for i in range(6):
        dxc[i] = deadband(dx[i], gains[DEADBAND, i])
    abs_beta = abs(dx[4])
    rot_weight = 1.0
    if abs_beta > taper[0]:
        rot_weight = max(0.0, (taper[1] - abs_beta) / (taper[1] - taper[0]))
    scalars[ROT_WEIGHT] = rot_weight

    # Rate command: K_V on translations, Eq 5 (static angles used as angle rates) on rotations.
    for i in range(6):
        twist[i] = 0.0
    if deadman and rate_mode:
        wx, wy, wz = body_rate_from_euler(dxc[3], dxc[4], (dxc[3], dxc[4], dxc[5]))
        for i in range(3):
            twist[i] = gains[K_V, i] * dxc[i]
        twist[3] = gains[K_V, 3] * wx * rot_weight
        twist[4] = gains[K_V, 4] * wy * rot_weight
        twist[5] = gains[K_V, 5] * wz * rot_weight

    # Task wrench: payload weight removed with gravity in {S}, Eq 6 to {MRF}, K_T to the grip.
    F_task = vectors[F_S_TASK]
    if remove_payload:
        load = np.empty(3)
        for i in range(3):
            load[i] = payload_mass * (
                R_w_S[0, i] * gravity_w[0] + R_w_S[1, i] * gravity_w[1] + R_w_S[2, i] * gravity_w[2]
            )
        cx, cy, cz = payload_com_S[0], payload_com_S[1], payload_com_S[2]
        F_task[0] -= load[0]
        F_task[1] -= load[1]
        F_task[2] -= load[2]
        F_task[3] -= cy * load[2] - cz * load[1]
        F_task[4] -= cz * load[0] - cx * load[2]
        F_task[5] -= cx * load[1] - cy * load[0]
    F_mrf = vectors[F_MRF]
    for i in range(6):
        acc = 0.0
        for k in range(6):
            acc += X_MRF_S[i, k] * F_task[k]
        F_mrf[i] = acc
    for i in range(6):
        vectors[G_F_T, i] = gains[K_T, i] * F_mrf[i] if reflecting else 0.0

    # Assists at the grip: return-to-centre (Eq 8, rate mode only) + damping (Eq 9) = Eq 10.
    for i in range(6):
        r = 0.0
        d = 0.0
        if reflecting:
            if rate_mode and rtc_kind == RTC_CONSTANT:
                r = constant_force_rtc(
                    dx[i], gains[RTC_A, i], gains[DEADBAND, i], gains[WALL_START, i], gains[K_WALL, i]
                )
            elif rate_mode and rtc_kind == RTC_HOOKE:
                r = hooke_rtc(dx[i], gains[K_R, i])
            d = damping(dx[i], dx_prev[i], gains[K_D, i], dt, i >= 3)
            if i >= 3:
                # Near the Z-Y-X singularity the angles jump: fade the rotational channels out.
                r *= rot_weight
                d *= rot_weight
        vectors[G_F_R, i] = r
        vectors[G_F_D, i] = d
        vectors[G_F_RD, i] = r + d
        dx_prev[i] = dx[i]

    # {G} -> base coordinates at {W} (Eq 6 form, with W's Jacobian in {0}) and Eq 7: tau = J^T F.
    r_WG_0 = p_0_G - p_0_W
    F0_T = move_wrench(R_0_G, r_WG_0, vectors[G_F_T], np.empty(6))
    F0_RD = move_wrench(R_0_G, r_WG_0, vectors[G_F_RD], np.empty(6))
    move_wrench(R_W_G, p_W_G, vectors[G_F_T], vectors[W_F_T])
    n = J_W.shape[1]
    for j in range(n):
        t_T = 0.0
        t_RD = 0.0
        for k in range(6):
            t_T += J_W[k, j] * F0_T[k]
            t_RD += J_W[k, j] * F0_RD[k]
        torques[TAU_T, j] = t_T
        torques[TAU_RD, j] = t_RD

    # Eq 11: the assists use at most a set fraction of capacity so the task wrench dominates.
    a = uniform_scale(torques[TAU_RD], assist_limit)
    scalars[ASSIST_SCALE] = a
    total = 0.0
    for j in range(n):
        torques[TAU_RDS, j] = a * torques[TAU_RD, j]
        torques[TAU, j] = torques[TAU_T, j] + torques[TAU_RDS, j] + torques[TAU_G, j]  # Eq 12
        total += torques[TAU, j]
    if not math.isfinite(total):
        return False
    scalars[SATURATION_SCALE] = motor_commands(
        torques, joint_limit, gear_ratio, horner_pos, horner_neg, counts_max, counts
    )
    return True


@njit(cache=True)
def add_inertial_load(
    R_w_S: Array, acc_w: Array, omega_w: Array, mass: float, com_S: Array, inertia_S: Array, F_S: Array
) -> None:
    """Add the payload's inertial load back to the reading ``F_S`` (6,) in place.

    The sensor reads minus the payload's d'Alembert load; :func:`cartesian_tick` then removes
    the weight.

    Args:
        R_w_S: Sensor orientation in the slave world (3, 3).
        acc_w: Linear acceleration of {S}'s origin and angular acceleration, in {w} (m/s^2,
            rad/s^2), (6,). ``omega_w``: angular velocity in {w} (rad/s), (3,).
        mass, com_S, inertia_S: The payload's mass (kg), centre of mass in {S} (m) and inertia
            about it in {S} axes (kg m^2).
        F_S: Wrench at {S} in {S} (N, N m), (6,), updated.
    """
    R_S_w = R_w_S.T
    w_S = _mat_vec(R_S_w, omega_w)
    alpha_S = _mat_vec(R_S_w, acc_w[3:6])
    a_com = _mat_vec(R_S_w, acc_w[0:3]) + cross3(alpha_S, com_S) + cross3(w_S, cross3(w_S, com_S))
    f = mass * a_com
    m_com = cross3(com_S, f)
    m_alpha = _mat_vec(inertia_S, alpha_S)
    m_gyro = cross3(w_S, _mat_vec(inertia_S, w_S))
    for i in range(3):
        F_S[i] = F_S[i] + f[i]
        F_S[3 + i] = F_S[3 + i] + m_com[i] + m_alpha[i] + m_gyro[i]


@njit(cache=True)
def pose_command(T_w_MRF0: Array, k_p: Array, delta_x_cmd: Array, T_w_MRF: Array) -> None:
    """Sec 3.5: Delta X (after the deadband) scaled by K_P and applied to the slave reference pose.

    Translations are in base/world axes; the rotation is applied in the reference frame's own
    axes. Writes the commanded pose ``T_w_MRF`` (4, 4) from the reference ``T_w_MRF0`` (4, 4),
    the gain row ``k_p`` (6,) and ``delta_x_cmd`` (6,). Without the deadman the caller does not
    call this, so the last command is held.
    """
    R = _zyx_to_matrix(delta_x_cmd[3], delta_x_cmd[4], delta_x_cmd[5])
    for i in range(3):
        T_w_MRF[i, 3] = T_w_MRF0[i, 3] + k_p[i] * delta_x_cmd[i]
        for j in range(3):
            T_w_MRF[i, j] = T_w_MRF0[i, 0] * R[0, j] + T_w_MRF0[i, 1] * R[1, j] + T_w_MRF0[i, 2] * R[2, j]


@njit(cache=True)
def _total(a: Array) -> float:
    """Sum of all elements of ``a`` (any shape)."""
    s = 0.0
    for x in a.flat:
        s += x
    return s


@njit(cache=True)
def _mat_vec(M: Array, v: Array) -> Array:
    """``M @ v`` for a (3, 3) matrix of any layout and a (3,) vector (numba's ``@`` needs BLAS)."""
    out = np.empty(3)
    for i in range(3):
        out[i] = M[i, 0] * v[0] + M[i, 1] * v[1] + M[i, 2] * v[2]
    return out
