"""The pacer holds a loop to its period without holding the CPU for whole periods."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from app.session import pacer as pacer_module
from app.session.log import TickLog
from app.session.pacer import BACKGROUND_NICE, SPIN_NS, Pacer


@pytest.mark.parametrize("rate", [1000.0, 4000.0])
def test_a_wait_spins_at_most_its_share_of_the_period(rate: float, monkeypatch: pytest.MonkeyPatch) -> None:
    """A loop under real-time scheduling that spins whole periods is throttled by Linux for 50 ms
    a second (sched_rt_runtime_us): so even at 4 kHz, where every wait is shorter than the 1 kHz
    spin of SPIN_NS, the pacer sleeps first and spins at most half a period (median
    over the waits; a preempted spin only looks longer)."""
    last_sleep_end = [0]
    real_sleep = time.sleep

    def recording_sleep(seconds: float) -> None:
        real_sleep(seconds)
        last_sleep_end[0] = time.perf_counter_ns()

    monkeypatch.setattr(pacer_module.time, "sleep", recording_sleep)
    period_ns = round(1e9 / rate)
    pacer = Pacer(1.0 / rate)
    spins = []
    for _ in range(400):
        before = time.perf_counter_ns()
        pacer.wait()
        started = time.perf_counter_ns()
        if started - before >= 0.8 * period_ns:  # an idle wait (a late loop's catch-up waits are ~0)
            spins.append(started - max(before, last_sleep_end[0]))
        pacer.done()
    assert len(spins) >= 20
    budget = min(SPIN_NS, 0.5 * period_ns)  # half of an idle period is slept at least
    assert np.median(spins) <= budget + 20_000


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a thread's niceness is Linux's")
def test_the_logs_writer_runs_at_the_lowest_niceness(tmp_path: Path) -> None:
    """The writer shares an unpaced loop's CPU: at nice 0 its part writes stalled the loop for
    milliseconds. After a part is written, the thread that wrote it is at BACKGROUND_NICE under
    the ordinary policy (read from /proc), and the loop's thread kept its own niceness."""
    own = os.getpriority(os.PRIO_PROCESS, 0)
    log = TickLog(tmp_path / "log", 3)
    writers: list[int] = []
    try:
        log._writer.submit(lambda: writers.append(threading.get_native_id())).result()
        stat = Path(f"/proc/self/task/{writers[0]}/stat").read_text().rsplit(")", 1)[1].split()
        # Fields 19 (nice) and 41 (policy) of proc(5), counted after the command name.
        assert int(stat[16]) == BACKGROUND_NICE
        assert int(stat[38]) == os.SCHED_OTHER
    finally:
        log.close()
    assert os.getpriority(os.PRIO_PROCESS, 0) == own
