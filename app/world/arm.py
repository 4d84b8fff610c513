"""A slave robot arm (``slaves/<name>/arm.xml``) behind the same interface as the ideal tool.

The paper's point (Sec 1, 5) is that master and slave need not be kinematically alike: the
controller's Cartesian command (rate or pose, :class:`~app.controller.types.SlaveCommand`) is all
the slave sees. :class:`ArmSlave` carries the scene's tool on the wrist flange of a MuJoCo arm and
follows that command as a real robot controller would:

1. The Cartesian reference is updated exactly as for the ideal tool
   (:func:`app.world.kernel.rate_reference`, with NTRFC accommodation and the following-error
   limit, or the pose command).
2. Differential IK (:mod:`app.world.arm_kernel`) moves a joint set-point toward that reference
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
at {MRF} (:func:`app.world.arm_kernel.limit_wrench`, the scene's ``kp_lin``/``kp_rot``, saturated
at its force and torque limits), added to the sensor reading, so the controller renders a wall
at the limit without changing.

Frames as in :mod:`app.world.scene`, plus the arm's base (upright, placed so that the home
keyframe of the arm file reaches the scene's home pose) and the flange (z out of the wrist). The
tool's {T} is mounted with its -z along the flange's z: every scene's tool points down -z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntFlag

import mujoco
import numpy as np

from app.controller.types import FTReading, SlaveCommand
from app.spatial import Array
from app.world import arm_kernel as ak
from app.world.arm_model import ArmGeom, arm_spec, link_contact_models, scene_box
from app.world.contact import ContactModel, ContactResult
from app.world.scene import Scene
from app.world.slave import DEFAULT_PERIOD, SlaveBase, command_error, finite, invalid_contact

_ZERO6 = np.zeros(6)
_ZERO6.flags.writeable = False


class ArmStatus(IntFlag):
    """Why the arm did not follow the command exactly this tick (combinable)."""

    NONE = 0
    SINGULAR = ak.SINGULAR  # near a singularity: damped least squares active
    JOINT_LIMIT = ak.JOINT_LIMIT  # a joint's rate was clamped near its limit
    VELOCITY = ak.VELOCITY  # the commanded motion was scaled down to the joint velocity limits
    TRACKING = ak.TRACKING  # the reference is out of reach (beyond the dead band): the limit wrench acts
    TORQUE = ak.TORQUE  # a motor saturated (e.g. the arm is blocked)


@dataclass(frozen=True)
class ArmParams:
    """Tuning of the arm's IK and joint servos (the same for every arm; rates per second).

    Attributes:
        servo_bandwidth: Joint servo natural frequency (Hz); ``kp = M_ii w^2`` with ``M_ii`` the
            joint's inertia (armature included) at the home configuration.
        servo_damping: Joint servo damping ratio (-): ``kd = 2 zeta M_ii w``.
        k_ik: Gain (1/s) on the set-point's pose error (half of it corrected per 1 ms tick).
        lambda_max: Largest damping (-) of the least squares, reached at a singularity.
        eps_singular: Smallest singular value of J (m or rad per rad) below which damping starts.
        k_limit: Rate (1/s) at which a joint may approach its soft limit.
        k_null: Null-space pull (1/s) toward the middle of the joint ranges (redundant arms only).
        limit_margin: Soft joint limits inside the hard stops (rad).
        dead_lin, dead_rot: Dead band (m, rad) of the limit wrench.
    """

    servo_bandwidth: float = 12.0
    servo_damping: float = 1.0
    k_ik: float = 500.0
    lambda_max: float = 0.08
    eps_singular: float = 0.06
    k_limit: float = 20.0
    k_null: float = 1.0
    limit_margin: float = 0.05
    dead_lin: float = 0.001
    dead_rot: float = 0.01


class ArmSlave(SlaveBase):
    """A simulated slave arm carrying the scene's tool and F/T sensor (module docstring).

    Args:
        scene: The scene; ``scene.spec.slave.kind`` names the arm (``slaves/<kind>/arm.xml``).
        accommodation: NTRFC force accommodation on (True) or "blind" rate control (False).
        period: Servo period (s) the slave expects; ``step`` may be given another ``dt``.
        params: IK and servo tuning.

    Attributes:
        q_home: Joint angles (rad) the reset's inverse kinematics starts from (the arm file's
            home keyframe); a redundant arm's reset picks the solution nearest it.
        status: :class:`ArmStatus` of the last step.
        link_contacts: The last contact results of the links near the world (empty when none is):
            they load the arm, not the sensor; :attr:`contact` is the tool's.
    """

    def __init__(
        self, scene: Scene, accommodation: bool = True, period: float = DEFAULT_PERIOD, params: ArmParams = ArmParams()
    ) -> None:
        super().__init__(scene, accommodation)
        self.params = params
        g = self.gains
        self.name = g.kind
        self._substeps = g.substeps
        self._h = period / g.substeps
        self.model = m = arm_spec(scene, g.kind, self._h).compile()
        self.data = d = mujoco.MjData(m)
        self.n = n = m.nu
        self.contact_model = ContactModel(scene)
        obj = mujoco.mjtObj
        self._tool = mujoco.mj_name2id(m, obj.mjOBJ_BODY, "tool")
        self._site_mrf = mujoco.mj_name2id(m, obj.mjOBJ_SITE, "mrf")
        self._site_ft = mujoco.mj_name2id(m, obj.mjOBJ_SITE, "ft")
        self._sens = int(m.sensor_adr[0])
        base = mujoco.mj_name2id(m, obj.mjOBJ_BODY, "base")
        # Place the upright base so that the home keyframe puts {MRF} at the scene's home position.
        self.q_home = m.key_qpos[0].copy()
        d.qpos[:] = self.q_home
        mujoco.mj_kinematics(m, d)
        m.body_pos[base] = tool_home = scene.tool.T_w_MRF_home[0:3, 3] - d.site_xpos[self._site_mrf]
        self.T_w_base = np.eye(4)
        self.T_w_base[0:3, 3] = tool_home
        rng = m.jnt_range[:n]
        self._lo = rng[:, 0] + params.limit_margin
        self._hi = rng[:, 1] - params.limit_margin
        self._mid = 0.5 * (rng[:, 0] + rng[:, 1])
        self._qd_max = m.numeric("velocity_limit").data.copy()
        self._tau_max = m.actuator_ctrlrange[:, 1].copy()
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        w = 2.0 * math.pi * params.servo_bandwidth
        self._kp = np.diag(M) * w * w
        self._kd = np.diag(M) * 2.0 * params.servo_damping * w
        self._ik = np.array(
            (params.k_ik, params.lambda_max, params.eps_singular, params.k_limit, params.k_null if n > 6 else 0.0)
        )
        self._links, self._link_models, self._link_spheres = link_contact_models(m, self._tool, scene)
        self._scene_lo, self._scene_hi = scene_box(scene)
        # Views into MjData (never reallocated), fetched once: attribute access costs ~1 us.
        self._qpos, self._qvel, self._ctrl = d.qpos, d.qvel, d.ctrl
        self._bias, self._xfrc, self._sdata = d.qfrc_bias, d.xfrc_applied, d.sensordata
        self._site_xpos, self._site_xmat, self._xpos, self._xipos = d.site_xpos, d.site_xmat, d.xpos, d.xipos
        self._xmat = d.xmat
        self._link_ids = np.array(self._links, dtype=np.int64)
        self._jac = np.zeros((6, m.nv))
        self._res = np.zeros(6)
        self._q_c = np.zeros(n)
        self._qd_c = np.zeros(n)
        self._e = np.zeros(6)
        self._sv = np.full(7, 1.0)  # [sigma_min, warm start of its singular vector]
        self._W_limit = np.zeros(6)
        self._feel = np.array((params.dead_lin, params.dead_rot, g.kp_lin, g.kp_rot, g.force_limit, g.torque_limit))
        self.status = ArmStatus.NONE
        self._fault: str | None = None
        self.link_contacts: list[ContactResult] = []
        self.reset()

    # --- construction helpers ------------------------------------------------------------------
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
        self.link_contacts = []
        # At rest the sensor reads the payload weight; MuJoCo's sensor needs accelerations, which
        # a held arm does not have, so build that reading from the model directly.
        self._reading = self._make_reading(self._contact, at_rest=True)

    def _solve_ik(self, T: Array, iterations: int = 300) -> Array | None:
        """Joint angles (n,) putting {MRF} at ``T`` from the home keyframe, or None if out of reach."""
        m, d = self.model, self.data
        q = self.q_home.copy()
        e = np.zeros(6)
        for _ in range(iterations):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, self._jac[0:3], self._jac[3:6], self._site_mrf)
            ak.pose_error(T, d.site_xpos[self._site_mrf], d.site_xmat[self._site_mrf].reshape(3, 3), e)
            if np.linalg.norm(e[0:3]) < 1e-9 and np.linalg.norm(e[3:6]) < 1e-8:
                return q
            J = self._jac
            q = np.clip(q + J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), e), self._lo, self._hi)
        return None

    def _read_mrf(self) -> None:
        """Jacobian of {MRF}, its pose and twist for the current kinematics, into the buffers."""
        s, J = self._site_mrf, self._jac
        mujoco.mj_jacSite(self.model, self.data, J[0:3], J[3:6], s)
        ak.mrf_from_site(self._site_xpos[s], self._site_xmat[s], J, self._qvel, self._T, self._V)

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
    def _apply_contacts(self) -> ContactResult:
        """Tool and link contact wrenches into ``xfrc_applied`` for the current state."""
        xfrc = self._xfrc
        xfrc.fill(0.0)
        contact = self.contact_model.wrench(self._T, self._V)
        if contact.valid:
            T = self._T
            ak.body_wrench(
                contact.force_w,
                contact.wrench_MRF[3:6],
                T[0:3, 0:3],
                T[0:3, 3],
                self._xipos[self._tool],
                xfrc[self._tool],
            )
        near = ak.links_near(
            self._xpos, self._xmat, self._link_ids, *self._link_spheres, self._scene_lo, self._scene_hi
        )
        if not near.any():
            if self.link_contacts:
                self.link_contacts = []
            return contact
        self.link_contacts = []
        for i in np.flatnonzero(near):
            b = self._links[i]
            T = np.eye(4)
            T[0:3, 0:3] = self._xmat[b].reshape(3, 3)
            T[0:3, 3] = self._xpos[b]
            mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_BODY, b, self._res, 0)
            V = np.concatenate((self._res[3:6], self._res[0:3]))
            r = self._link_models[i].wrench(T, V)
            self.link_contacts.append(r)
            if r.valid:
                ak.body_wrench(r.force_w, r.wrench_MRF[3:6], T[0:3, 0:3], T[0:3, 3], self._xipos[b], xfrc[b])
        return contact

    def step(self, command: SlaveCommand, dt: float = DEFAULT_PERIOD) -> FTReading:
        """Advance one servo period ``dt`` (s) under ``command``; return the F/T sensor reading.

        A faulted slave (see :meth:`reset`), or a non-finite command or period, returns an
        invalid reading and leaves the state as it was.
        """
        error = self._fault or command_error(command, dt)
        if error is not None:
            self._reading = self._make_reading(invalid_contact(error))
            return self._reading
        h = dt / self._substeps
        if h != self._h:
            self.model.opt.timestep = self._h = h
        m, d, n = self.model, self.data, self.n
        status = 0
        contact = self._contact
        for sub in range(self._substeps):
            mujoco.mj_step1(m, d)
            self._read_mrf()
            if sub == 0:
                self._update_reference(command, dt)
                status = ak.ik_step(
                    self._jac[:, :n],
                    self._T_ref,
                    self._V_ref_w,
                    self._T,
                    self._qpos[:n],
                    self._q_c,
                    self._qd_c,
                    self._lo,
                    self._hi,
                    self._qd_max,
                    self._mid,
                    self._ik,
                    self._sv,
                    self._feel,
                    dt,
                    self._e,
                    self._W_limit,
                )
            status |= ak.joint_servo(
                self._q_c,
                self._qd_c,
                self._qpos[:n],
                self._qvel[:n],
                self._bias[:n],
                self._kp,
                self._kd,
                self._tau_max,
                self._ctrl,
            )
            contact = self._apply_contacts()
            mujoco.mj_step2(m, d)
        self._contact = contact
        self.status = ArmStatus(status)
        self._reading = self._make_reading(contact)
        return self._reading

    def _make_reading(self, contact: ContactResult, at_rest: bool = False) -> FTReading:
        """The F/T reading at {S} for the state the last step's forces were computed at
        (:func:`~app.world.arm_kernel.ft_reading`). ``at_rest`` evaluates MuJoCo's sensors with
        zero accelerations (a held arm) and adds the contact at that pose."""
        m, d, s = self.model, self.data, self._site_ft
        if at_rest or not contact.valid:
            d.qacc[:] = 0.0
            mujoco.mj_rnePostConstraint(m, d)
            mujoco.mj_sensorAcc(m, d)
            self._W_limit.fill(0.0)
            self._res.fill(0.0)
            self._res[3:6] = -self.scene.gravity_w
        else:
            mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_SITE, s, self._res, 0)
        wrench_S, R_w_S, acc_w, omega_w = ak.ft_reading(
            self._sdata,
            self._sens,
            self._W_limit,
            self._T,
            self._V,
            self._site_xmat[s],
            self._site_xpos[s],
            self._res,
            self.scene.gravity_w,
        )
        if not contact.valid:
            return FTReading(np.zeros(6), R_w_S, np.zeros(6), omega_w, False)
        if at_rest:
            wrench_S += contact.wrench_S
        return FTReading(wrench_S, R_w_S, acc_w, omega_w, True)
