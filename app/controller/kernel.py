"""One controller tick after MuJoCo's forward kinematics (paper Eq 2-12, Sec 3.3-3.5), compiled with numba.

:class:`~app.controller.frhc.FRHCController` runs ``mj_kinematics`` and hands the rest of the tick
to :func:`controller_tick`: input checks, gravity torques, switch edges, reference, Delta X,
commands, task wrench, assists, Jacobian-transpose torques, saturation and motor counts. In
CPython the same arithmetic costs ~150 us a tick on a 2-core machine (about 1 us per numpy call
on six-vectors); compiled it is a few microseconds, which is what a 1 kHz haptic loop needs.

Everything the tick keeps between calls (configuration, state and outputs) lives in one numpy
record, :func:`~app.controller.record.record_dtype`, passed as a one-element array: numba unboxes each argument of a
call separately (~0.2 us per array here), so one record instead of thirty arrays keeps the call
cheap. The controller reads and writes its fields through numpy views. numba compiles a function
taking the record once per record layout, i.e. per device shape, so only the thin adapters
(:func:`controller_tick`, :func:`set_reference`) take it; they hand its fields on to the workers
as named bundles of plain arrays (:class:`Grip`, :class:`Payload`, :class:`Laws`,
:class:`Motors`, :class:`Outputs`), which are compiled once for every device. Array copies and
fills are element loops: numba takes seconds to compile a slice assignment.

Row and slot indices of the ``gains``, ``vectors``, ``torques`` and ``scalars`` blocks are derived
from the names in :mod:`app.controller.layout`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.controller.assist import constant_force_rtc, damping, deadband, hooke_rtc, saturate, uniform_scale
from app.controller.calibration import curve_counts
from app.controller.kinematics import RecordArray, gravity_torque, wrist_jacobian
from app.controller.passivity import coupling_hold, observe_energy, passivity_control
from app.controller.payload import add_inertial_load, remove_weight
from app.controller.record import (
    ASSIST_SCALE,
    DEADBAND,
    DELTA_X,
    DELTA_X_CMD,
    F_MRF,
    F_S_TASK,
    G_F_D,
    G_F_R,
    G_F_RD,
    G_F_T,
    K_D,
    K_P,
    K_R,
    K_T,
    K_V,
    K_WALL,
    PC_CUT,
    PO_ENERGY,
    RAMP,
    ROT_WEIGHT,
    RTC_A,
    RTC_CONSTANT,
    RTC_HOOKE,
    SATURATION_SCALE,
    TAU,
    TAU_G,
    TAU_MOTOR,
    TAU_PC,
    TAU_RD,
    TAU_RDS,
    TAU_SAT,
    TAU_T,
    W_F_T,
    WALL_START,
    Grip,
    Laws,
    Motors,
    Outputs,
    Payload,
)
from app.controller.safety import velocity_brake
from app.controller.types import Fault
from app.filters import lowpass, lowpass_gain
from app.spatial import Array, IntArray, body_rate_from_euler, move_wrench, tmat_difference, zyx_to_matrix

# What :func:`controller_tick` returns: 0, a combination of these :class:`Fault` bits, or
# JOINTS_NONFINITE when even the joint angles are unusable (no gravity compensation possible).
NONFINITE_INPUT = int(Fault.NONFINITE_INPUT)
BAD_PERIOD = int(Fault.BAD_PERIOD)
FT_INVALID = int(Fault.FT_INVALID)
OVERSPEED = int(Fault.OVERSPEED)
NONFINITE_OUTPUT = int(Fault.NONFINITE_OUTPUT)
JOINTS_NONFINITE = -1

# The pose command's rotation; the same function the rest of the app calls from Python.
_zyx_to_matrix = njit(cache=True)(zyx_to_matrix)


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
    for i in range(3):
        r.pc_offset[i] = 0.0  # the PC's hold on the slave command starts over with the reference
        r.pc_dx_prev[i] = 0.0
    r.restart_damping = True


@njit(cache=True)
def motor_commands(torques: Array, motors: Motors, counts: IntArray) -> float:
    """Sec 3.4: uniform saturation of ``torques[TAU]``, gear ratios, torque curve -> ``counts``.

    Returns the saturation scale. The curves are :class:`~app.controller.calibration.TorqueCurve`'s
    Horner-ordered coefficient arrays.
    """
    s = saturate(torques[TAU], motors.joint_limit, torques[TAU_SAT])
    for j in range(torques.shape[1]):
        torques[TAU_MOTOR, j] = torques[TAU_SAT, j] / motors.gear_ratio[j]
    curve_counts(torques[TAU_MOTOR], motors.horner_pos, motors.horner_neg, motors.counts_max, counts)
    return s


@njit(cache=True)
def record_motors(rec: RecordArray) -> Motors:
    """The :class:`Motors` bundle of views into ``rec``."""
    r = rec[0]
    return Motors(r.joint_limit[:], r.gear_ratio[:], r.horner_pos[:], r.horner_neg[:], r.counts_max)


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
        rec: One-element array of :func:`~app.controller.record.record_dtype`: read and updated.
    """
    r = rec[0]
    # A sum is finite only if every term is (huge finite values overflowing to inf also trip
    # it, which is the safe side).
    if not math.isfinite(_total(q)):
        r.have_q_prev = False  # no velocity across the gap
        r.gravity_level = 0.0  # the safe output has no gravity compensation: it ramps back in
        return JOINTS_NONFINITE
    # The record's array fields as plain arrays (``[:]``): numba types a field by its shape,
    # which would compile every worker again for each device.
    T_0_G = r.T_0_G[:]
    out = Outputs(r.vectors[:], r.torques[:], r.counts[:], r.twist[:], r.scalars[:])
    torques = out.torques
    joint_ids, slide = r.joint_ids[:], r.slide[:]
    for i in range(3):
        T_0_G[i, 3] = site_xpos[r.grip_site, i]
        for k in range(3):
            T_0_G[i, k] = site_xmat[r.grip_site, 3 * i + k]
    if r.gravity_compensation:
        gravity_torque(xaxis, xanchor, xipos, joint_ids, slide, r.moves[:], r.support[:], torques[TAU_G])
        if r.gravity_level < 1.0:
            # Back from a joint-reading fault: the compensation ramps in at the safety ramp's rate,
            # as the rendered wrench does after any fault, instead of stepping to full.
            ramp_step = r.ramp_rate * dt if r.min_period <= dt <= r.max_period else 0.0
            r.gravity_level = min(1.0, r.gravity_level + ramp_step)
            for j in range(torques.shape[1]):
                torques[TAU_G, j] *= r.gravity_level
    else:
        for j in range(torques.shape[1]):
            torques[TAU_G, j] = 0.0
    faults = 0
    period_ok = r.min_period <= dt <= r.max_period  # also False for a NaN period
    if not period_ok:
        faults |= BAD_PERIOD
    moved = period_ok and r.have_q_prev  # an encoder difference over one usable period
    if velocity_brake(q, dt if period_ok else 0.0, rec):
        faults |= OVERSPEED
    # The observer runs on every tick, faults included: the device moved under last tick's torque.
    po_energy, qdot = r.po_energy[:], r.qdot[:]
    out.scalars[PO_ENERGY] = observe_energy(
        po_energy,
        r.po_tau[:],
        q,
        r.po_angle[:],
        qdot,
        dt if moved else 0.0,
        r.po_cap,
        r.po_friction[:],
        r.po_damping[:],
        r.encoder_count[:],
        r.po_run[:],
        r.po_swing,
    )
    out.scalars[PC_CUT] = 0.0
    pc_velocity = r.pc_velocity[:]
    lowpass(qdot, lowpass_gain(dt if period_ok else 0.0, r.pc_filter), pc_velocity)
    if not ft_valid:
        faults |= FT_INVALID
    elif not math.isfinite(
        _total(wrench_S) + _total(R_w_S) + (_total(acc_w) + _total(omega_w) if r.remove_inertia else 0.0)
    ):
        faults |= NONFINITE_INPUT  # the acceleration and angular velocity count only when used
    if faults:
        return faults

    p_0_W = site_xpos[r.wrist_site]
    J_W = r.J_W[:]
    wrist_jacobian(xaxis, xanchor, p_0_W, joint_ids, slide, r.moves_wrist[:], J_W)
    if not render(rec, T_0_G, p_0_W, J_W, wrench_S, R_w_S, acc_w, omega_w, dt, deadman, reference, reflection, out):
        return NONFINITE_OUTPUT
    # Passivity controller (app.controller.passivity) on the rendered torque, then Sec 3.4.
    n = torques.shape[1]
    po_tau = r.po_tau[:]
    for j in range(n):
        po_tau[j] = torques[TAU, j] - torques[TAU_G, j]
        torques[TAU_PC, j] = 0.0
    if r.pc_on:
        out.scalars[PC_CUT] = passivity_control(
            po_energy,
            po_tau,
            pc_velocity,
            dt,
            r.pc_step[:],
            r.pc_credit[:],
            r.pc_reserve,
            r.pc_limit[:],
            torques[TAU],
            torques[TAU_PC],
            r.pc_law_count[:],
            r.pc_law_zero[:],
            r.pc_law_step,
        )
    s = motor_commands(torques, record_motors(rec), out.counts)
    out.scalars[SATURATION_SCALE] = s
    # What the motors were commanded to render (the uniform saturation scales it too).
    for j in range(n):
        po_tau[j] = s * (torques[TAU, j] - torques[TAU_G, j])
    if deadman and not r.rate_mode:
        dx_cmd = out.vectors[DELTA_X_CMD]
        if r.pc_hold:
            cut = out.scalars[PC_CUT] if r.pc_on else 0.0
            coupling_hold(
                cut,
                T_0_G[0:3, 0:3],
                out.vectors[G_F_T],
                dx_cmd,
                r.pc_dx_prev[:],
                r.pc_offset[:],
                r.pc_b_device,
                dt,
                r.pc_bleed,
            )
        pose_command(r.T_w_MRF0[:], r.gains[:][K_P], dx_cmd, r.T_w_MRF[:])
    return 0


@njit(cache=True)
def cartesian_device_tick(
    T_dev: Array,
    wrench_S: Array,
    R_w_S: Array,
    acc_w: Array,
    omega_w: Array,
    dt: float,
    ft_valid: bool,
    deadman: bool,
    reference: bool,
    reflection: bool,
    rec: RecordArray,
) -> int:
    """One tick for a Cartesian device: the grip pose ``T_dev`` (4, 4, {0}) comes from the device's
    SDK (its Eq 1), and the output is the grip wrench for its SDK's J^T (its Eq 7).

    The record has six "joints", the wrench axes ``[fx, fy, fz, mx, my, mz]`` at the grip in {0},
    and ``J_W`` is the identity (zero moment rows for a 3-dof-force device), so :func:`render`
    runs Eq 2-12 unchanged and ``torques[TAU_SAT]`` is the wrench after the uniform saturation to
    the device's limits (Sec 3.4). No gravity torques (the device compensates its own), no
    velocity brake and no passivity controller (they act on joint ports); ``counts`` stay zero.
    Returns 0 or fault bits as :func:`controller_tick` does.
    """
    r = rec[0]
    if not math.isfinite(_total(T_dev)):
        return JOINTS_NONFINITE
    T_0_G = r.T_0_G[:]
    for i in range(4):
        for k in range(4):
            T_0_G[i, k] = T_dev[i, k]
    out = Outputs(r.vectors[:], r.torques[:], r.counts[:], r.twist[:], r.scalars[:])
    torques = out.torques
    for j in range(torques.shape[1]):
        torques[TAU_G, j] = 0.0
        torques[TAU_PC, j] = 0.0
    out.scalars[PO_ENERGY] = 0.0
    out.scalars[PC_CUT] = 0.0
    faults = 0
    if not r.min_period <= dt <= r.max_period:
        faults |= BAD_PERIOD
    if not ft_valid:
        faults |= FT_INVALID
    elif not math.isfinite(_total(wrench_S) + _total(R_w_S)):
        faults |= NONFINITE_INPUT
    if faults:
        return faults
    if not render(
        rec, T_0_G, T_0_G[0:3, 3], r.J_W[:], wrench_S, R_w_S, acc_w, omega_w, dt, deadman, reference, reflection, out
    ):
        return NONFINITE_OUTPUT
    out.scalars[SATURATION_SCALE] = saturate(torques[TAU], r.joint_limit[:], torques[TAU_SAT])
    if deadman and not r.rate_mode:
        pose_command(r.T_w_MRF0[:], r.gains[:][K_P], out.vectors[DELTA_X_CMD], r.T_w_MRF[:])
    return 0


@njit(cache=True, inline="always")
def render(
    rec: RecordArray,
    T_0_G: Array,
    p_0_W: Array,
    J_W: Array,
    wrench_S: Array,
    R_w_S: Array,
    acc_w: Array,
    omega_w: Array,
    dt: float,
    deadman: bool,
    reference: bool,
    reflection: bool,
    out: Outputs,
) -> bool:
    """Switch edges and reference (Sec 4.1), the F/T reading's loads, the safety ramp and Eq 2-12
    (:func:`cartesian_tick`), for either kind of device. Returns False if the torques came out
    non-finite.

    Args:
        rec: The controller's record. T_0_G: this tick's grip pose in {0} (4, 4). p_0_W, J_W: the
            wrist's position (3,) and Jacobian in {0} (6, n): the device's own for a joint-space
            device; for a Cartesian device {W} = {G} and J_W is the identity, so the ``torques``
            rows are the wrench at the grip in {0} (Eq 7 is the device SDK's).
        wrench_S, R_w_S, acc_w, omega_w: The F/T reading. dt: servo period (s).
        deadman, reference, reflection: The switches. out: The outputs (``torques[TAU_G]`` set).
    """
    r = rec[0]
    # Switches (Sec 4.1). A deadman press in pose mode is a clutch: re-reference, no jump.
    reference_edge = reference and not r.prev_reference
    deadman_edge = deadman and not r.prev_deadman
    r.prev_reference = reference
    r.prev_deadman = deadman
    if reference_edge or (deadman_edge and not r.rate_mode):
        set_reference(rec)

    F_S = out.vectors[F_S_TASK]
    for i in range(6):
        F_S[i] = wrench_S[i]
    if r.remove_inertia:
        add_inertial_load(R_w_S, acc_w, omega_w, r.payload_mass, r.payload_com_S[:], r.payload_inertia_S[:], F_S)
    grip = Grip(r.T_0_G0[:], T_0_G[0:3, 0:3], T_0_G[0:3, 3], p_0_W, J_W, r.R_W_G[:], r.p_W_G[:])
    payload = Payload(r.remove_payload, r.payload_mass, r.payload_com_S[:], r.gravity_w[:], r.X_MRF_S[:])
    laws = Laws(r.gains[:], r.rate_mode, r.rtc_kind, r.taper[:], r.assist_limit[:])
    reflecting = deadman and reflection
    if reflecting and not r.prev_reflecting:
        out.scalars[RAMP] = 0.0  # rendering starts: ramp the wrench in
    r.prev_reflecting = reflecting
    out.scalars[RAMP] = min(1.0, out.scalars[RAMP] + r.ramp_rate * dt)
    ok = cartesian_tick(
        grip,
        R_w_S,
        payload,
        laws,
        deadman,
        deadman and reflection,
        dt,
        r.dx_prev[:],
        r.restart_damping,
        out,
    )
    r.restart_damping = False
    return ok


@njit(cache=True)
def cartesian_tick(
    grip: Grip,
    R_w_S: Array,
    payload: Payload,
    laws: Laws,
    deadman: bool,
    reflecting: bool,
    dt: float,
    dx_prev: Array,
    restart_damping: bool,
    out: Outputs,
) -> bool:
    """Eq 2-12 from the grip pose to the total torque ``torques[TAU]``. Returns False if it came out
    non-finite. The caller adds the passivity controller and the motor commands (Sec 3.4).

    Args:
        grip: This tick's grip kinematics. R_w_S: sensor orientation in the slave world (3, 3).
        payload, laws: The bundles of the same names.
        deadman, reflecting: Switch state (reflecting = deadman and reflection switch).
        dt: Servo period (s). ``dx_prev``: Delta X of the previous tick (6,), updated here.
        restart_damping: No previous Delta X on this reference (Eq 9 starts from zero).
        out: The outputs. On entry ``out.vectors[F_S_TASK]`` holds the F/T reading at {S} in
            {S} (inertial load already handled) and ``out.torques[TAU_G]`` the gravity torques.
    """
    vectors, torques, scalars, twist = out.vectors, out.torques, out.scalars, out.twist
    gains = laws.gains
    dx = vectors[DELTA_X]
    tmat_difference(grip.T_0_G0, grip.R_0_G, grip.p_0_G, dx)
    if restart_damping:
        for i in range(6):
            dx_prev[i] = dx[i]
    dxc = vectors[DELTA_X_CMD]
    for i in range(6):
        dxc[i] = deadband(dx[i], gains[DEADBAND, i])
    abs_beta = abs(dx[4])
    rot_weight = 1.0
    taper = laws.taper
    if abs_beta > taper[0]:
        rot_weight = max(0.0, (taper[1] - abs_beta) / (taper[1] - taper[0]))
    scalars[ROT_WEIGHT] = rot_weight
    rate_mode = laws.rate_mode

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
    if payload.remove:
        remove_weight(R_w_S, payload.gravity_w, payload.mass, payload.com_S, F_task)
    F_mrf = vectors[F_MRF]
    X_MRF_S = payload.X_MRF_S
    for i in range(6):
        acc = 0.0
        for k in range(6):
            acc += X_MRF_S[i, k] * F_task[k]
        F_mrf[i] = acc
    # Forces cross between slave and master in world/base axes, as translations do (Delta X and
    # the slave's position are in {0} and {w} axes): K_T f_w, re-expressed in {G}. Moments cross
    # in the tool's and the grip's own axes, as rotations do: K_T m_MRF as a moment in {G}. (Eq 6
    # read literally puts f_MRF on {G}'s axes: that rotates the felt force against the motion by
    # R_0_G0 R_w_MRF0^T, which is not the identity on a device whose grip starts tilted.)
    G_F = vectors[G_F_T]
    for i in range(3):
        f = R_w_S[i, 0] * F_task[0] + R_w_S[i, 1] * F_task[1] + R_w_S[i, 2] * F_task[2]
        G_F[i] = gains[K_T, i] * f if reflecting else 0.0
        G_F[3 + i] = gains[K_T, 3 + i] * F_mrf[3 + i] if reflecting else 0.0
    base_to_grip(grip.R_0_G, G_F)

    # Assists at the grip: return-to-centre (Eq 8, rate mode only) + damping (Eq 9) = Eq 10.
    rtc_kind = laws.rtc_kind
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
        dx_prev[i] = dx[i]
    # Delta X's translations are in {0}: so are the assists' forces; the wrenches are in {G}.
    base_to_grip(grip.R_0_G, vectors[G_F_R])
    base_to_grip(grip.R_0_G, vectors[G_F_D])
    for i in range(6):
        vectors[G_F_RD, i] = vectors[G_F_R, i] + vectors[G_F_D, i]

    # {G} -> base coordinates at {W} (Eq 6 form, with W's Jacobian in {0}) and Eq 7: tau = J^T F.
    R_0_G, p_0_G, p_0_W, J_W = grip.R_0_G, grip.p_0_G, grip.p_0_W, grip.J_W
    r_WG_0 = p_0_G - p_0_W
    F0_T = move_wrench(R_0_G, r_WG_0, vectors[G_F_T], np.empty(6))
    F0_RD = move_wrench(R_0_G, r_WG_0, vectors[G_F_RD], np.empty(6))
    move_wrench(grip.R_W_G, grip.p_W_G, vectors[G_F_T], vectors[W_F_T])
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
    a = uniform_scale(torques[TAU_RD], laws.assist_limit)
    scalars[ASSIST_SCALE] = a
    # The safety ramp (app.controller.safety) scales what is rendered, never gravity compensation.
    ramp = scalars[RAMP]
    total = 0.0
    for j in range(n):
        torques[TAU_T, j] *= ramp
        torques[TAU_RDS, j] = ramp * a * torques[TAU_RD, j]
        torques[TAU, j] = torques[TAU_T, j] + torques[TAU_RDS, j] + torques[TAU_G, j]  # Eq 12
        total += torques[TAU, j]
    return math.isfinite(total)


@njit(cache=True)
def base_to_grip(R_0_G: Array, F: Array) -> None:
    """Re-express the force part ``F[0:3]`` of a wrench from base {0} axes in grip {G} axes, in
    place: ``R_0_G^T F[0:3]`` (``R_0_G`` (3, 3), ``F`` (6,); the moment part is left as it is)."""
    x, y, z = F[0], F[1], F[2]
    for i in range(3):
        F[i] = R_0_G[0, i] * x + R_0_G[1, i] * y + R_0_G[2, i] * z


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
