"""Headless Debian chromium via playwright, for the browser tests and ``bench/web_realtime.py``.

Uses the system browser (``/usr/bin/chromium``); playwright's own browser download is never needed.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

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
