"""Run a headless scripted session: the Python API behind ``frhc run``.

Example::

    from app.session import load_session, run_session
    result = run_session(load_session("probe_rate"), out_dir=Path("runs/probe"))
    print(result.summary["work_eq13"])
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from app.controller.frhc import ControllerOutput
from app.session.log import TickLog
from app.session.loop import LoopConfig, ServoLoop
from app.session.metrics import SessionMetrics
from app.session.script import OperatorScript
from app.session.spec import Session
from app.spatial import Array


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


def make_loop(session: Session) -> ServoLoop:
    d = session.data
    return ServoLoop(LoopConfig(session.device, session.scene, session.gains, d.hand, d.accommodation, d.servo_rate))


def drive(session: Session, loop: ServoLoop, realtime: bool = False) -> Iterator[tuple[ControllerOutput, Array | None]]:
    """Play the session's operator script on ``loop``, one tick per iteration.

    Yields the controller output and the hand target of each tick (None while the hand is off
    the grip). With ``realtime`` the ticks are paced to the wall clock.
    """
    d = session.data
    script = OperatorScript(d, loop.reading.T_0_G.copy())
    loop.switches = script.switches
    start = time.perf_counter()
    for tick in range(d.n_ticks):
        t = loop.time
        script.update_switches(t, tick)
        target = script.hand_target(t, tick) if script.hand_on else None
        loop.set_hand_target(target)
        yield loop.tick(), target
        if realtime:
            lag = start + (tick + 1) * loop.dt - time.perf_counter()
            if lag > 0:
                time.sleep(lag)


def run_session(
    session: Session,
    out_dir: Path | None = None,
    plots: bool = True,
    progress: bool = False,
    realtime: bool = False,
) -> SessionResult:
    """Run ``session`` to its duration.

    Args:
        session: A loaded session (:func:`app.session.spec.load_session`).
        out_dir: Where to write ``log/`` (Parquet parts), ``summary.json`` and plots; None = no files.
        plots: Write the PNG plots (needs ``out_dir``).
        progress: Show a progress bar.
        realtime: Pace ticks to the wall clock instead of running as fast as possible.
    """
    loop = make_loop(session)
    d = session.data
    n_ticks = d.n_ticks
    metrics = SessionMetrics(loop, n_ticks)
    log = TickLog(out_dir / "log", session.device.n_joints) if out_dir is not None else None
    bar = tqdm(total=n_ticks, unit="tick", disable=not progress, mininterval=0.5)
    try:
        for out, target in drive(session, loop, realtime):
            metrics.record(out)
            if log is not None:
                log.record(loop, out, target)
            bar.update(1)
    finally:
        bar.close()
        if log is not None:
            log.close()
    summary = metrics.summary()
    summary["session"] = str(session.path) if session.path else None
    summary["scene"] = session.scene.spec.name
    summary["device"] = session.device.name
    summary["mode"] = d.mode
    summary["accommodation"] = d.accommodation
    written: list[Path] = []
    if out_dir is not None:
        (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        if plots and log is not None:
            from app.session.plots import plot_session

            written = plot_session(log.directory, out_dir)
    return SessionResult(summary, log.directory if log else None, written, loop)
