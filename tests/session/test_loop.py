"""The servo loop with the real controller on each device: gravity hold, reflection, 7-dof."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.controller.types import Fault
from app.device.spec import available_devices, load_device
from app.session.loop import LoopConfig, ServoLoop
from app.session.spec import load_session
from app.world.scene import load_scene


def make_loop(device: str, scene: str = "probe") -> ServoLoop:
    spec = load_device(device)
    session = load_session("probe_rate")
    return ServoLoop(LoopConfig(spec, load_scene(scene), spec.data.gains, session.data.hand))


#: Devices the controller drives joint by joint (a Cartesian device's SDK compensates its own
#: gravity: tests/device/test_cartesian.py).
JOINT_DEVICES = [name for name in available_devices() if load_device(name).data.interface == "joint"]


@pytest.mark.parametrize("device", JOINT_DEVICES)
@pytest.mark.parametrize("offset", [0.0, 0.25])
def test_released_device_holds_its_pose_on_gravity_compensation(device: str, offset: float) -> None:
    """Deadman off, hand released: the controller's tau_G alone keeps the grip within 1 mm and 1 deg
    for 5 s of simulated time (the paper: gravity compensation works without the deadman)."""
    loop = make_loop(device)
    q0 = np.array(loop.config.device.data.home) + offset * np.cos(np.arange(loop.config.device.n_joints))
    loop.plant.reset(q0)
    loop.controller.reset(q0)
    loop.set_hand_target(None)
    T0 = loop.plant.reading.T_0_G.copy()
    worst_p = worst_r = 0.0
    for _ in range(5000):
        out = loop.tick().out
        assert out.faults == Fault.NONE
        T = loop.plant.reading.T_0_G
        worst_p = max(worst_p, float(np.linalg.norm(T[0:3, 3] - T0[0:3, 3])))
        c = (np.trace(T0[0:3, 0:3].T @ T[0:3, 0:3]) - 1) / 2
        worst_r = max(worst_r, math.acos(min(1.0, max(-1.0, c))))
    assert worst_p < 1e-3
    assert worst_r < math.radians(1.0)


def test_without_gravity_compensation_the_kraft_device_falls() -> None:
    loop = make_loop("kraft")
    loop.set_gains(loop.config.gains.with_changes(gravity_compensation=False))
    loop.set_hand_target(None)
    T0 = loop.plant.reading.T_0_G.copy()
    for _ in range(1000):
        loop.tick()
    assert np.linalg.norm(loop.plant.reading.T_0_G[0:3, 3] - T0[0:3, 3]) > 0.05


def test_redundant_freflex_reflects_a_contact_through_seven_joints() -> None:
    """End to end on the 7-dof exoskeleton: push the probe into the surface, feel it in all joints."""
    loop = make_loop("freflex")
    T_target = loop.plant.reading.T_0_G.copy()
    T_target[2, 3] -= 0.03
    loop.set_hand_target(T_target)
    loop.switches.deadman = loop.switches.reflection = True
    for _ in range(3000):
        out = loop.tick().out
    assert loop.slave.contact.count > 0
    assert out.G_F_T[2] > 1.0  # the surface pushes the tool (and the hand) up
    assert out.tau_T.shape == (7,)
    assert np.count_nonzero(np.abs(out.tau_T) > 1e-6) >= 5


def test_after_a_reset_the_plant_is_sent_no_counts_and_the_ticks_repeat_a_fresh_loops() -> None:
    """The loop hands the plant the controller's own counts buffer (no copy a tick): a reset must
    still send zero counts on the next tick, although the controller's output keeps the last
    tick's. With the hand let go, the reset loop's next 200 ticks equal a new loop's, bit for bit."""
    loop = make_loop("kraft")
    loop.set_hand_target(None)
    for _ in range(300):
        loop.tick()
    assert np.any(loop.controller.out.counts != 0)  # gravity compensation drives the motors
    loop.reset()
    assert loop.counts.tolist() == [0] * loop.config.device.n_joints
    assert np.any(loop.controller.out.counts != 0)
    fresh = make_loop("kraft")
    fresh.set_hand_target(None)
    for _ in range(200):
        a, b = loop.tick(), fresh.tick()
        assert a.reading.q.tolist() == b.reading.q.tolist()
        assert a.out.counts.tolist() == b.out.counts.tolist()
