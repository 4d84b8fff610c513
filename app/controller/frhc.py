"""The Cartesian FRHC controller: the paper's Fig. 3 pipeline, one :meth:`FRHCController.step` a tick.

Per tick: encoder angles -> FK ``T_0_G`` (Eq 1) -> TMAT difference against ``T_0_G0`` (Eq 2-4)
-> deadband channels -> rate command (K_V, Eq 5) or pose command (K_P, Sec 3.5) for the slave.
Back: F/T reading ``F_S`` -> payload removal -> ``F_MRF`` (Eq 6) -> K_T -> ``G_F_T`` ->
{G} to {W} (Eq 6 form) -> ``tau_T = J^T F`` (Eq 7); return-to-centre (Eq 8) + damping (Eq 9)
-> ``tau_RD`` scaled to a fraction of capacity (Eq 10-11); + gravity compensation ``tau_G``;
total (Eq 12) -> uniform saturation -> gear ratios -> torque curve -> motor counts.

The tick works on Python floats for the six-vectors and writes its results into preallocated
arrays in a few bulk assignments: on small vectors each numpy call costs about a microsecond,
which would dominate the tick. MuJoCo does the kinematics, Jacobian and gravity sums in C.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from app.controller.assist import constant_force_rtc, damping, deadband, hooke_rtc, saturate, uniform_scale
from app.controller.calibration import TorqueCurve
from app.controller.gains import ControllerGains
from app.controller.kinematics import DeviceKinematics
from app.controller.types import Fault, FTReading, SlaveCommand, SlaveModel, Switches
from app.device.spec import DeviceSpec
from app.spatial import Array, body_rate_from_euler, move_wrench, tmat_difference, wrench_transform, zyx_to_matrix

Vec = list[float]

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
        self.torques = np.zeros((len(TORQUE_ROWS), n))
        for i, name in enumerate(VECTOR_ROWS):
            setattr(self, name, self.vectors[i])
        for i, name in enumerate(TORQUE_ROWS):
            setattr(self, name, self.torques[i])
        self.counts = np.zeros(n, dtype=np.int64)
        self.command = SlaveCommand()
        self.assist_scale = 1.0
        self.saturation_scale = 1.0
        self.rot_weight = 1.0
        self.reflecting = False
        self.faults = Fault.NONE
        self.fault_message = ""


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
        self.gear_ratio = [float(v) for v in motors.gear_ratio]
        self.joint_limit = [gr * lim for gr, lim in zip(self.gear_ratio, motors.torque_limit, strict=True)]
        self.out = ControllerOutput(n)
        self._J = np.zeros((6, n))
        self._F0 = np.zeros((6, 2))
        self._tau2 = np.zeros((n, 2))
        self._tau_G = np.zeros(n)
        self._dx_prev: Vec = [0.0] * 6
        self._T_w_MRF0 = np.array(slave.T_w_MRF_home, dtype=float)
        T_MRF_S = np.asarray(slave.T_MRF_S, dtype=float)
        self._X_MRF_S = wrench_transform(T_MRF_S[0:3, 0:3], T_MRF_S[0:3, 3]).tolist()
        self._gravity_w = [float(v) for v in slave.gravity_w]
        self._payload_com = [float(v) for v in slave.payload_com_S]
        # {G} is rigidly attached to {W}: its offset is fixed by the device geometry.
        self.kin.update(np.array(device.data.home))
        R_0_W = self.kin.R_0_W
        self._R_W_G = (R_0_W.T @ self.kin.R_0_G).tolist()
        self._p_W_G = (R_0_W.T @ (self.kin.p_0_G - self.kin.p_0_W)).tolist()
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
        self._assist_limit = [gains.assist_fraction * lim for lim in self.joint_limit]
        self._taper = (math.radians(gains.euler_taper_deg[0]), math.radians(gains.euler_taper_deg[1]))
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
            return self._safe_output(Fault.NONFINITE_INPUT, "non-finite joint angles", None)
        faults = Fault.NONE
        if not 0.0 < dt <= g.max_period:  # also catches a NaN period
            faults |= Fault.BAD_PERIOD
        F_S = ft.wrench_S.tolist()
        R_w_S = ft.R_w_S.tolist()
        if not ft.valid:
            faults |= Fault.FT_INVALID
        elif not math.isfinite(sum(F_S) + sum(map(sum, R_w_S))):
            faults |= Fault.NONFINITE_INPUT

        kin = self.kin
        kin.update(q)
        o.T_0_G[0:3, 0:3] = kin.R_0_G
        o.T_0_G[0:3, 3] = kin.p_0_G
        tau_G = kin.gravity_torque(self._tau_G).tolist() if g.gravity_compensation else [0.0] * o.n
        if faults:
            return self._safe_output(faults, _fault_text(faults), tau_G)

        # Switches (Sec 4.1). A deadman press in pose mode is a clutch: re-reference, no jump.
        reference_edge = switches.reference and not self._prev_reference
        deadman_edge = switches.deadman and not self._prev_deadman
        self._prev_reference = switches.reference
        self._prev_deadman = switches.deadman
        if reference_edge or (deadman_edge and g.mode == "pose"):
            self._set_reference()

        # Eq 2-4, then the deadband input channels.
        dx = tmat_difference(o.T_0_G0, o.T_0_G)
        if self._restart_damping:
            self._dx_prev = dx
            self._restart_damping = False
        dxc = [deadband(v, db) for v, db in zip(dx, g.deadband, strict=True)]
        abs_beta = abs(dx[4])
        start, stop = self._taper
        rot_weight = 1.0 if abs_beta <= start else max(0.0, (stop - abs_beta) / (stop - start))
        twist = self._command(switches.deadman, dxc, rot_weight)

        reflecting = switches.deadman and switches.reflection
        F_S_task = self._remove_payload(F_S, R_w_S, ft)
        X = self._X_MRF_S
        F_MRF = [sum(x * f for x, f in zip(row, F_S_task, strict=True)) for row in X]
        G_F_T = [k * f for k, f in zip(g.k_t, F_MRF, strict=True)] if reflecting else [0.0] * 6
        G_F_R, G_F_D = self._assist(dx, dt, rot_weight, reflecting)
        self._dx_prev = dx
        G_F_RD = [r + d for r, d in zip(G_F_R, G_F_D, strict=True)]

        # {G} -> {W} -> base coordinates, then Eq 7 for task and assist wrenches in one product.
        R_0_G = kin.R_0_G.tolist()
        r_WG_0 = (kin.p_0_G - kin.p_0_W).tolist()
        self._F0[:] = list(zip(move_wrench(R_0_G, r_WG_0, G_F_T), move_wrench(R_0_G, r_WG_0, G_F_RD), strict=True))
        np.matmul(kin.jacobian_W(self._J).T, self._F0, out=self._tau2)
        tau_T, tau_RD = zip(*self._tau2.tolist(), strict=True)
        W_F_T = move_wrench(self._R_W_G, self._p_W_G, G_F_T)

        # Eq 11: the assists use at most a set fraction of capacity so the task wrench dominates.
        assist_scale = uniform_scale(tau_RD, self._assist_limit)
        tau_RDs = [t * assist_scale for t in tau_RD]
        tau = [a + b + c for a, b, c in zip(tau_T, tau_RDs, tau_G, strict=True)]
        if not math.isfinite(sum(tau)):
            return self._safe_output(Fault.NONFINITE_OUTPUT, "non-finite torque (singular pose?)", tau_G)

        o.vectors[:] = (dx, dxc, F_S_task, F_MRF, G_F_T, G_F_R, G_F_D, G_F_RD, W_F_T)
        o.command.twist[:] = twist
        o.command.active = switches.deadman
        o.assist_scale = assist_scale
        o.rot_weight = rot_weight
        o.reflecting = reflecting
        o.faults = Fault.NONE
        o.fault_message = ""
        self._motor_commands(tau_T, tau_RD, tau_RDs, tau_G, tau)
        return o

    def _command(self, deadman: bool, dxc: Vec, rot_weight: float) -> Vec:
        """Rate twist (K_V and Eq 5) or pose command (K_P, Sec 3.5) from Delta X after the deadband.

        Returns the rate twist ``[v; w]`` (zero in pose mode or without the deadman); a pose
        command is written into ``command.T_w_MRF`` (held while the deadman is released).
        """
        if not deadman:
            return [0.0] * 6
        g = self.gains
        if g.mode == "rate":
            gamma, beta, alpha = dxc[3:6]
            # Eq 5 with the static angles used as angle rates: body angular velocity (rad/s).
            w = body_rate_from_euler(gamma, beta, (gamma, beta, alpha))
            kv = g.k_v
            return [
                kv[0] * dxc[0],
                kv[1] * dxc[1],
                kv[2] * dxc[2],
                kv[3] * w[0] * rot_weight,
                kv[4] * w[1] * rot_weight,
                kv[5] * w[2] * rot_weight,
            ]
        T0 = self._T_w_MRF0
        T = self.out.command.T_w_MRF
        T[0:3, 3] = T0[0:3, 3] + np.multiply(g.k_p[0:3], dxc[0:3])
        T[0:3, 0:3] = T0[0:3, 0:3] @ zyx_to_matrix(dxc[3], dxc[4], dxc[5])
        return [0.0] * 6

    def _remove_payload(self, F_S: Vec, R_w_S: list[Vec], ft: FTReading) -> Vec:
        """Subtract the payload's weight (gravity expressed in {S}) and optionally its inertial load."""
        g = self.gains
        if not (g.remove_payload or g.remove_inertia):
            return F_S
        s = self.slave
        load = [0.0] * 6
        if g.remove_payload:
            gw = self._gravity_w
            m = s.payload_mass
            # g_S = R_w_S^T g_w, one column of R_w_S at a time.
            for i in range(3):
                load[i] = m * (R_w_S[0][i] * gw[0] + R_w_S[1][i] * gw[1] + R_w_S[2][i] * gw[2])
        if g.remove_inertia:
            # The sensor reads minus the payload's d'Alembert load; removing it means adding it back.
            R_S_w = ft.R_w_S.T
            c_S = s.payload_com_S
            a_S = R_S_w @ ft.acc_w[0:3]
            w_S = R_S_w @ ft.omega_w
            alpha_S = R_S_w @ ft.acc_w[3:6]
            a_com = a_S + np.cross(alpha_S, c_S) + np.cross(w_S, np.cross(w_S, c_S))
            I = s.payload_inertia_S
            inertial = np.concatenate((-s.payload_mass * a_com, -(I @ alpha_S + np.cross(w_S, I @ w_S))))
            load = [a + b for a, b in zip(load, inertial.tolist(), strict=True)]
        c = self._payload_com
        fx, fy, fz = load[0:3]
        load[3] += c[1] * fz - c[2] * fy
        load[4] += c[2] * fx - c[0] * fz
        load[5] += c[0] * fy - c[1] * fx
        return [f - lo for f, lo in zip(F_S, load, strict=True)]

    def _assist(self, dx: Vec, dt: float, rot_weight: float, reflecting: bool) -> tuple[Vec, Vec]:
        """Return-to-centre (Eq 8, rate mode only) and damping (Eq 9) at the grip, if reflecting.

        Near the Z-Y-X singularity the angles (and their differences) jump, so the rotational
        channels are faded out with ``rot_weight``.
        """
        if not reflecting:
            return [0.0] * 6, [0.0] * 6
        g = self.gains
        if g.mode == "rate" and g.rtc == "constant":
            rtc = [
                constant_force_rtc(v, a, db, w, k)
                for v, a, db, w, k in zip(dx, g.rtc_a, g.deadband, g.wall_start, g.k_wall, strict=True)
            ]
        elif g.mode == "rate" and g.rtc == "hooke":
            rtc = [hooke_rtc(v, k) for v, k in zip(dx, g.k_r, strict=True)]
        else:
            rtc = [0.0] * 6
        damp = [
            damping(v, vp, k, dt, i >= 3) for i, (v, vp, k) in enumerate(zip(dx, self._dx_prev, g.k_d, strict=True))
        ]
        for i in range(3, 6):
            rtc[i] *= rot_weight
            damp[i] *= rot_weight
        return rtc, damp

    def _motor_commands(
        self,
        tau_T: Sequence[float],
        tau_RD: Sequence[float],
        tau_RDs: Sequence[float],
        tau_G: Sequence[float],
        tau: Sequence[float],
    ) -> None:
        """Uniform saturation, gear ratios and the torque curve (Sec 3.4): tau -> counts."""
        o = self.out
        tau_sat, o.saturation_scale = saturate(tau, self.joint_limit)
        tau_motor = [t / gr for t, gr in zip(tau_sat, self.gear_ratio, strict=True)]
        o.torques[:] = (tau_T, tau_RD, tau_RDs, tau_G, tau, tau_sat, tau_motor)
        o.counts[:] = self.curve.counts(tau_motor)

    def _safe_output(self, faults: Fault, message: str, tau_G: Sequence[float] | None) -> ControllerOutput:
        """Fallback: gravity compensation only (zero without usable q), slave stopped, fault named."""
        o = self.out
        o.faults = faults
        o.fault_message = message
        o.reflecting = False
        o.command.active = False
        o.command.twist[:] = 0.0
        o.vectors[:] = 0.0
        o.assist_scale = 1.0
        self._restart_damping = True
        zeros = [0.0] * o.n
        gravity = zeros if tau_G is None or not math.isfinite(sum(tau_G)) else tau_G
        self._motor_commands(zeros, zeros, zeros, gravity, gravity)
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
