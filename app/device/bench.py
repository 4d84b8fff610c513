"""Benchmark of the device plant step (with the operator's hand engaged), per shipped device.

Each device runs at 1 kHz with its hand spring pulling the grip toward a target 1 cm away and a
fresh command vector every step (a random walk in counts, generated before timing so that only
the plant is measured). Reported per step, in microseconds: median and 99th percentile of
``DevicePlant.step`` alone (what a servo loop calls), and of a step followed by reading the grip
pose and hand wrench (which are filled on access, for a UI or a log).
"""

from __future__ import annotations

import time

import numpy as np

from app.device.plant import DevicePlant
from app.device.spec import available_devices, load_device

DT = 0.001  # s: 1 kHz servo rate


def _time_device(name: str, steps: int) -> tuple[float, float, float, float]:
    spec = load_device(name)
    plant = DevicePlant(spec)
    T_0_H = plant.reading.T_0_G.copy()
    T_0_H[:3, 3] += [0.01, 0.0, 0.0]
    plant.set_hand_target(T_0_H)
    rng = np.random.default_rng(0)
    walk = np.cumsum(rng.integers(-20, 21, size=(steps, spec.n_joints)), axis=0)
    commands = np.clip(walk, -300, 300).astype(np.int64)
    for k in range(min(steps, 1000)):  # warm up caches and the branch predictor
        plant.step(commands[k], DT)
    plant.reset()
    step_ns = np.empty(steps)
    clock = time.perf_counter_ns
    for k in range(steps):
        t0 = clock()
        plant.step(commands[k], DT)
        step_ns[k] = clock() - t0
    plant.reset()
    full_ns = np.empty(steps)
    for k in range(steps):
        t0 = clock()
        reading = plant.step(commands[k], DT)
        _ = reading.T_0_G, reading.wrench_G
        full_ns[k] = clock() - t0
    if plant.warnings():
        raise RuntimeError(f"{name}: MuJoCo warnings during the benchmark: {plant.warnings()}")
    us = 1e-3
    return (
        float(np.median(step_ns)) * us,
        float(np.percentile(step_ns, 99)) * us,
        float(np.median(full_ns)) * us,
        float(np.percentile(full_ns, 99)) * us,
    )


def run(quick: bool = False) -> str:
    """Time the plant step of every shipped device; return a text table (microseconds per step).

    Args:
        quick: 2,000 steps per device instead of 20,000 (for smoke tests; the figures get noisier).
    """
    steps = 2_000 if quick else 20_000
    lines = [
        f"device plant step at 1 kHz with the hand engaged, {steps} steps per device (us)",
        f"{'device':10s} {'joints':>6s} {'median':>8s} {'p99':>8s} {'+read med':>10s} {'+read p99':>10s}",
    ]
    for name in available_devices():
        med, p99, full_med, full_p99 = _time_device(name, steps)
        n = load_device(name).n_joints
        lines.append(f"{name:10s} {n:6d} {med:8.1f} {p99:8.1f} {full_med:10.1f} {full_p99:10.1f}")
    return "\n".join(lines)
