"""What the page is sent about a tick, without a browser."""

from __future__ import annotations

import numpy as np

from app.controller.types import SlaveCommand
from app.session.loop import LoopConfig, ServoLoop
from app.session.spec import load_session
from app.web.snapshot import take_snapshot
from app.world.arm import ArmStatus


def test_an_arm_out_of_reach_is_flagged_in_the_snapshot() -> None:
    """The PUMA pushed up past its reach: the tick's slave status (TRACKING) reaches the page's data."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate").with_changes(slave="puma560")))
    assert take_snapshot(loop.tick(), np.eye(4)).slave_status == ArmStatus.NONE
    up = SlaveCommand(active=True, mode="rate", twist=np.array([0.0, 0.0, 0.25, 0.0, 0.0, 0.0]))
    for _ in range(3000):
        loop.slave.step(up)
    snap = take_snapshot(loop.tick(), np.eye(4))
    assert ArmStatus(snap.slave_status) & ArmStatus.TRACKING
