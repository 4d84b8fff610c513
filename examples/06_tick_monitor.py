"""A tick observer of your own: watch every servo tick of a session without touching the loop.

Each tick produces one read-only :class:`app.session.tick.TickRecord` (device reading, controller
output with its intermediates, slave command, F/T reading, contact, stage timings). The log and
the metrics are observers of it; so is this monitor, which tracks the largest torque saturation,
the peak force felt at the grip and the slowest tick.

    .venv/bin/python examples/06_tick_monitor.py
"""

import os

import numpy as np

from app.session import load_session
from app.session.loop import LoopConfig, ServoLoop
from app.session.run import play
from app.session.tick import TickRecord


class Monitor:
    """Peak felt force (N), lowest saturation scale and slowest tick (us), over a session."""

    def __init__(self) -> None:
        self.peak_felt = 0.0
        self.lowest_scale = 1.0
        self.slowest_us = 0.0
        self.contact_ticks = 0

    def on_tick(self, tick: TickRecord) -> None:
        out = tick.out
        self.peak_felt = max(self.peak_felt, float(np.linalg.norm(out.G_F_T[0:3])))
        self.lowest_scale = min(self.lowest_scale, out.saturation_scale)
        if tick.index > 1:  # the first tick loads the compiled kernels
            self.slowest_us = max(self.slowest_us, tick.stage_ns[-1] / 1000.0)
        self.contact_ticks += tick.contact.count > 0


session = load_session("peg_ntrfc")
if os.environ.get("FRHC_EXAMPLE_FAST"):
    session = session.with_changes(duration=3.0)
loop = ServoLoop(LoopConfig.from_session(session))
monitor = loop.observe(Monitor())
for _ in play(session, loop):
    pass
print(f"{loop.ticks} ticks, {monitor.contact_ticks} in contact")
print(f"peak force felt at the grip {monitor.peak_felt:.2f} N; lowest saturation scale {monitor.lowest_scale:.3f}")
print(f"slowest tick {monitor.slowest_us:.0f} us")
