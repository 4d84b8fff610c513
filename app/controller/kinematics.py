"""The controller's own model of the device: FK (Eq 1), wrist Jacobian, gravity torques.

It is compiled from the device's MJCF (the *nominal* model) and never touches a simulator's
state: the controller sees only encoder angles, as on real hardware.

MuJoCo's ``mj_kinematics`` does the forward kinematics. The Jacobian and the gravity sum are
then plain sums over the joint axes it leaves in ``MjData`` (:func:`wrist_jacobian`,
:func:`gravity_torque`), compiled with numba so the controller's tick kernel can call them
directly: a MuJoCo ``mj_jac*`` call per link from Python would cost more than the rest of the
tick.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
from numba import njit
from numpy.typing import NDArray

from app.device.spec import DeviceSpec
from app.spatial import Array, IntArray

FlagArray = NDArray[np.uint8]
"""0/1 flags; uint8 rather than bool because numba has no bool arrays inside records."""
Field = tuple[Any, ...]
"""One field of a numpy record dtype: ``(name, type)`` or ``(name, type, shape)``."""
RecordArray = NDArray[np.void]
"""A one-element numpy record array: how records are passed to compiled functions (numba unboxes
an array cheaply but a bare ``numpy.void`` record slowly)."""


def topology_fields(n: int, nbody: int) -> list[Field]:
    """Record fields for :class:`DeviceKinematics`' topology attributes (same names, same meaning).

    ``n`` is the number of controlled joints, ``nbody`` MuJoCo's body count. The controller's
    tick record embeds them so its compiled tick needs no further arguments for them.
    """
    return [
        ("joint_ids", np.int64, (n,)),
        ("slide", np.uint8, (n,)),
        ("moves", np.uint8, (n, nbody)),
        ("moves_wrist", np.uint8, (n,)),
        ("support", np.float64, (nbody, 3)),
        ("grip_site", np.int64),
        ("wrist_site", np.int64),
    ]


@njit(cache=True)
def wrist_jacobian(
    xaxis: Array,
    xanchor: Array,
    p_0_W: Array,
    joint_ids: IntArray,
    slide: FlagArray,
    moves_wrist: FlagArray,
    out: Array,
) -> Array:
    """Geometric Jacobian of {W}'s origin, base {0} coordinates, written into ``out`` (6, n).

    Rows are ``[v; w]``: ``[v_W; w] = J @ qdot``, so ``tau = J.T @ [f; m]`` for a wrench at {W}'s
    origin expressed in {0} coordinates (Eq 7 with J and F in the same coordinates). A hinge
    with world axis a through anchor c gives column ``[a x (p_W - c); a]``, a slide ``[a; 0]``.

    Args:
        xaxis, xanchor: MuJoCo's joint axes and anchors in {0} after ``mj_kinematics``, (njnt, 3).
        p_0_W: {W}'s origin in {0} (m), (3,).
        joint_ids, slide, moves_wrist: :class:`DeviceKinematics`' attributes of those names.
        out: (6, n), overwritten.
    """
    for j in range(joint_ids.shape[0]):
        for k in range(6):
            out[k, j] = 0.0
        if not moves_wrist[j]:
            continue
        a = xaxis[joint_ids[j]]
        if slide[j]:
            out[0, j], out[1, j], out[2, j] = a[0], a[1], a[2]
            continue
        c = xanchor[joint_ids[j]]
        rx, ry, rz = p_0_W[0] - c[0], p_0_W[1] - c[1], p_0_W[2] - c[2]
        out[0, j] = a[1] * rz - a[2] * ry
        out[1, j] = a[2] * rx - a[0] * rz
        out[2, j] = a[0] * ry - a[1] * rx
        out[3, j], out[4, j], out[5, j] = a[0], a[1], a[2]
    return out


@njit(cache=True)
def gravity_torque(
    xaxis: Array,
    xanchor: Array,
    xipos: Array,
    joint_ids: IntArray,
    slide: FlagArray,
    moves: FlagArray,
    support: Array,
    out: Array,
) -> Array:
    """FRHC gravity compensation ``tau_G = sum_i J_i^T m_i (-g)`` (Sec 3.3), into ``out`` (n,) (N m or N).

    The paper's per-link sum, each link's weight held at its centre of mass: a hinge j carries
    the moment of every body it moves about its own axis, ``a_j . sum_b (c_b - anchor_j) x
    (-m_b g)``; a slide carries the force along its axis.

    Args:
        xaxis, xanchor: MuJoCo's joint axes and anchors in {0} after ``mj_kinematics``, (njnt, 3).
        xipos: MuJoCo's body centres of mass in {0} (m), (nbody, 3).
        joint_ids, slide, moves, support: :class:`DeviceKinematics`' attributes of those names.
        out: (n,), overwritten.
    """
    for j in range(joint_ids.shape[0]):
        a = xaxis[joint_ids[j]]
        c = xanchor[joint_ids[j]]
        acc = 0.0
        for b in range(support.shape[0]):
            if not moves[j, b]:
                continue
            f = support[b]
            if slide[j]:
                acc += a[0] * f[0] + a[1] * f[1] + a[2] * f[2]
            else:
                # a . (r x f) with r the lever from the anchor to the body's centre of mass.
                rx, ry, rz = xipos[b, 0] - c[0], xipos[b, 1] - c[1], xipos[b, 2] - c[2]
                acc += a[0] * (ry * f[2] - rz * f[1]) + a[1] * (rz * f[0] - rx * f[2]) + a[2] * (rx * f[1] - ry * f[0])
        out[j] = acc
    return out


class DeviceKinematics:
    """Forward kinematics, Jacobian and gravity compensation of the nominal device model.

    Call :meth:`update` with the joint angles once per tick, then read ``R_0_G``, ``p_0_G``,
    ``R_0_W``, ``p_0_W`` (views into MuJoCo's data: read-only, valid until the next update) and
    call :meth:`jacobian_W` / :meth:`gravity_torque`. Frames: {0} = MJCF world = device base,
    {W} = the device file's ``wrist_site``, {G} = its ``grip_site``.

    Attributes:
        fk_arrays: MuJoCo's arrays the compiled functions read after :meth:`update`:
            ``(xaxis, xanchor, xipos, site_xpos, site_xmat)`` (views, fixed for this object's life).
        joint_ids: MuJoCo joint id of each controlled joint (rows of ``xaxis``/``xanchor``), (n,).
        slide: 1 for a slide joint, 0 for a hinge, (n,).
        moves: ``moves[j, b]`` is 1 if joint j moves body b (j's body is b or an ancestor), (n, nbody).
        moves_wrist: The column of ``moves`` of the body carrying {W}, (n,).
        support: Force holding each body's weight, ``-m_b g`` (N), in {0}, (nbody, 3).
        grip_site, wrist_site: MuJoCo site ids of {G} and {W}.
    """

    def __init__(self, spec: DeviceSpec) -> None:
        self.spec = spec
        self.model = m = spec.model
        self.data = d = mujoco.MjData(m)
        self.n = n = spec.n_joints
        qpos_ids = np.array(spec.qpos_ids)
        # A plain slice avoids a gather per tick when the joints are MuJoCo's first in order.
        self._qpos: Array | None = d.qpos[0:n] if np.array_equal(qpos_ids, np.arange(n)) else None
        self._qpos_ids = qpos_ids
        self.grip_site = grip = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, spec.data.grip_site)
        self.wrist_site = wrist = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, spec.data.wrist_site)
        self.R_0_G: Array = d.site_xmat[grip].reshape(3, 3)
        self.p_0_G: Array = d.site_xpos[grip]
        self.R_0_W: Array = d.site_xmat[wrist].reshape(3, 3)
        self.p_0_W: Array = d.site_xpos[wrist]
        self.fk_arrays = (d.xaxis, d.xanchor, d.xipos, d.site_xpos, d.site_xmat)
        self.joint_ids: IntArray = np.array(spec.joint_ids, dtype=np.int64)
        self.slide: FlagArray = (m.jnt_type[self.joint_ids] == mujoco.mjtJoint.mjJNT_SLIDE).astype(np.uint8)
        self.moves: FlagArray = np.array(
            [[_is_ancestor(m, body, b) for b in range(m.nbody)] for body in m.jnt_bodyid[self.joint_ids]],
            dtype=np.uint8,
        ).reshape(n, m.nbody)
        self.moves_wrist: FlagArray = np.ascontiguousarray(self.moves[:, m.site_bodyid[wrist]])
        self.support: Array = -m.body_mass[:, None] * m.opt.gravity

    def update(self, q: Array) -> None:
        """Set the joint angles ``q`` (rad or m), shape (n,), and run FK (Eq 1).

        Only ``mj_kinematics``: the Jacobian and gravity sums here need no centre-of-mass frames,
        so ``mj_comPos`` (which MuJoCo's own ``mj_jac*`` would need first) is skipped.
        """
        if self._qpos is not None:
            self._qpos[:] = q
        else:
            self.data.qpos[self._qpos_ids] = q
        mujoco.mj_kinematics(self.model, self.data)

    def jacobian_W(self, out: Array) -> Array:
        """Geometric Jacobian of {W}'s origin in {0} into ``out`` (6, n); see :func:`wrist_jacobian`."""
        xaxis, xanchor, _, _, _ = self.fk_arrays
        return wrist_jacobian(xaxis, xanchor, self.p_0_W, self.joint_ids, self.slide, self.moves_wrist, out)

    def gravity_torque(self, out: Array) -> Array:
        """Gravity compensation torques ``tau_G`` into ``out`` (n,); see :func:`gravity_torque`."""
        xaxis, xanchor, xipos, _, _ = self.fk_arrays
        return gravity_torque(xaxis, xanchor, xipos, self.joint_ids, self.slide, self.moves, self.support, out)


def _is_ancestor(m: mujoco.MjModel, ancestor: int, body: int) -> bool:
    """Whether ``ancestor`` is ``body`` or on its path to the world body."""
    while body > 0 and body != ancestor:
        body = int(m.body_parentid[body])
    return body == ancestor
