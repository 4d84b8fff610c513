"""Device files: ``devices/<name>/device.toml`` and the MJCF model it names.

A device file describes one force-reflecting hand controller. The controller reads the
kinematic/inertial model (MJCF), the motors (limits, gear ratios, counts) and the torque
curves; the simulated plant additionally reads the ``[plant]`` table, which describes how
the simulated hardware differs from that model (see :mod:`app.device.plant`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco

from app.config import from_dict, load_toml
from app.controller.gains import ControllerGains
from app.errors import ConfigError, InvalidField

DEVICES_DIR = Path(__file__).resolve().parents[2] / "devices"


@dataclass(frozen=True)
class MotorSpec:
    """Motors and drive electronics of every joint (arrays are per joint, in joint order).

    Attributes:
        torque_limit: Peak motor torque (N m, motor shaft side).
        gear_ratio: Joint torque per motor torque (-); joint limit = gear_ratio * torque_limit.
        counts_max: Full-scale command of the motor amplifier DAC (counts); commands clip to +-this.
        counts_per_nm: The manufacturer's linear torque curve (counts per N m of motor torque).
    """

    torque_limit: tuple[float, ...]
    gear_ratio: tuple[float, ...]
    counts_max: int
    counts_per_nm: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("torque_limit", "gear_ratio", "counts_per_nm"):
            if any(not (v > 0 and math.isfinite(v)) for v in getattr(self, name)):
                raise InvalidField(name, "values must be positive and finite")
        if self.counts_max <= 0:
            raise InvalidField("counts_max", "must be positive")


@dataclass(frozen=True)
class CalibrationSpec:
    """Fitted torque-to-counts curves (paper Sec 4.2), per joint and driving direction.

    ``counts = sum_k c[k] * tau**k`` for ``k = 0..5`` with tau the motor torque (N m);
    ``positive`` applies for tau >= 0 and ``negative`` for tau < 0. Shapes (n_joints, 6).
    """

    positive: tuple[tuple[float, ...], ...]
    negative: tuple[tuple[float, ...], ...]

    def __post_init__(self) -> None:
        for name in ("positive", "negative"):
            for i, row in enumerate(getattr(self, name)):
                if len(row) != 6:
                    raise InvalidField(f"{name}[{i}]", f"expected 6 coefficients (5th order), got {len(row)}")


@dataclass(frozen=True)
class DeviceFile:
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
    """

    name: str
    description: str
    mjcf: str
    grip_site: str
    wrist_site: str
    joints: tuple[str, ...]
    home: tuple[float, ...]
    motors: MotorSpec
    calibration: str | None = None
    torque_curve: str = "manufacturer"
    gains: ControllerGains = field(default_factory=ControllerGains)
    plant: dict[str, Any] = field(default_factory=dict)


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

    @property
    def n_joints(self) -> int:
        return len(self.data.joints)

    @property
    def mjcf_path(self) -> Path:
        return self.path.parent / self.data.mjcf


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
    if not path.is_file():
        raise ConfigError(source, field_name, f"MJCF file not found: {path}")
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        reason = " ".join(str(exc).split())
        raise ConfigError(source, field_name, f"MuJoCo cannot load {path.name}: {reason}") from None


def load_device(name_or_path: str | Path) -> DeviceSpec:
    """Load and cross-check a device file and its MJCF.

    Raises:
        ConfigError: naming the file and field, for any malformed or inconsistent entry.
    """
    path = resolve_device_path(name_or_path)
    if not path.is_file():
        known = ", ".join(available_devices())
        raise ConfigError(path, "<file>", f"no such device (shipped devices: {known})")
    data = from_dict(DeviceFile, load_toml(path), path)
    model = load_mjcf(path.parent / data.mjcf, path)
    n = len(data.joints)
    for name in ("torque_limit", "gear_ratio", "counts_per_nm"):
        if len(getattr(data.motors, name)) != n:
            raise ConfigError(
                path, f"motors.{name}", f"expected {n} values (one per joint), got {len(getattr(data.motors, name))}"
            )
    if len(data.home) != n:
        raise ConfigError(path, "home", f"expected {n} values (one per joint), got {len(data.home)}")
    joint_ids = []
    for i, jname in enumerate(data.joints):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, jname)
        if jid < 0:
            raise ConfigError(path, f"joints[{i}]", f"unknown joint '{jname}' in {data.mjcf}")
        if int(model.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ConfigError(path, f"joints[{i}]", f"joint '{jname}' must be a hinge or slide joint")
        joint_ids.append(jid)
    for fname in ("grip_site", "wrist_site"):
        sname = getattr(data, fname)
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, sname) < 0:
            raise ConfigError(path, fname, f"unknown site '{sname}' in {data.mjcf}")
    calibration = None
    if data.calibration is not None:
        cal_path = path.parent / data.calibration
        calibration = from_dict(CalibrationSpec, load_toml(cal_path), cal_path)
        for side in ("positive", "negative"):
            if len(getattr(calibration, side)) != n:
                raise ConfigError(
                    cal_path, side, f"expected {n} rows (one per joint), got {len(getattr(calibration, side))}"
                )
    if data.torque_curve not in ("manufacturer", "calibrated"):
        raise ConfigError(path, "torque_curve", "must be 'manufacturer' or 'calibrated'")
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
