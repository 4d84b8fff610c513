"""The device boundary's Cartesian path: the guard, the Inverse Service protocol, the simulated
device in process and served over loopback (``frhc device serve``), drops and stalls."""

from __future__ import annotations

import json
import math
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from device_helpers import make_served_loop, press_into_contact

from app.device.boundary import CartesianReading, LinkStatus
from app.device.cartesian_sim import SimCartesianDevice
from app.device.guard import ForceGuard
from app.device.haply import (
    DeviceServer,
    HaplyClient,
    SimInfo,
    force_command,
    parse_command,
    parse_state,
    state_message,
)
from app.device.spec import CartesianSpec, load_device
from app.session.cartesian_loop import CartesianServoLoop
from app.session.log import read_log
from app.session.loop import LoopConfig, ServoLoop
from app.session.run import run_session
from app.session.script import Operator, OperatorScript
from app.session.spec import load_session
from app.world.scene import load_scene

DT = 1e-3
#: The touch3 session: hand 3 cm below the reference from 1 s on, deadman and reflection held.
SESSION = """
scene = "probe"
device = "touch3"
mode = "rate"
duration = {duration}
servo_rate = 1000.0
accommodation = true

[[events]]
t = 0.0
deadman = true
reflection = true

[[waypoints]]
t = 0.3
position = [0.0, 0.0, 0.0]

[[waypoints]]
t = 1.0
position = [0.0, 0.0, -0.03]
"""


def fresh_reading() -> CartesianReading:
    r = CartesianReading()
    r.fresh = True
    r.status = LinkStatus.RAMPING
    return r


# -- the guard ------------------------------------------------------------------------------------


def test_guard_limits_the_force_keeping_its_direction_and_drops_moments_of_a_3dof_device() -> None:
    guard = ForceGuard(CartesianSpec(force_limit=3.3, torque_limit=0.5, ramp_time=0.0), torque_capable=False)
    sent = guard.apply(np.array([30.0, 0.0, 40.0, 1.0, 2.0, 3.0]), fresh_reading(), DT)
    np.testing.assert_allclose(sent, [3.3 * 0.6, 0.0, 3.3 * 0.8, 0.0, 0.0, 0.0])
    within = guard.apply(np.array([1.0, -2.0, 0.5, 0.0, 0.0, 0.0]), fresh_reading(), DT)
    np.testing.assert_allclose(within, [1.0, -2.0, 0.5, 0, 0, 0])


def test_guard_limits_moments_of_a_6dof_device_and_zeroes_non_finite_wrenches() -> None:
    guard = ForceGuard(CartesianSpec(force_limit=10.0, torque_limit=0.5, ramp_time=0.0), torque_capable=True)
    sent = guard.apply(np.array([0.0, 0.0, 1.0, 0.0, 3.0, 4.0]), fresh_reading(), DT)
    np.testing.assert_allclose(sent, [0, 0, 1.0, 0, 0.3, 0.4])
    sent = guard.apply(np.array([np.nan, 0.0, 1.0, 0.0, 0.0, 0.1]), fresh_reading(), DT)
    np.testing.assert_array_equal(sent, [0, 0, 0, 0, 0, 0.1])


def test_guard_limits_a_huge_finite_force_to_the_limit_along_it_without_a_warning() -> None:
    """A finite force whose squared length overflows (a client's 1e200 N, as ``frhc device
    serve`` takes any finite number) is the limit along it, as the docstring says. Before: the
    sum of squares overflowed to inf, the force was zeroed and numpy printed a RuntimeWarning."""
    guard = ForceGuard(CartesianSpec(force_limit=3.3, torque_limit=0.5, ramp_time=0.0), torque_capable=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sent = guard.apply(np.array([1e200, 0.0, -1e200, 0.0, 0.0, 0.0]), fresh_reading(), DT)
    np.testing.assert_allclose(sent, [3.3 / math.sqrt(2), 0.0, -3.3 / math.sqrt(2), 0.0, 0.0, 0.0])


def test_guard_ramps_after_connect_zeroes_on_a_missed_sample_and_ramps_faster_after_a_gap() -> None:
    spec = CartesianSpec(force_limit=5.0, ramp_time=0.1, gap_ramp_time=0.01)
    guard = ForceGuard(spec, torque_capable=False)
    push = np.array([0.0, 0.0, 2.0, 0, 0, 0])
    r = fresh_reading()
    levels = [guard.apply(push, r, DT)[2] / 2.0 for _ in range(100)]
    np.testing.assert_allclose(levels, np.arange(1, 101) * DT / 0.1, rtol=1e-9)
    assert r.status == LinkStatus.OK
    r.fresh = False
    np.testing.assert_array_equal(guard.apply(push, r, DT), 0.0)  # the same period's command
    assert (r.status, r.watchdog_trips, r.motors_off) == (LinkStatus.STALLED, 1, True)
    r.fresh = True
    assert guard.apply(push, r, DT)[2] == pytest.approx(2.0 * DT / 0.01)
    r.status = LinkStatus.DISCONNECTED  # a reconnect after a loss ramps the slow way again
    r.fresh = False
    guard.apply(push, r, DT)
    r.fresh, r.status = True, LinkStatus.RAMPING
    assert guard.apply(push, r, DT)[2] == pytest.approx(2.0 * DT / 0.1)


# -- the protocol -------------------------------------------------------------------------------


def test_state_and_command_messages_have_the_fields_isaac_labs_haply_client_reads() -> None:
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.05]
    msg = json.loads(state_message("inv3-1", T, (True, False, True), None))
    inv = msg["inverse3"][0]
    assert inv["device_id"] == "inv3-1"
    assert inv["state"]["cursor_position"] == {"x": 0.1, "y": -0.2, "z": 0.05}
    grip = msg["wireless_verse_grip"][0]["state"]
    assert grip["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    assert grip["buttons"] == {"a": True, "b": False, "c": True}
    assert "frhc_sim" not in msg
    cmd = json.loads(force_command("inv3-1", np.array([1.5, 0.0, -2.0]), None, sim=False))
    assert cmd == {
        "inverse3": [
            {"device_id": "inv3-1", "commands": {"set_cursor_force": {"values": {"x": 1.5, "y": 0.0, "z": -2.0}}}}
        ]
    }


def test_messages_round_trip_pose_buttons_force_and_hand_target() -> None:
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [0.01, 0.02, 0.03]
    state = parse_state(state_message("d", T, (False, True, False), {"device": "touch3"}))
    np.testing.assert_allclose(state.R, R, atol=1e-15)
    np.testing.assert_array_equal(state.position, [0.01, 0.02, 0.03])
    assert state.buttons == (False, True, False)
    assert state.sim == SimInfo("touch3")
    force, target, sim = parse_command(force_command("d", np.array([0.1, 0.2, 0.3]), T, sim=True))
    np.testing.assert_array_equal(force, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(target, T)
    assert sim
    with pytest.raises(ValueError, match=r"length >= 1 - at `\$.inverse3`"):
        parse_state('{"inverse3": []}')


# -- the simulated device in process ----------------------------------------------------------


def test_touch3_is_driven_through_its_cartesian_interface_and_kraft_is_not() -> None:
    scene = load_scene("probe")
    for name, kind in (("touch3", CartesianServoLoop), ("kraft", ServoLoop)):
        spec = load_device(name)
        assert type(ServoLoop(LoopConfig(spec, scene, spec.data.gains))) is kind


def test_simulated_sdk_renders_the_wrench_as_a_force_on_the_grip() -> None:
    """The SDK's J^T and gravity compensation: with the hand released, a commanded +z force of
    1 N lifts the grip, and zero force holds it where it is (gravity compensated)."""
    device = SimCartesianDevice(load_device("touch3"))
    device.set_hand_target(None)
    z0 = device.reading.T_0_G[2, 3]
    for _ in range(300):
        device.step(np.zeros(6), DT)
    assert abs(device.reading.T_0_G[2, 3] - z0) < 2e-3
    for _ in range(100):
        device.step(np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]), DT)
    assert device.reading.T_0_G[2, 3] - z0 > 5e-3


def test_a_simulated_sdk_whose_plant_goes_unstable_sends_no_fresh_sample(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The plant's joint speed turned NaN: its simulation stops (``DevicePlant.fault``) and the SDK
    reports no new sample from then on, so the guard zeroes the force (STALLED), as for a device
    whose amplifier faulted. Before, the SDK went on reporting the pose of MuJoCo's reset."""
    monkeypatch.chdir(tmp_path)
    device = SimCartesianDevice(load_device("touch3"))
    spec = load_device("touch3").data.cartesian
    assert spec is not None
    guard = ForceGuard(spec, device.torque_capable)
    push = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    for _ in range(5):
        reading = device.step(guard.apply(push, device.reading, DT), DT)
    assert reading.fresh
    plant = device.plant
    plant.data.qvel[plant.dof_slice.start] = math.nan
    reading = device.step(guard.apply(push, reading, DT), DT)
    assert plant.fault is not None
    assert not reading.fresh
    np.testing.assert_array_equal(guard.apply(push, reading, DT), 0.0)
    assert reading.status == LinkStatus.STALLED
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def session_file(tmp_path: Path, duration: float) -> Path:
    path = tmp_path / "touch3_probe.toml"
    path.write_text(SESSION.format(duration=duration))
    return path


def steady_contact_force(out_dir: Path, t0: float) -> tuple[float, float]:
    """Mean contact force (N, z at {MRF}) and mean force sent to the device (N, z in {0}) after t0."""
    import pyarrow.parquet as pq

    table = pq.read_table(out_dir / "log")
    t = table["t"].to_numpy()
    keep = t >= t0
    return (
        float(np.mean(table["contact_MRF_fz"].to_numpy()[keep])),
        float(np.mean(table["tau_sat_2"].to_numpy()[keep])),
    )


def test_touch3_session_in_process_reflects_k_t_times_the_contact_force_upward(tmp_path: Path) -> None:
    run_session(load_session(session_file(tmp_path, 2.5)), out_dir=tmp_path / "run", plots=False)
    contact, sent = steady_contact_force(tmp_path / "run", 2.0)
    assert contact > 5.0  # the tool presses on the probe's surface
    # Eq 6 and K_T = 0.1 on forces: the device pushes the hand back up with a tenth of it.
    assert sent == pytest.approx(0.1 * contact, rel=0.02)


def test_a_cartesian_devices_log_replays_its_grip_reference_and_tool_without_links(tmp_path: Path) -> None:
    """The replay of a touch3 run (its q_* columns are the grip pose's six coordinates): the last
    row's view is the live loop's last state, and the device's links, which the log cannot pose,
    are not drawn."""
    from app.web.replay import LogReplay

    result = run_session(load_session(session_file(tmp_path, 1.2)), out_dir=tmp_path / "run", plots=False)
    meta = json.loads((tmp_path / "run" / "log" / "_meta.json").read_text())
    assert (meta["cartesian"], meta["device_url"]) == (True, None)
    replay = LogReplay(tmp_path / "run")
    assert replay.cartesian
    assert len(replay) == 1200
    last = replay.snapshot(len(replay) - 1)
    loop = result.loop
    np.testing.assert_allclose(last.T_0_G, loop.reading.T_0_G, atol=1e-12)
    # {G0} recovered from the grip pose and Delta X (Eq 2-4 inverted) is the controller's reference.
    np.testing.assert_allclose(last.T_0_G0, loop.controller.out.T_0_G0, atol=1e-9)
    np.testing.assert_allclose(last.T_w_MRF, loop.record.T_w_MRF, atol=1e-12)
    assert last.time == pytest.approx(loop.time)
    assert last.geom_xpos.shape == (0, 3)
    assert last.geom_xmat.shape == (0, 3, 3)


# -- served over loopback -----------------------------------------------------------------------


#: How long (s) the link test's loop waits for a reply in the ticks its stream is stopped: no reply
#: comes however long it waits, so the length only sets the test's time (and how long the served
#: device runs on under zero force).
STOPPED_WAIT = 0.05


#: How long (s) the loopback comparison's client waits for a reply and its server for a command
#: before either counts the other as stopped. Under load (three busy loops beside the test on the
#: 2-core machine) this process was starved for longer than the served device's own 20 ms
#: watchdog, which then ran the simulation on under zero force (8 trips: the steady force 1.5 %
#: off the in-process run's; none: identical), and longer than 0.5 s (a stalled tick,
#: watchdog_trips 1 and 3). Neither timeout is what the tests below compare.
STARVED_WAIT = 10.0


def test_session_over_loopback_reaches_the_in_process_contact_force(tmp_path: Path) -> None:
    """The same session against ``frhc device serve``: the served simulation is synchronous, so
    the steady contact force matches the in-process run within 2 %. The comparison is of forces,
    not of the watchdogs (the tests below): client and server wait up to :data:`STARVED_WAIT`
    for each other, because on this shared machine a reply or a command a period late is common,
    and each would be a (correct) zero for a period, or a period run under zero force."""
    session = load_session(session_file(tmp_path, 2.5))
    run_session(session, out_dir=tmp_path / "local", plots=False)
    served = DeviceServer(SimCartesianDevice(load_device("touch3")), port=0, watchdog=STARVED_WAIT).start()
    try:
        result = run_session(
            session,
            out_dir=tmp_path / "served",
            plots=False,
            device_url=f"ws://127.0.0.1:{served.port}",
            sample_wait=STARVED_WAIT,
        )
    finally:
        served.shutdown()
    local, _ = steady_contact_force(tmp_path / "local", 2.0)
    remote, _ = steady_contact_force(tmp_path / "served", 2.0)
    assert remote == pytest.approx(local, rel=0.02)
    assert result.summary["device"] == "touch3"
    assert result.summary["watchdog_trips"] == 0
    assert served.log.events == []  # the server never ran on under zero force: synchronous throughout
    assert served.log.commands == 2500 + 1  # every tick's, and the zero force sent on closing


def test_served_device_holds_its_own_force_limit_and_answers_each_command_once(served: DeviceServer) -> None:
    """A client that is not frhc (no guard, no ``frhc_sim``): the served device clips 10 N to its
    3.3 N, keeps the direction, and steps one period per command."""
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{served.port}", ping_interval=None) as ws:
        first = parse_state(ws.recv(timeout=5.0))
        assert first.device_id == "sim-touch3"
        assert first.sim is not None
        t0 = first.sim.time
        assert t0 is not None
        ws.send(force_command(first.device_id, np.array([6.0, 0.0, -8.0]), None, sim=False))
        second = parse_state(ws.recv(timeout=5.0))
    np.testing.assert_allclose(served.device.applied[:3], [3.3 * 0.6, 0.0, -3.3 * 0.8])
    for _ in range(500):  # the server's thread sees the close (bounded wait)
        if served.log.events and served.log.events[-1].reason == "disconnect":
            break
        time.sleep(0.01)
    assert served.log.events[-1].reason == "disconnect"
    np.testing.assert_array_equal(served.log.commanded, 0.0)  # zeroed when the client left
    assert second.sim is not None
    assert second.sim.time == pytest.approx(t0 + DT)


def test_a_served_device_refuses_a_hand_target_that_is_not_rigid_and_the_hand_holds(served: DeviceServer) -> None:
    """A hand target scaled by 2 % (no pose: the slave refuses such a command, :func:`pose_error`)
    closes the connection with 1003 naming the field, as any bad command does; the hand holds the
    last target it accepted, and the force is zeroed."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    hand = served.device.plant.hand
    with connect(f"ws://127.0.0.1:{served.port}", ping_interval=None) as ws:
        first = parse_state(ws.recv(timeout=5.0))
        held = np.eye(4)
        held[:3, 3] = first.position - np.array([0.0, 0.0, 0.01])
        ws.send(force_command(first.device_id, np.array([0.0, 0.0, -1.0]), held, sim=True))
        parse_state(ws.recv(timeout=5.0))
        scaled = held.copy()
        scaled[:3, :3] *= 1.02
        ws.send(force_command(first.device_id, np.zeros(3), scaled, sim=True))
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=5.0)
    assert closed.value.rcvd is not None
    assert closed.value.rcvd.code == 1003
    assert closed.value.rcvd.reason.startswith("$.frhc_sim.hand_target is not rigid: its rotation block is off")
    assert served.zeroed.wait(5.0)
    np.testing.assert_array_equal(served.log.commanded, 0.0)
    assert hand.T_0_H is not None
    np.testing.assert_array_equal(hand.T_0_H, held)


def test_a_silent_client_zeroes_the_force_on_the_watchdog_and_the_device_runs_on_in_real_time(
    served: DeviceServer,
) -> None:
    """After a command and then 0.3 s of silence, the served device has run on for that silence
    less the watchdog (zero force, real time) and one period for the next command: its clock is the
    wall clock, not a count of 1 ms receive timeouts (each returns late, under load much later).
    Before, each timeout counted one period."""
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{served.port}", ping_interval=None) as ws:
        first = parse_state(ws.recv(timeout=5.0))
        before_first = time.monotonic()
        ws.send(force_command(first.device_id, np.array([0.0, 0.0, -0.5]), None, sim=True))
        t0 = parse_state(ws.recv(timeout=5.0)).sim.time
        after_first = time.monotonic()
        time.sleep(0.3)
        assert served.zeroed.wait(5.0)
        before_last = time.monotonic()
        ws.send(force_command(first.device_id, np.zeros(3), None, sim=True))
        after_last = time.monotonic()
        t1 = parse_state(ws.recv(timeout=5.0)).sim.time
    assert served.log.events[0].reason == "watchdog"
    ran_on = t1 - t0 - DT  # less the last command's own period
    # The server heard the two commands somewhere between these client times.
    least, most = before_last - after_first, after_last - before_first
    assert least - served.watchdog - 2 * DT <= ran_on <= most - served.watchdog + 2 * DT, (ran_on, least, most)


def test_dropped_connection_zeroes_the_force_the_next_period_and_ramps_back_on_reconnect(served: DeviceServer) -> None:
    loop = make_served_loop(served.port)
    press_into_contact(loop)
    for _ in range(100):  # the device renders a force (a late reply makes the last one sent zero)
        if np.any(served.log.commanded):
            break
        loop.tick()
    assert np.any(served.log.commanded)
    served.zeroed.clear()
    served.drop_client()
    assert served.zeroed.wait(5.0)
    np.testing.assert_array_equal(served.log.commanded, 0.0)  # the device's own side
    assert served.log.events[-1].reason == "disconnect"
    # The tick that meets the closed connection (after any reply already on its way: on a
    # loaded machine one may be) sends nothing, and the next period's wrench is zero.
    for _ in range(10):
        loop.tick()
        if loop.reading.status == LinkStatus.DISCONNECTED:
            break
    assert loop.reading.status == LinkStatus.DISCONNECTED
    np.testing.assert_array_equal(loop.wrench, 0.0)
    for _ in range(200_000):  # the client retries every 0.1 s of wall time
        loop.tick()
        if loop.reading.status != LinkStatus.DISCONNECTED:
            break
    assert loop.reading.status == LinkStatus.RAMPING
    assert served.log.connections == 2
    spec = load_device("touch3").data.cartesian
    assert spec is not None
    assert loop.guard.level == pytest.approx(DT / spec.ramp_time)  # the first period after
    for k in range(2, 11):
        loop.tick()
        # On the ramp, or below it where a late reply (this machine is shared) restarted it.
        assert 0.0 <= loop.guard.level <= k * DT / spec.ramp_time + 1e-12
    loop.close()


def test_stalled_stream_trips_the_watchdog_and_the_force_ramps_back_after_the_gap(served: DeviceServer) -> None:
    loop = make_served_loop(served.port)
    press_into_contact(loop)
    trips = loop.reading.watchdog_trips
    served.pause_stream(True)
    # The first tick without a state within one period (a reply already on its way may come
    # first on a loaded machine) zeroes the next period's wrench.
    for _ in range(10):
        loop.tick()
        if not loop.reading.fresh:
            break
    assert loop.reading.status == LinkStatus.STALLED
    assert loop.reading.watchdog_trips > trips
    np.testing.assert_array_equal(loop.wrench, 0.0)
    served.pause_stream(False)
    for _ in range(100):
        loop.tick()
        if loop.reading.fresh:
            break
    spec = load_device("touch3").data.cartesian
    assert spec is not None
    assert loop.reading.status == LinkStatus.RAMPING
    # The gap ramp's first step (the connect ramp's, slower, if the gap fell within it).
    assert loop.guard.level in (pytest.approx(DT / spec.gap_ramp_time), pytest.approx(DT / spec.ramp_time))
    loop.close()


def test_web_loop_process_drives_touch3_and_publishes_its_link_state() -> None:
    """The browser demo's loop process with the Cartesian device (as `frhc web --device touch3` or
    the page's device list starts it): it ticks, the hand moves the grip, and the page's snapshot
    says the link is up."""
    from app.web.realtime import RealtimeLoop

    spec = load_device("touch3")
    rt = RealtimeLoop(LoopConfig(spec, load_scene("probe"), spec.data.gains))
    rt.start()
    try:
        assert rt.wait_running()
        first = rt.snapshot
        target = first.T_0_G.copy()
        target[0, 3] += 0.02
        rt.set_hand_target(target)
        for _ in range(3000):  # up to 30 s on a loaded machine; usually 1 s
            snap = rt.snapshot
            if snap.time > first.time + 1.0:
                break
            time.sleep(0.01)
        assert snap.time > first.time + 1.0
        assert snap.device_link == "OK"  # past the 0.5 s connect ramp
        assert snap.T_0_G[0, 3] - first.T_0_G[0, 3] > 0.01  # the hand pulled the grip along x
    finally:
        rt.stop()


def test_realtime_run_against_a_served_device_raises_its_priority_for_the_ticks_only(
    tmp_path: Path, served: DeviceServer, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``frhc run --realtime --device ws://...``: the ticks run at the priority the web demo's loop
    asks for, and the run says which it got (summary and the pacing line); the log's writer
    thread, started by the raised loop, runs at ordinary scheduling; the caller's scheduling is
    back afterwards."""
    import os

    from app.cli import main
    from app.session.log import TickLog
    from app.session.pacer import SCHEDULING

    writer_policies: list[int] = []
    append = TickLog._append

    def recording_append(self: TickLog, *args: object) -> None:
        writer_policies.append(os.sched_getscheduler(0))
        append(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(TickLog, "_append", recording_append)
    before = os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, 0)
    out = tmp_path / "out"
    argv = ["run", str(session_file(tmp_path, 0.5)), "--out", str(out), "--no-plots", "--realtime"]
    assert main([*argv, "--device", f"ws://127.0.0.1:{served.port}"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scheduling"] in SCHEDULING[1:]  # SCHED_FIFO where permitted, else a lower niceness
    assert f"at {summary['scheduling']}" in capsys.readouterr().out
    assert set(writer_policies) == {os.SCHED_OTHER}  # rows were written, all at ordinary scheduling
    assert (os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, 0)) == before


class LinkTrouble:
    """The session's script, plus trouble on the served device's link before given rows' ticks:
    its stream stalls for ``stall_ticks`` ticks from row ``stall_at``, and its connection is
    pulled (as a cable would be) before row ``drop_at``.

    The loop's client waits :data:`STOPPED_WAIT` for a reply in the stopped ticks and the run's
    ``sample_wait`` (:data:`STARVED_WAIT`) in all others, so that a tick is stalled because the
    stream stopped, never because this process was starved (with one wait of 0.5 s for all, tick
    0 stalled in 1 of 5 runs beside two busy loops)."""

    def __init__(self, script: Operator, served: DeviceServer, stall_at: int, stall_ticks: int, drop_at: int) -> None:
        self.script = script
        self.served = served
        self.stall_at, self.stall_ticks, self.drop_at = stall_at, stall_ticks, drop_at
        self.row = 0  # the log row the next tick writes

    def before_tick(self, loop: ServoLoop) -> None:
        self.script.before_tick(loop)
        client = loop.device
        assert isinstance(client, HaplyClient)
        if self.row == self.stall_at:
            self.served.pause_stream(True)
            client.period = STOPPED_WAIT
        elif self.row == self.stall_at + self.stall_ticks:
            self.served.pause_stream(False)
            client.period = STARVED_WAIT
        elif self.row == self.drop_at:
            self.served.drop_client()
        self.row += 1


def runs(column: np.ndarray) -> list[tuple[int, int, int]]:
    """``(value, first row, length)`` of each run of equal values in ``column``."""
    edges = np.flatnonzero(np.diff(column)) + 1
    starts = np.concatenate(([0], edges))
    lengths = np.diff(np.concatenate((starts, [len(column)])))
    return [(int(column[s]), int(s), int(n)) for s, n in zip(starts, lengths, strict=True)]


def test_link_state_is_logged_per_tick_through_a_stall_and_a_dropped_connection_mid_contact(
    tmp_path: Path, served: DeviceServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The log's ``device_link`` column against ``frhc device serve`` (in this process): connect
    ramp, OK in contact, three stalled ticks exactly where the stream stopped (the watchdog's
    zero), the gap ramp, OK, DISCONNECTED from exactly the tick that met the pulled connection,
    the connect ramp again on reconnect, OK. A replay's status line says the same."""
    from app.device import haply
    from app.web.replay import LogReplay

    monkeypatch.setattr(haply, "RETRY_INTERVAL", 0.0)  # reconnect at the next tick (default 0.1 s of wall time)
    session = load_session(session_file(tmp_path, 2.2))
    stall_at, drop_at = 1400, 1600  # contact from 1.26 s on
    spec = load_device("touch3").data.cartesian
    assert spec is not None
    result = run_session(
        session,
        out_dir=tmp_path / "run",
        plots=False,
        device_url=f"ws://127.0.0.1:{served.port}",
        sample_wait=STARVED_WAIT,  # a reply is late only when the stream stopped (LinkTrouble)
        operator=lambda loop: LinkTrouble(OperatorScript.for_loop(session.data, loop), served, stall_at, 3, drop_at),
    )
    table = read_log(tmp_path / "run" / "log")
    link = table["device_link"].to_numpy()
    assert len(link) == 2200
    ok, ramping, stalled, gone = (int(s) for s in LinkStatus)
    connect_ramp, gap_ramp = round(spec.ramp_time / DT), round(spec.gap_ramp_time / DT)
    got = runs(link)
    # The ramp's last tick reaches level 1 (OK) or, by rounding of the sum, one tick later.
    assert [(v, start) for v, start, _ in got[:3]] == [(ramping, 0), (ok, got[1][1]), (stalled, stall_at)]
    assert got[0][2] in (connect_ramp - 1, connect_ramp)
    assert got[2][2] == 3
    assert got[3][:2] == (ramping, stall_at + 3)
    assert got[3][2] in (gap_ramp - 1, gap_ramp)
    assert got[4][0] == ok
    assert got[5][:2] == (gone, drop_at)  # the first tick after the pull
    assert got[6][0] == ramping  # reconnected (a tick or a few later: the server frees the device first)
    assert got[6][2] in (connect_ramp - 1, connect_ramp)
    assert got[7][0] == ok
    assert len(got) == 8
    # The summary counts the ticks of each state but OK, as the log has them (before: not at all).
    assert result.summary["device_link_ticks"] == {
        "RAMPING": got[0][2] + got[3][2] + got[6][2],
        "STALLED": 3,
        "DISCONNECTED": got[5][2],
    }
    contacts = table["contacts"].to_numpy()
    assert contacts[stall_at - 1] > 0  # both happened mid-contact
    assert contacts[drop_at - 1] > 0
    assert table["tau_sat_2"].to_numpy()[drop_at - 1] > 0.0  # the device was pushing the hand back
    replay = LogReplay(tmp_path / "run")
    assert [replay.snapshot(i).device_link for i in (drop_at - 1, drop_at, stall_at)] == [
        "OK",
        "DISCONNECTED",
        "STALLED",
    ]
