"""The controller of a Cartesian device: the paper's Eq 2-12 on a grip pose the device reports.

A Cartesian device's SDK (Force Dimension's dhd, OpenHaptics' HD, Haply's Inverse Service, or
:class:`~app.device.cartesian_sim.SimCartesianDevice`) reports the grip pose {G} in its base {0}
and takes a wrench at the grip in {0}: it does Eq 1 (forward kinematics), Eq 7 (J^T) and its own
gravity compensation (the tau_G of Eq 11-12). :class:`CartesianController` runs everything
between, unchanged: Delta X (Eq 2-4), the rate or pose command (Eq 5, Sec 3.5), the task wrench
(Eq 6), return-to-centre and damping (Eq 8-10), the assists' share of capacity (Eq 11), the safety
ramp and the uniform saturation (Sec 3.4), in the compiled :func:`app.controller.kernel.cartesian_device_tick`.

Its output's ``torques`` rows have six columns, the wrench axes ``[fx, fy, fz, mx, my, mz]``
(N, N m) at the grip in {0}; :attr:`ControllerOutput.tau_sat` is the wrench for the device.
"""

from __future__ import annotations

import numpy as np

from app.compiled import entry_point
from app.controller import kernel
from app.controller.frhc import ControllerOutput, FRHCController, fill_record
from app.controller.gains import ControllerGains
from app.controller.passivity import PassivitySettings
from app.controller.record import RAMP, record_dtype
from app.controller.safety import SafetyLimits
from app.controller.types import SlaveModel
from app.device.spec import CartesianSpec, DeviceSpec
from app.spatial import Array

#: The wrench axes: the controller's "joints" on a Cartesian device.
AXES = 6
_SHAPE_44 = (4, 4)
#: Saturation limit (N m) of the moment axes of a 3-dof-force device, whose moment rows of J are
#: zero: any positive value (their wrench is always 0), kept to avoid dividing by zero.
_NO_MOMENT_LIMIT = 1.0


def _pose_from_device(T_0_G: Array) -> None:
    """Eq 1 on a Cartesian device: the device's SDK did it."""


class CartesianController(FRHCController):
    """The Cartesian FRHC controller for a device whose SDK does Eq 1, Eq 7 and gravity.

    Args:
        device: The device (for its ``[cartesian]`` limits and default gains).
        gains: Gains and options (:class:`ControllerGains`; ``gravity_compensation`` is the
            device's own and ignored here).
        slave: What the controller knows of the slave tool.
        torque_capable: The device renders moments; False for a 3-dof-force device (the moment
            rows of J are then zero, so no moment is computed for it, nor counted in Eq 11).
        safety: Ramps and accepted periods (the velocity brake is the device's own).
        passivity: Must be off: the passivity controller acts on joint ports.
    """

    def __init__(
        self,
        device: DeviceSpec,
        gains: ControllerGains,
        slave: SlaveModel,
        torque_capable: bool,
        safety: SafetyLimits | None = None,
        passivity: PassivitySettings | None = None,
    ) -> None:
        spec = device.data.cartesian
        if spec is None:
            raise ValueError(f"device {device.name} has no [cartesian] table")
        self.device = device
        self.cartesian: CartesianSpec = spec
        self.safety = safety = safety if safety is not None else SafetyLimits()
        self.slave = slave
        self._rec = rec = np.zeros(1, dtype=record_dtype(AXES, 1, 1))
        fill_record(rec, slave, safety)
        self._brake_damping = 0.0
        moment = spec.torque_limit if torque_capable and spec.torque_limit > 0 else _NO_MOMENT_LIMIT
        rec["gear_ratio"] = 1.0
        rec["joint_limit"] = [spec.force_limit] * 3 + [moment] * 3
        rec["counts_max"] = 1
        rec["J_W"] = np.diag([1.0, 1.0, 1.0] + [1.0 if torque_capable else 0.0] * 3)
        rec["R_W_G"] = np.eye(3)
        self.gear_ratio: Array = rec["gear_ratio"][0]
        self.joint_limit: Array = rec["joint_limit"][0]
        self.out = ControllerOutput(rec)
        self._motors = kernel.record_motors(rec)
        example = (np.eye(4), np.zeros(6), np.eye(3), np.zeros(6), np.zeros(3), 1e-3)
        self._tick = entry_point(kernel.cartesian_device_tick, *example, True, True, True, True, rec)
        # ``step`` is the joint-space controller's: its "q" is the grip pose, and Eq 1 is the SDK's.
        self._fixed_args = (rec,)
        self._shape_q = (4, 4)
        self._fk = _pose_from_device
        self._q_name = "T_0_G"
        self._nonfinite_q = "non-finite grip pose from the device"
        self.set_gains(gains)
        self.set_passivity(passivity if passivity is not None else PassivitySettings())
        self.reset(np.eye(4))

    def set_passivity(self, settings: PassivitySettings) -> None:
        """Only "off": the passivity controller observes and damps joint ports, which a Cartesian
        device keeps to itself."""
        if settings.enabled:
            raise ValueError("the passivity controller is not available on a Cartesian device")
        self.passivity = settings
        self._rec["pc_on"] = False

    def reset(self, T_0_G: Array, T_w_MRF_home: Array | None = None) -> None:
        """Start over at grip pose ``T_0_G`` (4, 4, {0}): reference {G0} := it, slave at home."""
        self.out.command.T_w_MRF[:] = self.slave.T_w_MRF_home if T_w_MRF_home is None else T_w_MRF_home
        self.out.T_0_G[:] = T_0_G
        kernel.set_reference(self._rec)
        for flag in ("prev_reference", "prev_deadman", "prev_reflecting"):
            self._rec[flag] = False
        self.out.scalars[RAMP] = 0.0

    def resume(self) -> None:
        """After a gap in the servo ticks: the wrench ramps in again."""
        self.out.scalars[RAMP] = 0.0
