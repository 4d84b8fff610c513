"""What a device's own hardware dissipates, read from its file (the MJCF plus the ``[plant]`` table).

One source for the controller's passivity layer (:func:`~app.controller.passivity.device_dissipation`:
the friction credit and the virtual coupling's ``b``) and the stability tools
(:func:`~app.session.stability.grip_damping`: the ``b`` of the bound ``2 b / T``), so the two can
never disagree about the device.
"""

from __future__ import annotations

import mujoco
import numpy as np

from app.device.spec import DeviceSpec
from app.spatial import Array


def joint_friction(device: DeviceSpec) -> Array:
    """Each joint's Coulomb friction (N m, or N for slides), (n,): the MJCF's plus ``plant.frictionloss``."""
    dofs = list(device.dof_ids)
    return device.model.dof_frictionloss[dofs] + device.data.plant.per_joint("frictionloss", device.n_joints)


def joint_damping(device: DeviceSpec) -> Array:
    """Each joint's viscous damping (N m s/rad, or N s/m for slides), (n,): the MJCF's plus ``plant.damping``."""
    dofs = list(device.dof_ids)
    return device.model.dof_damping[dofs] + device.data.plant.per_joint("damping", device.n_joints)


def grip_damping_matrix(device: DeviceSpec) -> Array | None:
    """The joints' viscous damping seen at the grip at the home pose, ``B = (J D^-1 J^T)^-1``.

    ``J`` is the grip site's 6 x n Jacobian in the device base {0} (rows: linear, then angular
    velocity of the grip point), ``D`` the diagonal of :func:`joint_damping`: ``B`` is the least
    damping any joint motion producing a given grip twist meets (a pseudo-inverse for a device
    with fewer than six joints). Units: N s/m in the translational block ``B[0:3, 0:3]``, N m s
    in the rotational one. None if some joint has no damping (``D`` has no inverse).
    """
    damping = joint_damping(device)
    if not np.all(damping > 0.0):
        return None
    model = device.model
    data = mujoco.MjData(model)
    data.qpos[list(device.qpos_ids)] = device.data.home
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, device.data.grip_site)
    J = np.zeros((6, model.nv))
    mujoco.mj_jacSite(model, data, J[:3], J[3:], site)
    J = J[:, list(device.dof_ids)]
    return np.asarray(np.linalg.pinv(J @ (J.T / damping[:, None])))
