"""The demo's task side in a real browser: play a session, replay a log, run the experiment.

Drives the page through the panel's server-side handles (what a click changes) and checks what
the browser displays. Needs Debian's chromium; skips without it.
"""

from __future__ import annotations

import asyncio
import re
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import viser
import viser._gui_api
from viser._messages import GuiUpdateMessage
from web_helpers import SCREENSHOT_DIR, STEP_TIMEOUT, wait_until

from app.session.log import read_log
from app.session.run import run_session
from app.session.spec import load_session
from app.web.controls import PLOT_EVERY, PLOT_SECONDS
from app.web.scene_view import WORLD_ORIGIN_V
from app.web.server import UI_RATE, DemoApp
from app.web.session_panel import FULL_CHART
from app.world.scene import load_scene

pytestmark = pytest.mark.browser


def _body(page: object) -> str:
    return str(page.inner_text("body"))  # type: ignore[attr-defined]


def _click(page: object, label: str) -> None:
    """Click the panel button ``label`` in the browser (opening its folder first if needed).

    The click event is dispatched to the button itself: with WebGL rendered in software on a busy
    2-core machine, playwright's pointer simulation (hit test, stability wait) timed out.
    """
    button = page.get_by_role("button", name=label).first  # type: ignore[attr-defined]
    if not button.is_visible():
        page.get_by_text(FOLDER_OF[label], exact=True).first.dispatch_event("click")  # type: ignore[attr-defined]
    button.dispatch_event("click", timeout=STEP_TIMEOUT * 1000)


#: The panel folder each button lives in (collapsed ones are opened before a click).
FOLDER_OF = {
    "Try the peg task": "Start here",
    "Open": "Replay a log",
    "Back to live": "Replay a log",
    "Run experiment": "Experiment (Table I)",
    FULL_CHART: "Experiment (Table I)",
}


def test_the_guide_is_on_the_first_page(page: object) -> None:
    text = _body(page)
    assert "Start here" in text
    assert "drag the" in text.lower()


def _checked(page: object, label: str) -> bool:
    return bool(page.get_by_label(label, exact=True).first.is_checked())  # type: ignore[attr-defined]


def test_try_the_peg_task_plays_it_to_the_inserted_state(demo: DemoApp, page: object, tmp_path: Path) -> None:
    """The button says at once that it is loading (before the new loop runs), rebuilds the loop
    for peg_in_hole and plays peg_ntrfc live: the switch checkboxes show the switches the script
    holds, the status shows the contact force when the pegs press on the block (the play is paused
    there for the slow page), the pegs go in, and the speed set during the play is 1 again after it."""
    _click(page, "Try the peg task")
    clicked = time.monotonic()
    while "loading peg_ntrfc" not in _body(page):
        assert demo.rt.snapshot.playing is None, "the session played before the page said it was loading"
        assert time.monotonic() < clicked + STEP_TIMEOUT, "no loading notice"
        time.sleep(0.02)
    print(f"loading notice on the page {time.monotonic() - clicked:.2f} s after the click")
    wait_until(lambda: demo.rt.snapshot.playing is not None, "the session did not start playing")
    task = load_scene("peg_in_hole").spec.task
    assert task is not None
    # Hold the play once the pegs press on the block, so the page (slow: software WebGL) can show it.
    end = time.monotonic() + 3 * STEP_TIMEOUT
    while float(np.linalg.norm(demo.rt.snapshot.F_MRF[0:3])) < 0.5:
        assert demo.rt.snapshot.playing is not None, "the session ended without a contact force"
        assert time.monotonic() < end, "no contact force"
        time.sleep(0.01)
    demo.panel.pause.value = True
    wait_until(lambda: demo.rt.snapshot.paused, "the loop did not pause")
    snap = demo.rt.snapshot
    assert snap.deadman  # the script holds both while it presses
    assert snap.reflection
    wait_until(
        lambda: (_checked(page, "Deadman [D]"), _checked(page, "Reflection [F]")) == (snap.deadman, snap.reflection),
        "the switch checkboxes do not show the script's switches",
    )
    shown = float(np.linalg.norm(snap.F_MRF[0:3]))
    wait_until(
        lambda: f"|F_MRF| = {shown:.2f} N" in _body(page), f"the page does not show the {shown:.2f} N contact force"
    )
    demo.panel.pause.value = False
    demo.panel.speed.value = "2"  # the rest of the play at 2x (and a shorter test)
    wait_until(lambda: demo.rt.snapshot.speed == 2.0, "the speed did not reach the loop")
    inserted = False
    while demo.rt.snapshot.playing is not None:
        assert time.monotonic() < end, "the session did not finish"
        inserted |= task.done(demo.rt.snapshot.T_w_MRF)
        time.sleep(0.02)
    snap = demo.rt.snapshot
    # Inserted: the goal depth was reached (the script then pushes on to the holes' floor).
    goal = task.goal.matrix()[0:3, 3]
    p = snap.T_w_MRF[0:3, 3]
    assert inserted or (np.linalg.norm(p[0:2] - goal[0:2]) < task.position_tolerance and p[2] < goal[2]), p
    page.get_by_text("no session playing").first.wait_for(state="attached", timeout=STEP_TIMEOUT * 1000)  # type: ignore[attr-defined]
    assert demo.rt.snapshot.speed == 1.0  # the speed ended with the session
    wait_until(lambda: demo.panel.speed.value == "1", "the speed selector is not back at 1")
    wait_until(
        lambda: (
            (_checked(page, "Deadman [D]"), _checked(page, "Reflection [F]"))
            == (demo.rt.snapshot.deadman, demo.rt.snapshot.reflection)
        ),
        "the switch checkboxes do not show the loop's switches after the play",
    )
    SCREENSHOT_DIR.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(tmp_path / "peg.png"))  # type: ignore[attr-defined]
    shutil.copy(tmp_path / "peg.png", SCREENSHOT_DIR / "peg_played.png")


def test_replay_shows_the_recorded_tick(demo: DemoApp, page: object, tmp_path: Path) -> None:
    """Scrubbing to a tick shows that tick's recorded tool pose and task force."""
    session = load_session("probe_rate").with_changes(duration=2.5)
    run_session(session, out_dir=tmp_path / "run", plots=False)
    log = read_log(tmp_path / "run" / "log")
    live_ticks = demo.rt.stats().counted
    demo.panel.log_path.value = str(tmp_path / "run")
    _click(page, "Open")
    wait_until(lambda: demo.player is not None, "the replay did not open")
    force = log["F_MRF_fz"].to_numpy()
    i = int(np.argmax(force))  # the firmest contact of the run
    t = float(log["t"][i].as_py())
    demo.panel.timeline.value = t
    tool = [1000 * float(log[f"tool_{a}"][i].as_py()) for a in "xyz"]
    expected = f"[{tool[0]:+.1f}, {tool[1]:+.1f}, {tool[2]:+.1f}] mm"
    wait_until(lambda: f"replay t = {t:.3f} s" in _body(page), "the page does not show the scrubbed time")
    text = _body(page)
    assert expected in text
    shown = float(re.search(r"replay t = [^\n]*\|F_MRF\| = ([0-9.]+) N", text).group(1))  # type: ignore[union-attr]
    f = np.array([float(log[f"F_MRF_f{a}"][i].as_py()) for a in "xyz"])
    assert shown == pytest.approx(float(np.linalg.norm(f)), abs=0.006)
    assert demo.rt.stats().counted > live_ticks  # the live loop kept running beside the replay
    _click(page, "Back to live")
    wait_until(lambda: demo.player is None, "did not go back to live")


def test_experiment_button_shows_the_table(demo: DemoApp, page: object) -> None:
    demo.panel.operators.value = 1
    _click(page, "Run experiment")
    end = time.monotonic() + 6 * STEP_TIMEOUT
    while "blind / NTRFC" not in _body(page):
        assert time.monotonic() < end, "the experiment table did not appear"
        assert "experiment failed" not in _body(page)
        time.sleep(0.5)
    text = _body(page)
    assert "FRHC/NTRFC" in text
    assert "along the insertion" in text  # the work split
    assert demo.panel.chart is not None


def test_the_experiment_chart_opens_full_size(demo: DemoApp, page: object) -> None:
    """After an experiment (the test above), its button opens the chart in a window: the image
    sent is the chart's own 1600 x 1000 px, drawn more than twice as wide as the thumbnail in the
    panel; Close removes the window."""
    if demo.panel._chart_image is None:
        pytest.skip("needs the experiment of test_experiment_button_shows_the_table")
    images = page.locator("img")  # type: ignore[attr-defined]
    before = images.count()
    thumbnail = float(images.last.bounding_box()["width"])
    _click(page, FULL_CHART)
    wait_until(lambda: images.count() == before + 1, "the chart's window did not open")
    chart = images.last
    wait_until(lambda: chart.evaluate("i => i.complete && i.naturalWidth") > 0, "the chart did not load")
    assert chart.evaluate("i => [i.naturalWidth, i.naturalHeight]") == [1600, 1000]
    shown = chart.bounding_box()
    assert shown["width"] > 2 * thumbnail, (shown, thumbnail)
    assert shown["width"] >= 0.5 * 1600
    page.get_by_role("button", name="Close").last.dispatch_event("click")  # type: ignore[attr-defined]
    wait_until(lambda: images.count() == before, "the chart's window did not close")


#: The x scale ``[min, max]`` of the page's uPlot chart with the given viser GUI id (viser's own
#: end-to-end testpoint, ``window.__viserTestpoints``), or null before the chart exists.
PLOT_X_SCALE_JS = """(uuid) => {
  const chart = window.__viserTestpoints?.uplots?.[uuid]?.chart;
  return chart ? [chart.scales.x.min, chart.scales.x.max] : null;
}"""


def test_a_device_change_stops_the_session_and_says_so(demo: DemoApp, page: object) -> None:
    """Changing the device while a session plays stops it: the status names the session and the
    change, and a notification pops up. Then the Delta X chart in the page spans exactly the
    samples it was sent, all of the new loop (its time restarts at 0): no sample of the old loop
    is left before them, none lies ahead of the new loop's time."""
    demo.panel.speed.value = "0.1"  # a 55 s play: it cannot end by itself before the change
    demo.play_session("peg_ntrfc")
    wait_until(lambda: demo.rt.snapshot.playing is not None, "the session did not start playing")
    device = next(name for name in ("touch3", "kraft") if name != demo.rt.config.device.name)
    demo.controls.device.value = device  # what choosing it in the page's dropdown does
    assert demo.rt.config.device.name == device
    page.get_by_text("stopped peg_ntrfc").first.wait_for(state="attached", timeout=STEP_TIMEOUT * 1000)  # type: ignore[attr-defined]
    text = _body(page)
    assert "stopped peg_ntrfc" in text
    assert "Session stopped" in text  # the notification
    wait_until(lambda: demo.rt.snapshot.playing is None and demo.rt.snapshot.time > 2.0, "the new loop does not run")
    demo.pause(True)  # the plots then hold still, and the page can catch up with them
    wait_until(lambda: demo.rt.snapshot.paused, "the loop did not pause")
    time.sleep(2 * PLOT_EVERY / UI_RATE)  # a plot refresh after the pause
    times = demo.controls.delta_plot.data[0]  # the Delta X chart's time axis as sent
    now = demo.rt.snapshot.time
    assert np.all(np.diff(times) > 0.0)
    assert times[0] >= 0.0
    assert times[-1] <= now
    assert times[-1] - times[0] <= PLOT_SECONDS
    uuid = demo.controls.delta_plot._impl.uuid  # viser's id of the chart in the page

    def x_scale() -> list[float]:
        shown = page.evaluate(PLOT_X_SCALE_JS, uuid)  # type: ignore[attr-defined]
        return [float("nan")] * 2 if shown is None else [float(v) for v in shown]

    wait_until(
        lambda: np.allclose(x_scale(), (times[0], times[-1]), atol=1e-6),
        f"the page's Delta X axis {x_scale()} is not the {times[0]:.3f}-{times[-1]:.3f} s it was sent",
    )
    demo.pause(False)


#: A camera straight above the box's path, looking down (viser's camera: x right, y down, z
#: forward, so a half turn about x), and the render it asks the page for.
TOP_HEIGHT, TOP_X, TOP_FOV = 0.35, 0.015, np.radians(40.0)  # m above the table, m in {w}, rad
RENDER_H, RENDER_W = 240, 320  # px
BOX_TOP = 0.05  # m: box_push's 5 cm box on the table (z = 0)


def _box_drawn_x(demo: DemoApp) -> float:
    """The box's centre along {w} x (m) as the page draws it: the centroid column of the teal
    pixels (the dynamic objects' colour) in a render from the top camera, back-projected at the
    box's top face."""
    client = next(iter(demo.server.get_clients().values()))
    position = WORLD_ORIGIN_V + np.array([TOP_X, 0.0, TOP_HEIGHT])
    image = client.get_render(RENDER_H, RENDER_W, wxyz=(0.0, 1.0, 0.0, 0.0), position=position, fov=TOP_FOV)
    rgb = image[..., 0:3].astype(float)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    teal = (g > 2.0 * r + 20.0) & (b > 2.0 * r + 20.0)  # lit or shaded, teal keeps g, b >> r
    assert teal.sum() > 100, "the box is not in the render"
    f = 0.5 * RENDER_H / np.tan(0.5 * TOP_FOV)  # px per unit of x / depth
    u = float(np.nonzero(teal)[1].mean())
    return TOP_X + (u - 0.5 * RENDER_W) * (TOP_HEIGHT - BOX_TOP) / f


def test_a_pushed_box_is_drawn_where_it_is_live_and_replayed(demo: DemoApp, page: object, tmp_path: Path) -> None:
    """box_push played live: the box the page draws (a render read back from the browser) starts
    and ends where the simulation has it; its recorded log replayed: drawn at the logged poses."""
    demo.play_session("box_push")
    wait_until(lambda: demo.rt.snapshot.playing is not None, "the session did not start playing")
    assert demo.rt.snapshot.object_poses.shape == (1, 7)
    wait_until(lambda: demo.rt.snapshot.playing is None, "the session did not end")
    moved = float(demo.rt.snapshot.object_poses[0, 0])
    assert moved > 0.01  # the stylus pushed the box along x (the script moves the hand 3 cm)
    wait_until(lambda: abs(_box_drawn_x(demo) - moved) < 2e-3, f"the page does not draw the box at x = {moved:.4f} m")

    run_session(load_session("box_push"), out_dir=tmp_path / "run", plots=False)
    log = read_log(tmp_path / "run" / "log")
    xs = log["object_box_x"].to_numpy()
    demo.open_replay(str(tmp_path / "run"))
    try:
        for t in (0.0, float(log["t"][-1].as_py())):
            demo.panel.timeline.value = t
            i = int(np.searchsorted(log["t"].to_numpy(), t, side="right")) - 1
            x = float(xs[max(i, 0)])
            wait_until(lambda x=x: abs(_box_drawn_x(demo) - x) < 2e-3, f"replay at {t} s: the box is not at {x:.4f} m")
        assert xs[-1] - xs[0] > 0.01
    finally:
        demo.close_replay()


def test_values_the_page_would_not_send_are_refused_on_the_page_not_raised(
    demo: DemoApp, page: object, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each value goes through viser's own handler for the connected page's client, as a message
    from a client that sends what the widgets do not offer (viser casts a value to the widget's
    type and checks nothing else). Before harden8: a speed of "abc" and operators of -3 raised in
    viser's thread, a replay speed of "nan" was taken, a NaN time broke the replay's plots."""
    finished: list[BaseException | None] = []
    monkeypatch.setattr(viser._gui_api, "print_threadpool_errors", lambda f: finished.append(f.exception()))
    client = next(iter(demo.server.get_clients()))

    def send(handle: viser.GuiInputHandle[Any], value: object) -> None:
        before, callbacks = len(finished), len(handle._impl.update_cb)  # a dropdown read on Play has none
        message = GuiUpdateMessage(handle._impl.uuid, {"value": value})
        update = demo.server.gui._handle_gui_updates(client, message)
        asyncio.run_coroutine_threadsafe(update, demo.server._event_loop).result(STEP_TIMEOUT)
        wait_until(lambda: len(finished) == before + callbacks, f"{handle.label}'s callbacks did not finish")
        raised = [e for e in finished[before:] if e is not None]
        assert not raised, f"{handle.label} = {value!r} raised {raised!r}"

    demo.rt.stop_playing()  # a session an earlier test played would own the status line
    wait_until(lambda: demo.rt.snapshot.playing is None, "the session did not stop")
    demo.close_replay()
    job = demo.experiment
    p = demo.panel
    send(p.speed, "abc")
    assert p.play_status.content == "**Refused Speed: not one of the choices, got 'abc'**"
    assert demo.rt.snapshot.speed == 1.0
    send(p.session, "../../etc/passwd")
    send(p.play, True)
    assert p.play_status.content == "**Refused Session: not one of the choices, got '../../etc/passwd'**"
    assert demo.rt.snapshot.playing is None
    send(p.operators, -3)
    send(p.run_experiment, True)
    assert p.play_status.content == "**Refused Operators: must be in [1, 20], got -3**"
    assert demo.experiment is job
    run_session(load_session("probe_rate").with_changes(duration=0.5), out_dir=tmp_path / "run", plots=False)
    send(p.log_path, str(tmp_path / "run"))
    send(p.open, True)
    assert demo.player is not None
    send(p.timeline, 0.25)
    send(p.timeline, float("nan"))
    assert demo.player.cursor == pytest.approx(0.25)
    assert p.timeline.value == pytest.approx(0.25)  # the slider put back, not left at NaN
    send(p.replay_speed, "nan")
    assert demo.player.speed == 1.0
    send(p.live, True)
    assert p.timeline.value == 0.0  # not the NaN sent above, which the replay refused


def test_values_viser_cannot_cast_are_refused_in_one_line(
    demo: DemoApp, page: object, capfd: pytest.CaptureFixture[str]
) -> None:
    """Sent the way a page's message is dispatched (every handler viser registered), the three
    values viser's own cast raises on leave their widgets as they were and give one line each
    (before harden9: a traceback from viser's event loop, "Task exception was never retrieved")."""
    client = next(iter(demo.server.get_clients()))
    interface = demo.server._websock_server
    cases = (
        (demo.controls.delay, "abc", "ValueError: could not convert string to float: 'abc'"),
        (demo.panel.timeline, "x", "ValueError: could not convert string to float: 'x'"),
        (demo.panel.operators, float("nan"), "ValueError: cannot convert float NaN to integer"),
    )
    capfd.readouterr()
    for handle, value, _ in cases:
        before = handle.value
        message = GuiUpdateMessage(handle._impl.uuid, {"value": value})
        dispatch = interface._handle_incoming_message(client, message)
        asyncio.run_coroutine_threadsafe(dispatch, demo.server._event_loop).result(STEP_TIMEOUT)
        assert handle.value == before
    # Only the guard's lines: the demo's other threads may write to stderr meanwhile.
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("frhc web: ")]
    assert lines == [
        f"frhc web: refused a page value for {handle.label!r}: {{'value': {value!r}}} ({error})"
        for handle, value, error in cases
    ]
