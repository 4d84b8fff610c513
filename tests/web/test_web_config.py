"""The web entry point refuses bad input leaving nothing served, and serves for a bounded time."""

from __future__ import annotations

import gzip
import os
import signal
import socket
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
import viser
import websockets.asyncio.server
from web_helpers import listening_tcp_ports, nothing_listens

from app.errors import ConfigError, InvalidField, ListenError
from app.session.files import SESSIONS_DIR
from app.web import launch as server
from app.web.headless import free_port
from app.world.scene import SCENES_DIR


@pytest.mark.parametrize(
    ("scene", "device", "session", "field"),
    [
        ("no_such_scene", "kraft", None, "<file>"),
        ("probe", "no_such_device", None, "<file>"),
        ("probe", "kraft", "no_such_session", None),
    ],
)
def test_unknown_names_raise_config_error_leaving_nothing_served(
    scene: str, device: str, session: str | None, field: str | None
) -> None:
    """The server listens (with the guide) while the inputs are checked: a bad one stops it."""
    port = free_port()
    with pytest.raises(ConfigError) as info:
        server.serve(scene, device, port=port, session=session, open_seconds=0.0)
    if field is not None:
        assert info.value.field == field
    assert nothing_listens(port)


@pytest.mark.parametrize("host", ["127.0.0.1", "0.0.0.0"])
def test_a_busy_port_is_refused_not_swapped_leaving_nothing_served(host: str) -> None:
    """``frhc web --port P`` with P taken (a second ``frhc web``): one error naming the address,
    as ``frhc device serve`` says it. Before, viser served on P + 1 under a printed URL the user
    did not ask for (loopback), and the token gate failed with a traceback after the demo was
    built (0.0.0.0)."""
    before = listening_tcp_ports()
    with socket.create_server(("0.0.0.0", 0)) as holder:
        port = holder.getsockname()[1]
        with pytest.raises(ListenError, match=rf"^cannot listen on {host}:{port}: Address already in use \(") as info:
            server.start_demo("probe", "kraft", host=host, port=port).close()
        assert (info.value.host, info.value.port) == (host, port)
    assert listening_tcp_ports() == before


def test_loopback_detection() -> None:
    assert server.is_loopback("127.0.0.1")
    assert server.is_loopback("localhost")
    assert server.is_loopback("::1")
    assert not server.is_loopback("0.0.0.0")
    assert not server.is_loopback("192.168.1.10")


def test_serve_prints_url_and_returns(capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    server.serve("probe", "kraft", port=port, open_seconds=0.5)
    assert f"http://127.0.0.1:{port}/" in capsys.readouterr().out


def test_demo_runs_everything_at_the_asked_servo_rate() -> None:
    """``frhc web --rate 4000``: the loop ticks every 250 us of simulated time, publishes 50
    snapshots a second, and a session played from the page runs at 4 kHz too (not its own 1 kHz)."""
    app = server.start_demo("probe", "kraft", port=free_port(), servo_rate=4000.0)
    try:
        assert app.rt.wait_running()
        assert app.rt.publish_every == 80
        time.sleep(0.3)
        snap = app.rt.snapshot
        assert snap.ticks > 0
        assert snap.time == pytest.approx(snap.ticks / 4000.0, rel=1e-9)
        app.play_session("peg_ntrfc")
        assert app.rt.config.servo_rate == 4000.0
        assert app.session is not None
        assert app.session.data.servo_rate == 4000.0
    finally:
        app.close()


def test_the_demos_loop_spins_as_asked_and_keeps_it_when_rebuilt() -> None:
    """``frhc web --spin 0.5``: the loop process runs with the pacer told to spin half of each
    period, and so does the loop rebuilt for a session of another scene."""
    app = server.start_demo("probe", "kraft", port=free_port(), spin=0.5)
    try:
        assert app.rt.spin == 0.5
        assert app.rt.wait_running()
        first = app.rt
        app.play_session("peg_ntrfc")
        assert app.rt is not first
        assert app.rt.spin == 0.5
        assert app.rt.wait_running()
    finally:
        app.close()


def test_a_servo_rate_outside_the_sessions_range_is_refused_leaving_nothing_served() -> None:
    port = free_port()
    with pytest.raises(InvalidField) as info:
        server.start_demo("probe", "kraft", port=port, servo_rate=50.0)
    assert info.value.field == "servo_rate"
    assert nothing_listens(port)


def test_a_signal_during_the_demos_build_is_delivered_after_it() -> None:
    """A SIGTERM inside :func:`signals_held` (the demo's imports, where third-party code catches
    ``BaseException``) reaches the handler in place only when the block ends, once."""
    seen: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, _: seen.append(signum))
    try:
        with server.signals_held():
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)  # the handler would have run by now
            assert seen == []
        assert seen == [signal.SIGTERM]
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_the_page_is_served_with_the_head_script_first() -> None:
    """A viser server built inside :func:`script_in_page_head` serves viser's page with the script
    first in its ``<head>``, gzipped or not as asked, with the right length; other paths are
    viser's own answers, and servers built after the block are untouched."""
    original_serve = websockets.asyncio.server.serve
    with server.script_in_page_head("window.frhcProbe = 1;"):
        viser_server = viser.ViserServer(port=free_port(), verbose=False)
    assert websockets.asyncio.server.serve is original_serve
    page = server.VISER_PAGE.read_bytes()
    head = page.index(b"<head>") + len(b"<head>")
    expected = page[:head] + b"<script>window.frhcProbe = 1;</script>" + page[head:]
    base = f"http://127.0.0.1:{viser_server.get_port()}"
    try:
        for path in ("/", "/index.html", "/?fixedDpr=1"):
            for encoding in ("gzip", "identity"):
                request = urllib.request.Request(base + path, headers={"Accept-Encoding": encoding})
                with urllib.request.urlopen(request, timeout=10) as response:
                    raw = response.read()
                    assert int(response.headers["Content-Length"]) == len(raw)
                    body = gzip.decompress(raw) if response.headers["Content-Encoding"] == "gzip" else raw
                    assert response.headers["Content-Encoding"] == encoding
                assert body == expected
        with pytest.raises(urllib.error.HTTPError, match="404"):
            urllib.request.urlopen(base + "/no-such-file.js", timeout=10)
    finally:
        viser_server.stop()


def test_a_scene_whose_arm_cannot_reach_its_home_is_refused_and_the_running_loop_kept(tmp_path: Path) -> None:
    """The page switched to a scene whose PUMA cannot reach the tool's home (turned 90 deg about
    y): the file loads, but building its loop refuses it naming ``tool.home``. The page says so and
    the loop that was running goes on, dropdowns on it. Before, the running loop was stopped first
    and the refusal escaped the callback: no loop, nothing said."""
    text = (SCENES_DIR / "probe.toml").read_text()
    text = text.replace(
        "home = { position = [0.0, 0.0, 0.03] }", "home = { position = [0.0, 0.0, 0.03], zyx_deg = [0.0, 90.0, 0.0] }"
    )
    text = text.replace("[slave]\n", '[slave]\nkind = "puma560"\n', 1)
    path = tmp_path / "turned_puma.toml"
    path.write_text(text)
    app = server.start_demo("probe", "kraft", port=free_port())
    try:
        assert app.rt.wait_running()
        running = app.rt
        app.select(str(path), "kraft")
        assert app.rt is running
        assert running.ended() is None
        ticks = running.snapshot.ticks
        time.sleep(0.3)
        assert running.snapshot.ticks > ticks
        assert "cannot load" in app.controls.record_status.content
        assert "tool.home" in app.controls.record_status.content
        assert app._scene.spec.name == "probe"
    finally:
        app.close()


def test_the_po_pc_checkbox_shows_the_loops_passivity_and_is_greyed_out_on_a_cartesian_device(tmp_path: Path) -> None:
    """A session that enables PO/PC ticks the checkbox; a device without joint ports (touch3,
    driven through its Cartesian interface) greys it out and runs without PO/PC, instead of the
    loop failing to build (a session's PO/PC) or ending in a ValueError (a click); the Kraft
    again: the session's PO/PC is back."""
    session = tmp_path / "probe_pc.toml"
    session.write_text((SESSIONS_DIR / "probe_rate.toml").read_text() + "\n[passivity]\nenabled = true\n")
    app = server.start_demo("probe", "kraft", port=free_port(), session=str(session))
    try:
        pc = app.controls.pc
        assert app.rt.config.passivity.enabled
        assert (pc.value, pc.disabled) == (True, False)
        app.select("probe", "touch3")
        assert app.rt.config.device.name == "touch3"  # built, not refused
        assert not app.rt.config.passivity.enabled
        assert (pc.value, pc.disabled) == (False, True)
        assert "Cartesian" in pc.hint
        assert app.rt.wait_running()
        app.select("probe", "kraft")
        assert (pc.value, pc.disabled) == (True, False)
        assert app.rt.config.passivity.enabled
    finally:
        app.close()


def test_an_edited_copy_of_a_shipped_scene_is_told_apart_from_it(tmp_path: Path) -> None:
    """A session plays an edited copy of ``scenes/probe.toml`` that keeps its ``name = "probe"``
    (a stiffer surface): the scene dropdown shows the copy's path, not "probe", and choosing
    "probe" there loads the shipped file. Before, the dropdown said "probe" and choosing it did
    nothing (the same name counted as the running scene), so the copy ran on."""
    copy = tmp_path / "probe.toml"
    copy.write_text((SCENES_DIR / "probe.toml").read_text())
    session = tmp_path / "edited.toml"
    session.write_text((SESSIONS_DIR / "probe_rate.toml").read_text().replace('scene = "probe"', f'scene = "{copy}"'))
    app = server.start_demo("probe", "kraft", port=free_port())
    try:
        assert app.rt.wait_running()
        app.play_session(str(session))
        assert app.rt.config.scene.path == copy
        assert app.controls.scene.value == str(copy)
        app.controls.scene.value = "probe"  # as a browser's choice: the dropdown's callback runs
        assert app.rt.wait_running()
        assert app.rt.config.scene.path == SCENES_DIR / "probe.toml"
        assert app.controls.scene.value == "probe"
    finally:
        app.close()
