"""Safety at the device boundary, as the vendors do it: force limit, ramp, watchdog.

Every wrench the servo loop sends to a Cartesian device passes :meth:`ForceGuard.apply`:

- **force limit**: the force is scaled (direction kept) to at most the device's ``force_limit``
  (N), the moment to ``torque_limit`` (N m); a 3-dof-force device gets no moment at all;
- **ramp**: after a connect, and after any gap in the device's stream, the wrench is scaled by a
  level rising linearly from 0 to 1 over ``ramp_time`` (s; ``gap_ramp_time`` after a gap in
  the stream of a device that stayed connected), so contact the operator drifted into while the
  link was down does not kick;
- **watchdog**: in a period in which no new sample arrived, the wrench sent is zero, and the next
  sample starts a new ramp. The command of that same period is the zero: the force goes to zero
  within one servo period of the stream stopping.
"""

from __future__ import annotations

import math

import numpy as np

from app.device.boundary import CartesianReading, LinkStatus
from app.device.spec import CartesianSpec
from app.spatial import Array


class ForceGuard:
    """The boundary's guard for one Cartesian device.

    Args:
        spec: The device's limits and ramp time.
        torque_capable: The device renders moments; otherwise moments are never sent.

    Attributes:
        level: The ramp level in [0, 1].
        sent: The wrench last sent (N, N m, {0}), (6,).
    """

    def __init__(self, spec: CartesianSpec, torque_capable: bool) -> None:
        self.spec = spec
        self.torque_limit = spec.torque_limit if torque_capable else 0.0
        self.level = 0.0
        self.sent = np.zeros(6)
        self.watchdog_trips = 0
        self._ramp_time = spec.ramp_time

    def reset(self) -> None:
        """A new connection: zero force, the ramp starts again."""
        self.level = 0.0
        self.sent[:] = 0.0
        self.watchdog_trips = 0
        self._ramp_time = self.spec.ramp_time

    def gap(self) -> None:
        """The loop skipped periods: the force ramps in again from zero."""
        self.level = 0.0
        self._ramp_time = self.spec.gap_ramp_time

    def apply(self, wrench_0: Array, reading: CartesianReading, dt: float) -> Array:
        """The wrench to send this period for the controller's ``wrench_0`` (6,), given the
        device's last sample; also sets the sample's ``status``, ``motors_off`` and
        ``watchdog_trips``. Returns :attr:`sent` (reused)."""
        out = self.sent
        if reading.status == LinkStatus.DISCONNECTED or not reading.fresh:
            if reading.status == LinkStatus.DISCONNECTED:
                self._ramp_time = self.spec.ramp_time
            else:
                reading.status = LinkStatus.STALLED
                if self.level >= 1.0:  # a stall during the connect ramp keeps that ramp
                    self._ramp_time = self.spec.gap_ramp_time
            if self.level > 0.0 or not reading.motors_off:
                self.watchdog_trips += 1
            self.level = 0.0
            out[:] = 0.0
            reading.motors_off = True
            reading.watchdog_trips = self.watchdog_trips
            return out
        ramp = self._ramp_time
        self.level = 1.0 if ramp <= 0.0 else min(1.0, self.level + dt / ramp)
        reading.status = LinkStatus.OK if self.level >= 1.0 else LinkStatus.RAMPING
        reading.motors_off = False
        reading.watchdog_trips = self.watchdog_trips
        limited(wrench_0[:3], self.spec.force_limit, self.level, out[:3])
        limited(wrench_0[3:], self.torque_limit, self.level, out[3:])
        return out


def limited(v: Array, limit: float, level: float, out: Array) -> Array:
    """``level * v`` with ``|v|`` first scaled (direction kept) to at most ``limit``, into ``out``
    (3,), returned; zero for a non-finite ``v`` (or one longer than the largest float) or a zero
    limit."""
    # hypot, not the root of the sum of squares: that overflows from |v| ~ 1e154 on.
    norm = math.hypot(float(v[0]), float(v[1]), float(v[2]))
    if not math.isfinite(norm) or limit <= 0.0:
        out[:] = 0.0
        return out
    return np.multiply(v, level * (1.0 if norm <= limit else limit / norm), out=out)
