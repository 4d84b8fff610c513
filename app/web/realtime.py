"""The servo loop paced to the wall clock in its own process: the web server's handle on it.

:class:`RealtimeLoop` starts :func:`~app.web.loop_process.loop_main` in a child process and talks
to it through three channels, none of which can block the loop:

- **Commands** (parent -> child): the typed :mod:`~app.web.commands` on a pipe, applied by the
  loop between ticks (``poll`` is a non-blocking check each tick).
- **Snapshots** (child -> parent): a :class:`~app.web.snapshot.Snapshot` every ``publish_every``
  ticks in a seqlocked shared buffer (:class:`~app.web.snapshot.SharedSnapshot`).
- **Timing** (child -> parent): the :class:`~app.session.pacer.Pacer`'s ring buffers in shared
  memory; the parent computes the statistics, so asking for them costs the loop nothing.

The parent keeps an identical but never-ticked :class:`ServoLoop` for the static geometry the view
needs (device geoms, world meshes, tool).
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

from app.controller.gains import ControllerGains
from app.controller.passivity import PassivitySettings
from app.errors import ConfigError
from app.session.loop import LoopConfig, ServoLoop
from app.session.pacer import SCHEDULING, TimingStats, timing_stats
from app.session.spec import Session
from app.spatial import Array
from app.teleop.channel import ChannelSettings
from app.web.commands import (
    LoopCommand,
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
from app.web.loop_process import SharedTiming, loop_main
from app.web.snapshot import SharedSnapshot, Snapshot, take_snapshot

#: Snapshots a second the loop publishes by default (above the page's redraw rate), whatever its servo rate.
SNAPSHOT_RATE = 50.0
#: Seconds to wait for the child to exit before it is terminated.
STOP_TIMEOUT = 5.0


class RealtimeLoop:
    """Runs a servo loop at its configured rate in a child process.

    Args:
        config: The loop to run; its scene and device must come from files.
        publish_every: Ticks between snapshots; default: :data:`SNAPSHOT_RATE` snapshots a second at
            the loop's servo rate (every 20 ticks at 1 kHz, every 80 at 4 kHz).
        spin: Share of each period the loop process spins instead of sleeping
            (:class:`~app.session.pacer.Pacer`); None: the pacer's default (at most 0.3 ms).

    Attributes:
        loop: A parent-side copy of the loop, never ticked: static geometry for the view.
    """

    def __init__(self, config: LoopConfig, publish_every: int | None = None, spin: float | None = None) -> None:
        if config.scene.path is None:
            raise ConfigError("<scene>", "path", "the web demo needs a scene loaded from a file")
        self.config = config
        # Never ticked, and never connected: a device outside this process is driven by the loop
        # process alone (a served device takes one client), so this copy simulates its model.
        self.loop = ServoLoop(dataclasses.replace(config, device_url=None))
        self.publish_every = publish_every or max(1, round(config.servo_rate / SNAPSHOT_RATE))
        self.spin = spin
        self._gains = config.gains
        self._snapshot = SharedSnapshot()
        self._timing = SharedTiming()
        self._rings = self._timing.rings()
        self._initial = take_snapshot(self.loop.record, self.loop.controller.slave.T_MRF_S)
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
            target=loop_main,
            args=(self.config, self._child_conn, self._snapshot, self._timing, self.publish_every, self.spin),
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
        while not self._snapshot.published:
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
        self.send(Stop())
        self._process.join(STOP_TIMEOUT)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join()
        self._process = None

    @property
    def alive(self) -> bool:
        """Whether the loop process is running."""
        return self._process is not None and self._process.is_alive()

    @property
    def pid(self) -> int | None:
        """The loop process's id (None before :meth:`start` has spawned it)."""
        return None if self._process is None else self._process.pid

    def ended(self) -> str | None:
        """Why the loop process ended although it was never stopped ("killed by SIGKILL", "exit
        code 1"); None while it runs, before :meth:`start` and after :meth:`stop`."""
        process = self._process
        if process is None or process.is_alive():
            return None
        code = process.exitcode
        if code is not None and code < 0:
            try:
                return f"killed by {signal.Signals(-code).name}"
            except ValueError:  # a signal number Python does not name
                return f"killed by signal {-code}"
        return f"exit code {code}"

    def cpu_seconds(self) -> float | None:
        """CPU time (user + system, s) the loop process has used so far; None when it is not
        running or the system does not say (read from Linux's ``/proc``)."""
        if not self.alive:
            return None
        try:
            fields = Path(f"/proc/{self._process.pid}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return None

    # -- commands (any thread) ------------------------------------------------------------------

    def send(self, command: LoopCommand) -> None:
        """Send one command (applied before the loop's next tick); dropped if the loop process has
        ended (:meth:`ended`).

        Raises:
            UnknownCommand: ``command`` is not one of :data:`~app.web.commands.COMMANDS`.
        """
        check_command(command)
        if self.ended() is not None:
            # Nobody reads the pipe any more: once its buffer is full a send would block forever.
            return
        with self._send_lock:
            self._conn.send(command)

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Where the operator's hand pulls the grip (4, 4, device base {0}); None lets go."""
        self.send(SetHandTarget(None if T_0_H is None else T_0_H.astype(float)))

    def set_deadman(self, on: bool) -> None:
        self.send(SetDeadman(bool(on)))

    def set_reflection(self, on: bool) -> None:
        self.send(SetReflection(bool(on)))

    def press_reference(self) -> None:
        """A momentary press of the reference switch: on for exactly one tick (Sec 4.1)."""
        self.send(PressReference())

    @property
    def gains(self) -> ControllerGains:
        """The gains most recently set (possibly not yet applied by the loop)."""
        return self._gains

    def set_gains(self, gains: ControllerGains) -> None:
        self._gains = gains
        self.send(SetGains(gains))

    def reset(self) -> None:
        """Device and slave home, switches off; the hand keeps holding its current target."""
        self.send(Reset())

    def start_recording(self, directory: Path) -> None:
        """Write the per-tick log (the same Parquet log as a headless session) into ``directory``."""
        self.send(Record(directory))

    def stop_recording(self) -> None:
        self.send(Record(None))

    def play(self, session: Session, record: Path | None = None) -> None:
        """Reset and play ``session``'s operator script in real time (optionally logging exactly its ticks).

        Raises:
            ConfigError: the session has no file, or needs another loop (scene, device, hand,
                accommodation or rate) than this one runs.
        """
        if session.path is None:
            raise ConfigError("<session>", "path", "a played session must come from a file")
        wanted, have = LoopConfig.from_session(session), self.config
        for name in ("hand", "accommodation", "servo_rate"):
            if getattr(wanted, name) != getattr(have, name):
                raise ConfigError(session.path, name, "differs from the running loop's: rebuild the loop for it")
        if wanted.scene.path != have.scene.path or wanted.device.path != have.device.path:
            raise ConfigError(session.path, "scene", "scene or device differs from the running loop's")
        self._gains = session.gains
        self.send(Play(session.data, session.gains, session.path, record))

    def pause(self, on: bool) -> None:
        """Hold the loop (simulated time stops) or let it run again."""
        self.send(Pause(bool(on)))

    def set_speed(self, factor: float) -> None:
        """Simulated seconds per wall-clock second, 0.1 to 4 (InvalidField outside)."""
        self.send(SetSpeed(float(factor)))

    def set_passivity(self, settings: PassivitySettings) -> None:
        self.send(SetPassivity(settings))

    def set_channel(self, settings: ChannelSettings) -> None:
        self.send(SetChannel(settings))

    def stop_playing(self) -> None:
        """Stop a playing script (the loop goes on from where it is)."""
        self.send(Play(None))

    # -- state (any thread) ---------------------------------------------------------------------

    @property
    def snapshot(self) -> Snapshot:
        """The latest snapshot (the loop's initial state until the process publishes)."""
        return self._snapshot.read() or self._initial

    @property
    def scheduling(self) -> str:
        """The scheduling the loop process obtained (see :data:`~app.session.pacer.SCHEDULING`)."""
        return SCHEDULING[int(self._timing.scheduling.value)]

    def stats(self, last: int | None = None) -> TimingStats:
        """Timing over the last ``last`` periods (default: all kept, up to ``TIMING_HISTORY``)."""
        return timing_stats(self._rings, round(self.loop.dt * 1e9), last)
