"""Names of the controller's record rows and choice lists, defined once.

The compiled tick (:mod:`app.controller.kernel`) indexes rows of its gain, vector, torque and
scalar blocks by position; :class:`~app.controller.frhc.ControllerOutput` names them; the log
(:mod:`app.session.log`) turns them into columns; the web panel lists the gains and laws. All of
them take the names and the order from here, so a reordered or added row cannot silently
mislabel data: the indices, attribute names and column names are derived, never written twice.

Axis labels of each six-vector row say what kind of six-vector it is: Delta X
``[x, y, z, gamma, beta, alpha]`` (m, rad) or a wrench ``[f; m]`` (N, N m).
"""

from __future__ import annotations

from typing import Literal, get_args

DELTA_X_AXES = ("x", "y", "z", "gamma", "beta", "alpha")
WRENCH_AXES = ("fx", "fy", "fz", "mx", "my", "mz")
TWIST_AXES = ("vx", "vy", "vz", "wx", "wy", "wz")

GAIN_ROWS = ("k_v", "k_p", "k_t", "k_d", "rtc_a", "deadband", "k_r", "wall_start", "k_wall")
"""Rows of the kernel's ``gains`` block (9, 6): the six-tuple fields of
:class:`~app.controller.gains.ControllerGains` of the same names, each ordered like Delta X."""

VECTOR_ROWS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("delta_x", DELTA_X_AXES),
    ("delta_x_cmd", DELTA_X_AXES),
    ("F_S_task", WRENCH_AXES),
    ("F_MRF", WRENCH_AXES),
    ("G_F_T", WRENCH_AXES),
    ("G_F_R", WRENCH_AXES),
    ("G_F_D", WRENCH_AXES),
    ("G_F_RD", WRENCH_AXES),
    ("W_F_T", WRENCH_AXES),
)
"""Rows of the ``vectors`` block (9, 6): name and axis labels (see ``ControllerOutput``)."""

TORQUE_ROWS = ("tau_T", "tau_RD", "tau_RDs", "tau_G", "tau_PC", "tau", "tau_sat", "tau_motor")
"""Rows of the ``torques`` block (8, n): joint-side torques (``tau_PC`` is the passivity
controller's damping, :mod:`app.controller.passivity`), then motor-side ``tau_motor``."""

SCALARS = ("assist_scale", "saturation_scale", "rot_weight", "ramp", "po_energy", "pc_cut")
"""Slots of the ``scalars`` block (6,): the Eq 11 assist scale, the Sec 3.4 saturation scale, the
rotational fade near gimbal lock, the safety ramp level (:mod:`app.controller.safety`), the
passivity observer's energy summed over the joints (J) and the largest joint damping the
passivity controller applied this tick (N m s/rad) (:mod:`app.controller.passivity`)."""

Mode = Literal["rate", "pose"]
"""How the grip commands the slave: a twist (Eq 5, K_V) or a pose (Sec 3.5, K_P)."""
RtcLaw = Literal["off", "constant", "hooke"]
"""Return-to-centre laws (rate mode, Sec 3.3); the kernel's ``rtc_kind`` is the index here."""

MODES: tuple[str, ...] = get_args(Mode)
RTC_LAWS: tuple[str, ...] = get_args(RtcLaw)


def vector_row_names() -> tuple[str, ...]:
    """Names of the ``vectors`` rows in order."""
    return tuple(name for name, _ in VECTOR_ROWS)
