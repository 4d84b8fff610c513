"""The free peg of scenes/peg_carry.toml taken in the grip, carried and lowered into its hole
(the paper's task, Sec 4.3, with a free peg): known answers from the peg's weight and the fit.

The tool is kinematic (its pose and twist prescribed, as a stiff slave would hold them); the
world's contact, grip and MuJoCo's collision of the peg with the table and the bore are the real
code.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from app.world.assets import HOLE_RADIUS, PEG_RADIUS
from app.world.dynamics import MovingWorld
from app.world.scene import load_scene

DT = 1e-3
TOP = 0.05 + 0.005 - 0.0003  # the tip's centre with the 5 mm tip 0.3 mm into the peg's top face
# The tip's path: (time (s), position (m)); the grip closes at 0.5 s and opens at 4.0 s.
PATH = (
    (0.0, (0.06, 0.0, 0.065)),
    (0.3, (0.06, 0.0, TOP)),
    (0.5, (0.06, 0.0, TOP)),
    (1.0, (0.06, 0.0, TOP + 0.035)),  # lifted 35 mm: the peg's end 10 mm over the 25 mm collar
    (2.0, (5e-5, 0.0, TOP + 0.035)),  # over the hole, 50 um off its axis (the clearance is 102.5 um)
    (2.5, (5e-5, 0.0, TOP + 0.035)),
    (3.5, (5e-5, 0.0, TOP + 1e-4)),  # lowered 35 mm: the peg's end on the table in the bore
    (4.0, (5e-5, 0.0, TOP + 1e-4)),
    (4.5, (5e-5, 0.0, TOP + 0.02)),  # the tool lifted away
)
GRIP, RELEASE = 0.5, 4.0


def _tip(t: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose and twist of {MRF} at time t on PATH (straight segments at constant speed)."""
    T = np.eye(4)
    for (t0, p0), (t1, p1) in itertools.pairwise(PATH):
        if t <= t1:
            a, b = np.array(p0), np.array(p1)
            T[0:3, 3] = a + (t - t0) / (t1 - t0) * (b - a)
            return T, np.concatenate([(b - a) / (t1 - t0), np.zeros(3)])
    T[0:3, 3] = PATH[-1][1]
    return T, np.zeros(6)


def test_the_peg_is_carried_with_its_weight_felt_and_lowered_into_the_hole() -> None:
    scene = load_scene("peg_carry")
    world = MovingWorld(scene, DT)
    peg = scene.bodies[0]
    world.wrench(*_tip(0.0))
    assert world.grip(True) == -1  # the tip 1 cm above the peg: nothing to hold
    carried, rest, held = [], [], -2
    for i in range(5500):
        t = i * DT
        if i == round(GRIP / DT):
            held = world.grip(True)
        if i == round(RELEASE / DT):
            assert world.grip(False) == -1
        T, V = _tip(t)
        result = world.wrench(T, V)
        world.step(DT)
        if 2.1 <= t < 2.5:  # held still over the hole
            carried.append(result.force_w)
        if t >= 4.6:  # let go, the tool away
            rest.append(world.poses()[0][0:3, 3])
    assert held == 0  # the peg, which the tip touched
    assert world.held == -1
    # Held still, the grip carries the peg's weight: the tool feels m g down, nothing else.
    assert np.mean(carried, axis=0) == pytest.approx([0.0, 0.0, -peg.mass * 9.81], rel=1e-3, abs=1e-6)
    # In the hole: its axis within the radial clearance of the hole's, its end on the table 25 mm
    # down the bore (MuJoCo's soft contact sinks it a few micrometres), upright, and staying
    # there (MuJoCo's cylinder on a flat face rocks at a few mrad/s: it moved 0.7 um, measured).
    T_peg = world.poses()[0]
    assert math.hypot(T_peg[0, 3], T_peg[1, 3]) <= HOLE_RADIUS - PEG_RADIUS
    assert T_peg[2, 3] - 0.025 == pytest.approx(0.0, abs=2e-5)
    assert T_peg[2, 2] > math.cos(math.radians(0.5))
    assert np.ptp(np.array(rest), axis=0).max() < 5e-6
