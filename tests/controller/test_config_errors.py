"""Malformed gain sets (alone or in a device file) raise one ConfigError naming the file and the field.

The device file's other fields are covered in ``tests/device/test_device_files.py``.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from app.config import from_dict
from app.controller.gains import ControllerGains
from app.device.spec import DEVICES_DIR, load_device
from app.errors import ConfigError


@pytest.mark.parametrize(
    ("gains", "field", "reason"),
    [
        ({"k_v": [1.0, 1.0, 1.0]}, "k_v", "expected 6 values"),
        ({"k_d": [1.0, -1.0, 1.0, 1.0, 1.0, 1.0]}, "k_d", "non-negative"),
        ({"k_p": [1.0, 1.0, 1.0, 1.0, 1.0, 0.5]}, "k_p", "must be 1"),
        ({"mode": "velocity"}, "mode", "must be one of"),
        ({"assist_fraction": 1.5}, "assist_fraction", "in \\(0, 1\\]"),
        ({"k_t": [1.0, 1.0, "x", 1.0, 1.0, 1.0]}, "k_t\\[2\\]", "expected a number"),
        ({"k_vv": [1.0] * 6}, "k_vv", "unknown field"),
    ],
)
def test_bad_gain_sets(gains, field, reason) -> None:
    with pytest.raises(ConfigError, match=rf"my_gains.toml: field '{field}': .*{reason}"):
        from_dict(ControllerGains, gains, "my_gains.toml")


def copy_kraft(tmp_path: Path) -> Path:
    dst = tmp_path / "kraft"
    shutil.copytree(DEVICES_DIR / "kraft", dst)
    return dst / "device.toml"


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("k_p = [2.0, 2.0, 2.0, 1.0, 1.0, 1.0]", "k_p = [2.0, 2.0, 2.0, 2.0, 1.0, 1.0]", "gains.k_p"),
        ('grip_site = "grip"', 'grip_site = "handle_tip"', "grip_site"),
    ],
)
def test_bad_device_files_name_file_and_field(tmp_path: Path, old: str, new: str, field: str) -> None:
    path = copy_kraft(tmp_path)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    with pytest.raises(ConfigError) as err:
        load_device(path)
    assert err.value.source == str(path)
    assert err.value.field == field
