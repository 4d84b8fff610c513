"""The operator's hand: a 6-dof spring-damper pulling the grip {G} toward a hand target {H}.

A human arm holding a hand controller behaves, at the low frequencies that matter here, like a
spring-damper about where the operator *wants* the grip to be (the hand target ``T_0_H``).
Scripts set that target; the browser gizmo drags it. The hand pushes on the grip with

    f = K_t (p_H - p_G) - D_t v_G                 (N, base {0} coordinates, acting at the G origin)
    m = K_r log(R_H R_G^T) - D_r omega_G          (N m, base {0} coordinates)

where ``v_G``/``omega_G`` are the grip's linear (m/s) and angular (rad/s) velocities in {0} and
``log(R_H R_G^T)`` is the rotation vector (rad) turning {G} onto {H}, in {0}; their magnitudes are
limited to a person's strength (``HandParams.force_limit``, ``torque_limit``).

It is built from MuJoCo parts so that it costs no Python in the servo loop: {H} is a mocap body
with a site, and six position actuators with a *site transmission* (``site = grip``,
``refsite = H``, unit gears along the three translations and three rotations of {H}) implement
the spring (``kp``) and damper (``kv``). MuJoCo applies their force at the grip site itself (the
point of application is G, not a body's centre of mass) and integrates the damping implicitly.
With isotropic gains the {H}-frame components rotate into the {0}-frame law above exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import mujoco
import numpy as np
from numba import njit

from app.compiled import entry_point, is_f8
from app.config import Checked, Range
from app.device.boundary import HAND_OFF, HAND_ROTATED
from app.mjcall import address, call_model_data, pointers
from app.spatial import Array, IntArray, quat_of

#: MuJoCo actuator group of the hand's actuators; disabled (``opt.disableactuator``) when released.
HAND_GROUP = 5
HAND_BODY = "operator_hand"
HAND_SITE = "operator_hand_site"


@njit(cache=True)
def rotate_wrench(T: Array, w: Array, out: Array, at: int) -> None:
    """``out[at : at + 6]`` = the wrench ``w`` (6,) in the axes of pose ``T`` (4, 4), expressed in
    its base's (a compiled product: numpy's on 3-vectors costs microseconds, and more through
    BLAS); ``at`` lets a caller write into a larger row without making a view of it."""
    for a in range(3):
        out[at + a] = T[a, 0] * w[0] + T[a, 1] * w[1] + T[a, 2] * w[2]
        out[at + 3 + a] = T[a, 0] * w[3] + T[a, 1] * w[4] + T[a, 2] * w[5]


@njit(cache=True)
def pull_target(
    T_0_H: Array, T: Array, mocap_pos: Array, mocap_quat: Array, kinematics: int, transmission: int, m: int, d: int
) -> bool:
    """Copy a finite ``T_0_H`` (4, 4) to ``T`` and to the hand's mocap pose, then run MuJoCo's
    kinematics and transmissions (functions at ``kinematics``, ``transmission``; model and data
    at ``m``, ``d``); False, with nothing written, if ``T_0_H`` is not finite.

    A target whose mocap pose is the one already there (a hand held still) is only copied to
    ``T``: MuJoCo's kinematics and transmissions in ``d`` already belong to it, as every change of
    the joints is followed by them (the plant's period ends with ``mj_step1``, its reset too), and
    they are functions of the joints and the mocap pose only. ~1 us of a script's tick saved on
    a held hand; the same values in ``d``.
    """
    for a in range(4):
        for b in range(4):
            if not math.isfinite(T_0_H[a, b]):
                return False
    for a in range(4):
        for b in range(4):
            T[a, b] = T_0_H[a, b]
    qw, qx, qy, qz = quat_of(T_0_H)
    if (
        mocap_pos[0] == T[0, 3]
        and mocap_pos[1] == T[1, 3]
        and mocap_pos[2] == T[2, 3]
        and mocap_quat[0] == qw
        and mocap_quat[1] == qx
        and mocap_quat[2] == qy
        and mocap_quat[3] == qz
    ):
        return True
    for a in range(3):
        mocap_pos[a] = T[a, 3]
    mocap_quat[0], mocap_quat[1], mocap_quat[2], mocap_quat[3] = qw, qx, qy, qz
    call_model_data(kinematics, m, d)
    call_model_data(transmission, m, d)
    return True


@njit(cache=True)
def copy_and_pull(
    T_0_H: Array,
    copy: Array,
    T: Array,
    mocap_pos: Array,
    mocap_quat: Array,
    kinematics: int,
    transmission: int,
    m: int,
    d: int,
) -> bool:
    """``T_0_H`` (4, 4) copied into ``copy`` (a loop's record of the target), then
    :func:`pull_target`: what a caller holding :meth:`OperatorHand.pull_args` does each tick."""
    for a in range(4):
        for b in range(4):
            copy[a, b] = T_0_H[a, b]
    return pull_target(T_0_H, T, mocap_pos, mocap_quat, kinematics, transmission, m, d)


#: What :func:`pull_target` takes after the target: the hand's target and mocap position and
#: quaternion, MuJoCo's kinematics and transmission functions, model and data (addresses).
PullArgs = tuple[Array, Array, Array, int, int, int, int]


@dataclass(frozen=True)
class HandParams(Checked):
    """Impedance of the operator's hand/arm as felt at the grip (ranges: ``sessions/README.md``).

    Attributes:
        stiffness_trans: Translational stiffness K_t (N/m); a human arm holding a haptic device is
            63-533 (Fu & Cavusoglu 2012, the arm element: ``docs/experiment.md``).
        damping_trans: Translational damping D_t (N s/m); 3.7-27.6 for the same arms.
        stiffness_rot: Rotational stiffness K_r (N m/rad); the passive wrist is 1.28-1.74 (Formica
            et al. 2012), a grip held with co-contraction stiffer.
        damping_rot: Rotational damping D_r (N m s/rad); no source found.
        force_limit: The most the hand pushes or pulls (N): a person's strength, the bound on the
            force's magnitude (each axis of {H} is limited to ``force_limit / sqrt(3)``). 400, the
            strongest isometric pull of males seated or standing anywhere in the workspace (Das &
            Wang 2004, Int. J. Occup. Saf. Ergon. 10(1):43-58; their strongest push, 227-251 N, is
            lower).
        torque_limit: The most the hand twists (N m), the same way. 18.7, the largest peak
            isometric wrist moment of ten males (flexion 5.2-18.7, radial-ulnar deviation up to
            15.3; Delp, Grierson & Buchanan 1996, J. Biomech. 29(10):1371-1375).
    """

    stiffness_trans: Annotated[float, Range(0.0, 1e4, "N/m")] = 400.0
    damping_trans: Annotated[float, Range(0.0, 1e3, "N s/m")] = 10.0
    stiffness_rot: Annotated[float, Range(0.0, 100.0, "N m/rad")] = 2.0
    damping_rot: Annotated[float, Range(0.0, 10.0, "N m s/rad")] = 0.05
    force_limit: Annotated[float, Range(0.0, 1e4, "N", lo_open=True)] = 400.0
    torque_limit: Annotated[float, Range(0.0, 1e3, "N m", lo_open=True)] = 18.7


def add_hand(mjspec: mujoco.MjSpec, grip_site: str, params: HandParams) -> None:
    """Add the hand target (mocap body + site) and its six spring-damper actuators to ``mjspec``."""
    body = mjspec.worldbody.add_body(name=HAND_BODY, mocap=True)
    body.add_site(name=HAND_SITE, size=[0.01, 0.01, 0.01], rgba=[0.2, 0.9, 0.3, 0.5])
    kp = [params.stiffness_trans] * 3 + [params.stiffness_rot] * 3
    kv = [params.damping_trans] * 3 + [params.damping_rot] * 3
    # A target far from the grip is a person pulling as hard as they can, not a spring of
    # kilonewtons: 30 m out, the unlimited spring (12 kN) drove the Touch's joints unstable
    # within 12 ms and the Kraft's to 850 rad/s. MuJoCo limits each actuator, so each axis gets
    # the share that keeps the magnitude within.
    share = 1.0 / math.sqrt(3.0)
    limit = [params.force_limit * share] * 3 + [params.torque_limit * share] * 3
    for k in range(6):
        act = mjspec.add_actuator(
            name=f"operator_hand_{'xyzXYZ'[k]}",
            trntype=mujoco.mjtTrn.mjTRN_SITE,
            target=grip_site,
            refsite=HAND_SITE,
        )
        act.gear = [1.0 if i == k else 0.0 for i in range(6)]
        act.group = HAND_GROUP
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.gainprm[0] = kp[k]
        # force = kp * ctrl - kp * length - kv * velocity, with ctrl left at 0: a spring to {H}.
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.biasprm[0] = 0.0
        act.biasprm[1] = -kp[k]
        act.biasprm[2] = -kv[k]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-limit[k], limit[k]]


class OperatorHand:
    """The hand inside a model built with :func:`add_hand`: sets its target, reports its wrench.

    Args:
        params: The impedance the model was built with.
        model: The compiled model.
        data: Its data.
    """

    def __init__(self, params: HandParams, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.params = params
        self._model = model
        self._data = data
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, HAND_BODY)
        self._mocap = int(model.body_mocapid[body])
        first = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "operator_hand_x")
        self._force_H = data.actuator_force[first : first + 6]
        self._wrench_G = np.zeros(6)
        self._T = np.eye(4)
        # How the wrench is made (GripSources.how): held or not, for compiled readers.
        self._how = np.array([HAND_OFF], dtype=np.int64)
        # Read every tick by the state row: the compiled specialisation, without numba's typing.
        self._rotate = entry_point(rotate_wrench, self._T, self._force_H, self._wrench_G, 0)
        self._mocap_pos = data.mocap_pos[self._mocap]
        self._mocap_quat = data.mocap_quat[self._mocap]
        self._opt = model.opt
        kinematics, transmission = address("mj_kinematics"), address("mj_transmission")
        self._pull_args = (self._T, self._mocap_pos, self._mocap_quat, kinematics, transmission, *pointers(model, data))
        # Called every tick with the same kinds of arguments: the compiled specialisation, once.
        self._pull = entry_point(pull_target, self._T, *self._pull_args)
        #: Hand target pose T_0_H (4, 4), or None when the operator has let go.
        self.T_0_H: Array | None = None
        self.set_target(None)

    def set_target(self, T_0_H: Array | None) -> None:
        """Grab the grip and pull it toward ``T_0_H`` (4, 4, base frame), or let go with None.

        The pose is copied (callers may reuse their array), and the hand actuators' lengths are
        brought up to date (MuJoCo's kinematics and transmissions, the only part of the next
        step's spring lengths the target changes). Scripts and the UI call this every servo
        tick: one compiled call, with no allocation.
        """
        opt = self._opt
        if T_0_H is None:
            self.T_0_H = None
            self._how[0] = HAND_OFF
            opt.disableactuator |= 1 << HAND_GROUP
            mujoco.mj_kinematics(self._model, self._data)
            mujoco.mj_transmission(self._model, self._data)
            return
        if T_0_H.__class__ is not np.ndarray or T_0_H.shape != (4, 4):
            raise ValueError("T_0_H must be a finite 4x4 pose")
        if not is_f8(T_0_H, (4, 4)):
            T_0_H = np.ascontiguousarray(T_0_H, dtype=float)
        if not self._pull(T_0_H, *self._pull_args):
            raise ValueError("T_0_H must be a finite 4x4 pose")
        if self.T_0_H is None:
            opt.disableactuator &= ~(1 << HAND_GROUP)
            self._how[0] = HAND_ROTATED
        self.T_0_H = self._T

    def pull_args(self) -> PullArgs | None:
        """What :func:`pull_target` takes after the target, for a caller that moves the held hand
        from its own compiled code every tick (:meth:`~app.session.loop.ServoLoop.hand_pull`); None
        while the hand is off the grip (only :meth:`set_target` takes hold)."""
        return None if self.T_0_H is None else self._pull_args

    def wrench_sources(self) -> tuple[Array, Array, IntArray]:
        """What :meth:`wrench_G` is made of (:class:`~app.device.boundary.GripSources`' ``T_H``,
        ``w_H``, ``how``): the target pose, the actuators' forces, whether the hand holds."""
        return self._T, self._force_H, self._how

    def wrench_G(self) -> Array:
        """The hand's wrench on the grip in the last physics step.

        Returns:
            ``[f; m]`` (N, N m) at the G origin in base {0} coordinates, shape (6,), zero when
            released. The array is reused by the next call.
        """
        if self.T_0_H is None:
            self._wrench_G.fill(0.0)
        else:
            self._rotate(self._T, self._force_H, self._wrench_G, 0)
        return self._wrench_G
