"""MuJoCo's C functions called from compiled code do exactly what the bindings do."""

from __future__ import annotations

import mujoco
import numpy as np
from numba import njit

from app.mjcall import address, call_model_data, pointers
from app.spatial import IntArray

_PENDULUM = """<mujoco><worldbody><body><joint type="hinge" axis="0 1 0"/>
<geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/></body></worldbody></mujoco>"""


@njit(cache=True)
def _steps(mj: IntArray, n: int) -> None:
    for _ in range(n):
        call_model_data(mj[0], mj[1], mj[2])


def _pendulum() -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(_PENDULUM)
    data = mujoco.MjData(model)
    data.qpos[0] = 0.3
    return model, data


def test_compiled_mj_step_matches_the_bindings_bit_for_bit() -> None:
    m1, d1 = _pendulum()
    m2, d2 = _pendulum()
    for _ in range(200):
        mujoco.mj_step(m1, d1)
    _steps(np.array((address("mj_step"), *pointers(m2, d2))), 200)
    assert d2.time == d1.time
    np.testing.assert_array_equal(d2.qpos, d1.qpos)
    np.testing.assert_array_equal(d2.qvel, d1.qvel)
    assert d2.qpos[0] != 0.3  # it did move


def test_kinematics_entry_point_fills_the_bindings_views() -> None:
    model, data = _pendulum()
    _steps(np.array((address("mj_kinematics"), *pointers(model, data))), 1)
    # The capsule's centre is 0.15 m along the link, rotated by qpos about y.
    np.testing.assert_allclose(data.geom_xpos[0], [0.15 * np.cos(0.3), 0.0, -0.15 * np.sin(0.3)], atol=1e-12)
