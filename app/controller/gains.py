"""Controller gains and options (the paper's K matrices, Fig. 3), as one frozen dataclass.

All six-element tuples are the diagonals of the paper's 6x6 gain matrices, ordered like
Delta X: ``[x, y, z, gamma, beta, alpha]`` (translations first, then Z-Y-X angles).

Every field has a physical :class:`~app.config.Range` (shown in ``devices/README.md``), checked
whenever gains are built: from a device or session file, or from the web panel's text fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Annotated, Any

from app.config import Checked, Range
from app.controller.layout import Mode, RtcLaw
from app.errors import InvalidField

Six = tuple[float, float, float, float, float, float]

ZERO6: Six = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
ONE6: Six = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
INF6: Six = (math.inf, math.inf, math.inf, math.inf, math.inf, math.inf)


@dataclass(frozen=True)
class ControllerGains(Checked):
    """Gains of the Cartesian FRHC controller. Units are per axis: translations, then rotations.

    Attributes:
        mode: ``"rate"`` (Eq 5, K_V) or ``"pose"`` (Sec 3.5, K_P) commands to the slave.
        k_v: Rate gains K_V (1/s): slave MRF velocity (m/s, rad/s) per unit Delta X.
        k_p: Pose gains K_P (-): slave displacement per grip displacement. The three
            rotational gains must be 1, because Z-Y-X angles cannot be scaled (Sec 3.5).
        k_t: Task-wrench gains K_T (-): grip wrench per MRF wrench component.
        k_d: Damping gains K_D (N s/m, N m s/rad): ``G_F_D = -K_D d(Delta X)/dt`` (Eq 9,
            divided by the period so the gain means the same at any servo rate).
        rtc: Return-to-centre law (rate mode only): ``"constant"`` (CFRTC, Eq 8),
            ``"hooke"`` (``-K_R Delta X``) or ``"off"``.
        rtc_a: CFRTC parabolic constants a_i (N/m^2, N m/rad^2).
        deadband: Deadband half-widths Delta X_iDB (m, rad); inside, the axis commands nothing.
        k_r: Hooke return-to-centre stiffness K_R (N/m, N m/rad).
        wall_start: Where the optional stiff workspace-edge wall begins (m, rad); inf = no wall.
        k_wall: Wall stiffness beyond ``wall_start`` (N/m, N m/rad).
        assist_fraction: Fraction (0, 1] of motor capacity the assist torques tau_RD may use
            (Eq 11); tau_RD is scaled uniformly to fit.
        remove_payload: Subtract the end-effector/payload weight from the F/T reading.
        remove_inertia: Also subtract the payload's inertial load, so only the contact wrench is
            reflected (:func:`~app.controller.payload.add_inertial_load`). Needs the linear and
            angular acceleration of {S} and the tool's angular velocity in the reading
            (:class:`~app.controller.types.FTReading`): both simulated slaves report the
            accelerations their integrator applied; a real slave must supply its arm's joint
            accelerations mapped through the Jacobian (``J qdd + Jdot qd``) or a filtered
            estimate (encoder positions differentiated twice and low-passed, or an
            accelerometer at the sensor less gravity), whose lag puts the inertial load back
            late. Off by default, by measurement (issue 26; ``docs/conventions.md``, "The
            reflected wrench is the sensor's reading"): the reading is the force the tool's
            mass transmits, which filters the impact on a stiff surface; reflecting the contact
            force alone passes the impact on, and plain rendering held 26 instead of 39 of the
            84 shipped-device test walls, 58 instead of 121 of 216 held-out ones (PO/PC 71 and
            193 instead of 62 and 158, but felt softer).
        gravity_compensation: Add tau_G (Sec 3.3). On by default and independent of the deadman.
        euler_taper_deg: ``(start, stop)`` |beta| in degrees over which the rotational rate command
            is tapered to zero near the Z-Y-X singularity cos(beta) = 0.
        max_period: Longest servo period (s) accepted; a longer one is an overrun fault.
    """

    mode: Mode = "rate"
    k_v: Annotated[Six, Range(0.0, 1e3, "1/s", name_array=True)] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    k_p: Annotated[Six, Range(0.0, 100.0, name_array=True)] = ONE6
    k_t: Annotated[Six, Range(0.0, 1e6, name_array=True)] = ONE6
    k_d: Annotated[Six, Range(0.0, 1e3, "N s/m; N m s/rad", name_array=True)] = (2.0, 2.0, 2.0, 0.02, 0.02, 0.02)
    rtc: RtcLaw = "constant"
    rtc_a: Annotated[Six, Range(0.0, 1e7, "N/m^2; N m/rad^2", name_array=True)] = (2.0e3, 2.0e3, 2.0e3, 2.0, 2.0, 2.0)
    deadband: Annotated[Six, Range(0.0, 1.0, "m; rad", name_array=True)] = (0.01, 0.01, 0.01, 0.05, 0.05, 0.05)
    k_r: Annotated[Six, Range(0.0, 1e5, "N/m; N m/rad", name_array=True)] = (50.0, 50.0, 50.0, 0.5, 0.5, 0.5)
    wall_start: Annotated[Six, Range(0.0, 10.0, "m; rad", inf_ok=True, name_array=True)] = INF6
    k_wall: Annotated[Six, Range(0.0, 1e6, "N/m; N m/rad", name_array=True)] = ZERO6
    assist_fraction: Annotated[float, Range(0.0, 1.0, lo_open=True)] = 0.3
    remove_payload: bool = True
    remove_inertia: bool = False
    gravity_compensation: bool = True
    euler_taper_deg: Annotated[tuple[float, float], Range(0.0, 90.0, "deg", lo_open=True, hi_open=True)] = (75.0, 85.0)
    max_period: Annotated[float, Range(1e-5, 1.0, "s")] = 0.01

    def validate(self) -> None:
        if self.k_p[3:] != (1.0, 1.0, 1.0):
            raise InvalidField("k_p", "rotational pose gains (last three) must be 1: Z-Y-X angles cannot be scaled")
        if any(w < db for w, db in zip(self.wall_start, self.deadband, strict=True)):
            raise InvalidField("wall_start", "the wall must begin outside the deadband")
        start, stop = self.euler_taper_deg
        if not start < stop:
            raise InvalidField("euler_taper_deg", "need 0 < start < stop < 90 degrees")

    def with_changes(self, **changes: Any) -> ControllerGains:
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)
