"""The meshes the page draws: as few triangles as show the same picture (without a GPU the page
draws every triangle of every frame in software)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.web.scene_view import _tool_mesh, drawn_mesh, static_mesh
from app.world.scene import available_scenes, load_scene


def _first_hits(mesh: trimesh.Trimesh, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance along each ray to the first triangle it meets (inf: none)."""
    hits, rays, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=True)
    distance = np.full(len(origins), np.inf)
    along = np.einsum("ij,ij->i", hits - origins[rays], directions[rays])
    np.minimum.at(distance, rays, along)
    return distance


def test_the_tool_drawn_without_its_hidden_triangles_looks_the_same_from_everywhere() -> None:
    # Three overlapping spheres along x, as the tool's shell overlaps along its length.
    centers = np.array([[0.0, 0.0, 0.0], [0.003, 0.0, 0.0], [0.006, 0.0, 0.0]])
    radii = np.array([0.005, 0.005, 0.004])
    drawn = _tool_mesh(centers, radii)
    every = trimesh.util.concatenate(
        [
            trimesh.creation.icosphere(subdivisions=1, radius=r).apply_translation(c)
            for c, r in zip(centers, radii, strict=True)
        ]
    )
    assert len(drawn.faces) < 0.8 * len(every.faces)  # hidden triangles left out
    # Rays from all round, aimed near the shell: each meets the drawn tool where it meets every sphere.
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(400, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    targets = centers[rng.integers(0, 3, 400)] + rng.normal(scale=0.002, size=(400, 3))
    origins = targets - 0.1 * directions
    seen = _first_hits(every, origins, directions)
    assert np.isfinite(seen).sum() > 200
    np.testing.assert_allclose(_first_hits(drawn, origins, directions), seen, atol=1e-9)


def test_a_mesh_over_the_budget_is_drawn_with_fewer_triangles_of_the_same_shape() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)  # 20480 triangles
    drawn = drawn_mesh(sphere, faces=2000)
    assert 500 < len(drawn.faces) <= 2000
    distance = np.linalg.norm(drawn.vertices[np.unique(drawn.faces)], axis=1)
    assert distance.max() <= 1.0 + 1e-9  # still the unit sphere
    assert distance.min() > 0.97
    np.testing.assert_allclose(drawn.bounds, sphere.bounds, atol=0.03)
    # Every triangle still faces outward (its winding kept).
    centres = drawn.vertices[drawn.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", drawn.face_normals, centres) > 0).all()
    assert drawn_mesh(sphere, faces=20480) is sphere  # within the budget: drawn as it is


@pytest.mark.parametrize("name", available_scenes())
def test_a_scenes_static_objects_are_one_mesh_of_the_same_geometry(name: str) -> None:
    """The static objects drawn as one mesh (one draw): each object's drawn triangles, in order,
    at the same vertices; the same bounds and triangle count as the objects drawn one by one."""
    objects = [drawn_mesh(obj.mesh) for obj in load_scene(name).objects]
    merged = static_mesh(load_scene(name))
    assert merged is not None
    assert len(merged.faces) == sum(len(o.faces) for o in objects)
    np.testing.assert_array_equal(merged.bounds[0], np.min([o.bounds[0] for o in objects], axis=0))
    np.testing.assert_array_equal(merged.bounds[1], np.max([o.bounds[1] for o in objects], axis=0))
    start = 0
    for o in objects:  # triangle by triangle: the same corners
        np.testing.assert_array_equal(merged.vertices[merged.faces[start : start + len(o.faces)]], o.vertices[o.faces])
        start += len(o.faces)
