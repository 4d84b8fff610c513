"""Constants and helpers shared by the web tests."""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable
from pathlib import Path

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


def listening_tcp_ports() -> set[int]:
    """TCP ports this process listens on (IPv4 and IPv6), from ``/proc``: the sockets among its
    open files that the kernel's tables list in state LISTEN."""
    inodes = set()
    for fd in Path("/proc/self/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:
                ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports
