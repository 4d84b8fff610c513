"""Torque-curve calibration on the simulated device (paper Sec 4.2, Fig. 5).

The paper's Kraft master felt "all wrong" with the manufacturer's linear torque curves, so the
author measured torque against counts for every joint in both driving directions and fitted a
5th-order least-squares polynomial to each. This module does the same on the plant:

1. Put the device on a test stand: brake every joint at the home pose (:meth:`DevicePlant.lock_joints`).
2. Tare: with zero counts, record the torque each joint exerts on its brake (gravity, mostly).
3. For each joint and each direction, step the counts from 0 to full scale; after the device has
   settled, the brake torque minus the tare is the joint torque the motor produced; divided by the
   gear ratio it is the motor torque. Only brake reactions are read -- never the plant's curve.
4. Fit ``counts = sum c_k tau_motor^k`` per joint and direction (deadzone and saturated samples
   excluded: they carry no torque information) and write ``calibration.toml``.

The demonstration (the paper's "simple 1-dof Cartesian test task force"): command 2 N along x at
the grip through ``tau = J_G^T F`` and the nominal model, convert to counts with the linear and
with the fitted curves, and measure the force the grip actually produces from the brake reactions
(``F = (J_G^T)^+ tau_measured``).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
import re
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from app.controller.calibration import DEGREE, TorqueCurve, fit_torque_curve
from app.device.plant import Counts, DevicePlant
from app.device.spec import DeviceSpec, available_devices, load_device, resolve_device_path
from app.errors import ConfigError
from app.spatial import Array

DT = 0.001  # s, servo period of the stand
SETTLE_STEPS = 150  # steps (s * 1000) for the braked device to come to rest after a change of counts
SWEEP_POINTS = 40  # count levels per joint and direction, 0 excluded
TEST_FORCE_G = np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # N, N m: the 1-dof Cartesian test wrench, {0} axes


@dataclass(frozen=True)
class CalibrationReport:
    """Result of :func:`calibrate`.

    Attributes:
        device: Device name.
        positive: Fitted coefficients for tau >= 0, (n, 6), lowest order first (counts per N m^k).
        negative: The same for tau < 0, (n, 6).
        fit_rms_counts: RMS residual of the fits per joint (counts), (n,), both directions pooled.
        test_force: The commanded grip wrench ``[f; m]`` (N, N m) in {0}, (6,).
        force_linear: Wrench measured with the manufacturer's linear curve, (6,).
        force_fitted: Wrench measured with the fitted curves, (6,).
        written: The calibration file written, or None.
    """

    device: str
    positive: Array
    negative: Array
    fit_rms_counts: Array
    test_force: Array
    force_linear: Array
    force_fitted: Array
    written: Path | None

    @property
    def error_linear(self) -> float:
        """Force error (N) of the linear curve: norm of the force part of measured - commanded."""
        return float(np.linalg.norm(self.force_linear[:3] - self.test_force[:3]))

    @property
    def error_fitted(self) -> float:
        """Force error (N) of the fitted curves."""
        return float(np.linalg.norm(self.force_fitted[:3] - self.test_force[:3]))

    def __str__(self) -> str:
        fmt = np.array2string
        return "\n".join(
            [
                f"device {self.device}: fit RMS residual (counts) per joint {fmt(self.fit_rms_counts, precision=2)}",
                "  2 N test force along x at the grip, measured from brake reactions:",
                f"    linear curve : f = {fmt(self.force_linear[:3], precision=3)} N, error {self.error_linear:.3f} N",
                f"    fitted curves: f = {fmt(self.force_fitted[:3], precision=3)} N, error {self.error_fitted:.3f} N",
                f"  written: {self.written}" if self.written else "  (not written)",
            ]
        )


def _settle(plant: DevicePlant, counts: Counts) -> Array:
    for _ in range(SETTLE_STEPS):
        plant.step(counts, DT)
    return plant.brake_torque()


def measure_joint_curves(plant: DevicePlant) -> tuple[list[tuple[Array, Array]], Array]:
    """Sweep every joint's counts on the braked stand at the home pose.

    Returns:
        Per joint ``(counts, tau_motor)`` samples (counts, N m), each (2 * SWEEP_POINTS,), and the
        joint-torque limits (N m), (n,), used to recognise saturated samples.
    """
    spec = plant.spec
    n = spec.n_joints
    motors = spec.data.motors
    gear = np.asarray(motors.gear_ratio)
    plant.set_hand_target(None)
    plant.reset()
    plant.lock_joints(True)
    zero = np.zeros(n, dtype=np.int64)
    tare = _settle(plant, zero)
    # Denser at small counts, where the deadzone edge sets the curve's offset and small forces live.
    levels = np.unique(np.rint(motors.counts_max * np.linspace(0, 1, SWEEP_POINTS + 1)[1:] ** 1.5).astype(np.int64))
    samples = []
    for j in range(n):
        cs = np.concatenate([levels, -levels])
        taus = np.empty(cs.size)
        for k, c in enumerate(cs):
            counts = zero.copy()
            counts[j] = c
            taus[k] = (_settle(plant, counts)[j] - tare[j]) / gear[j]
        samples.append((cs, taus))
    plant.lock_joints(False)
    return samples, np.asarray(motors.torque_limit)


def fit_curves(samples: list[tuple[Array, Array]], torque_limit: Array) -> tuple[Array, Array, Array]:
    """Fit the 5th-order curves from :func:`measure_joint_curves` samples.

    Samples inside the deadzone (|tau| below 0.2 % of the limit) and in saturation (within 0.2 % of
    the largest torque measured in that direction, where more counts give no more torque) are left
    out: both would make counts a non-function of torque.

    Returns:
        ``positive`` (n, 6), ``negative`` (n, 6) coefficients and the RMS residual (counts), (n,).
    """
    n = len(samples)
    positive = np.zeros((n, DEGREE + 1))
    negative = np.zeros((n, DEGREE + 1))
    rms = np.zeros(n)
    for j, (cs, taus) in enumerate(samples):
        residuals = []
        for sign, out in ((1.0, positive), (-1.0, negative)):
            t = sign * taus
            peak = t.max()
            keep = (sign * cs > 0) & (t > 2e-3 * torque_limit[j]) & (t < peak - 2e-3 * torque_limit[j])
            # Keep the first sample that reached the peak: the curve's end point.
            first_peak = np.flatnonzero((sign * cs > 0) & (t >= peak - 2e-3 * torque_limit[j]))[0]
            keep[first_peak] = True
            out[j] = fit_torque_curve(taus[keep], cs[keep].astype(float))
            residuals.append(np.polynomial.polynomial.polyval(taus[keep], out[j]) - cs[keep])
        rms[j] = float(np.sqrt(np.mean(np.concatenate(residuals) ** 2)))
    return positive, negative, rms


def grip_jacobian(spec: DeviceSpec, q: Array) -> Array:
    """Jacobian of the grip site {G} in base {0} coordinates on the *nominal* model, (6, n) [v; w]."""
    model = spec.model
    data = mujoco.MjData(model)
    data.qpos[list(spec.qpos_ids)] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, spec.data.grip_site)
    jac = np.zeros((6, model.nv))
    mujoco.mj_jacSite(model, data, jac[:3], jac[3:], site)
    return jac[:, list(spec.dof_ids)]


def measure_grip_wrench(plant: DevicePlant, curve: TorqueCurve, F_G: Array) -> Array:
    """Command wrench ``F_G`` (N, N m; at G, {0} axes, (6,)) on the braked stand; measure what the motors produce.

    The counts come from ``tau = J_G^T F_G`` on the nominal model at the home pose and ``curve``;
    the produced wrench is the least-squares ``(J_G^T)^+ (tau_brake - tau_tare)``. A device with
    fewer than six joints whose grip's linear Jacobian has full column rank (a 3-dof positional
    device: Touch, Falcon) renders forces only, so its wrench is solved from that block with zero
    moments: the minimum-norm solution over all six axes would spread the torques over forces and
    moments that the device cannot tell apart (it read 1.6 N of error on 2 N on touch3).
    """
    spec = plant.spec
    q = np.asarray(spec.data.home)
    J_G = grip_jacobian(spec, q)
    tau_motor = (J_G.T @ F_G) / np.asarray(spec.data.motors.gear_ratio)
    counts = np.array(curve.counts(tau_motor.tolist()), dtype=np.int64)
    plant.set_hand_target(None)
    plant.reset(q)
    plant.lock_joints(True)
    tare = _settle(plant, np.zeros(spec.n_joints, dtype=np.int64))
    tau_measured = _settle(plant, counts) - tare
    plant.lock_joints(False)
    n = spec.n_joints
    if n < 6 and np.linalg.matrix_rank(J_G[:3]) == n:
        wrench = np.zeros(6)
        wrench[:3] = np.linalg.lstsq(J_G[:3].T, tau_measured, rcond=None)[0]
        return wrench
    return np.asarray(np.linalg.lstsq(J_G.T, tau_measured, rcond=None)[0], dtype=float)


def _fmt_rows(rows: Array) -> str:
    lines = ",\n".join("  [" + ", ".join(repr(float(v)) for v in row) + "]" for row in rows)
    return f"[\n{lines},\n]"


def calibration_text(positive: Array, negative: Array, header: str) -> str:
    """A :class:`~app.device.spec.CalibrationSpec` file's text: ``positive``/``negative`` (n, 6)."""
    comment = "".join(f"# {line}\n" for line in header.splitlines())
    return f"{comment}positive = {_fmt_rows(positive)}\nnegative = {_fmt_rows(negative)}\n"


def pointed_at(device_text: str, calibration_name: str) -> str:
    """``device_text`` (a ``device.toml``) with ``calibration = ...`` and ``torque_curve =
    "calibrated"`` set in its top table."""
    head, sep, tail = device_text.partition("\n[")
    head = re.sub(r"(?m)^calibration\s*=.*\n", "", head)
    head = re.sub(r"(?m)^torque_curve\s*=.*$", 'torque_curve = "calibrated"', head)
    if "torque_curve" not in head:
        head = head.rstrip("\n") + '\ntorque_curve = "calibrated"\n'
    head = re.sub(r'(?m)^(torque_curve = "calibrated")$', rf'\1\ncalibration = "{calibration_name}"', head)
    return head + sep + tail


def replace_together(texts: dict[Path, str]) -> None:
    """Write every file of ``texts`` (path -> text) or none: each goes to a temporary file beside
    it first, and only once all are written are they renamed into place.

    Raises:
        ConfigError: A file could not be written (a read-only folder, a folder in the way, a full
            disk), naming it and field ``--write``; no file of ``texts`` was changed.
    """
    written: list[Path] = []
    try:
        for path, text in texts.items():
            if path.is_dir():  # the rename would fail, after the files before it were replaced
                raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_text(text)
            written.append(tmp)
        for tmp, path in zip(written, texts, strict=True):
            os.replace(tmp, path)
    except OSError as exc:
        for tmp in written:
            with contextlib.suppress(OSError):
                tmp.unlink()
        reason = exc.strerror or str(exc)
        raise ConfigError(
            exc.filename or "<device>",
            "--write",
            f"cannot write the calibration: {reason}; the device's files are unchanged",
        ) from None


def calibrate(device: str | Path, write: bool = False) -> CalibrationReport:
    """Calibrate a device's torque curves on its simulated plant and run the 2 N demonstration.

    Args:
        device: Device name (``"kraft"``) or path to its ``device.toml`` / folder.
        write: Write ``calibration.toml`` next to the device file and point the device file at it
            (``torque_curve = "calibrated"``).
    """
    spec = load_device(device)
    plant = DevicePlant(spec)
    samples, limits = measure_joint_curves(plant)
    positive, negative, rms = fit_curves(samples, limits)
    motors = spec.data.motors
    force_linear = measure_grip_wrench(
        plant, TorqueCurve.linear(np.array(motors.counts_per_nm), motors.counts_max), TEST_FORCE_G
    )
    force_fitted = measure_grip_wrench(plant, TorqueCurve(positive, negative, motors.counts_max), TEST_FORCE_G)
    written = None
    if write:
        written = spec.path.parent / "calibration.toml"
        header = (
            f"Torque-to-counts calibration of '{spec.name}' (paper Sec 4.2), written by app.device.calibrate.\n"
            "counts = sum_k c[k] * tau_motor**k (tau_motor in N m), one row per joint in joint order;\n"
            "'positive' applies for tau >= 0, 'negative' for tau < 0. Measured on the simulated plant."
        )
        device_toml = resolve_device_path(device)
        replace_together(
            {
                written: calibration_text(positive, negative, header),
                device_toml: pointed_at(device_toml.read_text(), written.name),
            }
        )
    return CalibrationReport(
        spec.name, positive, negative, rms, TEST_FORCE_G.copy(), force_linear, force_fitted, written
    )


def main(argv: list[str] | None = None) -> None:
    """``python -m app.device.calibrate [--write] [device ...]`` (default: every shipped device)."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("devices", nargs="*", help="device names or paths (default: all shipped devices)")
    parser.add_argument("--write", action="store_true", help="write calibration.toml and update device.toml")
    args = parser.parse_args(argv)
    for device in args.devices or available_devices():
        print(calibrate(device, write=args.write))


if __name__ == "__main__":
    main()
