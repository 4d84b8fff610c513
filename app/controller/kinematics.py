"""The controller's own model of the device: FK (Eq 1), wrist Jacobian, gravity torques.

It is compiled from the device's MJCF (the *nominal* model) and never touches a simulator's
state: the controller sees only encoder angles, as on real hardware.
"""

from __future__ import annotations

import mujoco
import numpy as np

from app.device.spec import DeviceSpec
from app.spatial import Array


class DeviceKinematics:
    """Forward kinematics, Jacobian and gravity compensation of the nominal device model.

    Call :meth:`update` with the joint angles once per tick, then read ``R_0_G``, ``p_0_G``,
    ``R_0_W``, ``p_0_W`` (views into MuJoCo's data: read-only, valid until the next update) and
    call :meth:`jacobian_W` / :meth:`gravity_torque`. Frames: {0} = MJCF world = device base,
    {W} = the device file's ``wrist_site``, {G} = its ``grip_site``.
    """

    def __init__(self, spec: DeviceSpec) -> None:
        self.spec = spec
        self.model = m = spec.model
        self.data = d = mujoco.MjData(m)
        self.n = spec.n_joints
        self._qpos_ids = np.array(spec.qpos_ids)
        dofs = np.array(spec.dof_ids)
        # Plain slices avoid a gather per tick when the joints are MuJoCo's first dofs in order.
        self._dofs: slice | Array = slice(0, self.n) if np.array_equal(dofs, np.arange(self.n)) else dofs
        grip = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, spec.data.grip_site)
        wrist = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, spec.data.wrist_site)
        self._wrist = wrist
        self.R_0_G: Array = d.site_xmat[grip].reshape(3, 3)
        self.p_0_G: Array = d.site_xpos[grip]
        self.R_0_W: Array = d.site_xmat[wrist].reshape(3, 3)
        self.p_0_W: Array = d.site_xpos[wrist]
        self._jacp = np.zeros((3, m.nv))
        self._jacr = np.zeros((3, m.nv))
        # Each tree hanging from the world contributes its whole weight through its subtree COM.
        self._roots = [b for b in range(1, m.nbody) if m.body_parentid[b] == 0 and m.body_subtreemass[b] > 0]
        self._support = [-m.body_subtreemass[b] * m.opt.gravity for b in self._roots]

    def update(self, q: Array) -> None:
        """Set the joint angles ``q`` (rad or m), shape (n,), and run FK (Eq 1)."""
        self.data.qpos[self._qpos_ids] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def jacobian_W(self, out: Array) -> Array:
        """Geometric Jacobian of {W}'s origin, base {0} coordinates, written into ``out`` (6, n).

        Rows are ``[v; w]``: ``[v_W; w] = J @ qdot``, so ``tau = J.T @ [f; m]`` for a wrench at
        {W}'s origin expressed in {0} coordinates (Eq 7 with J and F in the same coordinates).
        """
        mujoco.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self._wrist)
        out[0:3] = self._jacp[:, self._dofs]
        out[3:6] = self._jacr[:, self._dofs]
        return out

    def gravity_torque(self, out: Array) -> Array:
        """FRHC gravity compensation ``tau_G = sum_i J_i^T m_i (-g)`` (Sec 3.3), into ``out`` (n,).

        The paper sums over links the torques holding each link's weight at its centre of mass.
        The Jacobian of a tree's subtree centre of mass is the mass-weighted mean of the link
        Jacobians, so ``sum_i J_i^T m_i (-g) = J_com^T M (-g)``: one MuJoCo call per tree instead
        of one per link, and the same sum.
        """
        out[:] = 0.0
        for root, support in zip(self._roots, self._support, strict=True):
            mujoco.mj_jacSubtreeCom(self.model, self.data, self._jacp, root)
            out += self._jacp[:, self._dofs].T @ support
        return out
