"""Properties of the assist laws (Eq 8-11) and the saturation of Sec 3.4."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from app.controller.assist import constant_force_rtc, damping, deadband, saturate

dx_s = st.floats(-5.0, 5.0, allow_nan=False)
pos = st.floats(1e-3, 100.0)


@given(dx_s, pos, st.floats(0.0, 0.5), st.floats(0.5, 3.0), st.floats(0.0, 100.0))
def test_cfrtc_is_odd(dx, a, db, wall, k_wall) -> None:
    assert constant_force_rtc(-dx, a, db, wall, k_wall) == -constant_force_rtc(dx, a, db, wall, k_wall)


@given(dx_s, pos, st.floats(1e-3, 0.5))
def test_cfrtc_points_back_to_centre_and_is_bounded_without_wall(dx, a, db) -> None:
    f = constant_force_rtc(dx, a, db, math.inf, 0.0)
    assert f * dx <= 0.0
    assert abs(f) <= a * db * db * (1 + 1e-12)


@given(dx_s, pos, st.floats(1e-3, 0.5), st.floats(0.5, 3.0), st.floats(0.0, 100.0))
def test_cfrtc_is_continuous(dx, a, db, wall, k_wall) -> None:
    """No step anywhere, including the deadband edge and the wall start: Lipschitz in dx."""
    h = 1e-7
    lipschitz = 2 * a * db + k_wall
    assert abs(constant_force_rtc(dx + h, a, db, wall, k_wall) - constant_force_rtc(dx, a, db, wall, k_wall)) <= (
        lipschitz * h * 1.0001 + 1e-12
    )


def test_cfrtc_zones_have_the_papers_values() -> None:
    a, db, wall, k = 1e4, 0.01, 0.1, 500.0
    assert constant_force_rtc(0.005, a, db, wall, k) == -a * 0.005**2  # parabolic deadband wall
    assert constant_force_rtc(0.05, a, db, wall, k) == -a * db**2  # constant force: 1 N
    assert math.isclose(constant_force_rtc(0.12, a, db, wall, k), -(a * db**2 + k * 0.02))  # stiff wall
    assert constant_force_rtc(0.0, a, db, wall, k) == 0.0


@given(dx_s, st.floats(0.0, 0.5))
def test_deadband_channel(dx, db) -> None:
    """Zero inside; outside, Delta X minus sign * deadband: continuous and odd."""
    out = deadband(dx, db)
    if abs(dx) <= db:
        assert out == 0.0
    else:
        assert math.isclose(out, dx - math.copysign(db, dx), abs_tol=1e-15)
    assert deadband(-dx, db) == -out
    assert abs(deadband(dx + 1e-9, db) - out) <= 1e-9 * 1.0001


@given(st.floats(-1.0, 1.0), st.sampled_from([1e-4, 5e-4, 1e-3, 2e-3]))
def test_damping_gain_means_the_same_at_any_rate(velocity, dt) -> None:
    """The same grip velocity gives the same damping force at any servo period."""
    f = damping(0.1 + velocity * dt, 0.1, 3.0, dt, angular=False)
    assert math.isclose(f, -3.0 * velocity, rel_tol=1e-6, abs_tol=1e-9)


def test_damping_wraps_angles() -> None:
    """An angle stepping from +pi - 0.01 to -pi + 0.01 moved +0.02 rad, not -2 pi."""
    f = damping(-math.pi + 0.01, math.pi - 0.01, 1.0, 1.0, angular=True)
    assert math.isclose(f, -0.02, abs_tol=1e-12)


big = st.floats(-1e300, 1e300, allow_nan=False)


@given(st.lists(big, min_size=6, max_size=6), st.lists(st.floats(0.01, 100.0), min_size=6, max_size=6))
def test_saturation_never_exceeds_and_keeps_direction(tau, limit) -> None:
    out = np.empty(6)
    s = saturate(np.array(tau), np.array(limit), out)
    assert all(abs(o) <= lim for o, lim in zip(out, limit, strict=True))
    assert 0.0 < s <= 1.0
    # Direction kept: out is a positive multiple of tau (compare unit vectors, scaled first
    # by the largest entry so the norms of 1e300-sized vectors do not overflow).
    t = np.array(tau)
    o = np.array(out)
    if np.abs(t).max() > 0:
        t = t / np.abs(t).max()
        o = o / np.abs(o).max()
        np.testing.assert_allclose(o / np.linalg.norm(o), t / np.linalg.norm(t), atol=1e-9)


def test_saturation_of_huge_command_hits_the_binding_limit() -> None:
    out = np.empty(6)
    s = saturate(np.array([1e9, -5e8, 0, 0, 0, 0]), np.array([2.0, 2.0, 1, 1, 1, 1]), out)
    assert out[0] == 2.0
    assert math.isclose(out[1], -1.0)
    assert math.isclose(s, 2e-9)
