"""First panel from launching ``frhc web``: seconds from the process's start to the guide
visible in headless chromium (1400x900), with the time a fresh interpreter takes to import what
the server needs before it listens (``app.web.launch``) and the demo itself (``app.web.server``,
imported while the page boots) beside it.

Chromium is started first (its own start is not the demo's), then ``frhc web`` on a free port;
the page is loaded as soon as the port answers and timed until the guide's first folder shows.
Each run is a fresh process (cold imports only on the first, as the OS caches the files).

Run from the repository root:
    .venv/bin/python bench/web_launch.py [runs]
Goal: first panel <= 3 s on a quiet machine.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.web.headless import free_port, open_page

ROOT = Path(__file__).resolve().parents[1]
FRHC = ROOT / ".venv" / "bin" / "frhc"
PYTHON = ROOT / ".venv" / "bin" / "python"
#: Seconds the demo gets to answer and show its guide.
TIMEOUT = 120.0


def first_panel(page: object) -> tuple[float, float]:
    """Seconds from starting ``frhc web`` to its page loaded (the server listens once its
    inputs are checked) and to its guide visible in ``page``."""
    port = free_port()
    start = time.monotonic()
    server = subprocess.Popen(
        [str(FRHC), "web", "--port", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        while True:
            try:
                page.goto(f"http://127.0.0.1:{port}/", timeout=TIMEOUT * 1000)  # type: ignore[attr-defined]
                break
            except Exception:  # refused until the server listens
                if time.monotonic() - start > TIMEOUT or server.poll() is not None:
                    raise
                time.sleep(0.05)
        loaded = time.monotonic() - start
        page.get_by_text("Start here").first.wait_for(timeout=TIMEOUT * 1000)  # type: ignore[attr-defined]
        return loaded, time.monotonic() - start
    finally:
        server.terminate()
        server.wait(30)


def import_seconds(module: str) -> float:
    """Seconds a fresh interpreter takes to import ``module`` (``-X importtime``)."""
    out = subprocess.run(
        [str(PYTHON), "-X", "importtime", "-c", f"import {module}"], capture_output=True, text=True, cwd=ROOT
    ).stderr
    match = re.search(rf"\|\s*(\d+) \| {re.escape(module)}\s*$", out, re.MULTILINE)
    assert match, f"no import time for {module}"
    return int(match.group(1)) / 1e6


def main(runs: int) -> None:
    with open_page("about:blank") as page:
        for i in range(runs):
            loaded, panel = first_panel(page)
            before, demo = import_seconds("app.web.launch"), import_seconds("app.web.server")
            load = os.getloadavg()[0]
            print(
                f"run {i + 1}: page loaded {loaded:5.2f} s, first panel {panel:5.2f} s after launch; "
                f"import app.web.launch {before:4.2f} s, app.web.server {demo:4.2f} s; load {load:.2f}"
            )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
