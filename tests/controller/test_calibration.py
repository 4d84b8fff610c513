"""Torque curves (Sec 4.2): the fit recovers a known 5th-order curve per driving direction."""

from __future__ import annotations

import numpy as np
import pytest

from app.controller.calibration import TorqueCurve, fit_joint_curves
from app.errors import FrhcError


def test_fit_recovers_known_fifth_order_curves_per_direction() -> None:
    pos_true = np.array([0.0, 4000.0, -300.0, 900.0, -2000.0, 5000.0])
    neg_true = np.array([0.0, 5200.0, 800.0, 100.0, 3000.0, 1000.0])
    tau = np.linspace(-0.4, 0.4, 161)
    counts = np.where(
        tau >= 0, np.polynomial.polynomial.polyval(tau, pos_true), np.polynomial.polynomial.polyval(tau, neg_true)
    )
    pos, neg = fit_joint_curves(tau, counts)
    np.testing.assert_allclose(pos, pos_true, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(neg, neg_true, rtol=1e-6, atol=1e-6)


def test_fit_needs_enough_samples() -> None:
    with pytest.raises(FrhcError, match="need more than 5 samples"):
        fit_joint_curves(np.array([0.0, 0.1, 0.2]), np.array([0.0, 1.0, 2.0]))


def test_curve_uses_the_direction_of_each_torque_and_clips() -> None:
    pos = np.zeros((2, 6))
    neg = np.zeros((2, 6))
    pos[:, 1] = 1000.0
    neg[:, 1] = 3000.0
    curve = TorqueCurve(pos, neg, counts_max=2047)
    np.testing.assert_array_equal(curve.counts(np.array([0.5, -0.5])), [500, -1500])
    np.testing.assert_array_equal(curve.counts(np.array([10.0, -10.0])), [2047, -2047])


def test_linear_manufacturer_curve() -> None:
    curve = TorqueCurve.linear(np.array([5000.0, 20000.0]), counts_max=2047)
    np.testing.assert_array_equal(curve.counts(np.array([0.2, -0.05])), [1000, -1000])
