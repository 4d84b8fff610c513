"""The scene file schema: ``scenes/<name>.toml`` -> :class:`SceneFile` (dataclasses and their ranges).

Split from :mod:`app.world.scene`, which builds meshes, the tool's sphere set and the
:class:`~app.world.scene.Scene` from a parsed :class:`SceneFile`. Every field carries its
physical :class:`~app.config.Range` (generous, finite; SI units) and ``scenes/README.md``
shows the same ranges. Resource limits (tool spheres, objects, triangles) are here too, so a
file is refused before anything large is allocated.

Frames: {w} the slave world, {T} the tool body (the frame the tool geometry and inertia are
written in), {MRF} the moving reference frame under Cartesian control, {S} the F/T sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np
from numba import njit

from app.config import Checked, Count, Range
from app.errors import InvalidField
from app.spatial import Array, make_pose, quat_to_matrix, zyx_to_matrix

#: Where the slave arm models live: ``slaves/<name>/arm.xml`` (MJCF) with a NOTES.md each.
SLAVES_DIR = Path(__file__).resolve().parents[2] / "slaves"


def available_arms() -> list[str]:
    """Names of the slave arms shipped in ``slaves/``."""
    return sorted(p.parent.name for p in SLAVES_DIR.glob("*/arm.xml"))


def check_slave_kind(kind: str, field_name: str) -> None:
    """Raise :class:`InvalidField` on ``field_name`` unless ``kind`` is ``"tool"`` or a shipped arm."""
    if kind != "tool" and kind not in available_arms():
        raise InvalidField(field_name, f"unknown slave {kind!r} (choices: tool, {', '.join(available_arms())})")


#: Most spheres the tool's point shell may have (spheres, capsule chains and box grids together).
MAX_TOOL_SPHERES = 10_000
#: Most static objects in a scene, and most tool spheres/capsules/boxes given explicitly.
MAX_OBJECTS = 1000
#: Most triangles of one object's mesh (the shipped ``large_mesh`` has 196,608).
MAX_MESH_FACES = 2_000_000
#: Largest mesh file read (bytes).
MAX_MESH_BYTES = 256 * 1024 * 1024
#: Smallest principal moment of inertia of the tool (kg m^2); MuJoCo refuses below ~1e-15.
MIN_INERTIA = 1e-12

WORLD_POSITION = Range(-100.0, 100.0, "m")
TOOL_POSITION = Range(-10.0, 10.0, "m")
ANGLE_DEG = Range(-360.0, 360.0, "deg")
OBJECT_SIZE = Range(1e-6, 100.0, "m")
TOOL_RADIUS = Range(1e-5, 1.0, "m")
TOOL_SIZE = Range(1e-5, 10.0, "m")
SPACING = Range(1e-6, 10.0, "m")

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Pose(Checked):
    """A pose in a scene file: ``position`` (m) and at most one orientation field.

    Attributes:
        position: Origin of the frame, shape (3,).
        zyx_deg: ``[gamma, beta, alpha]`` (degrees) with ``R = Rz(alpha) Ry(beta) Rx(gamma)``,
            the order of the paper's Delta X (Eq 4).
        quat_wxyz: Quaternion ``[w, x, y, z]`` (-), normalised on load; its norm must exceed 1e-9.
    """

    position: Annotated[Vec3, WORLD_POSITION] = (0.0, 0.0, 0.0)
    zyx_deg: Annotated[Vec3 | None, ANGLE_DEG] = None
    quat_wxyz: Annotated[tuple[float, float, float, float] | None, Range(-1e3, 1e3)] = None

    def validate(self) -> None:
        if self.zyx_deg is not None and self.quat_wxyz is not None:
            raise InvalidField("quat_wxyz", "give either zyx_deg or quat_wxyz, not both")
        if self.quat_wxyz is not None and not math.hypot(*self.quat_wxyz) > 1e-9:
            raise InvalidField("quat_wxyz", "must be a non-zero quaternion (norm > 1e-9)")

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


SHAPES = ("mesh", "box", "sphere", "cylinder", "plane")


@dataclass(frozen=True)
class DynamicSpec(Checked):
    """What makes an object move (simulated by :mod:`app.world.dynamics`). Exactly one of
    ``mass`` and ``density``; the centre of mass and the inertia come from the closed mesh
    (uniform density). Its initial pose is the object's ``pose``; its contact with the tool and,
    through FCL, with other objects takes the object's ``stiffness``, ``damping`` and
    ``friction`` (MuJoCo's contacts take the friction, see :mod:`app.world.dynamics`).

    Attributes:
        mass: Mass (kg).
        density: Density (kg/m^3); the mass is density times the mesh's volume.
        twist: Initial twist ``[v; w]`` (m/s, rad/s) of the object frame in {w} (v of its origin).
    """

    mass: Annotated[float | None, Range(1e-6, 1e4, "kg")] = None
    density: Annotated[float | None, Range(1e-3, 1e5, "kg/m^3")] = None
    twist: Annotated[tuple[float, float, float, float, float, float], Range(-100.0, 100.0, "m/s; rad/s")] = (
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    )  # fmt: skip

    def validate(self) -> None:
        if (self.mass is None) == (self.density is None):
            raise InvalidField("mass", "give exactly one of mass and density")


@dataclass(frozen=True)
class ObjectSpec(Checked):
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
        friction: Coulomb coefficient (-) of a regularised friction force (0 = frictionless); for a
            dynamic object also its friction with other objects.
        dynamic: Present for an object that moves (:class:`DynamicSpec`); absent for a static one.
    """

    name: str
    stiffness: Annotated[float, Range(0.0, 1e7, "N/m", lo_open=True)]
    damping: Annotated[float, Range(0.0, 1e5, "N s/m")] = 0.0
    friction: Annotated[float, Range(0.0, 10.0)] = 0.0
    mesh: str | None = None
    box: Annotated[Vec3 | None, OBJECT_SIZE] = None
    sphere: Annotated[float | None, OBJECT_SIZE] = None
    cylinder: Annotated[tuple[float, float] | None, OBJECT_SIZE] = None
    plane: Annotated[tuple[float, float] | None, OBJECT_SIZE] = None
    plane_thickness: Annotated[float, OBJECT_SIZE] = 0.01
    pose: Pose = field(default_factory=Pose)
    dynamic: DynamicSpec | None = None

    def validate(self) -> None:
        given = [k for k in SHAPES if getattr(self, k) is not None]
        if len(given) != 1:
            raise InvalidField(
                "mesh", f"give exactly one of mesh, box, sphere, cylinder, plane (got {given or 'none'})"
            )
        if self.dynamic is not None and self.plane is not None:
            raise InvalidField("dynamic", "a plane cannot be dynamic (use a box)")

    @property
    def shape(self) -> str:
        """The name of the shape field given (``"mesh"``, ``"box"``, ...)."""
        return next(k for k in SHAPES if getattr(self, k) is not None)


@dataclass(frozen=True)
class SphereSpec(Checked):
    """A tool sphere: ``center`` (m, in {T}) and ``radius`` (m)."""

    center: Annotated[Vec3, TOOL_POSITION]
    radius: Annotated[float, TOOL_RADIUS]


@dataclass(frozen=True)
class CapsuleSpec(Checked):
    """A tool capsule from ``start`` to ``end`` (m, in {T}), expanded into a chain of spheres.

    ``spacing`` (m) is the largest distance between neighbouring sphere centres (default
    ``radius / 2``; the surface ripple is ``r - sqrt(r^2 - spacing^2 / 4)``, 3 % of r).
    """

    start: Annotated[Vec3, TOOL_POSITION]
    end: Annotated[Vec3, TOOL_POSITION]
    radius: Annotated[float, TOOL_RADIUS]
    spacing: Annotated[float | None, SPACING] = None

    def sphere_count(self) -> int:
        """Number of spheres of the chain (see :func:`app.world.scene.capsule_spheres`)."""
        length = math.dist(self.start, self.end)
        return max(1, math.ceil(length / (self.spacing or self.radius / 2))) + 1


@dataclass(frozen=True)
class BoxSpec(Checked):
    """A tool box (``extents`` m, centred on ``pose`` in {T}), its faces covered by small spheres.

    Spheres of ``sphere_radius`` (m) sit tangent to the inside of each face on a grid of at most
    ``spacing`` (m, default ``sphere_radius``), so the box is rendered to within the ripple of
    that grid; edges and corners are rounded by ``sphere_radius``.
    """

    extents: Annotated[Vec3, TOOL_SIZE]
    sphere_radius: Annotated[float, TOOL_RADIUS]
    spacing: Annotated[float | None, SPACING] = None
    pose: Pose = field(default_factory=Pose)

    def validate(self) -> None:
        if not 2 * self.sphere_radius <= min(self.extents):
            raise InvalidField("sphere_radius", "must be at most half the smallest extent")

    def grid(self) -> list[int]:
        """Grid points per axis of the face grids (see :func:`app.world.scene.box_spheres`)."""
        spacing = self.spacing or self.sphere_radius
        half = [e / 2.0 - self.sphere_radius for e in self.extents]
        return [max(1, math.ceil(2 * h / spacing)) + 1 if h > 0 else 1 for h in half]

    def sphere_count(self) -> int:
        """An upper bound on the number of spheres (edges shared by two faces counted twice)."""
        n = self.grid()
        return 2 * (n[1] * n[2] + n[0] * n[2] + n[0] * n[1])


def inertia_matrix(i: tuple[float, ...]) -> Array:
    """``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` as the symmetric (3, 3) matrix (kg m^2)."""
    ixx, iyy, izz, ixy, ixz, iyz = i
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)


@dataclass(frozen=True)
class ToolSpec(Checked):
    """The slave's tool: end effector + payload outboard of the F/T sensor.

    Attributes:
        mass: Mass outboard of the sensor (kg).
        com: Centre of mass (m) in {T}.
        inertia: ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (kg m^2) about the centre of mass, {T} axes;
            positive definite with principal moments >= :data:`MIN_INERTIA`.
        mrf: Pose of {MRF} in {T}.
        sensor: Pose of {S} in {T}.
        home: Starting pose of {MRF} in {w}.
        spheres, capsules, boxes: The contact geometry, in {T}; at most :data:`MAX_TOOL_SPHERES`
            spheres in all.
    """

    mass: Annotated[float, Range(1e-6, 1e3, "kg")]
    inertia: Annotated[tuple[float, float, float, float, float, float], Range(-1e3, 1e3, "kg m^2")]
    home: Pose
    com: Annotated[Vec3, TOOL_POSITION] = (0.0, 0.0, 0.0)
    mrf: Pose = field(default_factory=Pose)
    sensor: Pose = field(default_factory=Pose)
    spheres: Annotated[tuple[SphereSpec, ...], Count(0, MAX_OBJECTS)] = ()
    capsules: Annotated[tuple[CapsuleSpec, ...], Count(0, MAX_OBJECTS)] = ()
    boxes: Annotated[tuple[BoxSpec, ...], Count(0, MAX_OBJECTS)] = ()

    def validate(self) -> None:
        ixx, iyy, izz = self.inertia[0:3]
        ev = np.linalg.eigvalsh(inertia_matrix(self.inertia))
        if ev[0] < MIN_INERTIA or ixx + iyy < izz or iyy + izz < ixx or izz + ixx < iyy:
            raise InvalidField(
                "inertia",
                f"must be positive definite (principal moments >= {MIN_INERTIA:g} kg m^2) "
                "and satisfy the triangle inequality",
            )
        if not (self.spheres or self.capsules or self.boxes):
            raise InvalidField("spheres", "the tool needs contact geometry (spheres, capsules or boxes)")
        total = len(self.spheres)
        parts: list[tuple[str, CapsuleSpec | BoxSpec]] = [(f"capsules[{i}]", c) for i, c in enumerate(self.capsules)]
        parts += [(f"boxes[{i}]", b) for i, b in enumerate(self.boxes)]
        for where, part in parts:
            total += part.sphere_count()
            if total > MAX_TOOL_SPHERES:
                size = (
                    "spacing"
                    if part.spacing is not None
                    else "radius"
                    if isinstance(part, CapsuleSpec)
                    else "sphere_radius"
                )
                raise InvalidField(
                    f"{where}.{size}", f"the tool would have over {MAX_TOOL_SPHERES} spheres; use a larger {size}"
                )


@dataclass(frozen=True)
class SlaveGains(Checked):
    """The virtual slave robot's Cartesian controller (see :mod:`app.slave.tool`).

    Attributes:
        kind: ``"tool"``: the ideal Cartesian tool (:mod:`app.slave.tool`); or the name of an arm
            in ``slaves/`` carrying the tool on its flange (:mod:`app.slave.arm`). The gains below
            are the tool's Cartesian PD; an arm uses ``kp_*``, the limits and ``accommodation`` for
            its reference and the wrench felt at its limits, and its own joint servos.
        kp_lin: Translational tracking stiffness (N/m) of {MRF} toward its reference.
        kd_lin: Translational damping (N s/m) on the velocity error.
        kp_rot: Rotational tracking stiffness (N m/rad).
        kd_rot: Rotational damping (N m s/rad).
        force_limit: Largest force (N) the robot can exert; the PD force saturates (direction kept).
        torque_limit: Largest torque (N m), likewise.
        accommodation: NTRFC force accommodation gains ``[m/(N s)] * 3 + [rad/(N m s)] * 3`` on the
            contact wrench at {MRF} in {MRF} (paper Sec 4.3).
        substeps: MuJoCo steps per servo tick at the default 1 kHz; contact and PD are re-evaluated
            every substep. A slower servo takes proportionally more (the physics step stays the
            one this gives at 1 kHz); a faster one takes this many.
    """

    kp_lin: Annotated[float, Range(0.0, 1e6, "N/m", lo_open=True)] = 3000.0
    kd_lin: Annotated[float, Range(0.0, 1e4, "N s/m", lo_open=True)] = 60.0
    kp_rot: Annotated[float, Range(0.0, 1e4, "N m/rad", lo_open=True)] = 30.0
    kd_rot: Annotated[float, Range(0.0, 1e3, "N m s/rad", lo_open=True)] = 0.3
    force_limit: Annotated[float, Range(0.0, 1e4, "N", lo_open=True)] = 40.0
    torque_limit: Annotated[float, Range(0.0, 1e3, "N m", lo_open=True)] = 3.0
    accommodation: Annotated[
        tuple[float, float, float, float, float, float], Range(0.0, 10.0, "m/(N s); rad/(N m s)")
    ] = (0.004, 0.004, 0.004, 0.2, 0.2, 0.2)
    substeps: Annotated[int, Range(1, 100)] = 1
    kind: str = "tool"

    def validate(self) -> None:
        check_slave_kind(self.kind, "kind")


@dataclass(frozen=True)
class TaskSpec(Checked):
    """A task's completion test: {MRF} within the tolerances of ``goal`` (a pose in {w})."""

    goal: Pose
    position_tolerance: Annotated[float, Range(1e-6, 1.0, "m")] = 0.002
    angle_tolerance_deg: Annotated[float, Range(1e-3, 180.0, "deg")] = 3.0
    description: str = ""

    def done(self, T_w_MRF: Array) -> bool:
        """True when the pose ``T_w_MRF`` (4, 4) is within tolerance of the goal."""
        return within_goal(T_w_MRF, self.goal.matrix(), self.position_tolerance, math.radians(self.angle_tolerance_deg))


@njit(cache=True)
def within_goal(T: Array, T_goal: Array, position_tolerance: float, angle_tolerance: float) -> bool:
    """Whether pose ``T`` is within ``position_tolerance`` (m) and ``angle_tolerance`` (rad) of
    ``T_goal`` (both (4, 4))."""
    dp2 = (T[0, 3] - T_goal[0, 3]) ** 2 + (T[1, 3] - T_goal[1, 3]) ** 2 + (T[2, 3] - T_goal[2, 3]) ** 2
    trace = 0.0  # trace(R_goal^T R)
    for a in range(3):
        for b in range(3):
            trace += T_goal[b, a] * T[b, a]
    angle = math.acos(max(-1.0, min(1.0, (trace - 1.0) * 0.5)))
    return math.sqrt(dp2) <= position_tolerance and angle <= angle_tolerance


@dataclass(frozen=True)
class ViewSpec(Checked):
    """What the browser demo's world view frames: an axis-aligned box in {w} (presentation only)."""

    center: Annotated[Vec3, WORLD_POSITION]
    size: Annotated[Vec3, OBJECT_SIZE]


@dataclass(frozen=True)
class SceneFile(Checked):
    """The schema of ``scenes/<name>.toml`` (see ``scenes/README.md``)."""

    name: str
    tool: ToolSpec
    description: str = ""
    gravity: Annotated[Vec3, Range(-100.0, 100.0, "m/s^2")] = (0.0, 0.0, -9.81)
    objects: Annotated[tuple[ObjectSpec, ...], Count(0, MAX_OBJECTS)] = ()
    slave: SlaveGains = field(default_factory=SlaveGains)
    task: TaskSpec | None = None
    margin: Annotated[float, Range(0.0, 1.0, "m")] = 0.0
    view: ViewSpec | None = None

    def validate(self) -> None:
        names = [o.name for o in self.objects]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise InvalidField(f"objects[{i}].name", f"duplicate object name {n!r}")
