"""Scene files: the shipped ones load; bad ones fail with one ConfigError naming file and field."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

from app.errors import ConfigError
from app.world import available_scenes, contact_wrench, load_scene
from app.world.scene import DEFAULT_SCENE

SHIPPED = ["bowl", "box_push", "large_mesh", "peg_carry", "peg_in_hole", "probe", "stack_topple"]

GOOD = """
name = "t"
[[objects]]
name = "surface"
MESH_LINE
stiffness = STIFFNESS
[tool]
mass = 0.5
inertia = [1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0]
home = { position = [0.0, 0.0, 0.1] }
[[tool.spheres]]
center = [0.0, 0.0, 0.0]
radius = 0.01
"""


def write_scene(
    tmp_path: Path,
    mesh_line: str = "box = [0.2, 0.2, 0.02]",
    stiffness: str = "1000.0",
    root: str = "",
    extra: str = "",
) -> Path:
    """Write the GOOD scene with one line changed, ``root`` keys first and ``extra`` tables last."""
    path = tmp_path / "scene.toml"
    path.write_text(
        root + textwrap.dedent(GOOD).replace("MESH_LINE", mesh_line).replace("STIFFNESS", stiffness) + extra
    )
    return path


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scene_loads(name: str) -> None:
    scene = load_scene(name)
    assert scene.name == name
    assert scene.objects
    assert len(scene.tool.radii) > 0
    assert all(o.mesh.is_watertight for o in scene.objects)
    # Home is free of contact.
    res = contact_wrench(scene, scene.tool.T_w_MRF_home)
    assert res.valid
    assert res.count == 0


def test_shipped_scene_list_and_default() -> None:
    assert available_scenes() == SHIPPED
    assert DEFAULT_SCENE == "probe"
    assert max(len(o.mesh.faces) for o in load_scene("large_mesh").objects) > 100_000
    total = sum(p.stat().st_size for p in (Path(__file__).parents[2] / "assets").iterdir())
    assert total < 15e6


def test_peg_task_goal_is_reached_only_when_inserted() -> None:
    scene = load_scene("peg_in_hole")
    task = scene.spec.task
    assert task is not None
    assert not task.done(scene.tool.T_w_MRF_home)
    assert task.done(task.goal.matrix())


def test_good_file_in_tmp_loads(tmp_path: Path) -> None:
    scene = load_scene(write_scene(tmp_path))
    assert scene.objects[0].stiffness == 1000.0


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"root": "colour = 'red'\n"}, "colour"),
        (
            {"extra": "[[tool.capsules]]\nstart = [0, 0, 0]\nend = [0, 0, 1]\nradius = 0.01\nradus = 1\n"},
            "tool.capsules[0].radus",
        ),
        ({"stiffness": "-5.0"}, "objects[0].stiffness"),
        ({"mesh_line": 'mesh = "no_such_mesh.stl"'}, "objects[0].mesh"),
        ({"mesh_line": "box = [0.2, 0.2, 0.02]\nsphere = 0.1"}, "objects[0].mesh"),
        ({"extra": "[slave]\nkp_lin = 100.0\nki = 3.0\n"}, "slave.ki"),
        ({"mesh_line": "box = [0.2, 0.2, 0.02]\ndynamic = { mass = -1.0 }"}, "objects[0].dynamic.mass"),
        ({"mesh_line": "box = [0.2, 0.2, 0.02]\ndynamic = { mass = 1.0, density = 600.0 }"}, "objects[0].dynamic.mass"),
        ({"mesh_line": "box = [0.2, 0.2, 0.02]\ndynamic = { density = 600.0, spin = 1 }"}, "objects[0].dynamic.spin"),
        (
            {"mesh_line": "box = [0.2, 0.2, 0.02]\ndynamic = { mass = 1.0, twist = [0, 0, 0] }"},
            "objects[0].dynamic.twist",
        ),
        ({"mesh_line": "plane = [0.2, 0.2]\ndynamic = { mass = 1.0 }"}, "objects[0].dynamic"),
    ],
)
def test_bad_scene_names_file_and_field(tmp_path: Path, kwargs: dict, field: str) -> None:
    path = write_scene(tmp_path, **kwargs)
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    assert info.value.field == field
    assert info.value.source == str(path)


def test_degenerate_mesh_is_rejected(tmp_path: Path) -> None:
    flat = tmp_path / "flat.ply"
    # Two triangles in one plane: zero volume, so there is no inside to push out of.
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]], process=False).export(flat)
    path = write_scene(tmp_path, mesh_line=f'mesh = "{flat}"')
    with pytest.raises(ConfigError, match="degenerate") as info:
        load_scene(path)
    assert info.value.field == "objects[0].mesh"


def test_unreadable_mesh_is_rejected(tmp_path: Path) -> None:
    junk = tmp_path / "junk.stl"
    junk.write_bytes(b"\x00\x01 not a mesh")
    with pytest.raises(ConfigError) as info:
        load_scene(write_scene(tmp_path, mesh_line=f'mesh = "{junk}"'))
    assert info.value.field == "objects[0].mesh"


def test_missing_scene_file_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_scene(tmp_path / "nope.toml")
    assert info.value.field == "<file>"


def test_a_closed_mesh_with_a_sliver_triangle_loads_closed(tmp_path: Path) -> None:
    """A T-junction closed by a zero-area sliver (issue 25): the file is closed, and the loader's
    repair keeps it closed instead of refusing it as open once the sliver is gone."""
    corners = [(x, y, z) for z in (-1, 1) for (x, y) in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    vertices = np.array([*corners, (0, 0, 1)]) * (0.1, 0.1, 0.01)  # 8: the middle of the top diagonal 4-6
    sides = [
        [0, 2, 1],
        [0, 3, 2],
        [0, 1, 5],
        [0, 5, 4],
        [2, 3, 7],
        [2, 7, 6],
        [0, 4, 7],
        [0, 7, 3],
        [1, 2, 6],
        [1, 6, 5],
    ]
    # The top: one triangle whole, the other split at 8, and the sliver 4-6-8 closing the T-junction.
    faces = [*sides, [4, 5, 6], [4, 8, 7], [8, 6, 7], [4, 6, 8]]
    sliver = trimesh.Trimesh(vertices, np.array(faces), process=False)
    assert sliver.is_watertight  # closed as written, with one zero-area face
    assert np.min(sliver.area_faces) == 0.0
    path_mesh = tmp_path / "sliver.ply"
    sliver.export(path_mesh)
    scene = load_scene(write_scene(tmp_path, mesh_line=f'mesh = "{path_mesh}"'))
    mesh = scene.objects[0].mesh
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(0.2 * 0.2 * 0.02)
    assert np.min(mesh.area_faces) > 0.0


def test_open_mesh_is_refused_naming_the_field(tmp_path: Path) -> None:
    # Contact signs distances by the side of the surface: an open one has no inside (issue 12:
    # a box without its bottom pushed the tool sideways in free space).
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.02))
    open_box = trimesh.Trimesh(
        box.vertices, np.delete(box.faces, np.flatnonzero(box.face_normals[:, 2] < -0.9), axis=0)
    )
    assert not open_box.is_watertight
    path_mesh = tmp_path / "open.ply"
    open_box.export(path_mesh)
    with pytest.raises(ConfigError, match="not closed") as info:
        load_scene(write_scene(tmp_path, mesh_line=f'mesh = "{path_mesh}"'))
    assert info.value.field == "objects[0].mesh"


def test_declared_faces_counts_each_format_without_parsing(tmp_path: Path) -> None:
    """Known counts: a binary and an ASCII STL, an OBJ with a quad, a PLY header; None for others."""
    from app.world.mesh_check import _SCAN_CHUNK, declared_faces

    box = trimesh.creation.box()
    box.export(tmp_path / "box.stl")
    (tmp_path / "box_ascii.stl").write_text(trimesh.exchange.stl.export_stl_ascii(box))
    box.export(tmp_path / "box.ply")
    box.export(tmp_path / "box.glb")
    # The 4th face's "\nf " straddles the scan's first chunk boundary: counted once.
    pad = "#" * (_SCAN_CHUNK - len("v 0 0 0\n" * 4 + "f 1 2 3\nf 1 2 4\nf 1 3 4") - 1)
    (tmp_path / "q.obj").write_text("v 0 0 0\n" * 4 + "f 1 2 3\nf 1 2 4\nf 1 3 4" + pad + "\nf 1 2 3 4\n")
    got = {p.name: declared_faces(p) for p in sorted(tmp_path.iterdir())}
    assert got == {"box.glb": None, "box.ply": 12, "box.stl": 12, "box_ascii.stl": 12, "q.obj": 4}
