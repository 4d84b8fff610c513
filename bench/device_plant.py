"""Benchmark the simulated device plant: median and p99 step time per shipped device.

Run from the repository root:  .venv/bin/python bench/device_plant.py [--quick]
The goal is a median of at most 20 us per 1 kHz step (hand engaged) for the 6-dof devices.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.device.bench import run

if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv[1:]))
