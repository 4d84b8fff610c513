"""Benchmark of the virtual world's contact wrench and slave step (median and p99 per call).

Usage: ``python bench/world_contact.py [--quick]``. Prints a table; see :mod:`app.world.bench`
for the cases. Goals: median <= 40 us on the shipped scenes, a 1M-triangle mesh no more than
2x the 10k cost, far objects nearly free.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.world.bench import run

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer calls, no 1M-triangle mesh")
    print(run(quick=parser.parse_args().quick))
