"""The browser haptic demo: the :class:`DemoApp` that :func:`~app.web.launch.serve` (behind ``frhc web``) runs.

Three kinds of thread run the demo:

- the servo loop, in its own process (:class:`~app.web.realtime.RealtimeLoop`), paced at the
  servo rate;
- viser's own threads (websocket event loop, callback pool), which turn browser input into loop
  commands and never touch the loop directly;
- the UI thread here, which at :data:`UI_RATE` redraws the panel from the loop's latest
  snapshot and, half a frame later, the scene from the same snapshot. Every browser watches the
  same scene; a slow one only delays its own messages.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

import numpy as np
import viser

from app.controller.gains import ControllerGains
from app.device.spec import DeviceSpec, available_devices, load_device, resolve_device_path
from app.errors import ConfigError, InvalidField
from app.session.files import RUNS_DIR, fresh_folder
from app.session.loop import LoopConfig, ServoLoop
from app.session.spec import Session, load_session
from app.spatial import Array
from app.teleop.channel import ChannelSettings
from app.web.access import TokenGate
from app.web.camera import (
    DOLLY_TO_CURSOR_JS,
    FOV,
    NO_EMPTY_BACKGROUND_JS,
    PANEL_WIDTH,
    SOFTWARE_LAMBERT_JS,
    SOFTWARE_RESOLUTION_JS,
    CameraPose,
    box_corners,
    choose_direction,
    fit_camera,
    recentre,
    run_in_page,
)
from app.web.controls import PLOT_SECONDS, Controls
from app.web.realtime import RealtimeLoop
from app.web.replay import LogReplay, ReplayPlayer
from app.web.scene_view import WORLD_ORIGIN_V, SceneView
from app.web.session_panel import ExperimentJob, SessionPanel
from app.web.snapshot import Snapshot
from app.world.scene import Scene, available_scenes, load_scene, resolve_scene_path

#: Scene and panel redraws per second. 40, not 30: a page redrawn at 30 Hz shows at most 30
#: changes a second and, with any late frame, fewer (28.8 Hz measured with the probe pressed).
UI_RATE = 40.0
#: The canvas width / height the opening camera is fitted for before a browser reports its own:
#: a 1400x900 page's, beside the docked panel.
DEFAULT_ASPECT = (1400 - PANEL_WIDTH) / 900
#: The hemisphere light replacing the environment map (:func:`light_without_shadows`): its ground
#: colour (RGB) and intensity, chosen so the picture matches viser's default lighting by eye.
FILL_GROUND = (90, 90, 100)
FILL_INTENSITY = 1.5


def light_without_shadows(server: viser.ViserServer) -> None:
    """viser's two directional lights without their shadows and a hemisphere light instead of the
    image-based (environment map) light: the picture looks the same (the scenes have no floor to
    take a shadow), but a 3D frame in a browser without a GPU (software WebGL) no longer draws three
    shadow cascades nor samples the environment at every pixel."""
    server.scene.configure_default_lights(enabled=True, cast_shadow=False)
    server.scene.configure_environment_map(None)
    server.scene.add_light_hemisphere("/fill_light", ground_color=FILL_GROUND, intensity=FILL_INTENSITY)


def _view_files(loop: ServoLoop) -> tuple[Path, Path, str] | None:
    """What a :class:`SceneView` of ``loop`` is built from: its scene and device files and its
    slave's kind (None for a scene made in code, which is never taken for another)."""
    path = loop.config.scene.path
    return None if path is None else (path, loop.config.device.path, loop.slave.scene.spec.slave.kind)


def _same_file(a: Path, b: Path | None) -> bool:
    """Whether ``a`` and ``b`` are one file (a scene built in code, ``b`` None, is no file)."""
    return b is not None and a.resolve() == b.resolve()


def _shown(name: str, path: Path | None, shipped: Callable[[str], Path]) -> str:
    """What a dropdown shows for the running scene or device: its name if it is the shipped file
    of that name (``shipped(name)``), else its path, so an edited copy that kept the name is not
    taken for the shipped one (choosing the name in the dropdown then loads the shipped file)."""
    return name if path is None or _same_file(shipped(name), path) else str(path)


class DemoApp:
    """The demo: one servo loop in real time, its 3D view and the control panel, on one viser server.

    Args:
        server: The viser server (already listening).
        scene, device: The loaded scene and device to start with.
        session: Optional session whose gains, mode, hand, accommodation and servo rate are used.
        servo_rate: The loop's rate (Hz) for everything the demo runs, sessions played included;
            None: the session's (1 kHz without one).
        device_url: ``device`` is outside this process, at this address (``ws://host:port``,
            ``fd:N``, ``openhaptics:NAME``); ``device`` is its file (limits, gains). Choosing
            another device in the page simulates that one; choosing ``device`` again reconnects.
        panel: The guide and task panel, if already shown (:func:`~app.web.launch.start_demo`
            builds it before importing this module); else built first here.
        spin: Share of each servo period the loop process spins instead of sleeping
            (:class:`~app.session.pacer.Pacer`); None: the pacer's default, which leaves the CPU
            idle between ticks.
    """

    def __init__(
        self,
        server: viser.ViserServer,
        scene: Scene,
        device: DeviceSpec,
        session: Session | None,
        servo_rate: float | None = None,
        device_url: str | None = None,
        panel: SessionPanel | None = None,
        spin: float | None = None,
    ) -> None:
        self.server = server
        self.servo_rate = servo_rate
        self._spin = spin
        self._device_url = device_url
        self._url_device = device.path
        self.session = self._at_rate(session) if session is not None else None
        self._lock = threading.Lock()  # the UI thread redraws; a selection change rebuilds
        self._scene, self._device = scene, device
        self.player: ReplayPlayer | None = None
        self._showing_selection = False
        #: A line above the status: loading a session, or why one stopped ("" for none).
        self._notice = ""
        self._loading = False  # the notice is a loading one, cleared when the play shows up
        #: The notice saying the running loop's process ended unasked (killed, crashed), once the
        #: UI thread noticed; None while it runs.
        self._loop_lost: str | None = None
        # The guide first: a browser that connects at once shows it while the loop is built (a
        # click on it in that time waits, with "starting..." shown, until :meth:`SessionPanel.ready`).
        self.panel = panel if panel is not None else SessionPanel(server, RUNS_DIR)
        self.rt = RealtimeLoop(self._loop_config(device, scene, self._start_gains(device)), spin=spin)
        server.scene.set_up_direction("+z")
        light_without_shadows(server)
        self.view = SceneView(server, self.rt.loop, self.rt.set_hand_target)
        #: The loop the view was built for (its scene and device files).
        self.view_loop = self.rt.loop
        #: Clients whose camera was fitted to their canvas: the canvas' aspect, the pose set, the preset.
        self._fitted: dict[int, tuple[float, CameraPose, str]] = {}
        self._frame_initial_camera()
        server.on_client_connect(self._on_connect)
        server.scene.on_click()(self._on_scene_click)
        self._home_T_0_G = self.rt.loop.reading.T_0_G.copy()
        self.rt.set_hand_target(self._home_T_0_G)
        self._recording = False
        self.controls = Controls(server, self, available_scenes(), available_devices(), scene.spec.name, device.name)
        self._show_passivity(self.rt.config)
        self._replay_shown = float("nan")  # the replay cursor the plots show
        self._drawn: Snapshot | None = None  # what the panel shows, for the scene's redraw
        self.experiment: ExperimentJob | None = None
        self.gate: TokenGate | None = None
        self.url = ""
        self._stop = threading.Event()
        self._ui = threading.Thread(target=self._ui_loop, name="web-ui", daemon=True)
        self.rt.start()
        self._ui.start()
        self.panel.ready(self)

    def _loop_config(self, device: DeviceSpec, scene: Scene, gains: ControllerGains) -> LoopConfig:
        """The loop for ``device`` and ``scene``; the session, if any, adds its hand, accommodation and rate."""
        if self.session is None:
            config = LoopConfig(device, scene, gains)
            if self.servo_rate is not None:
                config = dataclasses.replace(config, servo_rate=self.servo_rate)
        else:
            config = LoopConfig.from_session(self.session, scene, device, gains)
        if self._device_url is not None and device.path == self._url_device:
            config = dataclasses.replace(config, device_url=self._device_url)
        if config.cartesian and config.passivity.enabled:
            # A session's PO/PC cannot act on a device chosen in the page that has no joint
            # ports; the loop runs without it and the greyed checkbox says why.
            config = dataclasses.replace(config, passivity=dataclasses.replace(config.passivity, enabled=False))
        return config

    def _at_rate(self, session: Session) -> Session:
        """``session`` at the demo's servo rate, if one was asked for (its gains are physical, so
        they mean the same at any rate: ``docs/conventions.md``)."""
        if self.servo_rate is None or session.data.servo_rate == self.servo_rate:
            return session
        return session.with_changes(servo_rate=self.servo_rate)

    def _start_gains(self, device: DeviceSpec) -> ControllerGains:
        if self.session is not None and self.session.device.path == device.path:
            return self.session.gains
        return device.data.gains

    # -- DemoActions ----------------------------------------------------------------------------

    @property
    def gains(self) -> ControllerGains:
        return self.rt.gains

    def set_gains(self, gains: ControllerGains) -> None:
        self.rt.set_gains(gains)

    def set_deadman(self, on: bool) -> None:
        self.rt.set_deadman(on)

    def press_reference(self) -> None:
        self.rt.press_reference()

    def set_reflection(self, on: bool) -> None:
        self.rt.set_reflection(on)

    def move_hand_target(self, T_0_H: Array) -> None:
        """Move the operator's hand to ``T_0_H`` (4, 4, device base) as if the gizmo were dragged there."""
        self.view.set_hand_target(T_0_H)
        self.rt.set_hand_target(T_0_H)

    def hand_to_grip(self) -> None:
        self.move_hand_target(self.rt.snapshot.T_0_G)

    def set_hand_holds(self, on: bool) -> None:
        """The operator's hand takes hold of the grip where the grip is (the gizmo moved there: no
        pull), or lets go (``on`` False; a drag of the gizmo takes hold again)."""
        if on:
            self.hand_to_grip()
        else:
            self.rt.set_hand_target(None)

    def reset(self) -> None:
        """Device and slave home, switches off, the hand back on the grip's home pose (in a new
        loop process if the last one ended unasked)."""
        if self.rt.ended() is not None:
            self._rebuild(dataclasses.replace(self.rt.config, gains=self.rt.gains))
        self.rt.reset()
        self.move_hand_target(self._home_T_0_G)

    def select(self, scene_name: str, device_name: str) -> None:
        """Rebuild the loop for another scene and/or device (gains follow the device); a session
        playing is stopped, and the page says so."""
        same_scene = _same_file(resolve_scene_path(scene_name), self._scene.path)
        same_device = _same_file(resolve_device_path(device_name), self._device.path)
        if self._showing_selection or (same_scene and same_device):
            return
        playing = self.rt.snapshot.playing
        what = "scene" if not same_scene else "device"
        try:
            scene = self._scene if same_scene else load_scene(scene_name)
            device = self._device if same_device else load_device(device_name)
            gains = self.rt.gains if device is self._device else self._start_gains(device)
            # Building the loop refuses what the files alone do not show (an arm that cannot
            # reach the tool's home), before the running loop is stopped.
            self._rebuild(self._loop_config(device, scene, gains))
        except Exception as exc:  # a broken file in scenes/ or devices/ must not kill the server
            self.controls.record_status.content = f"**cannot load:** {exc}"
            self._show_selection()  # the dropdowns back on what still runs
            return
        if playing is not None:
            # Not a loading notice any more: the redraw that sees the play start must not clear it.
            self._notice, self._loading = f"**stopped `{playing.stem}`**: the {what} was changed", False
            for client in self.server.get_clients().values():  # viser notifies per browser
                client.add_notification("Session stopped", f"{playing.stem}: the {what} was changed", color="yellow")

    def _rebuild(self, config: LoopConfig) -> None:
        """Replace the running loop (and the view, unless a replay is shown) by one of ``config``.

        Raises:
            ConfigError: ``config``'s loop cannot be built; the running loop is left as it is.
        """
        rt = RealtimeLoop(config, spin=self._spin)
        with self._lock:
            self.rt.stop()  # closes a log being written
            self._recording = False
            self.controls.record.label = "Record"
            self._scene, self._device = config.scene, config.device
            self.rt = rt
            if self._notice == self._loop_lost:  # not a loading notice written over it
                self._notice = ""
            self._loop_lost = None
            if self.player is None:
                self._show_view(self.rt.loop, self.rt.set_hand_target)
            self._home_T_0_G = self.rt.loop.reading.T_0_G.copy()
            self.rt.set_hand_target(self._home_T_0_G)
            self.controls.show_gains(config.gains)
            self._show_passivity(config)
            self.controls.release_switches()
            self.controls.clear_plots()
            self.rt.start()
        self._show_selection()

    def _show_passivity(self, config: LoopConfig) -> None:
        """The PO/PC checkbox on ``config``'s passivity, greyed out on a Cartesian device."""
        self.controls.show_passivity(config.passivity.enabled, not config.cartesian)

    def _show_selection(self) -> None:
        """The scene and device dropdowns on the running loop's."""
        self._showing_selection = True  # the dropdowns' callbacks must not rebuild again
        try:
            self.controls.show_selection(
                _shown(self._scene.spec.name, self._scene.path, resolve_scene_path),
                _shown(self._device.name, self._device.path, resolve_device_path),
            )
        finally:
            self._showing_selection = False

    # -- camera -------------------------------------------------------------------------------

    def preset_points(self, preset: str) -> Array:
        """The points (k, 3, viser frame, m) camera preset ``preset`` frames: the corners of the
        device's box, the world's, both (the two boxes' 16 corners, not the box round both: its
        corners above the low world and below the device's reach are empty), or the tool's."""
        view = self.view
        if preset == "device":
            return box_corners(view.device_box_v)
        if preset == "world":
            return box_corners(view.world_box_v)
        if preset == "tool":
            centre = self.shown_snapshot().T_w_MRF[0:3, 3] + WORLD_ORIGIN_V
            half = np.full(3, 1.5 * view.tool_radius)
            return box_corners(np.stack((centre - half, centre + half)))
        return np.vstack((box_corners(view.device_box_v), box_corners(view.world_box_v)))

    def frame_camera(self, client: viser.ClientHandle, preset: str = "both") -> CameraPose:
        """Point ``client``'s camera at ``preset`` fitted to its canvas beside the panel, from the
        view's direction."""
        camera = client.camera
        aspect = camera.aspect if camera.image_height else DEFAULT_ASPECT
        camera.fov = FOV
        pose = fit_camera(self.preset_points(preset), aspect, self.view_direction)
        camera.position = pose.position
        camera.look_at = pose.look_at
        if camera.image_height:
            self._fitted[client.client_id] = (aspect, pose, preset)
        return pose

    def _frame_initial_camera(self) -> None:
        """The view's direction (the one showing both spaces largest at :data:`DEFAULT_ASPECT`)
        and the opening (and Reset View) camera: both spaces from it."""
        both = self.preset_points("both")
        #: The direction every preset looks from (unit, viser frame): the view's own.
        self.view_direction = choose_direction(both, DEFAULT_ASPECT)
        pose = fit_camera(both, DEFAULT_ASPECT, self.view_direction)
        initial = self.server.initial_camera
        initial.fov = FOV
        initial.position = pose.position
        initial.look_at = pose.look_at

    def _on_scene_click(self, event: viser.SceneClickEvent) -> None:
        """A click on a mesh makes the point clicked the centre the browser's camera orbits and
        zooms about (the camera moves, keeping its direction and distance); elsewhere, nothing."""
        origin, direction = np.array(event.ray_origin), np.array(event.ray_direction)
        with self._lock:  # the view is not rebuilt while it is searched
            hit = self.view.pick(origin, direction)
        if hit is None:
            return
        camera = event.client.camera
        # viser moves the look-at point with the position (by the same offset): onto ``hit``.
        camera.position = recentre(CameraPose(camera.position, camera.look_at), hit).position

    def _on_connect(self, client: viser.ClientHandle) -> None:
        """Zoom toward the cursor in the new browser, draw its view at a lower resolution and shade
        its lit nodes with the Lambert shader if it has no GPU, draw it without viser's empty
        background quad, and fit its camera once it has reported its canvas size, and again while
        the canvas changes shape (the page docks the panel after its first report) as long as the
        camera is where the fit put it."""
        run_in_page(client, DOLLY_TO_CURSOR_JS)
        run_in_page(client, SOFTWARE_RESOLUTION_JS)
        run_in_page(client, SOFTWARE_LAMBERT_JS)
        run_in_page(client, NO_EMPTY_BACKGROUND_JS)

        @client.camera.on_update
        def _(camera: viser.CameraHandle) -> None:
            if not camera.image_height:
                return
            fitted = self._fitted.get(client.client_id)
            if fitted is None:
                self.frame_camera(client)
                return
            aspect, pose, preset = fitted
            if (
                abs(camera.aspect / aspect - 1.0) > 0.01
                and np.allclose(camera.position, pose.position, atol=1e-4)
                and np.allclose(camera.look_at, pose.look_at, atol=1e-4)
            ):
                self.frame_camera(client, preset)

    def _show_view(self, loop: ServoLoop, on_hand_moved: Callable[[Array], None]) -> None:
        """Replace the 3D view by one of ``loop``; every browser's camera is refitted when what
        it frames changed (another scene or device: each has its own framing)."""
        files = _view_files(loop)
        if files is not None and files == _view_files(self.view_loop):
            # The same scene and device (a replay of a log of the live loop, or back to live):
            # the nodes stay, and the browsers get only what moves, not every mesh again.
            self.view.on_hand_moved = on_hand_moved
            self.view_loop = loop
            return
        before = self.preset_points("both")
        self.view.remove()
        self.view = SceneView(self.server, loop, on_hand_moved)
        self.view_loop = loop
        self._drawn = None  # a snapshot of the view before: another device's links
        if not np.allclose(before, self.preset_points("both")):
            self._frame_initial_camera()
            for client in self.server.get_clients().values():
                self.frame_camera(client)

    def shown_snapshot(self) -> Snapshot:
        """The state the view shows: the replay's cursor, else the live loop's latest."""
        player = self.player
        return player.snapshot() if player is not None else self.rt.snapshot

    # -- SessionActions -------------------------------------------------------------------------

    def play_session(self, name: str) -> None:
        """Play session ``name`` (in ``sessions/``, or a path) live, rebuilding the loop if it needs another."""
        # Shown at once: loading the session's scene and device and building its loop take seconds.
        self._notice = f"**loading `{name}`**: building the loop and starting its script..."
        self.panel.show_play_status(self._notice)
        self._loading = True
        try:
            session = self._at_rate(load_session(name))
        except ConfigError as exc:
            self.show_notice(f"**cannot load:** {exc}")
            return
        self.close_replay()
        wanted = LoopConfig.from_session(session)
        have = self.rt.config
        same = (wanted.scene.path, wanted.device.path, wanted.hand, wanted.accommodation, wanted.servo_rate) == (
            have.scene.path,
            have.device.path,
            have.hand,
            have.accommodation,
            have.servo_rate,
        )
        if not same or self.rt.ended() is not None:
            try:
                self._rebuild(wanted)
            except ConfigError as exc:
                self.show_notice(f"**cannot load:** {exc}")
                return
            try:
                started = self.rt.wait_running()
            except RuntimeError:  # it died while starting: the UI frame says so (_notice_lost_loop)
                return
            if not started:
                self.show_notice(f"**cannot play `{name}`:** the servo loop process did not start")
                return
        self.session = session
        self.rt.play(session)
        self.rt.set_speed(float(self.panel.speed.value))
        self.controls.show_gains(session.gains)
        self.controls.clear_plots()

    def pause(self, on: bool) -> None:
        self.rt.pause(on)

    def show_notice(self, text: str) -> None:
        """Say ``text`` (Markdown) in the player's status line until a session is played."""
        self._notice, self._loading = text, False
        self.panel.show_play_status(text)

    def set_speed(self, factor: float) -> None:
        self.rt.set_speed(factor)

    def open_replay(self, directory: str) -> None:
        """Show the log in ``directory`` instead of the live loop (which keeps running)."""
        try:
            replay = LogReplay(Path(directory))
        except (ConfigError, OSError, ValueError) as exc:
            self.panel.show_replay(None, f"**cannot replay:** {exc}")
            return
        self.show_replay(replay)

    def show_replay(self, replay: LogReplay) -> None:
        """Show ``replay`` instead of the live loop (which keeps running)."""
        player = ReplayPlayer(replay)
        with self._lock:
            self._show_view(player.replay.loop, lambda _: None)
            self.player = player
            self._replay_shown = float("nan")
        text = f"replaying `{player.replay.directory}` ({len(player.replay)} ticks)"
        if player.replay.unchecked:
            text += f" · **not checked:** {player.replay.unchecked}"
        self.panel.show_replay(player.duration, text)
        self.panel.show_cursor(player.cursor)

    def close_replay(self) -> None:
        """Back to the live loop."""
        with self._lock:
            if self.player is None:
                return
            self.player = None
            self._show_view(self.rt.loop, self.rt.set_hand_target)
        self.panel.show_replay(None, "")

    def seek(self, t: float) -> None:
        """Show time ``t`` (s) of the replay; a refused ``t`` (NaN) puts the timeline back."""
        player = self.player
        if player is not None:
            player.seek(t)
            if not np.isfinite(t):
                self.panel.show_cursor(player.cursor)

    def set_replay_playing(self, on: bool) -> None:
        if self.player is not None:
            self.player.playing = on

    def set_replay_speed(self, factor: float) -> None:
        if self.player is not None:
            self.player.speed = factor

    def start_experiment(self, operators: int) -> None:
        """Run the Table I experiment in the background; the panel shows progress and results."""
        if self.experiment is not None and not self.experiment.finished:
            return
        self.experiment = ExperimentJob(RUNS_DIR, f"web-experiment-{datetime.now():%Y%m%d-%H%M%S}", operators)

    def set_passivity(self, on: bool) -> None:
        """Switch the passivity controller (its settings otherwise the loop's: a session's own)."""
        self.rt.set_passivity(dataclasses.replace(self.rt.config.passivity, enabled=on))

    def set_channel(self, delay_ms: float, coupling: str) -> None:
        """A master-slave channel of ``delay_ms`` each way with ``coupling``; refused values are shown."""
        try:
            settings = ChannelSettings(delay_ms=delay_ms, coupling=coupling)  # type: ignore[arg-type]
        except (ConfigError, InvalidField) as exc:
            self.controls.gain_message.content = f"**Refused channel:** {exc}"
            return
        self.rt.set_channel(settings)

    def toggle_recording(self) -> Path | None:
        """Start a log in ``runs/web-<timestamp>/log`` and return it, or stop the current one (None).

        Raises:
            OSError: the log's folder cannot be made.
        """
        if self._recording:
            self.rt.stop_recording()
            self._recording = False
            return None
        directory = fresh_folder(RUNS_DIR, f"web-{datetime.now():%Y%m%d-%H%M%S}") / "log"
        self.rt.start_recording(directory)
        self._recording = True
        return directory

    # -- UI thread ------------------------------------------------------------------------------

    def _ui_loop(self) -> None:
        """Redraw the panel, then half a frame later the scene, at :data:`UI_RATE` each.

        Apart, they reach the browsers in separate websocket windows: viser's page applies a
        window holding a scene update only in its next 3D frame (a render in software WebGL costs
        tens of ms), but a panel-only window at once, so the status does not wait for the 3D view.
        """
        half = 0.5 / UI_RATE
        next_step = last_panel = time.perf_counter()
        panel = True
        while not self._stop.is_set():
            with self._lock:
                if panel:
                    # The wall time since the last panel, not the nominal period: frames the loop
                    # drops under load must not slow a replay below its speed.
                    now = time.perf_counter()
                    self._draw_panel(now - last_panel)
                    last_panel = now
                elif self._drawn is not None:
                    with self.server.atomic():  # one websocket window: the page applies it in one frame
                        self.view.update(self._drawn)
            # Sent now, not at viser's next window tick: its event loop sends a window and then
            # waits up to 1/60 s for more, so a redraw could wait there, merge with the next one
            # (panel with scene: the status waits for a 3D frame) or be superseded by it.
            self.server.flush()
            panel = not panel
            next_step += half
            self._stop.wait(max(0.0, next_step - time.perf_counter()))
            next_step = max(next_step, time.perf_counter() - half)

    def _draw_panel(self, period: float) -> None:
        """Redraw the panel once, from the replay or the live loop, and keep the snapshot shown
        for the scene's redraw (``period``: wall seconds since the last call)."""
        self._notice_lost_loop()
        player = self.player
        stats = self.rt.stats(last=round(1.0 / self.rt.loop.dt))
        servo_rate = 1.0 / self.rt.loop.dt
        if player is None:
            snap = self.rt.snapshot
            if self._loading and snap.playing is not None:
                self._loading, self._notice = False, ""
            self.controls.update(snap, stats, self.rt.scheduling, servo_rate, self._notice)
            if snap.playing is not None and self._loop_lost is None:  # a dead loop's last snapshot
                left = f", {snap.play_left:.1f} s left at {snap.speed:g}x"
                text = f"playing `{snap.playing.stem}`{left}" + (" (paused)" if snap.paused else "")
            else:
                text = self._notice or "no session playing" + (" (paused)" if snap.paused else "")
            self.panel.show_play_status(text)
            self.panel.show_speed(snap.speed)
        else:
            played_from = player.cursor
            player.advance(period)
            snap = player.snapshot()
            self.controls.update(snap, stats, "replay", servo_rate, "", live=False)
            # As often as the live page plots, and only when the cursor moved: a still replay sends none.
            if player.cursor != self._replay_shown and self.controls.plot_due():
                self.controls.plot(player.window(PLOT_SECONDS))
                self._replay_shown = player.cursor
            # Only a cursor that playing moved: paused, the timeline is the page's, and writing it
            # back here could land between viser taking a scrub and its callback reading it.
            if player.cursor != played_from:
                self.panel.show_cursor(player.cursor)
            p = snap.T_w_MRF[0:3, 3]
            self.panel.replay_status.content = (
                f"replay t = {snap.time:.3f} s (tick {snap.ticks} of {len(player.replay)}) · tool at "
                f"[{1000 * p[0]:+.1f}, {1000 * p[1]:+.1f}, {1000 * p[2]:+.1f}] mm · "
                f"|F_MRF| = {float(np.linalg.norm(snap.F_MRF[0:3])):.2f} N"
            )
        self._drawn = snap
        job = self.experiment
        if job is not None:
            if job.error is not None:
                self.panel.experiment_result.content = f"**experiment failed:** {job.error}"
                self.experiment = None
            else:
                self.panel.show_experiment(job.done, job.total, job.report.table if job.report else None, job.chart())
                if job.finished:
                    self.experiment = None

    def _notice_lost_loop(self) -> None:
        """Say once, on the page (status line and a notification) and on stderr, that the loop
        process ended although nothing stopped it (killed, crashed): the page would otherwise go
        on showing its last snapshot as if it ran."""
        if self._loop_lost is not None:
            return
        why = self.rt.ended()
        if why is None:
            return
        message = (
            f"the servo loop process stopped ({why}): nothing is simulated; "
            "Play, Try the peg task or Reset starts a new one"
        )
        print(f"frhc web: {message}", file=sys.stderr, flush=True)
        self._loop_lost = f"**{message}**"
        self._notice, self._loading = self._loop_lost, False
        for client in self.server.get_clients().values():  # viser notifies per browser
            client.add_notification("Servo loop stopped", message, color="red")

    def close(self) -> None:
        """Stop the UI thread, the servo loop (closing any log) and the token gate; the server is
        left running."""
        self._stop.set()
        self._ui.join()
        self.rt.stop()
        if self.gate is not None:
            self.gate.close()
