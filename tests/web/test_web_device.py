"""``frhc web --device ws://...``: the browser demo driving a device served by ``frhc device serve``
(a real subprocess, over loopback) through the device boundary, with a real viser server. The
served device is the simulated touch3: a stand-in for a real Inverse Service, which cannot be here.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator

import pytest
from web_helpers import nothing_listens

from app.web.headless import free_port
from app.web.launch import start_demo
from app.web.server import DemoApp
from app.web.snapshot import Snapshot

WAIT_S = 60.0  # bound on each wait below (a loaded machine); the conditions are what is tested


def wait_for(app: DemoApp, done: Callable[[Snapshot], bool]) -> Snapshot:
    end = time.monotonic() + WAIT_S
    snap = app.rt.snapshot
    while not done(snap) and time.monotonic() < end:
        time.sleep(0.02)
        snap = app.rt.snapshot
    return snap


@pytest.fixture
def served() -> Iterator[tuple[subprocess.Popen[str], str]]:
    cmd = [sys.executable, "-m", "app.cli", "device", "serve", "--device", "touch3", "--port", "0"]
    server = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert server.stdout is not None
        found = re.search(r"ws://[\d.]+:(\d+)", server.stdout.readline())
        assert found is not None, "frhc device serve did not print its address"
        yield server, f"ws://127.0.0.1:{found.group(1)}"
    finally:
        server.terminate()
        server.wait(timeout=10)


def test_demo_drives_a_served_device_shows_its_link_and_no_links_it_cannot_pose(
    served: tuple[subprocess.Popen[str], str],
) -> None:
    process, url = served
    app = start_demo("probe", url, port=free_port())
    try:
        assert app.rt.config.device_url == url
        assert app.rt.config.device.name == "touch3"  # the device file the server named
        assert app.rt.wait_running(), "the servo loop process did not publish within 60 s"
        first = wait_for(app, lambda s: s.device_link == "OK")  # past the 0.5 s connect ramp
        assert first.device_link == "OK"
        target = first.T_0_G.copy()
        target[0, 3] += 0.02
        app.move_hand_target(target)  # the page's gizmo: sent to the served simulation's hand
        moved = wait_for(app, lambda s: s.T_0_G[0, 3] - first.T_0_G[0, 3] > 0.01)
        assert moved.T_0_G[0, 3] - first.T_0_G[0, 3] > 0.01  # the served grip followed the hand
        assert moved.geom_xpos.shape == (0, 3)  # the device reports its grip, not its links
        for _ in range(int(WAIT_S / 0.02)):  # the page's next redraw hides them
            if not any(n.visible for n in app.view.links.nodes):
                break
            time.sleep(0.02)
        assert app.view.links.nodes
        assert not any(n.visible for n in app.view.links.nodes)
        process.terminate()  # the device goes away: the page says so
        gone = wait_for(app, lambda s: s.device_link == "DISCONNECTED")
        assert gone.device_link == "DISCONNECTED"
        assert gone.watchdog_trips > 0
    finally:
        app.close()
        app.server.stop()


def test_an_address_where_nothing_answers_is_refused_leaving_nothing_served() -> None:
    from app.device.haply import DeviceUnreachable

    port = free_port()  # free: nothing listens there
    web_port = free_port()
    with pytest.raises(DeviceUnreachable, match=f"no usable Inverse Service at ws://127.0.0.1:{port}: cannot connect"):
        start_demo("probe", f"ws://127.0.0.1:{port}", port=web_port)
    assert nothing_listens(web_port)  # the demo's server was stopped
