"""Contact wrench against geometry whose answer is known."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from world_helpers import make_scene, plane, pose, sphere_tool

from app.spatial import make_pose, quat_to_matrix
from app.world import ContactModel, contact_wrench
from app.world.assets import BOWL_CAVITY_RADIUS, PEG_SPACING, RIM_RADIUS
from app.world.scene import BoxSpec, CapsuleSpec, ObjectSpec, Pose, Scene, SphereSpec, ToolSpec, load_scene

K = 1000.0
R = 0.01


@functools.cache
def _scene_of(mesh: str) -> Scene:
    """A shipped mesh at the origin and a 5 mm sphere tool (built once: hypothesis reuses it)."""
    return make_scene([ObjectSpec(name=mesh, mesh=mesh, stiffness=K)], sphere_tool(0.005))


@functools.cache
def _plane_scene() -> Scene:
    return make_scene([plane(K)])


unit_quats = st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: math.hypot(*q) > 0.1)


@given(
    depth=st.floats(1e-5, 0.009),
    x=st.floats(-0.15, 0.15),
    y=st.floats(-0.15, 0.15),
    q=unit_quats,
)
@settings(max_examples=60, deadline=None)
def test_sphere_on_plane_force_is_k_times_depth_with_no_moment(depth: float, x: float, y: float, q: tuple) -> None:
    scene = _plane_scene()
    R_w_T = quat_to_matrix(np.array(q) / math.hypot(*q))
    res = contact_wrench(scene, make_pose(R_w_T, np.array([x, y, R - depth])))
    assert res.valid
    assert res.count == 1
    # The sensor is at the sphere centre: force K*depth along the world +z, in {S} axes, no moment.
    np.testing.assert_allclose(res.wrench_S[0:3], R_w_T.T @ [0.0, 0.0, K * depth], atol=1e-9)
    np.testing.assert_allclose(res.wrench_S[3:6], 0.0, atol=1e-12)
    np.testing.assert_allclose(res.force_w, [0.0, 0.0, K * depth], atol=1e-9)
    np.testing.assert_allclose(res.points_w[0], [x, y, 0.0], atol=1e-12)
    assert res.depths[0] == pytest.approx(depth, abs=1e-12)


def test_sphere_offset_from_sensor_gives_r_cross_f() -> None:
    tool = sphere_tool(R, center=(0.1, 0.02, -0.05))
    scene = make_scene([plane(K)], tool)
    depth = 0.002
    # {T} = {S} = {MRF} sits 0.05 m above the sphere centre, offset in x and y.
    res = contact_wrench(scene, pose((-0.1, -0.02, 0.05 + R - depth)))
    f = K * depth
    r_S_contact = np.array([0.1, 0.02, -0.05 - (R - depth)])
    np.testing.assert_allclose(res.wrench_S, [0, 0, f, *np.cross(r_S_contact, [0, 0, f])], atol=1e-12)
    assert res.wrench_S[3] == pytest.approx(0.02 * f)
    assert res.wrench_S[4] == pytest.approx(-0.1 * f)


def box_tool(sensor: Pose | None = None) -> ToolSpec:
    """A 6 x 4 x 2 cm box of 2 mm spheres on a 5 mm grid, centred on {T} = {MRF}."""
    return ToolSpec(
        mass=0.5,
        inertia=(1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0),
        home=Pose((0.0, 0.0, 0.1)),
        boxes=(BoxSpec(extents=(0.06, 0.04, 0.02), sphere_radius=0.002, spacing=0.005),),
        sensor=sensor or Pose(),
    )


def test_box_resting_flat_has_no_moment_about_its_centre() -> None:
    scene = make_scene([plane(K)], box_tool())
    depth = 0.0005
    res = contact_wrench(scene, pose((0.01, -0.02, 0.01 - depth), (0.0, 0.0, 0.3)))
    centers = scene.tool.centers_T
    n_bottom = int(np.sum(np.isclose(centers[:, 2], -0.008)))
    assert res.count == n_bottom == 13 * 9
    np.testing.assert_allclose(res.force_w, [0, 0, n_bottom * K * depth], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(res.wrench_S[3:6], 0.0, atol=1e-12)


def test_box_half_over_an_edge_gives_the_moment_of_each_contact() -> None:
    # Block occupying x < 0 with its top at z = 0; the box straddles the edge x = 0.
    block = ObjectSpec(name="block", box=(0.2, 0.2, 0.02), pose=Pose((-0.1, 0.0, -0.01)), stiffness=K)
    sensor = Pose((0.01, 0.0, 0.05))  # the sensor sits above and to the side of the box centre
    scene = make_scene([block], box_tool(sensor))
    depth, x_box = 0.0005, 0.0012  # one column of spheres sits 1.2 mm past the edge
    T = pose((x_box, 0.0, 0.01 - depth))
    res = contact_wrench(scene, T)
    # Expected from the geometry: spheres over the top face press straight down; spheres past the
    # edge (x > 0) touch the edge line, normal from the edge to the centre.
    r = 0.002
    F = np.zeros(3)
    M_S = np.zeros(3)
    p_S = T[0:3, 3] + np.array(sensor.position)
    for c in scene.tool.centers_T + T[0:3, 3]:
        if c[0] <= 0:
            n, point, d = np.array([0, 0, 1.0]), np.array([c[0], c[1], 0.0]), c[2]
        else:
            d = math.hypot(c[0], c[2])
            n, point = np.array([c[0], 0.0, c[2]]) / d, np.array([0.0, c[1], 0.0])
        if r - d > 0:
            f = K * (r - d) * n
            F += f
            M_S += np.cross(point - p_S, f)
    assert res.count > 0
    np.testing.assert_allclose(res.force_w, F, rtol=1e-9, atol=1e-9)
    assert np.any(res.normals_w[:, 0] > 0.1)  # some spheres press on the edge, not the face
    np.testing.assert_allclose(res.wrench_S[3:6], M_S, rtol=1e-9, atol=1e-12)
    assert M_S[1] > 0.0  # the force acts left of the sensor: it tips the box toward the free side


def test_tilted_peg_on_the_hole_rim_is_pushed_from_the_rim_point() -> None:
    r = 0.006
    peg = ToolSpec(
        mass=0.5,
        inertia=(1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0),
        home=Pose((0.0, 0.0, 0.1)),
        capsules=(CapsuleSpec(start=(0.0, 0.0, 0.0), end=(0.0, 0.0, 0.04), radius=r),),
    )
    block = ObjectSpec(name="block", mesh="peg_block.ply", stiffness=K)
    scene = make_scene([block], peg)
    rim = np.array([PEG_SPACING / 2 + RIM_RADIUS, 0.0, 0.0])  # a vertex of the 256-gon rim (top of the chamfer)
    c = rim + np.array([-0.002, 0.0, 0.003])  # tip centre inside the hole's circle, above the top
    theta = math.radians(10)  # the peg leans toward the hole centre going up
    T = pose(tuple(c), (0.0, -theta, 0.0))
    assert T[0, 2] < 0
    res = contact_wrench(scene, T)
    assert res.count == 1
    assert res.sphere_ids[0] == 0
    d = np.linalg.norm(c - rim)
    n = (c - rim) / d
    # Tolerances from the 256-gon rim: its nearest point may sit ~30 um along the tangent.
    np.testing.assert_allclose(res.points_w[0], rim, atol=5e-5)
    np.testing.assert_allclose(res.normals_w[0], n, atol=1e-2)
    assert res.depths[0] == pytest.approx(r - d, abs=2e-6)
    np.testing.assert_allclose(res.force_w, K * (r - d) * n, atol=0.01 * K * (r - d))
    # The moment about {S} (= the tip centre) is exactly that of the reported point and force.
    np.testing.assert_allclose(
        res.wrench_S[3:6], T[0:3, 0:3].T @ np.cross(res.points_w[0] - c, res.force_w), atol=1e-12
    )


@given(
    azimuth=st.floats(0, 2 * math.pi),
    elevation=st.floats(math.radians(-85), math.radians(-20)),
    depth=st.floats(1e-4, 3e-3),
)
@settings(max_examples=25, deadline=None)
def test_contact_inside_the_bowl_cavity(azimuth: float, elevation: float, depth: float) -> None:
    scene = _scene_of("bowl.ply")
    u = np.array(
        [math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)]
    )
    c = u * (BOWL_CAVITY_RADIUS - 0.005 + depth)
    res = contact_wrench(scene, pose(tuple(c)))
    assert res.count == 1
    # The cavity is a 5-times subdivided icosphere: its facets sit up to ~10 um inside the sphere.
    assert res.depths[0] == pytest.approx(depth, abs=2e-5)
    # Its facet normals differ from the sphere's radial direction by at most the facets' own
    # tilt, measured from the mesh (about 1.4 degrees). Across a crease band the contact is the
    # gradient of the blended potential, whose weights rise at most 1.5 / band (x^2 (3 - 2x)), so
    # its normal leans a little further: at most two tilts (1.53 tilts at worst in 20,000 random
    # poses and hypothesis's searches, at the shallowest depth, where the band is widest).
    angle = math.acos(min(1.0, float(res.normals_w[0] @ -u)))
    assert angle <= 2.0 * _cavity_facet_tilt() + 1e-6


@functools.cache
def _cavity_facet_tilt() -> float:
    """Largest angle (rad) between a cavity facet's normal and the radial line through its corners."""
    mesh = _scene_of("bowl.ply").objects[0].mesh
    radii = np.linalg.norm(mesh.vertices, axis=1)
    cavity = np.all(np.abs(radii[mesh.faces] - BOWL_CAVITY_RADIUS) < 1e-3, axis=1)
    corners = mesh.vertices[mesh.faces[cavity]]  # (k, 3, 3)
    radial = corners / np.linalg.norm(corners, axis=2, keepdims=True)
    # The cavity's surface normals point out of the solid, towards the centre: flip them.
    normal_radial = -mesh.face_normals[cavity]
    cos = np.einsum("kij,kj->ki", radial, normal_radial)
    return float(np.arccos(np.clip(cos.min(), -1.0, 1.0)))


def test_the_bowls_convex_hull_would_give_a_wrong_contact(tmp_path) -> None:
    bowl = ObjectSpec(name="bowl", mesh="bowl.ply", stiffness=K)
    scene = make_scene([bowl], sphere_tool(0.005))
    T = pose((0.0, 0.0, -BOWL_CAVITY_RADIUS + 0.004))  # 1 mm into the bottom of the cavity
    res = contact_wrench(scene, T)
    # A facet of the 5-times subdivided icosphere cavity tilts its normal by up to ~1.5 deg.
    np.testing.assert_allclose(res.force_w, [0, 0, K * 0.001], atol=0.03 * K * 0.001)
    hull_path = tmp_path / "hull.stl"
    scene.objects[0].mesh.convex_hull.export(hull_path)
    hull_scene = make_scene([ObjectSpec(name="hull", mesh=str(hull_path), stiffness=K)], sphere_tool(0.005))
    hull_res = contact_wrench(hull_scene, T)
    # The hull is solid there: the sphere's centre is buried 24 mm above the hull's bottom face
    # (z = -0.08), its nearest surface, and with no history it is pushed out through it: 87 N
    # down instead of 3 N up.
    assert hull_res.valid
    hull_bottom = float(scene.objects[0].mesh.bounds[0, 2])
    np.testing.assert_allclose(hull_res.force_w, [0, 0, -K * (0.005 + T[2, 3] - hull_bottom)], atol=1e-9)


def test_force_is_continuous_across_edges_and_vertices(tmp_path) -> None:
    block = ObjectSpec(name="block", mesh="peg_block.ply", stiffness=K)
    model = ContactModel(make_scene([block], sphere_tool(0.005)))
    x_rim = PEG_SPACING / 2 + RIM_RADIUS
    last = None
    # Slide at constant height from over the top face, over the rim edge, into the hole.
    for x in np.arange(x_rim + 0.004, x_rim - 0.008, -1e-4):
        res = model.wrench(pose((x, 0.0, 0.004)))
        assert res.valid
        if last is not None:
            assert np.linalg.norm(res.force_w - last) <= 2 * K * 1e-4
        last = res.force_w


# Depths up to just under 2 r: deeper, the centre is out of reach of the surface and feels nothing.
@given(
    d1=st.floats(1e-5, 0.0095),
    d2=st.floats(1e-5, 0.0095),
    x=st.floats(-0.1, 0.1),
    y=st.floats(-0.1, 0.1),
)
@settings(max_examples=40, deadline=None)
def test_force_is_monotonic_in_depth_on_the_terrain(d1: float, d2: float, x: float, y: float) -> None:
    scene = _scene_of("terrain.ply")
    mesh = scene.objects[0].mesh
    hit, _, _ = mesh.ray.intersects_location([[x, y, 1.0]], [[0.0, 0.0, -1.0]], multiple_hits=False)
    z_top = float(hit[0, 2])
    f1, f2 = (contact_wrench(scene, pose((x, y, z_top + 0.005 - d))).force_w for d in (d1, d2))
    assert (np.linalg.norm(f1) <= np.linalg.norm(f2) + 1e-9) == (d1 <= d2) or math.isclose(d1, d2, abs_tol=1e-9)
    assert f1[2] > 0
    assert f2[2] > 0


def test_no_pop_through_when_pushing_a_1mm_plate_10mm() -> None:
    thin = ObjectSpec(name="plate", box=(0.2, 0.2, 0.001), stiffness=K)  # faces at z = +-0.5 mm
    scene = make_scene([thin], sphere_tool(0.005))
    model = ContactModel(scene)
    z_touch = 0.0005 + 0.005
    forces = []
    for dz in np.linspace(0.0, 0.010, 201):
        res = model.wrench(pose((0.01, 0.02, z_touch - dz)))
        assert res.valid
        forces.append(res.force_w.copy())
    F = np.array(forces)
    np.testing.assert_allclose(F[:, 0:2], 0.0, atol=1e-9)
    assert np.all(np.diff(F[:, 2]) >= -1e-9)
    assert F[-1, 2] == pytest.approx(K * 0.010, rel=1e-6)
    # Without the memory the same final pose pushes the wrong way or not at all.
    assert contact_wrench(scene, pose((0.01, 0.02, z_touch - 0.010))).force_w[2] <= 0.0
    # Backing out releases the memory at the original surface.
    for dz in np.linspace(0.010, -0.0005, 211):
        res = model.wrench(pose((0.01, 0.02, z_touch - dz)))
        assert res.force_w[2] == pytest.approx(K * max(dz, 0.0), abs=1e-9)
    assert res.count == 0
    assert model.remembered == 0


def test_no_double_counting_over_shared_edges_and_vertices(tmp_path) -> None:
    # A 10 x 10 cm plate tessellated into 2048 top triangles: interior edges and vertices on a 6.25 mm grid.
    v, f = trimesh.remesh.subdivide_to_size(*_box_arrays((0.1, 0.1, 0.01)), max_edge=0.007)
    path = tmp_path / "tessellated.ply"
    trimesh.Trimesh(v, f).export(path)
    scene = make_scene([ObjectSpec(name="plate", mesh=str(path), stiffness=K)], sphere_tool(0.005))
    mesh = scene.objects[0].mesh
    top = mesh.vertices[np.isclose(mesh.vertices[:, 2], 0.005)]
    z_top = top[0, 2]  # 0.005 rounded to float32 by the file
    inner = top[(np.abs(top[:, 0]) < 0.04) & (np.abs(top[:, 1]) < 0.04)]
    vertex = inner[0]
    edge_mid = mesh.vertices[mesh.edges_unique].mean(axis=1)
    edge = edge_mid[
        (np.isclose(edge_mid[:, 2], 0.005)) & (np.abs(edge_mid[:, 0]) < 0.04) & (np.abs(edge_mid[:, 1]) < 0.04)
    ]
    face = mesh.triangles_center[(mesh.face_normals[:, 2] > 0.99)][5]
    depth = 0.001
    for p in (vertex, *edge[:10], face):
        res = contact_wrench(scene, pose((p[0], p[1], z_top + 0.005 - depth)))
        assert res.count == 1
        np.testing.assert_allclose(res.force_w, [0, 0, K * depth], atol=1e-9)


def _box_arrays(extents: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    box = trimesh.creation.box(extents=extents)
    return box.vertices, box.faces


def test_nan_pose_gives_an_invalid_zero_reading_then_recovers() -> None:
    model = ContactModel(make_scene([plane(K)]))
    good = pose((0.0, 0.0, R - 0.001))
    assert model.wrench(good).valid
    bad = good.copy()
    bad[0, 3] = math.nan
    res = model.wrench(bad)
    assert not res.valid
    assert res.error
    assert np.all(res.wrench_S == 0)
    assert np.all(res.wrench_MRF == 0)
    assert res.count == 0
    assert not model.wrench(good, np.array([0, 0, math.inf, 0, 0, 0])).valid
    res = model.wrench(good)
    assert res.valid
    assert res.force_w[2] == pytest.approx(K * 0.001)


def test_culling_agrees_with_fresh_queries_along_a_random_walk() -> None:
    objects = [
        ObjectSpec(name="block", mesh="peg_block.ply", stiffness=K),
        ObjectSpec(name="ball", sphere=0.02, pose=Pose((0.0, 0.06, 0.01)), stiffness=K),
    ]
    tool = ToolSpec(
        mass=0.5,
        inertia=(1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0),
        home=Pose(),
        capsules=(CapsuleSpec(start=(0.0, 0.0, 0.0), end=(0.05, 0.0, 0.0), radius=0.005),),
        spheres=(SphereSpec((0.0, 0.0, 0.02), 0.004),),
    )
    scene = make_scene(objects, tool)
    r_max = float(scene.tool.radii.max())
    model, scratch = ContactModel(scene), ContactModel(scene)
    rng = np.random.default_rng(1)
    p = np.array([0.0, 0.03, 0.01])
    angles = np.zeros(3)
    queries = []
    behind = 0
    # Steps of ~0.5 mm and ~0.6 deg (a fast hand at 1 kHz); the tool grazes the block and the ball
    # and is pushed deep into them. ``scratch`` has the same history (remembered surfaces) but
    # evaluates every pair from scratch.
    for _ in range(400):
        p = np.clip(p + rng.normal(0.0, 0.0005, 3), [-0.05, -0.02, 0.002], [0.05, 0.08, 0.03])
        angles = np.clip(angles + rng.normal(0.0, 0.01, 3), -0.2, 0.2)
        T = pose(tuple(p), tuple(angles))
        scratch.forget_caches()
        culled, fresh = model.wrench(T), scratch.wrench(T)
        np.testing.assert_allclose(culled.wrench_S, fresh.wrench_S, atol=1e-9)
        queries.append(culled.queries)
        behind += bool(np.any(culled.depths > r_max))
    assert behind > 10  # the walk does push centres behind surfaces
    assert fresh.queries == len(scene.tool.radii) * 2
    assert np.mean(queries) < 0.5 * fresh.queries


def test_far_objects_cost_no_queries() -> None:
    objects = [plane(K)] + [
        ObjectSpec(name=f"far{i}", box=(0.01, 0.01, 0.01), pose=Pose((1.0 + 0.1 * i, 0.0, 0.0)), stiffness=K)
        for i in range(99)
    ]
    model = ContactModel(make_scene(objects))
    T = pose((0.0, 0.0, R - 0.001))
    model.wrench(T)
    res = model.wrench(T)
    assert res.queries == 1
    assert res.count == 1


def test_centre_exactly_on_the_surface_pushes_out_with_depth_r() -> None:
    res = contact_wrench(_plane_scene(), pose((0.013, 0.021, 0.0)))
    assert res.valid
    assert res.count == 1
    np.testing.assert_allclose(res.force_w, [0, 0, K * R], atol=1e-9)


def test_centre_exactly_on_a_vertical_face_pushes_out_sideways() -> None:
    block = ObjectSpec(name="block", box=(0.1, 0.1, 0.1), stiffness=K)  # faces at +-0.05
    res = contact_wrench(make_scene([block]), pose((0.05, 0.013, 0.021)))
    assert res.valid
    np.testing.assert_allclose(res.force_w, [K * R, 0, 0], atol=1e-9)


def test_damping_and_friction_use_the_contact_point_velocity() -> None:
    scene = make_scene([plane(K, damping=20.0, friction=0.5)])
    depth, vz, vx = 0.002, -0.01, 0.05  # pressing in at 1 cm/s while sliding at 5 cm/s
    res = contact_wrench(scene, pose((0.0, 0.0, R - depth)), np.array([vx, 0.0, vz, 0.0, 0.0, 0.0]))
    fn = K * depth + 20.0 * 0.01
    np.testing.assert_allclose(res.force_w, [-0.5 * fn, 0.0, fn], atol=1e-9)
    # Pulling out faster than the spring pushes: the normal force clamps at 0 (no sticking).
    res = contact_wrench(scene, pose((0.0, 0.0, R - depth)), np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(res.force_w, 0.0, atol=1e-12)


def test_cached_triangle_scans_agree_with_fresh_gathers_with_the_pegs_in_the_holes() -> None:
    # Small steps inside the holes: most queries scan a pair's cached candidate triangles instead
    # of gathering them from the grid; each tick must match a fresh model (every pair gathered).
    scene = load_scene("peg_in_hole")
    model = ContactModel(scene)
    rng = np.random.default_rng(2)
    p = np.array([0.0007, 0.0, -0.01])
    angles = np.zeros(3)
    counts = []
    scans = 0
    for _ in range(300):
        p = np.clip(p + rng.normal(0.0, 3e-5, 3), [-0.001, -0.001, -0.011], [0.001, 0.001, -0.009])
        angles = np.clip(angles + rng.normal(0.0, 2e-4, 3), -3e-3, 3e-3)
        T = pose(tuple(p), tuple(angles))
        cached, fresh = model.wrench(T), contact_wrench(scene, T)
        assert cached.valid
        assert fresh.valid
        assert cached.count == fresh.count
        np.testing.assert_allclose(cached.wrench_S, fresh.wrench_S, atol=1e-9)
        np.testing.assert_allclose(cached.points_w, fresh.points_w, atol=1e-12)
        np.testing.assert_allclose(cached.depths, fresh.depths, atol=1e-12)
        counts.append(cached.count)
        scans += cached.queries - cached.gathers
    assert min(counts) >= 2
    assert fresh.gathers == fresh.queries
    assert scans > 0
