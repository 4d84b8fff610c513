"""What one servo tick produced, as one read-only value, and the observers that consume it.

:meth:`~app.session.loop.ServoLoop.tick` returns a :class:`TickRecord`. Its attributes are views of
the rooms' own buffers (plant reading, controller output, slave reading and contact result), so
building it allocates nothing; the next tick overwrites them. An observer that keeps data copies
it. The log, the session metrics and the web snapshot are observers of this record, and so is any
monitor a user adds (:meth:`~app.session.loop.ServoLoop.observe`); none of them reaches into the
rooms.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from app.controller.frhc import ControllerOutput
from app.controller.types import FTReading, SlaveCommand
from app.device.boundary import CartesianReading, LinkStatus
from app.device.plant import PlantReading
from app.slave.api import Slave
from app.spatial import Array, IntArray
from app.world.contact import ContactResult

if TYPE_CHECKING:
    from app.session.state import StateBlock

STAGES = ("plant", "controller", "slave", "tick")
"""Stages of one tick timed in :attr:`TickRecord.stage_ns`, in order (``tick`` is their sum)."""


class TickRecord:
    """Everything one servo tick produced (paper Fig. 3), valid until the next tick.

    Treat it as read-only: the arrays are the rooms' own buffers.

    Attributes:
        index: Ticks run since the last reset (0 for the state right after a reset).
        time: Simulated time at the end of the tick (s).
        reading: The device's reading: the grip pose ``T_0_G`` (4, 4, base {0}), the device
            coordinates ``q`` (encoder angles (n,) of a joint-space device, the pose's six
            coordinates of a Cartesian one) and the simulated hand's wrench ``wrench_G``
            (:class:`~app.device.plant.PlantReading`, :class:`~app.device.boundary.CartesianReading`).
        hand_target: Where the operator's hand pulled the grip, ``T_0_H`` (4, 4, {0}), or None
            while the hand is off the grip.
        deadman, reference, reflection: The switches as this tick used them (a reference press
            is True for exactly one tick).
        out: The controller's output with all its intermediates (Delta X, task wrench at each
            frame, assists, every torque stage, counts, faults).
        command: The slave command of this tick (``out.command``).
        ft: The F/T reading the slave produced this tick (the controller reflects it next tick).
        contact: The tool's contact with the world at the end of the tick.
        slave_status: Why the slave did not follow the command exactly this tick: bits of
            :class:`~app.slave.arm.ArmStatus` (joint limit, singularity, ...); 0 for the ideal tool.
        stage_ns: Durations (ns) of the stages in :data:`STAGES`, (4,) int64.
        serial: Counts every tick and reset of the loop (never repeats): what the state block
            compares to fill its row once a tick.
        block: The loop's state block (:mod:`app.session.state`), set by the loop: :meth:`state`.
        pose_view: The slave's :meth:`~app.slave.api.Slave.pose_view`, bound once: the pose buffer
            :attr:`T_w_MRF` returns, refreshed when stale, without the property's call (read every
            tick by the state row and the operators).
        hand_buffer: The loop's buffer of the hand target (4, 4): :attr:`hand_target` while
            :attr:`hand_on`, else the last target held (for compiled readers that take it once).
    """

    __slots__ = (
        "_slave",
        "block",
        "command",
        "contact",
        "deadman",
        "ft",
        "hand_buffer",
        "hand_on",
        "index",
        "out",
        "pose_view",
        "reading",
        "reference",
        "reflection",
        "serial",
        "slave_status",
        "stage_ns",
        "time",
    )

    def __init__(
        self,
        reading: PlantReading | CartesianReading,
        out: ControllerOutput,
        slave: Slave,
        hand: Array,
        stage_ns: IntArray,
    ) -> None:
        self.index = 0
        self.time = 0.0
        self.reading = reading
        self.out = out
        self.command: SlaveCommand = out.command
        self._slave = slave
        self.pose_view = slave.pose_view
        self.hand_buffer = hand
        self.hand_on = False
        self.deadman = self.reference = self.reflection = False
        self.ft: FTReading = slave.reading()
        self.contact: ContactResult = slave.contact
        self.slave_status = 0
        self.stage_ns = stage_ns
        self.serial = 0
        self.block: StateBlock | None = None

    def state(self) -> Array:
        """Every value of this tick as one row (:class:`~app.session.state.StateBlock`; the log's
        columns first), filled on the first call of the tick. Read-only; valid until the next tick."""
        assert self.block is not None, "the loop sets the record's state block"
        return self.block.fill(self)

    @property
    def hand_target(self) -> Array | None:
        """``T_0_H`` (4, 4) the hand pulled toward this tick, or None when it let go."""
        return self.hand_buffer if self.hand_on else None

    def slave_geom_poses(self) -> tuple[Array, Array]:
        """The slave's geoms in {w}: positions (ngeom, 3), orientations (ngeom, 9) (views; see
        :meth:`~app.slave.api.Slave.geom_poses`)."""
        return self._slave.geom_poses()

    def object_poses(self) -> Array:
        """The dynamic objects' poses in {w}, rows ``[x, y, z, qw, qx, qy, qz]`` in
        ``scene.bodies`` order, (n, 7) (a view; see :meth:`~app.slave.api.Slave.object_poses`)."""
        return self._slave.object_poses()

    @property
    def device_link(self) -> LinkStatus:
        """The link to the device as of this tick's sample: a Cartesian device's, as the boundary's
        guard set it (it decides the wrench sent next tick); OK for a joint-space plant, which is
        simulated in this process."""
        return self.reading.status

    @property
    def T_w_MRF(self) -> Array:
        """Pose of the tool's {MRF} in the slave world {w} at the end of the tick, (4, 4)."""
        return self.pose_view()

    @property
    def link_force(self) -> float:
        """The world's force on the slave's links at the end of the tick (N): it loads the arm,
        not the F/T sensor (:attr:`~app.slave.api.Slave.link_force`; 0 for the ideal tool)."""
        return self._slave.link_force

    @property
    def contact_wrench_MRF(self) -> Array:
        """Contact wrench at the {MRF} origin in {MRF} (N, N m), (6,): what Eq 13 integrates."""
        return self.contact.wrench_MRF

    @property
    def stage_us(self) -> Array:
        """:attr:`stage_ns` in microseconds (a new array)."""
        return self.stage_ns / 1000.0


class TickObserver(Protocol):
    """Anything that watches the ticks of a loop (:meth:`~app.session.loop.ServoLoop.observe`)."""

    def on_tick(self, tick: TickRecord) -> None:
        """Called after every tick with its record; copy what you keep."""
