"""The controller's safety envelope beyond the paper: force ramps, the velocity brake, sane periods.

Real haptic SDKs do not switch a wrench on at full strength, brake a device that runs away and
refuse a servo period that makes no sense; this controller does the same, in its compiled tick:

- **Ramp**: the task and assist torques (``tau_T``, ``tau_RDs``) are scaled by a level that
  restarts from 0 whenever rendering starts (the deadman engages with reflection on, or
  reflection is switched on under the deadman) and after any fault tick, and rises linearly to 1
  over ``ramp_time``. Gravity compensation stays on through every other fault, so it is not
  ramped, except after non-finite joint angles: it was off (no pose to compute it at), and it
  comes back over ``ramp_time`` the same way.
- **Velocity brake**: joint speeds are estimated from encoder differences, averaged over about
  ``BRAKE_WINDOW`` (a low-pass of gain ``a = min(1, dt / BRAKE_WINDOW)``), and the brake judges the
  slowest speed the encoders allow: the average less its quantization bound ``a c_j / dt`` (``c_j``
  one count of joint ``j``; an encoder reading lies within half a count of the angle, so the
  filtered difference errs by at most ``a c_j / dt``, summing by parts). A single count is then not
  a speed: one 8192-count count in a 50 us tick reads 15.3 rad/s, and braked a still Kraft wrist at
  20 kHz. Above ``max_joint_speed`` on any joint the controller enters a damping-only state (fault
  ``OVERSPEED``): gravity compensation plus ``-brake_damping * qdot`` per joint, clipped to the
  joint's torque limit (a glitched encoder's jump must not become an infinite torque, nor scale
  the other joints' torques down), the slave stopped, until every joint is below
  ``release_fraction`` of the limit; then the ramp restarts.
- **Periods**: a period outside ``[min_period, max_period]`` is a ``BAD_PERIOD`` fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from numba import njit

from app.controller.kinematics import RecordArray
from app.errors import InvalidField
from app.spatial import Array

#: The time the velocity brake averages joint speeds over (s): the 1 kHz period its limits were
#: set at. At 1 kHz and slower it judges each tick's encoder difference alone, as before; faster,
#: a runaway at twice the limit still brakes within 1 ms (``tests/controller/test_safety.py``).
BRAKE_WINDOW = 1e-3


@dataclass(frozen=True)
class SafetyLimits:
    """Safety settings of one controller.

    Attributes:
        ramp_time: Seconds for the task and assist torques to ramp from 0 to full after rendering
            starts or a fault clears (0 = no ramp).
        max_joint_speed: Joint speed (rad/s; m/s for slides) above which the brake engages.
        release_fraction: The brake releases once every joint is below this fraction of
            ``max_joint_speed`` (-), in (0, 1).
        brake_damping: Joint damping while braking (N m s/rad; N s/m for slides), joint side.
        min_period: Shortest accepted servo period (s); ``ControllerGains.max_period`` is the longest.
    """

    ramp_time: float = 0.2
    max_joint_speed: float = 8.0
    release_fraction: float = 0.5
    brake_damping: float = 0.2
    min_period: float = 1e-5

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise InvalidField(f.name, "must be a finite number")
        if not 0.0 <= self.ramp_time <= 10.0:
            raise InvalidField("ramp_time", "must be between 0 and 10 s")
        if not 0.0 < self.max_joint_speed <= 1e3:
            raise InvalidField("max_joint_speed", "must be in (0, 1000] rad/s")
        if not 0.0 < self.release_fraction < 1.0:
            raise InvalidField("release_fraction", "must be in (0, 1)")
        if not 0.0 <= self.brake_damping <= 1e3:
            raise InvalidField("brake_damping", "must be between 0 and 1000 N m s/rad")
        if not 1e-7 <= self.min_period <= 1e-3:
            raise InvalidField("min_period", "must be between 1e-7 and 1e-3 s")

    @staticmethod
    def paper_only() -> SafetyLimits:
        """No ramp and a brake only at 1000 rad/s: the paper's controller as printed (for tests
        that check its equations tick by tick, with angles that jump between ticks)."""
        return SafetyLimits(ramp_time=0.0, max_joint_speed=1e3)

    @property
    def ramp_rate(self) -> float:
        """Ramp level gained per second (1/s); infinite without a ramp."""
        return math.inf if self.ramp_time == 0.0 else 1.0 / self.ramp_time


@njit(cache=True)
def velocity_brake(q: Array, dt: float, rec: RecordArray) -> bool:
    """Joint velocities from encoder differences and the brake's state (:mod:`app.controller.safety`).

    ``dt`` is the period (s), or 0 when it is unusable (no velocity this tick). Writes ``qdot``
    (this tick's differences), ``brake_velocity`` (their average over ``BRAKE_WINDOW``) and
    ``q_prev``; returns whether the brake holds.
    """
    r = rec[0]
    q_prev, qdot, average, count = r.q_prev[:], r.qdot[:], r.brake_velocity[:], r.encoder_count[:]
    moved = r.have_q_prev and dt > 0.0
    a = min(1.0, dt / BRAKE_WINDOW) if moved else 0.0
    fastest = 0.0
    for j in range(q.shape[0]):
        qdot[j] = (q[j] - q_prev[j]) / dt if moved else 0.0
        q_prev[j] = q[j]
        v = average[j] + a * (qdot[j] - average[j]) if r.have_q_prev else 0.0
        if math.isfinite(v):
            # The slowest speed the encoders allow: the average less its quantization bound.
            surely = abs(v) - a * count[j] / dt if moved else abs(v)
        else:
            surely, v = math.inf, 0.0  # an absurd reading brakes, and the average starts over
        average[j] = v
        fastest = max(fastest, surely)
    r.have_q_prev = True
    if r.braking:
        r.braking = fastest >= r.release_speed
    else:
        r.braking = fastest > r.max_joint_speed
    return r.braking
