"""The file-format documents show every field's range exactly as the schema states it."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path

import pytest

from app.config import MAX_FILE_BYTES, field_range
from app.controller.gains import ControllerGains
from app.controller.passivity import PassivitySettings
from app.device.hand import HandParams
from app.device.spec import CalibrationSpec, CartesianSpec, DeviceFile, MotorSpec, PlantParams
from app.session.spec import MAX_TICKS, SessionFile, SwitchEvent, Waypoint
from app.sweep.spec import SweepFile, Vary
from app.teleop.channel import ChannelSettings
from app.world.scene_file import (
    MAX_OBJECTS,
    MAX_TOOL_SPHERES,
    BoxSpec,
    CapsuleSpec,
    DynamicSpec,
    ObjectSpec,
    Pose,
    SceneFile,
    SlaveGains,
    SphereSpec,
    TaskSpec,
    ToolSpec,
    ViewSpec,
)

ROOT = Path(__file__).resolve().parents[2]

#: (document, heading, schema class): the table under that heading documents that class.
SECTIONS = [
    ("scenes/README.md", "## Poses", Pose),
    ("scenes/README.md", "## Top level", SceneFile),
    ("scenes/README.md", "## `[[objects]]`", ObjectSpec),
    ("scenes/README.md", "### `[objects.dynamic]`", DynamicSpec),
    ("scenes/README.md", "## `[tool]`", ToolSpec),
    ("scenes/README.md", "### `[[tool.spheres]]`", SphereSpec),
    ("scenes/README.md", "### `[[tool.capsules]]`", CapsuleSpec),
    ("scenes/README.md", "### `[[tool.boxes]]`", BoxSpec),
    ("scenes/README.md", "## `[slave]`", SlaveGains),
    ("scenes/README.md", "## `[task]`", TaskSpec),
    ("scenes/README.md", "## `[view]`", ViewSpec),
    ("devices/README.md", "## Top level", DeviceFile),
    ("devices/README.md", "## `[motors]`", MotorSpec),
    ("devices/README.md", "## `[gains]`", ControllerGains),
    ("devices/README.md", "## `[plant]`", PlantParams),
    ("devices/README.md", "## `[cartesian]`", CartesianSpec),
    ("devices/README.md", "## Calibration file", CalibrationSpec),
    ("sessions/README.md", "## Top level", SessionFile),
    ("sessions/README.md", "## `[[waypoints]]`", Waypoint),
    ("sessions/README.md", "## `[[events]]`", SwitchEvent),
    ("sessions/README.md", "## `[hand]`", HandParams),
    ("sessions/README.md", "## `[passivity]`", PassivitySettings),
    ("sessions/README.md", "## `[channel]`", ChannelSettings),
    ("sweeps/README.md", "## Top level", SweepFile),
    ("sweeps/README.md", "## `[[vary]]`", Vary),
]


def section(doc: str, heading: str) -> str:
    """The text under ``heading`` up to the next heading."""
    text = (ROOT / doc).read_text()
    start = text.index(heading + "\n") if heading + "\n" in text else text.index(heading)
    rest = text[start + len(heading) :]
    ends = [i for i in (rest.find("\n## "), rest.find("\n### ")) if i >= 0]
    return rest[: min(ends)] if ends else rest


@pytest.mark.parametrize(("doc", "heading", "cls"), SECTIONS, ids=[f"{d} {h}" for d, h, _ in SECTIONS])
def test_every_field_is_documented_with_its_range(doc: str, heading: str, cls: type) -> None:
    rows = {line.split("|")[1].strip(): line for line in section(doc, heading).splitlines() if line.startswith("| `")}
    for f in dataclasses.fields(cls):
        row = next((r for key, r in rows.items() if key.strip("`").strip("[]") == f.name), None)
        assert row is not None, f"{doc} {heading}: no row for `{f.name}`"
        rule = field_range(cls, f.name)
        if rule is not None:
            assert f"| {rule.text()} |" in row, f"{doc} {heading}: `{f.name}` should show {rule.text()}: {row}"


def schema_classes(cls: type, seen: set[type]) -> set[type]:
    """``cls`` and every dataclass its fields nest, at any depth."""
    seen.add(cls)
    for hint in typing.get_type_hints(cls).values():
        stack = [hint]
        while stack:
            tp = stack.pop()
            stack.extend(typing.get_args(tp))
            if dataclasses.is_dataclass(tp) and isinstance(tp, type) and tp not in seen:
                schema_classes(tp, seen)
    return seen


def test_every_schema_class_has_a_documented_section() -> None:
    classes: set[type] = set()
    for root in (SceneFile, DeviceFile, SessionFile, CalibrationSpec, ControllerGains, HandParams, SweepFile):
        schema_classes(root, classes)
    assert classes == {cls for _, _, cls in SECTIONS}


def test_resource_limits_are_documented() -> None:
    scenes = (ROOT / "scenes/README.md").read_text()
    assert f"| {MAX_TOOL_SPHERES} |" in scenes
    assert f"| {MAX_OBJECTS} each |" in scenes
    assert f"{MAX_FILE_BYTES // 2**20} MiB" in scenes
    assert f"at most {MAX_TICKS:,} ticks" in (ROOT / "sessions/README.md").read_text()
