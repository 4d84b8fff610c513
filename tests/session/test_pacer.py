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
from app.session.pacer import BACKGROUND_NICE, MAX_SPIN, SPIN_NS, Pacer


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


def test_a_pacer_told_to_spin_sleeps_only_the_rest_of_the_period(monkeypatch: pytest.MonkeyPatch) -> None:
    """``spin`` 0.8: an idle 1 ms period is slept for its first 0.2 ms and spun for the rest; by
    default all but SPIN_NS is slept. (A stand-in clock: each read advances 1 us, a sleep its length.)"""
    now = [0]
    slept: list[float] = []

    def clock() -> int:
        now[0] += 1_000
        return now[0]

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        now[0] += round(seconds * 1e9)

    monkeypatch.setattr(pacer_module.time, "perf_counter_ns", clock)
    monkeypatch.setattr(pacer_module.time, "sleep", sleep)
    for spin, asleep in ((0.8, 0.2e-3), (None, 1e-3 - SPIN_NS * 1e-9)):
        pacer = Pacer(1e-3, spin=spin)
        pacer.wait()  # the first tick starts at once
        pacer.done()
        slept.clear()
        pacer.wait()
        assert slept == [pytest.approx(asleep, abs=10e-6)]
    with pytest.raises(ValueError, match="spin must be a share"):
        Pacer(1e-3, spin=MAX_SPIN + 0.01)


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
