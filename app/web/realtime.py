"""The servo loop paced to the wall clock in its own thread, and the snapshots the UI reads.

The loop thread owns the :class:`~app.session.loop.ServoLoop`: nothing else touches it while the
thread runs. Other threads (viser callbacks, the UI refresh) talk to it in two ways only:

- **Commands** go into a deque of functions the loop thread applies at the start of its next tick
  (``deque.append``/``popleft`` are atomic), so a switch, a gain change or a hand-target drag takes
  effect between ticks, never in the middle of one.
- **Snapshots** come back: every ``publish_every`` ticks the loop thread copies what the display
  needs into a new immutable :class:`Snapshot` and swaps the reference (an atomic assignment). A
  slow or absent browser only ever reads an older snapshot; it cannot slow the loop.

Pacing uses absolute ``time.perf_counter_ns`` deadlines ``t0 + k dt``: sleep most of the wait and
spin the last :data:`SPIN_NS`, because ``time.sleep`` wakes up to ~0.1 ms late on Linux. A tick that
starts late is followed by catch-up ticks (so simulated time keeps up with real time) unless the
loop fell more than :data:`MAX_LAG_TICKS` behind, in which case the schedule restarts from now.
"""

from __future__ import annotations

import collections
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.controller.gains import ControllerGains
from app.session.log import TickLog
from app.session.loop import ServoLoop
from app.spatial import Array

#: The last part of each wait is spun rather than slept (ns): sleep wake-up latency is ~0.1 ms.
SPIN_NS = 300_000
#: Behind by more than this many periods, the schedule restarts instead of catching up.
MAX_LAG_TICKS = 50
#: Periods kept for the timing statistics (a ring buffer; 65 s at 1 kHz).
TIMING_HISTORY = 1 << 16
#: GIL switch interval (s) while the loop runs. Python's default 5 ms would let a UI thread hold
#: the interpreter for up to 5 ms after the loop thread wakes; 0.1 ms bounds that wait.
GIL_SWITCH_INTERVAL = 1e-4

Command = Callable[[ServoLoop], None]


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


class RealtimeLoop:
    """Runs a :class:`ServoLoop` at its configured rate in a daemon thread.

    Args:
        loop: The servo loop; owned by the thread between :meth:`start` and :meth:`stop`.
        publish_every: Ticks between snapshots (10 at 1 kHz = 100 snapshots/s, above any UI rate).
    """

    def __init__(self, loop: ServoLoop, publish_every: int = 10) -> None:
        self.loop = loop
        self.publish_every = publish_every
        self.dt_ns = round(loop.dt * 1e9)
        self._commands: collections.deque[Command] = collections.deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._hand_target: Array | None = None
        self._log: TickLog | None = None
        self._gains = loop.controller.gains
        self._periods = np.zeros(TIMING_HISTORY, dtype=np.int64)
        self._tick_ns = np.zeros(TIMING_HISTORY, dtype=np.int64)
        self._count = 0
        self._slips = 0
        self._old_switch_interval = sys.getswitchinterval()
        self.snapshot: Snapshot = self._take_snapshot()

    # -- lifetime -------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the paced thread."""
        if self._thread is not None:
            return
        self._old_switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(GIL_SWITCH_INTERVAL)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="servo-loop", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread (after its current tick) and close any log being written."""
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join()
        self._thread = None
        sys.setswitchinterval(self._old_switch_interval)
        self._close_log()

    # -- commands (any thread) ------------------------------------------------------------------

    def submit(self, command: Command) -> None:
        """Run ``command(loop)`` in the loop thread before its next tick."""
        self._commands.append(command)

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the operator's hand pulls the grip (4, 4, device base {0}); None lets go."""
        target = None if T_0_H is None else np.array(T_0_H, dtype=float)

        def apply(loop: ServoLoop) -> None:
            self._hand_target = target
            loop.set_hand_target(target)

        self.submit(apply)

    def set_deadman(self, on: bool) -> None:
        def apply(loop: ServoLoop) -> None:
            loop.switches.deadman = on

        self.submit(apply)

    def set_reflection(self, on: bool) -> None:
        def apply(loop: ServoLoop) -> None:
            loop.switches.reflection = on

        self.submit(apply)

    def press_reference(self) -> None:
        """A momentary press of the reference switch: on for exactly one tick (Sec 4.1)."""

        def apply(loop: ServoLoop) -> None:
            loop.switches.reference = True

        self.submit(apply)

    @property
    def gains(self) -> ControllerGains:
        """The gains most recently set (possibly not yet applied by the loop thread)."""
        return self._gains

    def set_gains(self, gains: ControllerGains) -> None:
        self._gains = gains

        def apply(loop: ServoLoop) -> None:
            loop.set_gains(gains)

        self.submit(apply)

    def reset(self) -> None:
        """Device and slave home, switches off; the hand keeps holding its current target."""

        def apply(loop: ServoLoop) -> None:
            loop.reset()
            loop.set_hand_target(self._hand_target)

        self.submit(apply)

    def start_recording(self, directory: Path) -> None:
        """Write the per-tick log (the same Parquet log as a headless session) into ``directory``."""

        def apply(loop: ServoLoop) -> None:
            self._close_log()
            self._log = TickLog(directory, loop.config.device.n_joints)

        self.submit(apply)

    def stop_recording(self) -> None:
        self.submit(lambda loop: self._close_log())

    # -- statistics (any thread) ----------------------------------------------------------------

    def stats(self, last: int | None = None) -> TimingStats:
        """Timing over the last ``last`` periods (default: all kept, up to :data:`TIMING_HISTORY`)."""
        count = self._count
        n = min(count - 1, TIMING_HISTORY - 1, last if last is not None else TIMING_HISTORY)
        if n < 1:
            return TimingStats(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, self._slips)
        idx = np.arange(count - n, count) % TIMING_HISTORY
        periods = self._periods[idx].astype(float) / 1e3
        ticks = self._tick_ns[idx].astype(float) / 1e3
        jitter = np.abs(periods - self.dt_ns / 1e3)
        return TimingStats(
            ticks=n,
            rate_hz=float(n / (periods.sum() * 1e-6)),
            period_p50_us=float(np.median(periods)),
            jitter_p99_us=float(np.percentile(jitter, 99)),
            jitter_max_us=float(jitter.max()),
            tick_p50_us=float(np.median(ticks)),
            tick_p99_us=float(np.percentile(ticks, 99)),
            slips=self._slips,
        )

    # -- the loop thread ------------------------------------------------------------------------

    def _close_log(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None

    def _run(self) -> None:
        loop = self.loop
        dt_ns = self.dt_ns
        commands = self._commands
        periods, tick_ns = self._periods, self._tick_ns
        clock = time.perf_counter_ns
        deadline = clock()
        previous = deadline
        while not self._stop.is_set():
            wait = deadline - clock()
            if wait > SPIN_NS:
                time.sleep((wait - SPIN_NS) * 1e-9)
            while clock() < deadline:
                pass
            start = clock()
            while commands:
                commands.popleft()(loop)
            out = loop.tick()
            loop.switches.reference = False  # momentary: one tick per press
            if self._log is not None:
                self._log.record(loop, out, self._hand_target)
            if loop.ticks % self.publish_every == 0:
                self.snapshot = self._take_snapshot()
            i = self._count % TIMING_HISTORY
            periods[i] = start - previous
            tick_ns[i] = clock() - start
            self._count += 1
            previous = start
            deadline += dt_ns
            if clock() - deadline > MAX_LAG_TICKS * dt_ns:
                deadline = clock()
                self._slips += 1

    def _take_snapshot(self) -> Snapshot:
        loop = self.loop
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
            T_0_H=None if self._hand_target is None else self._hand_target.copy(),
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
            recording=None if self._log is None else self._log.directory,
        )
