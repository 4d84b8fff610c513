"""``frhc bench sweep``: sweep throughput with ``--workers 1`` and with 2 Ray workers, in one run.

A fixed sweep of short probe sessions (0.5 s simulated each) runs serially in this process and on
an :class:`~app.sweep.engine.Engine` of 2 Ray workers. What is reported, and why:

- Sessions per second in the steady state. Start-up (starting Ray and its workers, then each
  worker's first points, which import the package and load the numba cache) is timed apart, on
  two extra points per worker, and the rate with it is given too. The serial run is split around
  the Ray run (first half before, second half after) so that a change of load from other
  processes weighs on both alike.
- Ray's per-point overhead: the wall time a worker spends between the end of one session and the
  start of the next (the remote call, pickling the row and the next payload), and the idle tail
  (the first worker to finish waiting for the last).
- The cores each run got (CPU time over wall time) and the CPU time per session, split into the
  session's own thread and the process's other threads (Ray's, in a worker). On a machine shared
  with other work, Linux's autogroup scheduling gives one terminal session (this command and
  its Ray workers) one share of the CPUs however many processes it runs, so two workers may get
  no more cores than one process: the speed-up per core received is what the engine controls.
"""

from __future__ import annotations

import itertools
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.sweep.engine import Engine, run_one
from app.sweep.run import SweepPoint
from app.sweep.spec import load_sweep

Rows = dict[int, dict[str, Any]]

#: Ray workers of the parallel run (the issue's bar compares 2 with 1 on a 2-core machine).
WORKERS = 2


@dataclass(frozen=True)
class Timed:
    """A sweep task that also reports where its worker spent the point (picklable, for Ray).

    Adds to the row the worker's process id ``_pid``, the wall-clock times (s, ``time.time``:
    one clock for every process of the machine) ``_t0`` and ``_t1`` when the session started and
    ended, and the CPU time (s) meanwhile of the whole process ``_cpu_s`` and of the session's
    own thread ``_thread_cpu_s``.
    """

    task: Callable[[Any], dict[str, Any]]

    def __call__(self, payload: Any) -> dict[str, Any]:
        t0, cpu, thread_cpu = time.time(), time.process_time(), time.thread_time()
        row = self.task(payload)
        # The thread's clock is read inside the process's on both sides, so that the process's
        # interval contains the thread's (read the other way round, the thread could count more).
        thread_s = time.thread_time() - thread_cpu
        cpu_s = time.process_time() - cpu
        return {**row, "_pid": os.getpid(), "_t0": t0, "_t1": time.time(), "_cpu_s": cpu_s, "_thread_cpu_s": thread_s}


def gaps(rows: list[dict[str, Any]]) -> list[float]:
    """Wall time (s) each worker spent between the end of one of its sessions and the start of the next."""
    out = []
    for pid in {r["_pid"] for r in rows}:
        mine = sorted((r["_t0"], r["_t1"]) for r in rows if r["_pid"] == pid)
        out += [start - end for (_, end), (start, _) in itertools.pairwise(mine)]
    return out


def _plan(n: int) -> Any:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_text(
            f'base = "probe_rate"\nsamples = {n}\nseed = 1\n'
            '[[vary]]\nfield = "scene.objects.surface.stiffness"\nrange = [1000.0, 20000.0]\nlog = true\n'
            '[[vary]]\nfield = "duration"\nvalues = [0.5]\n'
        )
        return load_sweep(path)


def _cpu(rows: Rows) -> str:
    n = len(rows)
    total = sum(r["_cpu_s"] for r in rows.values()) / n
    other = total - sum(r["_thread_cpu_s"] for r in rows.values()) / n
    return f"{total * 1e3:.0f} ms CPU per session ({other * 1e3:.0f} ms of it in other threads)"


def _public(rows: Rows) -> Rows:
    return {k: {c: v for c, v in r.items() if not c.startswith("_")} for k, r in rows.items()}


def run(quick: bool = False) -> str:
    """Run the benchmark (12 points if ``quick``, else 40) and return its report."""
    n = 12 if quick else 40
    warm = 2 * WORKERS
    plan = _plan(n + warm)
    task = Timed(SweepPoint(plan))
    points = list(enumerate(plan.points()))
    measured = points[warm:]
    load_before = os.getloadavg()[0]

    serial: Rows = {}

    def run_serial(part: list[tuple[int, Any]]) -> float:
        t0 = time.perf_counter()
        serial.update((index, run_one(task, payload)) for index, payload in part)
        return time.perf_counter() - t0

    for _, payload in points[:warm]:
        task(payload)  # this process's own warm-up: imports, numba cache, lru caches
    serial_s = run_serial(measured[: n // 2])
    t0 = time.perf_counter()
    with Engine(WORKERS) as engine:
        t_start = time.perf_counter()
        list(engine.run(task, points[:warm]))
        t_warm = time.perf_counter()
        on_ray = dict(engine.run(task, measured))
        t_end = time.perf_counter()
    serial_s += run_serial(measured[n // 2 :])
    load_after = os.getloadavg()[0]

    steady = t_end - t_warm
    rate_serial, rate_ray, rate_whole = n / serial_s, n / steady, n / (t_end - t0)
    cores_serial = sum(r["_cpu_s"] for r in serial.values()) / serial_s
    cores_ray = sum(r["_cpu_s"] for r in on_ray.values()) / steady
    per_core = (rate_ray / cores_ray) / (rate_serial / cores_serial)
    between = gaps(list(on_ray.values()))
    ends = [max(r["_t1"] for r in on_ray.values() if r["_pid"] == pid) for pid in {r["_pid"] for r in on_ray.values()}]
    same = "same rows as serial" if _public(on_ray) == _public(serial) else "ROWS DIFFER from serial"
    return "\n".join(
        [
            f"sweep throughput, {n} probe sessions of 0.5 s, on {os.cpu_count()} cores "
            f"(load average {load_before:.1f} before, {load_after:.1f} after):",
            f"  --workers 1 (serially, in this process): {rate_serial:6.2f} sessions/s on {cores_serial:.2f} cores, "
            f"{_cpu(serial)}",
            f"  {WORKERS} Ray workers, steady state:             {rate_ray:6.2f} sessions/s on {cores_ray:.2f} cores, "
            f"{_cpu(on_ray)} ({same})",
            f"  speed-up {WORKERS} workers / 1: {rate_ray / rate_serial:.2f}x; per core received {per_core:.2f} "
            "(the cores are the scheduler's to give, the work per session is the engine's)",
            f"  Ray start-up: {t_start - t0:.1f} s to start Ray and its workers, {t_warm - t_start:.1f} s for the "
            f"first {warm} points (imports, numba cache); counting it, {rate_whole:.2f} sessions/s "
            f"({rate_whole / rate_serial:.2f}x)",
            f"  Ray overhead per point (a worker's wall time between two sessions): median "
            f"{np.median(between) * 1e3:.1f} ms, max {max(between) * 1e3:.1f} ms; idle tail at the end "
            f"{max(ends) - min(ends):.2f} s",
        ]
    )
