"""The paced loop process of the web demo, without a browser: it runs the same ticks as a headless loop."""

from __future__ import annotations

import dataclasses
import time
import typing
from pathlib import Path

import numpy as np
import pytest

from app.controller.passivity import PassivitySettings
from app.errors import InvalidField
from app.session.log import read_log
from app.session.loop import LoopConfig, ServoLoop
from app.session.run import run_session
from app.session.spec import SESSIONS_DIR, load_session
from app.teleop.channel import ChannelSettings
from app.web.commands import (
    COMMANDS,
    LoopCommand,
    Pause,
    Play,
    SetChannel,
    SetPassivity,
    SetSpeed,
    UnknownCommand,
    check_command,
)
from app.web.loop_process import LoopHost
from app.web.realtime import RealtimeLoop
from app.web.snapshot import SharedSnapshot


def test_played_session_gives_the_headless_ticks_exactly(tmp_path: Path) -> None:
    """Fed the same script, the real-time loop process logs bit-identical ticks (all but timing)."""
    text = (SESSIONS_DIR / "probe_rate.toml").read_text().replace("duration = 5.0", "duration = 2.5")
    path = tmp_path / "probe_short.toml"
    path.write_text(text)
    session = load_session(path)
    headless = run_session(session, out_dir=tmp_path / "headless", plots=False)
    assert headless.summary["contact_fraction"] > 0.05  # the short run still reaches the surface

    # A generous amplifier watchdog: a scheduling hiccup on a busy machine then costs catch-up
    # ticks (the same ticks) rather than a simulated stall (other ticks).
    rt = RealtimeLoop(dataclasses.replace(LoopConfig.from_session(session), watchdog=1.0))
    rt.start()
    try:
        assert rt.wait_running()
        rt.set_deadman(True)  # state from before the play must not leak into it
        rt.play(session, record=tmp_path / "web" / "log")
        seen_playing = False
        end = time.monotonic() + 30.0
        while time.monotonic() < end:
            playing = rt.snapshot.playing
            seen_playing |= playing == path
            if seen_playing and playing is None:
                break
            time.sleep(0.01)
        assert seen_playing
        assert rt.snapshot.playing is None
        assert rt.stats().ticks > session.data.n_ticks
    finally:
        rt.stop()

    a = read_log(tmp_path / "headless" / "log")
    b = read_log(tmp_path / "web" / "log")
    assert a.num_rows == b.num_rows == session.data.n_ticks
    for name in a.column_names:
        if not name.endswith("_us"):
            np.testing.assert_array_equal(b[name].to_numpy(), a[name].to_numpy(), err_msg=name)


def test_unknown_commands_are_refused_loudly() -> None:
    with pytest.raises(UnknownCommand, match="not a loop command"):
        check_command(("deadman", True))


def test_every_command_type_is_known_to_both_ends() -> None:
    """The typed union and the runtime list of commands name the same classes."""
    assert set(typing.get_args(LoopCommand)) == set(COMMANDS)


def test_loop_host_applies_passivity_delay_pause_and_speed() -> None:
    """The loop process's command handler, without the process: each command reaches the loop."""
    session = load_session("probe_rate")
    loop = ServoLoop(LoopConfig.from_session(session))
    host = LoopHost(loop, SharedSnapshot(), publish_every=20)
    host.apply(SetPassivity(PassivitySettings(enabled=True)))
    assert loop.controller.passivity.enabled
    host.apply(SetChannel(ChannelSettings(delay_ms=20.0)))
    assert loop.link is not None
    assert not host.apply(SetSpeed(2.0))  # no session playing: the loop keeps real time
    assert host.speed == 1.0
    assert not host.apply(Pause(True))
    before = loop.ticks
    host.tick()
    assert loop.ticks == before  # paused: no tick
    assert host.apply(Pause(False))
    host.tick()
    assert loop.ticks == before + 1
    with pytest.raises(InvalidField, match="speed"):
        SetSpeed(10.0)


def test_speed_belongs_to_the_playing_session() -> None:
    """A speed set during a play holds until the script ends, then the loop is back at real time."""
    session = load_session("probe_rate").with_changes(duration=0.01)
    loop = ServoLoop(LoopConfig.from_session(session))
    host = LoopHost(loop, SharedSnapshot(), publish_every=20)
    assert host.apply(Play(session.data, session.gains, session.path))
    assert host.apply(SetSpeed(4.0))
    assert (host.speed, host.publisher.speed) == (4.0, 4.0)
    ended = [host.tick() for _ in range(session.data.n_ticks)]
    assert ended == [False] * (session.data.n_ticks - 1) + [True]  # the last scripted tick ends it
    assert host.operator is None
    assert (host.speed, host.publisher.speed) == (1.0, 1.0)
