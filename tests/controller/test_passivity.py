"""Passivity observer and controller (app.controller.passivity): energy bookkeeping with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.controller.passivity import PassivitySettings, observe_energy, passivity_control
from app.errors import InvalidField

T = 1e-3
INF = float("inf")


def observed(q: np.ndarray, tau_held: np.ndarray) -> np.ndarray:
    """The observer's energy after each step of the trajectory ``q`` (m,) under the held torques (m-1,)."""
    e, out = np.zeros(1), []
    for k in range(1, len(q)):
        out.append(observe_energy(e, tau_held[k - 1 : k], np.array([(q[k] - q[k - 1]) / T]), T, INF))
    return np.array(out)


trajectories = arrays(np.float64, st.integers(3, 60), elements=st.floats(-0.05, 0.05))


@settings(max_examples=60, deadline=None)
@given(q=trajectories, k=st.floats(0.0, 1e4), b=st.floats(0.0, 50.0))
def test_a_passive_spring_damper_port_observes_exactly_its_stored_plus_dissipated_energy(
    q: np.ndarray, k: float, b: float
) -> None:
    """Spring at the interval's midpoint (energy-conserving) and a damper on the interval's
    velocity: E_n = k/2 (q_n^2 - q_0^2) + b/T sum dq^2, which is >= 0 when starting at rest at 0."""
    q = np.concatenate(([0.0], q))
    dq = np.diff(q)
    tau = -k * 0.5 * (q[:-1] + q[1:]) - b * dq / T
    e = observed(q, tau)
    expected = 0.5 * k * q[1:] ** 2 + (b / T) * np.cumsum(dq**2)
    np.testing.assert_allclose(e, expected, rtol=1e-9, atol=1e-12)
    assert e.min() >= -1e-12


def test_an_active_sampled_spring_is_detected_and_the_pc_makes_it_decay() -> None:
    """A 1-dof mass (no physical damping) on a sampled spring K (zero-order hold) with a little
    virtual damping B, started moving from the spring's rest point: far beyond K = 2B/T
    (Colgate's bound) it oscillates with growing amplitude and the observer's energy goes
    negative; with the PC the motion decays."""

    def run(K: float, B: float, pc: bool) -> tuple[float, float]:
        m, x, v = 0.01, 0.0, 0.1
        e, tau_prev, tau_pc, vel = np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1)
        x_prev, lowest, amplitude = x, 0.0, 0.0
        for i in range(4000):
            vel[0] = (x - x_prev) / T if i else 0.0
            observe_energy(e, tau_prev, vel, T, INF)
            lowest = min(lowest, e[0])
            tau = np.array([-K * x - B * vel[0]])
            if pc:
                passivity_control(e, tau.copy(), vel, T, 0.0, 1e6, np.array([1e9]), tau, tau_pc)
            tau_prev[:] = tau
            x_prev = x
            for _ in range(20):  # the continuous mass under the held torque
                v += tau[0] / m * (T / 20)
                x += v * (T / 20)
            amplitude = max(amplitude, abs(x)) if i > 3000 else 0.0
        return lowest, amplitude

    start = 0.1 / np.sqrt(4000.0 / 0.01)  # the amplitude of the undamped continuous oscillation
    lowest, growing = run(4000.0, 0.5, pc=False)  # 2B/T = 1000 N/m
    assert lowest < -1e-4
    assert growing > 2 * start
    _lowest_pc, amplitude_pc = run(4000.0, 0.5, pc=True)
    assert amplitude_pc < 0.5 * start  # the PC took the excess out: it decays


@settings(max_examples=200, deadline=None)
@given(
    energy=arrays(np.float64, 4, elements=st.floats(-10.0, 10.0)),
    tau_r=arrays(np.float64, 4, elements=st.floats(-5.0, 5.0)),
    tau_g=arrays(np.float64, 4, elements=st.floats(-2.0, 2.0)),
    qdot=arrays(np.float64, 4, elements=st.floats(-20.0, 20.0)),
    max_damping=st.floats(0.0, 100.0),
)
def test_the_pc_only_dissipates_and_stays_within_the_limits(
    energy: np.ndarray, tau_r: np.ndarray, tau_g: np.ndarray, qdot: np.ndarray, max_damping: float
) -> None:
    limit = np.full(4, 6.0)
    tau = tau_r + tau_g
    tau_pc = np.zeros(4)
    alpha = passivity_control(energy, tau_r, qdot, T, 1e-3, max_damping, limit, tau, tau_pc)
    np.testing.assert_allclose(tau, tau_r + tau_g + tau_pc)
    assert np.all(tau_pc * qdot <= 0.0)  # never adds energy on the velocity it damps
    within = np.abs(tau_r + tau_g) <= limit
    assert np.all(np.abs(tau[within]) <= limit[within] + 1e-12)
    assert 0.0 <= alpha <= max_damping + 1e-9
    # Unclipped, it dissipates exactly the predicted excess: the energy after the tick is 0.
    predicted = energy - T * tau_r * qdot
    free = (predicted < 0) & (np.abs(qdot) > 1e-3) & (np.abs(tau) < limit - 1e-9)
    free &= np.abs(tau_pc) < max_damping * np.abs(qdot) - 1e-9
    np.testing.assert_allclose((predicted - T * tau_pc * qdot)[free], 0.0, atol=1e-9)
    assert np.all(tau_pc[predicted >= 0] == 0.0)


@pytest.mark.parametrize(
    ("field", "value"),
    [("max_torque_fraction", 0.0), ("energy_cap", -1.0), ("min_speed", float("nan")), ("max_damping", 1e9)],
)
def test_settings_outside_their_ranges_are_refused_naming_the_field(field: str, value: float) -> None:
    with pytest.raises(InvalidField) as exc:
        PassivitySettings(**{field: value})
    assert exc.value.field == field
