"""Benchmarks behind ``frhc bench``: each prints medians and p99 of the hot paths.

Speed goals live here, not in timed tests: the figures depend on the machine.
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.session.loop import STAGES


def _stats(ns: np.ndarray) -> str:
    us = ns / 1000.0
    return f"median {np.median(us):8.1f} us   p99 {np.percentile(us, 99):8.1f} us   (n={len(us)})"


def bench_controller(quick: bool = False) -> str:
    """Controller step on the Kraft-like device, rate mode, reflecting a contact, >= 10k steps."""
    from app.controller.frhc import FRHCController
    from app.controller.types import FTReading, Switches
    from app.device.spec import load_device
    from app.world.scene import load_scene
    from app.world.slave import VirtualSlave

    device = load_device("kraft")
    slave = VirtualSlave(load_scene("probe")).slave_model()
    ctrl = FRHCController(device, device.data.gains, slave)
    n = 3000 if quick else 20000
    rng = np.random.default_rng(0)
    q0 = np.array(device.data.home)
    walk = q0 + np.cumsum(rng.normal(scale=2e-4, size=(n, device.n_joints)), axis=0) + 0.05
    ft = FTReading(wrench_S=np.array([0.5, -0.2, 4.0, 0.01, 0.02, 0.0]))
    sw = Switches(deadman=True, reflection=True)
    ns = np.empty(n, dtype=np.int64)
    for i in range(n):
        t0 = time.perf_counter_ns()
        ctrl.step(walk[i], sw, ft, 1e-3)
        ns[i] = time.perf_counter_ns() - t0
    return f"controller step (kraft, rate mode, reflecting): {_stats(ns)}"


def bench_tick(quick: bool = False) -> str:
    """Whole servo tick per stage, scripted probing on the default scene and the large mesh."""
    from app.session.run import run_session
    from app.session.spec import load_session

    lines = ["servo tick per stage (headless, no logging):"]
    for scene in ("probe", "large_mesh"):
        session = load_session("probe_rate").with_changes(scene=scene, duration=1.5 if quick else 5.0)
        s = run_session(session, out_dir=None).summary
        lines.append(f"  scene {scene}: contact fraction {s['contact_fraction']:.2f}")
        for name in STAGES:
            t = s["timing"][name]
            lines.append(f"    {name:<11} median {t['median_us']:8.1f} us   p99 {t['p99_us']:8.1f} us")
        lines.append(f"    real-time factor at 1 kHz (1 ms / median tick): {s['real_time_factor']:.1f}")
    return "\n".join(lines)


def bench_arm(quick: bool = False) -> str:
    """Arm slaves (issue 15 bars): slave step alone, then the whole tick on ``probe`` with each arm."""
    from app.controller.types import SlaveCommand
    from app.session.run import run_session
    from app.session.spec import load_session
    from app.world.scene import load_scene, with_slave
    from app.world.slave_api import make_slave

    lines = ["slave step (probe, rate command down onto the surface, NTRFC on; first 500 steps not timed):"]
    n = 3000 if quick else 20000
    command = SlaveCommand(active=True, mode="rate", twist=np.array([0.01, 0.0, -0.02, 0.0, 0.0, 0.1]))
    for kind in ("tool", "puma560", "redundant7"):
        slave = make_slave(with_slave(load_scene("probe"), kind))
        ns = np.empty(n, dtype=np.int64)
        for i in range(n + 500):
            t0 = time.perf_counter_ns()
            slave.step(command)
            if i >= 500:
                ns[i - 500] = time.perf_counter_ns() - t0
        lines.append(f"  {kind:<11} {_stats(ns)}")
    lines.append("servo tick with an arm (probe_rate session, headless, no logging):")
    for kind in ("puma560", "redundant7"):
        session = load_session("probe_rate").with_changes(slave=kind, duration=1.5 if quick else 5.0)
        s = run_session(session, out_dir=None).summary
        t = s["timing"]
        lines.append(
            f"  {kind:<11} slave median {t['slave']['median_us']:6.1f} us, tick median {t['tick']['median_us']:6.1f} us "
            f"(p99 {t['tick']['p99_us']:7.1f} us), real-time factor {s['real_time_factor']:.1f}"
        )
    return "\n".join(lines)


def bench_stability(quick: bool = False) -> str:
    """Whole-loop contact stability: surface stiffness sweep (rate mode) and felt stiffness (pose mode).

    In pose mode the operator feels roughly ``K_T K_P k_s``, with ``k_s`` the slave's tracking
    spring in series with the surface; the sampled-data passivity bound for a virtual wall is
    ``K < 2 b / T`` with b the physical damping at the grip (device joints plus the hand).
    """
    from app.device.plant import DevicePlant
    from app.device.spec import load_device
    from app.session.spec import load_session
    from app.session.stability import press

    session = load_session("probe_rate")
    kp = session.scene.spec.slave.kp_lin
    k_p = session.gains.k_p[2]
    plant_model = DevicePlant(load_device("kraft")).model
    b_device = float(np.max(plant_model.dof_damping)) / 0.25**2  # joint damping over a ~25 cm lever
    b = b_device + session.data.hand.damping_trans
    lines = ["contact stability, probe pushed 3 cm by the hand, reflection on (settled: ripple < 5 % of mean)"]
    stiffnesses = (3e3, 3e4, 3e5) if quick else (3e3, 1e4, 3e4, 1e5, 3e5, 1e6)
    for k in stiffnesses:
        r = press(k, "rate")
        lines.append(
            f"  rate mode, surface {k:9.0f} N/m: force {r.mean_force:7.2f} N, ripple {r.ripple:8.3f} N, "
            f"{'settled' if r.settled else 'OSCILLATES'}"
        )
    k_surface = 1e5
    k_series = kp * k_surface / (kp + k_surface)
    lines.append(
        f"  passivity bound 2b/T with b = {b:.1f} N s/m (device ~{b_device:.1f} + hand): {2 * b / 1e-3:,.0f} N/m"
    )
    for k_t in (1.0, 4.0, 16.0) if quick else (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        r = press(k_surface, "pose", gains={"k_t": [k_t] * 3 + [1.0] * 3})
        felt = k_t * k_p * k_series
        lines.append(
            f"  pose mode, K_T {k_t:4.0f}: felt stiffness ~{felt:9,.0f} N/m ({felt / (2 * b / 1e-3):4.2f} x bound), "
            f"ripple {r.ripple:8.3f} N, {'settled' if r.settled else 'OSCILLATES'}"
        )
    return "\n".join(lines)


@dataclass(frozen=True)
class _Timed:
    """A sweep task that also reports where its worker spent the point (picklable, for Ray).

    Adds to the row the worker's process id ``_pid``, the wall-clock times (s, ``time.time``:
    one clock for every process of the machine) ``_t0`` and ``_t1`` when the session started and
    ended, ``_busy_s = _t1 - _t0`` and the process's CPU time meanwhile ``_cpu_s`` (s). The gaps
    between one session's end and the next one's start on the same worker are what the engine costs.
    """

    task: Callable[[Any], dict[str, Any]]

    def __call__(self, payload: Any) -> dict[str, Any]:
        t0, cpu = time.time(), time.process_time()
        row = self.task(payload)
        t1 = time.time()
        return {
            **row,
            "_pid": os.getpid(),
            "_t0": t0,
            "_t1": t1,
            "_busy_s": t1 - t0,
            "_cpu_s": time.process_time() - cpu,
        }


def _gaps(rows: list[dict[str, Any]]) -> list[float]:
    """Wall time (s) each worker spent between the end of one of its sessions and the start of the next."""
    gaps = []
    for pid in {r["_pid"] for r in rows}:
        mine = sorted((r["_t0"], r["_t1"]) for r in rows if r["_pid"] == pid)
        gaps += [start - end for (_, end), (start, _) in itertools.pairwise(mine)]
    return gaps


def bench_sweep(quick: bool = False) -> str:
    """Sweep throughput: a fixed sweep of short probe sessions with ``--workers 1`` (serially, in
    this process) and with 2 Ray workers, in one run.

    Start-up (starting Ray and its workers; each worker's first points, which import the package
    and load the numba cache) is timed apart from the steady state, on two extra points per
    worker. The serial run is split around the Ray run (first half before, second half after)
    so that a change of load from other processes weighs on both alike. Ray's per-point overhead
    is the wall time a worker spends between two sessions (the remote call, pickling the row and
    the next payload); the tail is the time the first worker to finish waits for the last. The CPU share (CPU time over wall time inside sessions) shows how
    much of a core each session got: below 1 the machine is shared and no engine can reach 2x.
    """
    import tempfile
    from pathlib import Path

    from app.sweep import load_sweep
    from app.sweep.engine import Engine, run_one
    from app.sweep.run import SweepPoint

    n = 12 if quick else 40
    workers = 2
    warm = 2 * workers
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_text(
            f'base = "probe_rate"\nsamples = {n + warm}\nseed = 1\n'
            '[[vary]]\nfield = "scene.objects.surface.stiffness"\nrange = [1000.0, 20000.0]\nlog = true\n'
            '[[vary]]\nfield = "duration"\nvalues = [0.5]\n'
        )
        plan = load_sweep(path)
    task = _Timed(SweepPoint(plan))
    points = list(enumerate(plan.points()))
    measured = points[warm:]
    load_before = os.getloadavg()[0]

    serial: dict[int, dict[str, Any]] = {}

    def run_serial(part: list[tuple[int, Any]]) -> float:
        t0 = time.perf_counter()
        serial.update((index, run_one(task, payload)) for index, payload in part)
        return time.perf_counter() - t0

    for _, payload in points[:warm]:
        task(payload)  # this process's own warm-up: imports, numba cache, lru caches
    serial_s = run_serial(measured[: n // 2])

    t0 = time.perf_counter()
    with Engine(workers) as engine:
        t_start = time.perf_counter()
        list(engine.run(task, points[:warm]))
        t_warm = time.perf_counter()
        on_ray = dict(engine.run(task, measured))
        t_end = time.perf_counter()
    serial_s += run_serial(measured[n // 2 :])
    load_after = os.getloadavg()[0]

    def strip(rows: dict[int, dict[str, Any]]) -> dict[int, dict[str, Any]]:
        return {k: {c: v for c, v in r.items() if not c.startswith("_")} for k, r in rows.items()}

    def share(rows: dict[int, dict[str, Any]]) -> float:
        return sum(r["_cpu_s"] for r in rows.values()) / sum(r["_busy_s"] for r in rows.values())

    steady = t_end - t_warm
    rate_serial, rate_ray = n / serial_s, n / steady
    rate_whole = n / (t_end - t0)
    gaps = _gaps(list(on_ray.values()))
    ends = [max(r["_t1"] for r in on_ray.values() if r["_pid"] == pid) for pid in {r["_pid"] for r in on_ray.values()}]
    cpu = {name: sum(r["_cpu_s"] for r in rows.values()) / n for name, rows in (("serial", serial), ("ray", on_ray))}
    same = "same rows as serial" if strip(on_ray) == strip(serial) else "ROWS DIFFER from serial"
    return "\n".join(
        [
            f"sweep throughput, {n} probe sessions of 0.5 s, on {os.cpu_count()} cores "
            f"(load average {load_before:.1f} before, {load_after:.1f} after):",
            f"  --workers 1 (serially, in this process): {rate_serial:6.2f} sessions/s, "
            f"{cpu['serial'] * 1e3:.0f} ms CPU and CPU share {share(serial):.2f} per session",
            f"  2 Ray workers, steady state:             {rate_ray:6.2f} sessions/s, "
            f"{cpu['ray'] * 1e3:.0f} ms CPU and CPU share {share(on_ray):.2f} per session ({same})",
            f"  speed-up, 2 workers / 1 (steady state):  {rate_ray / rate_serial:.2f}x",
            f"  Ray start-up: {t_start - t0:.1f} s to start Ray and its workers, {t_warm - t_start:.1f} s for the "
            f"first {warm} points (imports, numba cache); with it, {rate_whole:.2f} sessions/s "
            f"({rate_whole / rate_serial:.2f}x)",
            f"  Ray overhead per point (a worker's wall time between two sessions): median "
            f"{np.median(gaps) * 1e3:.1f} ms, max {max(gaps) * 1e3:.1f} ms; idle tail at the end "
            f"{max(ends) - min(ends):.2f} s",
        ]
    )


def _plant(quick: bool) -> str:
    from app.device.bench import run

    return run(quick=quick)


def _contact(quick: bool) -> str:
    from app.world.bench import run

    return run(quick=quick)


BENCHES: dict[str, Callable[[bool], str]] = {
    "controller": bench_controller,
    "plant": _plant,
    "contact": _contact,
    "tick": bench_tick,
    "arm": bench_arm,
    "stability": bench_stability,
    "sweep": bench_sweep,
}


def run(what: str = "all", quick: bool = False) -> str:
    """Run one benchmark (or ``"all"``) and return its report."""
    names = list(BENCHES) if what == "all" else [what]
    return "\n\n".join(BENCHES[name](quick) for name in names)
