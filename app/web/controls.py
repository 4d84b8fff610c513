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
from app.teleop.channel import COUPLINGS
from app.web.scene_view import DEVICE_ORIGIN_V, FORCE_SCALE, MOMENT_SCALE, WORLD_ORIGIN_V, WRENCH_ARROWS
from app.web.snapshot import Snapshot
from app.world.arm import ArmStatus

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
#: UI frames between plot refreshes (plots are the heaviest messages).
PLOT_EVERY = 3

#: One plot sample: t (s), F_MRF xyz (N), |K_T F_MRF| (N), Delta X xyz (mm).
PlotRow = tuple[float, ...]
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

    def reset(self) -> None: ...

    def select(self, scene: str, device: str) -> None: ...

    def toggle_recording(self) -> Path | None: ...

    def set_passivity(self, on: bool) -> None: ...

    def set_channel(self, delay_ms: float, coupling: str) -> None: ...


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
    """The legend: where {0} and {w} are, and the arrow colours and scales."""
    rows = "\n".join(f"- <span style='color:rgb{a.color}'>■</span> {a.label} (darker: moment)" for a in WRENCH_ARROWS)
    return (
        f"Device base {{0}} on the left at x = {DEVICE_ORIGIN_V[0]:+.2f} m, slave world {{w}} on the right "
        f"at x = {WORLD_ORIGIN_V[0]:+.2f} m (same axes, z up). Drag the gizmo: it is the operator's hand.\n\n"
        f"Arrows: {FORCE_SCALE * 100:g} cm/N for forces, {MOMENT_SCALE * 100:g} cm/(N m) for moments.\n\n"
        f"{rows}\n- <span style='color:rgb(255,0,200)'>●</span> contact points"
    )


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
        gui.configure_theme(control_width="large")
        gui.set_panel_label("FRHC haptic demo (Williams 1997)")

        with gui.add_folder("Switches (Sec 4.1)"):
            self.deadman = gui.add_checkbox("Deadman [D]", False, hint="Commands and reflection flow while on")
            self.reference = gui.add_button("Reference [R]", hint="Momentary: sets {G0} (and indexes in pose mode)")
            self.reflection = gui.add_checkbox("Reflection [F]", False, hint="Task wrench, return-to-centre, damping")
            self.hand_to_grip = gui.add_button("Hand target to grip", hint="Move the gizmo to where the grip is")

        with gui.add_folder("Status"):
            self.status = gui.add_markdown("starting...")
            self.wrench_readout = gui.add_markdown("")

        with gui.add_folder("Plots"):
            empty = np.zeros(0)
            stroke = ("red", "green", "blue")
            self.wrench_plot = gui.add_uplot(
                data=(empty, empty, empty, empty, empty),
                series=(
                    viser.uplot.Series(label="t (s)"),
                    *(
                        viser.uplot.Series(label=f"F_MRF {a} (N)", stroke=c, width=1.5)
                        for a, c in zip("xyz", stroke, strict=True)
                    ),
                    viser.uplot.Series(label="|K_T F_MRF| at G (N)", stroke="orange", width=1.5),
                ),
                title="Task wrench",
                aspect=2.0,
                scales={"x": viser.uplot.Scale(time=False)},
            )
            self.delta_plot = gui.add_uplot(
                data=(empty, empty, empty, empty),
                series=(
                    viser.uplot.Series(label="t (s)"),
                    *(
                        viser.uplot.Series(label=f"ΔX {a} (mm)", stroke=c, width=1.5)
                        for a, c in zip("xyz", stroke, strict=True)
                    ),
                ),
                title="Delta X (Eq 4)",
                aspect=2.0,
                scales={"x": viser.uplot.Scale(time=False)},
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
            self.pc = gui.add_checkbox(
                "PO/PC",
                False,
                hint="Passivity observer/controller: the rendered torque is scaled down so the device port "
                "never gives out more energy than it has taken in",
            )
            self.delay = gui.add_number("Delay one way (ms)", 0.0, min=0.0, max=1000.0, step=1.0)
            self.coupling = gui.add_dropdown("Coupling", COUPLINGS, initial_value=COUPLINGS[0])

        with gui.add_folder("Scene and device", expand_by_default=False):
            self.scene = gui.add_dropdown("Scene", scenes, initial_value=scene)
            self.device = gui.add_dropdown("Device", devices, initial_value=device)
            self.reset_button = gui.add_button("Reset", hint="Device and tool home, switches off")
            self.record = gui.add_button("Record", hint="Write the per-tick Parquet log to runs/web-<time>/log")
            self.record_status = gui.add_markdown("")

        with gui.add_folder("Legend", expand_by_default=False):
            gui.add_markdown(legend_markdown())

        self._connect()
        self._history: collections.deque[PlotRow] = collections.deque()
        self._frames = 0

    def _connect(self) -> None:
        a = self.actions

        @self.deadman.on_update
        def _(_: viser.GuiEvent) -> None:
            a.set_deadman(self.deadman.value)

        @self.reflection.on_update
        def _(_: viser.GuiEvent) -> None:
            a.set_reflection(self.reflection.value)

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

        self.pc.on_update(lambda _: a.set_passivity(self.pc.value))
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
        directory = self.actions.toggle_recording()
        if directory is None:
            self.record.label = "Record"
            self.record_status.content = "log written" if self.record_status.content else ""
        else:
            self.record.label = "Stop recording"
            self.record_status.content = f"recording to `{directory}`"

    def _apply_gains(self, event: viser.GuiEvent) -> None:
        """Build gains from every input; refuse (and say why) anything the gains reject."""
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
            self.gain_message.content = f"**{message}** (kept the previous gains)"
            if event.client is not None:
                event.client.add_notification("Gain refused", message, color="red", auto_close_seconds=6.0)
            return
        self.actions.set_gains(gains)
        self.gain_message.content = "gains applied"

    def show_gains(self, gains: ControllerGains) -> None:
        """Put ``gains`` into the inputs (after a device change) without re-applying them."""
        for name, handle in self.six.items():
            _assign(handle, format_six(getattr(gains, name)))

    def update(self, snap: Snapshot, timing: TimingStats, scheduling: str) -> None:
        """Redraw status and plots from ``snap`` (call from the UI thread)."""
        faults = Fault(snap.faults)
        fault_text = "none" if faults == Fault.NONE else f"{faults!r}: {snap.fault_message}"
        limits = ArmStatus(snap.slave_status)
        slave_text = "follows" if limits == ArmStatus.NONE else f"**limited: {limits.name}**"
        self.status.content = (
            f"t = {snap.time:.2f} s · mode **{snap.mode}** · deadman {'ON' if snap.deadman else 'off'} · "
            f"reflection {'ON' if snap.reflection else 'off'}\n\n"
            f"servo rate **{timing.rate_hz:.1f} Hz** · tick {timing.tick_p50_us:.0f} us "
            f"(p99 {timing.tick_p99_us:.0f}) · jitter p99 {timing.jitter_p99_us:.0f} us · slips {timing.slips} · {scheduling}\n\n"
            f"saturation scale {snap.saturation_scale:.3f} · force ramp {snap.ramp:.2f} · "
            f"contacts {len(snap.contact_points_w)} · "
            + (f"device link **{snap.device_link}** · " if snap.device_link else "")
            + f"amplifier watchdog trips {snap.watchdog_trips} · "
            f"PO energy {snap.po_energy:+.3f} J · PC cut {snap.pc_cut:.0%} · "
            f"slave {slave_text} · faults: {fault_text}"
        )
        f_mrf = float(np.linalg.norm(snap.F_MRF[0:3]))
        f_g = float(np.linalg.norm(snap.G_F_T[0:3]))
        self.wrench_readout.content = (
            f"Task force |F_MRF| = {f_mrf:.2f} N · reflected |K_T F| = {f_g:.2f} N · "
            f"hand |f| = {float(np.linalg.norm(snap.hand_wrench_0[0:3])):.2f} N\n\n"
            f"ΔX = [{', '.join(f'{1000 * v:+.1f}' for v in snap.delta_x[0:3])}] mm"
        )

        history = self._history
        if history and snap.time < history[-1][0]:
            history.clear()  # reset or a new loop
        history.append((snap.time, *snap.F_MRF[0:3], f_g, *(1000 * snap.delta_x[0:3])))
        while history and history[0][0] < snap.time - PLOT_SECONDS:
            history.popleft()
        self._frames += 1
        if self._frames % PLOT_EVERY == 0 and len(history) > 1:
            self.plot(np.array(history).T)

    def plot(self, cols: np.ndarray) -> None:
        """Show plot samples ``cols`` (8, k): rows as in :data:`PlotRow`."""
        self.wrench_plot.data = (cols[0], cols[1], cols[2], cols[3], cols[4])
        self.delta_plot.data = (cols[0], cols[5], cols[6], cols[7])
