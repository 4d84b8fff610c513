"""The arithmetic of one controller tick (paper Eq 2-12 and Sec 3.4), compiled with numba.

:class:`~app.controller.frhc.FRHCController` does the parts that need Python objects (MuJoCo
kinematics, switch edges, faults) and hands everything else to :func:`cartesian_tick`, which
reads and writes preallocated arrays only. In CPython the same arithmetic costs ~150 us a tick
on a 2-core machine (about 1 us per numpy call on six-vectors); compiled it is a few
microseconds, which is what a 1 kHz haptic loop needs.

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
from app.spatial import Array, IntArray, body_rate_from_euler, move_wrench, tmat_difference

K_V, K_P, K_T, K_D, RTC_A, DEADBAND, K_R, WALL_START, K_WALL = range(9)
RTC_OFF, RTC_CONSTANT, RTC_HOOKE = 0, 1, 2
DELTA_X, DELTA_X_CMD, F_S_TASK, F_MRF, G_F_T, G_F_R, G_F_D, G_F_RD, W_F_T = range(9)
TAU_T, TAU_RD, TAU_RDS, TAU_G, TAU, TAU_SAT, TAU_MOTOR = range(7)
# Slots of the ``scalars`` output.
ASSIST_SCALE, SATURATION_SCALE, ROT_WEIGHT = range(3)


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
def cartesian_tick(
    T_0_G0: Array,
    R_0_G: Array,
    p_0_G: Array,
    p_0_W: Array,
    J_W: Array,
    F_S: Array,
    R_w_S: Array,
    payload: Array,
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
    """One tick from grip pose to motor counts. Returns False if a torque came out non-finite.

    Args:
        T_0_G0: Reference grip pose (4, 4). ``R_0_G``, ``p_0_G``, ``p_0_W``: grip rotation and
            position and wrist position in {0}. ``J_W``: wrist Jacobian in {0} (6, n).
        F_S: F/T reading at {S} in {S} (6,) (inertial load already handled by the caller).
        R_w_S: Sensor orientation in the slave world (3, 3).
        payload: ``[mass (kg), com_S (3, m), gravity_w (3, m/s^2), remove (0/1)]`` (8,).
        X_MRF_S: Eq 6 matrix {S} -> {MRF} (6, 6). ``R_W_G``, ``p_W_G``: grip in the wrist frame.
        gains: The (9, 6) gain rows (module docstring). ``rate_mode``, ``rtc_kind``: options.
        taper: ``[start, stop]`` |beta| (rad) of the rotational fade near gimbal lock.
        assist_limit, joint_limit, gear_ratio: (n,) each. ``horner_pos``, ``horner_neg``: the torque curve.
        deadman, reflecting: Switch state (reflecting = deadman and reflection switch).
        dt: Servo period (s). ``dx_prev``: Delta X of the previous tick (6,), updated here.
        restart_damping: No previous Delta X on this reference (Eq 9 starts from zero).
        vectors, torques, counts, twist, scalars: Outputs (module docstring); ``torques[TAU_G]``
            must already hold the gravity torques.
    """
    dx = vectors[DELTA_X]
    tmat_difference(T_0_G0, R_0_G, p_0_G, dx)
    if restart_damping:
        dx_prev[:] = dx
    dxc = vectors[DELTA_X_CMD]
    for i in range(6):
        dxc[i] = deadband(dx[i], gains[DEADBAND, i])
    abs_beta = abs(dx[4])
    rot_weight = 1.0
    if abs_beta > taper[0]:
        rot_weight = max(0.0, (taper[1] - abs_beta) / (taper[1] - taper[0]))
    scalars[ROT_WEIGHT] = rot_weight

    # Rate command: K_V on translations, Eq 5 (static angles used as angle rates) on rotations.
    twist[:] = 0.0
    if deadman and rate_mode:
        wx, wy, wz = body_rate_from_euler(dxc[3], dxc[4], (dxc[3], dxc[4], dxc[5]))
        for i in range(3):
            twist[i] = gains[K_V, i] * dxc[i]
        twist[3] = gains[K_V, 3] * wx * rot_weight
        twist[4] = gains[K_V, 4] * wy * rot_weight
        twist[5] = gains[K_V, 5] * wz * rot_weight

    # Task wrench: payload weight removed with gravity in {S}, Eq 6 to {MRF}, K_T to the grip.
    F_task = vectors[F_S_TASK]
    F_task[:] = F_S
    if payload[7] > 0.0:
        m = payload[0]
        load = np.empty(3)
        for i in range(3):
            load[i] = m * (R_w_S[0, i] * payload[4] + R_w_S[1, i] * payload[5] + R_w_S[2, i] * payload[6])
        cx, cy, cz = payload[1], payload[2], payload[3]
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
    dx_prev[:] = dx

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
