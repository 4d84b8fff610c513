"""The controller's record: one numpy record per controller, and the named bundles the kernel passes.

:func:`record_dtype` lays out everything the compiled tick (:mod:`app.controller.kernel`) keeps
between calls; :class:`Grip`, :class:`Payload`, :class:`Laws`, :class:`Motors` and
:class:`Outputs` are the named groups of its fields the kernel's workers take (numba compiles
NamedTuples of arrays as ordinary tuples, so naming costs nothing at run time). The row and slot
indices of the ``gains``, ``vectors``, ``torques`` and ``scalars`` blocks are derived from the names
in :mod:`app.controller.layout`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from app.controller.kinematics import topology_fields
from app.controller.layout import GAIN_ROWS, RTC_LAWS, SCALARS, TORQUE_ROWS, VECTOR_ROWS, vector_row_names
from app.spatial import Array, IntArray

K_V, K_P, K_T, K_D, RTC_A, DEADBAND, K_R, WALL_START, K_WALL = (
    GAIN_ROWS.index(name) for name in ("k_v", "k_p", "k_t", "k_d", "rtc_a", "deadband", "k_r", "wall_start", "k_wall")
)
RTC_OFF, RTC_CONSTANT, RTC_HOOKE = (RTC_LAWS.index(name) for name in ("off", "constant", "hooke"))
DELTA_X, DELTA_X_CMD, F_S_TASK, F_MRF, G_F_T, G_F_R, G_F_D, G_F_RD, W_F_T = (
    vector_row_names().index(name)
    for name in ("delta_x", "delta_x_cmd", "F_S_task", "F_MRF", "G_F_T", "G_F_R", "G_F_D", "G_F_RD", "W_F_T")
)
TAU_T, TAU_RD, TAU_RDS, TAU_G, TAU_PC, TAU, TAU_SAT, TAU_MOTOR = (
    TORQUE_ROWS.index(name) for name in ("tau_T", "tau_RD", "tau_RDs", "tau_G", "tau_PC", "tau", "tau_sat", "tau_motor")
)
ASSIST_SCALE, SATURATION_SCALE, ROT_WEIGHT, RAMP, PO_ENERGY, PC_CUT = (
    SCALARS.index(name) for name in ("assist_scale", "saturation_scale", "rot_weight", "ramp", "po_energy", "pc_cut")
)


class Grip(NamedTuple):
    """The grip's kinematics this tick, in the base {0}.

    Attributes:
        T_0_G0: Reference grip pose (4, 4). R_0_G, p_0_G: grip rotation (3, 3) and position (m).
        p_0_W: Wrist position (m), (3,). J_W: wrist Jacobian in {0} (6, n).
        R_W_G, p_W_G: The grip {G} in the wrist frame {W} (fixed by the device geometry).
    """

    T_0_G0: Array
    R_0_G: Array
    p_0_G: Array
    p_0_W: Array
    J_W: Array
    R_W_G: Array
    p_W_G: Array


class Payload(NamedTuple):
    """What is removed from the F/T reading, and how it reaches {MRF}.

    Attributes:
        remove: Subtract the payload weight. mass (kg), com_S (m, in {S}): the payload.
        gravity_w: Gravity in the slave world (m/s^2), (3,). X_MRF_S: Eq 6 matrix {S} -> {MRF}.
    """

    remove: bool
    mass: float
    com_S: Array
    gravity_w: Array
    X_MRF_S: Array


class Laws(NamedTuple):
    """Gains and options of the command and rendering laws.

    Attributes:
        gains: The (9, 6) gain rows (:data:`~app.controller.layout.GAIN_ROWS`).
        rate_mode: Rate (else pose) commands. rtc_kind: index into
            :data:`~app.controller.layout.RTC_LAWS`. taper: ``[start, stop]`` |beta| (rad) of
            the rotational fade near gimbal lock. assist_limit: Eq 11 capacity share (n,).
    """

    gains: Array
    rate_mode: bool
    rtc_kind: int
    taper: Array
    assist_limit: Array


class Motors(NamedTuple):
    """Sec 3.4 and 4.2: joint limits (N m or N), gear ratios, the torque curves and counts range."""

    joint_limit: Array
    gear_ratio: Array
    horner_pos: Array
    horner_neg: Array
    counts_max: int


class Outputs(NamedTuple):
    """The tick's outputs (see :class:`~app.controller.frhc.ControllerOutput`): ``vectors`` (9, 6),
    ``torques`` (8, n), ``counts`` (n,) int64, ``twist`` (6,) and ``scalars`` (6,)."""

    vectors: Array
    torques: Array
    counts: IntArray
    twist: Array
    scalars: Array


def record_dtype(n: int, nbody: int, n_coeffs: int) -> np.dtype:
    """The controller's record for ``n`` joints, ``nbody`` MuJoCo bodies, ``n_coeffs`` curve coefficients.

    Fields, besides :func:`~app.controller.kinematics.topology_fields`:

    Configuration (set by the controller's constructor and ``set_gains``):
        gains: The (9, 6) gain rows. rate_mode: rate (else pose) commands. rtc_kind: index into
        ``RTC_LAWS``. taper: ``[start, stop]`` |beta| (rad) of the rotational fade near gimbal
        lock. gravity_compensation, remove_payload, remove_inertia: the options of the same
        names. min_period, max_period: accepted periods (s). ramp_rate (1/s), max_joint_speed and
        release_speed (rad/s or m/s): :class:`~app.controller.safety.SafetyLimits`. encoder_count:
        one count of each joint's encoder (rad or m, (n,); 0 for an ideal encoder), for the
        velocity brake and the passivity observer. pc_on, pc_limit
        (n,) (N m or N), po_cap (J), po_friction (N m, (n,)), po_damping (N m s/rad, (n,)), po_swing (the share of the reversal charge, -), pc_reserve (J), pc_step (rad, (n,)), pc_credit (N m, (n,)), pc_law_count (rad, (n,): the encoder count where ``passive_law``, else 0), pc_law_step (``law_onset == "step"``), pc_filter (s),
        pc_hold, pc_b_device (N s/m), pc_bleed (s): :class:`~app.controller.passivity.PassivitySettings`. assist_limit, joint_limit, gear_ratio:
        (n,) each (N m or N; -). horner_pos, horner_neg: (n, n_coeffs) torque curves, highest
        order first; counts_max: the amplifier's range. payload_mass (kg), payload_com_S (m, in
        {S}), payload_inertia_S (kg m^2, about the centre of mass, {S} axes), gravity_w (m/s^2,
        in {w}): the slave's payload. X_MRF_S: Eq 6 matrix {S} -> {MRF} (6, 6). R_W_G, p_W_G:
        the grip {G} in the wrist {W}.

    State:
        T_w_MRF0: The slave reference pose (4, 4). dx_prev: Delta X of the previous tick (6,).
        restart_damping: No previous Delta X on this reference (Eq 9 starts from zero).
        prev_reference, prev_deadman, prev_reflecting: Last tick's switches, for edges. J_W:
        wrist Jacobian (6, n). q_prev, have_q_prev: last finite joint angles; qdot: joint
        velocities from their difference (n,); brake_velocity: their average the velocity brake
        judges (n,). braking: the velocity brake is on. gravity_level:
        the share of gravity compensation applied, in [0, 1] (0 after a joint-reading fault, ramping
        back at ``ramp_rate``). po_energy:
        the passivity observer's energy of the whole port (J), (1,); po_tau: the rendered torque
        commanded last tick (N m or N), (n,); po_angle: the observer's joint angles, each on the
        edge of its count the joint last crossed (rad or m), (n,); po_run: each joint's counts moved in
        one direction since its last reversal (signed, (n,)); pc_law_zero: the passive law's zero
        (J), (1,), ``-inf`` while the law is not entered; pc_velocity: the low-passed joint velocity the
        passivity controller uses (n,); pc_offset: the PC's hold on
        the slave's command (m, {0}, (3,)); pc_dx_prev: last tick's Delta X command translations
        before it (m, (3,)).

    Outputs (see :class:`~app.controller.frhc.ControllerOutput`):
        T_0_G, T_0_G0 (4, 4); vectors (9, 6); torques (8, n); counts (n,) int64; scalars (6,);
        twist (6,) and T_w_MRF (4, 4): the slave command.
    """
    f8, i8, b1 = np.float64, np.int64, np.bool_
    return np.dtype(
        [
            *topology_fields(n, nbody),
            ("gains", f8, (len(GAIN_ROWS), 6)),
            ("rate_mode", b1),
            ("rtc_kind", i8),
            ("taper", f8, (2,)),
            ("gravity_compensation", b1),
            ("remove_payload", b1),
            ("remove_inertia", b1),
            ("max_period", f8),
            ("min_period", f8),
            ("ramp_rate", f8),
            ("max_joint_speed", f8),
            ("release_speed", f8),
            ("pc_on", b1),
            ("pc_limit", f8, (n,)),
            ("po_cap", f8),
            ("po_friction", f8, (n,)),
            ("po_damping", f8, (n,)),
            ("po_swing", f8),
            ("encoder_count", f8, (n,)),
            ("pc_reserve", f8),
            ("pc_step", f8, (n,)),
            ("pc_credit", f8, (n,)),
            ("pc_law_count", f8, (n,)),
            ("pc_law_step", b1),
            ("pc_filter", f8),
            ("pc_hold", b1),
            ("pc_b_device", f8),
            ("pc_bleed", f8),
            ("pc_offset", f8, (3,)),
            ("pc_dx_prev", f8, (3,)),
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
            ("prev_reflecting", b1),
            ("q_prev", f8, (n,)),
            ("have_q_prev", b1),
            ("qdot", f8, (n,)),
            ("brake_velocity", f8, (n,)),
            ("braking", b1),
            ("gravity_level", f8),
            ("po_energy", f8, (1,)),
            ("pc_law_zero", f8, (1,)),
            ("po_tau", f8, (n,)),
            ("po_angle", f8, (n,)),
            ("po_run", f8, (n,)),
            ("pc_velocity", f8, (n,)),
            ("J_W", f8, (6, n)),
            ("T_0_G", f8, (4, 4)),
            ("T_0_G0", f8, (4, 4)),
            ("vectors", f8, (len(VECTOR_ROWS), 6)),
            ("torques", f8, (len(TORQUE_ROWS), n)),
            ("counts", i8, (n,)),
            ("scalars", f8, (len(SCALARS),)),
            ("twist", f8, (6,)),
            ("T_w_MRF", f8, (4, 4)),
        ],
        align=True,
    )
