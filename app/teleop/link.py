"""The teleoperation link in the servo tick: commands through one delay line, F/T readings back through another.

:class:`~app.session.loop.ServoLoop` calls :meth:`TeleopLink.to_slave` with the controller's
command right after the controller's tick and hands the result to the slave, then
:meth:`TeleopLink.to_master` with the slave's reading: what it returns is what the controller
reflects next tick. Messages are packed into float rows of the two
:class:`~app.teleop.channel.DelayLine` objects:

- forward: ``[active, pose, twist (6), T_w_MRF (16), u (3)]``;
- backward: ``[wrench_S (6), R_w_S (9), acc_w (6), omega_w (3), valid, v (3), slave_status]``.

With ``coupling = "wave"`` and a pose command, the translational force crosses the channel as
wave variables (:mod:`app.teleop.wave`), per axis of the slave world {w}:

- Master end (in :meth:`TeleopLink.to_slave`): its velocity ``xdot_m`` (m/s) is that of the
  commanded slave position (``K_P`` and the deadband already applied), low-passed over
  ``wave_filter_ms`` against encoder steps; it smooths the arriving ``v``, sends ``u`` forward
  and the controller renders ``-F_m`` (N) as the contact force of the next reading (the weight
  added back, as the controller removes it). The grip therefore moves at ``xdot_m / K_P`` and
  feels ``K_T F_m``: the grip's power is ``K_T / K_P`` times the channel's, the same positive
  factor both ways, so the operator still cannot draw more energy from the grip than went in.
- Slave end (also in :meth:`TeleopLink.to_slave`, before the slave steps): it smooths the
  arriving ``u``; its force on the environment is minus the last F/T reading's force with the
  payload weight removed (for a tool whose whole mass is outboard of {S} that is the force its
  tracking controller pushes with, inertia included, less what holds the tool's weight up); the
  velocity its decoder gives is integrated into the position of the pose command, whose
  orientation passes as commanded. The wave ``v`` it computes goes back with the reading.

The reading the controller gets carries the master's wave force in place of the delayed contact
force; its moments, and everything in rate mode, are reflected directly (delayed).
"""

from __future__ import annotations

import numpy as np

from app.controller.types import FTReading, SlaveCommand, SlaveModel
from app.filters import lowpass, lowpass_gain
from app.spatial import Array
from app.teleop import wave
from app.teleop.channel import ChannelSettings, DelayLine

# Forward message layout.
_ACTIVE, _POSE, _TWIST, _T, _U, _FWD = 0, 1, slice(2, 8), slice(8, 24), slice(24, 27), 27
# Backward message layout.
_WRENCH, _R, _ACC, _OMEGA, _VALID, _V, _STATUS, _BACK = (
    slice(0, 6),
    slice(6, 15),
    slice(15, 21),
    slice(21, 24),
    24,
    slice(25, 28),
    28,
    29,
)


class TeleopLink:
    """The channel between one controller and one slave, both directions.

    Args:
        settings: Delay, jitter, loss, seed and coupling.
        servo_rate: Ticks per second (Hz): converts the delays to ticks.
        slave: What the master side knows of the slave tool (payload mass, gravity).
        command: The command the slave holds before the first one arrives (e.g. inactive).
        reading: The reading the controller holds before the first one arrives.
        stiffness: The slave's translational tracking stiffness (N/m, the scene's ``kp_lin``):
            the most force a commanded move adds per metre, before the slave measures it.

    Attributes:
        command: The command delivered to the slave this tick (its arrays are reused).
        reading: The reading delivered to the controller this tick (its arrays are reused).
        wave_force: The master's wave force ``F_m`` of this tick (N), (3,), {w} axes; zero
            unless the wave coupling acts.
    """

    def __init__(
        self,
        settings: ChannelSettings,
        servo_rate: float,
        slave: SlaveModel,
        command: SlaveCommand,
        reading: FTReading,
        stiffness: float,
    ) -> None:
        self.settings = settings
        rng = np.random.default_rng(settings.seed)
        delay, jitter = settings.delay_ticks(servo_rate), settings.jitter_ticks(servo_rate)
        self.forward = DelayLine(_FWD, delay, jitter, settings.loss, rng, _pack_command(command, np.zeros(_FWD)))
        self.backward = DelayLine(_BACK, delay, jitter, settings.loss, rng, _pack_reading(reading, np.zeros(_BACK)))
        f, b = self.forward.out, self.backward.out
        self.command = SlaveCommand(twist=f[_TWIST], T_w_MRF=f[_T].reshape(4, 4))
        self.reading = FTReading(b[_WRENCH], b[_R].reshape(3, 3), b[_ACC], b[_OMEGA], True)
        self._wave = settings.coupling == "wave"
        self._b = settings.wave_impedance
        self._stiffness = stiffness
        self._weight_w = slave.payload_mass * np.asarray(slave.gravity_w, dtype=float)
        self._p_prev = np.array(command.T_w_MRF[0:3, 3], dtype=float)
        self._xdot_m = np.zeros(3)
        self._u_m = np.zeros(3)
        self._v_m = np.zeros(3)
        self._u_s = np.zeros(3)
        self._F_port = np.zeros(3)
        self.wave_force = np.zeros(3)
        self._F_s = np.zeros(3)
        self._xdot_s = np.zeros(3)
        self._v_s = np.zeros(3)
        self._p_slave: Array | None = None
        self._master_waves = False

    def to_slave(self, command: SlaveCommand, dt: float) -> SlaveCommand:
        """Send this tick's controller ``command``; returns the command the slave gets this tick."""
        row = _pack_command(command, self.forward.send())
        p = command.T_w_MRF[0:3, 3]
        self._master_waves = waves = self._wave and command.mode == "pose"
        if waves:
            velocity_gain = lowpass_gain(dt, self.settings.wave_filter_ms * 1e-3)
            lowpass((p - self._p_prev) / dt, velocity_gain, self._xdot_m)
            lowpass(self.backward.out[_V], self.settings.wave_smoothing(dt), self._v_m)
            wave.master(self._xdot_m, self._v_m, self._b, self._u_m, self.wave_force)
            row[_U] = self._u_m
        else:
            self.wave_force.fill(0.0)
            row[_U] = 0.0
        self._p_prev[:] = p
        self.forward.receive()
        f = self.forward.out
        cmd = self.command
        cmd.active = bool(f[_ACTIVE])
        cmd.mode = "pose" if f[_POSE] else "rate"
        if self._wave and cmd.mode == "pose":
            self._slave_side(cmd, f[_U], dt)
        return cmd

    def _slave_side(self, cmd: SlaveCommand, u_s: Array, dt: float) -> None:
        """Wave decoder at the slave: integrate the velocity it gives into the position command.

        ``u_s`` is the arriving wave (sqrt(W)), (3,); ``dt`` the tick (s)."""
        lowpass(u_s, self.settings.wave_smoothing(dt), self._u_s)
        if not cmd.active:
            # A held slave does not move: the wave is reflected whole (no power in or out).
            self._v_s[:] = self._u_s
            return
        p = cmd.T_w_MRF[0:3, 3]
        if self._p_slave is None:
            self._p_slave = p.copy()
        wave.slave(self._u_s, self._F_s, self._b, self._stiffness * dt, self._xdot_s, self._F_port, self._v_s)
        self._p_slave += self._xdot_s * dt
        p[:] = self._p_slave

    def to_master(self, reading: FTReading) -> FTReading:
        """Send the slave's ``reading``; returns the reading the controller gets (next tick)."""
        row = _pack_reading(reading, self.backward.send())
        # The slave's force on the environment: minus the contact force, weight removed, in {w}.
        np.matmul(reading.R_w_S, reading.wrench_S[0:3], out=self._F_s)
        self._F_s -= self._weight_w
        self._F_s *= -1.0
        row[_V] = self._v_s
        self.backward.receive()
        out = self.reading
        out.valid = bool(self.backward.out[_VALID])
        out.slave_status = int(self.backward.out[_STATUS])
        if self._master_waves:
            # The operator feels -F_m: written as the contact part of the reading, weight added back.
            f_w = self._weight_w - self.wave_force
            np.matmul(out.R_w_S.T, f_w, out=out.wrench_S[0:3])
        return out


def _pack_command(command: SlaveCommand, row: Array) -> Array:
    row[_ACTIVE] = command.active
    row[_POSE] = command.mode == "pose"
    row[_TWIST] = command.twist
    row[_T] = command.T_w_MRF.ravel()
    return row


def _pack_reading(reading: FTReading, row: Array) -> Array:
    row[_WRENCH] = reading.wrench_S
    row[_R] = reading.R_w_S.ravel()
    row[_ACC] = reading.acc_w
    row[_OMEGA] = reading.omega_w
    row[_VALID] = reading.valid
    row[_STATUS] = reading.slave_status
    return row
