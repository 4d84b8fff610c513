"""The master-slave channel and wave variables (app.teleop): delivery, seeding, passivity, the loop."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.controller.types import SlaveCommand
from app.errors import InvalidField
from app.filters import lowpass
from app.session.loop import LoopConfig, ServoLoop
from app.session.script import OperatorScript
from app.session.spec import load_session
from app.slave.arm import ArmStatus
from app.teleop import wave
from app.teleop.channel import ChannelSettings, DelayLine


def deliveries(line: DelayLine, n: int) -> list[float]:
    """Send message k (the number k) at tick k for n ticks; what the receiver holds each tick."""
    held = []
    for k in range(n):
        line.send()[0] = k
        line.receive()
        held.append(float(line.out[0]))
    return held


@pytest.mark.parametrize("delay", [0, 1, 7, 50])
def test_every_message_arrives_exactly_after_the_delay_in_order(delay: int) -> None:
    line = DelayLine(1, delay, 0, 0.0, np.random.default_rng(0), np.array([-1.0]))
    held = deliveries(line, 200)
    assert held == [-1.0] * delay + [float(k) for k in range(200 - delay)]
    assert line.delivered == 200 - delay
    assert line.lost == 0


def test_jitter_and_loss_are_seeded_in_order_and_bounded() -> None:
    def run(seed: int) -> tuple[list[float], int]:
        line = DelayLine(1, 5, 4, 0.2, np.random.default_rng(seed), np.array([-1.0]))
        return deliveries(line, 3000), line.lost

    held, lost = run(3)
    assert (held, lost) == run(3)  # reproducible
    assert run(4) != (held, lost)
    assert 0.15 * 3000 < lost < 0.25 * 3000
    h = np.array(held)
    assert np.all(np.diff(h) >= 0)  # never an older message after a newer one
    ticks = np.arange(3000)
    arrived = h >= 0
    assert np.all(ticks[arrived] - h[arrived] >= 5)  # never earlier than the delay
    # Never held back beyond delay + jitter unless losses left nothing newer to deliver.
    assert np.median(ticks[arrived] - h[arrived]) <= 5 + 4 + 2


@settings(max_examples=100, deadline=None)
@given(
    xdot=arrays(np.float64, 3, elements=st.floats(-2.0, 2.0)),
    v_in=arrays(np.float64, 3, elements=st.floats(-20.0, 20.0)),
    F_prev=arrays(np.float64, 3, elements=st.floats(-50.0, 50.0)),
    b=st.floats(1.0, 1e3),
    c=st.floats(0.0, 100.0),
)
def test_wave_ports_put_exactly_the_wave_power_difference_in(
    xdot: np.ndarray, v_in: np.ndarray, F_prev: np.ndarray, b: float, c: float
) -> None:
    """Power into the channel at each port is (u^2 - v^2)/2 (master) and (v^2 - u^2)/2 sign-flipped
    (slave): a pure delay between them stores, never creates, energy."""
    u_m, F_m = np.zeros(3), np.zeros(3)
    wave.master(xdot, v_in, b, u_m, F_m)
    np.testing.assert_allclose(xdot @ F_m, 0.5 * (u_m @ u_m - v_in @ v_in), rtol=1e-9, atol=1e-9)
    xdot_s, F_s, v_s = np.zeros(3), np.zeros(3), np.zeros(3)
    wave.slave(u_m, F_prev, b, c, xdot_s, F_s, v_s)
    # The slave port gives out xdot_s F_s to the environment; the waves bring in (u^2 - v^2)/2.
    np.testing.assert_allclose(xdot_s @ F_s, 0.5 * (u_m @ u_m - v_s @ v_s), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(F_s, F_prev + c * xdot_s, rtol=1e-12, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    delay=st.integers(0, 30),
    b=st.floats(1.0, 1e3),
    a=st.floats(0.01, 1.0),
    c=st.floats(0.0, 100.0),
)
def test_the_channel_gives_out_no_more_energy_than_it_took_in_for_random_inputs(
    seed: int, delay: int, b: float, a: float, c: float
) -> None:
    """Random master velocities and slave forces through the delay lines, each end smoothing what
    it receives: at every tick the energy in at the master is at least the energy out at the slave."""
    rng = np.random.default_rng(seed)
    fwd = DelayLine(3, delay, 0, 0.0, rng, np.zeros(3))
    back = DelayLine(3, delay, 0, 0.0, rng, np.zeros(3))
    u_m, F_m, v_m, u_s = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    xdot_s, F_s, v_s = np.zeros(3), np.zeros(3), np.zeros(3)
    stored = 0.0  # energy in at the master minus energy out at the slave (J, per unit tick)
    lowest = 0.0
    for xdot_m, F_prev in zip(rng.normal(0.0, 0.5, (400, 3)), rng.normal(0.0, 20.0, (400, 3)), strict=True):
        lowpass(back.out, a, v_m)
        wave.master(xdot_m, v_m, b, u_m, F_m)
        fwd.send()[:] = u_m
        fwd.receive()
        lowpass(fwd.out, a, u_s)
        wave.slave(u_s, F_prev, b, c, xdot_s, F_s, v_s)
        back.send()[:] = v_s
        back.receive()
        stored += xdot_m @ F_m - xdot_s @ F_s
        lowest = min(lowest, stored)
    assert lowest >= -1e-9 * max(1.0, stored)


@settings(max_examples=100, deadline=None)
@given(x=arrays(np.float64, (200, 3), elements=st.floats(-1e3, 1e3)), a=st.floats(0.001, 1.0))
def test_smoothing_a_wave_never_adds_energy(x: np.ndarray, a: float) -> None:
    y = np.zeros(3)
    energy_in = energy_out = 0.0
    for row in x:
        lowpass(row, a, y)
        energy_in += row @ row
        energy_out += y @ y
        assert energy_out <= energy_in * (1.0 + 1e-12) + 1e-12


@pytest.mark.parametrize("delay", [1, 5, 50])
def test_the_slave_port_on_a_spring_lets_no_echo_grow_only_with_its_stiffness_term(delay: int) -> None:
    """A held master (a full reflection) and a slave pressing a 3000 N/m spring, released from
    3 N. Counting the force a tick's move adds (c = K dt), the energy can only fall: the force
    never exceeds 3 N. With the one-tick-old force alone (c = 0) each echo returns larger."""
    K, b, dt = 3000.0, 50.0, 1e-3

    def peaks(c: float) -> tuple[float, float]:
        rng = np.random.default_rng(0)
        fwd = DelayLine(3, delay, 0, 0.0, rng, np.zeros(3))
        back = DelayLine(3, delay, 0, 0.0, rng, np.zeros(3))
        held, u_m, F_m = np.zeros(3), np.zeros(3), np.zeros(3)
        xdot, F_s, v_s = np.zeros(3), np.zeros(3), np.zeros(3)
        x = np.array([1e-3, 0.0, 0.0])
        force = np.zeros(5000)
        for k in range(5000):
            wave.master(held, back.out, b, u_m, F_m)
            fwd.send()[:] = u_m
            fwd.receive()
            wave.slave(fwd.out, K * x, b, c, xdot, F_s, v_s)
            x += xdot * dt
            back.send()[:] = v_s
            back.receive()
            force[k] = abs(K * x[0])
        return float(force.max()), float(force[-500:].max())

    highest, late = peaks(K * dt)
    assert highest <= 3.0 + 1e-9
    assert late < 3.0
    _, late_without = peaks(0.0)
    assert late_without > 3.0 * 3.0


def run_ticks(loop: ServoLoop, n: int) -> np.ndarray:
    session = load_session("probe_rate")
    operator = OperatorScript.for_loop(session.data, loop)
    rows = []
    for _ in range(n):
        operator.before_tick(loop)
        rec = loop.tick()
        rows.append(np.concatenate((rec.out.counts, rec.T_w_MRF.ravel(), rec.ft.wrench_S)))
    return np.array(rows)


def test_an_idle_channel_is_no_channel_and_a_delay_delays_the_slave() -> None:
    session = load_session("probe_rate")
    plain = run_ticks(ServoLoop(LoopConfig.from_session(session)), 1100)
    loop = ServoLoop(LoopConfig.from_session(session))
    loop.set_channel(ChannelSettings(seed=5))
    assert loop.link is None
    np.testing.assert_array_equal(run_ticks(loop, 1100), plain)  # bit-identical
    delayed = ServoLoop(LoopConfig.from_session(session))
    delayed.set_channel(ChannelSettings(delay_ms=20.0))
    assert delayed.link is not None
    rows = run_ticks(delayed, 1100)
    z = session.device.n_joints + 11  # the column of T_w_MRF[2, 3]
    moved = np.flatnonzero(np.abs(plain[:, z] - plain[0, z]) > 1e-6)[0]
    moved_delayed = np.flatnonzero(np.abs(rows[:, z] - rows[0, z]) > 1e-6)[0]
    assert moved_delayed == moved + 20  # the slave starts moving 20 ticks later


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("delay_ms", -1.0),
        ("loss", 0.9),
        ("wave_impedance", 0.0),
        ("jitter_ms", float("inf")),
        ("wave_cutoff_hz", -1.0),
        ("wave_cutoff_hz", float("nan")),
    ],
)
def test_channel_settings_outside_their_ranges_are_refused(field: str, value: float) -> None:
    with pytest.raises(InvalidField) as exc:
        ChannelSettings(**{field: value})
    assert exc.value.field == field


def test_the_slaves_limit_bits_cross_the_channel_with_its_reading() -> None:
    """An arm pushed out of reach reports TRACKING with its reading; the controller's output gets
    it one channel delay (plus the reading's one tick) later."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate").with_changes(slave="puma560")))
    loop.set_channel(ChannelSettings(delay_ms=5.0))
    assert loop.link is not None
    up = SlaveCommand(active=True, mode="rate", twist=np.array([0.0, 0.0, 0.25, 0.0, 0.0, 0.0]))
    for _ in range(3000):
        reading = loop.slave.step(up)
    assert ArmStatus(reading.slave_status) & ArmStatus.TRACKING
    seen = []
    for _ in range(10):
        loop.tick()  # the slave holds its out-of-reach reference: TRACKING in every reading
        seen.append(loop.controller.out.slave_status)
    assert seen[0] == 0  # the readings in flight are from before the push
    assert ArmStatus(seen[-1]) & ArmStatus.TRACKING
