"""Torque-curve calibration on the plant (paper Sec 4.2) and the 2 N Cartesian test."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from numpy.polynomial import polynomial as npoly

from app.config import from_dict, load_toml
from app.device.calibrate import (
    CalibrationReport,
    calibrate,
    fit_curves,
    measure_joint_curves,
    write_calibration_toml,
)
from app.device.plant import DevicePlant, true_motor_torque
from app.device.spec import DEVICES_DIR, CalibrationSpec, load_device


@pytest.fixture(scope="module")
def kraft_calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[CalibrationReport, Path]:
    """Calibrate a scratch copy of the Kraft device, writing its files there."""
    dest = tmp_path_factory.mktemp("cal") / "kraft"
    shutil.copytree(DEVICES_DIR / "kraft", dest)
    (dest / "calibration.toml").unlink()
    text = (dest / "device.toml").read_text()
    # Start from a file that has never been calibrated, as a new device would.
    text = text.replace('calibration = "calibration.toml"\n', "").replace('"calibrated"', '"manufacturer"')
    (dest / "device.toml").write_text(text)
    return calibrate(dest / "device.toml", write=True), dest / "device.toml"


def test_fitted_curves_invert_the_true_curve(kraft_calibrated: tuple[CalibrationReport, Path]) -> None:
    report, path = kraft_calibrated
    spec = load_device(path)
    plant = DevicePlant(spec)
    motors = spec.data.motors
    limit = np.asarray(motors.torque_limit)
    for sign, coeffs, gain_name in ((1, report.positive, "motor_gain_pos"), (-1, report.negative, "motor_gain_neg")):
        reachable = np.minimum(plant.params.per_joint(gain_name, spec.n_joints), 1.0) * limit
        for j in range(spec.n_joints):
            tau_wanted = sign * np.linspace(0.02, 0.97, 40) * reachable[j]
            counts = np.zeros((tau_wanted.size, spec.n_joints))
            counts[:, j] = np.rint(npoly.polyval(tau_wanted, coeffs[j]))
            tau_true = true_motor_torque(plant.params, motors, counts)[:, j]
            # Within 1 % of the motor's rating over the whole range (the linear curve is off by ~10 %).
            assert np.max(np.abs(tau_true - tau_wanted)) < 0.01 * limit[j], (sign, j)
    assert np.all(report.fit_rms_counts < 10.0)


def test_two_newton_test_force_is_right_only_with_the_fitted_curves(
    kraft_calibrated: tuple[CalibrationReport, Path],
) -> None:
    report, _ = kraft_calibrated
    np.testing.assert_array_equal(report.test_force, [2.0, 0, 0, 0, 0, 0])
    assert report.error_linear > 0.5  # the paper's "feeling was all wrong"
    assert report.error_fitted < 0.1
    assert report.error_fitted < 0.1 * report.error_linear


def test_written_files_load_and_match_the_committed_calibration(
    kraft_calibrated: tuple[CalibrationReport, Path],
) -> None:
    report, path = kraft_calibrated
    spec = load_device(path)
    assert spec.data.torque_curve == "calibrated"
    assert spec.calibration is not None
    np.testing.assert_array_equal(np.array(spec.calibration.positive), report.positive)
    np.testing.assert_array_equal(np.array(spec.calibration.negative), report.negative)
    # The shipped file must be what the shipped plant table produces (re-run calibrate after editing it).
    shipped = load_device("kraft").calibration
    assert shipped is not None
    np.testing.assert_allclose(np.array(shipped.positive), report.positive, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.array(shipped.negative), report.negative, rtol=1e-6, atol=1e-6)


def test_calibration_toml_round_trips_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    positive, negative = rng.normal(size=(3, 6)) * 1e5, rng.normal(size=(3, 6))
    path = tmp_path / "cal.toml"
    write_calibration_toml(path, positive, negative, "test header\nsecond line")
    cal = from_dict(CalibrationSpec, load_toml(path), path)
    np.testing.assert_array_equal(np.array(cal.positive), positive)
    np.testing.assert_array_equal(np.array(cal.negative), negative)


@pytest.mark.parametrize("name", ["jpl", "freflex"])
def test_shipped_calibration_is_current(name: str) -> None:
    """The committed calibration.toml is what the committed [plant] table measures (else re-run calibrate)."""
    spec = load_device(name)
    samples, limits = measure_joint_curves(DevicePlant(spec))
    positive, negative, _ = fit_curves(samples, limits)
    assert spec.calibration is not None
    np.testing.assert_allclose(np.array(spec.calibration.positive), positive, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.array(spec.calibration.negative), negative, rtol=1e-6, atol=1e-6)
