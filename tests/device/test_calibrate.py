"""Torque-curve calibration on the plant (paper Sec 4.2) and the 2 N Cartesian test."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from numpy.polynomial import polynomial as npoly

from app.cli import main
from app.config import from_dict, load_toml
from app.device.calibrate import (
    CalibrationReport,
    calibrate,
    calibration_text,
    fit_curves,
    measure_joint_curves,
)
from app.device.plant import DevicePlant, true_motor_torque
from app.device.spec import DEVICES_DIR, CalibrationSpec, DeviceSpec, load_device


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


def test_a_three_joint_device_reads_its_test_force_as_a_force() -> None:
    """touch3 has three joints: the 2 N along x is read back from its brakes as 2 N along x and no
    moment (before: a minimum-norm wrench over six axes from three torques, 1.6 N of error)."""
    report = calibrate("touch3")
    for measured in (report.force_linear, report.force_fitted):
        np.testing.assert_allclose(measured, [2.0, 0, 0, 0, 0, 0], atol=0.01)


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
    shipped = load_device("kraft")
    assert shipped.calibration is not None
    assert counts_gap(shipped, shipped.calibration, report.positive, report.negative) < MAX_COUNTS_GAP


def test_calibration_toml_round_trips_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    positive, negative = rng.normal(size=(3, 6)) * 1e5, rng.normal(size=(3, 6))
    path = tmp_path / "cal.toml"
    path.write_text(calibration_text(positive, negative, "test header\nsecond line"))
    cal = from_dict(CalibrationSpec, load_toml(path), path)
    np.testing.assert_array_equal(np.array(cal.positive), positive)
    np.testing.assert_array_equal(np.array(cal.negative), negative)


#: Largest difference (counts) between the shipped curves and a fresh calibration over the whole
#: torque range: less than the DAC's quantum. The fitted coefficients themselves are compared no
#: more tightly: a 5th-order fit is ill-conditioned, and MuJoCo releases (3.x to 4.0) moved its
#: coefficients by up to 2e-4 relative while the counts it renders moved by < 0.3.
MAX_COUNTS_GAP = 0.5


def counts_gap(spec: DeviceSpec, stored: CalibrationSpec, positive: np.ndarray, negative: np.ndarray) -> float:
    """Largest |counts| difference between ``stored`` curves and ``positive``/``negative`` ones,
    over each joint's motor torque range in both directions."""
    limits = np.asarray(spec.data.motors.torque_limit)
    gap = 0.0
    for sign, fresh, old in ((1, positive, stored.positive), (-1, negative, stored.negative)):
        for j, limit in enumerate(limits):
            tau = sign * np.linspace(0.0, 1.0, 201) * limit
            gap = max(gap, float(np.max(np.abs(npoly.polyval(tau, fresh[j]) - npoly.polyval(tau, np.asarray(old[j]))))))
    return gap


@pytest.mark.parametrize("name", ["jpl", "freflex"])
def test_shipped_calibration_is_current(name: str) -> None:
    """The committed calibration.toml is what the committed [plant] table measures (else re-run calibrate)."""
    spec = load_device(name)
    samples, limits = measure_joint_curves(DevicePlant(spec))
    positive, negative, _ = fit_curves(samples, limits)
    assert spec.calibration is not None
    assert counts_gap(spec, spec.calibration, positive, negative) < MAX_COUNTS_GAP


def test_a_one_percent_motor_change_makes_the_shipped_calibration_stale(tmp_path: Path) -> None:
    """The check above can fail: 1 % more motor gain on one joint moves its curve by many counts."""
    dest = tmp_path / "jpl"
    shutil.copytree(DEVICES_DIR / "jpl", dest)
    spec = load_device(dest / "device.toml")
    gains = list(DevicePlant(spec).params.per_joint("motor_gain_pos", spec.n_joints))
    gains[0] *= 1.01
    text = (dest / "device.toml").read_text()
    table = "motor_gain_pos = [" + ", ".join(repr(float(g)) for g in gains) + "]\n"
    text = "\n".join(line for line in text.splitlines() if not line.startswith("motor_gain_pos")) + "\n"
    text = text.replace("[plant]\n", "[plant]\n" + table) if "[plant]" in text else text + "[plant]\n" + table
    (dest / "device.toml").write_text(text)
    changed = load_device(dest / "device.toml")
    samples, limits = measure_joint_curves(DevicePlant(changed))
    positive, negative, _ = fit_curves(samples, limits)
    assert changed.calibration is not None
    assert counts_gap(changed, changed.calibration, positive, negative) > 10 * MAX_COUNTS_GAP


def test_a_calibration_that_cannot_be_written_is_one_line_and_changes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``frhc calibrate --write`` into a device folder where ``calibration.toml`` cannot be written
    (here a folder of that name: the same OSError as a read-only folder, which root ignores): one
    line naming the file, exit 2, and the device file as it was. Before: an IsADirectoryError
    traceback."""
    dest = tmp_path / "touch3"
    shutil.copytree(DEVICES_DIR / "touch3", dest)
    (dest / "calibration.toml").mkdir()
    before = (dest / "device.toml").read_text()
    assert main(["calibrate", "--write", str(dest)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [
        f"error: {dest / 'calibration.toml'}: field '--write': cannot write the calibration: Is a directory; "
        "the device's files are unchanged"
    ]
    assert (dest / "device.toml").read_text() == before
    shipped = [p.name for p in (DEVICES_DIR / "touch3").iterdir()]
    assert sorted(p.name for p in dest.iterdir()) == sorted([*shipped, "calibration.toml"])  # no file left over


def test_a_device_file_that_cannot_be_rewritten_keeps_the_old_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The device file cannot be rewritten after the new curves could be: the calibration the
    device file points at is still the old one (before, the new curves were already in its place
    and the device used them while the command said it failed)."""
    dest = tmp_path / "kraft"
    shutil.copytree(DEVICES_DIR / "kraft", dest)
    old = (dest / "calibration.toml").read_text()
    (dest / ".device.toml.tmp").mkdir()  # where the new device file is written first
    assert main(["calibrate", "--write", str(dest / "device.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "cannot write the calibration" in err
    assert (dest / "calibration.toml").read_text() == old
    assert not (dest / ".calibration.toml.tmp").exists()
