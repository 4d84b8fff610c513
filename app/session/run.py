"""Run a headless scripted session: the Python API behind ``frhc run``.

Example::

    from app.session import load_session, run_session
    result = run_session(load_session("probe_rate"), out_dir=Path("runs/probe"))
    print(result.summary["work_eq13"])
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from app.session.log import TickLog, loop_meta, write_json
from app.session.loop import LoopConfig, ServoLoop
from app.session.metrics import SessionMetrics
from app.session.pacer import SCHEDULING, Pacer, raised_priority
from app.session.script import Operator, OperatorScript
from app.session.spec import Session
from app.session.tick import TickObserver, TickRecord


@dataclass
class SessionResult:
    """What a session produced.

    Attributes:
        summary: Work (Eq 13), contact statistics, task completion, faults, timing (JSON-able).
        log_dir: The Parquet log directory, if one was written.
        plots: PNG files written.
        loop: The servo loop in its final state (for further inspection).
    """

    summary: dict[str, Any]
    log_dir: Path | None
    plots: list[Path]
    loop: ServoLoop


def drive(loop: ServoLoop, operator: Operator, n_ticks: int, pacer: Pacer | None = None) -> Iterator[TickRecord]:
    """Run ``n_ticks`` ticks of ``loop`` with ``operator`` acting before each; yields each record.

    With a ``pacer`` the ticks are held to the wall clock.
    """
    act, tick = operator.before_tick, loop.tick
    if pacer is None:
        for _ in range(n_ticks):
            act(loop)
            yield tick()
        return
    pacer.restart()
    for _ in range(n_ticks):
        pacer.wait()
        act(loop)
        record = tick()
        pacer.done()
        yield record


def play(session: Session, loop: ServoLoop | None = None, pacer: Pacer | None = None) -> Iterator[TickRecord]:
    """Play ``session``'s operator script to its duration on ``loop`` (default: the session's own loop)."""
    loop = loop if loop is not None else ServoLoop(LoopConfig.from_session(session))
    return drive(loop, OperatorScript.for_loop(session.data, loop), session.data.n_ticks, pacer)


def run_session(
    session: Session,
    out_dir: Path | None = None,
    plots: bool = True,
    progress: bool = False,
    realtime: bool = False,
    flush_interval: float = 0.1,
    operator: Callable[[ServoLoop], Operator] | None = None,
    observers: Sequence[TickObserver] = (),
    device_url: str | None = None,
    sample_wait: float | None = None,
) -> SessionResult:
    """Run ``session`` to its duration.

    Args:
        session: A loaded session (:func:`app.session.spec.load_session`).
        out_dir: Where to write ``log/`` (Parquet parts), ``summary.json`` and plots; None = no files.
        plots: Write the PNG plots (needs ``out_dir``).
        progress: Show a progress bar.
        realtime: Pace ticks to the wall clock instead of running as fast as possible, at raised
            priority (:func:`~app.session.pacer.raise_priority`, for the ticks only); the
            summary then has the pacing figures under ``pacing`` and the scheduling obtained
            under ``scheduling``.
        flush_interval: Simulated seconds of ticks per write to the log: the most a crash can lose (s).
        operator: Makes the operator from the new loop (default: the session's script). An
            operator whose ``finished`` attribute turns true ends the session before its duration.
        observers: Further tick observers, added after the log and the metrics.
        device_url: Drive the device served at this ``ws://`` address (:mod:`app.device.haply`)
            instead of simulating it here; its device file is the one the server names.
        sample_wait: How long (s) to wait for that device's sample before the watchdog zeroes
            the force (default one servo period).
    """
    with _one_cpu():
        return _run(
            session, out_dir, plots, progress, realtime, flush_interval, operator, observers, device_url, sample_wait
        )


@contextmanager
def _one_cpu() -> Iterator[None]:
    """Keep this thread, and the threads it starts (the log's writer, the progress bar's monitor),
    on the CPU it is running on, for the duration; restore its CPUs after (Linux; elsewhere a no-op).

    Measured on a 2-core VM: a thread that wakes on the other CPU every 20-45 ms (the log writer
    handed a part every 100 ticks) slowed the loop's median tick from 21 to 47 us; with both on
    one CPU the tick is 21 us and the writer's share (~5 ms every 100 ms of ticks) is taken in
    turn. Each session runner pins to the CPU it already runs on, so parallel workers stay apart.
    """
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    allowed = os.sched_getaffinity(0)
    try:
        cpu = int(Path("/proc/thread-self/stat").read_text().rsplit(")", 1)[1].split()[36])
    except (OSError, ValueError, IndexError):
        cpu = -1
    if cpu not in allowed or len(allowed) == 1:
        yield
        return
    os.sched_setaffinity(0, {cpu})
    try:
        yield
    finally:
        os.sched_setaffinity(0, allowed)


def _run(
    session: Session,
    out_dir: Path | None,
    plots: bool,
    progress: bool,
    realtime: bool,
    flush_interval: float,
    operator: Callable[[ServoLoop], Operator] | None,
    observers: Sequence[TickObserver],
    device_url: str | None,
    sample_wait: float | None,
) -> SessionResult:
    device = None
    if device_url is not None:
        from app.device.haply import served_device

        device = served_device(device_url, session.device)
    loop = ServoLoop(LoopConfig.from_session(session, device=device, device_url=device_url, sample_wait=sample_wait))
    d = session.data
    n_ticks = d.n_ticks
    log = None
    if out_dir is not None:
        # Written by the metrics, in their compiled pass (the whole state row, then its logged
        # part); without a log the metrics write only the values they read (SessionMetrics.on_tick).
        meta = loop_meta(loop.config, session.path)
        log = TickLog(out_dir / "log", loop.controller.out.n, loop.dt, flush_interval, meta, loop.objects)
    metrics = loop.observe(SessionMetrics(loop.record, session.scene.spec.task, n_ticks, loop.dt, log))
    for observer in observers:
        loop.observe(observer)
    pacer = Pacer(loop.dt) if realtime else None
    bar = tqdm(total=n_ticks, unit="tick", disable=not progress, mininterval=0.5)
    actor = operator(loop) if operator is not None else OperatorScript.for_loop(d, loop)
    scheduling = None
    try:
        # A paced loop holds a device (in process, or one it drives over a link) to its period:
        # it keeps that period whatever else runs, as the web demo's loop process does.
        with raised_priority() if realtime else nullcontext(None) as got:
            scheduling = None if got is None else SCHEDULING[got]
            # A disabled bar's update and the look for a ``finished`` the operator lacks cost
            # ~0.3 us a tick between them: only what is there runs every tick.
            can_finish = hasattr(actor, "finished")
            for _ in drive(loop, actor, n_ticks, pacer):
                if progress:
                    bar.update(1)
                if can_finish and getattr(actor, "finished", False):
                    break
    finally:
        bar.close()
        loop.close()
        if log is not None:
            log.close()
    summary = metrics.summary()
    summary["session"] = str(session.path) if session.path else None
    summary["scene"] = session.scene.spec.name
    summary["device"] = loop.config.device.name
    summary["mode"] = d.mode
    summary["accommodation"] = d.accommodation
    summary["grips"] = [g.as_dict() for g in loop.grips]
    # Why the slave's readings were invalid at the end (its FT_INVALID ticks), or None.
    summary["slave_fault"] = loop.slave.fault
    # Why the simulated device stopped (its motors off since), or None; a real device reports
    # its own faults through the link's status.
    summary["device_fault"] = None if loop.plant is None else loop.plant.fault
    if pacer is not None:
        summary["pacing"] = pacer.stats().as_dict()
        summary["scheduling"] = scheduling
    written: list[Path] = []
    if out_dir is not None:
        write_json(out_dir / "summary.json", summary)
        if plots and log is not None:
            from app.session.plots import plot_session

            written = plot_session(log.directory, out_dir)
    return SessionResult(summary, log.directory if log else None, written, loop)
