"""The virtual slave: a tool body in MuJoCo, driven by a force-limited Cartesian PD toward a reference.

One servo tick (:meth:`VirtualSlave.step`):

1. Reference update. Rate mode (active): the {MRF} reference integrates the commanded twist
   (v in {w}, w in {MRF} axes, as :class:`~app.controller.types.SlaveCommand` defines it) plus,
   with accommodation on, the NTRFC term ``K_acc * F_MRF`` (paper Sec 4.3): the robot moves to
   relieve the contact wrench, so in steady contact ``v_cmd + K_acc * F = 0``, i.e. the wrench is
   proportional to the operator's command. Pose mode (active): the reference is the command.
   Inactive: the reference holds. The rate reference may not lead the tool by more than the PD
   can push against (``force_limit / kp_lin``): a real controller limits its following error
   rather than winding up while the tool is blocked.
2. For each MuJoCo substep: contact wrench from :class:`~app.world.contact.ContactModel`, the PD
   wrench at {MRF} saturated at the robot's limits (direction kept), both applied to the body,
   made implicit in the contact's and the PD's stiffness and damping as far as the step's
   stability needs (:func:`~app.slave.tool_kernel.implicit_wrench`: a stiff surface, a light tool
   or the friction's viscous band would ring or diverge explicitly), then ``mj_step``. The
   contact wrench reported is the one the step applied.
3. The virtual F/T sensor at {S} reports what a real one would: the wrench on everything
   outboard of it, ``contact + payload weight - payload inertial load``, with the accelerations
   the integrator applied in the step.

Frames as in :mod:`app.world.scene`. The MuJoCo body frame {C} is the tool's centre of mass with
the axes of {T}, so the free joint's linear velocity is the centre-of-mass velocity. The
arithmetic between MuJoCo and FCL is compiled (:mod:`app.slave.tool_kernel`).

Non-finite input never reaches MuJoCo (which would reset its state and write ``MUJOCO_LOG.TXT``):
a reset to a non-finite pose is refused and leaves the slave faulted (tool held, readings
invalid) until a reset to a finite pose; a non-finite command or period gives an invalid reading
for that tick and leaves the state as it was.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from app.compiled import entry_point, is_f8
from app.controller.types import FTReading, SlaveCommand, SlaveModel
from app.errors import InputError
from app.mjcall import address, pointers, substeps_for
from app.slave.tool_kernel import (
    GRAVITY_W,
    HOLD,
    INERTIA_C,
    KEEP,
    MASS,
    N_PARAMS,
    N_READING,
    N_SCRATCH,
    N_WORK,
    POSE,
    R_ACC,
    R_OMEGA,
    R_ROT,
    R_WRENCH,
    RATE,
    mrf_state,
    own_arrays,
    pd_modes,
    rate_reference,
    sensor_reading,
    tool_substep,
)
from app.spatial import SHAPE_44, Array, finite, invert_pose, matrix_to_quat, pose_error
from app.world.contact import ContactResult
from app.world.dynamics import MovingWorld, world_contact
from app.world.scene import Scene

DEFAULT_PERIOD = 1e-3  # s, the servo period
# A read-only zero six-vector: the accelerations of a tool held at rest, no accommodation term.
_ZERO6 = np.zeros(6)
_ZERO6.flags.writeable = False
# A contact result's ``w`` with no wrench: no accommodation. Left writeable (the kernel only reads
# it) because numba compiles a separate kernel for read-only arrays.
_ZERO15 = np.zeros(15)
# The dynamic objects' poses of a scene with none (left writeable for the same reason).
_NO_OBJECTS = np.zeros((0, 7))
# No contact rows (a result without contacts shares a read-only empty array).
_NO_ROWS = np.zeros((0, 9))
SHAPE_6 = (6,)


def contact_rows(contact: ContactResult) -> Array:
    """The contact rows ``[p, n, depth, sphere, object]`` (k, 9) a compiled substep is handed:
    the result's own, or a writeable empty array (one kernel for both, module note above)."""
    rows: Array = contact.contacts
    return rows if rows.flags.writeable else _NO_ROWS


def _tool_xml(scene: Scene, timestep: float) -> str:
    tool = scene.tool
    g = " ".join(repr(float(v)) for v in scene.gravity_w)
    I = tool.inertia_T
    full = " ".join(repr(float(v)) for v in (I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]))
    return f"""<mujoco model="virtual_slave">
  <option timestep="{timestep!r}" gravity="{g}" integrator="Euler">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="tool">
      <freejoint/>
      <inertial pos="0 0 0" mass="{tool.mass!r}" fullinertia="{full}"/>
    </body>
  </worldbody>
</mujoco>"""


def command_error(command: SlaveCommand, dt: float) -> str | None:
    """Why ``command`` and ``dt`` cannot be applied this tick, or None (for every kind of slave)."""
    if not (math.isfinite(dt) and dt > 0.0):
        return f"non-finite or non-positive period {dt!r}"
    if not command.active:
        return None
    if command.mode == "rate":
        return None if finite(command.twist) else "non-finite twist command"
    if command.mode == "pose":
        return pose_error(command.T_w_MRF, "pose command")
    raise ValueError(f"unknown slave command mode {command.mode!r}")


def checked_command(command: SlaveCommand) -> tuple[Array, Array]:
    """The command's twist (6,) and pose (4, 4) as C-contiguous float64, or :class:`InputError`."""
    arrays = []
    for name, value, shape in (("twist", command.twist, SHAPE_6), ("T_w_MRF", command.T_w_MRF, SHAPE_44)):
        a = np.asarray(value)
        if a.dtype.kind not in "iuf" or a.shape != shape:
            raise InputError(f"SlaveCommand.{name}: expected real numbers of shape {shape}, got {a.dtype} {a.shape}")
        arrays.append(np.ascontiguousarray(a, dtype=np.float64))
    return arrays[0], arrays[1]


def invalid_contact(error: str) -> ContactResult:
    """A contact result that says the world could not produce a trustworthy reading, for ``error``."""
    return ContactResult(False, np.zeros(15), error=error)


class SlaveBase:
    """What every slave does the same way: the Cartesian reference (step 1 of the module
    docstring) and the tool's contact, F/T reading and model.

    Subclasses keep the {MRF} pose ``_T`` (4, 4) and twist ``_V`` (6,) of their state up to date,
    and set ``_contact`` (the tool's last :class:`ContactResult`) and ``_reading`` (the last
    :class:`FTReading`).

    Args:
        scene: The scene (tool, objects, slave gains).
        accommodation: NTRFC force accommodation on (True) or "blind" rate control (False).
    """

    _contact: ContactResult
    _reading: FTReading
    _moving: MovingWorld | None
    _fault: str | None
    # The servo period (s), its substeps and the physics step (s): set by _divide.
    _dt: float
    _substeps: int
    _h: float
    model: mujoco.MjModel
    data: mujoco.MjData

    def __init__(self, scene: Scene, accommodation: bool) -> None:
        self.scene = scene
        self.accommodation = accommodation
        self.gains = g = scene.spec.slave
        self._k_acc = np.array(g.accommodation)
        # Following-error limits (m, rad): never lead the tool by more than the PD can push against.
        self._max_lead_lin = g.force_limit / g.kp_lin
        self._max_lead_rot = g.torque_limit / g.kp_rot
        self._V_ref_w = np.zeros(6)
        self._T_ref = np.eye(4)
        self._T = np.eye(4)
        self._V = np.zeros(6)
        # The compiled kernels' scratch (:data:`~app.slave.tool_kernel.N_SCRATCH`; its first blocks for
        # the stages called alone): nothing is allocated per tick.
        self._scratch = np.zeros((N_SCRATCH, 3, 3))
        self._work = self._scratch[0:N_WORK]
        # Stiffness, damping and friction per contact object id (static objects, then dynamic),
        # for the implicit substep (:func:`~app.slave.tool_kernel.implicit_shares`).
        self._materials = np.array(
            [(o.stiffness, o.damping, o.friction) for o in (*scene.objects, *(b.object for b in scene.bodies))],
            dtype=float,
        ).reshape(-1, 3)

    def _divide(self, dt: float) -> float:
        """Set the substeps for a servo period ``dt`` (s); returns the physics step (s).

        The scene's ``substeps`` are per 1 ms period (:func:`~app.mjcall.substeps_for`).
        """
        self._substeps = substeps_for(dt, self.gains.substeps)
        self._dt = dt
        self._h = dt / self._substeps
        return self._h

    @property
    def fault(self) -> str | None:
        """Why every reading is invalid until a reset (an unreachable reset pose, an arm whose
        simulation went unstable), or None."""
        return self._fault

    def _update_reference(self, command: SlaveCommand, dt: float) -> None:
        """Step 1: the reference for this tick of ``dt`` (s) under ``command``."""
        if not command.active:
            self._V_ref_w.fill(0.0)
        elif command.mode == "pose":
            self._T_ref[:] = command.T_w_MRF
            self._V_ref_w.fill(0.0)
        else:
            F_acc = self._k_acc * self._contact.wrench_MRF if self.accommodation and self._contact.valid else _ZERO6
            rate_reference(
                command.twist,
                F_acc,
                self._T,
                dt,
                self._max_lead_lin,
                self._max_lead_rot,
                self._T_ref,
                self._V_ref_w,
                self._work,
            )

    @property
    def contact(self) -> ContactResult:
        """The last contact evaluation (points, normals, depths for display)."""
        return self._contact

    def geom_poses(self) -> tuple[Array, Array]:
        """Positions (ngeom, 3) and orientations (ngeom, 9, row-major) in {w} of :attr:`model`'s
        geoms (an arm's links; none for the ideal tool): MuJoCo's views, overwritten by the next step."""
        return self.data.geom_xpos, self.data.geom_xmat

    def object_poses(self) -> Array:
        """Poses of the scene's dynamic objects' frames {B} in {w} as rows ``[x, y, z, qw, qx, qy,
        qz]`` (m, unit quaternion), (n, 7) in ``scene.bodies`` order, (0, 7) when all are static:
        a view of MuJoCo's free-joint coordinates, overwritten by the next step."""
        if self._moving is None:
            return _NO_OBJECTS
        return self._moving.data.qpos.reshape(-1, 7)

    def grip(self, on: bool) -> int:
        """Close the tool's grip on the dynamic object it touches, or open it (``on`` False):
        :meth:`~app.world.dynamics.MovingWorld.grip`. Returns the index in ``scene.bodies`` of
        the object held, or -1 (opened, nothing touched, or no dynamic object in the scene)."""
        return -1 if self._moving is None else self._moving.grip(on)

    @property
    def wrench_MRF_contact(self) -> Array:
        """Contact wrench at the {MRF} origin in {MRF} (N, N m), (6,): for the work metric (Eq 13)."""
        return self._contact.wrench_MRF

    def reading(self) -> FTReading:
        """The F/T sensor's current reading, without stepping (new arrays).

        After :meth:`reset` the tool is held at rest: the payload weight in {S} plus any contact
        at that pose. After :meth:`step` it is the reading that step returned. Read it after a
        reset so the controller's first tick does not see a zero wrench (which its payload
        removal would turn into a false ``+m g``).
        """
        return self._reading.copy()

    def slave_model(self) -> SlaveModel:
        """What the controller may know about the tool (for payload weight/inertia removal)."""
        tool = self.scene.tool
        R_T_S = tool.T_T_S[0:3, 0:3]
        return SlaveModel(
            T_MRF_S=tool.T_MRF_S,
            payload_mass=tool.mass,
            payload_com_S=R_T_S.T @ (tool.com_T - tool.T_T_S[0:3, 3]),
            payload_inertia_S=R_T_S.T @ tool.inertia_T @ R_T_S,
            gravity_w=self.scene.gravity_w.copy(),
            T_w_MRF_home=tool.T_w_MRF_home.copy(),
        )


class VirtualSlave(SlaveBase):
    """A simulated slave robot tool with a virtual F/T sensor.

    Args:
        scene: The scene (tool, objects, slave gains).
        accommodation: NTRFC force accommodation on (True) or "blind" rate control (False).
        period: Servo period (s) the slave expects; ``step`` may be given another ``dt``.
    """

    def __init__(self, scene: Scene, accommodation: bool = True, period: float = DEFAULT_PERIOD) -> None:
        super().__init__(scene, accommodation)
        g = self.gains
        tool = scene.tool
        self.contact_model = world_contact(scene, self._divide(period))
        # The scene's dynamic objects, advanced with every substep (None: all static).
        self._moving = self.contact_model if isinstance(self.contact_model, MovingWorld) else None
        self.model = mujoco.MjModel.from_xml_string(_tool_xml(scene, self._h))
        self.data = mujoco.MjData(self.model)
        body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "tool")
        # Views into MjData (its buffers are never reallocated), fetched once: attribute access
        # on MjData costs about a microsecond.
        self._qpos = self.data.qpos
        self._qvel = self.data.qvel
        self._qacc = self.data.qacc
        self._xfrc = self.data.xfrc_applied[body]
        self._mj = np.array((address("mj_step"), *pointers(self.model, self.data)), dtype=np.int64)
        # Poses of {MRF} and {S} in the body frame {C} (centre of mass, {T} axes).
        T_C_T = np.eye(4)
        T_C_T[0:3, 3] = -tool.com_T
        self._frames = np.stack((T_C_T @ tool.T_T_MRF, T_C_T @ tool.T_T_S))
        self._T_C_MRF = self._frames[0]
        gravity_w = np.asarray(scene.gravity_w, dtype=float)
        inertia = np.asarray(tool.inertia_T, dtype=float)
        inertia_inv = np.linalg.inv(inertia)
        pd = np.array((g.kp_lin, g.kd_lin, g.kp_rot, g.kd_rot, g.force_limit, g.torque_limit))
        self._params = np.concatenate(
            (
                pd,
                self._k_acc,
                (self._max_lead_lin, self._max_lead_rot),
                tool.mass * gravity_w,
                gravity_w,
                (tool.mass,),
                inertia.ravel(),
                inertia_inv.ravel(),
                pd_modes(pd, self._T_C_MRF[0:3, 3].copy(), tool.mass, inertia, inertia_inv),
            )
        )
        assert len(self._params) == N_PARAMS
        # The F/T reading every step returns (one buffer, overwritten): no allocation per tick.
        self._ft_buffer = np.zeros(N_READING)
        b = self._ft_buffer
        self._reading = FTReading(
            b[R_WRENCH : R_WRENCH + 6], b[R_ROT : R_ROT + 9].reshape(3, 3), b[R_ACC : R_ACC + 6], b[R_OMEGA:]
        )
        # {MRF} pose and twist (in the base's buffers) of the current MuJoCo state, valid while ``_fresh``.
        self._fresh = False
        self._fault: str | None = None
        self.status = 0  # the ideal tool always follows (its limits are the PD's saturation)
        self.link_force = 0.0  # it has no links for the world to touch
        self.reset()
        # The substep's arguments that are the slave's own arrays, the same objects every call.
        own = (self._mj, self._params, self._frames, self._T, self._V, self._T_ref, self._V_ref_w, self._qpos)
        self._own = own_arrays(
            *own, self._qvel, self._qacc, self._xfrc, self._scratch, self._materials, self._ft_buffer
        )
        # ``step`` checks the command's arrays, so the compiled substep is called without numba's typing.
        example_command = (RATE, np.zeros(6), np.eye(4), _ZERO15, period)
        self._substep = entry_point(tool_substep, self._own, *example_command, self._contact.w, True, _NO_ROWS, self._h)

    # --- state -----------------------------------------------------------------------------
    def reset(self, T_w_MRF: Array | None = None) -> None:
        """Put the tool at rest at ``T_w_MRF`` (default: the scene's home), reference there too.

        A non-finite pose is refused without touching the simulation: the tool stays where it
        was, and :attr:`contact`, :meth:`reading` and every :meth:`step` report invalid until a
        reset to a finite pose.
        """
        T = self.scene.tool.T_w_MRF_home if T_w_MRF is None else np.asarray(T_w_MRF, dtype=float)
        if not finite(T):
            self._fault = "reset to a non-finite pose"
            self._contact = self._invalid(self._fault)
            return
        self._fault = None
        mujoco.mj_resetData(self.model, self.data)
        T_w_C = T @ invert_pose(self._T_C_MRF)
        self._qpos[0:3] = T_w_C[0:3, 3]
        self._qpos[3:7] = matrix_to_quat(T_w_C[0:3, 0:3])
        mujoco.mj_forward(self.model, self.data)
        self._fresh = False
        self._T_ref[:] = T  # in place: the compiled substep holds this array
        self._V_ref_w.fill(0.0)
        self.contact_model.reset()
        T_now, V_now = self._state()
        self._contact = self.contact_model.wrench(T_now, V_now)
        self._reading = self._sensor(self._contact, _ZERO6)

    def _state(self) -> tuple[Array, Array]:
        """{MRF} pose (4, 4) and twist (6,) of the current state: the internal buffers, not copies."""
        if not self._fresh:
            mrf_state(self._qpos, self._qvel, self._T_C_MRF, self._T, self._V, self._work)
            self._fresh = True
        return self._T, self._V

    @property
    def T_w_MRF(self) -> Array:
        """Current pose of {MRF} in {w}, (4, 4) (a new array)."""
        return self._state()[0].copy()

    def pose_view(self) -> Array:
        """Current pose of {MRF} in {w}, (4, 4): the slave's own buffer, overwritten by the next
        step (read it, do not modify it). For per-tick observers that must not allocate."""
        if not self._fresh:  # fresh after every step: read each tick, without _state's tuple
            self._state()
        return self._T

    @property
    def V_w_MRF(self) -> Array:
        """Current twist ``[v; w]`` of {MRF} (origin velocity, angular velocity) in {w}, (6,) (a new array)."""
        return self._state()[1].copy()

    # --- servo tick --------------------------------------------------------------------------
    def step(self, command: SlaveCommand, dt: float = DEFAULT_PERIOD) -> FTReading:
        """Advance one servo period ``dt`` (s) under ``command``; return the F/T sensor reading.

        The reading is the slave's own object, overwritten by the next step and reset (copy what
        you keep). A faulted slave (see :meth:`reset`), or a non-finite command or period,
        returns an invalid reading and leaves the state as it was.
        """
        error = self._fault or command_error(command, dt)
        if error is not None:
            self._invalid(error)
            return self._reading
        if dt != self._dt:
            self.model.opt.timestep = self._divide(dt)
        h = self._h
        T, V = self._state()
        reference = RATE if command.active and command.mode == "rate" else POSE if command.active else HOLD
        twist, T_cmd = command.twist, command.T_w_MRF
        if not (is_f8(twist, SHAPE_6) and is_f8(T_cmd, SHAPE_44)):
            twist, T_cmd = checked_command(command)
        prev = self._contact
        accommodate = prev.w if self.accommodation and prev.valid else _ZERO15
        for _ in range(self._substeps):
            contact = self.contact_model.wrench(T, V)
            # The reading is taken at the substep's start, where the forces were computed; semi-
            # implicit Euler then applied exactly qacc over the substep. The state moves on after.
            self._substep(
                self._own, reference, twist, T_cmd, accommodate, dt, contact.w, contact.valid, contact_rows(contact), h
            )
            if self._moving is not None:
                self._moving.step(h)
            reference = KEEP
        self._fresh = True
        self._contact = contact
        self._reading.valid = contact.valid
        return self._reading

    def _invalid(self, error: str) -> ContactResult:
        """Make the current reading invalid (zero wrench, the held state's orientation) for ``error``."""
        contact = invalid_contact(error)
        self._state()
        self._reading = self._sensor(contact, _ZERO6)
        return contact

    def _sensor(self, contact: ContactResult, qacc: Array) -> FTReading:
        """F/T reading at {S} for the pose and twist in the buffers, accelerations ``qacc`` (6,)."""
        p = self._params
        sensor_reading(
            self._T,
            self._V,
            qacc,
            self._frames[0],
            self._frames[1],
            p[INERTIA_C : INERTIA_C + 9].reshape(3, 3),
            p[MASS],
            p[GRAVITY_W : GRAVITY_W + 3],
            contact.wrench_S,
            contact.valid,
            self._ft_buffer,
            self._work,
        )
        self._reading.valid = contact.valid
        return self._reading
