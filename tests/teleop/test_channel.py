"""The master-slave channel and wave variables (app.teleop): delivery, seeding, passivity, the loop."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.controller.types import SlaveCommand
from app.errors import InvalidField
from app.session.loop import LoopConfig, ServoLoop
from app.session.script import OperatorScript
from app.session.spec import load_session
from app.teleop import wave
from app.teleop.channel import ChannelSettings, DelayLine
from app.world.arm import ArmStatus


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
    F_s=arrays(np.float64, 3, elements=st.floats(-50.0, 50.0)),
    b=st.floats(1.0, 1e3),
)
def test_wave_ports_put_exactly_the_wave_power_difference_in(
    xdot: np.ndarray, v_in: np.ndarray, F_s: np.ndarray, b: float
) -> None:
    """Power into the channel at each port is (u^2 - v^2)/2 (master) and (v^2 - u^2)/2 sign-flipped
    (slave): a pure delay between them stores, never creates, energy."""
    u_m, F_m = np.zeros(3), np.zeros(3)
    wave.master(xdot, v_in, b, u_m, F_m)
    np.testing.assert_allclose(xdot @ F_m, 0.5 * (u_m @ u_m - v_in @ v_in), rtol=1e-9, atol=1e-9)
    xdot_s, v_s = np.zeros(3), np.zeros(3)
    wave.slave(u_m, F_s, b, xdot_s, v_s)
    # The slave port gives out xdot_s F_s to the environment; the waves bring in (u^2 - v^2)/2.
    np.testing.assert_allclose(xdot_s @ F_s, 0.5 * (u_m @ u_m - v_s @ v_s), rtol=1e-9, atol=1e-9)


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
    ("field", "value"), [("delay_ms", -1.0), ("loss", 0.9), ("wave_impedance", 0.0), ("jitter_ms", float("inf"))]
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
