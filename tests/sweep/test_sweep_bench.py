"""The figures of ``frhc bench sweep``: per-point overhead as the gaps between sessions on a worker."""

from __future__ import annotations

import os

import pytest

from app.sweep.bench import Timed, gaps


def test_gaps_are_measured_per_worker_between_consecutive_sessions() -> None:
    rows = [
        {"_pid": 1, "_t0": 0.0, "_t1": 1.0},
        {"_pid": 2, "_t0": 0.5, "_t1": 2.0},
        {"_pid": 1, "_t0": 1.25, "_t1": 3.0},
        {"_pid": 2, "_t0": 2.5, "_t1": 4.0},
        {"_pid": 1, "_t0": 3.0, "_t1": 3.5},
    ]
    assert sorted(gaps(rows)) == pytest.approx([0.0, 0.25, 0.5])


def test_timed_adds_its_worker_and_times_to_the_row() -> None:
    row = Timed(lambda n: {"n": n})(3)
    assert row["n"] == 3
    assert row["_pid"] == os.getpid()
    assert row["_t1"] >= row["_t0"]
    assert row["_cpu_s"] >= row["_thread_cpu_s"] >= 0.0
