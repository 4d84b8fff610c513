"""The python-fcl behaviour the contact model is designed around (docs/conventions.md), pinned on this version.

If one of these starts failing after an upgrade, revisit the workarounds in app/world/contact.py.
"""

from __future__ import annotations

import fcl
import numpy as np
import trimesh


def bvh_object(mesh: trimesh.Trimesh) -> fcl.CollisionObject:
    bvh = fcl.BVHModel()
    bvh.beginModel(len(mesh.vertices), len(mesh.faces))
    bvh.addSubModel(mesh.vertices, mesh.faces)
    bvh.endModel()
    return fcl.CollisionObject(bvh, fcl.Transform())


def slab() -> fcl.CollisionObject:
    return bvh_object(trimesh.creation.box(extents=(0.2, 0.2, 0.01)))  # top face z = 0.005, 2 triangles


def test_collide_counts_each_touched_triangle_so_a_shared_edge_doubles() -> None:
    ball = fcl.CollisionObject(fcl.Sphere(0.01), fcl.Transform(np.array([0.0, 0.0, 0.012])))
    result = fcl.CollisionResult()
    fcl.collide(slab(), ball, fcl.CollisionRequest(num_max_contacts=10, enable_contact=True), result)
    # The ball sits over the top face's diagonal: both of its triangles report a contact.
    assert len(result.contacts) >= 2


def test_point_distance_to_a_mesh_is_exact_with_mesh_first_nearest_point() -> None:
    core = fcl.CollisionObject(fcl.Sphere(0.0), fcl.Transform(np.array([0.013, 0.021, 0.0071])))
    res = fcl.DistanceResult()
    d = fcl.distance(slab(), core, fcl.DistanceRequest(enable_nearest_points=True), res)
    assert abs(d - 0.0021) < 1e-12
    np.testing.assert_allclose(res.nearest_points[0], [0.013, 0.021, 0.005], atol=1e-12)
    assert 0 <= res.b1 < 12


def test_point_distance_inside_is_the_unsigned_distance_to_the_nearest_face() -> None:
    core = fcl.CollisionObject(fcl.Sphere(0.0), fcl.Transform(np.array([0.0, 0.0, 0.004])))
    res = fcl.DistanceResult()
    d = fcl.distance(slab(), core, fcl.DistanceRequest(enable_nearest_points=True), res)
    assert abs(d - 0.001) < 1e-12  # positive: FCL does not know the inside of a BVH


def test_point_exactly_on_the_surface_gives_no_usable_distance() -> None:
    core = fcl.CollisionObject(fcl.Sphere(0.0), fcl.Transform(np.array([0.013, 0.021, 0.005])))
    res = fcl.DistanceResult()
    d = fcl.distance(slab(), core, fcl.DistanceRequest(enable_nearest_points=True), res)
    # Touching counts as collision: the distance is ~0 and the nearest points are not filled in
    # (the contact model re-queries 1 um off the surface).
    assert d < 1e-9
