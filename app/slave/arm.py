"""A slave robot arm (``slaves/<name>/arm.xml``) behind the same interface as the ideal tool.

The paper's point (Sec 1, 5) is that master and slave need not be kinematically alike: the
controller's Cartesian command (rate or pose, :class:`~app.controller.types.SlaveCommand`) is all
the slave sees. :class:`ArmSlave` carries the scene's tool on the wrist flange of a MuJoCo arm and
follows that command as a real robot controller would:

1. The Cartesian reference is updated as for the ideal tool
   (:func:`app.slave.tool_kernel.rate_reference`, with NTRFC accommodation, or the pose command),
   but its following-error limit is the arm's own: while the tool touches the world the
   reference may lead the tool only as far as the joint servos' stiffness at {MRF},
   ``(J K_q^-1 J^T)^-1``, turns into the scene's force and torque limits
   (:func:`app.slave.arm_kernel.bound_lead`): a blocked tool is pushed with at most 40 N, as the
   ideal tool's saturated PD pushes, not with the servos' 10^5 N/m times the ideal tool's lead.
2. Differential IK (:mod:`app.slave.arm_ik`) moves a joint set-point toward that reference
   under joint, velocity and singularity limits; the redundant arm spends its null space on
   joint-limit avoidance. The pose error of the set-point is ``e(q) - J (q_c - q)``, linearised
   about the measured state (the set-point is within a servo lag of it), which saves a second
   forward-kinematics pass per tick.
3. Joint servos (PD plus MuJoCo's gravity and Coriolis feedforward, saturated at each motor's
   torque limit) track the set-point; joint ranges are also hard stops in MuJoCo.
4. Contact: the tool's wrench from :class:`~app.world.contact.ContactModel` is applied to the
   tool body (outboard of the sensor); each arm link has its own sphere set (chains covering its
   capsules) and :class:`ContactModel` over the same scene, evaluated only when the link's bounding
   sphere reaches the objects' bounding box, its wrench applied to that link, so it loads the arm
   and not the F/T sensor, as on a real robot. MuJoCo's own collision stays off: the world's
   meshes and contact law are FCL's, and one contact law for tool and links keeps them alike.
5. The F/T reading is MuJoCo's force and torque sensors at {S} (contact + payload weight -
   payload inertial load, computed by MuJoCo's recursive Newton-Euler), plus the *limit wrench*.

When the arm cannot follow (joint limit, singularity, velocity limit, workspace edge) the
command is limited smoothly by the IK, the condition is set in :attr:`ArmSlave.status`
(:class:`ArmStatus`, logged per tick as ``slave_status``), and the operator feels it: the part of
the reference the set-point cannot reach beyond a small dead band is reflected as a spring wrench
at {MRF} (:func:`app.slave.arm_ik.limit_wrench`, the scene's ``kp_lin``/``kp_rot``, saturated
at its force and torque limits), added to the sensor reading, so the controller renders a wall
at the limit without changing.

Frames as in :mod:`app.world.scene`, plus the arm's base (upright, placed so that the home
keyframe of the arm file reaches the scene's home pose) and the flange (z out of the wrist). The
tool's {T} is mounted with its -z along the flange's z: every scene's tool points down -z.

The arithmetic of a tick is compiled (:mod:`app.slave.arm_kernel`, three calls per substep on
one record of the arm's state); building the arm is :mod:`app.slave.arm_model`.
"""

from __future__ import annotations

from enum import IntFlag

import mujoco
import numpy as np

from app.compiled import entry_point
from app.controller.types import FTReading, SlaveCommand
from app.errors import ConfigError
from app.mjcall import address, pointers
from app.slave import arm_ik
from app.slave import arm_kernel as ak
from app.slave.arm_model import ArmGeom, ArmParams, arm_model, arm_record, link_contact_models, place_base
from app.slave.tool import DEFAULT_PERIOD, SlaveBase, command_error, contact_rows, invalid_contact
from app.spatial import Array, finite
from app.world.contact import ContactResult
from app.world.contact.layout import MAX_PER_PAIR
from app.world.contact.model import failed
from app.world.dynamics import MovingWorld, world_contact
from app.world.scene import Scene


class ArmStatus(IntFlag):
    """Why the arm did not follow the command exactly this tick (combinable)."""

    NONE = 0
    SINGULAR = arm_ik.SINGULAR  # near a singularity: damped least squares active
    JOINT_LIMIT = arm_ik.JOINT_LIMIT  # a joint's rate was clamped near its limit
    # The commanded motion was scaled down to the joint velocity limits, or a joint servo's speed
    # demand was clamped to its limit (the joint lags its set-point).
    VELOCITY = arm_ik.VELOCITY
    TRACKING = arm_ik.TRACKING  # the reference is out of reach (beyond the dead band): the limit wrench acts
    TORQUE = arm_ik.TORQUE  # a motor saturated (e.g. the arm is blocked)
    # The world touches a link (not the tool): the force loads the arm, never the F/T sensor, so
    # the operator cannot feel it; this bit (and :attr:`ArmSlave.link_force`) is how it shows.
    LINK_CONTACT = 2 * arm_ik.TORQUE


# Every combination, built once: making an IntFlag from an int costs about a microsecond a tick.
_STATUS = tuple(ArmStatus(bits) for bits in range(2 * max(ArmStatus)))


class ArmSlave(SlaveBase):
    """A simulated slave arm carrying the scene's tool and F/T sensor (module docstring).

    Args:
        scene: The scene; ``scene.spec.slave.kind`` names the arm (``slaves/<kind>/arm.xml``).
        accommodation: NTRFC force accommodation on (True) or "blind" rate control (False).
        period: Servo period (s) the slave expects; ``step`` may be given another ``dt``.
        params: IK and servo tuning (default :class:`ArmParams`).

    Attributes:
        q_home: Joint angles (rad) the reset's inverse kinematics starts from (the arm file's
            home keyframe); a redundant arm's reset picks the solution nearest it.
        T_w_base: Pose of the arm's base in {w} (4, 4).
        status: :class:`ArmStatus` of the last step.
        link_contacts: The last contact results of the links near the world (empty when none is):
            they load the arm, not the sensor; :attr:`contact` is the tool's.

    Raises:
        ConfigError: The arm file is malformed (:mod:`app.slave.arm_model`), or the arm cannot
            reach the scene's tool home (field ``tool.home``).
    """

    def __init__(
        self, scene: Scene, accommodation: bool = True, period: float = DEFAULT_PERIOD, params: ArmParams | None = None
    ) -> None:
        super().__init__(scene, accommodation)
        self.params = params = params or ArmParams()
        g = self.gains
        self.name = g.kind
        self.model = m = arm_model(scene, g.kind, self._divide(period))
        self.data = d = mujoco.MjData(m)
        self.n = m.nu
        self.contact_model = world_contact(scene, self._h)
        # The scene's dynamic objects, advanced with every substep (None: all static). The
        # links touch only the static objects.
        self._moving = self.contact_model if isinstance(self.contact_model, MovingWorld) else None
        self.q_home, self.T_w_base = place_base(m, d, scene)
        tool = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")
        self._links, self._link_models, spheres = link_contact_models(m, tool, scene)
        self._rec = arm_record(m, d, scene, params, self._links, spheres)
        # The near links' contact results, written by the compiled substep end
        # (:func:`~app.slave.arm_kernel.links_end`): each link's ``w`` and contact count (or error
        # code), and their rows, link after link (as many as every link sphere can make).
        self._link_arrays = tuple(model.arrays for model in self._link_models)
        self._link_w = np.zeros((len(self._links), 15))
        self._link_count = np.full(len(self._links), -1, dtype=np.int64)
        self._link_rows = np.zeros((MAX_PER_PAIR * len(spheres[2]) * len(scene.objects) + 1, 9))
        self._links_were_near = False
        r = self._rec[0]
        # The base's buffers become views of the record, which the compiled tick writes.
        self._T, self._V, self._T_ref, self._V_ref_w = r["T"], r["V"], r["T_ref"], r["V_ref"]
        self._jac, self._q_c, self._qd_c, self._sv, self._W_limit = r["jac"], r["q_c"], r["qd_c"], r["sv"], r["W_limit"]
        self._lo, self._hi, self._near = r["lo"], r["hi"], r["near"]
        self._gravity_w = scene.gravity_w
        # Views into MjData (never reallocated), fetched once: attribute access costs ~1 us.
        self._qpos, self._qvel, self._ctrl, self._bias = d.qpos, d.qvel, d.ctrl, d.qfrc_bias
        self._xfrc, self._sdata, self._xanchor, self._xaxis = d.xfrc_applied, d.sensordata, d.xanchor, d.xaxis
        self._site_xpos, self._site_xmat, self._xpos, self._xmat, self._xipos = (
            d.site_xpos,
            d.site_xmat,
            d.xpos,
            d.xmat,
            d.xipos,
        )
        self._cvel, self._cacc, self._subtree_com = d.cvel, d.cacc, d.subtree_com
        # MuJoCo's counts of bad joint positions, velocities and accelerations: on one it resets
        # the arm to the model's zero angles and steps on, silently to its caller.
        w = mujoco.mjtWarning
        self._unstable = d.warning.number[w.mjWARN_BADQPOS : w.mjWARN_BADQACC + 1]
        self._qacc, self._M = d.qacc, d.M
        # The F/T reading every step returns (one buffer, overwritten): no allocation per tick.
        b = self._ft_buffer = np.zeros(24)
        self._ft = FTReading(b[0:6], b[6:15].reshape(3, 3), b[15:21], b[21:24])
        # The compiled substep's calls skip numba's typing: apart from the contact result's
        # arrays (C-contiguous float64 views of its ``w``), everything passed is the arm's own.
        contact_w = np.zeros(15)
        stages = ("mj_fwdActuation", "mj_fwdAcceleration", "mj_fwdConstraint")
        self._mj = np.array((address("mj_step1"), address("mj_step2"), *pointers(m, d), *map(address, stages)))
        self._begin = entry_point(
            ak.begin_substep,
            self._mj,
            self._rec,
            self._xanchor,
            self._xaxis,
            self._site_xpos,
            self._site_xmat,
            self._qvel,
        )
        self._mj_views = (
            self._qpos,
            self._qvel,
            self._bias,
            self._ctrl,
            self._xfrc,
            self._xpos,
            self._xmat,
            self._xipos,
        )
        # What the substep's end needs besides the record (:func:`~app.slave.arm_kernel.implicit_contacts`).
        self._end_views = (self._qacc, self._M, self._xanchor, self._xaxis, self._site_xpos, self._site_xmat)
        self._control = entry_point(
            ak.control,
            self._rec,
            True,
            period,
            self._h,
            *self._mj_views,
            *self._end_views,
            contact_w,
            contact_rows(invalid_contact("")),
            self._materials,
            True,
            self._mj,
        )
        # MuJoCo's arrays and the outputs of the substep's end with links near, after ``h`` and
        # before the tool's contact (:func:`~app.slave.arm_kernel.links_end`).
        self._links_views = (
            self._qvel,
            self._qacc,
            self._M,
            self._xfrc,
            self._xanchor,
            self._xaxis,
            self._xipos,
            self._xpos,
            self._xmat,
            self._cvel,
            self._subtree_com,
            self._site_xpos,
            self._site_xmat,
        )
        self._links_out = (self._materials, self._link_arrays, self._link_w, self._link_rows, self._link_count)
        self._links_end = (
            entry_point(
                ak.links_end,
                self._mj,
                self._rec,
                self._h,
                *self._links_views,
                contact_w,
                contact_rows(invalid_contact("")),
                *self._links_out,
            )
            if self._links
            else None
        )
        ft = self._ft
        motion = (self._sdata, self._site_xpos, self._site_xmat, self._cvel, self._cacc, self._subtree_com)
        self._ft_args = (*motion, self._gravity_w, ft.wrench_S, ft.R_w_S, ft.acc_w, ft.omega_w)
        self._ft_reading = entry_point(ak.ft_reading, self._rec, True, *self._ft_args)
        # In contact the lead is bounded further, by the arm's own stiffness
        # (:func:`~app.slave.arm_kernel.bound_lead`): the ideal tool's PD is about 30 times softer.
        # Out of contact the ideal tool's bound stays: unbounded, a reference pushed past the edge
        # of reach wound up (1.49 m after 6 s at 0.3 m/s on the PUMA) and the operator, reversing,
        # felt the 40 N limit wrench for the ~30 s it took to unwind (measured).
        self._bound_lead = entry_point(ak.bound_lead, self._rec)
        self.status = ArmStatus.NONE
        self._fault: str | None = None
        self.reset()
        if self._fault is not None:
            # Every tick of a run would be FT_INVALID, and nothing would say why (measured: the
            # probe scene with its home turned 90 deg about y ran 500 such ticks and exited 0).
            raise ConfigError(
                scene.path or f"<scene {scene.name}>",
                "tool.home",
                f"the {g.kind} arm cannot reach this pose: its inverse kinematics from the home keyframe "
                f"of slaves/{g.kind}/arm.xml (where the tool points down -z) does not converge",
            )

    # --- state ---------------------------------------------------------------------------------
    def reset(self, T_w_MRF: Array | None = None) -> None:
        """Put the arm at rest with {MRF} at ``T_w_MRF`` (default: the scene's home), reference there.

        The joint angles come from damped least squares started at the home keyframe. A
        non-finite or unreachable pose is refused: the arm stays where it was and every reading
        is invalid until a reset to a reachable pose.
        """
        T = self.scene.tool.T_w_MRF_home if T_w_MRF is None else np.asarray(T_w_MRF, dtype=float)
        q = self._solve_ik(T) if finite(T) else None
        if q is None:
            self._fault = "reset to a non-finite or unreachable pose"
            self._link_force = 0.0  # read by every tick's record, which this reset may precede
            self._contact = invalid_contact(self._fault)
            self._reading = self._make_reading(self._contact)
            return
        self._fault = None
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        self._q_c[:] = q
        self._qd_c.fill(0.0)
        self._read_mrf()
        self._T_ref[:] = self._T
        self._V_ref_w.fill(0.0)
        self._W_limit.fill(0.0)
        self.status = ArmStatus.NONE
        self.contact_model.reset()
        for model in self._link_models:
            model.reset()
        self._contact = self.contact_model.wrench(self._T, self._V)
        self._links_were_near = False
        self._link_force = 0.0
        # At rest the sensor reads the payload weight; MuJoCo's sensor needs accelerations, which
        # a held arm does not have, so build that reading from the model directly.
        self._reading = self._make_reading(self._contact, at_rest=True)

    def _solve_ik(self, T: Array, iterations: int = 300) -> Array | None:
        """Joint angles (n,) putting {MRF} at ``T`` from the home keyframe, or None if out of reach.

        Uses MuJoCo's kinematics; the arm's state (and the {MRF} buffers) are put back afterwards.
        """
        m, d = self.model, self.data
        q_was = self._qpos.copy()
        q = self.q_home.copy()
        e = np.zeros(6)
        J, T_now = self._jac, self._T
        found = None
        for _ in range(iterations):
            self._qpos[:] = q
            mujoco.mj_kinematics(m, d)
            self._read_mrf()
            arm_ik.pose_error(T, T_now[0:3, 3], T_now[0:3, 0:3], e)
            if np.linalg.norm(e[0:3]) < 1e-9 and np.linalg.norm(e[3:6]) < 1e-8:
                found = q
                break
            q = np.clip(q + J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), e), self._lo, self._hi)
        self._qpos[:] = q_was
        mujoco.mj_kinematics(m, d)
        self._read_mrf()
        return found

    def _read_mrf(self) -> None:
        """Jacobian of {MRF}, its pose and twist for the current kinematics, into the record."""
        ak.mrf_state(self._rec, self._xanchor, self._xaxis, self._site_xpos, self._site_xmat, self._qvel)

    @property
    def sigma_min(self) -> float:
        """Smallest singular value of the {MRF} Jacobian at the last step (m or rad per rad)."""
        return float(self._sv[0])

    @property
    def q(self) -> Array:
        """Joint angles (rad), (n,) (a new array)."""
        return self._qpos[: self.n].copy()

    @property
    def joint_limits(self) -> Array:
        """Hard joint limits (rad), (n, 2)."""
        return self.model.jnt_range[: self.n].copy()

    @property
    def T_w_MRF(self) -> Array:
        """Current pose of {MRF} in {w}, (4, 4) (a new array)."""
        return self._T.copy()

    def pose_view(self) -> Array:
        """Current pose of {MRF} in {w}, (4, 4): the slave's own buffer (read it, do not modify it)."""
        return self._T

    @property
    def V_w_MRF(self) -> Array:
        """Current twist ``[v; w]`` of {MRF} in {w}, (6,) (a new array)."""
        return self._V.copy()

    def geoms(self) -> list[ArmGeom]:
        """Every arm geom (links and base) with its current pose in {w}, for display."""
        m, d = self.model, self.data
        out = []
        for gid in range(m.ngeom):
            T = np.eye(4)
            T[0:3, 0:3] = d.geom_xmat[gid].reshape(3, 3)
            T[0:3, 3] = d.geom_xpos[gid]
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, gid) or f"geom{gid}"
            kind = mujoco.mjtGeom(m.geom_type[gid]).name.removeprefix("mjGEOM_").lower()
            out.append(ArmGeom(name, kind, m.geom_size[gid].copy(), T))
        return out

    # --- servo tick ------------------------------------------------------------------------------
    def step(self, command: SlaveCommand, dt: float = DEFAULT_PERIOD) -> FTReading:
        """Advance one servo period ``dt`` (s) under ``command``; return the F/T sensor reading.

        A faulted slave (see :meth:`reset`), or a non-finite command or period, returns an
        invalid reading and leaves the state as it was. A step in which MuJoCo finds a non-finite
        or huge joint position, velocity or acceleration (and resets the arm) faults the slave:
        every reading is invalid until :meth:`reset`.
        """
        error = self._fault or command_error(command, dt)
        if error is not None:
            self._reading = self._make_reading(invalid_contact(error))
            return self._reading
        if dt != self._dt:
            self.model.opt.timestep = self._divide(dt)
        h = self._h
        rec, T, V = self._rec, self._T, self._V
        status = 0
        contact = self._contact
        for sub in range(self._substeps):
            self._begin(self._mj, rec, self._xanchor, self._xaxis, self._site_xpos, self._site_xmat, self._qvel)
            if sub == 0:
                # Accommodation reads the previous tick's contact, as the ideal tool's does.
                self._update_reference(command, dt)
            contact = self.contact_model.wrench(T, V)
            rows = contact_rows(contact)
            w = contact.w
            bits, near = self._control(
                rec,
                sub == 0,
                dt,
                h,
                *self._mj_views,
                *self._end_views,
                w,
                rows,
                self._materials,
                contact.valid,
                self._mj,
            )
            status |= bits
            self._links_were_near = near
            if near:  # the kernel stopped before its end: the links' wrenches go in first
                assert self._links_end is not None
                touching, failed = self._links_end(self._mj, rec, h, *self._links_views, w, rows, *self._links_out)
                if touching:
                    status |= ArmStatus.LINK_CONTACT
                if failed:  # as a contact model does when its own step fails
                    for i in np.flatnonzero(self._near * (self._link_count < 0)):
                        self._link_models[i].reset()
            if self._moving is not None:
                self._moving.step(h)
        if self._unstable.any():
            # Before harden11 the arm went on from its zero angles, tool elsewhere, readings valid.
            self._fault = "the arm's simulation went unstable (MuJoCo reset it); reset the slave"
            self._link_force = 0.0
            self._reading = self._make_reading(invalid_contact(self._fault))
            return self._reading
        self._contact = contact
        self.status = _STATUS[status]
        self._link_force = 0.0
        if self._links_were_near:
            for i in np.flatnonzero(self._near * (self._link_count >= 0)):
                self._link_force += float(np.linalg.norm(self._link_w[i, 12:15]))
        self._reading = self._make_reading(contact)
        return self._reading

    def _update_reference(self, command: SlaveCommand, dt: float) -> None:
        """The reference for this tick of ``dt`` (s), as the ideal tool's (its lead within the
        tool's ``force_limit / kp_lin``, ``torque_limit / kp_rot``); while the tool touches the
        world (last tick), its lead bounded further by the arm's stiffness
        (:func:`~app.slave.arm_kernel.bound_lead`). Not in free space: there the lead is the
        servos' lag, which accelerates the arm, and at the edge of what the arm can reach it is
        what the operator feels (the limit wrench): bounded there by the arm's stiffness, which
        grows without bound toward a singularity, the reference could not pass the edge. A link's
        contact does not bound it: the limits are the tool's, and held to them the arm yields to
        a push on a link (a slab pressing the PUMA's upper arm with 6 N drove it off, measured)."""
        super()._update_reference(command, dt)
        if self._contact.count > 0:
            self._bound_lead(self._rec)

    @property
    def link_contacts(self) -> list[ContactResult]:
        """The contact results of the links near the world at the last substep (empty when none
        is), in the order of their bodies; the wrench each reads is the one the step applied.
        (New lists each call; their ``queries`` and ``gathers`` counts are not kept.)"""
        if not self._links_were_near:
            return []
        out: list[ContactResult] = []
        at = 0
        for i in np.flatnonzero(self._near):
            code = int(self._link_count[i])
            if code < 0:
                out.append(failed(code))
                continue
            out.append(ContactResult(True, self._link_w[i].copy(), self._link_rows[at : at + code].copy(), 0, 0, None))
            at += code
        return out

    @property
    def link_force(self) -> float:
        """Magnitude of the world's force on the links at the last substep (N), summed over links."""
        return self._link_force

    def _make_reading(self, contact: ContactResult, at_rest: bool = False) -> FTReading:
        """The F/T reading at {S} for the state the last step's forces were computed at
        (:func:`~app.slave.arm_kernel.ft_reading`). ``at_rest`` evaluates MuJoCo's sensors with
        zero accelerations (a held arm) and adds the contact at that pose."""
        held = at_rest or not contact.valid
        if held:
            m, d = self.model, self.data
            d.qacc[:] = 0.0
            mujoco.mj_rnePostConstraint(m, d)
            mujoco.mj_sensorAcc(m, d)
            self._W_limit.fill(0.0)
        ft = self._ft
        self._ft_reading(self._rec, held, *self._ft_args)
        ft.valid = contact.valid
        ft.slave_status = int(self.status)
        if not contact.valid:
            ft.wrench_S.fill(0.0)
        elif at_rest:
            ft.wrench_S += contact.wrench_S
        return ft
