"""Shared fixtures for controller tests: the Kraft-like device and a simple slave tool."""

from __future__ import annotations

import numpy as np
import pytest

from app.controller.frhc import FRHCController
from app.controller.types import SlaveModel
from app.device.spec import DeviceSpec, load_device
from app.spatial import make_pose, zyx_to_matrix


@pytest.fixture(scope="session")
def kraft() -> DeviceSpec:
    return load_device("kraft")


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
    return FRHCController(kraft, kraft.data.gains, slave)
