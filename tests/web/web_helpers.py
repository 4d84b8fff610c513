"""Constants and helpers shared by the web tests."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

from app.world.scene import ROOT_DIR

#: Where screenshots are copied for people to look at (runs/ is not committed).
SCREENSHOT_DIR = ROOT_DIR / "runs" / "web-test"
#: Seconds the page and the loop get for each step: generous, because chromium renders WebGL in
#: software on 2 cores while the real-time loop holds most of one.
STEP_TIMEOUT = 60.0


def nothing_listens(port: int) -> bool:
    """Whether a connection to ``port`` on 127.0.0.1 is refused."""
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) != 0


def wait_until(condition: Callable[[], object], what: str) -> None:
    """Poll ``condition`` every 0.1 s until it holds; fail with ``what`` after :data:`STEP_TIMEOUT`."""
    end = time.monotonic() + STEP_TIMEOUT
    while not condition():
        assert time.monotonic() < end, what
        time.sleep(0.1)
