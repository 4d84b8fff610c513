"""Bad device files fail with one ConfigError naming the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest
from device_helpers import replace_in

from app.device.plant import DevicePlant
from app.device.spec import available_devices, load_device
from app.errors import ConfigError


def load_with_plant(path: Path) -> DevicePlant:
    return DevicePlant(load_device(path))


def expect_error(path: Path, field: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_with_plant(path)
    assert info.value.source == str(path)
    assert info.value.field == field
    assert str(path) in str(info.value)
    return info.value


def test_shipped_devices_load_with_their_plants() -> None:
    assert set(available_devices()) >= {"kraft", "jpl", "freflex"}
    for name in available_devices():
        plant = load_with_plant(load_device(name).path)
        assert plant.n_joints == len(plant.spec.data.joints)


def test_missing_mjcf(kraft_copy: Path) -> None:
    replace_in(kraft_copy, 'mjcf = "kraft.xml"', 'mjcf = "nowhere.xml"')
    assert "not found" in expect_error(kraft_copy, "mjcf").reason


def test_missing_mesh(kraft_copy: Path) -> None:
    xml = kraft_copy.parent / "kraft.xml"
    replace_in(xml, "<worldbody>", '<asset><mesh name="base" file="missing_base.stl"/></asset>\n  <worldbody>')
    replace_in(xml, '<geom name="pedestal"', '<geom type="mesh" mesh="base"/>\n    <geom name="pedestal"')
    assert "missing_base.stl" in expect_error(kraft_copy, "mjcf").reason


@pytest.mark.parametrize(
    ("old", "new", "field", "reason"),
    [
        ('"j5", "j6"]', '"j5", "j9"]', "joints[5]", "unknown joint"),
        ("torque_limit = [0.40,", "torque_limit = [0.0,", "motors.torque_limit", "positive"),
        ("gear_ratio = [15.0, 15.0, 15.0,", "gear_ratio = [15.0, 15.0,", "motors.gear_ratio", "expected 6"),
        ("damping = [0.04, 0.04, 0.03,", "damping = [0.04, 0.03,", "plant.damping", ""),
        ("substeps = 1", "substeps = 1\nbacklash = 0.01", "plant.backlash", "unknown field"),
        ("motor_deadzone = [0.04,", "motor_deadzone = [0.7,", "plant.motor_deadzone[0]", ""),
        ("mass_scale = [1.0,", "mass_scale = [-1.0,", "plant.mass_scale[0]", ""),
        ("substeps = 1", "substeps = 0", "plant.substeps", ""),
    ],
)
def test_bad_field(kraft_copy: Path, old: str, new: str, field: str, reason: str) -> None:
    replace_in(kraft_copy, old, new)
    assert reason in expect_error(kraft_copy, field).reason


def test_empty_plant_table_is_an_ideal_plant(kraft_copy: Path) -> None:
    text = kraft_copy.read_text()
    kraft_copy.write_text(text[: text.index("[plant]")])
    plant = load_with_plant(kraft_copy)
    assert plant.params.per_joint("motor_deadzone", 6).tolist() == [0.0] * 6
    assert plant.params.per_joint("mass_scale", 6).tolist() == [1.0] * 6
