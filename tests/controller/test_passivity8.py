"""Known answers for the opt-in PC variants of issue 26 (helper passivity8; NOT shipped: they live
with the patch in the notes): the damping PC, the crossed-edge observer angle and the directed
prediction."""

from __future__ import annotations

import numpy as np
import pytest

from app.controller.passivity import (
    crossed_edge,
    dither_edge,
    passivity_control,
    passivity_damping,
    travel_direction,
)

T = 1e-3


def test_the_damping_pc_dissipates_exactly_the_deficit_over_a_tick_at_its_velocity() -> None:
    """alpha = -(E + E_r) / (T |v|^2): the damper's work over one tick at the velocity it acted on,
    -tau_pc . v T = alpha |v|^2 T, equals the deficit (here 5 mJ below the 20 mJ reserve)."""
    v = np.array([0.3, -0.1, 0.05])
    tau, tau_pc = np.zeros(3), np.zeros(3)
    alpha = passivity_damping(np.array([-0.025]), v, T, 0.02, np.full(3, 1e3), tau, tau_pc)
    assert alpha == pytest.approx(0.005 / (T * float(v @ v)))
    np.testing.assert_allclose(tau_pc, -alpha * v)
    assert -float(tau_pc @ v) * T == pytest.approx(0.005)
    # Within the reserve it does nothing.
    assert passivity_damping(np.array([-0.019]), v, T, 0.02, np.full(3, 1e3), tau, tau_pc) == 0.0
    assert not tau_pc.any()


def test_the_damping_pc_does_not_rectify_a_zero_mean_force_the_scale_pc_does() -> None:
    """Out of contact: a zero-mean spike train (-3 N m for one tick, +1 N m for three) on a joint
    drifting at 0.01 rad/s with the bank at its floor. The scale PC clamps the spikes to what the
    budget pays for, so the mean it passes is +0.4 N m (along the drift: it pushes the grip on);
    the damping PC adds only -alpha v, so the rendered force's mean less its damper is zero and the
    damper opposes the drift."""
    spikes = np.array([-3.0, 1.0, 1.0, 1.0] * 25)
    assert spikes.mean() == 0.0
    v, step, reserve = np.array([0.01]), np.array([1e-3]), 0.02
    scaled, damped, damper = [], [], []
    for f in spikes:
        tau, tau_pc = np.array([f]), np.zeros(1)
        # E = -reserve + 0.8 mJ: the scale PC passes |tau| d <= 0.8 mJ, |tau| <= 0.8 N m.
        passivity_control(
            np.array([-reserve + 8e-4]),
            np.array([f]),
            v,
            T,
            step,
            np.zeros(1),
            reserve,
            np.array([1e3]),
            tau,
            tau_pc,
            np.zeros(1),
            np.zeros(1),
            np.zeros(1),
        )
        scaled.append(tau[0])
        tau, tau_pc = np.array([f]), np.zeros(1)
        passivity_damping(np.array([-reserve - 1e-6]), v, T, reserve, np.array([1e3]), tau, tau_pc)
        damped.append(tau[0])
        damper.append(tau_pc[0])
    assert np.mean(scaled) == pytest.approx(0.4)
    assert np.mean(np.array(damped) - np.array(damper)) == pytest.approx(0.0, abs=1e-12)
    assert np.all(np.array(damper) < 0.0)


def test_the_crossed_edge_reads_no_travel_in_a_dither_and_a_count_per_count_in_steady_travel() -> None:
    """One count c: entering count 1 from 0 puts the angle on the edge c/2; dithering back and forth
    across it moves the angle by nothing; going on to counts 2, 3 moves it a count each."""
    c = 0.01
    edge = np.array([0.0])
    moves = [crossed_edge(q, dq, c, edge, 0) for q, dq in [(c, c), (0.0, -c), (c, c), (0.0, -c), (c, c)]]
    assert moves[0] == pytest.approx(0.5 * c)
    np.testing.assert_allclose(moves[1:], 0.0, atol=1e-15)
    assert [crossed_edge(q, c, c, edge, 0) for q in (2 * c, 3 * c)] == pytest.approx([c, c])
    assert crossed_edge(3 * c, 0.0, c, edge, 0) == 0.0  # no count changed: no travel
    assert crossed_edge(0.123, 0.0, 0.0, edge, 0) == pytest.approx(0.123 - 2.5 * c)  # ideal encoder


def test_the_direction_of_travel_is_known_after_two_counts_the_same_way_and_lost_on_a_reversal() -> None:
    c = 0.01
    direction, last = np.zeros(1), np.zeros(1)
    seen = []
    for dq in (c, c, 0.0, -c, -c, 2 * c):
        travel_direction(dq, c, direction, last, 0)
        seen.append(direction[0])
    assert seen == [0.0, 1.0, 1.0, 0.0, -1.0, 1.0]


def test_a_directed_prediction_charges_only_the_torque_along_the_travel() -> None:
    """Bank at its floor, no credit: along the known travel the torque is cut to nothing; against
    it (the torque absorbs energy as the joint goes on) it passes whole."""
    for f, kept in ((2.0, 0.0), (-2.0, -2.0)):
        tau, tau_pc = np.array([f]), np.zeros(1)
        passivity_control(
            np.array([-0.02]),
            np.array([f]),
            np.zeros(1),
            T,
            np.array([1e-3]),
            np.zeros(1),
            0.02,
            np.array([1e3]),
            tau,
            tau_pc,
            np.array([1.0]),
            np.zeros(1),
            np.zeros(1),
        )
        assert tau[0] == pytest.approx(kept)


def test_a_dithering_joint_is_held_within_twice_its_friction_above_the_other_side() -> None:
    """Diolaiti et al. 2006 / Abbott & Okamura 2005: a one-count dither is passive when the torque
    step across the edge is below 2 f_c. Joint in count 1 (torque -1 N m), crossed back to 0
    (torque 0) and in again: dithering, the other side's torque 0, so with f_c = 0.1 N m a
    rendered -1 N m is scaled to -0.2 N m; a second count the same way is travel, not a dither."""
    c, f_c = 0.01, 0.1
    sign, dither, other = np.zeros(1), np.zeros(1), np.zeros(1)
    for dq, tau_prev in ((c, 0.0), (-c, -1.0), (c, 0.0)):
        dither_edge(dq, c, tau_prev, sign, dither, other, 0)
    assert dither[0] == 1.0 and other[0] == 0.0
    tau, tau_pc = np.array([-1.0]), np.zeros(1)
    args = (np.zeros(1), T, np.array([1e-3]), np.array([f_c]), 0.02, np.array([1e3]), tau, tau_pc, np.zeros(1))
    passivity_control(np.array([0.0]), np.array([-1.0]), *args, dither, other)
    assert tau[0] == pytest.approx(-2 * f_c)
    dither_edge(c, c, -0.2, sign, dither, other, 0)
    assert dither[0] == 0.0
