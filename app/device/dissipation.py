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
    J = _home_jacobian(device)[1]
    return np.asarray(np.linalg.pinv(J @ (J.T / damping[:, None])))


def _home_jacobian(device: DeviceSpec) -> tuple[mujoco.MjData, Array]:
    """MuJoCo data of the nominal model at the home pose and the grip site's 6 x n Jacobian there
    (rows: linear, then angular velocity of the grip point, in the device base {0})."""
    model = device.model
    data = mujoco.MjData(model)
    data.qpos[list(device.qpos_ids)] = device.data.home
    mujoco.mj_forward(model, data)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, device.data.grip_site)
    J = np.zeros((6, model.nv))
    mujoco.mj_jacSite(model, data, J[:3], J[3:], site)
    return data, J[:, list(device.dof_ids)]


def grip_inertia_matrix(device: DeviceSpec) -> Array:
    """The device's translational inertia at the grip at the home pose, ``(J_v M^-1 J_v^T)^-1`` (kg), (3, 3).

    ``M`` is the joint-space inertia of the device's MJCF plus each joint's ``plant.armature``,
    ``J_v`` the linear rows of the grip site's Jacobian in {0} (a pseudo-inverse for a device
    with fewer than three translational degrees of freedom).
    """
    data, J = _home_jacobian(device)
    model = device.model
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    dofs = list(device.dof_ids)
    M = full[np.ix_(dofs, dofs)] + np.diag(device.data.plant.per_joint("armature", device.n_joints))
    Jv = J[0:3]
    return np.asarray(np.linalg.pinv(Jv @ np.linalg.solve(M, Jv.T)))


def grip_decay_time(device: DeviceSpec) -> float:
    """The slowest time constant (s) with which the device's own damping removes the kinetic energy of
    a free grip motion at the home pose: ``1 / (2 lambda_min(M_g^-1 B_g))``.

    ``M_g`` is :func:`grip_inertia_matrix`, ``B_g`` the translational block of
    :func:`grip_damping_matrix`: a grip moving freely along a generalised eigenvector ``v`` of
    ``(B_g, M_g)`` loses kinetic energy at the rate ``2 (v.B_g v / v.M_g v) KE``, so the least
    eigenvalue gives the slowest decay (Kraft / JPL / Freflex: 0.81 / 3.86 / 1.32 s). Inf when a
    joint has no damping.
    """
    B = grip_damping_matrix(device)
    if B is None:
        return float("inf")
    rates = np.linalg.eigvals(np.linalg.solve(grip_inertia_matrix(device), B[0:3, 0:3])).real
    slowest = float(rates.min())
    return 0.5 / slowest if slowest > 0.0 else float("inf")
