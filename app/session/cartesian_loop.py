"""The servo loop of a Cartesian device: grip pose in, guarded grip wrench out.

``ServoLoop(config)`` returns a :class:`CartesianServoLoop` when the device is driven through its
Cartesian interface (``interface = "cartesian"`` in its file, or a ``device_url``). One tick:

1. The device renders the wrench the guard let through last tick for one period and reports its
   grip pose (its SDK did Eq 1, Eq 7 and its gravity compensation).
2. The controller runs Eq 2-12 on that pose (:class:`~app.controller.cartesian.CartesianController`),
   and the guard (:class:`~app.device.guard.ForceGuard`) turns its wrench into the one sent next
   tick: force limit, ramp, and zero if this tick's sample did not arrive.
3. The slave moves and its F/T sensor reads, as in the joint-space loop.

The device's buttons, when it has them, act with the page's or the script's switches: button 0
holds the deadman, a press of button 1 is a reference press, a press of button 2 toggles
reflection (``docs/conventions.md``, "Devices").
"""

from __future__ import annotations

import logging
import time

from app.controller.cartesian import CartesianController
from app.controller.types import Switches
from app.device.boundary import CartesianDevice, CartesianReading, LinkStatus
from app.device.cartesian_sim import SimCartesianDevice
from app.device.guard import ForceGuard
from app.device.vendors import open_device_url
from app.session.loop import ServoLoop
from app.session.tick import TickRecord
from app.spatial import Array

log = logging.getLogger(__name__)


class CartesianServoLoop(ServoLoop):
    """:class:`~app.session.loop.ServoLoop` for a Cartesian device (same attributes and methods).

    Attributes:
        device: The Cartesian device (simulated here, or a client of a served one).
        guard: The boundary's force limit, ramp and watchdog.
        plant: The simulated plant when the device is simulated in this process (the page draws
            it), else None.
        wrench: The wrench sent to the device in the tick that comes next (N, N m at {G} in {0}).
    """

    device: CartesianDevice
    reading: CartesianReading  # type: ignore[assignment]
    controller: CartesianController

    def _open_device(self) -> None:
        config = self.config
        spec = config.device.data.cartesian
        if spec is None:
            raise ValueError(f"device {config.device.name} has no [cartesian] table")
        if config.device_url is not None:
            wait = config.sample_wait if config.sample_wait is not None else self.dt
            self.device = open_device_url(config.device_url, wait)
            self.plant = None  # type: ignore[assignment]
        else:
            sim = SimCartesianDevice(config.device, config.hand, config.watchdog)
            self.device = sim
            self.plant = sim.plant
        self.reading = self.device.reading
        self.guard = ForceGuard(spec, self.device.torque_capable)
        self.wrench = self.guard.sent
        self.controller = CartesianController(
            config.device,
            config.gains,
            self.slave.slave_model(),
            self.device.torque_capable,
            safety=config.safety,
            passivity=config.passivity,
        )
        self._buttons = Switches()
        self._prev_buttons = (False, False, False)
        self._status = LinkStatus.DISCONNECTED

    def reset(self) -> None:
        """Everything back to the start: the device reset (home, when simulated), zero force and a
        new ramp, slave at home, switches off."""
        self.reading = self.device.reset()
        self.guard.reset()
        self.slave.reset()
        self.controller.reset(self.reading.T_0_G.copy())
        self._restart()

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the (simulated) operator's hand pulls the grip (4, 4, {0}); None lets go."""
        self.record.hand_on = T_0_H is not None
        if T_0_H is not None:
            self._hand[:] = T_0_H
        self.device.set_hand_target(T_0_H)

    def hand_pull(self) -> None:
        """None: the hand of a Cartesian device is moved through :meth:`set_hand_target` only."""
        return None

    def stall(self, seconds: float) -> None:
        """The loop misses ``seconds`` of periods: the device gets no command meanwhile (its own
        watchdog acts), and the force ramps in again from zero."""
        self.guard.gap()
        self.controller.resume()

    def close(self) -> None:
        """Zero the force and release the device."""
        self.device.close()

    def _switches(self) -> Switches:
        """The switches this tick: the page's or script's, with the device's buttons."""
        sw = self.switches
        buttons = self.reading.buttons
        if buttons is None:
            return sw
        b = self._buttons
        prev = self._prev_buttons
        b.deadman = sw.deadman or buttons[0]
        b.reference = sw.reference or (buttons[1] and not prev[1])
        if buttons[2] and not prev[2]:
            sw.reflection = not sw.reflection
        b.reflection = sw.reflection
        self._prev_buttons = buttons
        return b

    def tick(self) -> TickRecord:
        """Run one servo period; returns its record (reused object) after the observers saw it."""
        t0 = time.perf_counter_ns()
        reading = self.reading = self.device.step(self.wrench, self.dt)
        t1 = time.perf_counter_ns()
        sw = self._switches()
        out = self.controller.step(reading.T_0_G, sw, self.ft, self.dt)
        t2 = time.perf_counter_ns()
        self.guard.apply(out.tau_sat, reading, self.dt)
        if reading.status != self._status:
            log.info("device %s: link %s at t = %.3f s", self.device.name, reading.status.name, self.time + self.dt)
            self._status = reading.status
        return self._slave_tick(sw, out, t0, t1, t2)
