"""A servo-loop process that dies under a running demo (killed by a signal here): the page and
stderr say so, and Play starts a new loop without restarting the server."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest
from web_helpers import wait_until

from app.web.commands import SetHandTarget
from app.web.headless import free_port
from app.web.launch import start_demo


def test_a_loop_process_killed_by_a_signal_is_said_and_play_starts_a_new_one(
    capfd: pytest.CaptureFixture[str],
) -> None:
    # The session's loop is the demo's own: Play needs no rebuild unless the loop is gone.
    app = start_demo("probe", "kraft", port=free_port(), session="probe_rate")
    try:
        assert app.rt.wait_running()
        first = app.rt
        assert first.pid is not None
        assert first.ended() is None
        os.kill(first.pid, signal.SIGKILL)
        wait_until(lambda: "stopped (killed by SIGKILL)" in app.panel.play_status.content, "the page's notice")
        assert "Play, Try the peg task or Reset starts a new one" in app.panel.try_status.content
        assert "the servo loop process stopped (killed by SIGKILL)" in app.controls.status_notes.content
        err = capfd.readouterr().err
        assert err.count("frhc web: the servo loop process stopped (killed by SIGKILL)") == 1  # said once

        # Commands to the dead loop are dropped: ~1 MB of them would fill the pipe nobody reads.
        hand = SetHandTarget(app.rt.loop.reading.T_0_G.copy())
        for _ in range(5000):
            first.send(hand)

        app.play_session("probe_rate")
        assert app.rt is not first
        assert app.rt.ended() is None
        wait_until(lambda: app.rt.snapshot.playing is not None, "the new loop plays")
        wait_until(lambda: "playing `probe_rate`" in app.panel.play_status.content, "the page shows the play")
        assert "stopped" not in app.controls.status_notes.content

        # A loop that dies while it starts: Play returns (before: RuntimeError in viser's callback
        # thread, a traceback) and the page says the loop stopped.
        second = app.rt
        assert second.pid is not None
        os.kill(second.pid, signal.SIGKILL)
        wait_until(lambda: "stopped (killed by SIGKILL)" in app.panel.play_status.content, "the second loss")
        raised: list[BaseException] = []

        def play() -> None:
            try:
                app.play_session("probe_rate")
            except BaseException as exc:  # the test asserts there is none
                raised.append(exc)

        player = threading.Thread(target=play)
        player.start()
        end = time.monotonic() + 30
        while app.rt is second or app.rt.pid is None:  # polled finely: killed while it builds its loop
            assert time.monotonic() < end, "the third loop is spawned"
            time.sleep(0.001)
        os.kill(app.rt.pid, signal.SIGKILL)
        player.join(60)
        assert not player.is_alive()
        assert raised == []
        assert app.rt.snapshot.playing is None
        wait_until(lambda: "stopped (killed by SIGKILL)" in app.panel.play_status.content, "the page's notice")
    finally:
        app.close()
        app.server.stop()
