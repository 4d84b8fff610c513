"""Shared fixtures for controller tests: the Kraft-like device, a kinematic variant of it, and a
simple slave tool."""

from __future__ import annotations

import numpy as np
import pytest

from app.controller.frhc import FRHCController
from app.controller.safety import SafetyLimits
from app.controller.types import SlaveModel
from app.device.spec import DEVICES_DIR, DeviceSpec, load_device
from app.spatial import make_pose, zyx_to_matrix

VARIANT_TOML = """
name = "variant"
description = "kraft with j3 a slide joint and an extra hinge 'tilt' in link5, listed after j5"
mjcf = "variant.xml"
grip_site = "grip"
wrist_site = "wrist"
joints = ["j1", "j2", "j3", "j4", "j5", "tilt", "j6"]
home = [0.0, 0.2, 0.01, 0.0, -0.5, 0.1, 0.0]

[motors]
torque_limit = [0.4, 0.4, 0.4, 0.1, 0.1, 0.1, 0.1]
gear_ratio = [15.0, 15.0, 15.0, 10.0, 10.0, 10.0, 10.0]
counts_max = 2047
counts_per_nm = [5117.5, 5117.5, 5117.5, 20470.0, 20470.0, 20470.0, 20470.0]
"""


@pytest.fixture(scope="session")
def kraft() -> DeviceSpec:
    return load_device("kraft")


@pytest.fixture(scope="session")
def variant(tmp_path_factory: pytest.TempPathFactory) -> DeviceSpec:
    """The Kraft geometry with what the shipped devices lack: a slide joint (j3, along x), and
    two joints in one body ('tilt' then j5 in link5) whose motor order is not MuJoCo's."""
    folder = tmp_path_factory.mktemp("variant")
    mjcf = (DEVICES_DIR / "kraft" / "kraft.xml").read_text()
    for old, new in (
        (
            '<joint name="j3" axis="0 1 0" range="-1.2 2.2"/>',
            '<joint name="j3" type="slide" axis="1 0 0" range="-0.05 0.05"/>',
        ),
        (
            '<joint name="j5" axis="0 1 0"',
            '<joint name="tilt" axis="0 0 1" range="-0.5 0.5"/>\n<joint name="j5" axis="0 1 0"',
        ),
    ):
        assert mjcf.count(old) == 1
        mjcf = mjcf.replace(old, new)
    (folder / "variant.xml").write_text(mjcf)
    (folder / "device.toml").write_text(VARIANT_TOML)
    return load_device(folder / "device.toml")


@pytest.fixture
def slave() -> SlaveModel:
    """A tool whose sensor sits 5 cm above the MRF, rotated, with a 0.4 kg payload off-axis."""
    return SlaveModel(
        T_MRF_S=make_pose(zyx_to_matrix(0.1, -0.2, 0.3), np.array([0.0, 0.0, 0.05])),
        payload_mass=0.4,
        payload_com_S=np.array([0.01, -0.02, -0.03]),
        payload_inertia_S=np.diag([1e-3, 2e-3, 3e-3]),
        gravity_w=np.array([0.0, 0.0, -9.81]),
        T_w_MRF_home=make_pose(np.eye(3), np.array([0.0, 0.0, 0.3])),
    )


@pytest.fixture
def controller(kraft: DeviceSpec, slave: SlaveModel) -> FRHCController:
    """The paper's controller as printed: these tests jump the angles between ticks and check
    each tick's equations, so the safety ramp and brake (tested on their own) are off."""
    return FRHCController(kraft, kraft.data.gains, slave, safety=SafetyLimits.paper_only())
