"""Largest stable surface stiffness of the virtual slave, by simulation.

Usage: ``python bench/world_stability.py``. The probe tool is driven (pose mode) into the probe
surface with the default slave gains, for a sweep of surface stiffness k and contact damping b,
with the slave's PD either inside its force limit (target 2 mm into the surface) or saturated
(target 20 mm in: the PD then pushes a constant 40 N and adds no damping). A run "settles" when
the sensor's z force over the last 0.5 s of 3 s varies by less than 0.1 % of its mean. The
table also prints the passivity bound 2 b_total / T of a sampled spring with damping b_total.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.controller.types import SlaveCommand
from app.slave.tool import VirtualSlave
from app.world.scene import build_scene, load_scene

T_SERVO = 1e-3


def settles(k: float, b: float, target_depth: float, substeps: int = 1) -> tuple[bool, float]:
    """Run 3 s; return (settled, relative peak-to-peak of the z force over the last 0.5 s)."""
    spec = load_scene("probe").spec
    surface = dataclasses.replace(spec.objects[0], stiffness=k, damping=b)
    slave_gains = dataclasses.replace(spec.slave, substeps=substeps)
    scene = build_scene(dataclasses.replace(spec, objects=(surface,), slave=slave_gains))
    slave = VirtualSlave(scene, accommodation=False, period=T_SERVO)
    start = slave.T_w_MRF
    start[2, 3] = 0.0055  # tip 0.5 mm above the surface
    slave.reset(start)
    target = slave.T_w_MRF
    target[2, 3] = 0.005 - target_depth
    command = SlaveCommand(active=True, mode="pose", T_w_MRF=target)
    fz = np.array([slave.step(command, T_SERVO).wrench_S[2] for _ in range(3000)])
    tail = fz[-500:]
    if not np.isfinite(tail).all():
        return False, float("inf")
    rel = float(np.ptp(tail) / max(abs(tail.mean()), 1e-9))
    return rel < 1e-3, rel


def main() -> None:
    gains = load_scene("probe").spec.slave
    mass = load_scene("probe").tool.mass
    print(f"slave: kp_lin {gains.kp_lin} N/m, kd_lin {gains.kd_lin} N s/m, force limit {gains.force_limit} N, T = 1 ms")
    print(f"integrator bound 4 m / h^2 with m = {mass} kg: {4 * mass / T_SERVO**2:.3g} N/m at h = T")
    print(
        f"{'PD':>10} {'b (N s/m)':>10} {'substeps':>8} {'largest settled k':>18} {'first unsettled k':>18} {'2b_tot/T':>10}"
    )
    ks = (1e4, 1e5, 1e6, 1.5e6, 1.9e6, 2.1e6, 3e6, 8e6, 3e7, 1e8)
    for saturated, depth in (("linear", 0.002), ("saturated", 0.02)):
        for b in (3.0, 30.0):
            for substeps in (1, 4):
                good, bad = 0.0, float("nan")
                for k in ks:
                    ok, _ = settles(k, b, depth, substeps)
                    if not ok:
                        bad = k
                        break
                    good = k
                b_tot = b + (gains.kd_lin if saturated == "linear" else 0.0)
                print(f"{saturated:>10} {b:10.1f} {substeps:8d} {good:18.3g} {bad:18.3g} {2 * b_tot / T_SERVO:10.0f}")


if __name__ == "__main__":
    main()
