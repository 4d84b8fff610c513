"""A scene built in code: a trimesh L-shaped block and a primitive, then contact wrenches.

Scenes are usually TOML files in ``scenes/`` (format in ``scenes/README.md``); the same frozen
dataclasses can be filled in code, and they check their fields exactly as a file is checked.
Meshes come from any file trimesh reads: here an L-shaped block is made with trimesh and written
to a temporary STL. The probe scene's stylus (a 5 mm tip sphere at {MRF}) is then placed against
the block's floor and its wall.

    .venv/bin/python examples/03_scene_in_code.py
"""

import dataclasses
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from app.spatial import make_pose
from app.world import contact_wrench
from app.world.scene import ObjectSpec, Pose, build_scene, load_scene

# An L-block: a floor slab with its top at z = 0 for x < 0, and a wall with its face at x = 0.
floor = trimesh.creation.box(extents=(0.2, 0.1, 0.02), transform=make_pose(np.eye(3), np.array([-0.1, 0.0, -0.01])))
wall = trimesh.creation.box(extents=(0.02, 0.1, 0.12), transform=make_pose(np.eye(3), np.array([0.01, 0.0, 0.04])))
block = trimesh.boolean.union([floor, wall])

with tempfile.TemporaryDirectory() as tmp:
    mesh_path = Path(tmp) / "l_block.stl"
    block.export(mesh_path)
    probe = load_scene("probe").spec  # reuse the shipped stylus tool and slave gains
    spec = dataclasses.replace(
        probe,
        name="l_block",
        objects=(
            ObjectSpec("block", stiffness=3000.0, mesh=str(mesh_path)),
            ObjectSpec("ball", stiffness=2000.0, sphere=0.03, pose=Pose(position=(-0.15, 0.0, 0.08))),
        ),
    )
    scene = build_scene(spec)

np.set_printoptions(precision=3, suppress=True)
tip_radius = 0.005
for label, tip in (
    ("tip 2 mm into the floor", (-0.05, 0.0, tip_radius - 0.002)),
    ("tip 1 mm into the wall", (-tip_radius + 0.001, 0.0, 0.05)),
    ("tip in free space", (-0.05, 0.0, 0.03)),
):
    result = contact_wrench(scene, make_pose(np.eye(3), np.array(tip)))
    force = result.force_w
    print(f"{label:<26} force in {{w}} {force} N, {result.count} contact(s), valid={result.valid}")
