"""A simulated Cartesian device: a MuJoCo plant behind the interface a vendor SDK presents.

:class:`SimCartesianDevice` wraps any device file's :class:`~app.device.plant.DevicePlant` (the
perturbed hardware) with what a vendor's SDK does on the device's own processor: forward
kinematics of its nominal model (Eq 1) reports the grip pose, and a wrench at the grip becomes
joint torques by J^T (Eq 7) plus the device's own gravity compensation (tau_G), motor torques by
the gear ratios and counts by the device file's torque curve. The servo loop then sees only a
grip pose in and a wrench out, as with a Force Dimension, Touch or Haply device.

Frames: {0} is the device MJCF's world, {G} its ``grip_site``, {W} its ``wrist_site``.
"""

from __future__ import annotations

import numpy as np

from app.controller.calibration import TorqueCurve
from app.controller.kinematics import DeviceKinematics
from app.device.boundary import CartesianReading, LinkStatus
from app.device.hand import HandParams
from app.device.plant import WATCHDOG, DevicePlant
from app.device.spec import CartesianSpec, DeviceSpec
from app.errors import ConfigError
from app.spatial import Array, cross3


class SimCartesianDevice:
    """A device file's simulated hardware, driven through a Cartesian SDK.

    Args:
        spec: The device; its ``[cartesian]`` table gives the limits and what it senses.
        hand: The simulated operator's hand on the grip.
        watchdog: The amplifier's watchdog (s) (:class:`DevicePlant`).

    Attributes:
        plant: The simulated hardware.
        reading: The last sample (reused).
    """

    kind = "cartesian"

    def __init__(self, spec: DeviceSpec, hand: HandParams | None = None, watchdog: float = WATCHDOG) -> None:
        cartesian = spec.data.cartesian
        if cartesian is None:
            raise ConfigError(spec.path, "cartesian", "the device has no [cartesian] table to be driven through")
        self.name = spec.name
        self.spec = spec
        self.cartesian: CartesianSpec = cartesian
        self.torque_capable = cartesian.torque_limit > 0.0
        self.plant = DevicePlant(spec, hand, watchdog)
        self._kin = DeviceKinematics(spec)
        self._curve = TorqueCurve.for_device(spec)
        self._gear = np.asarray(spec.data.motors.gear_ratio, dtype=float)
        self._J = np.zeros((6, spec.n_joints))
        self._tau_G = np.zeros(spec.n_joints)
        self._wrench_W = np.zeros(6)
        self.reading = CartesianReading()
        r = self.reading
        r.geom_xpos = self.plant.reading.geom_xpos
        r.geom_xmat = self.plant.reading.geom_xmat
        r.fresh = True
        r.status = LinkStatus.OK
        r.motors_off = False

    def reset(self) -> CartesianReading:
        """The device at rest at home, no force; returns the first sample."""
        self.plant.reset()
        self._sample()
        return self.reading

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the simulated operator's hand pulls the grip (4, 4, {0}); None lets go."""
        self.plant.set_hand_target(T_0_H)

    def step(self, wrench_0: Array, dt: float) -> CartesianReading:
        """Render ``wrench_0`` (``[f; m]`` at {G} in {0}, N and N m) for one period ``dt`` (s) and
        return the next sample.

        The joint torques are ``J_W^T [f; m + (p_G - p_W) x f] + tau_G`` at the encoder angles of
        the last sample (the SDK's own model), as the joint-space controller computes them.
        """
        kin = self._kin
        W = self._wrench_W
        W[:3] = wrench_0[:3]
        W[3:] = wrench_0[3:] + cross3(kin.p_0_G - kin.p_0_W, wrench_0[:3])
        tau = self._J.T @ W + self._tau_G
        self.plant.step(self._curve.counts(tau / self._gear), dt)
        self._sample()
        return self.reading

    def close(self) -> None:
        """Nothing to release: the simulation lives in this process."""

    def _sample(self) -> None:
        """Read the encoders, run the SDK's kinematics at them and fill :attr:`reading`."""
        p = self.plant.reading
        kin = self._kin
        kin.update(p.q)
        kin.jacobian_W(self._J)
        kin.gravity_torque(self._tau_G)
        r = self.reading
        r.set_pose(kin.R_0_G if self.cartesian.orientation else np.eye(3), kin.p_0_G)
        r.wrench_G = p.wrench_G
        r.time = p.time
        r.motors_off = p.motors_off
        r.watchdog_trips = p.watchdog_trips
