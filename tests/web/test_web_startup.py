"""A click in the page before the demo's loop exists: it waits ("starting..." shown) and then
acts, with no error in viser's callback thread. Needs Debian's chromium; skips without it.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest
import viser
from web_helpers import STEP_TIMEOUT

import app.web.server as web_server
from app.session.spec import load_session
from app.web.headless import CHROMIUM, free_port, open_page
from app.web.realtime import RealtimeLoop
from app.web.server import DemoApp

pytestmark = pytest.mark.browser


def test_a_click_before_the_loop_exists_waits_and_acts(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """The page is open on the guide while the demo is held before building its loop (the ~1 s
    a real start takes, made as long as the test needs): a click on Try the peg task shows
    "starting...", then plays the session once the loop is up."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium to run the browser tests")
    hold = threading.Event()

    class HeldLoop(RealtimeLoop):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            hold.wait(STEP_TIMEOUT)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(web_server, "RealtimeLoop", HeldLoop)
    server = viser.ViserServer(port=free_port(), verbose=False)
    session = load_session("peg_ntrfc")  # the demo runs its loop: Try the peg task needs no rebuild
    built: list[DemoApp] = []
    builder = threading.Thread(target=lambda: built.append(DemoApp(server, session.scene, session.device, session)))
    builder.start()
    try:
        with open_page(f"http://127.0.0.1:{server.get_port()}/") as page:
            page.set_default_timeout(STEP_TIMEOUT * 1000)
            button = page.get_by_role("button", name="Try the peg task").first
            button.wait_for()
            assert not built, "the demo was built before the click"
            button.dispatch_event("click")
            page.get_by_text("starting...").first.wait_for()
            hold.set()
            builder.join(STEP_TIMEOUT)
            demo = built[0]
            end = time.monotonic() + STEP_TIMEOUT
            while (playing := demo.rt.snapshot.playing) is None or playing.stem != "peg_ntrfc":
                assert time.monotonic() < end, "the click made before the loop existed did not play the session"
                time.sleep(0.1)
    finally:
        hold.set()
        builder.join(STEP_TIMEOUT)
        for demo in built:
            demo.close()
        server.stop()
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err
