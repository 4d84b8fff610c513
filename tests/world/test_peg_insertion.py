"""The peg block as a physical insertion: its fit, its chamfer and its wall friction.

The answers follow from the geometry written in ``app/world/assets.py`` (H11/c11 clearance, a
45-degree chamfer) and the scene's friction coefficient, through the public contact model.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from app.world import load_scene
from app.world.assets import CHAMFER, HOLE_RADIUS, PEG_RADIUS, PEG_SPACING, RIM_RADIUS
from app.world.contact import ContactModel
from app.world.scene import Scene, build_scene
from tests.world_helpers import pose, sphere_tool

AXIS_X = PEG_SPACING / 2  # the right hole's axis


@pytest.fixture(scope="module")
def peg_block() -> Scene:
    """The shipped block (its stiffness and friction) with a one-sphere peg of the pegs' radius."""
    scene = load_scene("peg_in_hole")
    return build_scene(dataclasses.replace(scene.spec, tool=sphere_tool(PEG_RADIUS)))


def test_the_fit_is_h11_c11_and_the_chamfer_45_degrees() -> None:
    # Mean diametral clearance of H11/c11 at 12 mm: (95 + 315) / 2 um.
    assert pytest.approx(205e-6, abs=1e-9) == 2 * (HOLE_RADIUS - PEG_RADIUS)
    assert RIM_RADIUS - HOLE_RADIUS == CHAMFER


def test_a_centred_peg_in_the_bore_touches_nothing_and_one_off_by_more_than_the_clearance_does(
    peg_block: Scene,
) -> None:
    model = ContactModel(peg_block)
    k = peg_block.objects[0].stiffness
    assert model.wrench(pose((AXIS_X, 0.0, -0.015))).count == 0
    push = 50e-6  # 50 um into the wall, past the 102.5 um clearance
    model.reset()
    res = model.wrench(pose((AXIS_X + HOLE_RADIUS - PEG_RADIUS + push, 0.0, -0.015)))
    # The bore is a 256-gon whose inscribed radius is within 0.5 um of HOLE_RADIUS.
    assert res.force_w[0] == pytest.approx(-k * push, abs=k * 0.6e-6)
    assert abs(res.force_w[2]) < 1e-9


def test_the_chamfer_turns_a_downward_push_into_a_centring_one(peg_block: Scene) -> None:
    """A peg landing on the chamfer, half way across it, is pushed up and toward the axis
    equally (the 45-degree face's normal)."""
    model = ContactModel(peg_block)
    mid = (HOLE_RADIUS + RIM_RADIUS) / 2  # the chamfer face at z = -CHAMFER / 2
    n = np.array([-1.0, 0.0, 1.0]) / math.sqrt(2.0)
    depth = 0.2e-3
    centre = np.array([AXIS_X + mid, 0.0, -CHAMFER / 2]) + (PEG_RADIUS - depth) * n
    res = model.wrench(pose(tuple(centre)))
    assert res.count == 1
    np.testing.assert_allclose(res.normals_w[0], n, atol=2e-3)
    assert res.depths[0] == pytest.approx(depth, abs=1e-6)


def test_sliding_down_the_wall_meets_coulomb_friction(peg_block: Scene) -> None:
    """Pressed 50 um into the bore's wall and moving down at 10 mm/s (past the 1 mm/s
    regularisation), the peg feels mu times the normal force upward, against the insertion."""
    model = ContactModel(peg_block)
    k, mu = peg_block.objects[0].stiffness, peg_block.objects[0].friction
    assert mu == 0.47  # the scene's value (aluminium on mild steel, kinetic)
    push = 50e-6
    res = model.wrench(
        pose((AXIS_X + HOLE_RADIUS - PEG_RADIUS + push, 0.0, -0.015)), np.array([0, 0, -0.01, 0, 0, 0.0])
    )
    normal = -res.force_w[0]
    assert normal == pytest.approx(k * push, rel=0.02)
    assert res.force_w[2] == pytest.approx(mu * normal, rel=1e-9)
