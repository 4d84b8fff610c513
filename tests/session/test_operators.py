"""Reacting operators: delayed senses, the force threshold, the population, the experiment."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.session import load_session
from app.session.loop import LoopConfig, ServoLoop
from app.session.operator_kernel import give_way
from app.session.operators import (
    MOTOR_BANDWIDTH,
    POPULATION,
    SLOW_DISTANCE,
    V_DB,
    W_DB,
    MotorLowPass,
    OperatorParams,
    ReactingOperator,
    _Delayed,
    sample_population,
)
from app.spatial import matrix_to_zyx
from app.study.experiment import BLIND, NTRFC, ExperimentPoint, run_experiment


@given(delay=st.floats(0.0, 0.3), rate=st.sampled_from([500.0, 1000.0, 2000.0]))
def test_a_sense_reports_exactly_its_delay_late(delay: float, rate: float) -> None:
    dt = 1.0 / rate
    n = max(1, round(delay / dt))
    sense = _Delayed(delay, dt, np.zeros(3))
    out = [sense.push(np.full(3, float(k)))[0] for k in range(1, n + 20)]
    # Tick k (1-based) perceives what happened n ticks before; before that, the first sample (0).
    assert out == [max(0.0, float(k - n)) for k in range(1, n + 20)]


def test_the_population_is_seeded_and_inside_its_ranges() -> None:
    a, b = sample_population(50, seed=7), sample_population(50, seed=7)
    assert a == b
    assert a != sample_population(50, seed=8)
    for name, (lo, hi) in POPULATION.items():
        values = [getattr(op, name) for op in a]
        assert all(lo <= v <= hi for v in values)
        assert max(values) - min(values) > 0.5 * (hi - lo)  # spread over the range, not one value
    bandwidths = [op.motor_bandwidth for op in a]
    assert all(MOTOR_BANDWIDTH[0] <= v <= MOTOR_BANDWIDTH[1] for v in bandwidths)
    assert max(bandwidths) - min(bandwidths) > 0.5 * (MOTOR_BANDWIDTH[1] - MOTOR_BANDWIDTH[0])


def test_the_motor_bandwidth_left_every_other_value_of_the_population_as_it_was() -> None:
    """Operator 1 of seed 0 as drawn before the bandwidth was added (its own stream). The hand
    stiffness is the same uniform draw (0.637 of the range), now over the sourced 63-533 N/m."""
    op = sample_population(100, seed=0)[0]
    assert (op.stiffness_trans, op.aim_error, op.seed) == (362.3719930410835, 0.0018237414024599961, 2881392816)
    assert (op.stiffness_trans - 63.0) / 470.0 == pytest.approx((564.0250967589453 - 150.0) / 650.0, rel=1e-12)


@settings(max_examples=25)
@given(bandwidth=st.floats(1.0, 30.0), rate=st.sampled_from([500.0, 1000.0, 4000.0]))
def test_the_motor_low_pass_steps_as_a_critically_damped_second_order_system(bandwidth: float, rate: float) -> None:
    """A unit step held from tick 1: ``1 - (1 + w t) exp(-w t)`` at ``t = k dt`` exactly, with
    ``w = 2 pi bandwidth``; no overshoot. An infinite bandwidth passes the input through."""
    dt, w = 1.0 / rate, 2.0 * math.pi * bandwidth
    f = MotorLowPass(bandwidth, dt, np.zeros(2))
    out = [f.push(np.array([1.0, -2.0])).copy() for _ in range(int(0.3 * rate))]
    for k, y in enumerate(out, start=1):
        expect = 1.0 - (1.0 + w * k * dt) * math.exp(-w * k * dt)
        assert y == pytest.approx([expect, -2.0 * expect], abs=1e-12)
    assert MotorLowPass(math.inf, dt, np.zeros(2)).push(np.array([1.0, -2.0])).tolist() == [1.0, -2.0]


def test_operators_whose_intent_switched_at_once_no_longer_trip_the_velocity_brake() -> None:
    """Operators 23, 24, 87 and 89 of seed 0 stepped their hand target when they went from
    inserting to holding or yielding: the hand spring snapped and the device's overspeed brake
    tripped (12-24 fault ticks each with FRHC/NTRFC). With their motor bandwidth, none."""
    pop = sample_population(100, seed=0)
    for i in (23, 24, 87, 89):
        row = ExperimentPoint()((pop[i - 1], NTRFC))
        assert (row["fault_ticks"], row["completed"]) == (0, True), f"operator {i}"


def test_operators_with_a_soft_hand_push_past_the_return_to_centre() -> None:
    """Operators 18 and 36 of seed 0 have 65-140 N/m hands: the Kraft's constant return-to-centre
    (1 N past its 10 mm deadband) held their grips inside the deadband and the FRHC/NTRFC runs
    never reached the block. Compensating the force they have learned to expect, they complete."""
    pop = sample_population(100, seed=0)
    for i in (18, 36):
        assert pop[i - 1].stiffness_trans < 150.0
        row = ExperimentPoint()((pop[i - 1], NTRFC))
        assert (row["fault_ticks"], row["completed"]) == (0, True), f"operator {i}"


def test_operator_81_gives_way_without_circling() -> None:
    """Operator 81 of seed 0 (223 N/m, 3.7 N s/m: the least damped hand; threshold 1.37 N; haptic
    delay 0.115 s) used to yield to the wall force by driving the tool along it at their own speed:
    the pegs crossed the clearance into the opposite wall, the exchange grew into a +-35 mm swing
    of the hand target and the velocity brake tripped on 753 ticks (0.51 J). Giving way by taking their own
    push back, they complete without a fault."""
    op = sample_population(100, seed=0)[80]
    assert op.name == "Operator 81"
    assert op.damping_trans < 3.8
    row = ExperimentPoint()((op, NTRFC))
    assert (row["fault_ticks"], row["completed"]) == (0, True)
    assert row["work_eq13"] < 0.1


@settings(max_examples=200)
@given(
    v=st.lists(st.floats(-0.05, 0.05), min_size=3, max_size=3),
    felt=st.lists(st.floats(-20.0, 20.0), min_size=3, max_size=3),
    threshold=st.floats(0.5, 5.0),
)
def test_giving_way_takes_back_only_the_push_against_the_felt_force(
    v: list[float], felt: list[float], threshold: float
) -> None:
    """Whatever the intent and the force: the velocity along the force grows by the push against it
    times the excess share ``min(f / threshold - 1, 1)``, never past zero; across it nothing
    changes; a velocity that does not push against the force is left as it is."""
    f = float(np.linalg.norm(felt))
    if f <= threshold:
        return
    v_, felt_ = np.array(v), np.array(felt)
    n = felt_ / f
    after = v_ + give_way(v_, felt_, f, threshold)
    along, along_after = float(v_ @ n), float(after @ n)
    share = min(f / threshold - 1.0, 1.0)
    assert along_after == pytest.approx(along + max(0.0, -along) * share, abs=1e-15)
    assert along_after <= max(along, 0.0) + 1e-15
    assert after - along_after * n == pytest.approx(v_ - along * n, abs=1e-15)


def test_giving_way_known_answers() -> None:
    """Pushing down at 40 mm/s against 3 N up: with a 1 N threshold all of it is taken back, with
    2 N half; pushing down against a sideways force, or moving with the force, nothing."""
    down = np.array([0.0, 0.0, -0.04])
    up3 = np.array([0.0, 0.0, 3.0])
    assert give_way(down, up3, 3.0, 1.0).tolist() == pytest.approx([0.0, 0.0, 0.04], abs=1e-15)
    assert give_way(down, up3, 3.0, 2.0).tolist() == pytest.approx([0.0, 0.0, 0.02], abs=1e-15)
    assert give_way(down, np.array([3.0, 0.0, 0.0]), 3.0, 1.0).tolist() == [0.0, 0.0, 0.0]
    assert give_way(-down, up3, 3.0, 1.0).tolist() == [0.0, 0.0, 0.0]
    # Down and 10 mm/s into a wall whose force points +x: only the 10 mm/s is taken back.
    slanted = np.array([-0.01, 0.0, -0.04])
    assert (slanted + give_way(slanted, np.array([4.0, 0.0, 0.0]), 4.0, 1.0)).tolist() == pytest.approx(
        [0.0, 0.0, -0.04], abs=1e-15
    )


def stub(record_T_0_G: np.ndarray, tool: np.ndarray, force: np.ndarray, t: float, tick: int) -> SimpleNamespace:
    T_w_MRF = np.eye(4)
    T_w_MRF[0:3, 3] = tool
    out = SimpleNamespace(G_F_T=np.concatenate((force, np.zeros(3))))
    record = SimpleNamespace(T_w_MRF=T_w_MRF, reading=SimpleNamespace(T_0_G=record_T_0_G), out=out)
    loop = SimpleNamespace(record=record, time=t, ticks=tick, targets=[])
    loop.set_hand_target = lambda T: loop.targets.append(T.copy())
    loop.hand_pull = lambda: None  # as a Cartesian device's loop: the hand moves through set_hand_target only
    return loop


def test_a_felt_force_above_the_threshold_is_yielded_to_after_the_haptic_delay() -> None:
    """Seen at home, far from the goal, the operator wants the tool down at ``speed``; holding the
    rate-mode inverse ``d = v / K_V + DB tanh(v / V_DB)``, set further down by the constant
    return-to-centre force ``a DB^2`` over the hand's stiffness (the operator has learned it). A
    felt upward force of twice the threshold makes them take the whole downward push back: the hand
    returns to the start, ``haptic_delay`` later."""
    session = load_session("peg_ntrfc")
    loop = ServoLoop(LoopConfig.from_session(session))
    params = OperatorParams(
        "test", tremor=0.0, aim_error=0.0, haptic_delay=0.05, force_threshold=3.0, speed=0.03, motor_bandwidth=math.inf
    )
    op = ReactingOperator(params, session, loop)
    T_0_G = loop.reading.T_0_G.copy()
    home = loop.record.T_w_MRF[0:3, 3].copy()
    k_v, db = session.gains.k_v[2], session.gains.deadband[2]
    a, k_hand = session.gains.rtc_a[2], session.data.hand.stiffness_trans
    pushing = -(params.speed / k_v + db * math.tanh(params.speed / V_DB) + a * db * db / k_hand)
    n_delay = round(params.haptic_delay * loop.config.servo_rate)
    heights = []
    for k in range(3 * n_delay):
        force = np.array([0.0, 0.0, 6.0]) if k >= n_delay else np.zeros(3)
        s = stub(T_0_G, home, force, k * loop.dt, k)
        op.before_tick(s)
        heights.append(s.targets[-1][2, 3] - T_0_G[2, 3])
    assert heights[n_delay] == pytest.approx(pushing, rel=1e-9)
    assert heights[2 * n_delay - 1] == pytest.approx(pushing, rel=1e-9)
    assert heights[2 * n_delay] == pytest.approx(0.0, abs=1e-12)
    assert op.phase == "insert"


def test_a_misjudged_upright_turns_the_grip_by_the_learned_rate_inverse() -> None:
    """Seen upright, an operator who takes upright to be 1 degree about x wants the tool to turn at
    ``w = 1 deg * speed / SLOW_DISTANCE`` about x: the grip turns from its start by
    ``w / K_V + DB tanh(w / W_DB)`` about x (as Z-Y-X angles), plus the constant return-to-centre
    moment ``a DB^2`` over the wrist's stiffness; one tilt is as seen as the other."""
    session = load_session("peg_ntrfc")
    loop = ServoLoop(LoopConfig.from_session(session))
    tilt = math.radians(1.0)
    # An unfiltered hand: the first tick's target is the learned inverse itself.
    params = OperatorParams(
        "test", tremor=0.0, aim_error=0.0, tilt_error=tilt, tilt_axis=0.0, speed=0.03, motor_bandwidth=math.inf
    )
    op = ReactingOperator(params, session, loop)
    T_0_G = loop.reading.T_0_G.copy()
    s = stub(T_0_G, loop.record.T_w_MRF[0:3, 3].copy(), np.zeros(3), 0.0, 0)
    op.before_tick(s)
    w = tilt * params.speed / SLOW_DISTANCE
    k_v, db = session.gains.k_v[3], session.gains.deadband[3]
    angle = w / k_v + db * math.tanh(w / W_DB)
    assert angle > db  # past the deadband: the constant part of the return-to-centre
    angle += session.gains.rtc_a[3] * db * db / session.data.hand.stiffness_rot
    turned = matrix_to_zyx(T_0_G[0:3, 0:3].T @ s.targets[-1][0:3, 0:3])
    assert turned == pytest.approx((angle, 0.0, 0.0), abs=1e-12)
    # About y instead: the same angle on beta.
    params_y = dataclasses.replace(params, tilt_axis=math.pi / 2)
    op = ReactingOperator(params_y, session, loop)
    s = stub(T_0_G, loop.record.T_w_MRF[0:3, 3].copy(), np.zeros(3), 0.0, 0)
    op.before_tick(s)
    turned = matrix_to_zyx(T_0_G[0:3, 0:3].T @ s.targets[-1][0:3, 0:3])
    assert turned == pytest.approx((0.0, angle, 0.0), abs=1e-12)


def test_an_operator_needs_a_task() -> None:
    session = load_session("probe_rate")
    loop = ServoLoop(LoopConfig.from_session(session))
    with pytest.raises(ValueError, match="no task"):
        ReactingOperator(OperatorParams("x"), session, loop)


def test_the_experiment_reports_both_conditions_and_finishes_early(tmp_path: Path) -> None:
    """One default operator: both insertions complete, the run ends when the operator has
    withdrawn, and blind (nothing felt, no accommodation) presses harder than with FRHC/NTRFC."""
    calls: list[tuple[int, int]] = []
    report = run_experiment(
        tmp_path, operators=[OperatorParams("Subject A")], workers=1, on_run=lambda *a: calls.append(a)
    )
    assert calls == [(1, 2), (2, 2)]
    rows = {r["condition"]: r for r in report.rows}
    for cond in (NTRFC, BLIND):
        assert rows[cond]["status"] == "ok"
        assert rows[cond]["completed"]
        assert rows[cond]["simulated_s"] < 12.0
    assert rows[BLIND]["peak_contact_force_N"] > 2.0 * rows[NTRFC]["peak_contact_force_N"]
    assert "Subject A" in report.table
    assert report.chart.stat().st_size > 0
    assert pq.read_table(report.results).num_rows == 2


def test_each_run_starts_with_the_pegs_over_where_the_operator_believes_the_holes_are() -> None:
    """The scene's home (tips 3 cm over the holes) moved by the operator's aim error: 2 mm at
    90 degrees is +2 mm in y, the orientation unchanged."""
    op = OperatorParams("test", aim_error=0.002, aim_angle=math.pi / 2)
    point = ExperimentPoint()
    scene = load_session("peg_blind").scene
    for cond in (NTRFC, BLIND):
        moved = point.session(op, cond).scene
        assert moved.tool.T_w_MRF_home[0:3, 3] == pytest.approx([0.0, 0.002, 0.03], abs=1e-15)
        assert moved.spec.tool.home.position == pytest.approx((0.0, 0.002, 0.03), abs=1e-15)
        assert np.array_equal(moved.tool.T_w_MRF_home[0:3, 0:3], scene.tool.T_w_MRF_home[0:3, 0:3])


def test_failed_runs_are_reported_not_averaged_and_ray_gives_the_serial_rows(tmp_path: Path, local_ray: None) -> None:
    """A 0.3 s limit is too short to insert anything: every run fails, no work is averaged."""
    ops = sample_population(2, seed=5)
    serial = run_experiment(tmp_path / "s", operators=ops, time_limit=0.3, workers=1)
    assert all(r["status"] == "ok" and not r["completed"] for r in serial.rows)
    summary = serial.table.split("Population")[1]
    assert summary.count("completed 0/2") == 2
    assert summary.count("work - J") == 2
    assert serial.table.count("failed") == 8  # 4 runs in the paper's layout, and in the per-operator lines
    on_ray = run_experiment(tmp_path / "r", operators=ops, time_limit=0.3, workers=2)
    assert on_ray.rows == serial.rows


def test_record_arrays_the_kernels_cannot_take_are_copied_and_not_remembered() -> None:
    """A C-contiguous float64 array of its shape is passed as it is, and the three are remembered
    (later ticks test identity only); one of another layout is copied, values equal, and then
    nothing is remembered, so the next tick checks (and copies) again."""
    session = load_session("peg_ntrfc")
    loop = ServoLoop(LoopConfig.from_session(session))
    op = ReactingOperator(sample_population(1, 0)[0], session, loop)
    T_w_MRF, T_0_G, G_F_T = np.eye(4), np.eye(4) * 2.0, np.arange(6.0)
    taken = op._check(T_w_MRF, T_0_G, G_F_T)
    assert all(t is a for t, a in zip(taken, (T_w_MRF, T_0_G, G_F_T), strict=True))
    assert op._checked == (T_w_MRF, T_0_G, G_F_T)
    fortran = np.asfortranarray(np.arange(16.0).reshape(4, 4))
    strided = np.arange(12.0)[::2]
    taken = op._check(T_w_MRF, fortran, strided)
    assert taken[0] is T_w_MRF
    assert taken[1] is not fortran
    assert taken[1].flags.c_contiguous
    assert taken[2] is not strided
    assert taken[2].flags.c_contiguous
    np.testing.assert_array_equal(taken[1], fortran)
    np.testing.assert_array_equal(taken[2], strided)
    assert op._checked == ()
