"""Headless Debian chromium via playwright, for the browser tests and ``bench/web_realtime.py``.

Uses the system browser (``/usr/bin/chromium``); playwright's own browser download is never needed.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from app.web.server import DemoApp

#: The system chromium.
CHROMIUM = Path("/usr/bin/chromium")
#: Flags for a quiet headless run in a container (no sandbox, GPU, QUIC or background traffic).
CHROMIUM_ARGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


def free_port() -> int:
    """A TCP port that was free on 127.0.0.1 a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextmanager
def open_page(url: str, width: int = 1400, height: int = 900) -> Iterator[Any]:
    """A playwright ``Page`` of headless chromium showing ``url`` (closed on exit)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=list(CHROMIUM_ARGS), headless=True)
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            page.goto(url)
            yield page
        finally:
            browser.close()


@contextmanager
def running_demo(scene: str = "probe", device: str = "kraft") -> Iterator[DemoApp]:
    """The demo on a free port with its loop running (stopped, with its server, on exit).

    Raises:
        RuntimeError: the loop process did not publish within a minute.
    """
    from app.web.launch import start_demo  # here: the page helpers above need no viser

    app = start_demo(scene, device, port=free_port())
    try:
        if not app.rt.wait_running():
            raise RuntimeError("the servo loop process did not start")
        yield app
    finally:
        app.close()
        app.server.stop()


def press_probe(app: DemoApp, depth: float = 0.03) -> None:
    """Deadman and reflection on and the hand ``depth`` (m) below the grip: in rate mode the probe
    tool then moves down onto the surface and presses on it (contact, arrows, plots all moving)."""
    app.controls.deadman.value = True  # type: ignore[misc]  # viser 1.1: the setter exists
    app.controls.reflection.value = True  # type: ignore[misc]
    T_0_H = app.rt.snapshot.T_0_G.copy()
    T_0_H[2, 3] -= depth
    app.move_hand_target(T_0_H)
