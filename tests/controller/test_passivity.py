"""Passivity observer and controller (app.controller.passivity): energy bookkeeping with known answers."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.controller.passivity import (
    SWING_SHARE,
    PassivitySettings,
    coupling_hold,
    crossed_edge,
    device_dissipation,
    observe_energy,
    passivity_control,
)
from app.device.spec import load_device
from app.errors import InvalidField
from app.session.stability import RELEASED, grip_damping

T = 1e-3
INF = float("inf")
#: The observer's device credit left out (friction, damping, count of one joint): the motors' port alone.
NO_DEVICE = (np.zeros(1), np.zeros(1), np.zeros(1))


def start(q0: np.ndarray) -> np.ndarray:
    """The observer's own angle at the first reading ``q0``: the reading."""
    return q0.astype(float).copy()


def observe(
    e: np.ndarray,
    tau_prev: np.ndarray,
    q: np.ndarray,
    state: np.ndarray,
    qdot: np.ndarray,
    cap: float = INF,
    device: tuple[np.ndarray, np.ndarray, np.ndarray] = NO_DEVICE,
    run: np.ndarray | None = None,
    swing: float = 0.0,
) -> float:
    """One observer step at encoder angles ``q`` (``state`` from :func:`start`, updated; ``run``
    the joints' swing counts, updated, needed with a ``swing`` share)."""
    run = np.zeros_like(state) if run is None else run
    return observe_energy(e, tau_prev, q, state, qdot, T, cap, *device, run, swing)


def observed(q: np.ndarray, tau_held: np.ndarray) -> np.ndarray:
    """The observer's energy after each step of the trajectory ``q`` (m,) under the held torques (m-1,)."""
    e, out, state = np.zeros(1), [], start(q[0:1])
    for k in range(1, len(q)):
        out.append(observe(e, tau_held[k - 1 : k], q[k : k + 1], state, np.array([(q[k] - q[k - 1]) / T])))
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


def test_the_observer_credits_the_device_friction_per_count_and_its_damping_beyond_one_count() -> None:
    """One joint, no torque, friction 0.06 N m, damping 0.04 N m s/rad, counts of 1 mrad, starting
    at the middle of count 0: entering count 1 puts the observed angle on their edge, half a
    count on, credited its friction only (the true motion may have been any fraction of a count,
    so damping is sure of nothing); three counts back in one tick (to count -2) move it two
    counts, to the edge of count -2 it crossed, and add the damping's least dissipation over the
    two sure counts, d (2 mrad)^2 / T; back into count -1 under 2 N m it crosses that same edge
    again: the angle stays, no work and no friction; a torque's work over a count of travel still
    counts; the cap still bounds the bank."""
    device = np.array([0.06]), np.array([0.04]), np.array([1e-3])
    e, state = np.zeros(1), start(np.zeros(1))
    observe(e, np.zeros(1), np.array([1e-3]), state, np.array([1e-3 / T]), device=device)
    assert e[0] == pytest.approx(0.03e-3, rel=1e-12)
    observe(e, np.zeros(1), np.array([-2e-3]), state, np.array([-3e-3 / T]), device=device)
    assert e[0] == pytest.approx(0.03e-3 + 0.12e-3 + 0.04 * 4e-6 / T, rel=1e-12)
    before = e[0]
    observe(e, np.array([2.0]), np.array([-1e-3]), state, np.array([1e-3 / T]), device=device)
    assert e[0] == before
    observe(e, np.array([2.0]), np.array([0.0]), state, np.array([1e-3 / T]), device=device)
    assert e[0] == pytest.approx(before - 2e-3 + 0.06e-3, rel=1e-12)
    e[0] = 0.0
    observe(e, np.zeros(1), np.array([-4e-3]), state, np.array([-4e-3 / T]), cap=1e-4, device=device)
    assert e[0] == 1e-4


def test_an_active_sampled_wall_is_detected_and_the_pc_keeps_the_bounce_passive() -> None:
    """A 1-dof mass with a little Coulomb friction f_c flies into a sampled one-sided wall K
    (zero-order hold, read through an encoder of 1e-5 m) with a little virtual damping B; the PC
    gets f_c as its friction credit. Far beyond K = 2B/T
    (Colgate's bound) it leaves faster than it came and the observer's energy goes negative; with
    the PC the energy never goes below zero, the wall still throws it back, no faster than it came."""
    step, v_in, f_c = 1e-5, 0.005, 5e-4

    def bounce(K: float, B: float, pc: bool, reserve: float = 0.0) -> tuple[float, float, float]:
        m, x, v, f_max = 0.01, -2e-5, v_in, 0.0
        e, tau_prev, tau_pc, vel = np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1)
        q_prev, lowest, travel = step * np.round(x / step), 0.0, 0.0
        state = start(np.array([q_prev]))
        for _ in range(1000):
            q = step * np.round(x / step)
            vel[0] = (q - q_prev) / T
            travel += abs(q - q_prev)
            observe(e, tau_prev, np.array([q]), state, vel)
            # The controller's energy plus what friction surely took on the observed travel.
            lowest = min(lowest, e[0] + (f_c * travel if pc else 0.0))
            tau = np.array([-K * q - B * vel[0]]) if q > 0.0 else np.zeros(1)
            if pc:
                passivity_control(
                    e,
                    tau.copy(),
                    vel,
                    T,
                    np.array([step]),
                    np.array([f_c]),
                    reserve,
                    np.array([1e9]),
                    tau,
                    tau_pc,
                    np.zeros(1),
                    np.array([-math.inf]),
                    False,
                )
            tau_prev[:] = tau
            f_max = max(f_max, abs(tau[0]))
            q_prev = q
            for _ in range(20):  # the continuous mass under the held torque
                v += (tau[0] - f_c * np.sign(v)) / m * (T / 20)
                x += v * (T / 20)
        return lowest, v, f_max

    lowest, _v_out, _ = bounce(40000.0, 0.5, pc=False)  # 2B/T = 1000 N/m
    assert lowest < -1e-6  # the plain wall gave out more than it took in
    lowest_pc, v_out_pc, _ = bounce(40000.0, 0.5, pc=True)
    assert lowest_pc >= -1e-12  # the port gave out no more than it took in plus the credit
    assert abs(v_out_pc) <= v_in  # never thrown back faster than it came
    # With a reserve the port may give out that much more than it took in, and no more than one
    # count of travel beyond the predicted step at the largest force (the prediction is the last
    # step's speed: a mass the wall accelerates may move a count further than predicted).
    reserve = 0.5 * abs(lowest)
    lowest_r, _, f_max = bounce(40000.0, 0.5, pc=True, reserve=reserve)
    assert lowest_r < -0.5 * reserve  # the reserve was used
    assert lowest_r >= -reserve - f_max * step


@settings(max_examples=200, deadline=None)
@given(
    energy=st.floats(-10.0, 10.0),
    tau_r=arrays(np.float64, 4, elements=st.floats(-20.0, 20.0)),
    tau_g=arrays(np.float64, 4, elements=st.floats(-2.0, 2.0)),
    velocity=arrays(np.float64, 4, elements=st.floats(-20.0, 20.0)),
    credit=st.floats(0.0, 1.0),
    reserve=st.floats(0.0, 0.05),
    law=st.booleans(),
    zero=st.one_of(st.just(-math.inf), st.floats(-10.0, 10.0)),
    onset_step=st.booleans(),
)
def test_the_pc_only_scales_the_rendered_torque_down_and_stays_within_the_limits(
    energy: float,
    tau_r: np.ndarray,
    tau_g: np.ndarray,
    velocity: np.ndarray,
    credit: float,
    reserve: float,
    law: bool,
    zero: float,
    onset_step: bool,
) -> None:
    """Also with the passive law, in either form and from any zero it may have been pinned at:
    never above the bound."""
    step = np.array([4e-4, 4e-4, 8e-4, 2e-4])  # 14-, 13- and 15-bit encoders
    count = step / 3 if law else np.zeros(4)
    limit = np.full(4, 6.0)
    tau = tau_r + tau_g
    tau_pc = np.zeros(4)
    cut = passivity_control(
        np.array([energy]),
        tau_r,
        velocity,
        T,
        step,
        np.full(4, credit),
        reserve,
        limit,
        tau,
        tau_pc,
        count,
        np.array([zero]),
        onset_step,
    )
    np.testing.assert_allclose(tau, tau_r + tau_g + tau_pc)
    rendered = tau_r + tau_pc
    assert np.all(rendered * tau_r >= -1e-15)  # never reverses a torque
    assert np.all(np.abs(rendered) <= np.abs(tau_r) + 1e-12)  # never adds: only scales down
    # The PC never pushes a total out past the limit, nor further out where it was already beyond.
    assert np.all(np.abs(tau) <= np.maximum(limit, np.abs(tau_r + tau_g)) + 1e-12)
    assert 0.0 <= cut <= 1.0
    # Whatever step the joints take next (up to the predicted one each), the energy stays at or
    # above -reserve, once the friction credit is paid: the bound the PC promises, also where the
    # rendered torque asks for more than the motors have (gravity alone is within the limits).
    d = np.maximum(step, np.abs(velocity) * T)
    worst = np.abs(rendered) @ d
    assert worst <= max(energy + reserve, 0.0) + credit * d.sum() + 1e-12
    if np.abs(tau_r) @ d <= max(energy + reserve, 0.0) + credit * d.sum() and zero == -math.inf:
        assert cut == 0.0  # enough energy and the law not entered: the PC does not act
        assert np.all(tau_pc == 0.0)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("max_torque_fraction", 0.0),
        ("energy_cap", -1.0),
        ("energy_reserve", -0.01),
        ("energy_reserve", 2.0),
        ("step", float("nan")),
        ("friction_credit", 1e9),
        ("step_counts", 0),
    ],
)
def test_settings_outside_their_ranges_are_refused_naming_the_field(field: str, value: float) -> None:
    with pytest.raises(InvalidField) as exc:
        PassivitySettings(**dict[str, Any]({field: value}))
    assert exc.value.field == field


def _hold(cut: float, f_0: np.ndarray, dx: float, prev: float, offset: float, R: np.ndarray | None = None) -> tuple:
    """One :func:`coupling_hold` step along z, from a grip at ``prev`` (m) moving to ``dx`` under
    the force ``f_0`` (N, {0}) with a hold ``offset`` (m); b = 0.4 N s/m, T = 1 ms (so the
    coupling k_c = 2b/T = 800 N/m). Returns (command z, offset z, last grip z)."""
    R = np.eye(3) if R is None else R
    G_F = np.concatenate((R.T @ f_0, np.zeros(3)))
    cmd = np.array([0.0, 0.0, dx, 0.0, 0.0, 0.0])
    dx_prev, off = np.array([0.0, 0.0, prev]), np.array([0.0, 0.0, offset])
    coupling_hold(cut, R, G_F, cmd, dx_prev, off, 0.4, T, 0.3)
    return cmd[2], off[2], dx_prev[2]


def test_the_hold_keeps_the_cut_share_of_the_push_from_the_slave_up_to_the_coupling() -> None:
    """The grip pushes 2 mm further into a 10 N force while the PC cuts half: the slave's command
    goes 1 mm in, the hold is 1 mm. A 2 cm push with the whole force cut is held back by at most
    the coupling's compression under 10 N, 10 / 800 = 12.5 mm."""
    up = np.array([0.0, 0.0, 10.0])
    assert _hold(0.5, up, -0.012, -0.010, 0.0) == pytest.approx((-0.011, -0.001, -0.012))
    assert _hold(1.0, up, -0.020, 0.0, 0.0) == pytest.approx((-0.0075, -0.0125, -0.020))
    # No cut, no hold; a push along the force (out of the wall) grows none either.
    assert _hold(0.0, up, -0.012, -0.010, 0.0) == pytest.approx((-0.012, 0.0, -0.012))
    assert _hold(1.0, up, -0.008, -0.010, 0.0) == pytest.approx((-0.008, 0.0, -0.008))
    # The grip's axes do not matter: the force is judged in {0} (grip turned 90 degrees about x).
    R_x = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    assert _hold(0.5, up, -0.012, -0.010, 0.0, R_x) == pytest.approx((-0.011, -0.001, -0.012))


def test_backing_out_uses_the_hold_up_before_the_slave_moves_and_a_dropped_force_keeps_it() -> None:
    """A grip 0.5 mm back out of the force with a 1 mm hold: the slave's command stays where it was
    (-11 mm), the hold is halved; 1 mm further out the hold is gone and the command follows the
    grip. The force dropping to nearly nothing bleeds the hold out slowly (no step back in)."""
    up = np.array([0.0, 0.0, 10.0])
    assert _hold(0.0, up, -0.0115, -0.012, -0.001) == pytest.approx((-0.011, -0.0005, -0.0115))
    assert _hold(0.0, up, -0.0105, -0.0115, -0.0005) == pytest.approx((-0.0105, 0.0, -0.0105))
    # The force nearly gone: the hold beyond the coupling's compression bleeds out over 0.3 s, by
    # 1 - exp(-T / 0.3 s) a tick (no step back in).
    kept = math.exp(-T / 0.3)
    assert _hold(0.0, 1e-6 * up, -0.012, -0.012, -0.001) == pytest.approx(
        (-0.012 + 0.001 * kept, -0.001 * kept, -0.012)
    )


def test_the_device_dissipation_is_read_from_the_device_file() -> None:
    """Kraft: each joint's Coulomb friction is the device file's ``plant.frictionloss`` (its MJCF
    has none), and the least damping at the grip is the joints' damping seen there, the ``b`` of
    the device-only bound (0.40 N s/m along z, the least direction at home), and each joint's
    damping is the file's ``plant.damping``. Freflex: the least direction has less than z's
    1.88 N s/m. A device without joint damping gives none."""
    kraft = load_device("kraft")
    friction, damping, b = device_dissipation(kraft)
    np.testing.assert_array_equal(friction, kraft.data.plant.per_joint("frictionloss", 6))
    np.testing.assert_array_equal(damping, kraft.data.plant.per_joint("damping", 6))
    assert b == pytest.approx(grip_damping("kraft", RELEASED), rel=1e-3)
    freflex = load_device("freflex")
    *_, b_freflex = device_dissipation(freflex)
    assert 0.0 < b_freflex < grip_damping("freflex", RELEASED)
    undamped = dataclasses.replace(kraft.data.plant, damping=(0.0,) * 6)
    bare = dataclasses.replace(kraft, data=dataclasses.replace(kraft.data, plant=undamped))
    assert device_dissipation(bare)[2] == 0.0


def test_the_crossed_edge_reads_no_travel_in_a_dither_and_a_count_per_count_in_steady_travel() -> None:
    """One count c: entering count 1 from 0 puts the angle on their edge c/2; dithering back and
    forth across it moves the angle by nothing; going on to counts 2, 3 moves it a count each; a
    tick with no count change moves it by nothing; an ideal encoder gives the reading itself
    (passivity8's known answer, kept with the observer)."""
    c = 0.01
    angle = np.array([0.0])
    moves = [crossed_edge(q, dq, c, angle, 0) for q, dq in [(c, c), (0.0, -c), (c, c), (0.0, -c), (c, c)]]
    assert moves[0] == pytest.approx(0.5 * c)
    np.testing.assert_allclose(moves[1:], 0.0, atol=1e-15)
    assert [crossed_edge(q, c, c, angle, 0) for q in (2 * c, 3 * c)] == pytest.approx([c, c])
    assert crossed_edge(3 * c, 0.0, c, angle, 0) == 0.0
    assert crossed_edge(0.123, 0.0, 0.0, angle, 0) == pytest.approx(0.123 - 2.5 * c)


def test_a_one_count_dither_reads_as_no_work_where_the_encoder_difference_reads_the_quantization_bound() -> None:
    """Module docstring, "Quantization": a joint dithering across one edge between count 0
    (no torque) and count 1 (a wall's -K c, K c = 0.5 N m, c = 1 mrad), friction f_c = 0.1 N m.
    The encoder difference's work with the friction credit is -(K c - 2 f_c) c = -0.3 mJ a cycle
    (Abbott & Okamura 2005's quantization energy; ten cycles, -3 mJ); the crossed edge reads the
    dither as no motion across the edge: after the first entry nothing is added."""
    c, f_c, Kc = 1e-3, 0.1, 0.5
    device = np.array([f_c]), np.zeros(1), np.array([c])
    e, state = np.zeros(1), start(np.zeros(1))
    observe(e, np.zeros(1), np.array([c]), state, np.array([c / T]), device=device)
    entered = e[0]
    encoder = 0.0
    for _ in range(10):
        for q, tau_prev in ((0.0, -Kc), (c, 0.0)):
            dq = q - (c if q == 0.0 else 0.0)
            encoder += -tau_prev * dq + f_c * abs(dq)
            observe(e, np.array([tau_prev]), np.array([q]), state, np.array([dq / T]), device=device)
    assert entered == pytest.approx(0.5 * f_c * c)
    assert e[0] == entered
    assert encoder == pytest.approx(-10 * (Kc - 2 * f_c) * c)


def _swing_observed(q: list[float], tau_held: list[float], c: float, f_c: float, swing: float) -> float:
    """The observer's energy (J) after the encoder readings ``q`` (rad, one per tick, from the
    first), each step under the held torque ``tau_held`` (N m), one joint of count ``c`` and
    friction ``f_c``, with the swing share ``swing``."""
    device = np.array([f_c]), np.zeros(1), np.array([c])
    e, state, run = np.zeros(1), start(np.array(q[0:1])), np.zeros(1)
    for k in range(1, len(q)):
        dq = q[k] - q[k - 1]
        observe(
            e,
            np.array([tau_held[k - 1]]),
            np.array([q[k]]),
            state,
            np.array([dq / T]),
            device=device,
            run=run,
            swing=swing,
        )
    return float(e[0])


def test_the_swing_charge_takes_half_the_readings_charge_at_a_turn_after_two_counts_and_none_in_a_dither() -> None:
    """Module docstring, "The swing's turn". Counts 0, 1, 2, 3 and back to 2 (c = 1 mrad, friction
    0.1 N m) under held torques t = 1, 2, 3, 4 N m: the crossed edge moves c/2, c, c, 0 (the first
    entry puts it on the edge; the turn is no motion across it), so it reads -(t0/2 + t1 + t2) c +
    f (5/2) c; the reading's charge at the turn is -t3 (-c) + f c, of which the swing charge adds
    SWING_SHARE. A one-count dither (counts 0, 1, 0, 1, 0: every run one count) adds nothing."""
    c, f_c = 1e-3, 0.1
    q = [0.0, c, 2 * c, 3 * c, 2 * c]
    t = [1.0, 2.0, 3.0, 4.0]
    edge = -(0.5 * t[0] + t[1] + t[2]) * c + 2.5 * f_c * c
    assert _swing_observed(q, t, c, f_c, 0.0) == pytest.approx(edge, abs=1e-15)
    assert SWING_SHARE == 0.5
    assert _swing_observed(q, t, c, f_c, SWING_SHARE) == pytest.approx(edge + 0.5 * (t[3] * c + f_c * c), abs=1e-15)
    dither = [0.0, c, 0.0, c, 0.0]
    assert _swing_observed(dither, t, c, f_c, SWING_SHARE) == _swing_observed(dither, t, c, f_c, 0.0)


def test_the_swing_charge_reads_an_active_multi_count_cycle_closer_to_its_true_work_than_the_crossed_edge() -> None:
    """A joint swinging 4.6 counts (c = 1 mrad) at 13 Hz for 4 s under a spring of 100 N m/rad on
    its reading delayed 3 ticks (an active loop: the true work of the held torque over the true
    motion is -98 mJ). The crossed edge misses the torque over each turn's last count and reads
    about 40 % less; the swing charge lies between it and the reading, closer to the truth."""
    c, K, delay = 1e-3, 100.0, 3
    t = np.arange(4001) * T
    x = 4.6 * c * np.sin(2 * np.pi * 13.0 * t) + 0.37 * c
    q = c * np.round(x / c)
    tau = -K * q[np.maximum(np.arange(len(q)) - delay, 0)]
    true = float(np.sum(-tau[:-1] * np.diff(x)))
    edge, swing, reading = (_swing_observed(list(q), list(tau), c, 0.0, share) for share in (0.0, SWING_SHARE, 1.0))
    assert true == pytest.approx(-0.098, abs=0.002)
    assert edge > 0.7 * true  # reads at most 70 % of what the port gave out
    assert edge > swing > reading
    assert abs(swing - true) < 0.5 * abs(edge - true)


def _law(
    energy: float, law: bool, zero: np.ndarray | None = None, count: float = 1e-3, onset_step: bool = False
) -> float:
    """The PC's scale s on one joint (tau_r 10 N m, a ``count`` of 1e-3 rad, friction 0.5 N m,
    step 3e-3 rad, no reserve): the bound's s = (E + f d) / (tau d), the credit f d = 1.5e-3 J,
    worst = tau d = 0.03 J; with the passive law a = tau^2 c / (2 f) = 0.1 J. ``zero``: the law's
    state (a new one, the law not entered, unless given; updated). ``onset_step``: the law's
    stateless form (``law_onset = "step"``) instead of the pinned one."""
    tau = np.array([10.0])
    cut = passivity_control(
        np.array([energy]),
        tau.copy(),
        np.zeros(1),
        T,
        np.array([3e-3]),
        np.array([0.5]),
        0.0,
        np.array([1e9]),
        tau,
        np.zeros(1),
        np.array([count if law else 0.0]),
        np.array([-math.inf]) if zero is None else zero,
        onset_step,
    )
    return 1.0 - cut


def test_the_passive_law_is_entered_where_the_bound_cuts_and_then_steps_twice_the_friction_a_count() -> None:
    """Known answers (the budget is E + 1.5 mJ; the bound cuts below E = 28.5 mJ): no step where
    the bound starts cutting (0.999 just below it, as the bound; vanish26's stateless law jumped to
    sqrt(r (2 s - r)) = 0.714 there, r = worst / a = 0.3); on the way down the law follows the
    bound (s = 0.5, then 0.3), its zero pinned where the bound cut deepest (B_0 = 9 mJ - a 0.3^2 / 2
    = 4.5 mJ), and back up it is the spring s = sqrt(2 (budget - B_0) / a): sqrt(0.21) at E = 13.5
    mJ (the bound 0.5), whose torque steps tau^2 c / a = 1 N m = 2 f a count (the bound's: tau^2 c
    s / worst = 1.67 N m); still sqrt(0.51) where the bound no longer cuts, and 1 again, the law
    left, where the budget reaches B_0 + a / 2 = 54.5 mJ."""
    zero = np.array([-math.inf])
    assert _law(0.0285 + 1e-6, True, zero) == 1.0
    assert zero[0] == -math.inf
    assert _law(0.0285 - 3e-5, True, zero) == pytest.approx(0.999)
    assert _law(0.0285 - 3e-5, False) == pytest.approx(0.999)
    assert _law(0.0135, True, zero) == pytest.approx(0.5)
    assert _law(0.0075, True, zero) == pytest.approx(0.3)
    assert zero[0] == pytest.approx(0.0045)
    assert _law(0.0135, True, zero) == pytest.approx(math.sqrt(0.21))
    assert _law(0.0135, False) == pytest.approx(0.5)
    count, tau, h = 1e-3, 10.0, 1e-8
    for law, most in ((False, 1.7), (True, 1.0 + 1e-4)):
        # One count out at the cut force takes s tau c from the energy; the torque changes by
        # tau ds/dE times that (to first order in a count's energy over the bank's).
        s = _law(0.0135, law, zero.copy())
        step = tau * (s - _law(0.0135 - h, law, zero.copy())) / h * s * tau * count
        assert step <= most
        assert law or step > 1.6  # the bound alone: 1.67 N m a count, above the 2 f = 1 N m
        assert not law or step > 1.0 - 1e-4  # the law: 2 f exactly
    assert _law(0.0285, True, zero) == pytest.approx(math.sqrt(0.51))  # the bound: 1
    assert _law(0.053 - 1e-6, True, zero) == pytest.approx(1.0, abs=1e-4)
    assert zero[0] == pytest.approx(0.0045)
    assert _law(0.053, True, zero) == 1.0
    assert zero[0] == -math.inf


def test_the_stateless_law_steps_at_the_onset_and_then_twice_the_friction_a_count() -> None:
    """The shipped form (``law_onset = "step"``), known answers on the same joint (r = worst / a =
    0.3): where the bound starts cutting (0.999 just below E = 28.5 mJ) it jumps to sqrt(r (2 s_b -
    r)) = sqrt(0.5094); at the bound's 0.5 it is sqrt(0.21), the same on the way down and back up
    (no state); at or below s_b = r it is the bound (0.3); and its torque steps tau^2 c r / worst =
    1 N m = 2 f a count (s s' = 1 / a, as the pinned law's spring)."""
    assert _law(0.0285 + 1e-6, True, onset_step=True) == 1.0
    assert _law(0.0285 - 3e-5, True, onset_step=True) == pytest.approx(math.sqrt(0.3 * (2 * 0.999 - 0.3)))
    assert _law(0.0135, True, onset_step=True) == pytest.approx(math.sqrt(0.21))
    assert _law(0.0075, True, onset_step=True) == pytest.approx(0.3)
    zero = np.array([-math.inf])
    for energy in (0.0135, 0.0075, 0.0135):  # down and back up through one state: the same law
        expected = 0.3 if energy < 0.01 else math.sqrt(0.21)
        assert _law(energy, True, zero, onset_step=True) == pytest.approx(expected)
    count, tau, h = 1e-3, 10.0, 1e-8
    s = _law(0.0135, True, onset_step=True)
    step = tau * (s - _law(0.0135 - h, True, onset_step=True)) / h * s * tau * count
    assert step == pytest.approx(1.0, rel=1e-4)


def test_where_the_bounds_own_step_is_within_twice_the_friction_the_law_is_the_bound() -> None:
    """A 100x finer count (1e-5 rad: a = 1 mJ, r = worst / a = 30): the bound's step per count,
    tau^2 c s / worst <= 0.033 N m, is within 2 f = 1 N m at every scale, so the law is the bound
    there (as on 20-bit encoders), and its zero only follows the bound."""
    zero = np.array([-math.inf])
    for energy, bound in ((0.0285, 1.0), (0.0135, 0.5), (0.0015, 0.1), (0.0135, 0.5), (0.05, 1.0)):
        assert _law(energy, True, zero, count=1e-5) == pytest.approx(bound)
    assert zero[0] == -math.inf


def test_one_count_out_and_back_at_the_onset_of_the_cut() -> None:
    """A whole count each way from where the bound starts cutting (E = 28.5 mJ, the full 10 N m),
    the friction crediting 0.5 mJ a count: out at the held 10 N m the budget falls to 20.5 mJ and
    the bound to 0.683; back in at the held 6.83 N m the bound returns to 0.928 (a 2.44 N m rise
    over the count: active, as main), the law to sqrt(2 (27.83 + 2.85) mJ / a) = 0.783, 2 f = 1 N
    m above the out-count's torque."""
    zero = np.array([-math.inf])
    e = 0.0285
    assert _law(e, True, zero) == 1.0
    e += -10.0 * 1e-3 + 0.5e-3
    out = _law(e, True, zero)
    assert out == _law(e, False) == pytest.approx(0.0205 / 0.03)
    e += 10.0 * out * 1e-3 + 0.5e-3
    assert 10.0 * (_law(e, False) - out) == pytest.approx(2.444, abs=1e-3)
    assert 10.0 * (_law(e, True, zero) - out) == pytest.approx(1.0)


def _push(law: bool) -> tuple[float, float]:
    """A 1-dof grip (0.1 kg, Coulomb friction 0.1 N, encoder 1e-4 m) in a wall that renders a
    constant 120 N outward (a slave at its force limit, as on the JPL at 1x), the observer's energy
    3 mJ above its floor (-30 mJ: a ring has spent the bank), a 400 N/m, 10 N s/m hand pulling it
    to 10 mm inside. Returns how deep the grip rests after 2 s (m) and the energy's rise (J)."""
    c, f_c, reserve, m, sub = 1e-4, 0.1, 0.03, 0.1, 20
    x = v = 0.0
    e = np.array([-reserve + 0.003])
    tau_prev, vel, angle = np.zeros(1), np.zeros(1), np.zeros(1)
    zero = np.array([-math.inf])
    q_prev = 0.0
    for _ in range(2000):
        q = c * round(x / c)
        qdot = np.array([(q - q_prev) / T])
        observe_energy(
            e,
            tau_prev,
            np.array([q]),
            angle,
            qdot,
            T,
            1e9,
            np.array([f_c]),
            np.zeros(1),
            np.array([c]),
            np.zeros(1),
            0.0,
        )
        vel[0] += 0.3 * (qdot[0] - vel[0])
        tau = np.array([120.0 if q <= 0.0 else 0.0])
        passivity_control(
            e,
            tau.copy(),
            vel,
            T,
            np.array([3 * c]),
            np.array([f_c]),
            reserve,
            np.array([1e9]),
            tau,
            np.zeros(1),
            np.array([c if law else 0.0]),
            zero,
            False,
        )
        tau_prev[:], q_prev = tau, q
        for _ in range(sub):  # the grip under the held torque, the hand and its own friction
            push = tau[0] - 400.0 * (x + 0.01) - 10.0 * v
            if v == 0.0 and abs(push) <= f_c:
                continue  # stuck
            v_next = v + (push - f_c * math.copysign(1.0, v if v != 0.0 else push)) / m * (T / sub)
            v = 0.0 if v * v_next < 0.0 else v_next
            x += v * (T / sub)
    return -x, e[0] - (-reserve + 0.003)


def test_a_steady_push_on_a_spent_bank_sinks_the_grip_with_the_bound_alone_and_not_with_the_passive_law() -> None:
    """The JPL 1x push-through in one dof (vanish26's trace): with the bound alone its cut force
    rings against the hand, each count out and back losing more than the friction takes (the
    energy falls 2.3 mJ, to within 1 mJ of its floor) and the hand sinks the grip 4.1 mm into a
    120 N wall. With the passive law the grip comes to rest 3.45 counts in: the first swings out
    follow the bound down (the energy falls 1.0 mJ, pinning the law's zero), then the cut force is
    the law's spring, 2 f a count, and the grip stays (vanish26's stateless law: 3.2 counts, the
    energy up 0.9 mJ, its deeper first cut spending less)."""
    depth, rise = _push(law=False)
    assert depth > 3e-3
    assert rise < -2e-3
    depth, rise = _push(law=True)
    assert depth < 4e-4
    assert rise > -1.5e-3
