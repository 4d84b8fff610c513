"""Device files: ``devices/<name>/device.toml``, its calibration file and the MJCF model it names.

A device file describes one force-reflecting hand controller. The controller reads the
kinematic/inertial model (MJCF), the motors (limits, gear ratios, counts) and the torque
curves; the simulated plant additionally reads the ``[plant]`` table, which describes how
the simulated hardware differs from that model (see :mod:`app.device.plant`). All of it,
``[plant]`` included, is parsed and cross-checked by :func:`load_device`, so ``frhc check``
sees every error ``frhc run`` would. Every field has a physical range
(:class:`~app.config.Range`), shown in ``devices/README.md``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Annotated, Literal

import mujoco
import numpy as np
from numpy.polynomial import polynomial as npoly

from app.config import Checked, Count, Range, deferred_warnings, from_dict, identity_digest, load_toml, require_file
from app.controller.gains import ControllerGains
from app.errors import ConfigError, InvalidField
from app.mjcall import file_warnings, refuse_warned
from app.spatial import Array

DEVICES_DIR = Path(__file__).resolve().parents[2] / "devices"
#: The device used where none is named (the web demo, ``frhc check`` of a scene).
DEFAULT_DEVICE = "kraft"

#: Most actuated joints of a device.
MAX_JOINTS = 32
#: Largest amplifier full scale (counts): a 16-bit DAC. The plant tabulates every count.
MAX_COUNTS = 65535
#: Samples per driving direction at which a calibration curve is checked (plus its turning points).
CURVE_SAMPLES = 2001

PerJoint = tuple[float, ...]


@dataclass(frozen=True)
class MotorSpec(Checked):
    """Motors and drive electronics of every joint (arrays are per joint, in joint order).

    Attributes:
        torque_limit: Peak motor torque (N m, motor shaft side).
        gear_ratio: Joint torque per motor torque (-); joint limit = gear_ratio * torque_limit.
        counts_max: Full-scale command of the motor amplifier DAC (counts); commands clip to +-this.
        counts_per_nm: The manufacturer's linear torque curve (counts per N m of motor torque).
    """

    torque_limit: Annotated[PerJoint, Range(0.0, 1e3, "N m", lo_open=True, name_array=True)]
    gear_ratio: Annotated[PerJoint, Range(0.0, 1e4, lo_open=True, name_array=True)]
    counts_max: Annotated[int, Range(1, MAX_COUNTS, "counts")]
    counts_per_nm: Annotated[PerJoint, Range(0.0, 1e9, "counts/(N m)", lo_open=True, name_array=True)]


@dataclass(frozen=True)
class CalibrationSpec(Checked):
    """Fitted torque-to-counts curves (paper Sec 4.2), per joint and driving direction.

    ``counts = sum_k c[k] * tau**k`` for ``k = 0..5`` with tau the motor torque (N m);
    ``positive`` applies for tau >= 0 and ``negative`` for tau < 0. Shapes (n_joints, 6).
    """

    positive: Annotated[tuple[PerJoint, ...], Range(-1e15, 1e15, "counts/(N m)^k")]
    negative: Annotated[tuple[PerJoint, ...], Range(-1e15, 1e15, "counts/(N m)^k")]

    def validate(self) -> None:
        for name in ("positive", "negative"):
            for i, row in enumerate(getattr(self, name)):
                if len(row) != 6:
                    raise InvalidField(f"{name}[{i}]", f"expected 6 coefficients (5th order), got {len(row)}")

    def check_curves(self, motors: MotorSpec) -> None:
        """Each curve, clipped to +-counts_max, must rise monotonically and keep the torque's sign.

        Checked over the whole torque range the controller commands, ``0..+-torque_limit``
        (motor side), at :data:`CURVE_SAMPLES` points plus the curve's turning points.

        Raises:
            InvalidField: naming ``positive[j]`` or ``negative[j]``.
        """
        cmax = float(motors.counts_max)
        for name, sign in (("positive", 1.0), ("negative", -1.0)):
            for j, row in enumerate(getattr(self, name)):
                limit = motors.torque_limit[j]
                c = np.asarray(row, dtype=float)
                turning = npoly.polyroots(npoly.polyder(c)) if np.any(c[1:]) else np.zeros(0)
                turning = np.abs(turning[np.abs(turning.imag) < 1e-12 * limit].real)
                mag = np.union1d(np.linspace(0.0, limit, CURVE_SAMPLES), turning[turning < limit])
                counts = sign * np.clip(npoly.polyval(sign * mag[1:], c), -cmax, cmax)
                drop = np.diff(counts) < -1e-9 * cmax
                if np.any(drop):
                    k = int(np.argmax(drop)) + 1
                    raise InvalidField(
                        f"{name}[{j}]",
                        f"not monotonic over 0..{sign * limit:+g} N m: it turns back at {sign * mag[k]:+.4g} N m",
                    )
                if np.any(counts < 0):
                    k = int(np.argmax(counts < 0)) + 1
                    raise InvalidField(
                        f"{name}[{j}]",
                        f"reverses the torque's sign: {sign * mag[k]:+.4g} N m gives {sign * counts[k - 1]:+.0f} counts",
                    )


#: Value a per-joint ``[plant]`` field takes for every joint when the table leaves it out (an ideal plant).
_IDEAL = {
    "mass_scale": 1.0,
    "frictionloss": 0.0,
    "damping": 0.0,
    "armature": 0.0,
    "encoder_counts_per_rev": 0,
    "motor_gain_pos": 1.0,
    "motor_gain_neg": 1.0,
    "motor_softening_pos": 0.0,
    "motor_softening_neg": 0.0,
    "motor_deadzone": 0.0,
}
#: Fields of :class:`PlantParams` holding one value per joint.
PER_JOINT_FIELDS = tuple(_IDEAL)
_SOFTENING = Range(-1.0, 0.5, lo_open=True)
_MOTOR_GAIN = Range(0.0, 10.0, lo_open=True)


@dataclass(frozen=True)
class PlantParams(Checked):
    """The ``[plant]`` table of a device file: how the simulated hardware differs from the model.

    Per-joint arrays are in motor (``joints``) order and have one value per joint, or are left out
    (empty) for the ideal value given in brackets.

    Attributes:
        substeps: Physics steps per 1 ms servo period (-); a slower servo takes proportionally more
            (:func:`~app.mjcall.substeps_for`), a faster one this many.
        mass_scale: Factor (-) on the mass and rotational inertia of the link each joint moves [1].
        frictionloss: Coulomb joint friction added to the MJCF's (N m joint side; N for slides) [0].
        damping: Viscous joint damping added to the MJCF's (N m s/rad; N s/m for slides) [0].
        armature: Reflected rotor inertia added to the MJCF's (kg m^2; kg for slides) [0].
        encoder_counts_per_rev: Encoder resolution at the joint (counts per revolution; counts per
            metre for slides); 0 means an ideal, unquantised encoder [0]. All joints or none.
        motor_gain_pos: True motor torque at +full-scale counts, as a fraction of ``torque_limit`` [1].
        motor_gain_neg: The same for -full-scale counts (-) [1].
        motor_softening_pos: Softening k (-) of the true curve for positive counts, in (-1, 0.5] [0].
        motor_softening_neg: The same for negative counts [0].
        motor_deadzone: Amplifier deadzone as a fraction of ``counts_max`` (-), in [0, 0.5) [0].
    """

    substeps: Annotated[int, Range(1, 100)] = 1
    mass_scale: Annotated[PerJoint, Range(0.01, 100.0)] = ()
    frictionloss: Annotated[PerJoint, Range(0.0, 1e3, "N m")] = ()
    damping: Annotated[PerJoint, Range(0.0, 1e3, "N m s/rad")] = ()
    armature: Annotated[PerJoint, Range(0.0, 10.0, "kg m^2")] = ()
    encoder_counts_per_rev: Annotated[tuple[int, ...], Range(0, 2**32, "counts/rev")] = ()
    motor_gain_pos: Annotated[PerJoint, _MOTOR_GAIN] = ()
    motor_gain_neg: Annotated[PerJoint, _MOTOR_GAIN] = ()
    motor_softening_pos: Annotated[PerJoint, _SOFTENING] = ()
    motor_softening_neg: Annotated[PerJoint, _SOFTENING] = ()
    motor_deadzone: Annotated[PerJoint, Range(0.0, 0.5, hi_open=True)] = ()

    def validate(self) -> None:
        cpr = self.encoder_counts_per_rev
        if any(v > 0 for v in cpr) and not all(v > 0 for v in cpr):
            raise InvalidField("encoder_counts_per_rev", "give every joint a resolution, or none")

    def per_joint(self, name: str, n: int) -> Array:
        """Field ``name`` as a float array of shape (n,), with the ideal value when left out."""
        values = getattr(self, name)
        return np.array(values, dtype=float) if values else np.full(n, float(_IDEAL[name]))


@dataclass(frozen=True)
class CartesianSpec(Checked):
    """The ``[cartesian]`` table: the device as its vendor's SDK presents it (``docs/conventions.md``).

    Through this interface the device reports its grip pose {G} in its base {0} and takes a
    wrench at the grip in {0}; its SDK does the kinematics (Eq 1), J^T (Eq 7) and its own gravity
    compensation. The limits are the boundary's (:mod:`app.device.guard`), applied to every
    wrench sent, whatever the controller asked. The vendor's figures for the real device
    (``peak_force`` to ``update_rate``) are each cited in the device's NOTES.md, and left out where
    no source gives them; ``force_limit`` and ``continuous_force`` may not exceed ``peak_force``.

    Attributes:
        force_limit: Largest force magnitude sent to the device (N).
        torque_limit: Largest moment magnitude sent (N m); 0 for a 3-dof-force device, whose
            moments are then never sent.
        ramp_time: Time (s) the wrench takes to ramp from 0 to full after a (re)connect.
        gap_ramp_time: The same after a gap in the stream of a device that stayed connected (s):
            a missed sample or a stalled stream.
        peak_force: The largest force the device renders (N); ``force_limit`` may not exceed it.
        continuous_force: The force it sustains (N), at most ``peak_force``.
        workspace_radius: Radius (m) of the sphere about the SDK's origin the grip reaches.
        position_resolution: The smallest grip displacement the device reports (m).
        update_rate: The rate of the device's own servo loop and state stream (Hz).
    """

    force_limit: Annotated[float, Range(0.0, 1e3, "N", lo_open=True)]
    torque_limit: Annotated[float, Range(0.0, 1e2, "N m")] = 0.0
    ramp_time: Annotated[float, Range(0.0, 10.0, "s")] = 0.5
    gap_ramp_time: Annotated[float, Range(0.0, 10.0, "s")] = 0.05
    peak_force: Annotated[float | None, Range(0.0, 1e3, "N", lo_open=True)] = None
    continuous_force: Annotated[float | None, Range(0.0, 1e3, "N", lo_open=True)] = None
    workspace_radius: Annotated[float | None, Range(0.0, 10.0, "m", lo_open=True)] = None
    position_resolution: Annotated[float | None, Range(0.0, 0.01, "m", lo_open=True)] = None
    update_rate: Annotated[float | None, Range(0.0, 1e5, "Hz", lo_open=True)] = None

    def figures(self) -> str:
        """The limit and the vendor's figures in one line, "?" where not sourced (``frhc check``)."""

        def shown(value: float | None, scale: float, unit: str) -> str:
            return "?" if value is None else f"{value * scale:g} {unit}"

        return (
            f"force limit {self.force_limit:g} N, peak {shown(self.peak_force, 1.0, 'N')}, "
            f"continuous {shown(self.continuous_force, 1.0, 'N')}, "
            f"workspace radius {shown(self.workspace_radius, 1e3, 'mm')}, "
            f"resolution {shown(self.position_resolution, 1e3, 'mm')}, rate {shown(self.update_rate, 1.0, 'Hz')}"
        )

    def validate(self) -> None:
        peak = self.peak_force
        if peak is None:
            return
        if self.force_limit > peak:
            raise InvalidField("force_limit", f"{self.force_limit:g} N is above the device's peak_force {peak:g} N")
        if self.continuous_force is not None and self.continuous_force > peak:
            raise InvalidField(
                "continuous_force", f"{self.continuous_force:g} N is above the device's peak_force {peak:g} N"
            )


@dataclass(frozen=True)
class DeviceFile(Checked):
    """The schema of ``device.toml``; see ``devices/kraft/device.toml`` for a commented example.

    Attributes:
        name: Short name, as used on the command line.
        description: One line for people.
        mjcf: MJCF file (relative to the device file) with the links, joints and sites.
        grip_site: MJCF site of the grip frame {G}.
        wrist_site: MJCF site of the wrist frame {W}, the frame the Jacobian is taken at.
        joints: Names of the actuated MJCF joints, in motor order.
        home: Joint angles (rad) the device starts at.
        motors: Motor and amplifier data.
        calibration: Optional file (relative) holding a :class:`CalibrationSpec`.
        torque_curve: ``"manufacturer"`` (linear) or ``"calibrated"`` (needs ``calibration``).
        gains: Default controller gains for this device.
        plant: How the simulated hardware differs from the model; read by the plant.
        interface: How the servo loop drives the device: ``"joint"`` (encoder angles in, motor
            counts out; the controller does Eq 1 and Eq 7) or ``"cartesian"`` (grip pose in, grip
            wrench out, through the ``cartesian`` table).
        cartesian: The device's Cartesian interface, needed to serve it (``frhc device serve``)
            or to drive it as ``interface = "cartesian"``.
    """

    name: str
    description: str
    mjcf: str
    grip_site: str
    wrist_site: str
    joints: Annotated[tuple[str, ...], Count(1, MAX_JOINTS)]
    home: Annotated[PerJoint, Range(-10.0, 10.0, "rad (m for slides)")]
    motors: MotorSpec
    calibration: str | None = None
    torque_curve: Literal["manufacturer", "calibrated"] = "manufacturer"
    gains: ControllerGains = field(default_factory=ControllerGains)
    plant: PlantParams = field(default_factory=PlantParams)
    interface: Literal["joint", "cartesian"] = "joint"
    cartesian: CartesianSpec | None = None

    def validate(self) -> None:
        if self.interface == "cartesian" and self.cartesian is None:
            raise InvalidField("interface", 'a "cartesian" interface needs a [cartesian] table')
        for i, jname in enumerate(self.joints):
            if jname in self.joints[:i]:
                raise InvalidField(f"joints[{i}]", f"duplicate joint name {jname!r}")


#: The MuJoCo model arrays that make a device's kinematics and dynamics, digested into its
#: :attr:`DeviceSpec.identity` (what the model computes, not how its MJCF is written).
MODEL_ARRAYS = (
    "body_pos",
    "body_quat",
    "body_ipos",
    "body_iquat",
    "body_mass",
    "body_inertia",
    "jnt_type",
    "jnt_pos",
    "jnt_axis",
    "jnt_range",
    "dof_damping",
    "dof_armature",
    "dof_frictionloss",
    "site_pos",
    "site_quat",
)
#: Device-file fields left out of the identity: names, prose, file names (their contents count),
#: and the default gains, which a session overrides (the log's ``mode`` and columns say what ran).
NOT_IDENTITY = ("name", "description", "mjcf", "calibration", "gains")


@dataclass(frozen=True)
class DeviceSpec:
    """A loaded, cross-checked device: the file's data plus its compiled MuJoCo model.

    Attributes:
        path: The device file.
        data: Its parsed contents.
        model: The MuJoCo model compiled from ``data.mjcf`` (the *nominal* model).
        joint_ids: MuJoCo joint ids of ``data.joints``.
        dof_ids: MuJoCo dof addresses of those joints (columns of Jacobians).
        qpos_ids: MuJoCo qpos addresses of those joints.
        calibration: Fitted torque curves, if the device has them.
    """

    path: Path
    data: DeviceFile
    model: mujoco.MjModel
    joint_ids: tuple[int, ...]
    dof_ids: tuple[int, ...]
    qpos_ids: tuple[int, ...]
    calibration: CalibrationSpec | None

    @property
    def name(self) -> str:
        return self.data.name

    @cached_property
    def identity(self) -> str:
        """A digest of the device as simulated and controlled: its file's physical fields (joints,
        home, motors, plant, interface, Cartesian limits; not :data:`NOT_IDENTITY`), its torque
        calibration and its compiled model's :data:`MODEL_ARRAYS` (``"sha256:"`` + 16 hex digits).
        A log keeps it (``device_identity``) so a replay can tell the device it names from the
        one it was run on."""
        fields = {k: v for k, v in dataclasses.asdict(self.data).items() if k not in NOT_IDENTITY}
        calibration = () if self.calibration is None else (self.calibration,)
        return identity_digest(fields, *calibration, *(getattr(self.model, name) for name in MODEL_ARRAYS))

    @property
    def n_joints(self) -> int:
        return len(self.data.joints)

    @property
    def mjcf_path(self) -> Path:
        return self.path.parent / self.data.mjcf

    @property
    def encoder_resolution(self) -> Array:
        """Encoder counts per radian of each hinge (per metre of each slide), (n,); all zero for
        ideal encoders (``plant.encoder_counts_per_rev`` left out, or 0 on any joint)."""
        n = self.n_joints
        cpr = self.data.plant.per_joint("encoder_counts_per_rev", n)
        if not np.all(cpr > 0):
            return np.zeros(n)
        hinge = int(mujoco.mjtJoint.mjJNT_HINGE)
        return np.array(
            [
                c / (2.0 * math.pi) if int(self.model.jnt_type[j]) == hinge else c
                for c, j in zip(cpr, self.joint_ids, strict=True)
            ]
        )

    @property
    def encoder_step(self) -> Array:
        """One encoder count of each joint (rad, or m for slides), (n,); zero for ideal encoders."""
        scale = self.encoder_resolution
        return np.divide(1.0, scale, out=np.zeros_like(scale), where=scale > 0)


def resolve_device_path(name_or_path: str | Path) -> Path:
    """A device name (``"kraft"``) or a path to a ``device.toml`` or its folder."""
    p = Path(name_or_path)
    if p.suffix == ".toml":
        return p
    if p.is_dir():
        return p / "device.toml"
    return DEVICES_DIR / str(name_or_path) / "device.toml"


def available_devices() -> list[str]:
    """Names of the devices shipped in ``devices/``."""
    return sorted(p.parent.name for p in DEVICES_DIR.glob("*/device.toml"))


def load_mjcf(path: Path, source: Path, field_name: str = "mjcf") -> mujoco.MjModel:
    """Compile an MJCF file, turning MuJoCo's errors into :class:`ConfigError`."""
    require_file(path, source, field_name, f"MJCF file not found: {path}")
    try:
        with deferred_warnings(), file_warnings() as warned:
            model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        reason = " ".join(str(exc).split())
        raise ConfigError(source, field_name, f"MuJoCo cannot load {path.name}: {reason}") from None
    refuse_warned(warned, source, field_name)
    return model


def load_device(name_or_path: str | Path) -> DeviceSpec:
    """Load and cross-check a device file and its MJCF.

    Raises:
        ConfigError: naming the file and field, for any malformed or inconsistent entry.
    """
    path = resolve_device_path(name_or_path)
    require_file(path, path, "<file>", f"no such device (shipped devices: {', '.join(available_devices())})")
    return _load_device(path, _folder_stamp(path.parent))


def _folder_stamp(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """Name, modification time (ns) and size of every file in ``folder``: what a device loaded
    from there is kept under (its file, MJCF and calibration sit beside each other; one of them
    elsewhere is not looked at)."""
    with os.scandir(folder) as entries:
        files = [(e.name, e.stat()) for e in entries if e.is_file()]
    return tuple(sorted((name, st.st_mtime_ns, st.st_size) for name, st in files))


@lru_cache(maxsize=16)
def _load_device(path: Path, stamp: tuple[tuple[str, int, int], ...]) -> DeviceSpec:
    """:func:`load_device` of ``path`` with its folder as ``stamp`` describes it: a device is
    loaded once per process while its files are unchanged (~10 ms each time, and every session a
    sweep or an experiment runs loads its device). Shared: nothing changes a loaded device (each
    plant compiles its own model; the nominal model is only read)."""
    data = from_dict(DeviceFile, load_toml(path), path)
    model = load_mjcf(path.parent / data.mjcf, path)
    n = len(data.joints)
    per_joint = [(f"motors.{k}", getattr(data.motors, k)) for k in ("torque_limit", "gear_ratio", "counts_per_nm")]
    per_joint += [("home", data.home)]
    per_joint += [(f"plant.{k}", getattr(data.plant, k)) for k in PER_JOINT_FIELDS if getattr(data.plant, k)]
    for fname, values in per_joint:
        if len(values) != n:
            raise ConfigError(path, fname, f"expected {n} values (one per joint), got {len(values)}")
    joint_ids = []
    for i, jname in enumerate(data.joints):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, jname)
        if jid < 0:
            raise ConfigError(path, f"joints[{i}]", f"unknown joint '{jname}' in {data.mjcf}")
        if int(model.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ConfigError(path, f"joints[{i}]", f"joint '{jname}' must be a hinge or slide joint")
        low, high = (float(v) for v in model.jnt_range[jid])
        if model.jnt_limited[jid] and not low <= data.home[i] <= high:
            raise ConfigError(
                path, f"home[{i}]", f"{data.home[i]:g} is outside joint '{jname}''s range [{low:g}, {high:g}]"
            )
        joint_ids.append(jid)
    for fname in ("grip_site", "wrist_site"):
        sname = getattr(data, fname)
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, sname) < 0:
            raise ConfigError(path, fname, f"unknown site '{sname}' in {data.mjcf}")
    calibration = None
    if data.calibration is not None:
        cal_path = path.parent / data.calibration
        require_file(cal_path, path, "calibration", f"calibration file not found: {cal_path}")
        calibration = from_dict(CalibrationSpec, load_toml(cal_path), cal_path)
        for side in ("positive", "negative"):
            if len(getattr(calibration, side)) != n:
                raise ConfigError(
                    cal_path, side, f"expected {n} rows (one per joint), got {len(getattr(calibration, side))}"
                )
        try:
            calibration.check_curves(data.motors)
        except InvalidField as exc:
            raise ConfigError(cal_path, exc.field, exc.reason) from None
    if data.torque_curve == "calibrated" and calibration is None:
        raise ConfigError(path, "torque_curve", "'calibrated' needs a calibration file")
    return DeviceSpec(
        path=path,
        data=data,
        model=model,
        joint_ids=tuple(joint_ids),
        dof_ids=tuple(int(model.jnt_dofadr[j]) for j in joint_ids),
        qpos_ids=tuple(int(model.jnt_qposadr[j]) for j in joint_ids),
        calibration=calibration,
    )
