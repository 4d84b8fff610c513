"""The servo loop paced to the wall clock in its own process, and the snapshots the UI reads.

The loop runs in a child process (``spawn``) so that the web server's threads (websocket, callbacks,
redraws) never compete with it for the GIL: in one process a redraw or a message encode held the
interpreter for milliseconds and the period jitter p99 was ~2 ms; in its own process the loop only
shares the CPU. The parent keeps an identical but never-ticked :class:`ServoLoop` for the static
geometry the view needs (device geoms, world meshes, tool).

Parent and child talk through three channels, none of which can block the loop:

- **Commands** (parent -> child): small tuples on a pipe, applied by the loop between ticks
  (``poll`` is a non-blocking check each tick).
- **Snapshots** (child -> parent): every ``publish_every`` ticks the loop pickles a
  :class:`Snapshot` into a shared buffer guarded by a sequence counter (a seqlock): the writer never
  waits, a reader retries if it raced a write. A slow or absent browser only ever reads an older one.
- **Timing** (child -> parent): per-tick period and compute time in shared ring buffers; the parent
  computes the statistics, so asking for them costs the loop nothing.

Pacing uses absolute ``time.perf_counter_ns`` deadlines ``t0 + k dt``: sleep most of the wait and
spin the last :data:`SPIN_NS`, because ``time.sleep`` wakes up to ~0.1 ms late on Linux. A tick that
starts late is followed by catch-up ticks (so simulated time keeps up with real time) unless the
loop fell more than :data:`MAX_LAG_TICKS` behind, in which case the schedule restarts from now.
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import pickle
import threading
import time
from dataclasses import dataclass, replace
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from app.controller.gains import ControllerGains
from app.device.hand import HandParams
from app.device.spec import load_device
from app.errors import ConfigError
from app.session.log import TickLog
from app.session.loop import LoopConfig, ServoLoop
from app.spatial import Array
from app.world.scene import load_scene

#: The last part of each wait is spun rather than slept (ns): sleep wake-up latency is ~0.1 ms.
SPIN_NS = 300_000
#: Behind by more than this many periods, the schedule restarts instead of catching up.
MAX_LAG_TICKS = 50
#: Periods kept for the timing statistics (a ring buffer; 65 s at 1 kHz).
TIMING_HISTORY = 1 << 16
#: Bytes of the shared snapshot buffer; contact points beyond what fits are dropped from display.
SNAPSHOT_BYTES = 1 << 20
#: Seconds to wait for the child to exit before it is terminated.
STOP_TIMEOUT = 5.0
#: SCHED_FIFO priority asked for the loop process. Without it, a headless browser rendering WebGL in
#: software on a 2-core machine preempted the loop for tens of milliseconds (~570 Hz achieved).
RT_PRIORITY = 50
#: Niceness tried when real-time scheduling is not permitted.
FALLBACK_NICE = -10
#: What :func:`_raise_priority` obtained, as stored in shared memory.
SCHEDULING = ("normal", f"nice {FALLBACK_NICE}", f"SCHED_FIFO {RT_PRIORITY}")


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
        recording: The log directory being written, or None.
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
    recording: Path | None


@dataclass(frozen=True)
class TimingStats:
    """How well the loop kept its period, over the last ``ticks`` ticks.

    Attributes:
        ticks: Periods measured (tick start to next tick start).
        rate_hz: Achieved ticks per second of wall time over those periods.
        period_p50_us: Median period (us).
        jitter_p99_us: 99th percentile of ``|period - dt|`` (us).
        jitter_max_us: Largest ``|period - dt|`` (us).
        tick_p50_us, tick_p99_us: Compute time of one tick, median and p99 (us).
        slips: Times since start the loop fell more than :data:`MAX_LAG_TICKS` behind and restarted
            its schedule (simulated time then lags wall time).
    """

    ticks: int
    rate_hz: float
    period_p50_us: float
    jitter_p99_us: float
    jitter_max_us: float
    tick_p50_us: float
    tick_p99_us: float
    slips: int


def take_snapshot(loop: ServoLoop, T_0_H: Array | None, recording: Path | None) -> Snapshot:
    """Copy the display state of ``loop`` after its last tick."""
    out = loop.controller.out
    data = loop.plant.data
    T_w_MRF = loop.slave.T_w_MRF
    return Snapshot(
        time=loop.time,
        ticks=loop.ticks,
        geom_xpos=data.geom_xpos.copy(),
        geom_xmat=data.geom_xmat.reshape(-1, 3, 3).copy(),
        T_0_G=loop.reading.T_0_G.copy(),
        T_0_G0=out.T_0_G0.copy(),
        T_0_H=None if T_0_H is None else T_0_H.copy(),
        T_w_MRF=T_w_MRF,
        T_w_S=T_w_MRF @ loop.controller.slave.T_MRF_S,
        contact_points_w=loop.slave.contact.points_w.copy(),
        F_MRF=out.F_MRF.copy(),
        G_F_T=out.G_F_T.copy(),
        G_F_RD=out.G_F_RD.copy(),
        hand_wrench_0=loop.reading.wrench_G.copy(),
        delta_x=out.delta_x.copy(),
        deadman=loop.switches.deadman,
        reflection=loop.switches.reflection,
        reflecting=out.reflecting,
        mode=loop.controller.gains.mode,
        faults=int(out.faults),
        fault_message=out.fault_message,
        saturation_scale=out.saturation_scale,
        recording=recording,
    )


@dataclass(frozen=True)
class LoopRecipe:
    """How the child process rebuilds the parent's :class:`LoopConfig` (files, not live objects:
    scenes hold FCL objects that cannot be pickled)."""

    scene_path: Path
    device_path: Path
    gains: ControllerGains
    hand: HandParams
    accommodation: bool
    servo_rate: float

    @staticmethod
    def of(config: LoopConfig) -> LoopRecipe:
        if config.scene.path is None:
            raise ConfigError("<scene>", "path", "the web demo needs a scene loaded from a file")
        return LoopRecipe(
            config.scene.path, config.device.path, config.gains, config.hand, config.accommodation, config.servo_rate
        )

    def build(self) -> ServoLoop:
        scene, device = load_scene(self.scene_path), load_device(self.device_path)
        return ServoLoop(LoopConfig(device, scene, self.gains, self.hand, self.accommodation, self.servo_rate))


class _Shared:
    """Memory both processes map: the seqlocked snapshot buffer and the timing ring buffers."""

    def __init__(self) -> None:
        ctx = mp.get_context("spawn")
        self.seq = ctx.RawValue(ctypes.c_uint64, 0)
        self.length = ctx.RawValue(ctypes.c_uint64, 0)
        self.buffer = ctx.RawArray(ctypes.c_uint8, SNAPSHOT_BYTES)
        self.count = ctx.RawValue(ctypes.c_int64, 0)
        self.slips = ctx.RawValue(ctypes.c_int64, 0)
        self.periods = ctx.RawArray(ctypes.c_int64, TIMING_HISTORY)
        self.tick_ns = ctx.RawArray(ctypes.c_int64, TIMING_HISTORY)
        self.scheduling = ctx.RawValue(ctypes.c_int64, 0)

    def write_snapshot(self, snap: Snapshot) -> None:
        data = pickle.dumps(snap, protocol=pickle.HIGHEST_PROTOCOL)
        if len(data) > SNAPSHOT_BYTES:
            data = pickle.dumps(_without_contacts(snap), protocol=pickle.HIGHEST_PROTOCOL)
        self.seq.value += 1  # odd: a write is in progress
        memoryview(self.buffer).cast("B")[: len(data)] = data
        self.length.value = len(data)
        self.seq.value += 1

    def read_snapshot(self) -> Snapshot | None:
        """The latest published snapshot, or None if nothing was published yet."""
        view = memoryview(self.buffer).cast("B")
        while True:
            before = self.seq.value
            if before == 0:
                return None
            if before % 2:
                continue
            data = bytes(view[: self.length.value])
            if self.seq.value == before:
                snap: Snapshot = pickle.loads(data)
                return snap

    def timing(self) -> tuple[int, Array, Array]:
        """``(ticks counted, periods (ns), tick compute times (ns))`` as numpy views."""
        return (
            int(self.count.value),
            np.frombuffer(memoryview(self.periods), dtype=np.int64),
            np.frombuffer(memoryview(self.tick_ns), dtype=np.int64),
        )


def _without_contacts(snap: Snapshot) -> Snapshot:
    return replace(snap, contact_points_w=snap.contact_points_w[:1000])


def _apply(loop: ServoLoop, state: dict[str, Any], command: tuple[Any, ...]) -> bool:
    """Apply one parent command in the loop process; False means stop."""
    name = command[0]
    if name == "hand":
        state["hand"] = command[1]
        loop.set_hand_target(command[1])
    elif name == "deadman":
        loop.switches.deadman = command[1]
    elif name == "reflection":
        loop.switches.reflection = command[1]
    elif name == "reference":
        loop.switches.reference = True
    elif name == "gains":
        loop.set_gains(command[1])
    elif name == "reset":
        loop.reset()
        loop.set_hand_target(state["hand"])
    elif name == "record":
        if state["log"] is not None:
            state["log"].close()
        state["log"] = None if command[1] is None else TickLog(command[1], loop.config.device.n_joints)
    elif name == "stop":
        return False
    return True


def _raise_priority() -> int:
    """Ask for real-time scheduling, else a lower niceness; returns an index into :data:`SCHEDULING`."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))
        return 2
    except (OSError, AttributeError):
        pass
    try:
        os.nice(FALLBACK_NICE)
        return 1
    except OSError:
        return 0


def _child_main(recipe: LoopRecipe, conn: Connection, shared: _Shared, publish_every: int) -> None:
    """The loop process: build the loop, then tick it on the wall clock until told to stop."""
    loop = recipe.build()
    loop.tick()  # the first tick loads the compiled kernels (~0.3 s): keep it off the clock
    loop.reset()
    shared.scheduling.value = _raise_priority()
    state: dict[str, Any] = {"hand": None, "log": None}
    dt_ns = round(loop.dt * 1e9)
    periods = np.frombuffer(memoryview(shared.periods), dtype=np.int64)
    tick_ns = np.frombuffer(memoryview(shared.tick_ns), dtype=np.int64)
    clock = time.perf_counter_ns
    running = True
    count = 0
    deadline = clock()
    previous = deadline
    try:
        while running:
            wait = deadline - clock()
            if wait > SPIN_NS:
                time.sleep((wait - SPIN_NS) * 1e-9)
            while clock() < deadline:
                pass
            start = clock()
            try:
                while running and conn.poll():
                    running = _apply(loop, state, conn.recv())
            except (EOFError, OSError):  # the parent is gone: nobody to serve
                running = False
            out = loop.tick()
            loop.switches.reference = False  # momentary: one tick per press
            log: TickLog | None = state["log"]
            if log is not None:
                log.record(loop, out, state["hand"])
            if loop.ticks % publish_every == 0:
                shared.write_snapshot(take_snapshot(loop, state["hand"], None if log is None else log.directory))
            i = count % TIMING_HISTORY
            periods[i] = start - previous
            tick_ns[i] = clock() - start
            count += 1
            shared.count.value = count
            previous = start
            deadline += dt_ns
            if clock() - deadline > MAX_LAG_TICKS * dt_ns:
                deadline = clock()
                shared.slips.value += 1
    finally:
        if state["log"] is not None:
            state["log"].close()


class RealtimeLoop:
    """Runs a servo loop at its configured rate in a child process.

    Args:
        config: The loop to run; its scene and device must come from files.
        publish_every: Ticks between snapshots (20 at 1 kHz = 50 snapshots/s, above the UI rate).

    Attributes:
        loop: A parent-side copy of the loop, never ticked: static geometry for the view.
    """

    def __init__(self, config: LoopConfig, publish_every: int = 20) -> None:
        self.recipe = LoopRecipe.of(config)
        self.loop = ServoLoop(config)
        self.publish_every = publish_every
        self.dt_ns = round(self.loop.dt * 1e9)
        self._gains = config.gains
        self._shared = _Shared()
        self._initial = take_snapshot(self.loop, None, None)
        self._conn, self._child_conn = mp.get_context("spawn").Pipe()
        self._send_lock = threading.Lock()  # viser callbacks send from several threads
        self._process: Any = None

    # -- lifetime -------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the loop process (it begins ticking once it has built its loop, ~1-3 s)."""
        if self._process is not None:
            return
        ctx = mp.get_context("spawn")
        self._process = ctx.Process(
            target=_child_main,
            args=(self.recipe, self._child_conn, self._shared, self.publish_every),
            name="servo-loop",
            daemon=True,
        )
        self._process.start()

    def wait_running(self, timeout: float = 60.0) -> bool:
        """Block until the loop process has published its first snapshot; False on timeout.

        Raises:
            RuntimeError: if the loop process died (its exit code is in the message).
        """
        end = time.monotonic() + timeout
        while self._shared.seq.value == 0:
            if self._process is not None and not self._process.is_alive():
                raise RuntimeError(f"the servo loop process exited with code {self._process.exitcode}")
            if time.monotonic() > end:
                return False
            time.sleep(0.01)
        return True

    def stop(self) -> None:
        """Stop the loop process after its current tick (it closes any log being written)."""
        if self._process is None:
            return
        self._send("stop")
        self._process.join(STOP_TIMEOUT)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join()
        self._process = None

    # -- commands (any thread) ------------------------------------------------------------------

    def _send(self, *command: Any) -> None:
        with self._send_lock:
            self._conn.send(command)

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the operator's hand pulls the grip (4, 4, device base {0}); None lets go."""
        self._send("hand", None if T_0_H is None else np.array(T_0_H, dtype=float))

    def set_deadman(self, on: bool) -> None:
        self._send("deadman", bool(on))

    def set_reflection(self, on: bool) -> None:
        self._send("reflection", bool(on))

    def press_reference(self) -> None:
        """A momentary press of the reference switch: on for exactly one tick (Sec 4.1)."""
        self._send("reference")

    @property
    def gains(self) -> ControllerGains:
        """The gains most recently set (possibly not yet applied by the loop)."""
        return self._gains

    def set_gains(self, gains: ControllerGains) -> None:
        self._gains = gains
        self._send("gains", gains)

    def reset(self) -> None:
        """Device and slave home, switches off; the hand keeps holding its current target."""
        self._send("reset")

    def start_recording(self, directory: Path) -> None:
        """Write the per-tick log (the same Parquet log as a headless session) into ``directory``."""
        self._send("record", directory)

    def stop_recording(self) -> None:
        self._send("record", None)

    # -- state (any thread) ---------------------------------------------------------------------

    @property
    def snapshot(self) -> Snapshot:
        """The latest snapshot (the loop's initial state until the process publishes)."""
        return self._shared.read_snapshot() or self._initial

    @property
    def scheduling(self) -> str:
        """The scheduling the loop process obtained (see :data:`SCHEDULING`)."""
        return SCHEDULING[int(self._shared.scheduling.value)]

    def stats(self, last: int | None = None) -> TimingStats:
        """Timing over the last ``last`` periods (default: all kept, up to :data:`TIMING_HISTORY`)."""
        count, all_periods, all_ticks = self._shared.timing()
        n = min(count - 1, TIMING_HISTORY - 1, last if last is not None else TIMING_HISTORY)
        if n < 1:
            return TimingStats(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, int(self._shared.slips.value))
        idx = np.arange(count - n, count) % TIMING_HISTORY
        periods = all_periods[idx].astype(float) / 1e3
        ticks = all_ticks[idx].astype(float) / 1e3
        jitter = np.abs(periods - self.dt_ns / 1e3)
        return TimingStats(
            ticks=n,
            rate_hz=float(n / (periods.sum() * 1e-6)),
            period_p50_us=float(np.median(periods)),
            jitter_p99_us=float(np.percentile(jitter, 99)),
            jitter_max_us=float(jitter.max()),
            tick_p50_us=float(np.median(ticks)),
            tick_p99_us=float(np.percentile(ticks, 99)),
            slips=int(self._shared.slips.value),
        )
