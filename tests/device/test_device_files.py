"""Bad device files fail with one ConfigError naming the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest
from device_helpers import copy_device, replace_in

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
    ("device", "old", "new", "field", "reason"),
    [
        ("kraft", '"j5", "j6"]', '"j5", "j9"]', "joints[5]", "unknown joint"),
        ("kraft", "torque_limit = [0.40,", "torque_limit = [0.0,", "motors.torque_limit", "positive"),
        ("kraft", "gear_ratio = [15.0, 15.0, 15.0,", "gear_ratio = [15.0, 15.0,", "motors.gear_ratio", "expected 6"),
        ("kraft", "damping = [0.04, 0.04, 0.03,", "damping = [0.04, 0.03,", "plant.damping", ""),
        ("kraft", "substeps = 1", "substeps = 1\nbacklash = 0.01", "plant.backlash", "unknown field"),
        ("kraft", "motor_deadzone = [0.04,", "motor_deadzone = [0.7,", "plant.motor_deadzone[0]", ""),
        ("kraft", "mass_scale = [1.0,", "mass_scale = [-1.0,", "plant.mass_scale[0]", ""),
        ("kraft", "substeps = 1", "substeps = 0", "plant.substeps", ""),
        # The vendor's figures of a real device's [cartesian] table.
        ("omega3", "force_limit = 12.0 ", "force_limit = 12.5 ", "cartesian.force_limit", "above the device's peak"),
        (
            "omega3",
            "peak_force = 12.0",
            "peak_force = 12.0\ncontinuous_force = 13",
            "cartesian.continuous_force",
            "above",
        ),
        ("omega3", "workspace_radius = 0.075", "workspace_radius = 0.0", "cartesian.workspace_radius", "(0, 10] m"),
        (
            "omega3",
            "workspace_radius = 0.075",
            "workspace_radius = 0.075\nupdate_rate = -1",
            "cartesian.update_rate",
            "Hz",
        ),
    ],
)
def test_bad_field(tmp_path: Path, device: str, old: str, new: str, field: str, reason: str) -> None:
    path = copy_device(tmp_path, device)
    replace_in(path, old, new)
    assert reason in expect_error(path, field).reason


def test_empty_plant_table_is_an_ideal_plant(kraft_copy: Path) -> None:
    text = kraft_copy.read_text()
    kraft_copy.write_text(text[: text.index("[plant]")])
    plant = load_with_plant(kraft_copy)
    assert plant.params.per_joint("motor_deadzone", 6).tolist() == [0.0] * 6
    assert plant.params.per_joint("mass_scale", 6).tolist() == [1.0] * 6


def test_real_devices_files_carry_their_sourced_figures_and_leave_the_rest_out() -> None:
    """The shipped files of real Cartesian devices: the values cited in their NOTES.md, and None
    where no source was found (nothing invented)."""
    omega3, inverse3, touch3 = (load_device(name).data.cartesian for name in ("omega3", "inverse3", "touch3"))
    assert omega3 is not None
    assert inverse3 is not None
    assert touch3 is not None
    assert (omega3.force_limit, omega3.peak_force, omega3.workspace_radius) == (12.0, 12.0, 0.075)
    assert (inverse3.force_limit, inverse3.peak_force, inverse3.workspace_radius) == (2.0, None, 0.10)
    assert (touch3.force_limit, touch3.peak_force, touch3.workspace_radius) == (3.3, 3.3, 0.075)
    for spec in (omega3, inverse3, touch3):
        assert (spec.continuous_force, spec.position_resolution, spec.update_rate) == (None, None, None)
        assert spec.torque_limit == 0.0  # all three render forces only


def test_check_lists_a_real_devices_figures_with_a_mark_where_unsourced() -> None:
    from app.check import check_file

    line = check_file("omega3")
    assert "Cartesian: force limit 12 N, peak 12 N, continuous ?, workspace radius 75 mm, resolution ?, rate ?" in line


def test_a_device_outside_the_process_gets_the_sessions_cartesian_file_else_its_vendors() -> None:
    """``--device fd:`` / ``openhaptics:`` / a real Inverse Service: the limits come from the
    session's device file when it is Cartesian, else from the vendor's shipped file (no device is
    opened here: only the file is chosen)."""
    from app.device.haply import served_device
    from app.device.vendors import vendor_device

    kraft, touch3 = load_device("kraft"), load_device("touch3")
    assert served_device("fd:", kraft).name == "omega3"
    assert served_device("fd:1", None).name == "omega3"
    assert served_device("openhaptics:", kraft).name == "touch3"
    assert served_device("fd:", touch3) is touch3
    assert vendor_device("ws://192.0.2.1:10001") == "inverse3"


def test_a_device_is_loaded_once_while_its_files_are_unchanged(tmp_path: Path) -> None:
    path = copy_device(tmp_path, "kraft")
    first = load_device(path)
    assert load_device(path) is first
    # An edit of the MJCF beside the file (its size changes) is a new device.
    replace_in(path.parent / "kraft.xml", "<worldbody>", "<worldbody>\n  ")
    second = load_device(path)
    assert second is not first
    assert load_device(path) is second
    # A broken file is refused every time, not kept.
    replace_in(path, 'mjcf = "kraft.xml"', 'mjcf = "nowhere.xml"')
    for _ in range(2):
        with pytest.raises(ConfigError):
            load_device(path)
