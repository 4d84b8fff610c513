"""The device boundary: what the servo loop asks of a hand controller, for both kinds of device.

A **joint-space** device (:class:`JointDevice`: today's MuJoCo plants) reports encoder angles and
takes motor counts; the controller does the kinematics (Eq 1) and J^T (Eq 7) with the device's
own model. A **Cartesian** device (:class:`CartesianDevice`: a vendor SDK, the Haply Inverse
Service, or a simulated one) reports its grip pose {G} in its base {0} and takes a wrench at the
grip in {0}; its SDK does Eq 1, Eq 7 and its own gravity compensation (Eq 11's tau_G). The
controller's Eq 2-12 run unchanged on both (``docs/conventions.md``, "Devices").

Every wrench a Cartesian device receives has passed the boundary's guard
(:class:`~app.device.guard.ForceGuard`): force limit, ramp after a connect or a gap, zero within
one period when the device's stream stops.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Literal, NamedTuple, Protocol

import numpy as np

from app.spatial import Array, IntArray, matrix_to_zyx


class LinkStatus(IntEnum):
    """The state of the link to a Cartesian device, as the page and the log show it.

    OK: samples arrive every period and the force is at full scale. RAMPING: samples arrive, the
    force limit is ramping up after a connect or a gap. STALLED: no new sample this period (the
    watchdog): zero force sent. DISCONNECTED: no connection: nothing sent (the device's own
    watchdog holds it at zero).
    """

    OK = 0
    RAMPING = 1
    STALLED = 2
    DISCONNECTED = 3


#: :attr:`GripSources.how`: the hand's wrench on the grip is zero (released), the force ``w_H``
#: in the axes of ``T_H`` (a simulated hand holding the grip), or ``w_H`` as it is (a reading's
#: own ``wrench_G``).
HAND_OFF, HAND_ROTATED, HAND_AS_IS = 0, 1, 2


class GripSources(NamedTuple):
    """The buffers a reading's grip pose and hand wrench are made of, for compiled code that
    builds them itself (the tick's state row) instead of through the reading's properties:
    ``T_0_G`` is ``[[R, p], [0, 0, 0, 1]]`` and ``wrench_G`` (N, N m, {0}) is as :attr:`how`
    says. The reading keeps them current and never replaces them.

    Attributes:
        R: Grip rotation in {0}, (3, 3). p: Grip position in {0} (m), (3,).
        T_H: The hand's target pose in {0}, (4, 4). w_H: The hand's wrench (N, N m), (6,).
        how: ``[HAND_OFF | HAND_ROTATED | HAND_AS_IS]``, int64 (1,).
    """

    R: Array
    p: Array
    T_H: Array
    w_H: Array
    how: IntArray


class CartesianReading:
    """One sample of a Cartesian device (the same object every period, overwritten).

    Attributes:
        T_0_G: Grip pose in the device base {0} (4, 4; m).
        q: The pose as six coordinates ``[x, y, z, gamma, beta, alpha]`` (m, rad; Z-Y-X angles of
            ``T_0_G``): the device's coordinates in the log's ``q_*`` columns.
        twist_0_G: Grip twist ``[v; w]`` in {0} (m/s, rad/s), (6,); NaN where the device gives none.
        buttons: The grip's buttons ``(deadman, reference, reflection)`` as the backend maps them,
            or None for a device without buttons (the switches then come from the page or script).
        wrench_G: The simulated operator's hand on the grip (N, N m, {0}); zero for real devices.
        geom_xpos, geom_xmat: The simulated device's geoms for display ((k, 3), (k, 9)); empty
            (k = 0) when the device is not simulated here.
        fresh: A new sample arrived this period (False trips the watchdog).
        status: :class:`LinkStatus` as of this sample (set by the guard).
        watchdog_trips: Periods since the reset in which the watchdog zeroed the force.
        motors_off: The force is zero because of the watchdog or a lost connection.
        time: The device's time of the sample (s).
    """

    __slots__ = (
        "T_0_G",
        "buttons",
        "fresh",
        "geom_xmat",
        "geom_xpos",
        "motors_off",
        "q",
        "status",
        "time",
        "twist_0_G",
        "watchdog_trips",
        "wrench_G",
    )

    def __init__(self) -> None:
        self.T_0_G = np.eye(4)
        self.q = np.zeros(6)
        self.twist_0_G = np.full(6, np.nan)
        self.buttons: tuple[bool, bool, bool] | None = None
        self.wrench_G = np.zeros(6)
        self.geom_xpos = np.zeros((0, 3))
        self.geom_xmat = np.zeros((0, 9))
        self.fresh = False
        self.status = LinkStatus.DISCONNECTED
        self.watchdog_trips = 0
        self.motors_off = True
        self.time = 0.0

    def grip_sources(self) -> GripSources:
        """:attr:`T_0_G` and :attr:`wrench_G` as :class:`GripSources` (views of them)."""
        return GripSources(self.T_0_G[:3, :3], self.T_0_G[:3, 3], _EYE4, self.wrench_G, _AS_IS)

    def set_pose(self, R_0_G: Array, p_0_G: Array) -> None:
        """Store a new grip pose (rotation (3, 3), position (3,) m, in {0}) and its coordinates."""
        T = self.T_0_G
        T[:3, :3] = R_0_G
        T[:3, 3] = p_0_G
        self.q[:3] = p_0_G
        self.q[3:] = matrix_to_zyx(T[:3, :3])


_EYE4 = np.eye(4)
_AS_IS = np.array([HAND_AS_IS], dtype=np.int64)


class JointDevice(Protocol):
    """A joint-space device: encoder angles in, motor counts out (:class:`~app.device.plant.DevicePlant`)."""

    kind: Literal["joint"]

    def reset(self, q: Array | None = None) -> object:
        """At rest at joint angles ``q`` (rad; default home); returns the reading."""

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the simulated operator's hand pulls the grip (4, 4, {0}); None lets go."""

    def step(self, counts: IntArray | None, dt: float) -> object:
        """One servo period under ``counts`` (None: none arrived); returns the reading."""


class CartesianDevice(Protocol):
    """A Cartesian device: grip pose in, grip wrench out; its SDK does Eq 1, Eq 7 and gravity.

    Attributes:
        kind: ``"cartesian"``.
        name: What to call it in the page and the log.
        torque_capable: The device renders moments (6-dof force); False for 3-dof-force devices,
            which are sent forces only.
        reading: The last sample (the object :meth:`step` returns).
    """

    kind: Literal["cartesian"]
    name: str
    torque_capable: bool
    reading: CartesianReading

    def reset(self) -> CartesianReading:
        """Start over (a simulated device returns home); zero force; returns the first sample."""

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where a simulated operator's hand pulls the grip (4, 4, {0}); None lets go. A real
        device has a real hand on it and ignores this."""

    def step(self, wrench_0: Array, dt: float) -> CartesianReading:
        """Send ``wrench_0`` (``[f; m]`` at the grip in {0}, N and N m, already guarded) for this
        period and return the next sample (``fresh`` False if none arrived within the period)."""

    def close(self) -> None:
        """Zero the force and release the device or connection."""


#: A device behind the boundary, of either kind (``ServoLoop.device``).
Device = JointDevice | CartesianDevice
