"""A simulated Cartesian device: any simulated plant behind a simulated vendor SDK.

:class:`SimCartesianDevice` is what a vendor's SDK makes of a device, done on the simulated plant
(:class:`~app.device.plant.DevicePlant`): it reports the grip pose from the encoders through the
device's nominal model (Eq 1), and renders a wrench at the grip as joint torques ``J^T F`` (Eq 7)
plus its own gravity compensation, sent to the motors through the device's torque curve. It is
the in-process backend of a ``interface = "cartesian"`` device (``devices/touch3``) and what
``frhc device serve`` serves over the Haply Inverse Service protocol (:mod:`app.device.haply`).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from app.controller.calibration import TorqueCurve
from app.controller.kernel import motor_commands
from app.controller.kinematics import DeviceKinematics
from app.controller.layout import TORQUE_ROWS
from app.controller.record import TAU, Motors
from app.device.boundary import CartesianReading, LinkStatus
from app.device.hand import HandParams
from app.device.plant import WATCHDOG, DevicePlant
from app.device.spec import DeviceSpec
from app.spatial import Array


class SimCartesianDevice:
    """A simulated device as its SDK presents it: grip pose in {0} out, grip wrench in {0} in.

    Args:
        spec: The device (plant, nominal model, motors); needs a ``[cartesian]`` table.
        hand: The simulated operator's hand on the grip.
        watchdog: The plant amplifier's watchdog (s).

    Attributes:
        plant: The simulated hardware.
        applied: The wrench the SDK rendered in the last period (N, N m at {G} in {0}), (6,):
            after its own limits (moments dropped on a 3-dof-force device).
    """

    kind: Literal["cartesian"] = "cartesian"

    def __init__(self, spec: DeviceSpec, hand: HandParams | None = None, watchdog: float = WATCHDOG) -> None:
        if spec.data.cartesian is None:
            raise ValueError(f"device {spec.name} has no [cartesian] table")
        self.spec = spec
        self.name = spec.name
        self.torque_capable = spec.data.cartesian.torque_limit > 0.0
        self.plant = DevicePlant(spec, hand, watchdog)
        self.kin = DeviceKinematics(spec)
        curve = TorqueCurve.for_device(spec)
        motors = spec.data.motors
        gear = np.asarray(motors.gear_ratio, dtype=float)
        self._motors = Motors(
            gear * np.asarray(motors.torque_limit), gear, curve.horner_pos, curve.horner_neg, curve.counts_max
        )
        n = spec.n_joints
        self._torques = np.zeros((len(TORQUE_ROWS), n))
        self._counts = np.zeros(n, dtype=np.int64)
        self._J = np.zeros((6, n))
        self._F_W = np.zeros(6)
        self._tau_G = np.zeros(n)
        self.applied = np.zeros(6)
        self.reading = r = CartesianReading()
        r.geom_xpos = self.plant.reading.geom_xpos
        r.geom_xmat = self.plant.reading.geom_xmat
        self.reset()

    def reset(self) -> CartesianReading:
        """The device at rest at home, no force; returns the first sample."""
        self.plant.reset()
        self.applied[:] = 0.0
        self._counts[:] = 0
        self._sample()
        return self.reading

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the simulated operator's hand pulls the grip (4, 4, {0}); None lets go."""
        self.plant.set_hand_target(T_0_H)

    def step(self, wrench_0: Array, dt: float) -> CartesianReading:
        """Render ``wrench_0`` (N, N m at {G} in {0}) for one period ``dt`` (s); the next sample.

        The SDK's torques are taken at the angles of the last sample, as a real SDK's servo does.
        """
        kin = self.kin
        kin.update(self.plant.reading.q)
        F = self.applied
        F[:3] = wrench_0[:3]
        F[3:] = wrench_0[3:] if self.torque_capable else 0.0
        # The wrench moved from {G} to {W}, where the Jacobian is taken: m_W = m_G + (p_G - p_W) x f.
        self._F_W[:3] = F[:3]
        self._F_W[3:] = F[3:] + np.cross(kin.p_0_G - kin.p_0_W, F[:3])
        tau = self._torques[TAU]
        np.dot(kin.jacobian_W(self._J).T, self._F_W, out=tau)
        tau += kin.gravity_torque(self._tau_G)
        motor_commands(self._torques, self._motors, self._counts)
        self.plant.step(self._counts, dt)
        self._sample()
        return self.reading

    def _sample(self) -> None:
        """The reading at the plant's present encoder angles (the SDK's forward kinematics)."""
        p = self.plant.reading
        self.kin.update(p.q)
        r = self.reading
        r.set_pose(self.kin.R_0_G, self.kin.p_0_G)
        r.wrench_G[:] = p.wrench_G
        r.time = p.time
        # A plant that went unstable has stopped (DevicePlant.fault): no new sample, as from a
        # device whose amplifier faulted, so the guard's watchdog zeroes the force.
        r.fresh = self.plant.fault is None
        if r.status == LinkStatus.DISCONNECTED:
            r.status = LinkStatus.RAMPING

    def close(self) -> None:
        """Nothing to release: the simulation ends with the object."""
        self.applied[:] = 0.0
