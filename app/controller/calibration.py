"""Torque-to-counts curves (paper Sec 3.4, 4.2): the manufacturer's line or fitted polynomials.

The paper found the manufacturer's linear torque curves made simple Cartesian test forces
feel "all wrong" and replaced them by a 5th-order least-squares polynomial per joint and per
driving direction. :func:`fit_torque_curve` does that fit; :class:`TorqueCurve` evaluates
either kind in the servo tick.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.polynomial import polynomial as npoly

from app.device.spec import CalibrationSpec, DeviceSpec
from app.errors import FrhcError
from app.spatial import Array, IntArray

DEGREE = 5


def fit_torque_curve(tau_motor: Array, counts: Array, degree: int = DEGREE) -> Array:
    """Least-squares polynomial ``counts = sum_k c_k tau^k`` for one joint and direction.

    Args:
        tau_motor: Measured motor torques (N m), shape (m,), all of one sign.
        counts: The counts commanded for each measurement, shape (m,).
        degree: Polynomial order (the paper: 5).

    Returns:
        Coefficients ``c_0 .. c_degree`` (lowest order first), shape (degree + 1,).
    """
    if len(tau_motor) <= degree:
        raise FrhcError(f"need more than {degree} samples to fit a degree-{degree} curve, got {len(tau_motor)}")
    return np.asarray(npoly.polyfit(tau_motor, counts, degree), dtype=float)


def fit_joint_curves(tau_motor: Array, counts: Array, degree: int = DEGREE) -> tuple[Array, Array]:
    """Fit one curve per driving direction from a sweep through both signs.

    Samples with ``tau >= 0`` fit the positive curve and ``tau < 0`` the negative one; the
    sample at zero torque goes to both so each curve is anchored at the origin.

    Returns:
        ``(positive, negative)`` coefficient vectors, each (degree + 1,).
    """
    pos = tau_motor >= 0
    neg = tau_motor <= 0
    return fit_torque_curve(tau_motor[pos], counts[pos], degree), fit_torque_curve(tau_motor[neg], counts[neg], degree)


@njit(cache=True)
def curve_counts(tau_motor: Array, horner_pos: Array, horner_neg: Array, counts_max: int, out: IntArray) -> IntArray:
    """Counts for motor torques ``tau_motor`` (N m), (n,), into ``out`` (int, (n,)), rounded and clipped.

    ``horner_pos``/``horner_neg`` (n, k) are each joint's coefficients, highest order first, for
    torques >= 0 and < 0 (the driving direction picks the curve, as the paper's Sec 4.2 fits).
    Zero torque is always zero counts: a fitted curve's constant term (deadzone compensation)
    must not drive a motor that is asked for nothing.
    """
    for j in range(tau_motor.shape[0]):
        tau = tau_motor[j]
        if tau == 0.0:
            out[j] = 0
            continue
        c = horner_pos[j] if tau >= 0.0 else horner_neg[j]
        acc = 0.0
        for k in range(c.shape[0]):
            acc = acc * tau + c[k]
        out[j] = min(counts_max, max(-counts_max, round(acc)))
    return out


class TorqueCurve:
    """Maps motor torques (N m) of every joint to amplifier counts, per driving direction.

    Attributes:
        positive: Coefficients for ``tau >= 0``, shape (n, 6), lowest order first.
        negative: Coefficients for ``tau < 0``, shape (n, 6).
        counts_max: Counts clip to ``[-counts_max, counts_max]``.
    """

    def __init__(self, positive: Array, negative: Array, counts_max: int) -> None:
        self.positive = np.asarray(positive, dtype=float)
        self.negative = np.asarray(negative, dtype=float)
        self.counts_max = counts_max
        # Horner's scheme runs from the highest order down.
        self.horner_pos = np.ascontiguousarray(self.positive[:, ::-1])
        self.horner_neg = np.ascontiguousarray(self.negative[:, ::-1])

    @classmethod
    def linear(cls, counts_per_nm: Array, counts_max: int) -> TorqueCurve:
        """The manufacturer's linear curve ``counts = k tau``, same in both directions."""
        k = np.asarray(counts_per_nm, dtype=float)
        coeffs = np.zeros((k.size, DEGREE + 1))
        coeffs[:, 1] = k
        return cls(coeffs, coeffs, counts_max)

    @classmethod
    def from_calibration(cls, cal: CalibrationSpec, counts_max: int) -> TorqueCurve:
        return cls(np.array(cal.positive), np.array(cal.negative), counts_max)

    @classmethod
    def for_device(cls, spec: DeviceSpec) -> TorqueCurve:
        """The curve the device file selects with ``torque_curve``."""
        motors = spec.data.motors
        if spec.data.torque_curve == "calibrated" and spec.calibration is not None:
            return cls.from_calibration(spec.calibration, motors.counts_max)
        return cls.linear(np.array(motors.counts_per_nm), motors.counts_max)

    def counts(self, tau_motor: Array) -> IntArray:
        """Counts (int64, rounded, clipped to +-counts_max) for motor torques ``tau_motor`` (N m), (n,)."""
        out = np.zeros(len(tau_motor), dtype=np.int64)
        return curve_counts(np.asarray(tau_motor, dtype=float), self.horner_pos, self.horner_neg, self.counts_max, out)
