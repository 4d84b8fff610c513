"""The demo in a real (headless) browser: page, scene nodes and controls, then a press into the probe.

Drives the demo through its server-side API (the same GUI handles and gizmo a browser changes) and
checks what the browser displays. Needs Debian's chromium; skips without it.
"""

from __future__ import annotations

import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from web_helpers import SCREENSHOT_DIR, STEP_TIMEOUT

from app.web.server import DemoApp

pytestmark = pytest.mark.browser


def _task_force_shown(page: object) -> float:
    """The task force the page displays (N), from the status readout."""
    text = page.inner_text("body")  # type: ignore[attr-defined]
    match = re.search(r"\|F_MRF\| = ([0-9.]+) N", text)
    assert match, "the wrench readout is not on the page"
    return float(match.group(1))


def test_page_shows_controls_and_scene(demo: DemoApp, page: object) -> None:
    text = page.inner_text("body")  # type: ignore[attr-defined]
    for label in ("Deadman [D]", "Reference [R]", "Reflection [F]", "Status", "Mode and gains", "servo rate"):
        assert label in text, label
    scene = demo.server.scene
    names = [
        "/grip",
        "/reference",
        "/hand_target",
        "/tool",
        "/mrf",
        "/sensor",
        "/world/object_0",
        "/links/geom_0",
        "/wrenches/task_MRF/force",
        "/wrenches/reflected_G/force",
        "/wrenches/assist_G/force",
        "/wrenches/hand_G/force",
    ]
    for name in names:
        assert scene.get_handle_by_name(name) is not None, name


def test_out_of_range_gain_is_refused_on_the_page(demo: DemoApp, page: object) -> None:
    before = demo.gains
    demo.controls.six["k_v"].value = "-1, 1, 1, 1, 1, 1"
    assert demo.gains == before
    page.get_by_text("Refused k_v").first.wait_for(state="attached", timeout=STEP_TIMEOUT * 1000)  # type: ignore[attr-defined]
    demo.controls.six["k_v"].value = "1, 1, 1, 1, 1, 1"
    assert demo.gains.k_v == (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)


def test_press_into_probe_shows_wrench(demo: DemoApp, page: object, tmp_path: Path) -> None:
    assert _task_force_shown(page) == 0.0
    demo.controls.deadman.value = True
    demo.controls.reflection.value = True
    T_0_H = demo.rt.snapshot.T_0_G.copy()
    T_0_H[2, 3] -= 0.03  # rate mode: 2 cm past the deadband -> 4 cm/s down; 2.5 cm to the surface
    demo.move_hand_target(T_0_H)
    assert np.allclose(demo.view.hand_target.position[2], T_0_H[2, 3], atol=1e-9)

    end = time.monotonic() + STEP_TIMEOUT
    while _task_force_shown(page) < 1.0:
        assert time.monotonic() < end, "no task force reached the page"
        time.sleep(0.2)
    snap = demo.rt.snapshot
    assert snap.F_MRF[2] > 1.0  # the surface pushes the tool up
    assert len(snap.contact_points_w) > 0
    assert demo.view.arrows["task_MRF/force"].visible
    assert demo.view.arrows["reflected_G/force"].visible
    assert demo.rt.stats().ticks > 1000  # rate and jitter are measured by bench/web_realtime.py, not here

    shot = tmp_path / "web_probe_contact.png"
    page.screenshot(path=str(shot))  # type: ignore[attr-defined]
    SCREENSHOT_DIR.mkdir(parents=True, exist_ok=True)
    shutil.copy(shot, SCREENSHOT_DIR / shot.name)


def test_hotkey_toggles_deadman(demo: DemoApp, page: object) -> None:
    before = demo.controls.deadman.value
    page.mouse.click(200, 700)  # type: ignore[attr-defined]  # focus the viewer (empty space)
    page.keyboard.press("d")  # type: ignore[attr-defined]
    end = time.monotonic() + STEP_TIMEOUT
    while demo.controls.deadman.value == before:
        assert time.monotonic() < end, "the D hotkey did not reach the server"
        time.sleep(0.1)
    assert _wait_deadman(demo, not before), "the loop did not see the deadman change"


def _wait_deadman(demo: DemoApp, value: bool) -> bool:
    """True once the loop's snapshot shows the deadman at ``value`` (False after the step timeout)."""
    end = time.monotonic() + STEP_TIMEOUT
    while demo.rt.snapshot.deadman is not value:
        if time.monotonic() > end:
            return False
        time.sleep(0.05)
    return True


def test_a_second_browser_watches_the_same_demo(demo: DemoApp, page: object) -> None:
    """Two pages at once: both show the live readout, and the loop keeps its pace."""
    second = page.context.browser.new_page()  # type: ignore[attr-defined]  # its own context: another user
    try:
        second.goto(f"http://127.0.0.1:{demo.server.get_port()}/")
        second.get_by_text("Deadman [D]").first.wait_for(timeout=STEP_TIMEOUT * 1000)
        ticks = demo.rt.stats().counted
        end = time.monotonic() + STEP_TIMEOUT
        while abs(_task_force_shown(second) - _task_force_shown(page)) > 0.2 or _task_force_shown(second) < 1.0:
            assert time.monotonic() < end, "the second page does not show the same wrench"
            time.sleep(0.2)
        time.sleep(1.0)
        assert demo.rt.stats().counted - ticks > 900  # still ~1 kHz with two browsers watching
    finally:
        second.close()
