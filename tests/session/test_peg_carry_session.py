"""sessions/peg_carry.toml played whole: the script's grip events close the slave tool's grip on the
free peg, carry it and let it go in its hole (the paper's task, Sec 4.3, with a free peg). Known
answers from the fit and the scene's geometry, the figures of tests/world/test_peg_carry.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.session import load_session, run_session
from app.session.loop import LoopConfig, ServoLoop
from app.world.assets import HOLE_RADIUS, PEG_RADIUS
from app.world.scene import load_scene


def test_the_session_carries_the_peg_into_the_hole() -> None:
    result = run_session(load_session("peg_carry"), plots=False)
    s = result.summary
    assert s["grips"] == [
        {"t": pytest.approx(1.201), "grip": True, "held": "peg", "note": "holds peg"},
        {"t": pytest.approx(5.0), "grip": False, "held": None, "note": "opened"},
    ]
    assert s["faults"] == {}
    # Let go in the bore: its axis within the radial clearance of the hole's (the collar is
    # centred on the origin), its end on the table 25 mm down (the peg's centre at half its 50 mm
    # length; MuJoCo's soft contact sinks it a few micrometres), upright.
    x, y, z, *quat = result.loop.slave.object_poses()[0]
    assert math.hypot(x, y) <= HOLE_RADIUS - PEG_RADIUS
    assert z - 0.025 == pytest.approx(0.0, abs=2e-5)
    tilt = 2.0 * math.acos(min(1.0, abs(quat[0])))
    assert tilt < math.radians(0.5)
    assert result.loop.slave.grip(False) == -1  # opened: nothing held


@pytest.mark.parametrize(
    ("scene", "note"), [("probe", "no dynamic objects in the scene"), ("peg_carry", "nothing touched")]
)
def test_a_grip_with_nothing_to_hold_holds_nothing_and_says_why(scene: str, note: str) -> None:
    """probe has no dynamic object; peg_carry's tool starts 1 cm over the peg."""
    session = load_session("peg_carry")
    loop = ServoLoop(LoopConfig.from_session(session, scene=load_scene(scene)))
    loop.tick()
    event = loop.set_grip(True)
    assert (event.held, event.note, event.t) == (None, note, pytest.approx(0.001))
    assert loop.slave.grip(False) == -1
    loop.tick()
    assert np.isfinite(loop.record.ft.wrench_S).all()
    loop.reset()
    assert loop.grips == []
