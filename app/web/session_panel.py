"""The panel's task side: a first-visit guide, playing a session, replaying a log, the experiment.

Like :mod:`app.web.controls`, it holds no state of its own: every input calls a method of a
:class:`SessionActions` (the demo application), and :meth:`SessionPanel.update` redraws from the
demo's state once per UI frame.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
import viser

from app.errors import InvalidField
from app.session.files import META_FILE, SESSIONS_DIR, fresh_folder
from app.web.camera import PANEL_WIDTH
from app.web.commands import MAX_SPEED, MIN_SPEED

if TYPE_CHECKING:
    from app.study.experiment import ExperimentReport

#: The button that opens the experiment's chart full size.
FULL_CHART = "Show the chart full size"
#: Size (CSS px) of the chart's window: the 1600 x 1000 px chart at 0.6, left of a 1400 px wide
#: page's panel (the window can be moved and resized).
CHART_WINDOW = (980.0, 740.0)
#: Seconds a click made before the demo is up waits for it (building the loop takes ~1 s; the
#: page connects while it is built).
READY_TIMEOUT = 120.0
#: Shown under the buttons when a click waits for the demo.
STARTING = "**starting...**: the servo loop is being built; your click runs as soon as it is up"
#: Choices of the speed selectors (simulated seconds per wall-clock second).
SPEEDS = tuple(f"{f:g}" for f in (MIN_SPEED, 0.25, 0.5, 1.0, 2.0, MAX_SPEED))

GUIDE = """**Start here.** The left space is the hand controller, the right one the virtual world.

1. Press **Try the peg task** to watch a scripted operator insert two pegs with force reflection
   (the paper's Table I task), or pick any session under *Play a session*.
2. To drive it yourself: drag the **gizmo** (the hand) a few cm down, then tick **Deadman** and
   **Reflection** (keys D, F). In rate mode the tool moves while the grip is off centre.
3. Arrows: red is the contact wrench on the tool, orange what the grip renders to your hand, blue
   the assists (return-to-centre and damping), green your hand's push. Magenta dots: contacts.
"""


def offered(handle: viser.GuiDropdownHandle[str]) -> str:
    """A dropdown's value, if it is one of its options: the page offers no other, but a client
    speaking viser's protocol may send any text (viser casts it, checks nothing).

    Raises:
        InvalidField: naming the dropdown's label.
    """
    if handle.value not in handle.options:
        raise InvalidField(handle.label, f"not one of the choices, got {handle.value!r}")
    return handle.value


def within(handle: viser.GuiSliderHandle[int]) -> int:
    """A slider's value, if it is within its own bounds (as :func:`offered`: viser checks none).

    Raises:
        InvalidField: naming the slider's label.
    """
    if not handle.min <= handle.value <= handle.max:
        raise InvalidField(handle.label, f"must be in [{handle.min}, {handle.max}], got {handle.value}")
    return handle.value


def available_sessions() -> list[str]:
    """Names of the sessions shipped in ``sessions/``."""
    return sorted(p.stem for p in SESSIONS_DIR.glob("*.toml"))


def latest_log(runs: Path) -> str:
    """The most recently written log directory under ``runs`` (or ``""``)."""
    logs = sorted(runs.glob(f"*/log/{META_FILE}"), key=lambda p: p.stat().st_mtime)
    return str(logs[-1].parent) if logs else ""


class SessionActions(Protocol):
    """What the task panel asks of the demo application (from viser's callback threads)."""

    def play_session(self, name: str) -> None: ...

    def pause(self, on: bool) -> None: ...

    def set_speed(self, factor: float) -> None: ...

    def open_replay(self, directory: str) -> None: ...

    def close_replay(self) -> None: ...

    def seek(self, t: float) -> None: ...

    def set_replay_playing(self, on: bool) -> None: ...

    def set_replay_speed(self, factor: float) -> None: ...

    def start_experiment(self, operators: int) -> None: ...

    def show_notice(self, text: str) -> None:
        """Say ``text`` in the player's status line until a session is played (Markdown)."""


class SessionPanel:
    """Guide, session player, log replay and experiment folders of the demo's panel.

    Built before the demo exists (the page shows the guide while the loop is built): the demo
    application, which every input acts on, is given to :meth:`ready`.

    Args:
        server: The viser server. runs: Where logs are looked for.
    """

    def __init__(self, server: viser.ViserServer, runs: Path) -> None:
        gui = server.gui
        # The panel is laid out before anything is in it, so the first page shows it in place.
        # Docked at the right (after the theme, which resets where the panel is), it sits beside
        # the 3D canvas instead of floating over its right part: a software page draws only the
        # pixels it shows (:mod:`app.web.camera`).
        gui.configure_theme(control_width="large")
        gui.main_panel.dock_right()
        gui.main_panel.set_width(PANEL_WIDTH)
        gui.set_panel_label("FRHC haptic demo (Williams 1997)")
        self._ready = threading.Event()
        self._actions: SessionActions | None = None
        on = self._when_ready
        with gui.add_folder("Start here", expand_by_default=True):
            gui.add_markdown(GUIDE)
            self.try_peg = gui.add_button("Try the peg task", hint="Play sessions/peg_ntrfc.toml in real time")
            self.try_peg.on_click(on(lambda a: a.play_session("peg_ntrfc")))
            self.try_status = gui.add_markdown("")

        with gui.add_folder("Play a session", expand_by_default=False):
            sessions = available_sessions()
            self.session = gui.add_dropdown("Session", sessions, initial_value="peg_ntrfc")
            self.play = gui.add_button("Play", hint="Reset and run the session's scripted operator")
            self.pause = gui.add_checkbox("Pause", False)
            self.speed = gui.add_dropdown("Speed", SPEEDS, initial_value="1")
            self._speed_seen = 1.0
            self.play_status = gui.add_markdown("")
        self.play.on_click(on(lambda a: a.play_session(offered(self.session))))
        self.pause.on_update(on(lambda a: a.pause(self.pause.value)))
        self.speed.on_update(on(lambda a: a.set_speed(float(offered(self.speed)))))

        with gui.add_folder("Replay a log", expand_by_default=False):
            self.log_path = gui.add_text("Log directory", latest_log(runs), hint="runs/<name> or runs/<name>/log")
            self.open = gui.add_button("Open", hint="Show the log instead of the live loop (which keeps running)")
            self.timeline = gui.add_slider("Time (s)", min=0.0, max=1.0, step=0.001, initial_value=0.0, disabled=True)
            self.replay_playing = gui.add_checkbox("Play replay", False)
            self.replay_speed = gui.add_dropdown("Replay speed", SPEEDS, initial_value="1")
            self.live = gui.add_button("Back to live")
            self.replay_status = gui.add_markdown("")
        self.open.on_click(on(lambda a: a.open_replay(self.log_path.value)))
        self.live.on_click(on(lambda a: a.close_replay()))
        self.timeline.on_update(on(lambda a: a.seek(float(self.timeline.value))))
        self.replay_playing.on_update(on(lambda a: a.set_replay_playing(self.replay_playing.value)))
        self.replay_speed.on_update(on(lambda a: a.set_replay_speed(float(offered(self.replay_speed)))))

        with gui.add_folder("Experiment (Table I)", expand_by_default=False):
            gui.add_markdown(
                "Dual peg-in-the-holes (Sec 4.3): simulated operators that react, drawn from a seeded "
                "population, each with FRHC/NTRFC and blind. `frhc experiment` runs 100 on Ray."
            )
            self.operators = gui.add_slider("Operators", min=1, max=20, step=1, initial_value=3)
            self.run_experiment = gui.add_button("Run experiment")
            self.progress = gui.add_progress_bar(0.0, visible=False)
            self.experiment_result = gui.add_markdown("")
            self.server = server
            self.chart: viser.GuiImageHandle | None = None
            self.full_chart = gui.add_button(
                FULL_CHART, visible=False, hint="Table I's chart in a window beside the panel, large enough to read"
            )
            self._chart_image: np.ndarray | None = None
        self.run_experiment.on_click(on(lambda a: a.start_experiment(within(self.operators))))
        self.full_chart.on_click(lambda event: self._open_chart(event.client))

    def ready(self, actions: SessionActions) -> None:
        """The demo ``actions`` is up (its loop, view and panel built): clicks act on it, and those
        made before run now."""
        self._actions = actions
        self._ready.set()

    def _when_ready(self, action: Callable[[SessionActions], None]) -> Callable[[viser.GuiEvent], None]:
        """A callback running ``action`` once the demo is up: a click made while its loop is still
        being built (the guide is shown first) waits, with :data:`STARTING` shown, in viser's
        callback thread instead of reaching a demo that does not exist yet. A value the page
        would not send (:func:`offered`, :func:`within`) is refused in the status line, naming
        the input, instead of raising in viser's thread."""

        def callback(event: viser.GuiEvent) -> None:
            if not self._ready.is_set():
                self.show_play_status(STARTING)
                if not self._ready.wait(READY_TIMEOUT):
                    self.show_play_status("**the demo did not start**: reload the page to try again")
                    return
            assert self._actions is not None  # set before the event
            try:
                action(self._actions)
            except InvalidField as exc:
                message = f"Refused {exc.field}: {exc.reason}"
                self._actions.show_notice(f"**{message}**")
                if event.client is not None:
                    event.client.add_notification("Input refused", message, color="red", auto_close_seconds=6.0)

        return callback

    def show_play_status(self, text: str) -> None:
        """What is playing (or loading), under both the guide's button and the player."""
        self.play_status.content = text
        self.try_status.content = text

    def show_speed(self, speed: float) -> None:
        """Show the loop's speed (back to 1 when its session ends) in the selector: on a change
        of the loop's speed only, so a choice not yet applied by the loop is not undone."""
        if speed == self._speed_seen:
            return
        self._speed_seen = speed
        shown = f"{speed:g}"
        if shown in SPEEDS and self.speed.value != shown:
            # Its callback re-sends the loop's own speed: no change.
            self.speed.value = shown  # type: ignore[misc]  # viser 1.1: setter exists

    def show_replay(self, duration: float | None, text: str) -> None:
        """Enable the timeline for a log of ``duration`` seconds (None: live again, the timeline
        back at 0: a value the page sent that the replay refused, such as NaN, is not left on it)."""
        self.timeline.disabled = duration is None
        if duration is not None:
            self.timeline.max = max(duration, 1e-3)
        else:
            self.show_cursor(0.0)
        self.replay_status.content = text

    def show_cursor(self, t: float) -> None:
        """Put the timeline at ``t`` (s). viser runs the timeline's callback (a seek) for it."""
        self.timeline.value = t  # type: ignore[misc]  # viser 1.1: the setter exists

    def show_experiment(self, done: int, total: int, table: str | None, chart: np.ndarray | None) -> None:
        """Progress (``done`` of ``total`` runs), then the table and the bar chart (RGB image)."""
        self.progress.visible = table is None
        # viser 1.1 annotates ``value`` as read-only although its setter exists.
        self.progress.value = 100.0 * done / max(total, 1)  # type: ignore[misc]
        self.run_experiment.disabled = table is None and done < total
        if table is None:
            self.experiment_result.content = f"running: {done} of {total} sessions"
            return
        if chart is not None:  # before the table: a page that shows the table has its chart
            self._chart_image = chart
            self.full_chart.visible = True
            if self.chart is None:
                with self.server.gui.add_folder("Experiment chart", expand_by_default=True):
                    self.chart = self.server.gui.add_image(chart, label="Table I (small: use the button above)")
            else:
                self.chart.image = chart
        self.experiment_result.content = f"```\n{table}\n```"

    def _open_chart(self, client: viser.ClientHandle | None) -> None:
        """Open the latest chart in a floating window of the page that asked (all pages if the click
        has no client), :data:`CHART_WINDOW` CSS px wide beside the panel; its Close removes it."""
        chart = self._chart_image
        if chart is None:
            return
        gui = client.gui if client is not None else self.server.gui
        window = gui.add_panel()
        with window.add_tab("Table I"):
            gui.add_image(chart, label="Work (Eq 13), where it goes, peak forces, blind / NTRFC")
            gui.add_button("Close").on_click(lambda _: window.remove())
        width, height = CHART_WINDOW
        window.float(x=16.0, y=16.0, width=width, height=height)


class ExperimentJob:
    """The Table I experiment running in a background thread of the server process (the servo loop
    has its own process and real-time priority, so it keeps its pace).

    Attributes:
        done, total: Runs finished and planned. report: The result once finished. error: Why it
        failed, if it did.

    Its results go to a new folder ``runs_dir / name`` (:func:`~app.session.files.fresh_folder`).
    """

    def __init__(self, runs_dir: Path, name: str, operators: int) -> None:
        self.done, self.total = 0, 1
        self.report: ExperimentReport | None = None
        self.error: str | None = None
        self._thread = threading.Thread(
            target=self._run, args=(runs_dir, name, operators), name="experiment", daemon=True
        )
        self._thread.start()

    def _run(self, runs_dir: Path, name: str, operators: int) -> None:
        def progress(done: int, total: int) -> None:
            self.done, self.total = done, total

        # Imported here, not at start: the experiment and matplotlib are not needed before the
        # first click, and the page's first panel waits for the server's imports.
        from app.study.experiment import run_experiment

        try:
            self.report = run_experiment(fresh_folder(runs_dir, name), n_operators=operators, on_run=progress)
        except Exception as exc:  # shown in the page; the server must live on
            self.error = f"{type(exc).__name__}: {exc}"

    @property
    def finished(self) -> bool:
        return self.report is not None or self.error is not None

    def chart(self) -> np.ndarray | None:
        """The bar chart as an RGB image (h, w, 3) uint8, once finished."""
        if self.report is None:
            return None
        import matplotlib.image as mpimg  # see _run

        rgba = mpimg.imread(self.report.chart)
        return np.asarray(rgba[..., :3] * 255.0, dtype=np.uint8)
