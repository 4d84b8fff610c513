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
   then ``mj_step``.
3. The virtual F/T sensor at {S} reports what a real one would: the wrench on everything
   outboard of it, ``contact + payload weight - payload inertial load``, with the accelerations
   the integrator applied in the step.

Frames as in :mod:`app.world.scene`. The MuJoCo body frame is the tool's centre of mass with the
axes of {T}, so the free joint's linear velocity is the centre-of-mass velocity.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from app.controller.types import FTReading, SlaveCommand, SlaveModel
from app.spatial import Array, matrix_to_quat, rotation_exp, rotation_log
from app.world.contact import ContactModel, ContactResult
from app.world.scene import Scene
from app.world.vec3 import cross3

DEFAULT_PERIOD = 1e-3  # s, the servo period


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


def _saturate(v: Array, limit: float) -> Array:
    n = math.sqrt(float(v @ v))
    return v * (limit / n) if n > limit else v


class VirtualSlave:
    """A simulated slave robot tool with a virtual F/T sensor.

    Args:
        scene: The scene (tool, objects, slave gains).
        accommodation: NTRFC force accommodation on (True) or "blind" rate control (False).
        period: Servo period (s) the slave expects; ``step`` may be given another ``dt``.
    """

    def __init__(self, scene: Scene, accommodation: bool = True, period: float = DEFAULT_PERIOD) -> None:
        self.scene = scene
        self.accommodation = accommodation
        self.gains = scene.spec.slave
        self.contact_model = ContactModel(scene)
        tool = scene.tool
        self._substeps = self.gains.substeps
        self.model = mujoco.MjModel.from_xml_string(_tool_xml(scene, period / self._substeps))
        self.data = mujoco.MjData(self.model)
        self._body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "tool")
        self._mass = tool.mass
        self._inertia_T = tool.inertia_T
        # Offsets of {MRF} and {S} from the centre of mass, in {T} axes (the body axes).
        self._R_T_MRF = tool.T_T_MRF[0:3, 0:3]
        self._p_com_MRF_T = tool.T_T_MRF[0:3, 3] - tool.com_T
        self._R_T_S = tool.T_T_S[0:3, 0:3]
        self._p_com_S_T = tool.T_T_S[0:3, 3] - tool.com_T
        self._k_acc = np.array(self.gains.accommodation)
        self._max_lead_lin = self.gains.force_limit / self.gains.kp_lin
        self._max_lead_rot = self.gains.torque_limit / self.gains.kp_rot
        self._V_ref_w = np.zeros(6)
        self._T_ref = np.eye(4)
        self._T_buf = np.eye(4)
        self._V_buf = np.zeros(6)
        self._R_buf = np.zeros(9)
        self._contact: ContactResult
        self.reset()

    # --- state -----------------------------------------------------------------------------
    def reset(self, T_w_MRF: Array | None = None) -> None:
        """Put the tool at rest at ``T_w_MRF`` (default: the scene's home), reference there too."""
        T = self.scene.tool.T_w_MRF_home if T_w_MRF is None else T_w_MRF
        mujoco.mj_resetData(self.model, self.data)
        R_w_T = T[0:3, 0:3] @ self._R_T_MRF.T
        p_w_com = T[0:3, 3] - R_w_T @ self._p_com_MRF_T
        self.data.qpos[0:3] = p_w_com
        self.data.qpos[3:7] = matrix_to_quat(R_w_T)
        mujoco.mj_forward(self.model, self.data)
        self._T_ref = np.array(T, dtype=float)
        self._V_ref_w.fill(0.0)
        self.contact_model.reset()
        self._contact = self.contact_model.wrench(self.T_w_MRF, self.V_w_MRF)

    def _R_w_T(self) -> Array:
        """Orientation of {T} in {w} (3, 3), written into a buffer (mju_quat2Mat: no Python maths)."""
        mujoco.mju_quat2Mat(self._R_buf, self.data.qpos[3:7])
        return self._R_buf.reshape(3, 3).copy()

    @property
    def T_w_MRF(self) -> Array:
        """Current pose of {MRF} in {w}, (4, 4)."""
        R_w_T = self._R_w_T()
        T = np.eye(4)
        T[0:3, 0:3] = R_w_T @ self._R_T_MRF
        T[0:3, 3] = self.data.qpos[0:3] + R_w_T @ self._p_com_MRF_T
        return T

    @property
    def V_w_MRF(self) -> Array:
        """Current twist ``[v; w]`` of {MRF} (origin velocity, angular velocity) in {w}, (6,)."""
        R_w_T = self._R_w_T()
        w_w = R_w_T @ self.data.qvel[3:6]
        v = self.data.qvel[0:3] + cross3(w_w, R_w_T @ self._p_com_MRF_T)
        return np.concatenate((v, w_w))

    @property
    def T_w_MRF_ref(self) -> Array:
        """The reference pose of {MRF} the PD pulls toward, (4, 4)."""
        return self._T_ref.copy()

    @property
    def contact(self) -> ContactResult:
        """The last contact evaluation (points, normals, depths for display)."""
        return self._contact

    @property
    def wrench_MRF_contact(self) -> Array:
        """Contact wrench at the {MRF} origin in {MRF} (N, N m), (6,): for the work metric (Eq 13)."""
        return self._contact.wrench_MRF

    def slave_model(self) -> SlaveModel:
        """What the controller may know about this tool (for payload weight/inertia removal)."""
        tool = self.scene.tool
        R_T_S = self._R_T_S
        return SlaveModel(
            T_MRF_S=tool.T_MRF_S,
            payload_mass=tool.mass,
            payload_com_S=R_T_S.T @ (tool.com_T - tool.T_T_S[0:3, 3]),
            payload_inertia_S=R_T_S.T @ tool.inertia_T @ R_T_S,
            gravity_w=self.scene.gravity_w.copy(),
            T_w_MRF_home=tool.T_w_MRF_home.copy(),
        )

    # --- servo tick --------------------------------------------------------------------------
    def _update_reference(self, command: SlaveCommand, dt: float, R_w_MRF: Array, p_w_MRF: Array) -> None:
        if not command.active:
            self._V_ref_w.fill(0.0)
            return
        if command.mode == "pose":
            self._T_ref = np.array(command.T_w_MRF, dtype=float)
            self._V_ref_w.fill(0.0)
            return
        if command.mode != "rate":
            raise ValueError(f"unknown slave command mode {command.mode!r}")
        v_w = command.twist[0:3].copy()
        w_MRF = command.twist[3:6].copy()
        if self.accommodation and self._contact.valid:
            F_MRF = self._contact.wrench_MRF
            v_w += R_w_MRF @ (self._k_acc[0:3] * F_MRF[0:3])
            w_MRF += self._k_acc[3:6] * F_MRF[3:6]
        w_w = R_w_MRF @ w_MRF
        self._V_ref_w[0:3] = v_w
        self._V_ref_w[3:6] = w_w
        T = self._T_ref
        p_ref = T[0:3, 3] + v_w * dt
        R_ref = rotation_exp(w_w * dt) @ T[0:3, 0:3]
        # Following-error limit: never lead the tool by more than the PD can push against.
        e_p = p_ref - p_w_MRF
        n = math.sqrt(float(e_p @ e_p))
        if n > self._max_lead_lin:
            p_ref = p_w_MRF + e_p * (self._max_lead_lin / n)
        e_r = rotation_log(R_ref @ R_w_MRF.T)
        n = math.sqrt(float(e_r @ e_r))
        if n > self._max_lead_rot:
            R_ref = rotation_exp(e_r * (self._max_lead_rot / n)) @ R_w_MRF
        T[0:3, 0:3] = R_ref
        T[0:3, 3] = p_ref

    def step(self, command: SlaveCommand, dt: float = DEFAULT_PERIOD) -> FTReading:
        """Advance one servo period ``dt`` (s) under ``command``; return the F/T sensor reading."""
        g = self.gains
        h = dt / self._substeps
        self.model.opt.timestep = h
        d = self.data
        xfrc = d.xfrc_applied[self._body]
        T_buf = self._T_buf
        V = self._V_buf
        for sub in range(self._substeps):
            mujoco.mju_quat2Mat(self._R_buf, d.qpos[3:7])
            R_w_T = self._R_buf.reshape(3, 3)
            w_w = R_w_T @ d.qvel[3:6]
            r_com_MRF = R_w_T @ self._p_com_MRF_T
            p_MRF = d.qpos[0:3] + r_com_MRF
            R_w_MRF = R_w_T @ self._R_T_MRF
            if sub == 0:
                self._update_reference(command, dt, R_w_MRF, p_MRF)
            V[0:3] = d.qvel[0:3] + cross3(w_w, r_com_MRF)
            V[3:6] = w_w
            T_buf[0:3, 0:3] = R_w_MRF
            T_buf[0:3, 3] = p_MRF
            contact = self.contact_model.wrench(T_buf, V)
            self._contact = contact
            e_R = rotation_log(self._T_ref[0:3, 0:3] @ R_w_MRF.T)
            f_pd = _saturate(
                g.kp_lin * (self._T_ref[0:3, 3] - p_MRF) + g.kd_lin * (self._V_ref_w[0:3] - V[0:3]), g.force_limit
            )
            t_pd = _saturate(g.kp_rot * e_R + g.kd_rot * (self._V_ref_w[3:6] - w_w), g.torque_limit)
            f_total = f_pd + contact.force_w
            xfrc[0:3] = f_total
            xfrc[3:6] = t_pd + R_w_MRF @ contact.wrench_MRF[3:6] + cross3(r_com_MRF, f_total)
            mujoco.mj_step(self.model, d)
        # Semi-implicit Euler applied exactly qacc over the last substep: [a_com in {w}; dw/dt in {T}].
        return self._sensor(R_w_T, w_w, d.qacc[0:3].copy(), R_w_T @ d.qacc[3:6], contact)

    def _sensor(self, R_w_T: Array, w_w: Array, a_com: Array, alpha_w: Array, contact: ContactResult) -> FTReading:
        """F/T reading at {S}: contact + weight - inertial load of the outboard body, in {S}."""
        R_w_S = R_w_T @ self._R_T_S
        if not contact.valid:
            return FTReading(np.zeros(6), R_w_S, np.zeros(6), w_w.copy(), valid=False)
        m = self._mass
        r_S_com = -(R_w_T @ self._p_com_S_T)  # from the {S} origin to the centre of mass, {w}
        I_w = R_w_T @ self._inertia_T @ R_w_T.T
        f_body = m * (self.scene.gravity_w - a_com)  # weight minus inertial force, at the com
        m_body = cross3(r_S_com, f_body) - (I_w @ alpha_w + cross3(w_w, I_w @ w_w))
        F_S = contact.wrench_S.copy()
        F_S[0:3] += f_body @ R_w_S
        F_S[3:6] += m_body @ R_w_S
        r_com_S = -r_S_com
        a_S = a_com + cross3(alpha_w, r_com_S) + cross3(w_w, cross3(w_w, r_com_S))
        return FTReading(F_S, R_w_S, np.concatenate((a_S, alpha_w)), w_w.copy(), valid=True)
