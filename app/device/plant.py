"""The simulated force-reflecting hand controller: a MuJoCo plant driven by motor counts.

The plant is what the controller cannot see: its own MuJoCo model compiled from the device's MJCF
and perturbed by the device file's ``[plant]`` table (link masses, joint friction, damping, rotor
inertia), the motors' *true* torque curve, the joint-torque limits and encoder quantisation.
The controller owns a separate, nominal model (``DeviceSpec.model``); the two differ as a real
device differs from its drawings.

One :meth:`DevicePlant.step` is one servo period ``dt``:

    counts (n,) --true motor curve--> motor torque --gear ratio, clip to limits--> joint torque
    --> MuJoCo (qfrc_applied, zero-order hold over ``substeps`` physics steps, plus the
    operator's hand J_G^T [f; m]) --> encoders (quantised joint angles), grip pose T_0_G.

True motor curve (per joint, per driving direction; the paper's Fig. 5 found the manufacturer's
linear curve wrong). With ``x = clip(c, -c_max, c_max) / c_max`` the normalised command,

    u   = max(|x| - deadzone, 0) / (1 - deadzone)          amplifier deadzone, then rescaled
    s   = (1 + k) u - k u^3                                 k = softening of that direction
    tau = sign(x) * gain * torque_limit * s                 motor torque (N m)

with ``gain``/``k`` taken from the ``_pos`` or ``_neg`` field by the sign of ``c``. ``s(0) = 0``,
``s(1) = 1`` and ``s`` is monotonic for ``-1 < k <= 0.5``: ``k > 0`` gives a curve that rises
faster than linear at small commands and flattens toward full scale (current-loop softening),
``k < 0`` the reverse. ``gain > 1`` lets the motor exceed its rating near full scale, where the
joint clip to ``gear_ratio * torque_limit`` then cuts it off.
"""

from __future__ import annotations

from typing import Any, Literal

import mujoco
import numpy as np
import numpy.typing as npt
from numba import njit

from app.compiled import I8, entry_point
from app.device.boundary import GripSources, LinkStatus
from app.device.hand import HandParams, OperatorHand, add_hand
from app.device.plant_kernel import plant_period
from app.device.spec import DeviceSpec, MotorSpec, PlantParams
from app.errors import ConfigError
from app.mjcall import address, pointers, substeps_for
from app.spatial import Array, IntArray

#: Integer motor commands (counts), shape (n,).
Counts = npt.NDArray[np.integer[Any]]

#: The amplifier's servo watchdog (s): 20 servo periods at 1 kHz without new counts.
WATCHDOG = 0.02

#: Impedance (d0, d_width) of the joints' friction-loss constraints: near 1 for little creep.
FRICTION_IMPEDANCE = (0.9999, 0.9999)


def true_motor_torque(params: PlantParams, motors: MotorSpec, counts: Array) -> Array:
    """The plant's true motor curve: motor torque (N m) for commanded counts.

    Args:
        params: The plant table holding the curve's gains, softening and deadzone.
        motors: Limits and full-scale counts.
        counts: Commands (counts), shape (..., n); need not be integers or within range.

    Returns:
        Motor-shaft torques (N m), shape of ``counts``, before the joint-torque clip.
    """
    n = len(motors.torque_limit)
    c = np.asarray(counts, dtype=float)
    x = np.clip(c, -motors.counts_max, motors.counts_max) / motors.counts_max
    dz = params.per_joint("motor_deadzone", n)
    u = np.maximum(np.abs(x) - dz, 0.0) / (1.0 - dz)
    positive = c >= 0
    k = np.where(positive, params.per_joint("motor_softening_pos", n), params.per_joint("motor_softening_neg", n))
    gain = np.where(positive, params.per_joint("motor_gain_pos", n), params.per_joint("motor_gain_neg", n))
    s = (1.0 + k) * u - k * u**3
    return np.sign(x) * gain * np.asarray(motors.torque_limit) * s


class PlantReading:
    """What one plant step reports. The arrays are reused: the next step overwrites them.

    Attributes:
        q: Encoder joint angles (rad; m for slides), shape (n,): what the controller sees.
        q_true: True joint angles, shape (n,) (read-only view of the simulation).
        qdot: True joint velocities (rad/s), shape (n,) (read-only view).
        tau_joint: Joint torques the motors applied in the last step (N m), shape (n,), after
            the true curve, gear ratio and clip to the joint limits (read-only view).
        geom_xpos, geom_xmat: Every device geom's position (m) and orientation in {0},
            (ngeom, 3) and (ngeom, 9) row-major (read-only views, for display).
        motors_off: The amplifier's watchdog switched the motors off in the last step (no new
            counts for longer than :attr:`DevicePlant.watchdog`).
        watchdog_trips: How many times since the reset the watchdog switched the motors off.
        fault: Why the simulation stopped (:attr:`DevicePlant.fault`), or None.
        time: Simulated time (s).
        status: The link to the device, always :attr:`~app.device.boundary.LinkStatus.OK`: the
            plant is simulated in this process (a :class:`~app.device.boundary.CartesianReading`'s
            guard sets its own).
    """

    status = LinkStatus.OK

    __slots__ = (
        "_T_0_G",
        "_hand",
        "_pose_into",
        "_xmat_G",
        "_xpos_G",
        "fault",
        "geom_xmat",
        "geom_xpos",
        "motors_off",
        "q",
        "q_true",
        "qdot",
        "tau_joint",
        "time",
        "watchdog_trips",
    )

    def __init__(self, plant: DevicePlant) -> None:
        d = plant.data
        n = plant.n_joints
        self.q = np.zeros(n)
        self.q_true = d.qpos[plant.qpos_slice]
        self.qdot = d.qvel[plant.dof_slice]
        self.tau_joint = d.qfrc_applied[plant.dof_slice]
        self.geom_xpos = d.geom_xpos[:]
        self.geom_xmat = d.geom_xmat[:]
        for view in (self.q_true, self.qdot, self.tau_joint, self.geom_xpos, self.geom_xmat):
            view.flags.writeable = False
        self.time = 0.0
        self.motors_off = False
        self.watchdog_trips = 0
        self.fault: str | None = None
        self._hand = plant.hand
        self._xmat_G = d.site_xmat[plant.grip_site_id].reshape(3, 3)
        self._xpos_G = d.site_xpos[plant.grip_site_id]
        self._T_0_G = np.eye(4)
        # Read every tick (the state row, the operators): one compiled copy, ~0.2 us against ~1 us
        # for the two numpy slice assignments.
        self._pose_into = entry_point(_pose_into, self._xmat_G, self._xpos_G, self._T_0_G)

    @property
    def T_0_G(self) -> Array:
        """Pose of the grip {G} in the base {0} at ``q_true``, (4, 4); filled on access (reused array)."""
        self._pose_into(self._xmat_G, self._xpos_G, self._T_0_G)
        return self._T_0_G

    @property
    def wrench_G(self) -> Array:
        """The hand's wrench on the grip ``[f; m]`` (N, N m) at G in {0}, (6,); zero when released."""
        return self._hand.wrench_G()

    def grip_sources(self) -> GripSources:
        """:attr:`T_0_G` and :attr:`wrench_G` as :class:`~app.device.boundary.GripSources`: MuJoCo's
        grip site and the hand's buffers."""
        return GripSources(self._xmat_G, self._xpos_G, *self._hand.wrench_sources())


@njit(cache=True)
def _pose_into(R: Array, p: Array, T: Array) -> None:
    """``T[:3, :3] = R`` (3, 3) and ``T[:3, 3] = p`` (3,); the last row of ``T`` is left as it is."""
    for a in range(3):
        for b in range(3):
            T[a, b] = R[a, b]
        T[a, 3] = p[a]


def _contiguous(ids: tuple[int, ...]) -> slice | None:
    """``ids`` as a slice when they are consecutive, so array reads become cheap views."""
    if ids and list(ids) == list(range(ids[0], ids[0] + len(ids))):
        return slice(ids[0], ids[0] + len(ids))
    return None


class DevicePlant:
    """A simulated FRHC: its own perturbed MuJoCo model, motors, encoders and the operator's hand.

    Args:
        spec: The loaded device (nominal model, motors, ``[plant]`` table).
        hand: Impedance of the operator's hand.
        watchdog: The amplifier's servo watchdog (s): with no new counts for longer than this, the
            motors are switched off until counts arrive again (as on real amplifiers).

    Raises:
        ConfigError: for joints without consecutive qpos/dof slots (the ``[plant]`` table itself,
            :class:`~app.device.spec.PlantParams`, was checked by :func:`~app.device.spec.load_device`).
    """

    #: A joint-space device (:class:`~app.device.boundary.JointDevice`): encoder angles in, counts out.
    kind: Literal["joint"] = "joint"

    def __init__(self, spec: DeviceSpec, hand: HandParams | None = None, watchdog: float = WATCHDOG) -> None:
        if not 0.0 < watchdog <= 1.0:
            raise ValueError(f"watchdog must be in (0, 1] s, got {watchdog}")
        self.spec = spec
        self.watchdog = watchdog
        self._since_counts = 0.0
        self.params = spec.data.plant
        n = spec.n_joints
        self.n_joints = n
        qpos_slice = _contiguous(spec.qpos_ids)
        dof_slice = _contiguous(spec.dof_ids)
        if qpos_slice is None or dof_slice is None:
            raise ConfigError(spec.path, "joints", "the plant needs the joints' qpos/dof slots to be consecutive")
        self.qpos_slice = qpos_slice
        self.dof_slice = dof_slice
        hand_params = hand or HandParams()
        self.model = self._compile(spec, self.params, hand_params)
        self.data = mujoco.MjData(self.model)
        self.grip_site_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, spec.data.grip_site)
        self.hand = OperatorHand(hand_params, self.model, self.data)

        motors = spec.data.motors
        cmax = motors.counts_max
        self._counts_max = int(cmax)
        self._no_counts = np.zeros(0, dtype=np.int64)
        # The true curve is tabulated at every integer count, so a step's motor stage is one gather.
        grid = np.broadcast_to(np.arange(-cmax, cmax + 1, dtype=float)[:, None], (2 * cmax + 1, n))
        gear = np.asarray(motors.gear_ratio)
        limit_joint = gear * np.asarray(motors.torque_limit)
        table = np.clip(true_motor_torque(self.params, motors, grid) * gear, -limit_joint, limit_joint)
        self._table = np.ascontiguousarray(table.T).ravel()
        self._row_offset = np.arange(n, dtype=np.int64) * (2 * cmax + 1) + cmax
        self._tau_out = self.data.qfrc_applied[dof_slice]

        # Quantise every joint or none (a zero resolution anywhere means ideal encoders).
        self._encoders = np.concatenate((spec.encoder_resolution, spec.encoder_step))
        self._mj = np.array((address("mj_step1"), address("mj_step2"), *pointers(self.model, self.data)))
        self.reading = PlantReading(self)
        # The period's arguments after the counts: the plant's own arrays, the same every call.
        r = self.reading
        # MuJoCo's counts of bad joint positions, velocities and accelerations (plant_period).
        w = mujoco.mjtWarning
        unstable = self.data.warning.number[w.mjWARN_BADQPOS : w.mjWARN_BADQACC + 1]
        self._own = (
            self._counts_max,
            self._table,
            self._row_offset,
            self._tau_out,
            self._encoders,
            r.q_true,
            r.q,
            unstable,
        )
        # ``step`` checks the counts, so the compiled period is called without numba's typing.
        self._period = entry_point(plant_period, self._mj, 1, self._no_counts, *self._own)
        self._qfrc_constraint = self.data.qfrc_constraint[dof_slice]
        self._eq0 = self.model.neq - n  # the brakes were appended after the MJCF's own equalities
        self._dt = 0.0
        self._substeps = self.params.substeps
        self.reset()

    @staticmethod
    def _compile(spec: DeviceSpec, params: PlantParams, hand: HandParams) -> mujoco.MjModel:
        """The device MJCF plus the operator's hand, a (disabled) joint brake, and the perturbations."""
        mjspec = mujoco.MjSpec.from_file(str(spec.mjcf_path))
        add_hand(mjspec, spec.data.grip_site, hand)
        for jname in spec.data.joints:
            # The calibration stand's brake: one joint equality per joint, enabled by lock_joints().
            eq = mjspec.add_equality()
            eq.type = mujoco.mjtEq.mjEQ_JOINT
            eq.objtype = mujoco.mjtObj.mjOBJ_JOINT
            eq.name1 = jname
            eq.active = False
            eq.solref = [0.004, 1.0]
        model = mjspec.compile()
        n = spec.n_joints
        # The device's links never touch anything, so collision detection is wasted time.
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        for i, jid in enumerate(spec.joint_ids):
            body = int(model.jnt_bodyid[jid])
            dof = int(model.jnt_dofadr[jid])
            scale = params.per_joint("mass_scale", n)[i]
            model.body_mass[body] *= scale
            model.body_inertia[body] *= scale
            model.dof_frictionloss[dof] += params.per_joint("frictionloss", n)[i]
            model.dof_damping[dof] += params.per_joint("damping", n)[i]
            model.dof_armature[dof] += params.per_joint("armature", n)[i]
        # MuJoCo's default soft friction (impedance 0.9-0.95) lets a joint creep at ~1e-3 rad/s under
        # a load below its friction, so a gravity-compensated device would sag; real drivetrains stick.
        model.dof_solimp[:, :2] = FRICTION_IMPEDANCE
        mujoco.mj_setConst(model, mujoco.MjData(model))  # derived constants (subtree masses...) after the edits
        return model

    @property
    def fault(self) -> str | None:
        """Why the simulated device stopped (None while it runs): its physics went unstable, as a
        real amplifier's fault would stop it. The motors stay off and the encoders hold their last
        reading until :meth:`reset` (also the reading's :attr:`PlantReading.fault`)."""
        return self.reading.fault

    def reset(self, q: Array | None = None) -> PlantReading:
        """Put the device at rest at joint angles ``q`` (rad, (n,); default the device's home pose).

        The hand target and the brakes keep their state.
        """
        d = self.data
        mujoco.mj_resetData(self.model, d)  # its warning counts too
        self.reading.fault = None
        self._since_counts = 0.0
        self.reading.motors_off = False
        self.reading.watchdog_trips = 0
        d.qpos[self.qpos_slice] = self.spec.data.home if q is None else np.asarray(q, dtype=float)
        if self.hand.T_0_H is not None:
            self.hand.set_target(self.hand.T_0_H)  # resetData moved the mocap body home
        mujoco.mj_step1(self.model, d)
        self._read()
        return self.reading

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """The operator grabs the grip and pulls toward ``T_0_H`` (4, 4, base frame); None lets go.

        The next :meth:`step` integrates with the spring lengths computed at the end of the last
        one. Of those, only the hand actuators' depend on the target (qpos has not changed), so
        the hand recomputes the kinematics and the transmissions rather than all of ``mj_step1``:
        a few microseconds instead of ~20 every tick.
        """
        self.hand.set_target(T_0_H)

    def step(self, counts: Counts | None, dt: float) -> PlantReading:
        """Advance one servo period with motor commands held constant.

        Args:
            counts: Integer motor commands (counts), shape (n,); out-of-range values clip to
                ``+-counts_max`` as the amplifier would. None: no new counts this period (the
                controller missed it): the amplifier holds the last ones until its watchdog
                expires, then switches the motors off.
            dt: Servo period (s); the physics takes ``substeps`` steps per 1 ms of it, at least
                ``substeps`` (:func:`~app.mjcall.substeps_for`).

        Returns:
            The reading at the end of the period (the same object every call, overwritten). Once
            the physics went unstable (:attr:`fault`), the reading of that moment, motors off.
        """
        m = self.model
        d = self.data
        if dt != self._dt:
            if not dt > 0:
                raise ValueError(f"dt must be positive, got {dt}")
            self._substeps = substeps_for(dt, self.params.substeps)
            m.opt.timestep = dt / self._substeps
            self._dt = dt
        r = self.reading
        if r.fault is not None:
            return r
        commands = self._no_counts
        if counts is None:
            self._since_counts += dt
            # The relative margin keeps a sum of periods equal to the watchdog from tripping it.
            if self._since_counts > self.watchdog * (1.0 + 1e-9) and not r.motors_off:
                self._tau_out[:] = 0.0
                r.motors_off = True
                r.watchdog_trips += 1
        else:
            ok = (
                counts.__class__ is np.ndarray
                and counts.dtype is I8
                and counts.shape == self._tau_out.shape
                and counts.flags.c_contiguous
            )
            commands = counts if ok else self._checked_counts(counts)  # type: ignore[assignment]
            self._since_counts = 0.0
            r.motors_off = False
        if self._period(self._mj, self._substeps, commands, *self._own):
            r.time = d.time
            return r
        # MuJoCo reset the state, its clock included: the time is the period's end as it would have been.
        r.time += dt
        r.fault = (
            f"the device's simulation went unstable by t = {r.time:.4f} s (MuJoCo: {self._warned()}); "
            "motors off until reset"
        )
        r.motors_off = True
        return r

    def _warned(self) -> str:
        """MuJoCo's warnings so far, as ``name x count`` (for :attr:`fault`)."""
        return ", ".join(f"{name} x {count}" for name, count in self.warnings().items())

    def _checked_counts(self, counts: object) -> IntArray:
        """``counts`` as int64 of shape (n,), or ValueError (a wrong type would compile a new kernel)."""
        c = np.asarray(counts)
        if c.shape != self._tau_out.shape or c.dtype.kind not in "iu":
            raise ValueError(f"counts must be integers of shape {self._tau_out.shape}, got {c.dtype} {c.shape}")
        return np.ascontiguousarray(c, dtype=np.int64)

    def _read(self) -> None:
        """The encoders at the present state, without stepping (after a reset)."""
        self._period(self._mj, 0, self._no_counts, *self._own)
        self.reading.time = self.data.time

    def lock_joints(self, locked: bool) -> None:
        """Calibration stand: brake every joint at its present angle (True) or release (False).

        The brakes are stiff MuJoCo joint-equality constraints; while they hold, the torque each
        joint exerts on its brake is :meth:`brake_torque`.
        """
        for i, adr in enumerate(self.spec.qpos_ids):
            self.model.eq_data[self._eq0 + i, 0] = self.data.qpos[adr]
        self.data.eq_active[self._eq0 :] = locked

    def brake_torque(self) -> Array:
        """Torque (N m; N for slides) each joint exerts on the stand's brakes, shape (n,).

        The reaction in the last physics step: minus the generalised constraint force (brake plus
        friction rows) on the joint's dof. Static only: meaningful once the device has settled.
        """
        return -np.array(self._qfrc_constraint)

    def warnings(self) -> dict[str, int]:
        """MuJoCo's warning counters that are non-zero (name -> count); empty when healthy."""
        return {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(self.data.warning) if int(w.number) > 0}
