"""The servo loop's own process: build the loop, apply commands between ticks, tick on the clock.

The loop runs in a child process (``spawn``) so that the web server's threads (websocket,
callbacks, redraws) never compete with it for the GIL: in one process a redraw or a message
encode held the interpreter for milliseconds and the period jitter p99 was ~2 ms; in its own
process the loop only shares the CPU. :func:`loop_main` is the process's entry point;
:class:`LoopHost` holds its state and applies the :mod:`~app.web.commands`.
"""

from __future__ import annotations

import ctypes
import dataclasses
import multiprocessing as mp
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from app.controller.gains import ControllerGains
from app.session.log import TickLog, loop_meta
from app.session.loop import LoopConfig, ServoLoop
from app.session.pacer import TIMING_HISTORY, Pacer, TimingRings, raise_priority
from app.session.script import OperatorScript
from app.session.spec import SessionFile
from app.web.commands import (
    Pause,
    Play,
    PressReference,
    Record,
    Reset,
    SetChannel,
    SetDeadman,
    SetGains,
    SetHandTarget,
    SetPassivity,
    SetReflection,
    SetSpeed,
    Stop,
    check_command,
)
from app.web.snapshot import SharedSnapshot, SnapshotPublisher

#: How often (s) the loop looks for the page's commands. Each look is a system call on the pipe
#: (``poll``: 3.6 us unpaced, 6-8 us paced on the 2-core machine this is measured on, 10-20 % of a
#: tick); a command waits at most this long, well inside the 20 ms between snapshots the page sees.
COMMAND_POLL_S = 0.005


class SharedTiming:
    """The pacer's timing rings and the scheduling obtained, in memory both processes map."""

    def __init__(self) -> None:
        ctx = mp.get_context("spawn")
        self.periods = ctx.RawArray(ctypes.c_int64, TIMING_HISTORY)
        self.tick_ns = ctx.RawArray(ctypes.c_int64, TIMING_HISTORY)
        self.counters = ctx.RawArray(ctypes.c_int64, 2)
        self.scheduling = ctx.RawValue(ctypes.c_int64, 0)

    def rings(self) -> TimingRings:
        """numpy views of the shared rings (call it in the process that uses them)."""
        return TimingRings(
            *(np.frombuffer(memoryview(a), dtype=np.int64) for a in (self.periods, self.tick_ns, self.counters))
        )


class LoopHost:
    """The loop process's state: the loop, its snapshot publisher, a log, a playing script.

    Args:
        loop: The servo loop (at its reset state).
        shared: Where snapshots are published. publish_every: Ticks between snapshots.
    """

    def __init__(self, loop: ServoLoop, shared: SharedSnapshot, publish_every: int) -> None:
        self.loop = loop
        self.publisher = loop.observe(SnapshotPublisher(shared, loop.controller.slave.T_MRF_S, publish_every, loop.dt))
        self.log: TickLog | None = None
        self.operator: OperatorScript | None = None
        self.ticks_left = 0
        self.running = True
        self.paused = False
        self.speed = 1.0
        self._log_ends_with_play = False

    def apply(self, command: object) -> bool:
        """Apply one command between ticks; True if it restarts the loop's schedule (a reset or a
        new play: wall time and simulated time start over together).

        Raises:
            UnknownCommand: ``command`` is not a loop command.
        """
        loop = self.loop
        match check_command(command):
            case SetHandTarget(T_0_H):
                loop.set_hand_target(T_0_H)
            case SetDeadman(on):
                loop.switches.deadman = on
            case SetReflection(on):
                loop.switches.reflection = on
            case PressReference():
                loop.press_reference()
            case SetGains(gains):
                loop.set_gains(gains)
            case Reset():
                self._end_play()
                loop.reset()
                return True
            case Record(directory):
                self._record(directory)
            case Play(script, gains, source, record):
                self._end_play()
                if script is not None and gains is not None:
                    self._play(script, gains, source, record)
                    return True
            case Pause(on):
                self.paused = on
                self.publisher.paused = on
                self.publisher.publish(loop.record)
                return not on
            case SetPassivity(settings):
                loop.set_passivity(settings)
            case SetChannel(settings):
                loop.set_channel(settings)
            case SetSpeed(factor):
                # Speed is a property of the playing session: without one the loop keeps real time.
                if self.operator is None:
                    return False
                self._set_speed(factor)
                return True
            case Stop():
                self.running = False
        return False

    def tick(self) -> bool:
        """One tick (none while paused), with the playing script acting first; True if the script
        ended on it (the speed is back to 1: the schedule restarts)."""
        if self.paused:
            return False
        operator = self.operator
        if operator is not None:
            operator.before_tick(self.loop)
        self.loop.tick()
        if operator is not None:
            self.ticks_left -= 1
            if self.ticks_left == 0:
                self._end_play()
                return True
        return False

    def close(self) -> None:
        """Close a log being written."""
        self._record(None)

    def _record(self, directory: Path | None) -> None:
        if self.log is not None:
            self.loop.unobserve(self.log)
            self.log.close()
            self.log = None
        if directory is not None:
            config = dataclasses.replace(self.loop.config, gains=self.loop.controller.gains)
            meta = loop_meta(config, self.publisher.playing)
            log = TickLog(directory, self.loop.controller.out.n, self.loop.dt, meta=meta, objects=self.loop.objects)
            self.log = self.loop.observe(log)
        self.publisher.recording = directory
        self._log_ends_with_play = False

    def _play(self, script: SessionFile, gains: ControllerGains, source: Path | None, record: Path | None) -> None:
        loop = self.loop
        loop.set_gains(gains)
        loop.reset()
        self.operator = OperatorScript.for_loop(script, loop)
        self.ticks_left = self.publisher.play_end = script.n_ticks  # from the reset: tick index 0
        self.publisher.playing = source
        if record is not None:
            self._record(record)
            self._log_ends_with_play = True

    def _end_play(self) -> None:
        if self._log_ends_with_play:
            self._record(None)
        self.operator = None
        self.publisher.playing = None
        self.publisher.play_end = 0
        self._set_speed(1.0)

    def _set_speed(self, factor: float) -> None:
        self.speed = factor
        self.publisher.speed = factor


def loop_main(
    config: LoopConfig,
    conn: Connection,
    snapshot: SharedSnapshot,
    timing: SharedTiming,
    publish_every: int,
    spin: float | None = None,
) -> None:
    """The loop process: build the loop, then tick it on the wall clock until told to stop
    (``spin``: :class:`~app.session.pacer.Pacer`'s)."""
    loop = ServoLoop(config)
    loop.tick()  # the first tick loads the compiled kernels (~0.3 s): keep it off the clock
    loop.reset()
    host = LoopHost(loop, snapshot, publish_every)
    timing.scheduling.value = raise_priority()
    pacer = Pacer(loop.dt, timing.rings(), spin)
    watchdog_ns = round(loop.config.watchdog * 1e9)  # the amplifier's, or a Cartesian device's own
    poll_every = max(1, round(COMMAND_POLL_S / loop.dt))
    since_poll = poll_every  # look at once
    try:
        while host.running:
            late = pacer.wait()
            if late > watchdog_ns:
                # The device kept running on the amplifier's last counts while this process was
                # stalled: simulate that gap (the watchdog switches the motors off) rather than
                # catching up with ticks the real controller never ran.
                loop.stall(late * 1e-9)
                pacer.restart(slip=True)
            since_poll += 1
            if since_poll >= poll_every:
                since_poll = 0
                try:
                    restart = False
                    while host.running and conn.poll():
                        restart |= host.apply(conn.recv())
                    if restart:
                        pacer.set_period(loop.dt / host.speed)
                except (EOFError, OSError):  # the parent is gone: nobody to serve
                    host.running = False
            if host.tick():
                pacer.set_period(loop.dt / host.speed)
            pacer.done()
    finally:
        host.close()
