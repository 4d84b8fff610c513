"""The viser GUI panel: switches, mode and gains, scene/device choice, reset, record, status, plots.

The panel is created once on the server (``server.gui``), so every connected browser sees and
drives the same state. It holds no servo state itself: every input calls a method of a
:class:`DemoActions` (the demo application), and :meth:`Controls.update` redraws status and plots
from a loop :class:`~app.web.snapshot.Snapshot`.

Keyboard: viser's command palette hotkeys (key presses only; there is no key-release event, so the
deadman is a toggle rather than a hold): ``D`` deadman, ``R`` reference, ``F`` reflection.
"""

from __future__ import annotations

import collections
import contextlib
import html
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol, TypeVar

import numpy as np
import viser
import viser.uplot

from app.controller.gains import ControllerGains
from app.controller.layout import MODES, RTC_LAWS
from app.controller.types import Fault
from app.errors import ConfigError, InvalidField
from app.session.pacer import TimingStats
from app.slave.arm import ArmStatus
from app.teleop.channel import COUPLINGS
from app.web.camera import PRESETS
from app.web.scene_view import (
    CONTACT_COLOR,
    DEVICE_ORIGIN_V,
    FORCE_REF,
    MOMENT_REF,
    WORLD_ORIGIN_V,
    WRENCH_ARROWS,
)
from app.web.snapshot import Snapshot

#: Gain fields typed as six comma-separated numbers, with their labels and units (translations; rotations).
SIX_GAINS = (
    ("k_v", "K_V rate gain", "1/s"),
    ("k_p", "K_P pose gain", "-; rotations must be 1"),
    ("k_t", "K_T task-wrench gain", "-"),
    ("k_d", "K_D damping", "N s/m; N m s/rad"),
    ("rtc_a", "CFRTC a_i (Eq 8)", "N/m^2; N m/rad^2"),
    ("k_r", "Hooke K_R", "N/m; N m/rad"),
    ("deadband", "Deadband", "m; rad"),
)
#: Seconds of history in the live plots.
PLOT_SECONDS = 10.0
#: Samples a plot window holds, live or replayed: ~2 px apart on the panel's ~330 px wide plot
#: area. A live plot keeps the first snapshot in each ``PLOT_SECONDS / PLOT_SAMPLES`` (67 ms) slot
#: of simulated time, whatever the speed.
PLOT_SAMPLES = 150
#: UI frames between plot refreshes (5 Hz at 40 frames/s). Plots are the heaviest messages: viser
#: sends every refresh whole, as float64 (13 columns x 150 samples = 15.6 kB).
PLOT_EVERY = 8
#: Width / height of each plot (the panel is ~380 px wide: ~240 px high plots).
PLOT_ASPECT = 1.6

#: One plot sample: t (s), F_MRF xyz (N), |K_T F_MRF| (N), hand |f| (N), Delta X xyz (mm), PO energy (J).
PlotRow = tuple[float, ...]
#: Rows of a plot sample array (see :data:`PlotRow`).
PLOT_ROWS = 10
#: The PO/PC checkbox's hint, on a device with joint ports and on one without (a Cartesian one).
PC_HINT = (
    "Passivity observer/controller: the rendered torque is scaled down so the device port never gives out "
    "more energy than it has taken in"
)
PC_UNAVAILABLE = "Not on this device: it is driven through its Cartesian interface, and PO/PC acts on joint ports"
T = TypeVar("T")


class DemoActions(Protocol):
    """What the panel asks of the demo application (called from viser's callback threads)."""

    @property
    def gains(self) -> ControllerGains: ...

    def set_gains(self, gains: ControllerGains) -> None: ...

    def set_deadman(self, on: bool) -> None: ...

    def press_reference(self) -> None: ...

    def set_reflection(self, on: bool) -> None: ...

    def hand_to_grip(self) -> None: ...

    def set_hand_holds(self, on: bool) -> None: ...

    def reset(self) -> None: ...

    def select(self, scene: str, device: str) -> None: ...

    def toggle_recording(self) -> Path | None: ...

    def set_passivity(self, on: bool) -> None: ...

    def set_channel(self, delay_ms: float, coupling: str) -> None: ...

    def frame_camera(self, client: viser.ClientHandle, preset: str) -> object: ...


def _assign(handle: viser.GuiInputHandle[T], value: T) -> None:
    """Set an input as if a browser had (its callbacks run).

    viser 1.1's annotations make ``value`` look read-only to mypy although its setter exists.
    """
    handle.value = value  # type: ignore[misc]


def format_six(values: tuple[float, ...]) -> str:
    return ", ".join(f"{v:g}" for v in values)


def parse_six(name: str, text: str) -> tuple[float, ...]:
    """``"1, 2, 3, 4, 5, 6"`` typed into gain ``name`` as floats; raises InvalidField naming ``name``.

    Only the shape is checked here: the values' ranges (finite, sign, magnitude) are
    :class:`ControllerGains`'s, checked when the gains are built from them.
    """
    try:
        values = tuple(float(v) for v in text.replace(";", ",").split(","))
    except ValueError:
        raise InvalidField(name, f"'{text}' is not six comma-separated numbers") from None
    if len(values) != 6:
        raise InvalidField(name, f"expected 6 values, got {len(values)}")
    return values


def legend_markdown() -> str:
    """The legend: arrow colours and their log scale, contacts, and where {0} and {w} are."""
    rows = "\n".join(f"- <span style='color:rgb{a.color}'>■</span> {a.label}" for a in WRENCH_ARROWS)
    return (
        f"{rows}\n- <span style='color:rgb{CONTACT_COLOR}'>●</span> contact points, arrows: surface normals\n\n"
        f"Arrow length grows as log2(1 + |f| / {FORCE_REF:g} N) (moments: {MOMENT_REF:g} N m; darker shade), "
        "in units of each space's size: 1 N draws one unit, 3 N two, 7 N three. The number at a tip is "
        "the force in N.\n\n"
        f"Device base {{0}} on the left at x = {DEVICE_ORIGIN_V[0]:+.2f} m, slave world {{w}} on the right "
        f"at x = {WORLD_ORIGIN_V[0]:+.2f} m (same axes, z up). Drag the gizmo: it is the operator's hand."
    )


def _series(label: str, stroke: str, dash: tuple[float, ...] | None = None) -> viser.uplot.Series:
    if dash is None:
        return viser.uplot.Series(label=label, stroke=stroke, width=2.0)
    return viser.uplot.Series(label=label, stroke=stroke, width=2.0, dash=dash)


def _add_plot(gui: viser.GuiApi, title: str, *series: viser.uplot.Series) -> viser.GuiUplotHandle:
    """A time plot (x: simulated s) of ``series``, empty until :meth:`Controls.plot` fills it.

    The legend is not live: a live one reads "--" until the pointer hovers over the plot.
    """
    return gui.add_uplot(
        data=(np.zeros(0),) * (len(series) + 1),
        series=(viser.uplot.Series(label="t (s)"), *series),
        title=title,
        aspect=PLOT_ASPECT,
        scales={"x": viser.uplot.Scale(time=False)},
        legend=viser.uplot.Legend(live=False),
    )


#: The status block's look: that of the code block viser's Markdown draws (Mantine's ``Code``,
#: measured in chromium: the panel's monospace font at its xs size, line height 1.55, gray-0
#: background, xs padding, sm corners, indented and as wide as a Markdown element is).
STATUS_STYLE = (
    "margin:0 var(--mantine-spacing-sm) var(--mantine-spacing-xs);padding:var(--mantine-spacing-xs);"
    "background:var(--mantine-color-gray-0);border-radius:var(--mantine-radius-sm);"
    "font-family:var(--mantine-font-family-monospace);font-size:var(--mantine-font-size-xs);"
    "line-height:1.55;white-space:pre;overflow-x:auto;max-width:calc(95% - 2 * var(--mantine-spacing-sm))"
)


def status_block(snap: Snapshot, timing: TimingStats, scheduling: str, servo_rate: float) -> str:
    """The status as a fixed-width block of HTML (a ``<pre>``): the same lines in the same places
    every frame, so the panel below it never moves. Rates: the servo rate is simulated (1/dt,
    what the controller runs at), the tick rate is wall-clock (ticks per second of real time,
    ``speed`` times it). HTML, not Markdown: the page parses a Markdown element's text again at
    each change (viser's Markdown: remark and rehype), and the status changes up to 40 times a
    second; while the view moves that parse took the page's main thread from its 3D frames."""
    f_task = float(np.linalg.norm(snap.F_MRF[0:3]))
    f_grip = float(np.linalg.norm(snap.G_F_T[0:3]))
    f_hand = float(np.linalg.norm(snap.hand_wrench_0[0:3]))
    dx = ", ".join(f"{1000 * v:+6.1f}" for v in snap.delta_x[0:3])
    lines = (
        f"t {snap.time:9.2f} s sim   mode {snap.mode:<4}",
        f"deadman {'ON ' if snap.deadman else 'off'}   reflection {'ON ' if snap.reflection else 'off'}",
        f"servo {servo_rate:6.0f} Hz simulated",
        f"ticks {timing.rate_hz:6.0f} /s wall (x{snap.speed:g})",
        f"tick {timing.tick_p50_us:5.0f} us p99 {timing.tick_p99_us:5.0f} us",
        f"jitter p99 {timing.jitter_p99_us:5.0f} us slips {timing.slips:4d}",
        f"sched {scheduling}",
        f"|F_MRF| = {f_task:.2f} N",
        f"|K_T F| = {f_grip:.2f} N   hand |f| = {f_hand:.2f} N",
        f"dX [{dx}] mm",
        f"contacts {len(snap.contact_points_w):4d}  sat {snap.saturation_scale:5.3f}  ramp {snap.ramp:4.2f}",
        f"PO {snap.po_energy:+8.3f} J  PC cut {snap.pc_cut:4.0%}  wdog {snap.watchdog_trips}",
    )
    return f'<pre style="{STATUS_STYLE}">' + html.escape("\n".join(lines)) + "</pre>"


def status_notes(snap: Snapshot, notice: str) -> str:
    """What the status block has above it (Markdown; "" for nothing): ``notice`` (loading, a
    stopped session), the device's link and faults, the slave's limits, the controller's faults."""
    faults = Fault(snap.faults)
    limits = ArmStatus(snap.slave_status)
    extra = []
    if notice:
        extra.append(notice)
    if snap.device_link:
        extra.append(f"device link **{snap.device_link}**")
    if snap.device_fault:
        extra.append(f"**device stopped:** {snap.device_fault}")
    if limits != ArmStatus.NONE:
        extra.append(f"**slave limited: {limits.name}**")
    if faults != Fault.NONE:
        extra.append(f"**fault {faults!r}:** {snap.fault_message}")
    return "\n\n".join(extra)


class Controls:
    """The GUI panel of the demo.

    Args:
        server: The viser server.
        actions: The demo application the inputs drive.
        scenes, devices: Names offered in the selectors.
        scene, device: The current selection.
    """

    def __init__(
        self,
        server: viser.ViserServer,
        actions: DemoActions,
        scenes: list[str],
        devices: list[str],
        scene: str,
        device: str,
    ) -> None:
        self.server = server
        self.actions = actions
        gui = server.gui

        with gui.add_folder("Switches (Sec 4.1)"):
            self.deadman = gui.add_checkbox("Deadman [D]", False, hint="Commands and reflection flow while on")
            self.reference = gui.add_button("Reference [R]", hint="Momentary: sets {G0} (and indexes in pose mode)")
            self.reflection = gui.add_checkbox("Reflection [F]", False, hint="Task wrench, return-to-centre, damping")
            self.hand_to_grip = gui.add_button("Hand target to grip", hint="Move the gizmo to where the grip is")
            self.hand_holds = gui.add_checkbox(
                "Hand holds the grip", True, hint="Off: the hand lets go and the device moves under its own forces"
            )

        with gui.add_folder("Camera"):
            self.camera = gui.add_button_group(
                "View", PRESETS, hint="Frame both spaces, the device, the world, the tool"
            )

        with gui.add_folder("Status"):
            self.status_notes = gui.add_markdown("starting...")
            self.status = gui.add_html("")

        with gui.add_folder("Legend", expand_by_default=True):
            gui.add_markdown(legend_markdown())

        with gui.add_folder("Plots"):
            xyz = ("red", "green", "blue")
            self.wrench_plot = _add_plot(
                gui,
                "Task wrench F_MRF at {MRF} (N)",
                *(_series(f"F_MRF {a}", c) for a, c in zip("xyz", xyz, strict=True)),
            )
            self.grip_plot = _add_plot(
                gui,
                "Forces at the grip (N)",
                _series("|K_T F_MRF| rendered", "orange"),
                _series("hand |f|", "rgb(40,170,80)", dash=(6.0, 4.0)),
            )
            self.delta_plot = _add_plot(
                gui, "Delta X, Eq 4 (mm)", *(_series(f"ΔX {a}", c) for a, c in zip("xyz", xyz, strict=True))
            )
            self.energy_plot = _add_plot(
                gui, "Passivity observer energy (J)", _series("PO energy into the device port", "purple")
            )

        with gui.add_folder("Mode and gains", expand_by_default=False):
            gains = actions.gains
            self.mode = gui.add_dropdown("Mode", MODES, initial_value=gains.mode)
            self.rtc = gui.add_dropdown("Return-to-centre", RTC_LAWS, initial_value=gains.rtc)
            self.six: dict[str, viser.GuiTextHandle] = {}
            for name, label, unit in SIX_GAINS:
                self.six[name] = gui.add_text(
                    label, format_six(getattr(gains, name)), hint=f"x, y, z, γ, β, α ({unit})"
                )
            self.remove_payload = gui.add_checkbox("Remove payload", gains.remove_payload)
            self.gravity_compensation = gui.add_checkbox("Gravity compensation", gains.gravity_compensation)
            self.gain_message = gui.add_markdown("")

        with gui.add_folder("Passivity and delay", expand_by_default=False):
            self.pc = gui.add_checkbox("PO/PC", False, hint=PC_HINT)
            self.delay = gui.add_number("Delay one way (ms)", 0.0, min=0.0, max=1000.0, step=1.0)
            self.coupling = gui.add_dropdown("Coupling", COUPLINGS, initial_value=COUPLINGS[0])

        with gui.add_folder("Scene and device", expand_by_default=False):
            self.scene = gui.add_dropdown("Scene", scenes, initial_value=scene)
            self.device = gui.add_dropdown("Device", devices, initial_value=device)
            self.reset_button = gui.add_button("Reset", hint="Device and tool home, switches off")
            self.record = gui.add_button("Record", hint="Write the per-tick Parquet log to runs/web-<time>/log")
            self.record_status = gui.add_markdown("")

        self._connect()
        self._history: collections.deque[PlotRow] = collections.deque()
        self._frames = 0
        self._switches_seen: tuple[bool, bool, bool] | None = None
        self._quiet_thread: int | None = None

    def _connect(self) -> None:
        a = self.actions

        @self.deadman.on_update
        def _(_: viser.GuiEvent) -> None:
            if not self._quiet():
                a.set_deadman(self.deadman.value)

        @self.reflection.on_update
        def _(_: viser.GuiEvent) -> None:
            if not self._quiet():
                a.set_reflection(self.reflection.value)

        @self.hand_holds.on_update
        def _(_: viser.GuiEvent) -> None:
            if not self._quiet():
                a.set_hand_holds(self.hand_holds.value)

        @self.camera.on_click
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:  # each browser frames its own camera
                a.frame_camera(event.client, self.camera.value)

        self.reference.on_click(lambda _: a.press_reference())
        self.hand_to_grip.on_click(lambda _: a.hand_to_grip())
        self.reset_button.on_click(lambda _: self._reset())
        self.record.on_click(lambda _: self._toggle_record())

        for handle in (self.mode, self.rtc):
            handle.on_update(self._apply_gains)
        for checkbox in (self.remove_payload, self.gravity_compensation):
            checkbox.on_update(self._apply_gains)
        for text in self.six.values():
            text.on_update(self._apply_gains)

        @self.pc.on_update
        def _(_: viser.GuiEvent) -> None:
            if not self._quiet():
                a.set_passivity(self.pc.value)

        for channel_input in (self.delay, self.coupling):
            channel_input.on_update(lambda _: a.set_channel(float(self.delay.value), self.coupling.value))

        self.scene.on_update(lambda _: a.select(self.scene.value, self.device.value))
        self.device.on_update(lambda _: a.select(self.scene.value, self.device.value))

        deadman_key = self.server.gui.add_command("Toggle deadman", hotkey="D")
        deadman_key.on_trigger(lambda _: _assign(self.deadman, not self.deadman.value))
        reference_key = self.server.gui.add_command("Press reference", hotkey="R")
        reference_key.on_trigger(lambda _: a.press_reference())
        reflection_key = self.server.gui.add_command("Toggle reflection", hotkey="F")
        reflection_key.on_trigger(lambda _: _assign(self.reflection, not self.reflection.value))

    def _quiet(self) -> bool:
        """Whether this thread is showing state in the inputs (their callbacks must not act on it)."""
        return self._quiet_thread == threading.get_ident()

    @contextlib.contextmanager
    def _showing(self) -> Iterator[None]:
        """Set inputs to show state without their callbacks sending it back (viser runs an input's
        callbacks synchronously on assignment, in the assigning thread)."""
        self._quiet_thread = threading.get_ident()
        try:
            yield
        finally:
            self._quiet_thread = None

    def follow_switches(self, deadman: bool, reflection: bool, hand_holds: bool) -> None:
        """Tick the switch checkboxes and the hand's as the shown state has them, whoever set them
        (a script, a replayed log, another browser, a drag of the gizmo taking hold): on every
        change of that state, not on every frame, so a click is never undone by a snapshot from
        before it."""
        seen = (deadman, reflection, hand_holds)
        if seen == self._switches_seen:
            return
        self._switches_seen = seen
        with self._showing():
            _assign(self.deadman, deadman)
            _assign(self.reflection, reflection)
            _assign(self.hand_holds, hand_holds)

    def clear_plots(self) -> None:
        """Forget the plotted history (a new loop, a new play: its time starts again)."""
        self._history.clear()
        self._switches_seen = None

    def show_passivity(self, enabled: bool, available: bool) -> None:
        """Tick the PO/PC checkbox as the running loop has it (a session may enable it); on a
        device without joint ports (``available`` false: a Cartesian device) it is greyed out,
        since the controller observes and damps joint ports that such a device keeps to itself."""
        with self._showing():
            _assign(self.pc, enabled)
        self.pc.disabled = not available
        self.pc.hint = PC_HINT if available else PC_UNAVAILABLE

    def _reset(self) -> None:
        self.actions.reset()
        self.release_switches()

    def show_selection(self, scene: str, device: str) -> None:
        """Show ``scene`` and ``device`` as selected (the demo's ``select`` ignores an unchanged pair)."""
        _assign(self.scene, scene)
        _assign(self.device, device)

    def release_switches(self) -> None:
        """Show deadman and reflection off (the loop's reset and a rebuild release them)."""
        _assign(self.deadman, False)
        _assign(self.reflection, False)

    def _toggle_record(self) -> None:
        try:
            directory = self.actions.toggle_recording()
        except OSError as exc:  # runs/ cannot be written: said on the page, the server lives on
            self.record_status.content = f"**cannot record:** {exc}"
            return
        if directory is None:
            self.record.label = "Record"
            self.record_status.content = "log written" if self.record_status.content else ""
        else:
            self.record.label = "Stop recording"
            self.record_status.content = f"recording to `{directory}`"

    def _apply_gains(self, event: viser.GuiEvent) -> None:
        """Build gains from every input; refuse (and say why) anything the gains reject, and put
        the gains still in force back into the inputs."""
        if self._quiet():
            return
        current = self.actions.gains
        try:
            changes: dict[str, object] = {name: parse_six(name, h.value) for name, h in self.six.items()}
            gains = current.with_changes(
                mode=self.mode.value,
                rtc=self.rtc.value,
                remove_payload=self.remove_payload.value,
                gravity_compensation=self.gravity_compensation.value,
                **changes,
            )
        except (ConfigError, InvalidField) as exc:
            field = getattr(exc, "field", "")
            reason = getattr(exc, "reason", str(exc))
            message = f"Refused {field}: {reason}"
            self.gain_message.content = f"**{message}** (kept the previous gains; the fields show them)"
            if event.client is not None:
                event.client.add_notification("Gain refused", message, color="red", auto_close_seconds=6.0)
            self.show_gains(current)
            return
        self.actions.set_gains(gains)
        self.gain_message.content = "gains applied"

    def show_gains(self, gains: ControllerGains) -> None:
        """Put ``gains`` into the inputs (the gains in force) without re-applying them."""
        with self._showing():
            for name, handle in self.six.items():
                _assign(handle, format_six(getattr(gains, name)))
            _assign(self.mode, gains.mode)
            _assign(self.rtc, gains.rtc)
            _assign(self.remove_payload, gains.remove_payload)
            _assign(self.gravity_compensation, gains.gravity_compensation)

    def update(
        self, snap: Snapshot, timing: TimingStats, scheduling: str, servo_rate: float, notice: str, live: bool = True
    ) -> None:
        """Redraw status and (``live``: a replay plots its own window) plots from ``snap`` (call from
        the UI thread); ``servo_rate`` (Hz) is the simulated rate, ``notice`` a line shown above the
        status (loading, a stopped session)."""
        notes = status_notes(snap, notice)
        if notes != self.status_notes.content:  # sent only when it changes: rarely
            self.status_notes.content = notes
            self.status_notes.visible = bool(notes)  # an empty one would still take its padding
        self.status.content = status_block(snap, timing, scheduling, servo_rate)
        self.follow_switches(snap.deadman, snap.reflection, snap.T_0_H is not None)
        self._frames += 1
        if not live:
            return
        history = self._history
        if history and snap.time < history[-1][0]:
            history.clear()  # reset or a new loop
        slot = PLOT_SECONDS / PLOT_SAMPLES
        if not history or snap.time // slot > history[-1][0] // slot:  # one sample a slot
            history.append(plot_row(snap))
        while history and history[0][0] < snap.time - PLOT_SECONDS:
            history.popleft()
        if self.plot_due() and len(history) > 1:
            self.plot(np.array(history).T)

    @property
    def redraws(self) -> int:
        """The panel redraws (:meth:`update` calls) so far."""
        return self._frames

    def plot_due(self) -> bool:
        """Whether this frame refreshes the plots (every :data:`PLOT_EVERY` frames)."""
        return self._frames % PLOT_EVERY == 0

    def plot(self, cols: np.ndarray) -> None:
        """Show plot samples ``cols`` (:data:`PLOT_ROWS`, k): rows as in :data:`PlotRow`."""
        self.wrench_plot.data = (cols[0], cols[1], cols[2], cols[3])
        self.grip_plot.data = (cols[0], cols[4], cols[5])
        self.delta_plot.data = (cols[0], cols[6], cols[7], cols[8])
        self.energy_plot.data = (cols[0], cols[9])


def plot_row(snap: Snapshot) -> PlotRow:
    """The plot sample of ``snap`` (see :data:`PlotRow`)."""
    return (
        snap.time,
        *snap.F_MRF[0:3],
        float(np.linalg.norm(snap.G_F_T[0:3])),
        float(np.linalg.norm(snap.hand_wrench_0[0:3])),
        *(1000 * snap.delta_x[0:3]),
        snap.po_energy,
    )
