"""Fixtures for device tests: a scratch copy of the Kraft device to break or modify."""

from __future__ import annotations

from pathlib import Path

import pytest
from device_helpers import copy_device


@pytest.fixture
def kraft_copy(tmp_path: Path) -> Path:
    """Path of ``device.toml`` in a fresh copy of ``devices/kraft`` (MJCF and calibration included)."""
    return copy_device(tmp_path, "kraft")
