"""Pacing a servo loop to the wall clock: one :class:`Pacer` for every paced loop.

Used by headless sessions run with ``--realtime`` and by the web demo's loop process. A paced
loop may also ask for real-time scheduling (:func:`raise_priority`), as the web demo's loop
process, ``frhc run --realtime`` and ``frhc device serve`` do.

Deadlines are absolute, ``t0 + k dt`` on ``time.perf_counter_ns``: the pacer sleeps most of the
wait and spins the last :data:`SPIN_NS` (at most :data:`SPIN_SHARE` of a period), because ``time.sleep`` wakes up to ~0.1 ms late on
Linux. A tick that starts late is followed by catch-up ticks (so simulated time keeps up with
real time) unless the loop fell more than :data:`MAX_LAG_TICKS` behind; then the schedule
restarts from now and the restart is counted as a *slip* (simulated time then lags wall time).

Each tick's period (start to next start) and compute time go into ring buffers
(:class:`TimingRings`); :func:`timing_stats` turns them into rate, jitter and slip figures. The
rings may live in shared memory, so another process can read the statistics without costing the
loop anything.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass

import numpy as np

from app.spatial import Array, IntArray

#: The last part of each wait is spun rather than slept (ns): sleep wake-up latency is ~0.1 ms.
SPIN_NS = 300_000
#: At most this share of a period is spun. A loop under real-time scheduling that spins for
#: whole periods (every wait of a 4 kHz loop is shorter than :data:`SPIN_NS`) uses the CPU all
#: the time; Linux then throttles it for the last 5 % of every second (``sched_rt_runtime_us``
#: 950000 of 1000000): measured at 4 kHz, a 54 ms stall once a second and the rate 1.7 % short.
SPIN_SHARE = 0.5
#: The largest share of a period a pacer may be told to spin (:class:`Pacer`'s ``spin``): with
#: the tick's compute on top, a loop at SCHED_FIFO busy past the 95 % above is throttled.
#: Measured with the demo's loop playing peg_ntrfc at 1 kHz: 0.8 kept 1000.0 Hz in two runs, 0.9
#: ran at 987.6 Hz in one and had a 875 us jitter p99 in the other.
MAX_SPIN = 0.8
#: Behind by more than this many periods, the schedule restarts instead of catching up.
MAX_LAG_TICKS = 50
#: Periods kept for the timing statistics (a ring buffer; 65 s at 1 kHz).
TIMING_HISTORY = 1 << 16
#: SCHED_FIFO priority a paced loop asks for. Without it, a headless browser rendering WebGL in
#: software on a 2-core machine preempted the web demo's loop for tens of milliseconds (~570 Hz
#: achieved).
RT_PRIORITY = 50
#: Niceness tried when real-time scheduling is not permitted.
FALLBACK_NICE = -10
#: What :func:`raise_priority` obtained (its return value indexes this).
SCHEDULING = ("normal", f"nice {FALLBACK_NICE}", f"SCHED_FIFO {RT_PRIORITY}")


def raise_priority() -> int:
    """Ask for real-time scheduling for the calling thread, else a lower niceness; returns an
    index into :data:`SCHEDULING`."""
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


def ordinary_priority() -> None:
    """Put the calling thread back under the ordinary time-sharing policy (``SCHED_OTHER``).

    For helper threads of a loop that raised its priority: a thread inherits its creator's
    policy, and a ``SCHED_FIFO`` helper pinned to the loop's CPU (the session log's writer) would
    hold that CPU for the whole of its work (~5 ms per part) while the loop waits."""
    with suppress(OSError, AttributeError):
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


#: Niceness of a loop's background helpers (:func:`background_priority`): the lowest.
BACKGROUND_NICE = 19


def background_priority() -> None:
    """:func:`ordinary_priority`, then the lowest niceness for the calling thread (Linux only: a
    thread's niceness is set through its own id there).

    For a helper that shares the loop's CPU and may run behind it, as the session log's writer
    does: at nice 0 its ~2.4 ms per part ran in slices that stalled an unpaced loop; measured on
    probe_rate / peg_ntrfc with a log (4 s, two runs): loop-iteration p99 0.96-1.12 / 1.51-1.91 ms
    at nice 0, 0.11-0.14 / 0.33-0.35 ms at nice 19, medians and the run's wall time unchanged.
    """
    ordinary_priority()
    if sys.platform.startswith("linux"):
        with suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BACKGROUND_NICE)


@contextmanager
def raised_priority() -> Iterator[int]:
    """:func:`raise_priority` for the duration of the block (yields its index); the calling
    thread's policy and niceness are restored after."""
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    nice = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        yield raise_priority()
    finally:
        with suppress(OSError):
            os.sched_setscheduler(0, policy, param)
            os.setpriority(os.PRIO_PROCESS, 0, nice)


@dataclass(frozen=True)
class TimingRings:
    """Ring buffers of the last :data:`TIMING_HISTORY` ticks.

    Attributes:
        periods: Tick start to next tick start (ns), int64 (TIMING_HISTORY,).
        tick_ns: Compute time of each tick (ns), int64 (TIMING_HISTORY,).
        counters: ``[ticks counted, slips]``, int64 (2,).
    """

    periods: IntArray
    tick_ns: IntArray
    counters: IntArray

    @staticmethod
    def allocate() -> TimingRings:
        """Rings in this process's memory."""
        return TimingRings(
            np.zeros(TIMING_HISTORY, dtype=np.int64), np.zeros(TIMING_HISTORY, dtype=np.int64), np.zeros(2, np.int64)
        )


@dataclass(frozen=True)
class TimingStats:
    """How well a loop kept its period, over the last ``ticks`` ticks.

    Attributes:
        ticks: Periods measured (tick start to next tick start), at most the rings' history.
        counted: Ticks counted since the pacer started (not capped).
        rate_hz: Achieved ticks per second of wall time over those periods.
        period_p50_us: Median period (us).
        jitter_p99_us: 99th percentile of ``|period - dt|`` (us).
        jitter_max_us: Largest ``|period - dt|`` (us).
        tick_p50_us, tick_p99_us: Compute time of one tick, median and p99 (us).
        slips: Times since start the loop fell more than :data:`MAX_LAG_TICKS` behind and restarted
            its schedule (simulated time then lags wall time).
    """

    ticks: int
    counted: int
    rate_hz: float
    period_p50_us: float
    jitter_p99_us: float
    jitter_max_us: float
    tick_p50_us: float
    tick_p99_us: float
    slips: int

    def as_dict(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in self.__dataclass_fields__}


def timing_stats(rings: TimingRings, period_ns: int, last: int | None = None) -> TimingStats:
    """Statistics of the last ``last`` periods in ``rings`` (default: all kept)."""
    count, slips = int(rings.counters[0]), int(rings.counters[1])
    n = min(count - 1, TIMING_HISTORY - 1, last if last is not None else TIMING_HISTORY)
    if n < 1:
        return TimingStats(0, max(count, 0), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, slips)
    idx = np.arange(count - n, count) % TIMING_HISTORY
    periods: Array = rings.periods[idx].astype(float) / 1e3
    ticks: Array = rings.tick_ns[idx].astype(float) / 1e3
    jitter = np.abs(periods - period_ns / 1e3)
    return TimingStats(
        ticks=n,
        counted=count,
        rate_hz=float(n / (periods.sum() * 1e-6)),
        period_p50_us=float(np.median(periods)),
        jitter_p99_us=float(np.percentile(jitter, 99)),
        jitter_max_us=float(jitter.max()),
        tick_p50_us=float(np.median(ticks)),
        tick_p99_us=float(np.percentile(ticks, 99)),
        slips=slips,
    )


class Pacer:
    """Holds a loop to its period: call :meth:`wait` before each tick and :meth:`done` after it.

    Args:
        period: Servo period (s).
        rings: Where the timing goes (default: new rings in this process).
        spin: Spin, rather than sleep, the last ``spin`` of each period (0 to :data:`MAX_SPIN`),
            whatever :data:`SPIN_NS` and :data:`SPIN_SHARE` say: the CPU is busy that share of
            the time, and the tick starts less cold (a tick after a sleep ran 2-5x its unpaced
            time on the shared 2-core machine: ``docs/conventions.md``). None: sleep all but the
            last :data:`SPIN_NS`, at most :data:`SPIN_SHARE` of a period.
    """

    def __init__(self, period: float, rings: TimingRings | None = None, spin: float | None = None) -> None:
        if spin is not None and not 0.0 <= spin <= MAX_SPIN:
            raise ValueError(f"spin must be a share of the period in [0, {MAX_SPIN}], got {spin}")
        self._spin = spin
        self.rings = rings if rings is not None else TimingRings.allocate()
        self._periods = self.rings.periods
        self._tick_ns = self.rings.tick_ns
        self._counters = self.rings.counters
        self._deadline = self._previous = self._start = 0
        self.set_period(period)

    def set_period(self, period: float) -> None:
        """Pace at another wall-clock period (s) from now on (e.g. a replay speed)."""
        self.period_ns = round(period * 1e9)
        spin = self._spin
        self._spin_ns = (
            min(SPIN_NS, round(SPIN_SHARE * self.period_ns)) if spin is None else round(spin * self.period_ns)
        )
        self.restart()

    def restart(self, slip: bool = False) -> None:
        """Start the schedule from now (the next :meth:`wait` returns at once); ``slip`` counts it
        as a slip (the loop fell behind and gave up catching up)."""
        self._deadline = self._previous = time.perf_counter_ns()
        if slip:
            self._counters[1] += 1

    def wait(self) -> int:
        """Sleep, then spin, until the next tick's deadline; returns how late the tick starts (ns)."""
        clock = time.perf_counter_ns
        wait = self._deadline - clock()
        if wait > self._spin_ns:
            time.sleep((wait - self._spin_ns) * 1e-9)
        while clock() < self._deadline:
            pass
        self._start = clock()
        return self._start - self._deadline

    def done(self) -> None:
        """Record the tick that started at the last :meth:`wait` and schedule the next one."""
        now = time.perf_counter_ns()
        counters = self._counters
        i = int(counters[0]) % TIMING_HISTORY
        self._periods[i] = self._start - self._previous
        self._tick_ns[i] = now - self._start
        counters[0] += 1
        self._previous = self._start
        self._deadline += self.period_ns
        if now - self._deadline > MAX_LAG_TICKS * self.period_ns:
            self._deadline = now
            counters[1] += 1

    def stats(self, last: int | None = None) -> TimingStats:
        """:func:`timing_stats` of this pacer's rings."""
        return timing_stats(self.rings, self.period_ns, last)
