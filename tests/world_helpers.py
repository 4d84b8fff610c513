"""Scenes built in code for world tests whose answers follow from geometry."""

from __future__ import annotations

from typing import Any

import numpy as np

from app.spatial import make_pose, zyx_to_matrix
from app.world.scene import ObjectSpec, Pose, Scene, SceneFile, SphereSpec, ToolSpec, build_scene


def sphere_tool(radius: float = 0.01, center: tuple[float, float, float] = (0.0, 0.0, 0.0), **kw: Any) -> ToolSpec:
    """A one-sphere tool; {T} = {S} = {MRF} unless given otherwise."""
    return ToolSpec(
        mass=0.5,
        inertia=(1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0),
        home=Pose((0.0, 0.0, 0.1)),
        spheres=(SphereSpec(center, radius),),
        **kw,
    )


def make_scene(objects: list[ObjectSpec] | tuple[ObjectSpec, ...], tool: ToolSpec | None = None, **kw: Any) -> Scene:
    """A scene of ``objects`` and ``tool`` (default: one 1 cm sphere at {T} = {S} = {MRF})."""
    return build_scene(SceneFile(name="test", tool=tool or sphere_tool(), objects=tuple(objects), **kw))


def plane(k: float = 1000.0, **kw: Any) -> ObjectSpec:
    """A 40 cm x 40 cm, 2 cm thick slab with its top face at z = 0."""
    return ObjectSpec(name=kw.pop("name", "plane"), plane=(0.4, 0.4), plane_thickness=0.02, stiffness=k, **kw)


def pose(p: tuple[float, float, float], zyx: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 pose from a position (m) and Z-Y-X angles [gamma, beta, alpha] (rad)."""
    return make_pose(zyx_to_matrix(*zyx), np.array(p, dtype=float))
