"""Fixtures for device tests: a scratch copy of the Kraft device to break or modify."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from app.device.spec import DEVICES_DIR


@pytest.fixture
def kraft_copy(tmp_path: Path) -> Path:
    """Path of ``device.toml`` in a fresh copy of ``devices/kraft`` (MJCF and calibration included)."""
    dest = tmp_path / "kraft"
    shutil.copytree(DEVICES_DIR / "kraft", dest)
    return dest / "device.toml"
