"""Data that crosses room boundaries in one servo tick (paper Fig. 3).

Flow: device plant -> ``q`` (encoder angles) + :class:`Switches` -> controller;
virtual slave -> :class:`FTReading` -> controller; controller -> :class:`SlaveCommand`
-> virtual slave, and motor counts -> device plant. The slave side is described to the
controller by :class:`SlaveModel` (what a real controller would know about its robot's tool).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntFlag

import numpy as np

from app.spatial import Array


@dataclass(slots=True)
class Switches:
    """The FRHC's three switches (paper Sec 4.1).

    Attributes:
        deadman: Held by the operator: commands flow to the slave and wrenches come back.
        reference: Momentary button; its rising edge sets the reference pose {G0}
            (and in pose mode indexes: FRHC and slave are re-referenced together).
        reflection: Latched toggle enabling task-wrench reflection, return-to-centre and damping.
    """

    deadman: bool = False
    reference: bool = False
    reflection: bool = False


@dataclass(slots=True)
class FTReading:
    """What the slave's force/torque sensor at {S} reports, plus the slave state it needs.

    Attributes:
        wrench_S: ``[f; m]`` (N, N m), shape (6,), at the origin of {S} in {S} coordinates:
            the external wrench acting on everything outboard of the sensor (contact wrench
            + payload weight - payload inertial load), as a real sensor measures it.
        R_w_S: Orientation of {S} in the slave world {w}, shape (3, 3); gives gravity in {S}.
        acc_w: Linear acceleration (m/s^2) of the {S} origin and angular acceleration (rad/s^2)
            of the tool, in {w}, shape (6,). Only used when inertial removal is on
            (:attr:`~app.controller.gains.ControllerGains.remove_inertia`: what a real slave supplies).
        omega_w: Angular velocity (rad/s) of the tool in {w}, shape (3,).
        valid: False when the world could not produce a trustworthy reading (failed or
            non-finite contact query); the controller then reflects nothing and flags a fault.
        slave_status: Why the slave did not follow its command exactly when it took the reading
            (:class:`~app.slave.arm.ArmStatus` bits; 0 = it did, always for the ideal tool): the
            slave reports it with the reading, and the controller's output carries it on.
    """

    wrench_S: Array = field(default_factory=lambda: np.zeros(6))
    R_w_S: Array = field(default_factory=lambda: np.eye(3))
    acc_w: Array = field(default_factory=lambda: np.zeros(6))
    omega_w: Array = field(default_factory=lambda: np.zeros(3))
    valid: bool = True
    slave_status: int = 0

    def copy(self) -> FTReading:
        """A reading with its own arrays (a slave's step returns one it overwrites next tick)."""
        r = self
        return FTReading(r.wrench_S.copy(), r.R_w_S.copy(), r.acc_w.copy(), r.omega_w.copy(), r.valid, r.slave_status)


@dataclass(frozen=True)
class SlaveModel:
    """What the controller knows about the slave's tool (from the scene's tool definition).

    Attributes:
        T_MRF_S: Pose of the sensor frame {S} in the moving reference frame {MRF}, (4, 4).
        payload_mass: Mass outboard of the sensor, end effector plus payload (kg).
        payload_com_S: Centre of that mass in {S} (m), shape (3,).
        payload_inertia_S: Its rotational inertia about the centre of mass, in {S} axes
            (kg m^2), shape (3, 3).
        gravity_w: Gravity in the slave world (m/s^2), shape (3,).
        T_w_MRF_home: The slave's starting pose of {MRF} in {w}, (4, 4).
    """

    T_MRF_S: Array
    payload_mass: float
    payload_com_S: Array
    payload_inertia_S: Array
    gravity_w: Array
    T_w_MRF_home: Array


@dataclass(slots=True)
class SlaveCommand:
    """The controller's command to the virtual slave for one tick.

    Attributes:
        active: True while the deadman is held and no fault is active. When False a rate
            slave stops and a pose slave holds its last command.
        mode: ``"rate"`` or ``"pose"``.
        twist: Rate mode: ``[v; w]`` with v (m/s) in {w} coordinates (the FRHC base axes are
            aligned with the slave world axes) and w (rad/s) in {MRF} body coordinates, as Eq 5
            gives it. Shape (6,). Zero in pose mode.
        T_w_MRF: Pose mode: commanded pose of {MRF} in {w}, (4, 4). In rate mode it is the
            last pose-mode command (unused).
    """

    active: bool = False
    mode: str = "rate"
    twist: Array = field(default_factory=lambda: np.zeros(6))
    T_w_MRF: Array = field(default_factory=lambda: np.eye(4))


class Fault(IntFlag):
    """Why the controller fell back to its safe output in a tick (combinable)."""

    NONE = 0
    NONFINITE_INPUT = 1  # q, the F/T reading or dt had NaN or inf
    BAD_PERIOD = 2  # dt outside [min_period, max_period] (an overrun, or a bad clock)
    FT_INVALID = 4  # the world said its reading is not trustworthy
    NONFINITE_OUTPUT = 8  # a torque came out non-finite (e.g. a singular pose)
    OVERSPEED = 16  # a joint moved faster than the velocity brake allows: damping only until it slows
