"""The browser haptic demo: :func:`serve` (behind ``frhc web``) and the :class:`DemoApp` it runs.

Three kinds of thread run the demo:

- the servo loop, in its own process (:class:`~app.web.realtime.RealtimeLoop`), paced at the
  servo rate;
- viser's own threads (websocket event loop, callback pool), which turn browser input into loop
  commands and never touch the loop directly;
- the UI thread here, which at :data:`UI_RATE` redraws the scene and the panel from the loop's
  latest snapshot. Every browser watches the same scene; a slow one only delays its own messages.
"""

from __future__ import annotations

import ipaddress
import sys
import threading
import time
from datetime import datetime
from pathlib import Path

import viser

from app.controller.gains import ControllerGains
from app.device.spec import DeviceSpec, available_devices, load_device
from app.session.loop import LoopConfig
from app.session.spec import Session, load_session
from app.spatial import Array
from app.web.access import TOKEN_NAME, TokenGate, new_token
from app.web.controls import Controls
from app.web.realtime import RealtimeLoop
from app.web.scene_view import SceneView
from app.world.scene import ROOT_DIR, Scene, available_scenes, load_scene

#: Scene and panel redraws per second.
UI_RATE = 30.0
#: Initial camera position and target in the viser frame (m).
INITIAL_CAMERA_POSITION = (-0.1, -1.1, 0.55)
INITIAL_CAMERA_LOOK_AT = (-0.1, 0.0, 0.08)
#: Where the record button writes ``web-<timestamp>/log``.
RUNS_DIR = ROOT_DIR / "runs"


class DemoApp:
    """The demo: one servo loop in real time, its 3D view and the control panel, on one viser server.

    Args:
        server: The viser server (already listening).
        scene, device: The loaded scene and device to start with.
        session: Optional session whose gains, mode, hand, accommodation and servo rate are used.
    """

    def __init__(self, server: viser.ViserServer, scene: Scene, device: DeviceSpec, session: Session | None) -> None:
        self.server = server
        self.session = session
        self._lock = threading.Lock()  # the UI thread redraws; a selection change rebuilds
        self._scene, self._device = scene, device
        self.rt = RealtimeLoop(self._loop_config(device, scene, self._start_gains(device)))
        server.scene.set_up_direction("+z")
        # In front of both spaces, slightly above: the device on the left, the world on the right.
        server.initial_camera.position = INITIAL_CAMERA_POSITION
        server.initial_camera.look_at = INITIAL_CAMERA_LOOK_AT
        self.view = SceneView(server, self.rt.loop, self.rt.set_hand_target)
        self._home_T_0_G = self.rt.loop.reading.T_0_G.copy()
        self.rt.set_hand_target(self._home_T_0_G)
        self._recording = False
        self.controls = Controls(server, self, available_scenes(), available_devices(), scene.spec.name, device.name)
        self.gate: TokenGate | None = None
        self.url = ""
        self._stop = threading.Event()
        self._ui = threading.Thread(target=self._ui_loop, name="web-ui", daemon=True)
        self.rt.start()
        self._ui.start()

    def _loop_config(self, device: DeviceSpec, scene: Scene, gains: ControllerGains) -> LoopConfig:
        """The loop for ``device`` and ``scene``; the session, if any, adds its hand, accommodation and rate."""
        if self.session is None:
            return LoopConfig(device, scene, gains)
        return LoopConfig.from_session(self.session, scene, device, gains)

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

    def reset(self) -> None:
        """Device and slave home, switches off, the hand back on the grip's home pose."""
        self.rt.reset()
        self.move_hand_target(self._home_T_0_G)

    def select(self, scene_name: str, device_name: str) -> None:
        """Rebuild the loop for another scene and/or device (gains follow the device)."""
        try:
            scene = self._scene if scene_name == self._scene.spec.name else load_scene(scene_name)
            device = self._device if device_name == self._device.name else load_device(device_name)
        except Exception as exc:  # a broken file in scenes/ or devices/ must not kill the server
            self.controls.record_status.content = f"**cannot load:** {exc}"
            return
        gains = self.rt.gains if device is self._device else self._start_gains(device)
        with self._lock:
            self.rt.stop()  # closes a log being written
            self._recording = False
            self.controls.record.label = "Record"
            self.view.remove()
            self._scene, self._device = scene, device
            self.rt = RealtimeLoop(self._loop_config(device, scene, gains))
            self.view = SceneView(self.server, self.rt.loop, self.rt.set_hand_target)
            self._home_T_0_G = self.rt.loop.reading.T_0_G.copy()
            self.rt.set_hand_target(self._home_T_0_G)
            self.controls.show_gains(gains)
            self.controls.release_switches()
            self.rt.start()

    def toggle_recording(self) -> Path | None:
        """Start a log in ``runs/web-<timestamp>/log`` and return it, or stop the current one (None)."""
        if self._recording:
            self.rt.stop_recording()
            self._recording = False
            return None
        directory = RUNS_DIR / f"web-{datetime.now():%Y%m%d-%H%M%S}" / "log"
        self.rt.start_recording(directory)
        self._recording = True
        return directory

    # -- UI thread ------------------------------------------------------------------------------

    def _ui_loop(self) -> None:
        period = 1.0 / UI_RATE
        next_frame = time.perf_counter()
        while not self._stop.is_set():
            with self._lock:
                snap = self.rt.snapshot
                self.view.update(snap)
                self.controls.update(snap, self.rt.stats(last=round(1.0 / self.rt.loop.dt)), self.rt.scheduling)
            next_frame += period
            self._stop.wait(max(0.0, next_frame - time.perf_counter()))
            next_frame = max(next_frame, time.perf_counter() - period)

    def close(self) -> None:
        """Stop the UI thread, the servo loop (closing any log) and the token gate; the server is
        left running."""
        self._stop.set()
        self._ui.join()
        self.rt.stop()
        if self.gate is not None:
            self.gate.close()


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def start_demo(
    scene: str,
    device: str,
    host: str = "127.0.0.1",
    port: int = 8080,
    session: str | None = None,
    insecure: bool = False,
) -> DemoApp:
    """Check the inputs, start a viser server and the demo on it; returns at once (non-blocking).

    On a non-loopback ``host`` the demo is served through a :class:`~app.web.access.TokenGate`
    (viser itself listens on loopback) unless ``insecure``; :attr:`DemoApp.url` is the address to
    open, with the token.

    Raises:
        ConfigError: for an unknown or malformed scene, device or session, before any server starts.
    """
    loaded_session = load_session(session) if session is not None else None
    scene_obj = load_scene(scene)
    device_obj = load_device(device)
    gated = not is_loopback(host) and not insecure
    server = viser.ViserServer(
        host="127.0.0.1" if gated else host, port=0 if gated else port, label="FRHC haptic demo", verbose=False
    )
    app = DemoApp(server, scene_obj, device_obj, loaded_session)
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    if gated:
        app.gate = TokenGate(host, port, server.get_port(), new_token())
        app.url = f"http://{shown}:{app.gate.port}/?{TOKEN_NAME}={app.gate.token}"
    else:
        if not is_loopback(host):
            print(
                f"warning: serving on {host} without a token (--insecure): anyone who can reach it can drive the demo",
                file=sys.stderr,
            )
        app.url = f"http://{shown}:{server.get_port()}/"
    return app


def serve(
    scene: str,
    device: str,
    host: str = "127.0.0.1",
    port: int = 8080,
    session: str | None = None,
    open_seconds: float | None = None,
    insecure: bool = False,
) -> None:
    """Serve the browser demo until interrupted (or for ``open_seconds`` seconds), printing its URL.

    Args:
        scene: Scene name in ``scenes/`` or path to a scene ``.toml``.
        device: Device name in ``devices/`` or path to a ``device.toml``.
        host: Bind address; anything but loopback needs the printed token (or ``insecure``).
        port: TCP port (viser moves to the next free one if it is taken; the printed URL is right).
        session: Optional session whose gains, mode, hand, accommodation and servo rate are used
            (scene and device still come from the arguments).
        open_seconds: Return after this long instead of serving forever (for tests).
        insecure: Serve a non-loopback ``host`` without a token.

    Raises:
        ConfigError: for an unknown or malformed scene, device or session, before the server starts.
    """
    app = start_demo(scene, device, host, port, session, insecure)
    print(f"FRHC haptic demo: {app.url}  (Ctrl+C to stop)", flush=True)
    try:
        if open_seconds is None:
            while True:
                time.sleep(3600.0)
        else:
            time.sleep(open_seconds)
    except KeyboardInterrupt:
        pass
    finally:
        app.close()
        app.server.stop()
