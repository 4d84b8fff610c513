"""The servo loop: hand -> device plant -> controller -> virtual slave and contact -> motors.

One :meth:`ServoLoop.tick` (paper Fig. 3, DESIGN.md "one servo tick"):

1. The plant integrates one period under the motor counts of the previous tick and the
   operator's hand spring, and reports quantised encoder angles.
2. The controller turns those angles, the switches and the slave's last F/T reading into a slave
   command and new motor counts (the reading is one tick old, as on hardware where the sensor
   sample arrives with the next cycle).
3. The virtual slave moves toward the command, meets the world through FCL contact, and its
   F/T sensor produces the reading the controller reflects next tick.

The same loop object serves headless sessions (as fast as possible) and the web UI (paced).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from app.controller.frhc import ControllerOutput, FRHCController
from app.controller.gains import ControllerGains
from app.controller.types import Switches
from app.device.hand import HandParams
from app.device.plant import DevicePlant, PlantReading
from app.device.spec import DeviceSpec
from app.spatial import Array
from app.world.scene import Scene
from app.world.slave import VirtualSlave

STAGES = ("plant", "controller", "slave", "tick")


@dataclass(frozen=True)
class LoopConfig:
    """What a servo loop is made of.

    Attributes:
        device: The FRHC (plant and controller model come from the same device file).
        scene: The virtual world.
        gains: Controller gains.
        hand: The operator's hand impedance.
        accommodation: NTRFC accommodation on the slave.
        servo_rate: Ticks per second (Hz).
    """

    device: DeviceSpec
    scene: Scene
    gains: ControllerGains
    hand: HandParams
    accommodation: bool = True
    servo_rate: float = 1000.0


class ServoLoop:
    """Plant, controller and slave joined into one servo tick.

    Attributes:
        plant, controller, slave: The three rooms.
        switches: The switch state the next tick uses (set by a script or the UI).
        stage_ns: Durations (ns) of the last tick's stages, in the order of :data:`STAGES`.
        time: Simulated time (s).
        ticks: Ticks run since the last reset.
    """

    def __init__(self, config: LoopConfig) -> None:
        self.config = config
        self.dt = 1.0 / config.servo_rate
        self.plant = DevicePlant(config.device, config.hand)
        self.slave = VirtualSlave(config.scene, accommodation=config.accommodation, period=self.dt)
        self.controller = FRHCController(config.device, config.gains, self.slave.slave_model())
        self.switches = Switches()
        self.stage_ns = np.zeros(len(STAGES), dtype=np.int64)
        self.reset()

    def reset(self) -> None:
        """Everything back to the start: device at home, slave at home, switches off."""
        home = np.array(self.config.device.data.home)
        self.reading: PlantReading = self.plant.reset(home)
        self.slave.reset()
        self.controller.reset(self.reading.q)
        # The sensor already reads the payload's weight at rest: start from that, not from zero,
        # or the first tick's payload removal would reflect a false +m g.
        self.ft = self.slave.reading()
        self.counts = np.zeros(self.config.device.n_joints, dtype=np.int64)
        self.switches.deadman = self.switches.reference = self.switches.reflection = False
        self.time = 0.0
        self.ticks = 0

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the operator's hand pulls the grip (4, 4, device base); None lets go.

        Not thread-safe: call it between ticks, from the thread that runs :meth:`tick`.
        """
        self.plant.set_hand_target(T_0_H)

    def set_gains(self, gains: ControllerGains) -> None:
        self.controller.set_gains(gains)

    def tick(self) -> ControllerOutput:
        """Run one servo period; returns the controller's output (reused object)."""
        t0 = time.perf_counter_ns()
        self.reading = self.plant.step(self.counts, self.dt)
        t1 = time.perf_counter_ns()
        out = self.controller.step(self.reading.q, self.switches, self.ft, self.dt)
        t2 = time.perf_counter_ns()
        self.ft = self.slave.step(out.command, self.dt)
        t3 = time.perf_counter_ns()
        self.counts[:] = out.counts
        self.time += self.dt
        self.ticks += 1
        ns = self.stage_ns
        ns[0] = t1 - t0
        ns[1] = t2 - t1
        ns[2] = t3 - t2
        ns[3] = t3 - t0
        return out
