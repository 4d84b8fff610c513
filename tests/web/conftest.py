"""Shared fixtures of the browser tests: one demo and one headless chromium page per test module."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from web_helpers import STEP_TIMEOUT

from app.web.headless import CHROMIUM, free_port, open_page
from app.web.launch import start_demo
from app.web.server import DemoApp


@pytest.fixture(scope="module")
def demo() -> Iterator[DemoApp]:
    """The default demo (probe scene, Kraft device) on a free port, its loop running."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium to run the browser tests")
    app = start_demo("probe", "kraft", port=free_port())
    try:
        assert app.rt.wait_running(), "the servo loop process did not publish within 60 s"
        yield app
    finally:
        app.close()
        app.server.stop()


@pytest.fixture(scope="module")
def page(demo: DemoApp) -> Iterator[object]:
    """A headless chromium page showing ``demo``, once its panel is drawn."""
    with open_page(f"http://127.0.0.1:{demo.server.get_port()}/") as p:
        # Every page call gets a step's time (playwright's default 30 s is too short when
        # chromium renders WebGL in software on a loaded machine).
        p.set_default_timeout(STEP_TIMEOUT * 1000)
        p.get_by_text("Deadman [D]").first.wait_for(timeout=STEP_TIMEOUT * 1000)
        yield p
