"""What the browser view shows of one tick, and how it crosses from the loop process to the server.

:class:`SnapshotPublisher` is a tick observer in the loop process: every ``every`` ticks it copies
the display state out of the :class:`~app.session.tick.TickRecord` into a :class:`Snapshot` and
writes it into :class:`SharedSnapshot`, a buffer in shared memory guarded by a sequence counter
(a seqlock): the writer never waits, a reader retries if it raced a write. A slow or absent
browser only ever reads an older snapshot.

The buffer holds the snapshot's arrays as one flat block of float64, copied in place, and its
other fields (numbers, strings, paths) with the arrays' shapes as one small pickled tuple: pickling
the whole snapshot (17 arrays) cost ~45 us warm and 250-350 us in the paced loop process, where the
cache is cold after each sleep; at 4 kHz that is more than a period.
"""

from __future__ import annotations

import ctypes
import math
import multiprocessing as mp
import pickle
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from app.device.boundary import CartesianReading
from app.device.plant import PlantReading
from app.session.tick import TickRecord
from app.spatial import Array

#: Bytes of the shared snapshot buffer's array block; contact points beyond what fits are dropped
#: from display.
SNAPSHOT_BYTES = 1 << 20
#: Bytes for the pickled fields that are not arrays (numbers, strings, paths, the arrays' shapes).
FIELDS_BYTES = 1 << 16
#: Contact points kept when a snapshot does not fit the buffer.
MAX_SHOWN_CONTACTS = 1000


@dataclass(frozen=True)
class Snapshot:
    """A consistent copy of the loop state after one tick, for display. Arrays are owned copies.

    Attributes:
        time: Simulated time (s); equal to the wall time since start while the loop keeps up.
        ticks: Ticks since the last reset.
        geom_xpos: Device geom positions in the device base {0} (m), (ngeom, 3).
        geom_xmat: Device geom orientations in {0}, (ngeom, 3, 3).
        T_0_G: Grip pose in {0}, (4, 4).
        T_0_G0: Reference grip pose in {0}, (4, 4).
        T_0_H: Hand target in {0}, (4, 4), or None when the hand has let go.
        T_w_MRF: Tool {MRF} pose in the slave world {w}, (4, 4).
        T_w_S: F/T sensor {S} pose in {w}, (4, 4).
        contact_points_w: Contact points on object surfaces in {w} (m), (k, 3).
        contact_normals_w: Outward object normals at those points in {w} (unit), (k, 3).
        F_MRF: Task wrench ``[f; m]`` (N, N m) at {MRF} in {MRF} (Eq 6).
        G_F_T: Task wrench to be felt at the grip ``K_T F_MRF`` in {G}.
        G_F_RD: Assist wrench (return-to-centre + damping, Eq 10) in {G}.
        hand_wrench_0: The operator's hand wrench on the grip at {G} in {0} coordinates.
        delta_x: Delta X (Eq 4) ``[x, y, z, gamma, beta, alpha]`` (m, rad).
        deadman, reflection: Switch states the tick used.
        reflecting: Task wrench and assists were rendered this tick.
        mode: ``"rate"`` or ``"pose"``.
        faults: :class:`~app.controller.types.Fault` bits of the tick (0 = none).
        fault_message: Why the controller used its safe output, or ``""``.
        saturation_scale: Uniform torque saturation factor in (0, 1] (1 = not saturated).
        ramp: Safety ramp level of the rendered wrench in [0, 1] (:mod:`app.controller.safety`).
        po_energy: Energy the passivity observer saw enter the device port, summed over joints (J).
        pc_cut: Share of the rendered torque the passivity controller removed this tick (0..1).
        watchdog_trips: Times the amplifier's watchdog switched the motors off since the reset (for
            a Cartesian device: times the boundary's watchdog zeroed the force).
        device_link: A Cartesian device's link state (:class:`~app.device.boundary.LinkStatus`
            name: OK, RAMPING, STALLED, DISCONNECTED); empty for a joint-space device.
        slave_status: Why the slave did not follow the command exactly this tick
            (:class:`~app.slave.arm.ArmStatus` bits; 0 = it did, always for the ideal tool).
        device_fault: Why the simulated device stopped (:attr:`~app.device.plant.DevicePlant.fault`),
            or ``""``.
        slave_geom_xpos, slave_geom_xmat: The slave's own geoms (an arm's links) in {w}, (k, 3)
            and (k, 3, 3); empty for the ideal tool and in a replay (the log keeps no arm angles).
        object_poses: The scene's dynamic objects' frames {B} in {w}, rows ``[x, y, z, qw, qx,
            qy, qz]`` (m, unit quaternion) in ``scene.bodies`` order, (n, 7); (0, 7) if none.
        recording: The log directory being written, or None.
        playing: The session file whose script drives the loop, or None.
        play_left: Simulated seconds the playing script has still to run.
        paused: The loop is held (simulated time stands still).
        speed: Simulated seconds per wall-clock second.
    """

    time: float
    ticks: int
    geom_xpos: Array
    geom_xmat: Array
    T_0_G: Array
    T_0_G0: Array
    T_0_H: Array | None
    T_w_MRF: Array
    T_w_S: Array
    contact_points_w: Array
    contact_normals_w: Array
    F_MRF: Array
    G_F_T: Array
    G_F_RD: Array
    hand_wrench_0: Array
    delta_x: Array
    deadman: bool
    reflection: bool
    reflecting: bool
    mode: str
    faults: int
    fault_message: str
    saturation_scale: float
    ramp: float
    po_energy: float
    pc_cut: float
    watchdog_trips: int
    slave_geom_xpos: Array
    slave_geom_xmat: Array
    object_poses: Array
    slave_status: int = 0
    device_link: str = ""
    device_fault: str = ""
    recording: Path | None = None
    playing: Path | None = None
    play_left: float = 0.0
    paused: bool = False
    speed: float = 1.0


#: The fields of :class:`Snapshot` that hold arrays (``T_0_H`` may be None), in order: the block's.
ARRAY_FIELDS = tuple(f.name for f in fields(Snapshot) if f.type in ("Array", "Array | None"))
#: The other fields, pickled.
OTHER_FIELDS = tuple(f.name for f in fields(Snapshot) if f.name not in ARRAY_FIELDS)


def take_snapshot(
    tick: TickRecord,
    T_MRF_S: Array,
    recording: Path | None = None,
    playing: Path | None = None,
    play_left: float = 0.0,
    paused: bool = False,
    speed: float = 1.0,
    copy: bool = True,
) -> Snapshot:
    """Copy the display state of ``tick``; ``T_MRF_S`` (4, 4) places the F/T sensor on the tool.
    The other arguments are the loop process's state (:class:`Snapshot`'s fields of those names).

    With ``copy`` False the arrays are views of the rooms' buffers, valid until the next tick
    (what :class:`SnapshotPublisher` hands to :meth:`SharedSnapshot.write`, which copies them).
    """
    own: Callable[[Array], Array] = np.array if copy else np.asarray
    out = tick.out
    reading = tick.reading
    T_w_MRF = own(tick.T_w_MRF)
    hand = tick.hand_target
    slave_xpos, slave_xmat = tick.slave_geom_poses()
    return Snapshot(
        time=tick.time,
        ticks=tick.index,
        geom_xpos=own(reading.geom_xpos),
        geom_xmat=own(reading.geom_xmat.reshape(-1, 3, 3)),
        T_0_G=own(reading.T_0_G),
        T_0_G0=own(out.T_0_G0),
        T_0_H=None if hand is None else own(hand),
        T_w_MRF=T_w_MRF,
        T_w_S=T_w_MRF @ T_MRF_S,
        contact_points_w=own(tick.contact.points_w),
        contact_normals_w=own(tick.contact.normals_w),
        F_MRF=own(out.F_MRF),
        G_F_T=own(out.G_F_T),
        G_F_RD=own(out.G_F_RD),
        hand_wrench_0=own(reading.wrench_G),
        delta_x=own(out.delta_x),
        deadman=tick.deadman,
        reflection=tick.reflection,
        reflecting=out.reflecting,
        mode=out.command.mode,
        faults=int(out.faults),
        fault_message=out.fault_message,
        saturation_scale=out.saturation_scale,
        ramp=out.ramp,
        po_energy=out.po_energy,
        pc_cut=out.pc_cut,
        watchdog_trips=reading.watchdog_trips,
        slave_status=tick.slave_status,
        device_link=reading.status.name if isinstance(reading, CartesianReading) else "",
        device_fault=(reading.fault or "") if isinstance(reading, PlantReading) else "",
        slave_geom_xpos=own(slave_xpos),
        slave_geom_xmat=own(slave_xmat.reshape(-1, 3, 3)),
        object_poses=own(tick.object_poses()),
        recording=recording,
        playing=playing,
        play_left=play_left,
        paused=paused,
        speed=speed,
    )


class SharedSnapshot:
    """The seqlocked snapshot buffer both processes map (create it before starting the child)."""

    def __init__(self) -> None:
        ctx = mp.get_context("spawn")
        self.seq = ctx.RawValue(ctypes.c_uint64, 0)
        self.length = ctx.RawValue(ctypes.c_uint64, 0)
        self.size = ctx.RawValue(ctypes.c_uint64, 0)
        self.block = ctx.RawArray(ctypes.c_double, SNAPSHOT_BYTES // 8)
        self.buffer = ctx.RawArray(ctypes.c_uint8, FIELDS_BYTES)

    @property
    def published(self) -> bool:
        """Whether anything was written yet."""
        return bool(self.seq.value)

    def write(self, snap: Snapshot) -> None:
        """Publish ``snap``: its arrays copied into the block, the rest pickled beside them."""
        arrays = [getattr(snap, name) for name in ARRAY_FIELDS]
        if sum(a.size for a in arrays if a is not None) > len(self.block):
            snap = replace(
                snap,
                contact_points_w=snap.contact_points_w[:MAX_SHOWN_CONTACTS],
                contact_normals_w=snap.contact_normals_w[:MAX_SHOWN_CONTACTS],
            )
            arrays = [getattr(snap, name) for name in ARRAY_FIELDS]
        shapes = tuple(None if a is None else a.shape for a in arrays)
        data = pickle.dumps((shapes, *(getattr(snap, name) for name in OTHER_FIELDS)), protocol=pickle.HIGHEST_PROTOCOL)
        block = np.frombuffer(memoryview(self.block), dtype=np.float64)
        self.seq.value += 1  # odd: a write is in progress
        at = 0
        for a in arrays:
            if a is not None:
                block[at : at + a.size] = a.ravel()
                at += a.size
        memoryview(self.buffer).cast("B")[: len(data)] = data
        self.length.value = len(data)
        self.size.value = at
        self.seq.value += 1

    def read(self) -> Snapshot | None:
        """The latest published snapshot, or None if nothing was published yet."""
        view = memoryview(self.buffer).cast("B")
        block = np.frombuffer(memoryview(self.block), dtype=np.float64)
        while True:
            before = self.seq.value
            if before == 0:
                return None
            if before % 2:
                continue
            data = bytes(view[: self.length.value])
            values = block[: self.size.value].copy()
            if self.seq.value == before:
                shapes, *others = pickle.loads(data)
                arrays: dict[str, Array | None] = {}
                at = 0
                for name, shape in zip(ARRAY_FIELDS, shapes, strict=True):
                    if shape is None:
                        arrays[name] = None
                        continue
                    n = math.prod(shape)
                    arrays[name] = values[at : at + n].reshape(shape)
                    at += n
                return Snapshot(**arrays, **dict(zip(OTHER_FIELDS, others, strict=True)))  # type: ignore[arg-type]


class SnapshotPublisher:
    """Tick observer: writes a :class:`Snapshot` of every ``every``-th tick into ``shared``.

    Args:
        shared: Where to write.
        T_MRF_S: The F/T sensor on the tool (4, 4).
        every: Ticks between snapshots.
        dt: The loop's servo period (s).

    Attributes:
        recording, playing: Shown in the snapshot (set by the loop process's command handler).
        play_end: The tick index at which the playing script ends (0 when none plays): the
            snapshot's ``play_left`` is worked out from it when one is taken, not every tick.
        paused, speed: The loop's state.
    """

    def __init__(self, shared: SharedSnapshot, T_MRF_S: Array, every: int, dt: float) -> None:
        self.shared = shared
        self.T_MRF_S = T_MRF_S
        self.every = every
        self.dt = dt
        self.recording: Path | None = None
        self.playing: Path | None = None
        self.play_end = 0
        self.paused = False
        self.speed = 1.0

    def on_tick(self, tick: TickRecord) -> None:
        if tick.index % self.every == 0:
            self.publish(tick)

    def publish(self, tick: TickRecord) -> None:
        """Write ``tick`` now, whatever its index."""
        # Built once with the loop's state (a dataclasses.replace after cost ~9 us a snapshot).
        play_left = max(self.play_end - tick.index, 0) * self.dt
        snap = take_snapshot(
            tick, self.T_MRF_S, self.recording, self.playing, play_left, self.paused, self.speed, copy=False
        )
        self.shared.write(snap)
