"""The servo loop: hand -> device plant -> controller -> virtual slave and contact -> motors.

One :meth:`ServoLoop.tick` (paper Fig. 3, ``docs/conventions.md`` "one servo tick"):

1. The plant integrates one period under the motor counts of the previous tick and the
   operator's hand spring, and reports quantised encoder angles.
2. The controller turns those angles, the switches and the slave's last F/T reading into a slave
   command and new motor counts (the reading is one tick old, as on hardware where the sensor
   sample arrives with the next cycle).
3. The virtual slave moves toward the command, meets the world through FCL contact, and its
   F/T sensor produces the reading the controller reflects next tick.

The tick returns a :class:`~app.session.tick.TickRecord` and hands it to every observer (the log,
the metrics, the web snapshot, a user's monitor). The same loop object serves headless sessions
(as fast as possible, or paced by :class:`~app.session.pacer.Pacer`) and the web UI's loop process.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from app.controller.frhc import ControllerOutput, FRHCController
from app.controller.gains import ControllerGains
from app.controller.passivity import PassivitySettings
from app.controller.safety import SafetyLimits
from app.controller.types import Switches
from app.device.boundary import Device
from app.device.hand import HandParams, PullArgs
from app.device.plant import WATCHDOG, DevicePlant
from app.device.spec import DeviceSpec, load_device
from app.errors import ConfigError
from app.session.state import StateBlock
from app.session.tick import STAGES, TickObserver, TickRecord
from app.slave.api import make_slave
from app.spatial import Array, IntArray
from app.teleop.channel import ChannelSettings
from app.teleop.link import TeleopLink
from app.world.scene import Scene, load_scene, with_slave

if TYPE_CHECKING:
    from app.session.spec import Session

ObserverT = TypeVar("ObserverT", bound=TickObserver)


@dataclass(frozen=True)
class LoopConfig:
    """What a servo loop is made of.

    Pickles as file paths plus values (scenes hold FCL objects that cannot be pickled), so a
    loop process can rebuild the same loop: the scene and device must then come from files.

    Attributes:
        device: The FRHC (plant and controller model come from the same device file).
        scene: The virtual world.
        gains: Controller gains.
        hand: The operator's hand impedance.
        accommodation: NTRFC accommodation on the slave.
        servo_rate: Ticks per second (Hz).
        safety: The controller's ramps, velocity brake and accepted periods.
        watchdog: The simulated amplifier's servo watchdog (s).
        passivity: The passivity controller on the device port (:mod:`app.controller.passivity`).
        channel: The master-slave channel: delay, jitter, loss, wave variables
            (:mod:`app.teleop`); the default is none.
        device_url: A Cartesian device outside this process (``ws://host:port``, ``fd:N``,
            ``openhaptics:NAME``: :func:`app.device.vendors.open_device_url`) instead of the
            simulated ``device``; ``device`` then gives its limits and gains.
        sample_wait: How long (s) the loop waits for a served device's sample before its
            watchdog zeroes the force; None: one servo period.
    """

    device: DeviceSpec
    scene: Scene
    gains: ControllerGains
    hand: HandParams = field(default_factory=HandParams)
    accommodation: bool = True
    servo_rate: float = 1000.0
    safety: SafetyLimits = field(default_factory=SafetyLimits)
    watchdog: float = WATCHDOG
    passivity: PassivitySettings = field(default_factory=PassivitySettings)
    channel: ChannelSettings = field(default_factory=ChannelSettings)
    device_url: str | None = None
    sample_wait: float | None = None

    @property
    def cartesian(self) -> bool:
        """The loop drives the device through its Cartesian interface (``docs/conventions.md``)."""
        return self.device_url is not None or self.device.data.interface == "cartesian"

    @staticmethod
    def from_session(
        session: Session,
        scene: Scene | None = None,
        device: DeviceSpec | None = None,
        gains: ControllerGains | None = None,
        device_url: str | None = None,
        sample_wait: float | None = None,
    ) -> LoopConfig:
        """The loop a session runs: its scene, device, gains, hand, accommodation, rate, passivity
        controller and channel.

        ``scene``, ``device`` and ``gains`` replace the session's own when given; ``device_url``
        and ``sample_wait`` drive a device outside this process (:attr:`device_url`).
        """
        d = session.data
        return LoopConfig(
            device or session.device,
            scene or session.scene,
            gains or session.gains,
            d.hand,
            d.accommodation,
            d.servo_rate,
            passivity=d.passivity,
            channel=d.channel,
            device_url=device_url,
            sample_wait=sample_wait,
        )

    def __reduce__(self) -> tuple[Any, ...]:
        if self.scene.path is None:
            raise ConfigError("<scene>", "path", "a loop run in another process needs a scene loaded from a file")
        values = (
            self.gains,
            self.hand,
            self.accommodation,
            self.servo_rate,
            self.safety,
            self.watchdog,
            self.passivity,
            self.channel,
            self.device_url,
            self.sample_wait,
        )
        return (_rebuild_config, (self.scene.path, self.scene.spec.slave.kind, self.device.path, *values))


@dataclass(frozen=True)
class GripEvent:
    """What one :meth:`ServoLoop.set_grip` did.

    Attributes:
        t: Simulated time (s) of the loop when it acted (between ticks).
        on: Closing (True) or opening (False).
        held: Name of the dynamic object the grip then holds, or None.
        note: Why, in words: ``"holds peg"``, ``"opened"``, ``"nothing touched"``, ``"no dynamic
            objects in the scene"``.
    """

    t: float
    on: bool
    held: str | None
    note: str

    def as_dict(self) -> dict[str, Any]:
        """JSON-able, for the session summary."""
        return {"t": self.t, "grip": self.on, "held": self.held, "note": self.note}


def _rebuild_config(scene: Path, slave: str, device: Path, *values: Any) -> LoopConfig:
    return LoopConfig(load_device(device), with_slave(load_scene(scene), slave), *values)


class ServoLoop:
    """Plant, controller and slave joined into one servo tick.

    Attributes:
        device: The hand controller behind the device boundary (:mod:`app.device.boundary`): here
            the simulated plant; a :class:`~app.session.cartesian_loop.CartesianServoLoop`'s is
            a Cartesian device.
        plant, controller, slave: The three rooms (the slave is the ideal tool or an arm, as the
            scene's ``[slave] kind`` says: :func:`~app.slave.api.make_slave`).
        switches: The switch state the next tick uses (set by a script or the UI). The
            reference switch is momentary: the loop releases it after the tick that used it.
        record: The :class:`TickRecord` of the last tick (or of the reset state).
        objects: Names of the scene's dynamic objects (``scene.bodies`` order), whose poses the
            tick's state row and the log hold.
        observers: Called with :attr:`record` after every tick, in order.
        time: Simulated time (s).
        ticks: Ticks run since the last reset.
        grips: What each :meth:`set_grip` since the last reset did, in order.
        link: The master-slave channel (:mod:`app.teleop`), or None when controller and slave
            are joined directly (no delay: the default).
    """

    def __new__(cls, config: LoopConfig) -> ServoLoop:
        """The loop for the device's kind: a :class:`CartesianServoLoop` for a Cartesian device."""
        if cls is ServoLoop and config.cartesian:
            from app.session.cartesian_loop import CartesianServoLoop

            return super().__new__(CartesianServoLoop)
        return super().__new__(cls)

    def __init__(self, config: LoopConfig) -> None:
        self.config = config
        self.dt = 1.0 / config.servo_rate
        self.slave = make_slave(config.scene, accommodation=config.accommodation, period=self.dt)
        self._open_device()
        self.channel = config.channel
        self.link: TeleopLink | None = None
        self.switches = Switches()
        self.observers: list[TickObserver] = []
        self._hand = np.eye(4)
        self.grips: list[GripEvent] = []
        self.record = TickRecord(
            self.reading, self.controller.out, self.slave, self._hand, np.zeros(len(STAGES), dtype=np.int64)
        )
        # The record's stage durations written through a memoryview: ~half the cost of numpy's
        # item assignment, four times a tick.
        self._stage_ns = self.record.stage_ns.data
        self.objects = tuple(b.name for b in self.slave.scene.bodies)
        self.record.block = StateBlock(self.controller.out.n, self.objects)
        self.reset()

    def _open_device(self) -> None:
        """The joint-space device (the simulated plant) and its controller."""
        config = self.config
        self.plant = DevicePlant(config.device, config.hand, config.watchdog)
        self.device: Device = self.plant
        self.reading = self.plant.reading
        self.controller = FRHCController(
            config.device, config.gains, self.slave.slave_model(), safety=config.safety, passivity=config.passivity
        )

    @property
    def stage_ns(self) -> IntArray:
        """Durations (ns) of the last tick's stages, in the order of :data:`STAGES`."""
        return self.record.stage_ns

    def observe(self, observer: ObserverT) -> ObserverT:
        """Add ``observer`` (called after every tick); returns it."""
        self.observers.append(observer)
        return observer

    def unobserve(self, observer: TickObserver) -> None:
        """Stop calling ``observer``."""
        self.observers.remove(observer)

    def reset(self) -> None:
        """Everything back to the start: device at home, slave at home, switches off.

        The hand keeps its target; the observers stay attached.
        """
        home = np.array(self.config.device.data.home)
        self.reading = self.plant.reset(home)
        self.slave.reset()
        self.controller.reset(self.reading.q)
        # The counts the plant is sent next tick: none yet (zero); after a tick, the controller's
        # output buffer itself, which only its step writes (no copy a tick).
        self.counts = np.zeros(self.config.device.n_joints, dtype=np.int64)
        self._restart()

    def _restart(self) -> None:
        """The reset of everything but the device and the controller."""
        # The sensor already reads the payload's weight at rest: start from that, not from zero,
        # or the first tick's payload removal would reflect a false +m g.
        self.ft = self.slave.reading()
        self.switches.deadman = self.switches.reference = self.switches.reflection = False
        self.time = 0.0
        self.ticks = 0
        self.grips.clear()
        self._connect()
        rec = self.record
        rec.index, rec.time, rec.ft, rec.contact = 0, 0.0, self.ft, self.slave.contact
        rec.serial += 1
        rec.slave_status = 0
        rec.deadman = rec.reference = rec.reflection = False
        rec.stage_ns[:] = 0

    def close(self) -> None:
        """Release the device: nothing to release for a plant simulated in this process."""

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the operator's hand pulls the grip (4, 4, device base); None lets go.

        Not thread-safe: call it between ticks, from the thread that runs :meth:`tick`.
        """
        self.record.hand_on = T_0_H is not None
        if T_0_H is not None:
            self._hand[:] = T_0_H
        self.plant.set_hand_target(T_0_H)

    def hand_pull(self) -> tuple[Array, PullArgs] | None:
        """For an operator that moves the held hand from its own compiled code every tick: the
        loop's hand target (4, 4; what the record reports) and the simulated hand's
        :meth:`~app.device.hand.OperatorHand.pull_args`. A finite target passed with them to
        :func:`~app.device.hand.copy_and_pull` (the first as its ``copy``) is :meth:`set_hand_target`
        without its checks; valid while the hand holds the grip (None otherwise: take hold with
        :meth:`set_hand_target`).
        """
        args = self.plant.hand.pull_args()
        return None if args is None or not self.record.hand_on else (self._hand, args)

    def set_grip(self, on: bool) -> GripEvent:
        """Close the slave tool's grip on the dynamic object it touches now, or open it (``on``
        False), between ticks: :meth:`~app.world.dynamics.MovingWorld.grip`. A scene without
        dynamic objects, or a tool touching none, holds nothing; either way the event is kept in
        :attr:`grips` and returned.

        The grip acts on the slave at once, not through :attr:`link`: a delayed channel delays
        the command and the reading, not this switch.
        """
        b = self.slave.grip(on)
        bodies = self.slave.scene.bodies
        held = bodies[b].name if b >= 0 else None
        if held is not None:
            note = f"holds {held}"
        elif not on:
            note = "opened"
        elif not bodies:
            note = "no dynamic objects in the scene"
        else:
            note = "nothing touched"
        event = GripEvent(self.time, on, held, note)
        self.grips.append(event)
        return event

    def press_reference(self) -> None:
        """Press the momentary reference switch: on for the next tick only (Sec 4.1)."""
        self.switches.reference = True

    def set_gains(self, gains: ControllerGains) -> None:
        self.controller.set_gains(gains)

    def set_passivity(self, settings: PassivitySettings) -> None:
        """Switch the passivity controller (or change its settings) between ticks; the observer's
        energy carries on."""
        self.controller.set_passivity(settings)

    def set_channel(self, settings: ChannelSettings) -> None:
        """Put a new master-slave channel between controller and slave, between ticks.

        Messages in flight on the old channel are lost; the slave holds the controller's last
        command and the controller the slave's last reading until the new channel delivers.
        """
        self.channel = settings
        self._connect()

    def _connect(self) -> None:
        """The link for :attr:`channel` (None when it is no channel), starting from the present state."""
        if not self.channel.active:
            self.link = None
            return
        self.link = TeleopLink(
            self.channel,
            self.config.servo_rate,
            self.controller.slave,
            self.controller.out.command,
            self.ft,
            self.config.scene.spec.slave.kp_lin,
        )

    def stall(self, seconds: float) -> None:
        """The controller misses ``seconds`` of servo periods (an overrun): the device runs on under
        the amplifier's last counts until its watchdog switches the motors off.

        The slave holds (it gets no command), the switches and the observers see nothing; the next
        :meth:`tick` resumes, and the controller's ramp brings the wrench back in.
        """
        for _ in range(max(1, round(seconds / self.dt))):
            self.reading = self.plant.step(None, self.dt)
            self.time += self.dt
        self.controller.resume()

    def tick(self) -> TickRecord:
        """Run one servo period; returns its record (reused object) after the observers saw it."""
        sw = self.switches
        t0 = time.perf_counter_ns()
        self.reading = self.plant.step(self.counts, self.dt)
        t1 = time.perf_counter_ns()
        out = self.controller.step(self.reading.q, sw, self.ft, self.dt)
        t2 = time.perf_counter_ns()
        self.counts = out.counts
        return self._slave_tick(sw, out, t0, t1, t2)

    def _slave_tick(self, sw: Switches, out: ControllerOutput, t0: int, t1: int, t2: int) -> TickRecord:
        """The rest of a tick once the controller ran (tick from ``t0``, controller from ``t1`` to
        ``t2``, ns): the slave and its sensor, the record, the observers."""
        link = self.link
        if link is None:
            ft = self.ft = self.slave.step(out.command, self.dt)
        else:
            ft = self.slave.step(link.to_slave(out.command, self.dt), self.dt)
            self.ft = link.to_master(ft)
        t3 = time.perf_counter_ns()
        self.time += self.dt
        self.ticks += 1
        rec = self.record
        ns = self._stage_ns
        ns[0] = t1 - t0
        ns[1] = t2 - t1
        ns[2] = t3 - t2
        ns[3] = t3 - t0
        rec.index = self.ticks
        rec.serial += 1
        rec.time = self.time
        rec.ft = ft
        rec.contact = self.slave.contact
        rec.slave_status = self.slave.status
        rec.deadman, rec.reference, rec.reflection = sw.deadman, sw.reference, sw.reflection
        self.switches.reference = False
        for observer in self.observers:
            observer.on_tick(rec)
        return rec
