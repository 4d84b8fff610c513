"""A simulated operator of your own that reacts to what it feels.

An operator is any object with ``before_tick(loop)`` (:class:`app.session.script.Operator`): it
reads the last tick's record and sets the hand target and the switches for the next tick. This one
holds the deadman with reflection on and pushes the grip down in rate mode until it *feels* 2 N at
the grip, then backs off: a force-controlling operator, where the shipped scripts are open-loop.

    .venv/bin/python examples/04_reacting_operator.py
"""

import os

import numpy as np

from app.session import load_session
from app.session.loop import LoopConfig, ServoLoop
from app.session.run import drive

FAST = bool(os.environ.get("FRHC_EXAMPLE_FAST"))
TARGET_FORCE = 2.0  # N, felt at the grip
PUSH_DEPTH = 0.03  # m below the start: outside the 1 cm deadband, so the tool moves down


class ForceSeekingOperator:
    """Pushes down while the felt force is below ``target`` (N), lifts the hand when above."""

    def __init__(self, loop: ServoLoop, target: float) -> None:
        self.target = target
        self.T_start = loop.reading.T_0_G.copy()
        self.hand = self.T_start.copy()
        self.depth = 0.0
        loop.switches.deadman = loop.switches.reflection = True

    def before_tick(self, loop: ServoLoop) -> None:
        felt = loop.record.out.G_F_T[2]  # N, upward at the grip
        step = 2e-5 if felt < self.target else -4e-5  # m per tick: slow in, quicker out
        self.depth = float(np.clip(self.depth + step, 0.0, PUSH_DEPTH))
        self.hand[2, 3] = self.T_start[2, 3] - self.depth
        loop.set_hand_target(self.hand)


session = load_session("probe_rate")
loop = ServoLoop(LoopConfig.from_session(session))
operator = ForceSeekingOperator(loop, TARGET_FORCE)
felt = np.array([tick.out.G_F_T[2] for tick in drive(loop, operator, 3000 if FAST else 8000)])
tail = felt[-1000:]
print(f"felt force over the last second: mean {tail.mean():.2f} N, range {tail.min():.2f} to {tail.max():.2f} N")
print(f"tool height {loop.record.T_w_MRF[2, 3] * 1000:.1f} mm (surface at 0, tip radius 5 mm)")
