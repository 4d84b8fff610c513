"""Fixtures for device tests: a scratch copy of the Kraft device to break or modify; a served touch3."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from device_helpers import copy_device

from app.device.cartesian_sim import SimCartesianDevice
from app.device.haply import DeviceServer
from app.device.spec import load_device


@pytest.fixture
def kraft_copy(tmp_path: Path) -> Path:
    """Path of ``device.toml`` in a fresh copy of ``devices/kraft`` (MJCF and calibration included)."""
    return copy_device(tmp_path, "kraft")


@pytest.fixture
def served() -> Iterator[DeviceServer]:
    """A simulated touch3 served over loopback (``frhc device serve`` in a thread of this process)."""
    server = DeviceServer(SimCartesianDevice(load_device("touch3")), port=0).start()
    yield server
    server.shutdown()
