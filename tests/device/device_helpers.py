"""Helpers shared by the device tests."""

from __future__ import annotations

import shutil
from pathlib import Path

from app.device.spec import DEVICES_DIR


def copy_device(folder: Path, name: str) -> Path:
    """Path of ``device.toml`` in a fresh copy of ``devices/<name>`` (MJCF and calibration
    included) under ``folder``."""
    dest = folder / name
    shutil.copytree(DEVICES_DIR / name, dest)
    return dest / "device.toml"


def replace_in(path: Path, old: str, new: str) -> None:
    """Replace one exact occurrence of ``old`` in the file (fails loudly if it is not there once)."""
    text = path.read_text()
    assert text.count(old) == 1, f"{old!r} occurs {text.count(old)} times in {path}"
    path.write_text(text.replace(old, new))
