"""The Cartesian FRHC controller: the paper's Fig. 3 pipeline, one :meth:`FRHCController.step` a tick.

Per tick: encoder angles -> FK ``T_0_G`` (Eq 1) -> TMAT difference against ``T_0_G0`` (Eq 2-4)
-> deadband channels -> rate command (K_V, Eq 5) or pose command (K_P, Sec 3.5) for the slave.
Back: F/T reading ``F_S`` -> payload removal -> ``F_MRF`` (Eq 6) -> K_T -> ``G_F_T`` ->
{G} to {W} (Eq 6 form) -> ``tau_T = J^T F`` (Eq 7); return-to-centre (Eq 8) + damping (Eq 9)
-> ``tau_RD`` scaled to a fraction of capacity (Eq 10-11); + gravity compensation ``tau_G``;
total (Eq 12) -> uniform saturation -> gear ratios -> torque curve -> motor counts.

MuJoCo does the forward kinematics; everything after it (input checks, Jacobian, gravity sum,
switch edges, reference, Eq 2-12 and the pose command) runs in one compiled call,
:func:`app.controller.kernel.controller_tick`, on the controller's preallocated record. This
class keeps what needs Python: configuration, the fault messages and the safe output.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from app.compiled import entry_point
from app.controller import kernel
from app.controller.calibration import TorqueCurve
from app.controller.gains import ControllerGains
from app.controller.inputs import SHAPE_3, SHAPE_6, SHAPE_33, checked_arrays, checked_float
from app.controller.kinematics import DeviceKinematics, RecordArray, topology_fields
from app.controller.layout import GAIN_ROWS, RTC_LAWS, TORQUE_ROWS, vector_row_names
from app.controller.passivity import SWING_SHARE, PassivitySettings, bank_bounds, device_dissipation
from app.controller.record import (
    ASSIST_SCALE,
    PC_CUT,
    PO_ENERGY,
    RAMP,
    ROT_WEIGHT,
    SATURATION_SCALE,
    record_dtype,
)
from app.controller.safety import SafetyLimits
from app.controller.types import Fault, FTReading, SlaveCommand, SlaveModel, Switches
from app.device.spec import DeviceSpec
from app.spatial import Array, IntArray, wrench_transform

_ND = np.ndarray
_F8 = np.dtype(np.float64)


class ControllerOutput:
    """Everything one tick produced, for the slave, the motors, the display and the logs.

    The controller reuses one instance and overwrites it every tick: copy what you keep.
    Wrenches are ``[f; m]`` (N, N m); torques are joint-side (N m, or N for slides) unless named
    ``motor``. Six-vectors are rows of ``vectors`` (9, 6), torques rows of ``torques`` (8, n) and
    the scale factors slots of ``scalars`` (6,); the named attributes are views of those rows,
    named and ordered by :mod:`app.controller.layout`. All arrays are views into the controller's
    record (:func:`app.controller.record.record_dtype`), which the compiled tick writes.

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
        tau_PC: The passivity controller's correction ``(s - 1) tau_r`` (zero unless it acts).
        tau: Total ``tau_T + tau_RDs + tau_G + tau_PC`` (Eq 12, plus the PC).
        tau_sat: ``tau`` after uniform saturation to the joint limits.
        tau_motor: Motor-side torques ``tau_sat / gear_ratio`` (N m).
        counts: Motor commands (counts), int64, shape (n,).
        assist_scale: Factor applied to ``tau_RD`` (Eq 11), in (0, 1].
        saturation_scale: Factor applied to ``tau`` by the final saturation, in (0, 1].
        ramp: Safety ramp level in [0, 1] on ``tau_T`` and ``tau_RDs`` (0 right after a fault).
        rot_weight: 1 normally; tapers to 0 near the Z-Y-X singularity |beta| -> 90 deg.
        po_energy: Energy the passivity observer saw the controller absorb, summed over the
            joints (J); negative means the rendering gave energy out.
        pc_cut: Share of the rendered torque the passivity controller removed this tick (0..1).
        reflecting: Task wrench and assists were rendered this tick (deadman and reflection on).
        faults: Why the safe output was used this tick (``Fault.NONE`` if it was not).
        fault_message: Human-readable reason, empty when there is no fault.
        slave_status: The slave's limit bits from the F/T reading this tick used
            (:attr:`FTReading.slave_status`: joint limit, singularity, out of reach...).
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
    tau_PC: Array
    tau: Array
    tau_sat: Array
    tau_motor: Array

    def __init__(self, rec: RecordArray) -> None:
        """Views of the outputs in ``rec``, a one-element array of :func:`record_dtype`."""
        self.T_0_G: Array = rec["T_0_G"][0]
        self.T_0_G0: Array = rec["T_0_G0"][0]
        self.vectors: Array = rec["vectors"][0]
        self.scalars: Array = rec["scalars"][0]
        self.torques: Array = rec["torques"][0]
        self.n = self.torques.shape[1]
        for i, name in enumerate(vector_row_names()):
            setattr(self, name, self.vectors[i])
        for i, name in enumerate(TORQUE_ROWS):
            setattr(self, name, self.torques[i])
        self.counts: IntArray = rec["counts"][0]
        self.command = SlaveCommand(twist=rec["twist"][0], T_w_MRF=rec["T_w_MRF"][0])
        self.reflecting = False
        self.faults = Fault.NONE
        self.fault_message = ""
        self.slave_status = 0

    @property
    def assist_scale(self) -> float:
        return float(self.scalars[ASSIST_SCALE])

    @property
    def saturation_scale(self) -> float:
        return float(self.scalars[SATURATION_SCALE])

    @property
    def rot_weight(self) -> float:
        return float(self.scalars[ROT_WEIGHT])

    @property
    def ramp(self) -> float:
        """Safety ramp level in [0, 1] applied to the task and assist torques (:mod:`app.controller.safety`)."""
        return float(self.scalars[RAMP])

    @property
    def po_energy(self) -> float:
        """Passivity observer's energy summed over the joints (J) (:mod:`app.controller.passivity`)."""
        return float(self.scalars[PO_ENERGY])

    @property
    def pc_cut(self) -> float:
        """Share of the rendered torque the passivity controller removed this tick (0..1)."""
        return float(self.scalars[PC_CUT])


def fill_record(rec: RecordArray, slave: SlaveModel, safety: SafetyLimits) -> None:
    """The record's poses, scale factors, safety limits and slave model (either kind of device)."""
    for name in ("T_0_G", "T_0_G0", "T_w_MRF", "T_w_MRF0"):
        rec[name] = np.eye(4)
    rec["scalars"] = 1.0
    rec["min_period"] = safety.min_period
    rec["ramp_rate"] = safety.ramp_rate
    rec["gravity_level"] = 1.0
    rec["max_joint_speed"] = safety.max_joint_speed
    rec["release_speed"] = safety.release_fraction * safety.max_joint_speed
    rec["payload_mass"] = slave.payload_mass
    rec["payload_com_S"] = slave.payload_com_S
    rec["payload_inertia_S"] = slave.payload_inertia_S
    rec["gravity_w"] = slave.gravity_w
    T_MRF_S = np.asarray(slave.T_MRF_S, dtype=float)
    rec["X_MRF_S"] = wrench_transform(T_MRF_S[0:3, 0:3], T_MRF_S[0:3, 3])


class FRHCController:
    """Cartesian controller of one force-reflecting hand controller (paper Sec 3-4).

    Args:
        device: The device (its nominal MJCF model, motors and torque curves).
        gains: Gains and options; see :class:`ControllerGains`.
        slave: What the controller knows of the slave tool: {MRF}-{S} transform, payload, gravity.
        curve: Torque-to-counts curve; by default the one the device file selects.
        safety: Ramps, velocity brake and accepted periods (:class:`SafetyLimits`).
        passivity: The passivity controller (:class:`PassivitySettings`); off by default.

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
        safety: SafetyLimits | None = None,
        passivity: PassivitySettings | None = None,
    ) -> None:
        self.device = device
        self.safety = safety = safety if safety is not None else SafetyLimits()
        self.kin = kin = DeviceKinematics(device)
        self.slave = slave
        self.curve = curve if curve is not None else TorqueCurve.for_device(device)
        motors = device.data.motors
        self._rec = rec = np.zeros(
            1, dtype=record_dtype(device.n_joints, kin.model.nbody, self.curve.horner_pos.shape[1])
        )
        for name, *_ in topology_fields(device.n_joints, kin.model.nbody):
            rec[name] = getattr(kin, name)
        fill_record(rec, slave, safety)
        self._brake_damping = safety.brake_damping
        rec["encoder_count"] = device.encoder_step
        self._shape_q: tuple[int, ...] = (device.n_joints,)
        rec["gear_ratio"] = motors.gear_ratio
        rec["joint_limit"] = rec["gear_ratio"] * np.array(motors.torque_limit)
        rec["horner_pos"] = self.curve.horner_pos
        rec["horner_neg"] = self.curve.horner_neg
        rec["counts_max"] = self.curve.counts_max
        self.gear_ratio: Array = rec["gear_ratio"][0]
        self.joint_limit: Array = rec["joint_limit"][0]
        self.out = ControllerOutput(rec)
        self._motors = kernel.record_motors(rec)
        # {G} is rigidly attached to {W}: its offset is fixed by the device geometry.
        kin.update(np.array(device.data.home))
        R_0_W = kin.R_0_W
        rec["R_W_G"] = R_0_W.T @ kin.R_0_G
        rec["p_W_G"] = R_0_W.T @ (kin.p_0_G - kin.p_0_W)
        self._friction, self._damping, self._b_device = device_dissipation(device)
        # The compiled tick's arguments that stay the same objects for this controller's life.
        self._fixed_args: tuple[object, ...] = (*kin.fk_arrays, rec)
        # Eq 1 before the compiled tick, and what the device's coordinates are called in errors.
        self._fk: Callable[[Array], None] = kin.update
        self._q_name = "q"
        self._nonfinite_q = "non-finite joint angles"
        # ``step`` checks the reading and the angles (type, dtype, shape, layout) and passes its
        # own arrays for the rest, so the compiled tick is called without numba's typing.
        example = (np.zeros(device.n_joints), np.zeros(6), np.eye(3), np.zeros(6), np.zeros(3), 1e-3)
        self._tick = entry_point(kernel.controller_tick, *example, True, True, True, True, *self._fixed_args)
        self.set_gains(gains)
        self.set_passivity(passivity if passivity is not None else PassivitySettings())
        self.reset(np.array(device.data.home))

    # -- configuration -------------------------------------------------------------------------

    def set_gains(self, gains: ControllerGains) -> None:
        """Switch gains (and mode) between ticks. Changing the mode re-references (no jump)."""
        previous: ControllerGains | None = getattr(self, "gains", None)
        self.gains = gains
        rec = self._rec
        rec["gains"] = [getattr(gains, name) for name in GAIN_ROWS]
        rec["rate_mode"] = gains.mode == "rate"
        rec["rtc_kind"] = RTC_LAWS.index(gains.rtc)
        rec["taper"] = np.radians(gains.euler_taper_deg)
        rec["gravity_compensation"] = gains.gravity_compensation
        rec["remove_payload"] = gains.remove_payload
        rec["remove_inertia"] = gains.remove_inertia
        rec["max_period"] = gains.max_period
        rec["assist_limit"] = gains.assist_fraction * self.joint_limit
        self.out.command.mode = gains.mode
        if previous is not None and previous.mode != gains.mode:
            kernel.set_reference(rec)

    def set_passivity(self, settings: PassivitySettings) -> None:
        """Switch the passivity controller on or off, or change its settings, between ticks.

        The observer keeps its energy: it runs whether the controller acts or not.
        """
        self.passivity = settings
        rec = self._rec
        rec["pc_on"] = settings.enabled
        rec["pc_limit"] = limit = settings.max_torque_fraction * self.joint_limit
        rec["pc_step"] = step = np.maximum(settings.step, settings.step_counts * self.device.encoder_step)
        rec["pc_reserve"], rec["po_cap"] = bank_bounds(settings, limit, step)
        rec["pc_credit"] = settings.friction_credit * self._friction
        rec["pc_law_count"] = self.device.encoder_step if settings.passive_law else 0.0
        rec["pc_law_step"] = settings.law_onset == "step"
        rec["pc_law_zero"] = -math.inf  # the law is entered anew where the bound next cuts
        observed = settings.observe_device
        rec["po_friction"] = settings.friction_credit * self._friction if observed else 0.0
        rec["po_damping"] = self._damping if observed else 0.0
        rec["po_swing"] = SWING_SHARE if settings.swing_charge else 0.0
        rec["pc_filter"] = settings.velocity_filter
        rec["pc_hold"] = settings.enabled and settings.hold_slave
        rec["pc_b_device"] = self._b_device
        rec["pc_bleed"] = settings.hold_bleed
        if not rec["pc_hold"][0]:
            rec["pc_offset"] = 0.0

    def reset(self, q: Array, T_w_MRF_home: Array | None = None) -> None:
        """Start over at joint angles ``q``: reference {G0} = FK(q), slave reference = home."""
        self.out.command.T_w_MRF[:] = self.slave.T_w_MRF_home if T_w_MRF_home is None else T_w_MRF_home
        self.kin.update(np.asarray(q, dtype=float))
        self.out.T_0_G[0:3, 0:3] = self.kin.R_0_G
        self.out.T_0_G[0:3, 3] = self.kin.p_0_G
        kernel.set_reference(self._rec)
        for flag in ("prev_reference", "prev_deadman", "prev_reflecting", "have_q_prev", "braking"):
            self._rec[flag] = False
        self.out.scalars[RAMP] = 0.0
        for name in ("po_energy", "po_tau", "po_run", "pc_velocity", "pc_offset", "pc_dx_prev", "brake_velocity"):
            self._rec[name] = 0.0
        self._rec["pc_law_zero"] = -math.inf
        self.out.scalars[PO_ENERGY] = self.out.scalars[PC_CUT] = 0.0

    def resume(self) -> None:
        """After a gap in the servo ticks (an overrun): no velocity across the gap, and the wrench
        ramps in again."""
        self._rec["have_q_prev"] = False
        self.out.scalars[RAMP] = 0.0

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
        w, R, acc, omega = ft.wrench_S, ft.R_w_S, ft.acc_w, ft.omega_w
        # Types and shapes at the boundary, the cheap way (identity tests): anything else would
        # make numba compile a new kernel, or read past the end of an array.
        if not (
            type(q) is _ND
            and type(w) is _ND
            and type(R) is _ND
            and type(acc) is _ND
            and type(omega) is _ND
            and q.dtype is _F8
            and w.dtype is _F8
            and R.dtype is _F8
            and acc.dtype is _F8
            and omega.dtype is _F8
            and q.shape == self._shape_q
            and w.shape == SHAPE_6
            and R.shape == SHAPE_33
            and acc.shape == SHAPE_6
            and omega.shape == SHAPE_3
            and q.flags.c_contiguous
            and w.flags.c_contiguous
            and R.flags.c_contiguous
            and acc.flags.c_contiguous
            and omega.flags.c_contiguous
        ):
            q, w, R, acc, omega = checked_arrays(
                (q, w, R, acc, omega),
                (self._shape_q, SHAPE_6, SHAPE_33, SHAPE_6, SHAPE_3),
                (self._q_name, "ft.wrench_S", "ft.R_w_S", "ft.acc_w", "ft.omega_w"),
            )
        if type(dt) is not float:
            dt = checked_float(dt, "dt")
        self.out.slave_status = ft.slave_status
        # FK runs even on unusable angles (MuJoCo just computes NaN poses): the kernel checks q
        # before it reads them, for a fraction of what a numpy check here would cost.
        self._fk(q)
        code = self._tick(
            q,
            w,
            R,
            acc,
            omega,
            dt,
            bool(ft.valid),
            bool(switches.deadman),
            bool(switches.reference),
            bool(switches.reflection),
            *self._fixed_args,
        )
        if code:
            return self._fault(code)
        o = self.out
        o.command.active = switches.deadman
        o.reflecting = switches.deadman and switches.reflection
        o.faults = Fault.NONE
        o.fault_message = ""
        return o

    def _fault(self, code: int) -> ControllerOutput:
        """The safe output for a non-zero :func:`kernel.controller_tick` result."""
        if code == kernel.JOINTS_NONFINITE:
            return self._safe_output(Fault.NONFINITE_INPUT, self._nonfinite_q, gravity=False)
        faults = Fault(code)
        if faults == Fault.NONFINITE_OUTPUT:
            return self._safe_output(faults, "non-finite torque (singular pose?)", gravity=True)
        return self._safe_output(faults, _fault_text(faults), gravity=True)

    def _safe_output(self, faults: Fault, message: str, gravity: bool) -> ControllerOutput:
        """Fallback: gravity compensation only (zero without usable q), slave stopped, fault named."""
        o = self.out
        o.faults = faults
        o.fault_message = message
        o.reflecting = False
        o.command.active = False
        o.command.twist[:] = 0.0
        o.vectors[:] = 0.0
        self._rec["restart_damping"] = True
        tau_G = o.tau_G.copy() if gravity and math.isfinite(float(o.tau_G.sum())) else np.zeros(o.n)
        o.torques[:] = 0.0
        o.tau_G[:] = tau_G
        o.tau[:] = tau_G
        if faults & Fault.OVERSPEED:
            # The brake never asks a joint for more than its torque limit: an encoder glitch of a
            # turn in one tick must not become an infinite torque, nor scale every joint's down.
            brake = self._brake_damping * self._rec["qdot"][0]
            o.tau[:] -= np.clip(brake, -self.joint_limit, self.joint_limit)
        o.scalars[ASSIST_SCALE] = 1.0
        o.scalars[RAMP] = 0.0  # the wrench ramps in again once the fault clears
        o.scalars[PC_CUT] = 0.0
        # The brake's damping is not credited to the observer (the conservative side).
        self._rec["po_tau"] = 0.0
        o.scalars[SATURATION_SCALE] = kernel.motor_commands(o.torques, self._motors, o.counts)
        return o


def _fault_text(faults: Fault) -> str:
    parts = []
    if faults & Fault.OVERSPEED:
        parts.append("a joint moved faster than the velocity brake allows: damping only until it slows")
    if faults & Fault.BAD_PERIOD:
        parts.append("servo period not in [min_period, max_period] (an overrun, or a bad clock)")
    if faults & Fault.FT_INVALID:
        parts.append("F/T reading marked invalid by the world (failed contact query)")
    if faults & Fault.NONFINITE_INPUT:
        parts.append("non-finite F/T reading (wrench, orientation, or the motion inertia removal uses)")
    return "; ".join(parts)
