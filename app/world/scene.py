"""Scene loading and building: ``scenes/<name>.toml`` -> :class:`Scene` (objects, tool, slave gains, task).

The file's schema and ranges are :mod:`app.world.scene_file` (re-exported here, so
``from app.world.scene import SceneFile, ToolSpec, ...`` keeps working); this module reads
meshes, builds the tool's sphere set and the :class:`Scene`. The file format is documented in
``scenes/README.md``. Loading is strict (via :func:`app.config.from_dict`): an unknown field,
a missing, unreadable, oversized or degenerate mesh, or a value outside its range raises one
:class:`~app.errors.ConfigError` naming the file and the field, and no warning is printed
before it (warnings are held back until the whole scene has loaded).

Frames: {w} the slave world, {T} the tool body (the frame the tool geometry and inertia are
written in), {MRF} the moving reference frame under Cartesian control, {S} the F/T sensor.
Static objects' pose is baked into their vertices at load time: every :class:`WorldObject`
mesh is in {w}. A dynamic object (``[objects.dynamic]``) is a :class:`Body` instead: its mesh
stays in its own frame {B} (the file's object frame, moved by :mod:`app.world.dynamics`), with
the mass properties of the solid mesh.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
import trimesh

from app.config import deferred_warnings, from_dict, identity_digest, load_toml, require_file
from app.errors import ConfigError
from app.spatial import Array, invert_pose
from app.world.collision import CollisionMesh, PackedMeshes, pack_meshes
from app.world.mesh_check import checked_mesh, declared_faces
from app.world.scene_file import (
    MAX_MESH_BYTES,
    MAX_MESH_FACES,
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
    inertia_matrix,
)

__all__ = [
    "ASSETS_DIR",
    "DEFAULT_SCENE",
    "ROOT_DIR",
    "SCENES_DIR",
    "Body",
    "BoxSpec",
    "CapsuleSpec",
    "DynamicSpec",
    "ObjectSpec",
    "Pose",
    "Scene",
    "SceneFile",
    "SlaveGains",
    "SphereSpec",
    "TaskSpec",
    "ToolGeometry",
    "ToolSpec",
    "WorldObject",
    "available_scenes",
    "box_spheres",
    "build_object",
    "build_scene",
    "capsule_spheres",
    "load_scene",
    "resolve_scene_path",
    "with_slave",
]

ROOT_DIR = Path(__file__).resolve().parents[2]
SCENES_DIR = ROOT_DIR / "scenes"
ASSETS_DIR = ROOT_DIR / "assets"
DEFAULT_SCENE = "probe"


@dataclass(frozen=True)
class WorldObject:
    """A loaded static object: its triangle mesh in {w} and contact parameters.

    Attributes:
        name: From the scene file.
        mesh: Triangle mesh with vertices in {w} (the object pose is already applied).
        stiffness, damping, friction: As in :class:`ObjectSpec`.
        collision: Its FCL BVH and pseudonormals, shared by every contact model of the scene.
    """

    name: str
    mesh: trimesh.Trimesh
    stiffness: float
    damping: float
    friction: float
    collision: CollisionMesh


@dataclass(frozen=True)
class Body:
    """A loaded dynamic object: its mesh in its own frame {B} and its mass properties.

    Attributes:
        object: The object with its mesh in {B} (contact parameters as for a static object).
        spec: Its file entry (shape, pose, :class:`DynamicSpec`).
        mass: Mass (kg).
        com_B: Centre of mass in {B} (m), (3,).
        inertia_B: Inertia about the centre of mass in {B} axes (kg m^2), (3, 3).
        T_w_B: Initial pose of {B} in {w}, (4, 4).
        twist: Initial twist ``[v; w]`` of {B} in {w} (v of its origin), (6,).
    """

    object: WorldObject
    spec: ObjectSpec
    mass: float
    com_B: Array
    inertia_B: Array
    T_w_B: Array
    twist: Array

    @property
    def name(self) -> str:
        return self.object.name

    @property
    def dynamic(self) -> DynamicSpec:
        assert self.spec.dynamic is not None
        return self.spec.dynamic


@dataclass(frozen=True)
class ToolGeometry:
    """The tool as a point shell of spheres, plus its frames and inertia.

    Attributes:
        centers_T: Sphere centres in {T} (m), shape (n, 3).
        radii: Sphere radii (m), shape (n,).
        T_T_MRF: Pose of {MRF} in {T}, (4, 4).
        T_T_S: Pose of {S} in {T}, (4, 4).
        mass: Outboard mass (kg).
        com_T: Centre of mass in {T} (m), shape (3,).
        inertia_T: Inertia about the centre of mass in {T} axes (kg m^2), (3, 3).
        T_w_MRF_home: Home pose of {MRF} in {w}, (4, 4).
    """

    centers_T: Array
    radii: Array
    T_T_MRF: Array
    T_T_S: Array
    mass: float
    com_T: Array
    inertia_T: Array
    T_w_MRF_home: Array

    @property
    def T_MRF_S(self) -> Array:
        """Pose of {S} in {MRF}, (4, 4)."""
        return invert_pose(self.T_T_MRF) @ self.T_T_S


@dataclass(frozen=True)
class Scene:
    """A loaded scene: what :class:`~app.world.contact.ContactModel` and the slave consume.

    Attributes:
        path: The scene file (or ``None`` for a scene built in code).
        spec: The parsed file.
        objects: Static objects with meshes in {w}.
        tool: The tool's sphere set, frames and inertia.
        gravity_w: Gravity in {w} (m/s^2), shape (3,).
        bodies: Dynamic objects (meshes in their own frames), in file order.
    """

    path: Path | None
    spec: SceneFile
    objects: tuple[WorldObject, ...]
    tool: ToolGeometry
    gravity_w: Array
    bodies: tuple[Body, ...] = ()

    @property
    def name(self) -> str:
        return self.spec.name

    @cached_property
    def identity(self) -> str:
        """A digest of the world as simulated (:func:`~app.config.identity_digest`): every object's
        name, contact parameters and mesh in {w} (its mesh in {B} and mass properties for a dynamic
        one), the tool's spheres, frames and inertia, and gravity. The scene's name and description
        and the mesh file names are left out (the meshes' contents count), and so is the tool's
        home, which a session or the experiment moves. A log keeps it (``scene_identity``) so a replay can tell the scene file
        it names from the one it was run with."""
        parts: list[object] = []
        for o in (*self.objects, *(b.object for b in self.bodies)):
            parts += [[o.name, o.stiffness, o.damping, o.friction], o.mesh.vertices, o.mesh.faces]
        for b in self.bodies:
            parts += [[b.mass], b.com_B, b.inertia_B, b.T_w_B, b.twist]
        tool = self.tool
        parts += [tool.centers_T, tool.radii, tool.T_T_MRF, tool.T_T_S, [tool.mass], tool.com_T, tool.inertia_T]
        return identity_digest(*parts, self.gravity_w)

    @cached_property
    def packed(self) -> PackedMeshes:
        """All objects' meshes packed for the compiled contact kernel (built on first use, then shared)."""
        return pack_meshes([o.collision for o in self.objects])


def capsule_spheres(spec: CapsuleSpec) -> Array:
    """Centres (n, 3) of a chain of spheres covering a capsule, no two neighbours > spacing apart."""
    start = np.array(spec.start, dtype=float)
    end = np.array(spec.end, dtype=float)
    return start + np.linspace(0.0, 1.0, spec.sphere_count())[:, None] * (end - start)


def box_spheres(spec: BoxSpec) -> Array:
    """Centres (n, 3) of spheres tangent to the inside of each face of the box, in the box frame."""
    half = np.array(spec.extents, dtype=float) / 2.0 - spec.sphere_radius  # centre-plane half extents
    axes = [np.linspace(-h, h, n) if h > 0 else np.zeros(1) for h, n in zip(half, spec.grid(), strict=True)]
    points = []
    for k in range(3):
        grids = np.meshgrid(*[axes[j] if j != k else np.array([-half[k], half[k]]) for j in range(3)], indexing="ij")
        points.append(np.stack([g.ravel() for g in grids], axis=1))
    return np.unique(np.round(np.concatenate(points), 12), axis=0)


def _tool_geometry(spec: ToolSpec) -> ToolGeometry:
    centers: list[Array] = []
    radii: list[Array] = []
    for s in spec.spheres:
        centers.append(np.array([s.center], dtype=float))
        radii.append(np.array([s.radius]))
    for c in spec.capsules:
        pts = capsule_spheres(c)
        centers.append(pts)
        radii.append(np.full(len(pts), c.radius))
    for b in spec.boxes:
        T = b.pose.matrix()
        pts = box_spheres(b)
        centers.append(pts @ T[0:3, 0:3].T + T[0:3, 3])
        radii.append(np.full(len(pts), b.sphere_radius))
    return ToolGeometry(
        centers_T=np.ascontiguousarray(np.concatenate(centers)),
        radii=np.concatenate(radii),
        T_T_MRF=spec.mrf.matrix(),
        T_T_S=spec.sensor.matrix(),
        mass=spec.mass,
        com_T=np.array(spec.com, dtype=float),
        inertia_T=inertia_matrix(spec.inertia),
        T_w_MRF_home=spec.home.matrix(),
    )


def _primitive_mesh(spec: ObjectSpec) -> trimesh.Trimesh:
    if spec.box is not None:
        return trimesh.creation.box(extents=spec.box)
    if spec.sphere is not None:
        return trimesh.creation.icosphere(subdivisions=4, radius=spec.sphere)
    if spec.cylinder is not None:
        return trimesh.creation.cylinder(radius=spec.cylinder[0], height=spec.cylinder[1], sections=128)
    assert spec.plane is not None
    t = spec.plane_thickness
    m = trimesh.creation.box(extents=(spec.plane[0], spec.plane[1], t))
    m.apply_translation((0.0, 0.0, -t / 2))
    return m


def _check_faces(faces: int, path: Path, source: str | Path, field_name: str) -> None:
    if faces > MAX_MESH_FACES:
        raise ConfigError(source, field_name, f"{path.name} has {faces} faces (at most {MAX_MESH_FACES})")


def _load_mesh(path: Path, source: str | Path, field_name: str) -> trimesh.Trimesh:
    require_file(path, source, field_name, f"mesh file not found: {path}")
    if path.stat().st_size > MAX_MESH_BYTES:
        raise ConfigError(source, field_name, f"{path.name} is larger than {MAX_MESH_BYTES // 2**20} MiB")
    # Checked before trimesh spends memory on the file (a 5M-triangle STL took 2.4 GB), from its
    # header or a byte scan, and again on the mesh built, for formats with no cheap count.
    _check_faces(declared_faces(path) or 0, path, source, field_name)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for a bad file
        reason = " ".join(str(exc).split())[:200]
        raise ConfigError(source, field_name, f"cannot read mesh {path.name}: {reason}") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise ConfigError(source, field_name, f"{path.name} holds no triangle mesh")
    _check_faces(len(loaded.faces), path, source, field_name)
    return loaded


def build_object(spec: ObjectSpec, source: str | Path, field_path: str, pose: bool = True) -> WorldObject:
    """Make the {w} mesh of one object (its own frame's if not ``pose``), checking it is usable for contact.

    Raises:
        ConfigError: naming ``<field_path>.<shape>``: the mesh is missing, unreadable or too large,
            or fails :func:`~app.world.mesh_check.checked_mesh` (non-finite vertices, degenerate,
            open or inconsistently wound).
    """
    mesh_field = f"{field_path}.{spec.shape}"
    if spec.mesh is not None:
        p = Path(spec.mesh)
        mesh = _load_mesh(p if p.is_absolute() else ASSETS_DIR / p, source, mesh_field)
    else:
        mesh = _primitive_mesh(spec)
    mesh = checked_mesh(mesh, source, mesh_field)
    if pose:
        mesh.apply_transform(spec.pose.matrix())
    return WorldObject(spec.name, mesh, spec.stiffness, spec.damping, spec.friction, CollisionMesh(mesh))


def build_body(spec: ObjectSpec, source: str | Path, field_path: str) -> Body:
    """A dynamic object: its mesh in {B} and the mass properties of the solid it bounds."""
    assert spec.dynamic is not None
    obj = build_object(spec, source, field_path, pose=False)
    volume = float(obj.mesh.volume)
    d = spec.dynamic
    mass = d.mass if d.mass is not None else d.density * volume  # type: ignore[operator]
    if not mass >= 1e-6:
        raise ConfigError(source, f"{field_path}.dynamic.density", f"the mass {mass:.3g} kg is below 1e-6 kg")
    # trimesh's moment_inertia is for its default density 1 kg/m^3: scale it to the mass.
    inertia = np.asarray(obj.mesh.moment_inertia, dtype=float) * (mass / volume)
    return Body(
        obj,
        spec,
        mass,
        np.asarray(obj.mesh.center_mass, dtype=float),
        inertia,
        spec.pose.matrix(),
        np.array(d.twist, dtype=float),
    )


def build_scene(spec: SceneFile, source: str | Path = "<scene>", path: Path | None = None) -> Scene:
    """Build a :class:`Scene` from a parsed :class:`SceneFile` (also for scenes made in code).

    Warnings (a mesh that is not watertight) are issued only once the whole scene has built.
    """
    with deferred_warnings():
        objects = tuple(
            build_object(o, source, f"objects[{i}]") for i, o in enumerate(spec.objects) if o.dynamic is None
        )
        bodies = tuple(
            build_body(o, source, f"objects[{i}]") for i, o in enumerate(spec.objects) if o.dynamic is not None
        )
        tool = _tool_geometry(spec.tool)
        return Scene(path, spec, objects, tool, np.array(spec.gravity, dtype=float), bodies)


def with_slave(scene: Scene, kind: str) -> Scene:
    """``scene`` with another slave (``"tool"`` or an arm name, see ``SlaveGains.kind``).

    Raises:
        InvalidField: ``kind`` is neither ``"tool"`` nor a shipped arm.
    """
    if kind == scene.spec.slave.kind:
        return scene
    spec = dataclasses.replace(scene.spec, slave=dataclasses.replace(scene.spec.slave, kind=kind))
    out = dataclasses.replace(scene, spec=spec)
    # The objects are the same: share their packed meshes (a cached property) rather than repack.
    out.__dict__["packed"] = scene.packed
    return out


def with_home_offset(scene: Scene, offset_w: Array) -> Scene:
    """``scene`` with the tool's home ({MRF}'s starting pose) translated by ``offset_w`` (m, {w}).

    The experiment starts each operator's run with the pegs over where that operator believes the
    holes are (:meth:`~app.session.operators.OperatorParams.aim_offset`)."""
    offset = np.asarray(offset_w, dtype=float)
    home = scene.spec.tool.home
    x, y, z = (float(v) for v in np.array(home.position) + offset)
    tool_spec = dataclasses.replace(scene.spec.tool, home=dataclasses.replace(home, position=(x, y, z)))
    T_home = scene.tool.T_w_MRF_home.copy()
    T_home[0:3, 3] += offset
    out = dataclasses.replace(
        scene,
        spec=dataclasses.replace(scene.spec, tool=tool_spec),
        tool=dataclasses.replace(scene.tool, T_w_MRF_home=T_home),
    )
    # The objects are the same: share their packed meshes (a cached property) rather than repack.
    out.__dict__["packed"] = scene.packed
    return out


def resolve_scene_path(name_or_path: str | Path) -> Path:
    """A scene name (``"probe"``) or a path to a ``.toml`` file."""
    p = Path(name_or_path)
    return p if p.suffix == ".toml" else SCENES_DIR / f"{name_or_path}.toml"


def available_scenes() -> list[str]:
    """Names of the scenes shipped in ``scenes/``."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def load_scene(name_or_path: str | Path = DEFAULT_SCENE) -> Scene:
    """Load a scene by name or path; meshes are read relative to ``assets/``.

    A process loads each scene file once while it is unchanged on disk (same modification time
    and size) and shares the :class:`Scene`, which is immutable, with its packed meshes: an
    experiment or a sweep builds a session per run, and building the peg block's contact grid
    costs ~0.1 s, a third of a run. The file's meshes are not watched, and a mesh warning is
    issued at the first load only.

    Raises:
        ConfigError: naming the file and the field, for any malformed entry.
    """
    path = resolve_scene_path(name_or_path)
    require_file(path, path, "<file>", f"no such scene (shipped scenes: {', '.join(available_scenes())})")
    stat = path.stat()
    return _load_scene(path, stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=16)
def _load_scene(path: Path, mtime_ns: int, size: int) -> Scene:
    """:func:`load_scene` of a file as it is at ``mtime_ns`` (ns) with ``size`` (bytes)."""
    spec = from_dict(SceneFile, load_toml(path), path)
    return build_scene(spec, path, path)
