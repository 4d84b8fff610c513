"""The contact-wrench API inside your own pytest tests.

``contact_wrench(scene, T_w_MRF)`` evaluates the tool of ``scene`` at one pose, with no session,
plant or controller: use it to pin a scene's contact behaviour by analytic answers. Run it with

    .venv/bin/python -m pytest examples/05_contact_wrench_test.py
"""

import numpy as np
import pytest

from app.spatial import make_pose, zyx_to_matrix
from app.world import contact_wrench
from app.world.scene import load_scene

STIFFNESS = 3000.0  # N/m, the probe surface (scenes/probe.toml)
TIP_RADIUS = 0.005  # m, the stylus tip sphere centred on {MRF}


@pytest.fixture(scope="module")
def probe():
    return load_scene("probe")


@pytest.mark.parametrize("depth", [0.0005, 0.001, 0.003])
def test_tip_pressed_into_the_surface_feels_stiffness_times_depth(probe, depth: float) -> None:
    T_w_MRF = make_pose(np.eye(3), np.array([0.02, -0.03, TIP_RADIUS - depth]))
    result = contact_wrench(probe, T_w_MRF)
    assert result.valid
    np.testing.assert_allclose(result.force_w, [0.0, 0.0, STIFFNESS * depth], atol=1e-9)
    np.testing.assert_allclose(result.depths, [depth], atol=1e-12)


def test_a_tilted_tool_is_pushed_along_the_surface_normal(probe) -> None:
    """The surface pushes along +z whatever the tool's orientation; {MRF} sees it rotated."""
    R = zyx_to_matrix(0.0, 0.3, 0.0)
    result = contact_wrench(probe, make_pose(R, np.array([0.0, 0.0, TIP_RADIUS - 0.002])))
    np.testing.assert_allclose(result.force_w, [0.0, 0.0, 6.0], atol=1e-9)
    np.testing.assert_allclose(result.wrench_MRF[0:3], R.T @ [0.0, 0.0, 6.0], atol=1e-9)


def test_no_force_above_the_surface(probe) -> None:
    result = contact_wrench(probe, make_pose(np.eye(3), np.array([0.0, 0.0, 0.02])))
    assert result.count == 0
    np.testing.assert_array_equal(result.wrench_S, np.zeros(6))
