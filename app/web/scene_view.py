"""The 3D scene in viser: device, grip frames, hand-target gizmo, world, slave arm, tool, contacts, wrenches.

The device base {0} and the slave world {w} are separate spaces. In the viser scene frame {v}
(z up) they are placed side by side without rotation: {0} at :data:`DEVICE_ORIGIN_V` (left) and
{w} at :data:`WORLD_ORIGIN_V` (right), so ``p_v = p_0 + DEVICE_ORIGIN_V`` and
``p_v = p_w + WORLD_ORIGIN_V``. Wrench arrows are drawn at their reference points, log-scaled
(:func:`arrow_length`) so that 0.5 N and 40 N both read: each space has its own arrow unit (a
fraction of its size), and each force arrow carries its magnitude as a label at its tip. A moment
arrow points along its axis (right-hand rule).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Literal, TypeVar, cast

import mujoco
import numpy as np
import trimesh
import viser

from app.session.loop import ServoLoop
from app.spatial import Array, invert_pose, make_pose, matrix_to_quat, quat_to_matrix
from app.web.snapshot import Snapshot
from app.world.scene import Scene

#: Where the device base {0} sits in the viser frame (m): on the left.
DEVICE_ORIGIN_V = np.array([-0.5, 0.0, 0.0])
#: Where the slave world {w} sits in the viser frame (m): on the right.
WORLD_ORIGIN_V = np.array([0.3, 0.0, 0.0])
#: Force that draws one arrow unit (N); moments use :data:`MOMENT_REF` (N m).
FORCE_REF = 1.0
MOMENT_REF = 0.1
#: One arrow unit as a fraction of the size (largest extent) of the space it is drawn in.
ARROW_UNIT_FRACTION = 0.08
#: Magnitudes below this share of the reference are hidden (no degenerate cone, no "0.0 N" label).
MIN_SHOWN = 0.02
#: The least move sent to the browsers, as a share of the size of the space the node is in: half a
#: pixel when that space fills 1000 px. The loop's sub-micron jitter and force noise then send
#: nothing, and a still picture costs the browser no 3D render (viser drains the panel's updates
#: at once only while no scene update waits for a frame).
SHOWN_RESOLUTION = 5e-4
#: The least turn sent (rad, 0.057 degrees): the end of a rod as long as its space's size then
#: moves by one pixel when the space fills 1000 px (twice :data:`SHOWN_RESOLUTION`).
SHOWN_TURN = 1e-3
#: The least change of a force label (N) that rewrites it.
SHOWN_FORCE = 0.1

T_V_0 = make_pose(np.eye(3), DEVICE_ORIGIN_V)
T_V_W = make_pose(np.eye(3), WORLD_ORIGIN_V)
T_0_V = invert_pose(T_V_0)

H = TypeVar("H", bound=viser.SceneNodeHandle)
#: The two spaces drawn side by side.
Space = Literal["device", "world"]
SPACES: tuple[Space, ...] = ("device", "world")


@dataclass(frozen=True)
class WrenchArrow:
    """One drawn wrench: which snapshot field, the space it is drawn in, its colour, its legend text."""

    key: str
    space: Space
    label: str
    color: tuple[int, int, int]


#: The wrenches drawn, each as a force arrow (with its magnitude) and a (darker) moment arrow.
WRENCH_ARROWS = (
    WrenchArrow("task_MRF", "world", "task wrench F_MRF at {MRF}", (230, 60, 40)),
    WrenchArrow("reflected_G", "device", "reflected task wrench K_T F_MRF at {G}", (240, 150, 20)),
    WrenchArrow("assist_G", "device", "assist wrench (return-to-centre + damping) at {G}", (60, 110, 230)),
    WrenchArrow("hand_G", "device", "operator's hand on the grip at {G}", (40, 170, 80)),
)
#: Contact points and their normals (magenta).
CONTACT_COLOR = (255, 0, 200)
#: A contact normal's key among the world's arrows (``contact/<i>``) and its length in arrow units.
CONTACT_NORMAL = "contact/"
CONTACT_NORMAL_UNITS = 0.8
#: Static objects (grey) and dynamic ones (teal: no other node of the world has that hue).
STATIC_COLOR = (170, 175, 185)
DYNAMIC_COLOR = (20, 150, 160)


def device_box(loop: ServoLoop) -> Array:
    """The device's links at the loop's current pose as a box ``[min, max]`` in {0} (m), (2, 3).

    Geom centres padded by each geom's bounding radius (MuJoCo's ``geom_rbound``).
    """
    xpos, rbound = loop.reading.geom_xpos, loop.plant.model.geom_rbound[:, None]
    return np.stack(((xpos - rbound).min(axis=0), (xpos + rbound).max(axis=0)))


def world_box(scene: Scene) -> Array:
    """What a view of the world frames, ``[min, max]`` in {w} (m), (2, 3): the scene file's
    ``[view]`` box if it has one, else the objects and the tool at home."""
    view = scene.spec.view
    if view is not None:
        centre, half = np.array(view.center), 0.5 * np.array(view.size)
        return np.stack((centre - half, centre + half))
    home = scene.tool.T_w_MRF_home[0:3, 3]
    points = [home[None], *(obj.mesh.bounds for obj in scene.objects)]
    stacked = np.vstack(points)
    return np.stack((stacked.min(axis=0), stacked.max(axis=0)))


def arrow_length(magnitude: float, reference: float, unit: float) -> float:
    """Drawn length (m) of a wrench part of ``magnitude`` (N or N m): ``unit * log2(1 + m/ref)``,
    so ``reference`` draws one unit, 3x it two units, 7x three: small and large forces both read."""
    return unit * float(np.log2(1.0 + magnitude / reference))


def space_size(points: Array) -> float:
    """Largest extent (m) of the axis-aligned box around ``points`` (k, 3)."""
    return float(np.max(np.ptp(points, axis=0)))


def pose_to_wxyz_position(T: Array) -> tuple[Array, Array]:
    """A 4x4 pose as viser's ``(wxyz, position)``."""
    return matrix_to_quat(T[0:3, 0:3]), T[0:3, 3].copy()


def turn_between(q1: Array, q2: Array) -> float:
    """The angle (rad) of the rotation between unit quaternions ``q1`` and ``q2`` (q and -q are one
    rotation)."""
    return 2.0 * float(np.arccos(min(1.0, abs(float(q1 @ q2)))))


def wxyz_position_to_pose(wxyz: Array, position: Array) -> Array:
    """viser's ``(wxyz, position)`` as a 4x4 pose."""
    return make_pose(quat_to_matrix(np.asarray(wxyz, dtype=float)), np.asarray(position, dtype=float))


def viser_to_device(wxyz: Array, position: Array) -> Array:
    """A pose given in the viser frame, as ``T_0_X`` in the device base {0} (4, 4)."""
    return T_0_V @ wxyz_position_to_pose(wxyz, position)


#: The most triangles a scene object is drawn with (:func:`drawn_mesh`). Without a GPU the page
#: draws every triangle in software for every frame (about 1 us each here): large_mesh's terrain of
#: 196,608 triangles alone would cost ~0.2 s a frame.
OBJECT_FACES = 20_000


#: Sections of a drawn capsule (round, along each end cap): trimesh's default 32 x 32 made a
#: capsule of 4096 triangles, 20k for the Kraft's links, which the page re-renders every frame
#: (in software WebGL on a machine without a GPU) and resends whenever the view is rebuilt.
CAPSULE_SECTIONS = (16, 8)


def _geom_mesh(model: mujoco.MjModel, g: int) -> trimesh.Trimesh | None:
    """Geom ``g`` of ``model`` as a mesh in the geom's own frame, or None for planes/height fields."""
    size = model.geom_size[g]
    kind = int(model.geom_type[g])
    geom = mujoco.mjtGeom
    if kind == geom.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=2, radius=size[0])
    if kind == geom.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(height=2 * size[1], radius=size[0], count=list(CAPSULE_SECTIONS))
    if kind == geom.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2 * size[1])
    if kind == geom.mjGEOM_BOX:
        return trimesh.creation.box(extents=2 * size)
    if kind == geom.mjGEOM_ELLIPSOID:
        mesh = trimesh.creation.icosphere(subdivisions=2)
        mesh.apply_scale(size)
        return mesh
    if kind == geom.mjGEOM_MESH:
        m = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        f0, nf = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        return trimesh.Trimesh(model.mesh_vert[v0 : v0 + nv], model.mesh_face[f0 : f0 + nf], process=False)
    return None


def _tool_mesh(centers_T: Array, radii: Array) -> trimesh.Trimesh:
    """The tool's sphere shell as one mesh in the tool frame {T}, without the triangles that are
    hidden inside another of its spheres: the shell's spheres overlap along its length, and the page
    draws every triangle of every frame (3360 triangles for the probe's 42 spheres, 1600 shown).

    A triangle is hidden when its three corners are inside the ball inscribed in another drawn
    sphere (an icosphere is convex and holds that ball, so it holds the triangle too)."""
    unit = trimesh.creation.icosphere(subdivisions=1)
    inscribed = float(np.min(np.einsum("ij,ij->i", unit.face_normals, unit.vertices[unit.faces[:, 0]])))
    parts = []
    for i, (c, r) in enumerate(zip(centers_T, radii, strict=True)):
        sphere = trimesh.Trimesh(unit.vertices * float(r) + c, unit.faces, process=False)
        others = np.delete(np.arange(len(radii)), i)
        # (vertex, other sphere): inside that sphere's inscribed ball?
        inside = (
            np.linalg.norm(sphere.vertices[:, None] - centers_T[others][None], axis=2) < inscribed * radii[others][None]
        )
        sphere.update_faces(~inside[sphere.faces].all(axis=1).any(axis=1))
        sphere.remove_unreferenced_vertices()
        parts.append(sphere)
    return cast(trimesh.Trimesh, trimesh.util.concatenate(parts))


def drawn_mesh(mesh: trimesh.Trimesh, faces: int = OBJECT_FACES) -> trimesh.Trimesh:
    """``mesh`` as drawn: itself if it has at most ``faces`` triangles, else merged by vertex
    clustering (the vertices in one cube of a grid become their mean; a triangle with two corners
    in one cube goes), the cube's side growing from the median edge by 1.5x until at most
    ``faces`` triangles remain. The shape keeps its size and place to within a cube's side."""
    if len(mesh.faces) <= faces:
        return mesh
    cell = float(np.median(mesh.edges_unique_length))
    while True:
        cell *= 1.5
        _, cluster, counts = np.unique(
            np.floor(mesh.vertices / cell).astype(np.int64), axis=0, return_inverse=True, return_counts=True
        )
        cluster = cluster.reshape(-1)
        vertices = np.zeros((len(counts), 3))
        np.add.at(vertices, cluster, mesh.vertices)
        vertices /= counts[:, None]
        corners = cluster[mesh.faces]
        corners = corners[
            (corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2]) & (corners[:, 0] != corners[:, 2])
        ]
        # A triangle merged onto another (the same three corners) once, in its first winding.
        _, first = np.unique(np.sort(corners, axis=1), axis=0, return_index=True)
        corners = corners[np.sort(first)]
        if len(corners) <= faces:
            return trimesh.Trimesh(vertices, corners, process=False)


def static_mesh(scene: Scene) -> trimesh.Trimesh | None:
    """The scene's static objects as drawn (:func:`drawn_mesh`), in one mesh in {w} (m); None if it
    has none. They never move and share a colour, so they are one node: one draw a frame where a
    node each cost a draw each (in software WebGL a lit draw costs the browser's GPU process up to
    a millisecond of CPU; peg_carry has nine). Seen through (opacity 0.9), one object's triangles
    are then drawn in the mesh's order rather than sorted by distance against another's."""
    drawn = [drawn_mesh(obj.mesh) for obj in scene.objects]
    if not drawn:
        return None
    return cast(trimesh.Trimesh, trimesh.util.concatenate(drawn))


def _add_axes(
    scene: viser.SceneApi, name: str, length: float, radius: float, position: Array | None = None
) -> viser.BatchedAxesHandle:
    """A coordinate frame's three axes (red x, green y, blue z) at ``name``: viser's batched axes
    with one instance, 192 triangles in one draw. viser's ``add_frame`` adds an origin sphere of
    960 triangles to each frame, five sixths of the frames' triangles, which a page without a GPU
    draws in software every frame."""
    return scene.add_batched_axes(
        name,
        np.array([[1.0, 0.0, 0.0, 0.0]]),
        np.zeros((1, 3)),
        axes_length=length,
        axes_radius=radius,
        position=np.zeros(3) if position is None else position,
    )


#: Radius / length of the axes of frames drawn together in one batched node
#: (:func:`_add_axes_set`), whose instances differ only by a uniform scale.
AXES_RADIUS_RATIO = 0.04


def _add_axes_set(
    scene: viser.SceneApi, name: str, poses: list[Array], lengths: list[float]
) -> viser.BatchedAxesHandle:
    """Several frames' axes at ``name``, one instance each (one draw for all; in software WebGL a
    draw costs the page's GPU process about 0.4 ms of CPU a frame): frame ``i`` at ``poses[i]``
    (4, 4, in the node's parent) with axes ``lengths[i]`` long (m), all of radius
    :data:`AXES_RADIUS_RATIO` x length."""
    wxyzs, positions = zip(*(pose_to_wxyz_position(T) for T in poses), strict=True)
    return scene.add_batched_axes(
        name,
        np.array(wxyzs),
        np.array(positions),
        np.array(lengths),
        axes_length=1.0,
        axes_radius=AXES_RADIUS_RATIO,
    )


def _pose(handle: viser.SceneNodeHandle) -> Array:
    """``handle``'s pose in its parent's frame as last sent (4, 4)."""
    return wxyz_position_to_pose(handle.wxyz, handle.position)


def _at_origin() -> Array:
    """The pose of a node whose parent is the viser frame itself."""
    return np.eye(4)


def _at_world() -> Array:
    """The pose of a node whose parent is /world, {w} in the viser frame."""
    return T_V_W


def _rgb(rgba: Array) -> tuple[int, int, int]:
    return (int(255 * rgba[0]), int(255 * rgba[1]), int(255 * rgba[2]))


def _linear_rgb(rgba: Array) -> tuple[int, int, int]:
    """:func:`_rgb` as a batched node's instance colour: viser's page takes a mesh's colour as
    sRGB (three.js converts it to linear) but an instance's as linear already, so the same bytes
    would draw a dark link grey. Converted here with the sRGB curve, it draws as a mesh of
    :func:`_rgb` does."""
    c = np.array(_rgb(rgba)) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    r, g, b = (round(255.0 * float(x)) for x in linear)
    return (r, g, b)


def _unit_parts() -> dict[str, trimesh.Trimesh]:
    """The unit meshes a geom is drawn from (:class:`GeomBatches`): a cylinder of radius 1 from
    z = -1 to 1 (capped), a capsule's open shaft of the same span and its cap (a hemisphere of
    radius 1 on z >= 0, both cut from trimesh's capsule of :data:`CAPSULE_SECTIONS`, so a capsule
    is drawn with the triangles it had as one mesh), a box from -1 to 1 and an icosphere of radius 1."""
    capsule = trimesh.creation.capsule(height=2.0, radius=1.0, count=list(CAPSULE_SECTIONS))
    z = capsule.vertices[capsule.faces][:, :, 2]
    shaft = cast(trimesh.Trimesh, capsule.submesh([np.flatnonzero((np.abs(z) <= 1.0 + 1e-9).all(axis=1))], append=True))
    cap = cast(trimesh.Trimesh, capsule.submesh([np.flatnonzero((z >= 1.0 - 1e-9).all(axis=1))], append=True))
    cap.apply_translation((0.0, 0.0, -1.0))
    return {
        "cylinder": trimesh.creation.cylinder(radius=1.0, height=2.0),
        "shaft": shaft,
        "cap": cap,
        "box": trimesh.creation.box(extents=(2.0, 2.0, 2.0)),
        "sphere": trimesh.creation.icosphere(subdivisions=2),
    }


#: A cap turned over (pi about x): the capsule's end at -z.
_FLIP = make_pose(np.diag([1.0, -1.0, -1.0]), np.zeros(3))


def _geom_parts(model: mujoco.MjModel, g: int) -> list[tuple[str, Array, Array]] | None:
    """Geom ``g`` as unit parts (:func:`_unit_parts`): each its name, its pose in the geom's frame
    (4, 4) and its scale along the part's axes (3,); None for a geom of another type (a mesh, a
    plane, a height field)."""
    r, h, c = (float(x) for x in model.geom_size[g])
    geom = mujoco.mjtGeom
    match int(model.geom_type[g]):
        case geom.mjGEOM_SPHERE:
            return [("sphere", np.eye(4), np.full(3, r))]
        case geom.mjGEOM_ELLIPSOID:
            return [("sphere", np.eye(4), np.array([r, h, c]))]
        case geom.mjGEOM_CYLINDER:
            return [("cylinder", np.eye(4), np.array([r, r, h]))]
        case geom.mjGEOM_BOX:
            return [("box", np.eye(4), np.array([r, h, c]))]
        case geom.mjGEOM_CAPSULE:
            end = make_pose(np.eye(3), np.array([0.0, 0.0, h]))
            return [
                ("shaft", np.eye(4), np.array([r, r, h])),
                ("cap", end, np.full(3, r)),
                ("cap", _FLIP @ end, np.full(3, r)),
            ]
    return None


class GeomBatches:
    """The geoms of a MuJoCo model (a device's links, a slave arm's) drawn as instances of a few
    unit meshes: one batched node (one draw) per kind of part (:func:`_unit_parts`) instead of a
    mesh node (a draw) per geom. In software WebGL a draw costs the browser's GPU process about
    half a millisecond or more of CPU whatever its size; the Kraft's eight links are three draws.
    A geom of another type (a mesh) keeps a mesh node of its own.

    Args:
        scene: The viser scene.
        name: The nodes' parent name (``/links``).
        model: The model.
        parent: The pose (4, 4) in the viser frame of the frame the geom poses are given in.
        opacity: The nodes' opacity (None: opaque).

    Attributes:
        meshes: Each drawn geom's mesh in its own frame, by geom index (what a click is tested on).
        poses: Each drawn geom's pose in the viser frame as last sent (4, 4), by geom index.
        nodes: The batched nodes by part name, and the mesh nodes of geoms drawn on their own.
    """

    def __init__(
        self, scene: viser.SceneApi, name: str, model: mujoco.MjModel, parent: Array, opacity: float | None = None
    ) -> None:
        self.parent = parent
        self.meshes: dict[int, trimesh.Trimesh] = {}
        self.poses: dict[int, Array] = {}
        #: Per part name: the geoms and their parts' poses in the geom's frame, in instance order.
        self._instances: dict[str, list[tuple[int, Array]]] = {}
        self._own: dict[int, viser.MeshHandle] = {}
        parts: dict[str, viser.BatchedMeshHandle] = {}
        scales: dict[str, list[Array]] = {}
        colors: dict[str, list[tuple[int, int, int]]] = {}
        units = _unit_parts()
        for g in range(model.ngeom):
            mesh = _geom_mesh(model, g)
            if mesh is None:
                continue
            self.meshes[g] = mesh
            self.poses[g] = np.eye(4)
            found = _geom_parts(model, g)
            if found is None:
                self._own[g] = scene.add_mesh_simple(
                    f"{name}/geom_{g}", mesh.vertices, mesh.faces, color=_rgb(model.geom_rgba[g]), opacity=opacity
                )
                continue
            for part, T_geom_part, scale in found:
                self._instances.setdefault(part, []).append((g, T_geom_part))
                scales.setdefault(part, []).append(scale)
                colors.setdefault(part, []).append(_linear_rgb(model.geom_rgba[g]))
        for part, instances in self._instances.items():
            n = len(instances)
            parts[part] = scene.add_batched_meshes_simple(
                f"{name}/{part}",
                units[part].vertices,
                units[part].faces,
                batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
                batched_positions=np.zeros((n, 3)),
                batched_scales=np.array(scales[part]),
                batched_colors=np.array(colors[part], dtype=np.uint8),
                lod="off",
                opacity=opacity,
            )
        self.nodes: list[viser.SceneNodeHandle] = [*parts.values(), *self._own.values()]
        self._parts = parts
        self._shown = True

    @property
    def visible(self) -> bool:
        """Whether the geoms are drawn."""
        return self._shown

    @visible.setter
    def visible(self, shown: bool) -> None:
        if shown != self._shown:
            for node in self.nodes:
                node.visible = shown
            self._shown = shown

    def pose(self, g: int) -> Array:
        """Geom ``g``'s pose in the viser frame as last sent (4, 4)."""
        return self.poses[g]

    def update(self, xpos: Array, xmat: Array, resolution: float) -> None:
        """Place every geom at its pose (``xpos`` (n, 3), ``xmat`` (n, 9), in the parent's frame):
        all are sent when one has moved by ``resolution`` (m) or turned by :data:`SHOWN_TURN`
        since last sent, else none."""
        poses = {g: self.parent @ make_pose(xmat[g].reshape(3, 3), xpos[g]) for g in self.poses}
        if not any(
            np.max(np.abs(T[0:3, 3] - self.poses[g][0:3, 3])) >= resolution
            or turn_between(matrix_to_quat(T[0:3, 0:3]), matrix_to_quat(self.poses[g][0:3, 0:3])) >= SHOWN_TURN
            for g, T in poses.items()
        ):
            return
        self.poses = poses
        for part, instances in self._instances.items():
            wxyzs, positions = zip(*(pose_to_wxyz_position(poses[g] @ T) for g, T in instances), strict=True)
            batch = self._parts[part]
            batch.batched_wxyzs = np.array(wxyzs, dtype=np.float32)
            batch.batched_positions = np.array(positions, dtype=np.float32)
        for g, own in self._own.items():
            own.wxyz, own.position = pose_to_wxyz_position(poses[g])


class SceneView:
    """The viser scene nodes of one servo loop (device + scene); rebuilt when either changes.

    Args:
        server: The viser server (scene shared by every browser).
        loop: The servo loop whose device and scene are drawn (only read at construction).
        on_hand_moved: Called with ``T_0_H`` (4, 4, device base) when a browser drags the gizmo.

    Attributes:
        on_hand_moved: As given; replaced when the view is reused for another loop of the same
            files (a replay of a log of the live scene and device).
    """

    def __init__(self, server: viser.ViserServer, loop: ServoLoop, on_hand_moved: Callable[[Array], None]) -> None:
        self.server = server
        self.on_hand_moved = on_hand_moved
        scene = server.scene
        self._handles: list[viser.SceneNodeHandle] = []
        #: Each placed node's orientation (wxyz) and position as last sent, apart: a node that only
        #: moves (a label, the grip in rate mode) sends no orientation.
        self._sent_wxyz: dict[str, Array] = {}
        self._sent_position: dict[str, Array] = {}
        self._last_points: dict[str, Array] = {}
        #: The meshes a click can land on: whether it is shown, the mesh in its own frame and its
        #: pose in the viser frame as last sent (4, 4): functions, as they change.
        self._pickable: list[tuple[Callable[[], bool], trimesh.Trimesh, Callable[[], Array]]] = []

        # The world's frames at its own scale (8 cm axes hid a 13 cm peg block).
        axes = 1.5 * ARROW_UNIT_FRACTION * space_size(world_box(loop.slave.scene))
        # {0} and {w} never move: their axes are one node (one draw), /device and /world groups
        # (no draw) hold their labels and the world's objects.
        self._add(_add_axes_set(scene, "/base_frames", [T_V_0, T_V_W], [0.08, axes]))
        self._add(scene.add_frame("/device", show_axes=False, position=DEVICE_ORIGIN_V))
        self._add(scene.add_label("/device/label", "device base {0}", position=(0.0, 0.0, -0.03)))
        self._add(scene.add_frame("/world", show_axes=False, position=WORLD_ORIGIN_V))
        self._add(scene.add_label("/world/label", "slave world {w}", position=(0.0, 0.0, -0.05)))

        self.links = self._geoms(GeomBatches(scene, "/links", loop.plant.model, T_V_0))

        self.grip = self._add(_add_axes(scene, "/grip", 0.05, 0.004))
        self._add(scene.add_label("/grip/label", "{G}", position=(0.0, 0.0, 0.02)))
        self.reference = self._add(_add_axes(scene, "/reference", 0.04, 0.0015))
        self._add(scene.add_label("/reference/label", "{G0}", position=(0.0, 0.0, -0.02)))
        T_0_G = loop.reading.T_0_G.copy()
        wxyz, position = pose_to_wxyz_position(T_V_0 @ T_0_G)
        self.hand_target = self._add(
            scene.add_transform_controls(
                "/hand_target", scale=0.12, depth_test=False, opacity=0.8, wxyz=wxyz, position=position
            )
        )
        #: The gizmo's pose ``T_0_H`` (4, 4, {0}) last asked for and last sent (:meth:`set_hand_target`).
        self._hand_target = self._hand_target_sent = T_0_G

        @self.hand_target.on_update
        def _(event: viser.TransformControlsEvent) -> None:
            self.on_hand_moved(viser_to_device(event.target.wxyz, event.target.position))

        static = static_mesh(loop.slave.scene)
        if static is not None:
            handle = scene.add_mesh_simple(
                "/world/objects", static.vertices, static.faces, color=STATIC_COLOR, opacity=0.9
            )
            self._mesh(handle, static, _at_world)
        # The dynamic objects: meshes in their own frames {B}, placed at {B}'s pose in {w} (their
        # parent /world is {w}) from each snapshot.
        self.bodies: list[viser.MeshHandle] = []
        for b, body in enumerate(loop.slave.scene.bodies):
            wxyz, position = pose_to_wxyz_position(body.T_w_B)
            mesh = drawn_mesh(body.object.mesh)
            handle = scene.add_mesh_simple(
                f"/world/body_{b}", mesh.vertices, mesh.faces, color=DYNAMIC_COLOR, wxyz=wxyz, position=position
            )
            self.bodies.append(self._mesh(handle, mesh, _at_world))
        self.slave_geoms = self._geoms(GeomBatches(scene, "/slave", loop.slave.model, T_V_W, opacity=0.85))
        # The tool and the F/T sensor are rigid on {MRF}: children of /mrf, so a moving tool costs
        # one pose update, not three.
        tool = loop.slave.scene.tool
        # /mrf is a group (no draw); the axes of {MRF} and {S} are one node in it (one draw), {S}'s
        # instance at {S}'s pose in {MRF} (fixed: sent once, with the /mrf/sensor group holding its label).
        self.mrf = self._add(scene.add_frame("/mrf", show_axes=False))
        self.mrf_axes = self._add(_add_axes_set(scene, "/mrf/axes", [np.eye(4), np.eye(4)], [axes, 0.75 * axes]))
        self._add(scene.add_label("/mrf/label", "{MRF}", position=(0.015, 0.0, 0.0)))
        tool_mesh = _tool_mesh(tool.centers_T, tool.radii)
        #: Radius (m) of the tool's sphere shell about {MRF}: what the tool camera preset frames.
        self.tool_radius = float(np.max(np.linalg.norm(tool_mesh.vertices - tool.T_T_MRF[0:3, 3], axis=1)))
        wxyz, position = pose_to_wxyz_position(invert_pose(tool.T_T_MRF))
        tool_handle = scene.add_mesh_simple(
            "/mrf/tool", tool_mesh.vertices, tool_mesh.faces, color=(200, 160, 60), wxyz=wxyz, position=position
        )
        self.tool = self._mesh(tool_handle, tool_mesh, lambda: _pose(self.mrf))
        self.sensor = self._add(scene.add_frame("/mrf/sensor", show_axes=False))
        self._add(scene.add_label("/mrf/sensor/label", "{S}", position=(0.015, 0.0, 0.0)))
        self.device_box_v = device_box(loop) + DEVICE_ORIGIN_V
        self.world_box_v = world_box(loop.slave.scene) + WORLD_ORIGIN_V
        # Arrow units: the device's and the world's own scale (a peg block is 10x smaller than a terrain).
        self.units = {
            "device": ARROW_UNIT_FRACTION * space_size(self.device_box_v),
            "world": ARROW_UNIT_FRACTION * space_size(self.world_box_v),
        }
        #: The least move (m) sent in each space (:data:`SHOWN_RESOLUTION`).
        self.resolution = {
            "device": SHOWN_RESOLUTION * space_size(self.device_box_v),
            "world": SHOWN_RESOLUTION * space_size(self.world_box_v),
        }
        world_unit = self.units["world"]
        self.contacts = self._add(
            scene.add_point_cloud(
                "/contacts",
                np.zeros((1, 3)),
                colors=CONTACT_COLOR,
                point_size=0.15 * world_unit,
                point_shape="circle",
                visible=False,
            )
        )
        #: The wrench arrows, one node per space: its arrows (shafts and heads) are two instanced
        #: draws whatever their number, where a node per arrow cost two draws each (software WebGL
        #: spends about half a millisecond of the GPU process's CPU a draw). Arrows in a space
        #: share its unit's radii. The world's node draws the contact normals too (magenta).
        self.arrows: dict[Space, viser.ArrowsHandle] = {}
        #: The arrows each node draws, in its order (``task_MRF/force``, ``hand_G/moment``...).
        self.arrow_keys: dict[Space, tuple[str, ...]] = {}
        for space in SPACES:
            unit = self.units[space]
            self.arrows[space] = self._add(
                scene.add_arrows(
                    f"/wrenches/{space}",
                    np.zeros((1, 2, 3)),
                    colors=(0, 0, 0),
                    shaft_radius=0.06 * unit,
                    head_radius=0.15 * unit,
                    head_length=0.3 * unit,
                    visible=False,
                )
            )
            self.arrow_keys[space] = ()
        #: Each arrow's colour: the wrench's, darker for its moment.
        self.arrow_colors: dict[str, tuple[int, int, int]] = {}
        self.labels: dict[str, viser.LabelHandle] = {}
        self._label_force: dict[str, float] = {}
        for arrow in WRENCH_ARROWS:
            for part, shade in (("force", 1.0), ("moment", 0.55)):
                r, g, b = (int(c * shade) for c in arrow.color)
                self.arrow_colors[f"{arrow.key}/{part}"] = (r, g, b)
            self.labels[arrow.key] = self._add(
                scene.add_label(f"/wrenches/{arrow.key}/label", "", visible=False, font_screen_scale=0.8)
            )

    def _add(self, handle: H) -> H:
        self._handles.append(handle)
        return handle

    def _mesh(self, handle: viser.MeshHandle, mesh: trimesh.Trimesh, parent: Callable[[], Array]) -> viser.MeshHandle:
        """Keep a mesh node (whose parent frame's pose in the viser frame ``parent`` gives) for :meth:`pick`."""
        self._pickable.append((lambda: bool(handle.visible), mesh, lambda: parent() @ _pose(handle)))
        return self._add(handle)

    def _geoms(self, batches: GeomBatches) -> GeomBatches:
        """Keep a model's geoms' nodes, and each geom for :meth:`pick`."""
        for node in batches.nodes:
            self._add(node)
        for g, mesh in batches.meshes.items():
            self._pickable.append((lambda: batches.visible, mesh, partial(batches.pose, g)))
        return batches

    def pick(self, origin: Array, direction: Array) -> Array | None:
        """The nearest point (viser frame, m) where the ray ``origin + t * direction`` (viser
        frame) meets a shown mesh, at the pose last sent to the browsers; None if it meets none."""
        direction = direction / np.linalg.norm(direction)
        nearest: float | None = None
        for shown, mesh, pose in self._pickable:
            if not shown():
                continue
            T_v_m = pose()
            R = T_v_m[0:3, 0:3]
            # The ray in the mesh's frame.
            o_m, d_m = R.T @ (origin - T_v_m[0:3, 3]), R.T @ direction
            hits, _, _ = mesh.ray.intersects_location([o_m], [d_m], multiple_hits=False)
            if len(hits):
                t = float((hits[0] - o_m) @ d_m)
                if t > 0.0 and (nearest is None or t < nearest):
                    nearest = t
        return None if nearest is None else origin + nearest * direction

    def remove(self) -> None:
        """Take every node of this view out of the scene."""
        for handle in reversed(self._handles):
            handle.remove()
        self._handles.clear()

    def set_hand_target(self, T_0_H: Array) -> None:
        """Put the gizmo at ``T_0_H`` (4, 4, device base) with the next :meth:`update`: sent in the
        scene's own websocket window, not in one of its own. A pose sent on its own lands in a
        window between the UI thread's, which the page applies only in a 3D frame, and holds the
        panel's next window behind it (a hand moved at the UI rate, 40 Hz, made every window a
        scene window)."""
        self._hand_target = T_0_H.copy()

    def _place(self, key: str, handle: viser.SceneNodeHandle, T_v: Array, space: Space) -> None:
        """Move ``handle`` to pose ``T_v`` (in its parent's frame): its orientation is sent when it
        has turned by :data:`SHOWN_TURN` since last sent, its position when it has moved by the
        ``space``'s resolution, each on its own (a node that moves without turning sends no
        orientation)."""
        wxyz, position = pose_to_wxyz_position(T_v)
        sent = self._sent_wxyz.get(key)
        if sent is None or turn_between(sent, wxyz) >= SHOWN_TURN:
            self._sent_wxyz[key] = wxyz
            handle.wxyz = wxyz
        sent = self._sent_position.get(key)
        if sent is None or np.max(np.abs(sent - position)) >= self.resolution[space]:
            self._sent_position[key] = position
            handle.position = position

    @staticmethod
    def _place_instance(batch: viser.BatchedAxesHandle, i: int, like: viser.SceneNodeHandle) -> None:
        """Put instance ``i`` of ``batch`` at ``like``'s pose as last sent (viser sends an array only
        when it changed: nothing while it is there)."""
        wxyzs, positions = np.array(batch.batched_wxyzs), np.array(batch.batched_positions)
        wxyzs[i], positions[i] = like.wxyz, like.position
        batch.batched_wxyzs = wxyzs
        batch.batched_positions = positions

    def _points(
        self, key: str, handle: viser.PointCloudHandle | viser.ArrowsHandle, points: Array, space: Space
    ) -> None:
        """Set ``handle``'s points (m, viser frame), sending nothing when none moved by the
        ``space``'s resolution since last sent."""
        last = self._last_points.get(key)
        if last is not None and last.shape == points.shape and np.max(np.abs(last - points)) < self.resolution[space]:
            return
        self._last_points[key] = points
        handle.points = points.astype(np.float32)

    @staticmethod
    def _arrow(origin_v: Array, vector_v: Array, reference: float, unit: float) -> Array | None:
        """The start and tip (2, 3; viser frame, m) of the arrow for ``vector_v`` (N or N m, viser
        axes) at ``origin_v`` in a space of arrow ``unit`` (m), or None when it is too small to show."""
        magnitude = float(np.linalg.norm(vector_v))
        if magnitude < MIN_SHOWN * reference:
            return None
        return np.stack((origin_v, origin_v + vector_v * (arrow_length(magnitude, reference, unit) / magnitude)))

    def _draw_arrows(self, space: Space, shown: dict[str, Array]) -> None:
        """Draw the arrows ``shown`` (key -> start and tip, (2, 3)) in ``space``'s node: its colours
        are sent when the set of arrows changes, its points as :meth:`_points` sends them."""
        handle, keys = self.arrows[space], tuple(shown)
        if keys != self.arrow_keys[space]:
            self.arrow_keys[space] = keys
            self._last_points.pop(f"arrows/{space}", None)  # other arrows: redrawn whatever moved
            if keys:
                colors = [CONTACT_COLOR if k.startswith(CONTACT_NORMAL) else self.arrow_colors[k] for k in keys]
                handle.colors = np.array(colors, dtype=np.uint8)
        if keys:
            self._points(f"arrows/{space}", handle, np.stack(list(shown.values())), space)
        handle.visible = bool(keys)

    def update(self, snap: Snapshot) -> None:
        """Move every node to the state in ``snap``, and the gizmo where it was last put (call from
        the UI thread)."""
        target = self._hand_target  # read once: a browser's callback may put it again meanwhile
        if target is not self._hand_target_sent:
            self._hand_target_sent = target
            self.hand_target.wxyz, self.hand_target.position = pose_to_wxyz_position(T_V_0 @ target)
        # A device not simulated here (a served or real one, or a Cartesian device's log) reports
        # its grip, not its links: they are hidden rather than left where the model put them.
        self.links.visible = len(snap.geom_xpos) > 0
        if self.links.visible:
            self.links.update(snap.geom_xpos, snap.geom_xmat, self.resolution["device"])
        if len(snap.slave_geom_xpos):
            self.slave_geoms.update(snap.slave_geom_xpos, snap.slave_geom_xmat, self.resolution["world"])
        T_v_G = T_V_0 @ snap.T_0_G
        self._place("grip", self.grip, T_v_G, "device")
        self._place("reference", self.reference, T_V_0 @ snap.T_0_G0, "device")
        T_v_MRF = T_V_W @ snap.T_w_MRF
        self._place("mrf", self.mrf, T_v_MRF, "world")  # with the tool and {S} on it
        T_MRF_S = invert_pose(snap.T_w_MRF) @ snap.T_w_S  # fixed: sent once
        self._place("sensor", self.sensor, T_MRF_S, "world")
        self._place_instance(self.mrf_axes, 1, self.sensor)
        for b, (handle, pose) in enumerate(zip(self.bodies, snap.object_poses, strict=True)):
            self._place(f"body_{b}", handle, make_pose(quat_to_matrix(pose[3:7]), pose[0:3]), "world")

        points = snap.contact_points_w
        if len(points):
            self._points("contacts", self.contacts, points + WORLD_ORIGIN_V, "world")
        self.contacts.visible = len(points) > 0

        R_v_MRF, R_v_G = T_v_MRF[0:3, 0:3], T_v_G[0:3, 0:3]
        p_MRF, p_G = T_v_MRF[0:3, 3], T_v_G[0:3, 3]
        in_v = {
            "task_MRF": (p_MRF, R_v_MRF @ snap.F_MRF[0:3], R_v_MRF @ snap.F_MRF[3:6]),
            "reflected_G": (p_G, R_v_G @ snap.G_F_T[0:3], R_v_G @ snap.G_F_T[3:6]),
            "assist_G": (p_G, R_v_G @ snap.G_F_RD[0:3], R_v_G @ snap.G_F_RD[3:6]),
            "hand_G": (p_G, snap.hand_wrench_0[0:3], snap.hand_wrench_0[3:6]),
        }
        arrows: dict[Space, dict[str, Array]] = {space: {} for space in SPACES}
        tips = points + CONTACT_NORMAL_UNITS * self.units["world"] * snap.contact_normals_w
        for i, ends in enumerate(np.stack((points, tips), axis=1) + WORLD_ORIGIN_V):
            arrows["world"][f"{CONTACT_NORMAL}{i}"] = ends
        for arrow in WRENCH_ARROWS:
            origin, force, moment = in_v[arrow.key]
            unit, drawn = self.units[arrow.space], arrows[arrow.space]
            for part, vector, reference in (("force", force, FORCE_REF), ("moment", moment, MOMENT_REF)):
                ends = self._arrow(origin, vector, reference, unit)
                if ends is not None:
                    drawn[f"{arrow.key}/{part}"] = ends
            tip = drawn.get(f"{arrow.key}/force")
            self._label(arrow.key, None if tip is None else tip[1], float(np.linalg.norm(force)), arrow.space)
        for space in SPACES:
            self._draw_arrows(space, arrows[space])

    def _label(self, key: str, tip: Array | None, magnitude: float, space: Space) -> None:
        """The magnitude at a force arrow's tip, rewritten when it has changed by
        :data:`SHOWN_FORCE` (so noise does not flicker its last digit), moved with the tip."""
        label = self.labels[key]
        if tip is None:
            label.visible = False
            return
        shown = self._label_force.get(key)
        if shown is None or abs(magnitude - shown) >= SHOWN_FORCE:
            self._label_force[key] = magnitude
            label.text = f"{magnitude:.1f} N"
        self._place(f"label/{key}", label, make_pose(np.eye(3), tip), space)
        label.visible = True
