"""Issue 12: several contacts per object, no phantom forces, degenerate positions, open meshes,
contact-point friction and checked poses; each against an analytic answer or a brute force."""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from world_helpers import make_scene, plane, pose, sphere_tool

from app.errors import ConfigError, ContactInputError
from app.world import ContactModel, contact_wrench
from app.world.contact.force import V_SLIP
from app.world.scene import ObjectSpec, Pose, Scene, build_scene, load_scene

K = 3000.0
r = 0.005


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> trimesh.Trimesh:
    lo_a, hi_a = np.array(lo), np.array(hi)
    box = trimesh.creation.box(extents=hi_a - lo_a)
    box.apply_translation((lo_a + hi_a) / 2)
    return box


FLOOR = ((-0.05, -0.05, -0.02), (0.0, 0.05, 0.0))  # top face z = 0 for x < 0
WALL = ((0.0, -0.05, -0.02), (0.02, 0.05, 0.05))  # face x = 0 for z > 0


def _mesh_file(tmp: Path, name: str, mesh: trimesh.Trimesh) -> str:
    path = tmp / f"{name}.ply"
    mesh.export(path)
    return str(path)


@functools.cache
def _meshes(tmp: Path) -> dict[str, str]:
    """The non-convex test meshes as files: an L-block, a block with a square pocket, and the shipped bowl and peg block."""
    floor = _box(FLOOR[0], (0.02, 0.05, 0.0))
    l_block = trimesh.boolean.union([floor, _box(*WALL)], engine="manifold")
    block = _box((-0.05, -0.05, -0.04), (0.05, 0.05, 0.0))
    pocket = trimesh.boolean.difference([block, _box((-0.02, -0.02, -0.02), (0.02, 0.02, 0.01))], engine="manifold")
    return {
        "l_block": _mesh_file(tmp, "l_block", l_block),
        "pocket": _mesh_file(tmp, "pocket", pocket),
        "bowl": "bowl.ply",
        "peg_block": "peg_block.ply",
    }


@pytest.fixture(scope="module")
def meshes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    return _meshes(tmp_path_factory.mktemp("meshes"))


def _scene(path: str, **kw: float) -> Scene:
    return make_scene([ObjectSpec(name="m", mesh=path, stiffness=K, **kw)], sphere_tool(r))


# --- 1. Concave edges: one mesh behaves like the two objects it is made of. ---


def test_l_block_corner_matches_the_two_object_split(meshes: dict[str, str]) -> None:
    one = _scene(meshes["l_block"])
    two = make_scene(
        [
            ObjectSpec(name="floor", box=(0.05, 0.1, 0.02), pose=_centre(*FLOOR), stiffness=K),
            ObjectSpec(name="wall", box=(0.02, 0.1, 0.07), pose=_centre(*WALL), stiffness=K),
        ],
        sphere_tool(r),
    )
    # 3 mm from both faces, and 20 um either side of the bisector: both faces push, 2 mm deep each.
    for dx in (-2e-5, 0.0, 2e-5):
        c = (-0.003 + dx, 0.0, 0.003 + dx)  # dx > 0: nearer the wall than the floor
        res = contact_wrench(one, pose(c))
        expected = [-K * (r - 0.003 + dx), 0.0, K * (r - 0.003 - dx)]
        np.testing.assert_allclose(res.force_w, expected, atol=1e-9)
        np.testing.assert_allclose(res.force_w, contact_wrench(two, pose(c)).force_w, atol=1e-9)
        assert res.count == 2
    # And everywhere in the corner's quadrant within reach of both faces.
    rng = np.random.default_rng(0)
    for _ in range(200):
        c = (-rng.uniform(0.0, 0.006), rng.uniform(-0.01, 0.01), rng.uniform(0.0, 0.006))
        np.testing.assert_allclose(
            contact_wrench(one, pose(c)).force_w, contact_wrench(two, pose(c)).force_w, atol=1e-9
        )


def _centre(lo: tuple[float, ...], hi: tuple[float, ...]) -> Pose:
    return Pose(tuple((a + b) / 2 for a, b in zip(lo, hi, strict=True)))


def test_force_is_continuous_sliding_into_the_corner(meshes: dict[str, str]) -> None:
    model = ContactModel(_scene(meshes["l_block"]))
    last = None
    step = 1e-5
    # Along the floor at 3 mm height, from far from the wall into the corner and up the wall.
    path = [(x, 0.0, 0.003) for x in np.arange(-0.012, -0.003, step)]
    path += [(-0.003, 0.0, z) for z in np.arange(0.003, 0.012, step)]
    for c in path:
        f = model.wrench(pose(c)).force_w
        if last is not None:
            assert np.linalg.norm(f - last) <= 2 * K * step
        last = f


def _pocket_corner(scene: Scene) -> float:
    """The pocket's walls x = y = a and floor z = a, a = -0.02 as stored (float32) in the file."""
    v = scene.objects[0].mesh.vertices
    return float(v[np.argmin(np.abs(v[:, 0] + 0.02)), 0])


def test_pocket_corner_pushes_off_all_three_faces(meshes: dict[str, str]) -> None:
    scene = _scene(meshes["pocket"])
    a = _pocket_corner(scene)
    res = contact_wrench(scene, pose((a + 0.002, a + 0.002, a + 0.002)))  # 2 mm from all three faces
    np.testing.assert_allclose(res.force_w, [K * 0.003] * 3, atol=1e-9)
    assert res.count == 3


# --- 2. Memory never outlives its geometry. ---


def test_pop_through_memory_is_released_off_the_plate() -> None:
    plate = ObjectSpec(name="plate", box=(0.1, 0.1, 0.002), stiffness=K)  # faces at z = +-1 mm
    scene = make_scene([plate], sphere_tool(r))
    model = ContactModel(scene)
    for z in np.arange(0.006, -0.0035, -1e-4):  # through the plate in 0.1 mm steps
        assert model.wrench(pose((0.0, 0.0, z))).force_w[2] > -1e-9
    assert model.remembered == 1
    res = model.wrench(pose((0.0, 0.0, -0.0035)))
    assert res.force_w[2] == pytest.approx(K * (r + 0.0045))  # still pushed back up through the top
    mesh = scene.objects[0].mesh
    for x in np.arange(0.0, 0.3, 5e-4):  # slide off the edge at x = 0.05, then 25 cm on
        c = np.array([x, 0.0, -0.0035])
        res = model.wrench(pose(tuple(c)))
        gap = float(trimesh.proximity.ProximityQuery(mesh).signed_distance([c])[0])
        if np.any(res.force_w != 0.0):
            assert abs(gap) <= r + 1e-9  # a force implies geometry within the radius
    assert np.all(res.force_w == 0.0)
    assert model.remembered == 0
    np.testing.assert_array_equal(res.force_w, contact_wrench(scene, pose(tuple(c))).force_w)


# --- 3. Degenerate positions push. ---


def test_centre_on_the_inside_edge_and_corner_of_a_pocket_pushes(meshes: dict[str, str]) -> None:
    scene = _scene(meshes["pocket"])
    a = _pocket_corner(scene)
    res = contact_wrench(scene, pose((a, 0.0, a)))  # on the floor-wall edge
    assert res.valid
    np.testing.assert_allclose(res.force_w, [K * r, 0.0, K * r], atol=1e-9)
    res = contact_wrench(scene, pose((a, a, a)))  # in the corner
    np.testing.assert_allclose(res.force_w, [K * r] * 3, atol=1e-9)


def test_centre_on_any_vertex_of_the_peg_block_pushes_out() -> None:
    scene = load_scene("peg_in_hole")
    scene = build_scene(dataclasses.replace(scene.spec, tool=sphere_tool(r)))
    mesh = scene.objects[0].mesh
    rng = np.random.default_rng(3)
    for v in rng.choice(len(mesh.vertices), 60, replace=False):
        res = contact_wrench(scene, pose(tuple(mesh.vertices[v])))
        assert res.valid
        assert res.count >= 1
        assert np.linalg.norm(res.force_w) >= K * r * 0.99  # depth r along an outward direction
        # Outward: a small step along the force leaves the solid.
        probe = mesh.vertices[v] + 1e-5 * res.force_w / np.linalg.norm(res.force_w)
        assert not mesh.contains([probe])[0]


# --- 4. Open, one-sided, inside-out and non-finite meshes. ---


def _write_scene(tmp: Path, mesh_path: str) -> Path:
    path = tmp / "s.toml"
    path.write_text(
        f'name = "s"\n[[objects]]\nname = "thing"\nmesh = "{mesh_path}"\nstiffness = 1000.0\n'
        "[tool]\nmass = 0.5\ninertia = [1e-3, 1e-3, 1e-3, 0, 0, 0]\nhome = { position = [0, 0, 0.1] }\n"
        "[[tool.spheres]]\ncenter = [0, 0, 0]\nradius = 0.005\n"
    )
    return path


@pytest.mark.parametrize(
    "corners",
    [
        [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]],  # axis-aligned
        [[0, 0, 0], [0.1, 0, 0.03], [0, 0.1, 0.05]],  # tilted: the same rule
    ],
)
def test_a_single_triangle_is_refused_in_any_orientation(tmp_path: Path, corners: list) -> None:
    path = _mesh_file(tmp_path, "tri", trimesh.Trimesh(corners, [[0, 1, 2]], process=False))
    with pytest.raises(ConfigError, match="not closed") as info:
        load_scene(_write_scene(tmp_path, path))
    assert info.value.field == "objects[0].mesh"


def test_a_nan_vertex_is_refused_naming_the_object(tmp_path: Path) -> None:
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 1\nf 1 2 3\nf 1 2 4\nf 2 3 4\nf 1 3 4\n")
    with pytest.raises(ConfigError, match="non-finite") as info:
        load_scene(_write_scene(tmp_path, str(path)))
    assert info.value.field == "objects[0].mesh"


def test_an_inside_out_box_is_reoriented(tmp_path: Path) -> None:
    box = _box((-0.05, -0.05, -0.02), (0.05, 0.05, 0.0))
    inverted = trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False)
    assert inverted.volume < 0
    scene = load_scene(_write_scene(tmp_path, _mesh_file(tmp_path, "inv", inverted)))
    res = contact_wrench(scene, pose((0.01, 0.0, 0.004)))
    np.testing.assert_allclose(res.force_w, [0.0, 0.0, 1000.0 * 0.001], atol=1e-6)  # float32 file


def test_free_space_above_a_pocket_feels_nothing(meshes: dict[str, str]) -> None:
    scene = _scene(meshes["pocket"])
    res = contact_wrench(scene, pose((0.0, 0.0, 0.003 + r)))  # 3 mm above the opening
    assert res.count == 0


# --- 5. Friction and damping at the contact point. ---


def test_friction_uses_the_contact_point_velocity_of_a_spinning_tool() -> None:
    scene = make_scene([plane(K, friction=0.5)], sphere_tool(r))  # {MRF} at the sphere centre
    depth = 0.001
    res = contact_wrench(scene, pose((0.0, 0.0, r - depth)), np.array([0.0, 0.0, 0.0, 0.0, 10.0, 0.0]))
    # The contact point is r - depth below the centre: it slips at 10 * 0.004 = 0.04 m/s along -x.
    slip = 10.0 * (r - depth)
    assert slip > V_SLIP
    fn = K * depth
    np.testing.assert_allclose(res.force_w, [0.5 * fn, 0.0, fn], atol=1e-9)


# --- 6. Poses and twists are checked. ---


def test_a_mirrored_or_scaled_pose_is_refused() -> None:
    model = ContactModel(load_scene("probe"))
    T = pose((0.0, 0.0, 0.004))
    mirrored = T.copy()
    mirrored[0, 0] = -1.0
    scaled = T.copy()
    scaled[0:3, 0:3] *= 1.001
    for bad in (mirrored, scaled, np.eye(3), np.ones((4, 4))):
        with pytest.raises(ContactInputError):
            model.wrench(bad)
    with pytest.raises(ContactInputError):
        model.wrench(T, np.zeros(5))
    with pytest.raises(ContactInputError):
        model.wrench(T, ["a"] * 6)  # type: ignore[arg-type]
    assert model.wrench(T.tolist()).count == 1  # type: ignore[arg-type]  # any array-like of numbers


# --- The fast path against an exhaustive one, and invariants along random walks. ---


def _exhaustive(scene: Scene) -> Scene:
    """The same scene with candidate pruning off: every triangle within reach is scanned."""
    packed = scene.packed
    objs = packed.objs.copy()
    objs["prune"] = 0
    exhaustive = dataclasses.replace(scene)
    exhaustive.__dict__["packed"] = dataclasses.replace(packed, objs=objs)
    return exhaustive


def _winding(mesh: trimesh.Trimesh, p: np.ndarray) -> float:
    """Generalised winding number of the closed mesh at p (1 inside, 0 outside), Van Oosterom & Strackee."""
    a, b, c = (mesh.vertices[mesh.faces[:, k]] - p for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la
    den += np.einsum("ij,ij->i", c, a) * lb
    return float(np.sum(2.0 * np.arctan2(num, den)) / (4.0 * math.pi))


@pytest.mark.parametrize("name", ["l_block", "pocket", "bowl", "peg_block"])
def test_fast_path_matches_the_exhaustive_one_along_random_walks(meshes: dict[str, str], name: str) -> None:
    scene = _scene(meshes[name])
    reference = _exhaustive(scene)
    mesh = scene.objects[0].mesh
    query = trimesh.proximity.ProximityQuery(mesh)
    model, ref_model = ContactModel(scene), ContactModel(reference)
    rng = np.random.default_rng(7)
    # Start on random surface points, pushed in or pulled out by up to 1.2 r, then walk. The
    # reference has the same history (remembered surfaces) but scans every triangle afresh.
    points, _ = trimesh.sample.sample_surface(mesh, 40, seed=7)
    for start in points:
        model.reset()
        ref_model.reset()
        c = start + rng.normal(0.0, r, 3)
        last_f = last_points = None
        for _ in range(25):
            step = rng.normal(0.0, 2e-5, 3)
            c = c + step
            ref_model.forget_caches()
            fast, ref = model.wrench(pose(tuple(c))), ref_model.wrench(pose(tuple(c)))
            assert fast.valid
            assert fast.count == ref.count
            np.testing.assert_allclose(fast.force_w, ref.force_w, atol=1e-9)
            np.testing.assert_allclose(fast.points_w, ref.points_w, atol=1e-12)
            np.testing.assert_allclose(fast.depths, ref.depths, atol=1e-12)
            distance = float(abs(query.signed_distance([c])[0]))
            inside = _winding(mesh, c) > 0.5
            if fast.count:
                # Outside the solid, no force without geometry within the radius, and the deepest
                # contact is the mesh's nearest point; inside, deeper than r (a remembered
                # surface holds however far the centre is from every face).
                if inside:
                    assert np.max(fast.depths) >= r - 1e-9
                else:
                    assert distance <= r + 1e-9
                    assert np.max(fast.depths) == pytest.approx(r - distance, abs=1e-6)
            else:
                assert distance >= r - 1e-9
            # Outside the solid: continuous under small motions unless a contact point jumped (a
            # medial axis) or a contact appeared (at zero depth, or behind a blended crease).
            outside = _winding(mesh, c) < 0.5
            if outside and last_f is not None and len(last_points) == fast.count:
                moved = np.max(np.linalg.norm(fast.points_w - last_points, axis=1), initial=0.0)
                if moved < 50 * np.linalg.norm(step):
                    assert np.linalg.norm(fast.force_w - last_f) <= 5 * K * np.linalg.norm(step) + 1e-9
            last_f, last_points = fast.force_w, fast.points_w
