"""The Cartesian FRHC controller: the paper's Fig. 3 pipeline, one :meth:`FRHCController.step` a tick.

Per tick: encoder angles -> FK ``T_0_G`` (Eq 1) -> TMAT difference against ``T_0_G0`` (Eq 2-4)
-> deadband channels -> rate command (K_V, Eq 5) or pose command (K_P, Sec 3.5) for the slave.
Back: F/T reading ``F_S`` -> payload removal -> ``F_MRF`` (Eq 6) -> K_T -> ``G_F_T`` ->
{G} to {W} (Eq 6 form) -> ``tau_T = J^T F`` (Eq 7); return-to-centre (Eq 8) + damping (Eq 9)
-> ``tau_RD`` scaled to a fraction of capacity (Eq 10-11); + gravity compensation ``tau_G``;
total (Eq 12) -> uniform saturation -> gear ratios -> torque curve -> motor counts.

MuJoCo does the kinematics, Jacobian and gravity sums; the arithmetic of Eq 2-12 runs in the
compiled kernel :func:`app.controller.kernel.cartesian_tick` on preallocated arrays. This class
keeps what needs Python: the switches, the reference, faults and the pose command.
"""

from __future__ import annotations

import math

import numpy as np

from app.controller import kernel
from app.controller.calibration import TorqueCurve
from app.controller.gains import ControllerGains
from app.controller.kinematics import DeviceKinematics
from app.controller.types import Fault, FTReading, SlaveCommand, SlaveModel, Switches
from app.device.spec import DeviceSpec
from app.spatial import Array, wrench_transform, zyx_to_matrix

VECTOR_ROWS = ("delta_x", "delta_x_cmd", "F_S_task", "F_MRF", "G_F_T", "G_F_R", "G_F_D", "G_F_RD", "W_F_T")
TORQUE_ROWS = ("tau_T", "tau_RD", "tau_RDs", "tau_G", "tau", "tau_sat", "tau_motor")


class ControllerOutput:
    """Everything one tick produced, for the slave, the motors, the display and the logs.

    The controller reuses one instance and overwrites it every tick: copy what you keep.
    Wrenches are ``[f; m]`` (N, N m); torques are joint-side (N m, or N for slides) unless named
    ``motor``. Six-vectors are rows of ``vectors`` (9, 6) and torques rows of ``torques`` (7, n);
    the named attributes are views of those rows.

    Attributes:
        T_0_G: Grip pose in the base frame (Eq 1), (4, 4).
        T_0_G0: Reference grip pose, (4, 4).
        delta_x: Delta X (Eq 4): ``[x, y, z, gamma, beta, alpha]`` (m, rad).
        delta_x_cmd: Delta X after the deadband channels (what is commanded).
        command: The slave command (rate twist or pose).
        F_S_task: F/T reading with payload (and optionally inertial) loads removed, at {S} in {S}.
        F_MRF: The task wrench at {MRF} in {MRF} (Eq 6).
        G_F_T: Task wrench to be felt at the grip, ``K_T F_MRF``, in {G}.
        G_F_R: Return-to-centre wrench (Eq 8) in {G}.
        G_F_D: Damping wrench (Eq 9) in {G}.
        G_F_RD: Assist wrench ``G_F_R + G_F_D`` (Eq 10) in {G}.
        W_F_T: The task wrench moved to the wrist {W}, in {W} (Eq 6 form, G -> W).
        tau_T, tau_RD, tau_RDs, tau_G: Task, assist, scaled assist (Eq 11) and gravity torques.
        tau: Total ``tau_T + tau_RDs + tau_G`` (Eq 12).
        tau_sat: ``tau`` after uniform saturation to the joint limits.
        tau_motor: Motor-side torques ``tau_sat / gear_ratio`` (N m).
        counts: Motor commands (counts), int64, shape (n,).
        assist_scale: Factor applied to ``tau_RD`` (Eq 11), in (0, 1].
        saturation_scale: Factor applied to ``tau`` by the final saturation, in (0, 1].
        rot_weight: 1 normally; tapers to 0 near the Z-Y-X singularity |beta| -> 90 deg.
        reflecting: Task wrench and assists were rendered this tick (deadman and reflection on).
        faults: Why the safe output was used this tick (``Fault.NONE`` if it was not).
        fault_message: Human-readable reason, empty when there is no fault.
    """

    delta_x: Array
    delta_x_cmd: Array
    F_S_task: Array
    F_MRF: Array
    G_F_T: Array
    G_F_R: Array
    G_F_D: Array
    G_F_RD: Array
    W_F_T: Array
    tau_T: Array
    tau_RD: Array
    tau_RDs: Array
    tau_G: Array
    tau: Array
    tau_sat: Array
    tau_motor: Array

    def __init__(self, n: int) -> None:
        self.n = n
        self.T_0_G = np.eye(4)
        self.T_0_G0 = np.eye(4)
        self.vectors = np.zeros((len(VECTOR_ROWS), 6))
        self.scalars = np.ones(3)  # assist_scale, saturation_scale, rot_weight (kernel slots)
        self.torques = np.zeros((len(TORQUE_ROWS), n))
        for i, name in enumerate(VECTOR_ROWS):
            setattr(self, name, self.vectors[i])
        for i, name in enumerate(TORQUE_ROWS):
            setattr(self, name, self.torques[i])
        self.counts = np.zeros(n, dtype=np.int64)
        self.command = SlaveCommand()
        self.reflecting = False
        self.faults = Fault.NONE
        self.fault_message = ""

    @property
    def assist_scale(self) -> float:
        return float(self.scalars[kernel.ASSIST_SCALE])

    @property
    def saturation_scale(self) -> float:
        return float(self.scalars[kernel.SATURATION_SCALE])

    @property
    def rot_weight(self) -> float:
        return float(self.scalars[kernel.ROT_WEIGHT])


class FRHCController:
    """Cartesian controller of one force-reflecting hand controller (paper Sec 3-4).

    Args:
        device: The device (its nominal MJCF model, motors and torque curves).
        gains: Gains and options; see :class:`ControllerGains`.
        slave: What the controller knows of the slave tool: {MRF}-{S} transform, payload, gravity.
        curve: Torque-to-counts curve; by default the one the device file selects.

    Frames: {0} device base, {G} grip, {G0} reference grip pose, {W} wrist, {w} slave world,
    {MRF} slave moving reference frame, {S} F/T sensor. The FRHC base axes are taken aligned
    with the slave world axes.
    """

    def __init__(
        self,
        device: DeviceSpec,
        gains: ControllerGains,
        slave: SlaveModel,
        curve: TorqueCurve | None = None,
    ) -> None:
        self.device = device
        self.kin = DeviceKinematics(device)
        self.slave = slave
        self.curve = curve if curve is not None else TorqueCurve.for_device(device)
        n = device.n_joints
        motors = device.data.motors
        self.gear_ratio = np.array(motors.gear_ratio, dtype=float)
        self.joint_limit = self.gear_ratio * np.array(motors.torque_limit)
        self.out = ControllerOutput(n)
        self._J = np.zeros((6, n))
        self._F_S = np.zeros(6)
        self._dx_prev = np.zeros(6)
        self._T_w_MRF0 = np.array(slave.T_w_MRF_home, dtype=float)
        T_MRF_S = np.asarray(slave.T_MRF_S, dtype=float)
        self._X_MRF_S = wrench_transform(T_MRF_S[0:3, 0:3], T_MRF_S[0:3, 3])
        self._payload = np.zeros(8)
        self._payload[0] = slave.payload_mass
        self._payload[1:4] = slave.payload_com_S
        self._payload[4:7] = slave.gravity_w
        # {G} is rigidly attached to {W}: its offset is fixed by the device geometry.
        self.kin.update(np.array(device.data.home))
        R_0_W = self.kin.R_0_W
        self._R_W_G = R_0_W.T @ self.kin.R_0_G
        self._p_W_G = R_0_W.T @ (self.kin.p_0_G - self.kin.p_0_W)
        self._prev_reference = False
        self._prev_deadman = False
        self._restart_damping = True
        self.set_gains(gains)
        self.reset(np.array(device.data.home))

    # -- configuration -------------------------------------------------------------------------

    def set_gains(self, gains: ControllerGains) -> None:
        """Switch gains (and mode) between ticks. Changing the mode re-references (no jump)."""
        previous: ControllerGains | None = getattr(self, "gains", None)
        self.gains = gains
        self._gains = np.array(
            [
                gains.k_v,
                gains.k_p,
                gains.k_t,
                gains.k_d,
                gains.rtc_a,
                gains.deadband,
                gains.k_r,
                gains.wall_start,
                gains.k_wall,
            ]
        )
        self._rtc_kind = {"off": kernel.RTC_OFF, "constant": kernel.RTC_CONSTANT, "hooke": kernel.RTC_HOOKE}[gains.rtc]
        self._assist_limit = gains.assist_fraction * self.joint_limit
        self._taper = np.radians(gains.euler_taper_deg)
        self._payload[7] = 1.0 if gains.remove_payload else 0.0
        self.out.command.mode = gains.mode
        if previous is not None and previous.mode != gains.mode:
            self._set_reference()

    def reset(self, q: Array, T_w_MRF_home: Array | None = None) -> None:
        """Start over at joint angles ``q``: reference {G0} = FK(q), slave reference = home."""
        self.out.command.T_w_MRF[:] = self.slave.T_w_MRF_home if T_w_MRF_home is None else T_w_MRF_home
        self.kin.update(np.asarray(q, dtype=float))
        self.out.T_0_G[0:3, 0:3] = self.kin.R_0_G
        self.out.T_0_G[0:3, 3] = self.kin.p_0_G
        self._set_reference()
        self._prev_reference = False
        self._prev_deadman = False

    def _set_reference(self) -> None:
        """Reference switch (Sec 3.1, 4.1): {G0} := {G}; the slave reference := its last command.

        In pose mode this is indexing: the new zero of Delta X maps onto where the slave was
        commanded to be, so the slave never jumps. Damping restarts from the new Delta X.
        """
        self.out.T_0_G0[:] = self.out.T_0_G
        self._T_w_MRF0[:] = self.out.command.T_w_MRF
        self._restart_damping = True

    # -- the tick -------------------------------------------------------------------------------

    def step(self, q: Array, switches: Switches, ft: FTReading, dt: float) -> ControllerOutput:
        """Run one servo tick.

        Args:
            q: Encoder joint angles (rad, or m for slides), shape (n,).
            switches: Deadman, reference (momentary) and reflection switches.
            ft: The slave's F/T reading at {S}.
            dt: Servo period (s) since the previous tick.

        Returns:
            The (reused) :class:`ControllerOutput`. It never holds a non-finite torque: on a
            NaN/inf input, a bad period or an invalid F/T reading it falls back to gravity
            compensation only (zero torque when even the joint angles are unusable), stops the
            slave and names the fault.
        """
        o = self.out
        g = self.gains
        # A sum is finite only if every term is (huge finite values overflowing to inf also trip
        # it, which is the safe side); one reduction per array keeps this cheap.
        if not math.isfinite(float(q.sum())):
            return self._safe_output(Fault.NONFINITE_INPUT, "non-finite joint angles", gravity=False)
        faults = Fault.NONE
        if not 0.0 < dt <= g.max_period:  # also catches a NaN period
            faults |= Fault.BAD_PERIOD
        if not ft.valid:
            faults |= Fault.FT_INVALID
        elif not math.isfinite(float(ft.wrench_S.sum()) + float(ft.R_w_S.sum())):
            faults |= Fault.NONFINITE_INPUT

        kin = self.kin
        kin.update(q)
        o.T_0_G[0:3, 0:3] = kin.R_0_G
        o.T_0_G[0:3, 3] = kin.p_0_G
        if g.gravity_compensation:
            kin.gravity_torque(o.tau_G)
        else:
            o.tau_G[:] = 0.0
        if faults:
            return self._safe_output(faults, _fault_text(faults), gravity=True)

        # Switches (Sec 4.1). A deadman press in pose mode is a clutch: re-reference, no jump.
        reference_edge = switches.reference and not self._prev_reference
        deadman_edge = switches.deadman and not self._prev_deadman
        self._prev_reference = switches.reference
        self._prev_deadman = switches.deadman
        if reference_edge or (deadman_edge and g.mode == "pose"):
            self._set_reference()

        reflecting = switches.deadman and switches.reflection
        F_S = self._remove_inertia(ft) if g.remove_inertia else ft.wrench_S
        ok = kernel.cartesian_tick(
            o.T_0_G0,
            kin.R_0_G,
            kin.p_0_G,
            kin.p_0_W,
            kin.jacobian_W(self._J),
            F_S,
            ft.R_w_S,
            self._payload,
            self._X_MRF_S,
            self._R_W_G,
            self._p_W_G,
            self._gains,
            g.mode == "rate",
            self._rtc_kind,
            self._taper,
            self._assist_limit,
            self.joint_limit,
            self.gear_ratio,
            self.curve.horner_pos,
            self.curve.horner_neg,
            self.curve.counts_max,
            switches.deadman,
            reflecting,
            dt,
            self._dx_prev,
            self._restart_damping,
            o.vectors,
            o.torques,
            o.counts,
            o.command.twist,
            o.scalars,
        )
        self._restart_damping = False
        if not ok:
            return self._safe_output(Fault.NONFINITE_OUTPUT, "non-finite torque (singular pose?)", gravity=True)
        o.command.active = switches.deadman
        if switches.deadman and g.mode == "pose":
            self._pose_command()
        o.reflecting = reflecting
        o.faults = Fault.NONE
        o.fault_message = ""
        return o

    def _pose_command(self) -> None:
        """Sec 3.5: Delta X (after the deadband) scaled by K_P and applied to the slave reference pose.

        Translations are in base/world axes; the rotation is applied in the reference frame's own
        axes. Without the deadman the last command is held.
        """
        dxc = self.out.delta_x_cmd
        T0 = self._T_w_MRF0
        T = self.out.command.T_w_MRF
        T[0:3, 3] = T0[0:3, 3] + self._gains[kernel.K_P, 0:3] * dxc[0:3]
        T[0:3, 0:3] = T0[0:3, 0:3] @ zyx_to_matrix(float(dxc[3]), float(dxc[4]), float(dxc[5]))

    def _remove_inertia(self, ft: FTReading) -> Array:
        """The reading with the payload's inertial load added back (the sensor reads minus its
        d'Alembert load); the kernel then removes the weight."""
        s = self.slave
        R_S_w = ft.R_w_S.T
        c_S = s.payload_com_S
        w_S = R_S_w @ ft.omega_w
        alpha_S = R_S_w @ ft.acc_w[3:6]
        a_com = R_S_w @ ft.acc_w[0:3] + np.cross(alpha_S, c_S) + np.cross(w_S, np.cross(w_S, c_S))
        f = s.payload_mass * a_com
        I = s.payload_inertia_S
        self._F_S[0:3] = ft.wrench_S[0:3] + f
        self._F_S[3:6] = ft.wrench_S[3:6] + np.cross(c_S, f) + I @ alpha_S + np.cross(w_S, I @ w_S)
        return self._F_S

    def _safe_output(self, faults: Fault, message: str, gravity: bool) -> ControllerOutput:
        """Fallback: gravity compensation only (zero without usable q), slave stopped, fault named."""
        o = self.out
        o.faults = faults
        o.fault_message = message
        o.reflecting = False
        o.command.active = False
        o.command.twist[:] = 0.0
        o.vectors[:] = 0.0
        self._restart_damping = True
        tau_G = o.tau_G.copy() if gravity and math.isfinite(float(o.tau_G.sum())) else np.zeros(o.n)
        o.torques[:] = 0.0
        o.tau_G[:] = tau_G
        o.tau[:] = tau_G
        o.scalars[kernel.ASSIST_SCALE] = 1.0
        o.scalars[kernel.SATURATION_SCALE] = kernel.motor_commands(
            o.torques,
            self.joint_limit,
            self.gear_ratio,
            self.curve.horner_pos,
            self.curve.horner_neg,
            self.curve.counts_max,
            o.counts,
        )
        return o


def _fault_text(faults: Fault) -> str:
    parts = []
    if faults & Fault.BAD_PERIOD:
        parts.append("servo period not in (0, max_period] (an overrun, or a bad clock)")
    if faults & Fault.FT_INVALID:
        parts.append("F/T reading marked invalid by the world (failed contact query)")
    if faults & Fault.NONFINITE_INPUT:
        parts.append("non-finite F/T reading")
    return "; ".join(parts)
