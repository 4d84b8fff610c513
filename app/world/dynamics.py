"""Objects that move: the scene's dynamic objects simulated in one MuJoCo model, stepped with the
slave's substeps.

:func:`world_contact` gives the slave what it evaluates every substep: the scene's
:class:`~app.world.contact.ContactModel` when every object is static (the static path, unchanged),
or a :class:`MovingWorld`, which answers the same :meth:`~MovingWorld.wrench` call and must then
be advanced with :meth:`~MovingWorld.step` after each substep.

Contact, per pair:

- **Tool - dynamic object**: the contact model of :mod:`app.world.contact`, one per object, built
  once on the object's mesh in its own frame {B}: each evaluation is a query in {B}, the tool's
  pose ``T_B_MRF = T_w_B^-1 T_w_MRF`` and its twist relative to the object (the velocity of the
  tool's material points as seen from {B}), so its memory, caches and culling work as for a
  static mesh and nothing is rebuilt per tick. The wrench it returns on the tool is applied,
  equal and opposite, to the object at the same instant (``xfrc_applied`` for the substep that
  follows): the F/T sensor and the object feel the same impulse. The static model, the
  objects' frames and every near object's model are evaluated in one compiled call
  (:func:`~app.world.dynamics_kernel.moving_wrench`, entered without numba's argument typing):
  a call into each model from Python cost ~2 us of crossing apiece, and the frame arithmetic
  around them as much again (stack_topple's wrench: 8.8 us median, 5.3 us in one call).
- **Object - object and object - static, convex shapes**: MuJoCo's own collision (boxes,
  spheres, cylinders, planes as its primitives, a convex mesh as itself), with its elliptic
  friction cone (a pair's coefficient is the larger of the two, MuJoCo's rule) and soft
  constraints, critically damped (damping ratio 1): an underdamped contact (ratio 0.22, a
  restitution of 0.5) left a box resting on a plane bouncing at 9 mm/s for good, measured,
  where ratio 1 holds it to 1e-12 m/s; so these impacts do not bounce. Measured
  on this machine against python-fcl on the same box resting on a slab (``frhc bench moving``):
  FCL's BVH-BVH ``collide`` returned 16 contacts (each corner several times) in 94 us with its
  contacts read into Python, and 1.3 mm for an icosphere sunk 3 mm into a slab (triangle-triangle
  depths, not the solids'); MuJoCo's box-box collider gives the four corners at the exact depth
  inside ``mj_step`` (the whole step of a three-box stack: see the bench). A pair of convex
  shapes is therefore MuJoCo's.
- **A pair with a non-convex mesh** (a block with holes, a peg with a head): MuJoCo would collide
  its convex hull, which fills the hole. python-fcl collides the two BVH meshes (the triangles
  themselves) and each contact pushes with the penalty law of the tool's contacts (:mod:`app.world.contact.force`): stiffness the
  two objects' in series, damping and friction the larger of the two. How many points FCL
  reports depends on the triangulation (a 64-section peg's end on a hole's floor: 32, more than
  the 1 ms step can hold as separate springs: a 61 g peg landing at 0.6 m/s exploded), so the
  contacts of a pair are grouped by normal (within :data:`FCL_SAME_NORMAL`) and each group is one
  contact: its deepest depth, its mean normal, at the depth-weighted mean of its points. A face
  on a face is one spring at its centre of pressure; a peg against a hole's floor and wall, two.
  This path is slow: a step took tens of milliseconds once many triangle pairs touched (a peg
  in its hole, a ball in a channel), so no shipped scene uses it yet: ``peg_carry`` authors its
  holed collar as convex boxes, which MuJoCo collides with the peg (a cylinder) in 8.7 us a
  step with the peg in the bore (median, measured).
- **The grip** (:meth:`MovingWorld.grip`): the tool holds the dynamic object it touches where
  it is in {MRF}, through a spring-damper computed with the tool's contacts
  (:func:`~app.world.dynamics_kernel.add_grip`): critically damped at ``omega = GRIP_OMEGA_H /
  h`` in every direction (stiffness ``m omega^2`` on the centre of mass, ``I omega^2`` about it,
  so a light peg's spin, 12 times less inertia than its tilt, is as stable as the rest; equal
  gains on all axes made the 15 g peg unstable at 1 ms, measured), its force on the tool equal
  and opposite at the same instant: carried still, the F/T reads the peg's weight. The held
  object leaves the tool's sphere contact (the grip is that contact).

Frames: {w} the world, {B} a dynamic object's frame (the MuJoCo body frame; its centre of mass
is ``Body.com_B`` in it). MuJoCo's free joint holds {B}'s origin (world) and orientation, its
velocity is the origin's (world axes) and its angular velocity in {B} axes.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import fcl
import mujoco
import numpy as np
import trimesh

from app.compiled import entry_point, is_f8
from app.mjcall import address, pointers
from app.spatial import Array, matrix_to_quat
from app.world.contact import ContactModel, ContactResult
from app.world.contact.force import V_SLIP
from app.world.contact.layout import MAX_PER_PAIR
from app.world.contact.model import contact_inputs, failed
from app.world.dynamics_kernel import body_frames, moving_wrench, world_step
from app.world.scene import Body, Scene, WorldObject

#: Time constant (s) of MuJoCo's soft contacts between objects: a numerical choice (MuJoCo asks
#: for at least two timesteps; four at the 1 ms servo period). A 0.2 kg box resting on a plane
#: sinks 4 um.
TIMECONST = 0.004
_SHAPE_T, _SHAPE_V = (4, 4), (6,)
#: The grip's natural frequency times the step (-): the held object follows the tool as a
#: critically damped oscillator of this frequency in every direction (its stiffness ``m omega^2``
#: and ``I omega^2`` scale with its mass and inertia), as stiff as the explicit coupling at the
#: step keeps well stable (it sags ``g / omega^2`` = 0.25 mm under its own weight at 1 kHz). A
#: numerical choice, not a gripper's.
GRIP_OMEGA_H = 0.2
#: Most contacts read from one FCL pair per step (before merging duplicates).
FCL_MAX_CONTACTS = 64
#: FCL contacts whose normals' cosine exceeds this are one group (one contact).
FCL_SAME_NORMAL = math.cos(math.radians(20.0))
#: FCL contacts deeper than this (m) are dropped: coplanar triangle pairs report the triangles'
#: extent as the depth (0.1 m for two 10 cm boxes side by side with flush tops, measured), while
#: a penalty contact at the shipped stiffnesses sinks well under a millimetre.
FCL_MAX_DEPTH = 0.005


def _convex(obj: WorldObject, shape: str) -> bool:
    """Whether MuJoCo collides the object as it is: a primitive, or a mesh equal to its hull."""
    return shape != "mesh" or bool(obj.mesh.is_convex)


def _shape(scene: Scene, obj: WorldObject) -> str:
    """The shape field of a static object's file entry."""
    return next(s.shape for s in scene.spec.objects if s.name == obj.name)


def _fmt(values: Array | tuple[float, ...]) -> str:
    """Numbers as MJCF writes them: space-separated, exact."""
    return " ".join(repr(float(v)) for v in np.ravel(np.asarray(values, dtype=float)))


def _geom(name: str, obj: WorldObject, shape: str, spec_shape: Any, T: Array, body: Body | None) -> str:
    """A MuJoCo geom for an object at pose T (its frame in the parent), or "" if not convex."""
    if not _convex(obj, shape):
        return ""
    pos, quat = _fmt(T[0:3, 3]), _fmt(matrix_to_quat(T[0:3, 0:3]))
    common = (
        f'name="{name}" pos="{pos}" quat="{quat}" friction="{obj.friction!r} 0 0" solref="{TIMECONST!r} 1" condim="3"'
    )
    if body is not None:
        common += ' mass="0"'  # the body's inertial comes from its mesh, not MuJoCo's geoms
    if shape == "box":
        return f'<geom type="box" size="{_fmt(np.asarray(spec_shape) / 2)}" {common}/>'
    if shape == "sphere":
        return f'<geom type="sphere" size="{spec_shape!r}" {common}/>'
    if shape == "cylinder":
        r, h = spec_shape
        return f'<geom type="cylinder" size="{r!r} {h / 2!r}" {common}/>'
    return f'<geom type="mesh" mesh="{name}" {common}/>'


def _mesh_asset(name: str, mesh: trimesh.Trimesh) -> str:
    return f'<mesh name="{name}" vertex="{_fmt(mesh.vertices)}" face="{" ".join(str(int(i)) for i in np.ravel(mesh.faces))}"/>'


def _world_xml(scene: Scene, timestep: float) -> str:
    assets, statics, bodies = [], [], []
    for j, o in enumerate(scene.objects):
        spec = next(s for s in scene.spec.objects if s.name == o.name)
        shape = spec.shape
        if shape == "mesh" and _convex(o, shape):
            assets.append(_mesh_asset(f"s{j}", o.mesh))  # in {w}: the pose is in its vertices
            statics.append(_geom(f"s{j}", o, "mesh", None, np.eye(4), None))
        elif shape == "plane":
            # The thin box it is (top face at the pose's z = 0) as MuJoCo's box, whose box-box
            # collider beat the same box as a mesh (stack_topple's step 6.8 against 7.4 us).
            t = spec.plane_thickness
            assert spec.plane is not None
            below = spec.pose.matrix() @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -t / 2], [0, 0, 0, 1.0]])
            statics.append(_geom(f"s{j}", o, "box", (*spec.plane, t), below, None))
        else:
            statics.append(_geom(f"s{j}", o, shape, getattr(spec, shape), spec.pose.matrix(), None))
    for b, body in enumerate(scene.bodies):
        shape = body.spec.shape
        if shape == "mesh" and _convex(body.object, shape):
            assets.append(_mesh_asset(f"b{b}", body.object.mesh))
        geom = _geom(f"b{b}", body.object, shape, getattr(body.spec, shape), np.eye(4), body)
        I = body.inertia_B
        full = _fmt((I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]))
        T = body.T_w_B
        bodies.append(
            f'<body name="b{b}" pos="{_fmt(T[0:3, 3])}" quat="{_fmt(matrix_to_quat(T[0:3, 0:3]))}">'
            f'<freejoint/><inertial pos="{_fmt(body.com_B)}" mass="{body.mass!r}" fullinertia="{full}"/>{geom}</body>'
        )
    return f"""<mujoco model="moving_world">
  <option timestep="{timestep!r}" gravity="{_fmt(scene.gravity_w)}" integrator="Euler" cone="elliptic"/>
  <asset>{"".join(assets)}</asset>
  <worldbody>{"".join(statics)}{"".join(bodies)}</worldbody>
</mujoco>"""


def _bvh(mesh: trimesh.Trimesh) -> fcl.CollisionObject:
    """An FCL object of the mesh's triangles (a BVH of oriented boxes), in the mesh's own frame."""
    model = fcl.BVHModel()
    model.beginModel(len(mesh.vertices), len(mesh.faces))
    model.addSubModel(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int32))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


@dataclasses.dataclass
class FclPair:
    """A pair collided by python-fcl: body ``a`` against body ``b`` (or static object ``static``).

    Attributes:
        a: Index of the first dynamic object.
        b: Index of the second, or -1 for a static object.
        k: Stiffness (N/m) per contact (group): the two objects' in series.
        damping: Damping (N s/m) per contact, the larger of the two.
        mu: Friction coefficient (-), the larger of the two.
        obj_a, obj_b: Their FCL objects (a static one in {w}, never moved).
        reach: Bounding-sphere radii (m) of the two meshes about their frames' origins, for culling.
        vertices_a: The first object's mesh vertices in its frame {B} (m), (V, 3).
        static_box: A static object's bounding box ``[lo, hi]`` in {w} (m), (6,).
    """

    a: int
    b: int
    k: float
    damping: float
    mu: float
    obj_a: fcl.CollisionObject
    obj_b: fcl.CollisionObject
    reach: tuple[float, float]
    vertices_a: Array
    static_box: Array | None = None


def fcl_contacts(obj_a: fcl.CollisionObject, obj_b: fcl.CollisionObject, vertices_a: Array, T_w_a: Array) -> Array:
    """Contacts between two FCL objects at their current transforms: rows ``[p (3), n (3), depth]``
    in {w}, n pointing from ``obj_a`` into ``obj_b`` (the direction of the force on b), (k, 7).

    FCL's contacts with depths in ``(0, FCL_MAX_DEPTH]`` are grouped by normal (module
    docstring): one row per group, its mean normal, at the depth-weighted mean of its points.
    FCL's BVH-BVH depth is the triangle pair's, not the solids' (1.3 mm for an icosphere sunk
    3 mm into a slab, measured), so a group's depth is that of the deepest vertex of a
    (``vertices_a``, (V, 3), in a's frame, placed by ``T_w_a``) over the group's patch (within
    the box of its points across n) past the group's point least far along n (on b's surface
    when FCL reports a point there), or FCL's deepest if larger (its points may all be a's
    vertices): exact where b's touched face is flat (a box's corners, a sphere's lowest vertex,
    a face pressed into a wall).
    """
    result = fcl.CollisionResult()
    fcl.collide(obj_a, obj_b, fcl.CollisionRequest(num_max_contacts=FCL_MAX_CONTACTS, enable_contact=True), result)
    if not result.contacts:
        return np.zeros((0, 7))
    rows = np.array([(*c.pos, *c.normal, c.penetration_depth) for c in result.contacts], dtype=float)
    rows = rows[(rows[:, 6] > 0.0) & (rows[:, 6] <= FCL_MAX_DEPTH)]
    rows = rows[np.argsort(-rows[:, 6], kind="stable")]
    out = []
    v_w = vertices_a @ T_w_a[0:3, 0:3].T + T_w_a[0:3, 3]
    while len(rows):
        same = rows[:, 3:6] @ rows[0, 3:6] > FCL_SAME_NORMAL
        group, rows = rows[same], rows[~same]
        n = group[:, 3:6].sum(axis=0)
        n /= np.linalg.norm(n)
        weights = group[:, 6] / group[:, 6].sum()
        p = weights @ group[:, 0:3]
        # Two axes across n; the patch is the box of the points in them.
        e1 = np.cross(n, (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0))
        e1 /= np.linalg.norm(e1)
        across = np.stack((e1, np.cross(n, e1)), axis=1)
        lo, hi = (group[:, 0:3] @ across).min(axis=0) - 1e-9, (group[:, 0:3] @ across).max(axis=0) + 1e-9
        uv = v_w @ across
        over = np.all((uv >= lo) & (uv <= hi), axis=1)
        entry = float((group[:, 0:3] @ n).min())  # the point least far along n: on b's surface
        depth = max(float((v_w[over] @ n).max()) - entry, group[0, 6]) if over.any() else group[0, 6]
        out.append((*p, *n, depth))
    return np.array(out)


class MovingWorld:
    """The scene's dynamic objects in one MuJoCo model, and the tool's contact with everything.

    Used like a :class:`~app.world.contact.ContactModel` (``wrench``, ``reset``) by the slave,
    which calls :meth:`step` after each substep to advance the objects by the same time under
    the reaction of the tool's last contact wrench.

    Args:
        scene: A scene with dynamic objects (``scene.bodies``).
        timestep: The slave's substep (s): the objects' integration step.
    """

    def __init__(self, scene: Scene, timestep: float) -> None:
        self.scene = scene
        self.static = ContactModel(scene)
        self.models = [ContactModel(dataclasses.replace(scene, objects=(b.object,), bodies=())) for b in scene.bodies]
        self.model = mujoco.MjModel.from_xml_string(_world_xml(scene, timestep))
        self.data = mujoco.MjData(self.model)
        self._h = timestep
        self._mj = np.array((address("mj_step"), *pointers(self.model, self.data)), dtype=np.int64)
        n = len(scene.bodies)
        self._qpos = self.data.qpos.reshape(n, 7)
        self._qvel = self.data.qvel.reshape(n, 6)
        self._xfrc = self.data.xfrc_applied[1 : n + 1]
        self._com = np.array([b.com_B for b in scene.bodies]).reshape(n, 3)
        self._reach = np.array([np.linalg.norm(b.object.mesh.vertices, axis=1).max() for b in scene.bodies])
        tool = scene.tool
        self._tool_reach = float(
            np.max(np.linalg.norm(tool.centers_T - tool.T_T_MRF[0:3, 3], axis=1) + tool.radii) + scene.spec.margin
        )
        self._pairs = self._fcl_pairs()
        # Buffers of body_frames: the objects' frames in {w} and the tool's last pose and twist in each.
        self._T, self._T_B_MRF = np.zeros((n, 4, 4)), np.zeros((n, 4, 4))
        self._c, self._vel, self._V_B = np.zeros((n, 3)), np.zeros((n, 6)), np.zeros((n, 6))
        self._near = np.zeros(n, dtype=np.int64)
        # A tool pose for body_frames when only the objects' frames are wanted (poses, FCL).
        self._any_pose = tool.T_w_MRF_home.copy()
        self._no_twist = np.zeros(6)
        # Outputs of moving_wrench: the tool's wrench, the contacts of every model in {w} (each
        # model's capacity), the summed queries and gathers, which model failed and the row count.
        self._w = np.zeros(15)
        self._rows = np.zeros((MAX_PER_PAIR * len(tool.radii) * (len(scene.objects) + n) + 1, 9))
        self._no_contacts = self._rows[:0]
        self._no_contacts.flags.writeable = False
        self._counts = np.zeros(4, dtype=np.int64)
        # The grip: [held object or -1, omega, its mass, its inertia in {B} (9)] and the held
        # object's pose in {MRF} (add_grip).
        self._grip = np.zeros(12)
        self._grip[0] = -1.0
        self._T_MRF_H = np.eye(4)
        self._T_w_MRF = tool.T_w_MRF_home.copy()  # the tool's pose at the last wrench
        # body_frames's arguments after the pose and twist.
        self._frame_args = (
            self._qpos, self._qvel, self._com, self._reach, self._tool_reach, self._T, self._c, self._vel,
            self._T_B_MRF, self._V_B, self._near,
        )  # fmt: skip
        # moving_wrench's arguments after the pose, twist and flag, the same objects every call:
        # the compiled call is entered without numba's typing of its arguments (app.compiled);
        # ``wrench`` checks the pose and twist.
        self._args = (
            self.static.arrays, tuple(m.arrays for m in self.models), self._frame_args, self._xfrc,
            len(scene.objects), self._grip, self._T_MRF_H, tool.T_MRF_S.copy(), self._w, self._rows, self._counts,
        )  # fmt: skip
        self._wrench = entry_point(moving_wrench, np.eye(4), self._no_twist, False, *self._args)
        self._step = entry_point(world_step, self._mj, self._xfrc)
        self.reset()

    def _fcl_pairs(self) -> list[FclPair]:
        """The pairs MuJoCo cannot collide (a non-convex mesh in them), each with its contact law."""
        scene = self.scene
        bodies = scene.bodies
        shapes = [b.spec.shape for b in bodies]
        pairs = []

        def law(*objs: WorldObject) -> tuple[float, float, float]:
            k = 1.0 / sum(1.0 / o.stiffness for o in objs)
            return k, max(o.damping for o in objs), max(o.friction for o in objs)

        bvh = [_bvh(b.object.mesh) for b in bodies]
        verts = [np.asarray(b.object.mesh.vertices, dtype=float) for b in bodies]
        reach = self._reach.tolist()
        convex = [_convex(b.object, s) for b, s in zip(bodies, shapes, strict=True)]
        for o in scene.objects:
            static_convex = _convex(o, _shape(scene, o))
            if static_convex and all(convex):
                continue
            obj = _bvh(o.mesh)
            box = np.concatenate([o.collision.lo, o.collision.hi])
            for a, body in enumerate(bodies):
                if convex[a] and static_convex:
                    continue
                k, b, mu = law(body.object, o)
                pairs.append(FclPair(a, -1, k, b, mu, bvh[a], obj, (reach[a], 0.0), verts[a], box))
        for a in range(len(bodies)):
            for c in range(a + 1, len(bodies)):
                if convex[a] and convex[c]:
                    continue
                k, b, mu = law(bodies[a].object, bodies[c].object)
                pairs.append(FclPair(a, c, k, b, mu, bvh[a], bvh[c], (reach[a], reach[c]), verts[a]))
        return pairs

    # --- state -----------------------------------------------------------------------------
    def reset(self) -> None:
        """Every object back to its initial pose and twist, the tool's contact memory forgotten."""
        mujoco.mj_resetData(self.model, self.data)
        for b, body in enumerate(self.scene.bodies):
            T = body.T_w_B
            self._qpos[b, 0:3] = T[0:3, 3]
            self._qpos[b, 3:7] = matrix_to_quat(T[0:3, 0:3])
            self._qvel[b, 0:3] = body.twist[0:3]
            self._qvel[b, 3:6] = T[0:3, 0:3].T @ body.twist[3:6]  # MuJoCo: angular velocity in {B}
        mujoco.mj_forward(self.model, self.data)
        self.static.reset()
        for m in self.models:
            m.reset()
        self._grip[0] = -1.0
        self._frames()

    def _frames(self) -> None:
        """Refresh the objects' frames, centres of mass and twists in {w} (the world's buffers)."""
        body_frames(self._any_pose, self._no_twist, *self._frame_args)

    def poses(self) -> Array:
        """Poses of the dynamic objects' frames {B} in {w}, (n, 4, 4) (a new array)."""
        self._frames()
        return self._T.copy()

    def twists(self) -> Array:
        """Twists ``[v; w]`` of the {B} frames in {w} (v of the origin), (n, 6) (a new array)."""
        self._frames()
        return self._vel.copy()

    # --- the tool's contact ------------------------------------------------------------------
    def wrench(self, T_w_MRF: Array, V_w_MRF: Array | None = None) -> ContactResult:
        """The tool's contact wrench with {MRF} at ``T_w_MRF`` against static and dynamic objects
        (as :meth:`ContactModel.wrench`; dynamic object b's contacts have object id
        ``len(scene.objects) + b``; ``queries`` and ``gathers`` are summed over the models). Its
        reaction on each dynamic object is applied during the next :meth:`step`. One compiled
        call (:func:`~app.world.dynamics_kernel.moving_wrench`) evaluates every model."""
        if not (is_f8(T_w_MRF, _SHAPE_T) and (V_w_MRF is None or is_f8(V_w_MRF, _SHAPE_V))):
            T_w_MRF, V_w_MRF = contact_inputs(T_w_MRF, V_w_MRF)
        if V_w_MRF is None:
            code = self._wrench(T_w_MRF, self._no_twist, False, *self._args)
        else:
            code = self._wrench(T_w_MRF, V_w_MRF, True, *self._args)
        self._T_w_MRF = T_w_MRF
        queries, gathers, which, _ = self._counts.tolist()
        if code < 0:
            (self.static if which < 0 else self.models[which]).reset()
            return failed(code)
        rows = self._rows[:code].copy() if code else self._no_contacts
        return ContactResult(True, self._w.copy(), rows, queries, gathers, None)

    # --- the grip ----------------------------------------------------------------------------
    @property
    def held(self) -> int:
        """Index of the dynamic object the grip holds, or -1."""
        return int(self._grip[0])

    def grip(self, on: bool) -> int:
        """Close the grip on the dynamic object the tool touches (or open it: ``on`` False).

        Closing holds the object the tool's last :meth:`wrench` touched (the one with the most
        contacts) where it is in {MRF} then; from the next :meth:`wrench` it follows the tool
        through a critically damped spring (:data:`GRIP_OMEGA_H`, module docstring) instead of
        the tool's spheres. Returns the object held, or -1 (nothing touched, or opened).
        """
        self._grip[0] = -1.0
        if not on:
            return -1
        touched = self._rows[: int(self._counts[3])]
        ids = touched[:, 8].astype(np.int64) - len(self.scene.objects)
        ids = ids[ids >= 0]
        if not len(ids):
            return -1
        b = int(np.bincount(ids).argmax())
        body = self.scene.bodies[b]
        self._grip[1], self._grip[2] = GRIP_OMEGA_H / self._h, body.mass
        self._grip[3:12] = body.inertia_B.ravel()
        self._frames()
        self._T_MRF_H[:] = np.linalg.solve(self._T_w_MRF, self._T[b])
        self._grip[0] = b
        return b

    # --- the objects' motion -----------------------------------------------------------------
    def step(self, h: float) -> None:
        """Advance the objects by ``h`` (s) under gravity, their contacts (MuJoCo's and FCL's) and
        the reaction of the tool's last :meth:`wrench`."""
        if h != self._h:
            self.model.opt.timestep = self._h = h
        if self._pairs:
            self._frames()
            self._fcl_forces()
        self._step(self._mj, self._xfrc)

    def _fcl_forces(self) -> None:
        """Add the FCL pairs' penalty forces to ``xfrc_applied`` (world force and torque at the
        centres of mass), for the frames in the buffers."""
        T_all, V_all, c_all = self._T, self._vel, self._c
        for pr in self._pairs:
            Ta = T_all[pr.a]
            if pr.b < 0:
                assert pr.static_box is not None
                lo, hi = pr.static_box[0:3], pr.static_box[3:6]
                gap = np.maximum(lo - Ta[0:3, 3], 0.0) + np.maximum(Ta[0:3, 3] - hi, 0.0)
                if np.linalg.norm(gap) > pr.reach[0]:
                    continue
            else:
                Tb = T_all[pr.b]
                if np.linalg.norm(Ta[0:3, 3] - Tb[0:3, 3]) > pr.reach[0] + pr.reach[1]:
                    continue
                pr.obj_b.setTransform(fcl.Transform(Tb[0:3, 0:3], Tb[0:3, 3]))
            pr.obj_a.setTransform(fcl.Transform(Ta[0:3, 0:3], Ta[0:3, 3]))
            for row in fcl_contacts(pr.obj_a, pr.obj_b, pr.vertices_a, Ta):
                q, n, depth = row[0:3], row[3:6], row[6]
                u = -(V_all[pr.a, 0:3] + np.cross(V_all[pr.a, 3:6], q - Ta[0:3, 3]))
                if pr.b >= 0:
                    u += V_all[pr.b, 0:3] + np.cross(V_all[pr.b, 3:6], q - T_all[pr.b, 0:3, 3])
                f = _penalty(pr.k, pr.damping, pr.mu, depth, n, u)  # on b; u: b relative to a
                self._xfrc[pr.a, 0:3] -= f
                self._xfrc[pr.a, 3:6] -= np.cross(q - c_all[pr.a], f)
                if pr.b >= 0:
                    self._xfrc[pr.b, 0:3] += f
                    self._xfrc[pr.b, 3:6] += np.cross(q - c_all[pr.b], f)


def _penalty(k: float, b: float, mu: float, depth: float, n: Array, u: Array) -> Array:
    """Force (N, {w}) on the body the unit normal ``n`` points into, at a contact of ``depth`` (m),
    its velocity relative to the other body there ``u`` (m/s): the law of
    :func:`app.world.contact.force.contact_force` (``k depth - b u_n`` clamped at 0, regularised
    Coulomb friction)."""
    un = float(u @ n)
    fn = max(0.0, k * depth - b * un)
    ut = u - un * n
    return fn * n - mu * fn * ut / max(float(np.linalg.norm(ut)), V_SLIP)


def world_contact(scene: Scene, timestep: float) -> ContactModel | MovingWorld:
    """What a slave evaluates the tool's contact with: the static :class:`ContactModel` when the
    scene has no dynamic object, else a :class:`MovingWorld` (advance it with ``step``)."""
    return MovingWorld(scene, timestep) if scene.bodies else ContactModel(scene)
