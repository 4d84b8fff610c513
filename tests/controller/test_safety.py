"""The safety envelope: force ramps, the velocity brake, sane periods and the API boundary."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from app.controller.frhc import FRHCController
from app.controller.safety import SafetyLimits
from app.controller.types import Fault, FTReading, SlaveModel, Switches
from app.device.spec import DeviceSpec
from app.errors import InputError, InvalidField

DT = 1e-3
RAMP_TIME = 0.1


def pushed(slave: SlaveModel, fz: float = 3.0) -> FTReading:
    """Payload weight at a level sensor plus a contact force ``fz`` (N) along +z."""
    ft = FTReading()
    ft.wrench_S[0:3] = slave.payload_mass * slave.gravity_w + np.array([0.0, 0.0, fz])
    ft.wrench_S[3:6] = np.cross(slave.payload_com_S, slave.payload_mass * slave.gravity_w)
    return ft


@pytest.fixture
def safe(kraft: DeviceSpec, slave: SlaveModel) -> FRHCController:
    return FRHCController(kraft, kraft.data.gains, slave, safety=SafetyLimits(ramp_time=RAMP_TIME))


def deadzone_counts(controller: FRHCController) -> int:
    """The largest constant term of the torque curves (counts): a fitted curve steps by it when a
    torque leaves zero, to cross the amplifier's deadzone."""
    curve = controller.curve
    return int(np.ceil(max(np.abs(curve.horner_pos[:, -1]).max(), np.abs(curve.horner_neg[:, -1]).max())))


def full_strength(kraft: DeviceSpec, slave: SlaveModel, q: np.ndarray) -> np.ndarray:
    """The task torques without any ramp, at ``q``."""
    paper = FRHCController(kraft, kraft.data.gains, slave, safety=SafetyLimits.paper_only())
    return paper.step(q, Switches(deadman=True, reflection=True), pushed(slave), DT).tau_T.copy()


def test_wrench_ramps_in_after_the_deadman_engages(safe, kraft, slave) -> None:
    q = np.array(kraft.data.home)
    target = full_strength(kraft, slave, q)
    assert np.abs(target).max() > 0.3
    on = Switches(deadman=True, reflection=True)
    taus, counts, levels = [], [], []
    for _ in range(round(1.5 * RAMP_TIME / DT)):
        out = safe.step(q, on, pushed(slave), DT)
        taus.append(out.tau_sat.copy())
        counts.append(out.counts.copy())
        levels.append(out.ramp)
        np.testing.assert_allclose(out.tau_T, out.ramp * target, atol=1e-12)
    assert levels[0] == pytest.approx(DT / RAMP_TIME)
    assert levels[round(RAMP_TIME / DT) - 1] == pytest.approx(1.0)  # full strength within the ramp time
    # Per tick, the torque moves by the ramp's share of the rendered torque, and the counts by that
    # share plus at most one deadzone step as a torque leaves zero.
    rendered = np.abs(taus[-1] - safe.step(q, Switches(), pushed(slave), DT).tau_sat)
    assert np.all(np.abs(np.diff(np.array(taus), axis=0)) <= rendered * DT / RAMP_TIME + 1e-9)
    full_counts = np.abs(counts[-1]).max()
    steps = np.abs(np.diff(np.array(counts), axis=0)).max()
    assert steps <= full_counts * DT / RAMP_TIME * 1.5 + deadzone_counts(safe) + 1


def test_wrench_ramps_in_again_after_a_fault_window(safe, kraft, slave) -> None:
    q = np.array(kraft.data.home)
    on = Switches(deadman=True, reflection=True)
    for _ in range(round(2 * RAMP_TIME / DT)):
        out = safe.step(q, on, pushed(slave), DT)
    full, full_tau = out.counts.copy(), out.tau_sat.copy()
    assert out.ramp == 1.0
    bad = pushed(slave)
    bad.wrench_S[2] = np.nan
    for _ in range(100):
        out = safe.step(q, on, bad, DT)
        assert out.faults & Fault.NONFINITE_INPUT
    gravity_only, gravity_tau = out.counts.copy(), out.tau_sat.copy()
    previous, previous_tau = gravity_only, gravity_tau
    worst, worst_tau = 0, np.zeros_like(full_tau)
    for _ in range(round(RAMP_TIME / DT)):
        out = safe.step(q, on, pushed(slave), DT)
        worst = max(worst, int(np.abs(out.counts - previous).max()))
        worst_tau = np.maximum(worst_tau, np.abs(out.tau_sat - previous_tau))
        previous, previous_tau = out.counts.copy(), out.tau_sat.copy()
    np.testing.assert_array_equal(out.counts, full)  # back at full strength within the ramp time
    jump = int(np.abs(full - gravity_only).max())
    assert jump > 100  # without the ramp this would be one step
    assert np.all(worst_tau <= np.abs(full_tau - gravity_tau) * DT / RAMP_TIME + 1e-9)
    assert worst <= jump * DT / RAMP_TIME * 1.5 + deadzone_counts(safe) + 1


def test_velocity_brake_damps_until_the_device_slows(safe, kraft, slave) -> None:
    q = np.array(kraft.data.home)
    on = Switches(deadman=True, reflection=True)
    limit = safe.safety.max_joint_speed
    safe.step(q, on, pushed(slave), DT)
    fast = q.copy()
    fast[1] += 2 * limit * DT  # twice the limit
    out = safe.step(fast, on, pushed(slave), DT)
    assert out.faults == Fault.OVERSPEED
    assert not out.command.active
    np.testing.assert_array_equal(out.tau_T, 0.0)
    # Damping only: gravity compensation minus brake damping on the moving joint.
    assert out.tau[1] == pytest.approx(out.tau_G[1] - safe.safety.brake_damping * 2 * limit)
    # Still above the release speed: still braking; below it: released, and the wrench ramps in.
    slower = fast.copy()
    slower[1] += 0.6 * limit * DT
    assert safe.step(slower, on, pushed(slave), DT).faults == Fault.OVERSPEED
    out = safe.step(slower + 0.1 * limit * DT, on, pushed(slave), DT)
    assert out.faults == Fault.NONE
    assert out.ramp == pytest.approx(DT / RAMP_TIME)


@pytest.mark.parametrize("dt", [0.0, -1e-3, 1e-300, 5e-6, 0.5, np.nan, np.inf])
def test_a_period_outside_the_sane_range_is_a_fault(safe, kraft, slave, dt: float) -> None:
    out = safe.step(np.array(kraft.data.home), Switches(deadman=True), pushed(slave), dt)
    assert out.faults & Fault.BAD_PERIOD
    assert np.all(np.isfinite(out.tau))


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("ramp_time", -1.0),
        ("ramp_time", np.inf),
        ("max_joint_speed", 0.0),
        ("release_fraction", 1.0),
        ("min_period", 0.1),
    ],
)
def test_safety_limits_refuse_bad_values(field: str, value: float) -> None:
    with pytest.raises(InvalidField, match=field):
        SafetyLimits(**{field: value})


ARRAY_DTYPES = st.sampled_from([np.float64, np.float32, np.int64, np.int8, np.uint16, np.bool_, np.complex128])
SHAPES = st.sampled_from([(), (1,), (3,), (5,), (6,), (7,), (2, 2), (3, 3), (4, 4), (6, 1)])


def any_array(draw: st.DrawFn, good_shape: tuple[int, ...]) -> object:
    shape = draw(st.one_of(st.just(good_shape), SHAPES))
    dtype = draw(st.one_of(st.just(np.float64), ARRAY_DTYPES))
    values = (
        hnp.from_dtype(np.dtype(dtype), allow_nan=True, allow_infinity=True) if dtype != np.bool_ else st.booleans()
    )
    array = draw(hnp.arrays(dtype, shape, elements=values))
    return array.tolist() if draw(st.booleans()) and array.ndim else array


@st.composite
def step_inputs(draw: st.DrawFn) -> tuple[object, FTReading, object]:
    q = any_array(draw, (6,))
    ft = FTReading(
        wrench_S=any_array(draw, (6,)),  # type: ignore[arg-type]
        R_w_S=any_array(draw, (3, 3)),  # type: ignore[arg-type]
        acc_w=any_array(draw, (6,)),  # type: ignore[arg-type]
        omega_w=any_array(draw, (3,)),  # type: ignore[arg-type]
        valid=draw(st.booleans()),
    )
    dt = draw(
        st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.just(DT), st.integers(-2, 2), st.text(max_size=2))
    )
    return q, ft, dt


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(inputs=step_inputs(), deadman=st.booleans(), reflection=st.booleans())
def test_any_input_gives_bounded_counts_or_the_projects_error(safe, kraft, inputs, deadman, reflection) -> None:
    """Arbitrary shapes, dtypes and values: never a non-finite or over-range count, never an
    unflagged non-finite output, never an exception outside the project's errors."""
    q, ft, dt = inputs
    try:
        out = safe.step(q, Switches(deadman=deadman, reflection=reflection), ft, dt)  # type: ignore[arg-type]
    except InputError:
        return  # the project's error for a malformed argument: anything else fails the test
    counts_max = safe.curve.counts_max
    assert out.counts.dtype == np.int64
    assert np.all(np.abs(out.counts) <= counts_max)
    assert np.all(np.isfinite(out.tau))
    assert np.all(np.isfinite(out.tau_sat))
    limit = safe.joint_limit
    assert np.all(np.abs(out.tau_sat) <= limit * (1 + 1e-12))
    if not (np.all(np.isfinite(out.vectors)) and np.all(np.isfinite(out.torques))):
        assert out.faults != Fault.NONE


def test_amplifier_watchdog_switches_the_motors_off_and_the_loop_ramps_back() -> None:
    """A stalled controller: the amplifier holds its counts for ``watchdog`` seconds, then the
    motors go off (the grip falls); once ticks resume, the wrench ramps in again."""
    from app.device.spec import load_device
    from app.session.loop import LoopConfig, ServoLoop
    from app.world.scene import load_scene

    device = load_device("kraft")
    loop = ServoLoop(LoopConfig(device, load_scene("probe"), device.data.gains))
    loop.set_hand_target(None)
    for _ in range(50):
        record = loop.tick()
    held = loop.plant.reading.tau_joint.copy()
    assert np.abs(held).max() > 0.1  # gravity compensation holds the device
    watchdog = loop.plant.watchdog
    steps = round(watchdog / loop.dt)
    for _ in range(steps):  # within the watchdog: the last counts are held
        loop.plant.step(None, loop.dt)
        np.testing.assert_array_equal(loop.plant.reading.tau_joint, held)
        assert not loop.plant.reading.motors_off
    loop.plant.step(None, loop.dt)
    assert loop.plant.reading.motors_off
    np.testing.assert_array_equal(loop.plant.reading.tau_joint, 0.0)
    assert loop.plant.reading.watchdog_trips == 1
    loop.stall(0.05)  # still no counts: no second trip, motors stay off
    assert loop.plant.reading.watchdog_trips == 1
    record = loop.tick()
    assert not record.reading.motors_off
    assert record.reading.watchdog_trips == 1
    assert record.out.ramp == pytest.approx(loop.dt / loop.config.safety.ramp_time)


def test_strided_or_transposed_inputs_give_the_contiguous_answer(kraft: DeviceSpec, slave: SlaveModel) -> None:
    """The compiled tick is called without numba's typing: other layouts are converted first."""
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, 0.8, -0.6], [0.0, 0.6, 0.8]])
    q = np.array(kraft.data.home) + 0.05
    sw = Switches(deadman=True, reflection=True)
    contiguous, other = (FRHCController(kraft, kraft.data.gains, slave) for _ in range(2))
    ft = pushed(slave)
    ft.R_w_S[:] = tilt
    odd = FTReading(ft.wrench_S.copy(), np.asfortranarray(tilt), ft.acc_w.copy(), ft.omega_w.copy())
    strided_q = np.repeat(q, 2)[::2]
    assert not odd.R_w_S.flags.c_contiguous
    assert not strided_q.flags.c_contiguous
    for _ in range(5):
        expected = contiguous.step(q, sw, ft, DT).tau.copy()
        got = other.step(strided_q, sw, odd, DT).tau
    np.testing.assert_array_equal(got, expected)
    assert np.abs(expected).max() > 0.0


@pytest.mark.parametrize("jump", [1e300, -1e308, 1e6])
def test_an_encoder_glitch_brakes_within_each_joints_limit(safe, kraft, slave, jump: float) -> None:
    """One joint's encoder jumps absurdly in one tick (finite, so not a non-finite input): the
    brake engages, its torque is finite and within that joint's limit (not the full-scale pulse
    on every joint a 1e302 N m request caused through the uniform saturation), and the joints
    that did not move get no brake torque."""
    q = np.array(kraft.data.home)
    on = Switches(deadman=True, reflection=True)
    safe.step(q, on, pushed(slave), DT)
    glitch = q.copy()
    glitch[2] = jump
    out = safe.step(glitch, on, pushed(slave), DT)
    assert out.faults == Fault.OVERSPEED
    assert np.all(np.isfinite(out.tau))
    assert abs(out.tau[2] - out.tau_G[2]) == pytest.approx(safe.joint_limit[2])
    others = [0, 1, 3, 4, 5]
    np.testing.assert_allclose(out.tau[others], out.tau_G[others])
    back = safe.step(q, on, pushed(slave), DT)  # and the jump back: the same bound, the other way
    assert np.all(np.isfinite(back.tau))
    assert np.all(np.abs(back.tau - back.tau_G) <= safe.joint_limit + 1e-12)


def test_gravity_ramps_back_after_a_joint_reading_fault(safe, kraft, slave) -> None:
    """Non-finite joint angles leave no gravity compensation (no pose to compute it at); when the
    reading recovers, the torque comes back at the ramp's rate like after any other fault, not as
    one step (it was a step of 32 % of the amplifier's full scale in counts)."""
    q = np.array(kraft.data.home)
    on = Switches(deadman=True, reflection=True)
    for _ in range(round(2 * RAMP_TIME / DT)):
        out = safe.step(q, on, pushed(slave), DT)
    full_tau, full = out.tau_sat.copy(), out.counts.copy()
    for _ in range(10):
        out = safe.step(np.full_like(q, np.nan), on, pushed(slave), DT)
        assert out.faults == Fault.NONFINITE_INPUT
        np.testing.assert_array_equal(out.counts, 0)
    previous, previous_tau, worst, worst_tau = out.counts.copy(), out.tau_sat.copy(), 0, np.zeros_like(full_tau)
    for _ in range(round(RAMP_TIME / DT)):
        out = safe.step(q, on, pushed(slave), DT)
        assert out.faults == Fault.NONE
        worst = max(worst, int(np.abs(out.counts - previous).max()))
        worst_tau = np.maximum(worst_tau, np.abs(out.tau_sat - previous_tau))
        previous, previous_tau = out.counts.copy(), out.tau_sat.copy()
    np.testing.assert_array_equal(out.counts, full)  # back at full strength within the ramp time
    jump = int(np.abs(full).max())
    assert jump > 0.2 * safe.curve.counts_max  # a large torque to bring back
    assert worst <= jump * DT / RAMP_TIME * 1.5 + deadzone_counts(safe) + 1, worst / safe.curve.counts_max
    assert np.all(worst_tau <= np.abs(full_tau) * DT / RAMP_TIME * 1.001 + 1e-9)


def quantised(kraft: DeviceSpec, q: np.ndarray) -> np.ndarray:
    """``q`` as the Kraft's encoders read it (rad): rounded to whole counts of each joint."""
    count = kraft.encoder_step
    return np.round(q / count) * count


@pytest.mark.parametrize("rate", [1000.0, 4000.0, 20000.0])
def test_one_encoder_count_is_not_overspeed_at_any_rate(safe, kraft, slave, rate: float) -> None:
    """The wrist joint turns at 0.5 rad/s (1/16 of the limit) for 0.1 s, read through the Kraft's
    8192-count wrist encoder (7.67e-4 rad a count): no tick may brake. One count in one 50 us tick
    reads 15.3 rad/s, twice the 8 rad/s limit, and braked 1 tick in ~20 at 20 kHz."""
    dt = 1.0 / rate
    on = Switches(deadman=True, reflection=True)
    home = np.array(kraft.data.home)
    assert kraft.encoder_step[4] / 50e-6 > safe.safety.max_joint_speed  # a count does read as overspeed
    faults = []
    for k in range(int(0.1 * rate)):
        q = home.copy()
        q[4] += 0.5 * k * dt
        faults.append(safe.step(quantised(kraft, q), on, pushed(slave), dt).faults)
    assert all(f == Fault.NONE for f in faults), f"{sum(f != Fault.NONE for f in faults)} fault ticks"


@pytest.mark.parametrize("rate", [1000.0, 4000.0, 20000.0])
def test_a_quantised_runaway_brakes_within_a_millisecond(safe, kraft, slave, rate: float) -> None:
    """The same wrist joint runs away at twice the limit (16 rad/s), read through its encoder:
    the brake holds within 1 ms of the start at every rate."""
    dt = 1.0 / rate
    on = Switches(deadman=True, reflection=True)
    home = np.array(kraft.data.home)
    speed = 2 * safe.safety.max_joint_speed
    first = None
    for k in range(int(0.005 * rate)):
        q = home.copy()
        q[4] += speed * k * dt
        if safe.step(quantised(kraft, q), on, pushed(slave), dt).faults == Fault.OVERSPEED and first is None:
            first = k * dt
    assert first is not None
    assert first <= 1e-3
