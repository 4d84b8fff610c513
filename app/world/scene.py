"""Scene files: ``scenes/<name>.toml`` -> :class:`Scene` (objects, tool, slave gains, task).

The file format is documented in ``scenes/README.md``. Loading is strict (via
:func:`app.config.from_dict`): an unknown field, a missing, unreadable or degenerate mesh, or
a bad value raises one :class:`~app.errors.ConfigError` naming the file and the field.

Frames: {w} the slave world, {T} the tool body (the frame the tool geometry and inertia are
written in), {MRF} the moving reference frame under Cartesian control, {S} the F/T sensor.
Objects are static, so their pose is baked into their vertices at load time: every
:class:`WorldObject` mesh is in {w}.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh

from app.config import from_dict, load_toml
from app.errors import ConfigError, InvalidField
from app.spatial import Array, invert_pose, make_pose, quat_to_matrix, zyx_to_matrix
from app.world.collision import CollisionMesh, PackedMeshes, pack_meshes
from app.world.mesh_check import checked_mesh

ROOT_DIR = Path(__file__).resolve().parents[2]
SCENES_DIR = ROOT_DIR / "scenes"
ASSETS_DIR = ROOT_DIR / "assets"
DEFAULT_SCENE = "probe"


def _finite(values: tuple[float, ...]) -> bool:
    return all(math.isfinite(v) for v in values)


@dataclass(frozen=True)
class Pose:
    """A pose in a scene file: ``position`` (m) and at most one orientation field.

    Attributes:
        position: Origin of the frame, shape (3,).
        zyx_deg: ``[gamma, beta, alpha]`` (degrees) with ``R = Rz(alpha) Ry(beta) Rx(gamma)``,
            the order of the paper's Delta X (Eq 4).
        quat_wxyz: Unit quaternion ``[w, x, y, z]`` (normalised on load).
    """

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    zyx_deg: tuple[float, float, float] | None = None
    quat_wxyz: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if not _finite(self.position):
            raise InvalidField("position", "must be finite")
        if self.zyx_deg is not None and self.quat_wxyz is not None:
            raise InvalidField("quat_wxyz", "give either zyx_deg or quat_wxyz, not both")
        if self.zyx_deg is not None and not _finite(self.zyx_deg):
            raise InvalidField("zyx_deg", "must be finite")
        if self.quat_wxyz is not None and not (_finite(self.quat_wxyz) and math.hypot(*self.quat_wxyz) > 1e-9):
            raise InvalidField("quat_wxyz", "must be a finite, non-zero quaternion")

    def matrix(self) -> Array:
        """The 4x4 homogeneous pose."""
        if self.quat_wxyz is not None:
            q = np.array(self.quat_wxyz, dtype=float)
            R = quat_to_matrix(q / np.linalg.norm(q))
        elif self.zyx_deg is not None:
            R = zyx_to_matrix(*(math.radians(a) for a in self.zyx_deg))
        else:
            R = np.eye(3)
        return make_pose(R, np.array(self.position, dtype=float))


@dataclass(frozen=True)
class ObjectSpec:
    """One static object. Exactly one of ``mesh``, ``box``, ``sphere``, ``cylinder``, ``plane``.

    Attributes:
        name: Unique name (for display and error messages).
        mesh: Mesh file (STL, PLY, OBJ, ...) relative to ``assets/`` (or absolute).
        box: Box extents (m), shape (3,), centred on the pose.
        sphere: Sphere radius (m).
        cylinder: ``[radius, height]`` (m), axis along the pose's z.
        plane: ``[size_x, size_y]`` (m) of a finite plane: a thin box whose top face is the
            pose's z = 0 plane, ``plane_thickness`` thick (a plane must have an inside).
        plane_thickness: Thickness (m) of that box.
        pose: Pose of the object frame in {w}.
        stiffness: Contact stiffness (N/m), per tool sphere in contact.
        damping: Contact damping (N s/m) on the penetration rate.
        friction: Coulomb coefficient (-) of a regularised friction force (0 = frictionless).
    """

    name: str
    stiffness: float
    damping: float = 0.0
    friction: float = 0.0
    mesh: str | None = None
    box: tuple[float, float, float] | None = None
    sphere: float | None = None
    cylinder: tuple[float, float] | None = None
    plane: tuple[float, float] | None = None
    plane_thickness: float = 0.01
    pose: Pose = field(default_factory=Pose)

    def __post_init__(self) -> None:
        given = [k for k in ("mesh", "box", "sphere", "cylinder", "plane") if getattr(self, k) is not None]
        if len(given) != 1:
            raise InvalidField(
                "mesh", f"give exactly one of mesh, box, sphere, cylinder, plane (got {given or 'none'})"
            )
        for name in ("stiffness", "damping", "friction"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InvalidField(name, "must be finite and >= 0")
        if self.stiffness == 0:
            raise InvalidField("stiffness", "must be positive")
        for name in ("box", "cylinder", "plane"):
            v = getattr(self, name)
            if v is not None and not (_finite(v) and min(v) > 0):
                raise InvalidField(name, "dimensions must be positive and finite")
        if self.sphere is not None and not (math.isfinite(self.sphere) and self.sphere > 0):
            raise InvalidField("sphere", "radius must be positive and finite")
        if not (math.isfinite(self.plane_thickness) and self.plane_thickness > 0):
            raise InvalidField("plane_thickness", "must be positive and finite")


@dataclass(frozen=True)
class SphereSpec:
    """A tool sphere: ``center`` (m, in {T}) and ``radius`` (m)."""

    center: tuple[float, float, float]
    radius: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise InvalidField("radius", "must be positive and finite")


@dataclass(frozen=True)
class CapsuleSpec:
    """A tool capsule from ``start`` to ``end`` (m, in {T}), expanded into a chain of spheres.

    ``spacing`` (m) is the largest distance between neighbouring sphere centres (default
    ``radius / 2``; the surface ripple is ``r - sqrt(r^2 - spacing^2 / 4)``, 3 % of r).
    """

    start: tuple[float, float, float]
    end: tuple[float, float, float]
    radius: float
    spacing: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise InvalidField("radius", "must be positive and finite")
        if self.spacing is not None and not (math.isfinite(self.spacing) and self.spacing > 0):
            raise InvalidField("spacing", "must be positive and finite")


@dataclass(frozen=True)
class BoxSpec:
    """A tool box (``extents`` m, centred on ``pose`` in {T}), its faces covered by small spheres.

    Spheres of ``sphere_radius`` (m) sit tangent to the inside of each face on a grid of at most
    ``spacing`` (m, default ``sphere_radius``), so the box is rendered to within the ripple of
    that grid; edges and corners are rounded by ``sphere_radius``.
    """

    extents: tuple[float, float, float]
    sphere_radius: float
    spacing: float | None = None
    pose: Pose = field(default_factory=Pose)

    def __post_init__(self) -> None:
        if not (_finite(self.extents) and min(self.extents) > 0):
            raise InvalidField("extents", "must be positive and finite")
        if not (math.isfinite(self.sphere_radius) and 0 < 2 * self.sphere_radius <= min(self.extents)):
            raise InvalidField("sphere_radius", "must be positive and at most half the smallest extent")
        if self.spacing is not None and not (math.isfinite(self.spacing) and self.spacing > 0):
            raise InvalidField("spacing", "must be positive and finite")


@dataclass(frozen=True)
class ToolSpec:
    """The slave's tool: end effector + payload outboard of the F/T sensor.

    Attributes:
        mass: Mass outboard of the sensor (kg).
        com: Centre of mass (m) in {T}.
        inertia: ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (kg m^2) about the centre of mass, {T} axes.
        mrf: Pose of {MRF} in {T}.
        sensor: Pose of {S} in {T}.
        home: Starting pose of {MRF} in {w}.
        spheres, capsules, boxes: The contact geometry, in {T}.
    """

    mass: float
    inertia: tuple[float, float, float, float, float, float]
    home: Pose
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mrf: Pose = field(default_factory=Pose)
    sensor: Pose = field(default_factory=Pose)
    spheres: tuple[SphereSpec, ...] = ()
    capsules: tuple[CapsuleSpec, ...] = ()
    boxes: tuple[BoxSpec, ...] = ()

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mass) and self.mass > 0):
            raise InvalidField("mass", "must be positive and finite")
        if not _finite(self.inertia):
            raise InvalidField("inertia", "must be finite")
        ixx, iyy, izz = self.inertia[0:3]
        ev = np.linalg.eigvalsh(_inertia_matrix(self.inertia))
        if ev[0] <= 0 or ixx + iyy < izz or iyy + izz < ixx or izz + ixx < iyy:
            raise InvalidField("inertia", "must be positive definite and satisfy the triangle inequality")
        if not (self.spheres or self.capsules or self.boxes):
            raise InvalidField("spheres", "the tool needs contact geometry (spheres, capsules or boxes)")


@dataclass(frozen=True)
class SlaveGains:
    """The virtual slave robot's Cartesian controller (see :mod:`app.world.slave`).

    Attributes:
        kp_lin: Translational tracking stiffness (N/m) of {MRF} toward its reference.
        kd_lin: Translational damping (N s/m) on the velocity error.
        kp_rot: Rotational tracking stiffness (N m/rad).
        kd_rot: Rotational damping (N m s/rad).
        force_limit: Largest force (N) the robot can exert; the PD force saturates (direction kept).
        torque_limit: Largest torque (N m), likewise.
        accommodation: NTRFC force accommodation gains ``[m/(N s)] * 3 + [rad/(N m s)] * 3`` on the
            contact wrench at {MRF} in {MRF} (paper Sec 4.3).
        substeps: MuJoCo steps per servo tick; contact and PD are re-evaluated every substep.
    """

    kp_lin: float = 3000.0
    kd_lin: float = 60.0
    kp_rot: float = 30.0
    kd_rot: float = 0.3
    force_limit: float = 40.0
    torque_limit: float = 3.0
    accommodation: tuple[float, float, float, float, float, float] = (0.004, 0.004, 0.004, 0.2, 0.2, 0.2)
    substeps: int = 1

    def __post_init__(self) -> None:
        for name in ("kp_lin", "kd_lin", "kp_rot", "kd_rot", "force_limit", "torque_limit"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InvalidField(name, "must be positive and finite")
        if not (_finite(self.accommodation) and min(self.accommodation) >= 0):
            raise InvalidField("accommodation", "gains must be finite and >= 0")
        if self.substeps < 1:
            raise InvalidField("substeps", "must be at least 1")


@dataclass(frozen=True)
class TaskSpec:
    """A task's completion test: {MRF} within the tolerances of ``goal`` (a pose in {w})."""

    goal: Pose
    position_tolerance: float = 0.002
    angle_tolerance_deg: float = 3.0
    description: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.position_tolerance) and self.position_tolerance > 0):
            raise InvalidField("position_tolerance", "must be positive and finite")
        if not (math.isfinite(self.angle_tolerance_deg) and self.angle_tolerance_deg > 0):
            raise InvalidField("angle_tolerance_deg", "must be positive and finite")

    def done(self, T_w_MRF: Array) -> bool:
        """True when the pose ``T_w_MRF`` (4, 4) is within tolerance of the goal."""
        T_goal = self.goal.matrix()
        dp = float(np.linalg.norm(T_w_MRF[0:3, 3] - T_goal[0:3, 3]))
        cos_a = (float(np.trace(T_goal[0:3, 0:3].T @ T_w_MRF[0:3, 0:3])) - 1.0) * 0.5
        angle = math.degrees(math.acos(max(-1.0, min(1.0, cos_a))))
        return dp <= self.position_tolerance and angle <= self.angle_tolerance_deg


@dataclass(frozen=True)
class SceneFile:
    """The schema of ``scenes/<name>.toml`` (see ``scenes/README.md``)."""

    name: str
    tool: ToolSpec
    description: str = ""
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    objects: tuple[ObjectSpec, ...] = ()
    slave: SlaveGains = field(default_factory=SlaveGains)
    task: TaskSpec | None = None
    margin: float = 0.0

    def __post_init__(self) -> None:
        if not _finite(self.gravity):
            raise InvalidField("gravity", "must be finite")
        names = [o.name for o in self.objects]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise InvalidField(f"objects[{i}].name", f"duplicate object name {n!r}")
        if not (math.isfinite(self.margin) and self.margin >= 0):
            raise InvalidField("margin", "must be finite and >= 0")


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
    """

    path: Path | None
    spec: SceneFile
    objects: tuple[WorldObject, ...]
    tool: ToolGeometry
    gravity_w: Array

    @property
    def name(self) -> str:
        return self.spec.name

    @cached_property
    def packed(self) -> PackedMeshes:
        """All objects' meshes packed for the compiled contact kernel (built on first use, then shared)."""
        return pack_meshes([o.collision for o in self.objects])


def _inertia_matrix(i: tuple[float, ...]) -> Array:
    ixx, iyy, izz, ixy, ixz, iyz = i
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)


def capsule_spheres(start: Array, end: Array, radius: float, spacing: float) -> Array:
    """Centres (n, 3) of a chain of spheres covering a capsule, no two neighbours > spacing apart."""
    length = float(np.linalg.norm(end - start))
    n = max(1, math.ceil(length / spacing)) + 1
    return start + np.linspace(0.0, 1.0, n)[:, None] * (end - start)


def box_spheres(extents: Array, sphere_radius: float, spacing: float) -> Array:
    """Centres (n, 3) of spheres tangent to the inside of each face of a box centred at 0."""
    half = extents / 2.0 - sphere_radius  # centre-plane half extents
    axes = [np.linspace(-h, h, max(1, math.ceil(2 * h / spacing)) + 1) if h > 0 else np.zeros(1) for h in half]
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
        pts = capsule_spheres(np.array(c.start, float), np.array(c.end, float), c.radius, c.spacing or c.radius / 2)
        centers.append(pts)
        radii.append(np.full(len(pts), c.radius))
    for b in spec.boxes:
        T = b.pose.matrix()
        pts = box_spheres(np.array(b.extents, float), b.sphere_radius, b.spacing or b.sphere_radius)
        centers.append(pts @ T[0:3, 0:3].T + T[0:3, 3])
        radii.append(np.full(len(pts), b.sphere_radius))
    return ToolGeometry(
        centers_T=np.ascontiguousarray(np.concatenate(centers)),
        radii=np.concatenate(radii),
        T_T_MRF=spec.mrf.matrix(),
        T_T_S=spec.sensor.matrix(),
        mass=spec.mass,
        com_T=np.array(spec.com, dtype=float),
        inertia_T=_inertia_matrix(spec.inertia),
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


def _load_mesh(path: Path, source: str | Path, field_name: str) -> trimesh.Trimesh:
    if not path.is_file():
        raise ConfigError(source, field_name, f"mesh file not found: {path}")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for a bad file
        raise ConfigError(source, field_name, f"cannot read mesh {path.name}: {exc}") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise ConfigError(source, field_name, f"{path.name} holds no triangle mesh")
    return loaded


def build_object(spec: ObjectSpec, source: str | Path, field_path: str) -> WorldObject:
    """Make the {w} mesh of one object, checking it is usable for contact.

    Raises:
        ConfigError: The mesh is missing, unreadable, or fails :func:`~app.world.mesh_check.checked_mesh`
            (non-finite vertices, degenerate, open or inconsistently wound).
    """
    if spec.mesh is not None:
        mesh_field = f"{field_path}.mesh"
        p = Path(spec.mesh)
        mesh = _load_mesh(p if p.is_absolute() else ASSETS_DIR / p, source, mesh_field)
    else:
        mesh_field = field_path
        mesh = _primitive_mesh(spec)
    mesh = checked_mesh(mesh, source, mesh_field)
    mesh.apply_transform(spec.pose.matrix())
    return WorldObject(spec.name, mesh, spec.stiffness, spec.damping, spec.friction, CollisionMesh(mesh))


def build_scene(spec: SceneFile, source: str | Path = "<scene>", path: Path | None = None) -> Scene:
    """Build a :class:`Scene` from a parsed :class:`SceneFile` (also for scenes made in code)."""
    objects = tuple(build_object(o, source, f"objects[{i}]") for i, o in enumerate(spec.objects))
    return Scene(path, spec, objects, _tool_geometry(spec.tool), np.array(spec.gravity, dtype=float))


def resolve_scene_path(name_or_path: str | Path) -> Path:
    """A scene name (``"probe"``) or a path to a ``.toml`` file."""
    p = Path(name_or_path)
    return p if p.suffix == ".toml" else SCENES_DIR / f"{name_or_path}.toml"


def available_scenes() -> list[str]:
    """Names of the scenes shipped in ``scenes/``."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def load_scene(name_or_path: str | Path = DEFAULT_SCENE) -> Scene:
    """Load a scene by name or path; meshes are read relative to ``assets/``.

    Raises:
        ConfigError: naming the file and the field, for any malformed entry.
    """
    path = resolve_scene_path(name_or_path)
    if not path.is_file():
        raise ConfigError(path, "<file>", f"no such scene (shipped scenes: {', '.join(available_scenes())})")
    spec = from_dict(SceneFile, load_toml(path), path)
    return build_scene(spec, path, path)
