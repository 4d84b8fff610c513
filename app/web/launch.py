"""Starting the browser demo: :func:`serve` (behind ``frhc web``) and :func:`start_demo`.

The server listens, with the guide panel, before anything else is imported: the servo loop,
MuJoCo, trimesh with scipy and numba take 1-2 s to import, the page's own boot in the browser
about 1.5 s, and the two now overlap (the page's websocket gets the guide as soon as it
connects; a click on it waits until the demo is up). The inputs are therefore checked with the
server already listening; a bad one stops it before :func:`start_demo` raises, so nothing is
served and the command exits with its one-line error. This module imports only viser and the
panel's light modules; :mod:`app.web.server` (the demo itself) is imported in :func:`start_demo`.
"""

from __future__ import annotations

import errno
import gzip
import io
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stdout
from pathlib import Path
from typing import TYPE_CHECKING, Any

import viser
import websockets.asyncio.server
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from app.errors import ListenError
from app.interrupts import signals_held
from app.listen import check_listenable, url_authority
from app.session.files import RUNS_DIR
from app.web.access import TOKEN_NAME, TokenGate, is_loopback, new_token, viser_on_unix_socket
from app.web.camera import SOFTWARE_NO_ANTIALIAS_JS
from app.web.casts import guard_page_casts
from app.web.session_panel import SessionPanel

if TYPE_CHECKING:
    from app.web.server import DemoApp

#: viser's page (one file: its whole script is inlined).
VISER_PAGE = Path(viser.__file__).parent / "client" / "build" / "index.html"


@contextmanager
def script_in_page_head(source: str) -> Iterator[None]:
    """A viser server constructed inside the block serves its page with the script ``source``
    first in its ``<head>``, so that it runs before viser's own (which makes the WebGL context as
    it boots, before the websocket brings any message that could run a script).

    viser has no option for it: like :func:`~app.web.access.viser_on_unix_socket`, the block
    wraps the ``websockets.asyncio.server.serve`` call viser's constructor makes, here to wrap the
    HTTP handler viser passes it (``process_request``). The page's other files, and any response
    but a 200, are viser's own. Only that constructor may run inside the block.
    """
    original = websockets.asyncio.server.serve
    page = VISER_PAGE.read_bytes().replace(b"<head>", b"<head><script>" + source.encode() + b"</script>", 1)
    zipped = gzip.compress(page)

    def on_serve(handler: Any, *args: Any, **options: Any) -> Any:
        viser_http = options.get("process_request")
        if viser_http is not None:

            def process_request(connection: Any, request: Request) -> Response | None:
                response: Response | None = viser_http(connection, request)
                path = request.path.partition("?")[0]
                if response is None or response.status_code != 200 or path not in ("/", "/index.html"):
                    return response
                body = zipped if response.headers.get("Content-Encoding") == "gzip" else page
                headers = Headers(response.headers)
                del headers["Content-Length"]  # setting a header adds a value
                headers["Content-Length"] = str(len(body))
                return Response(response.status_code, response.reason_phrase, headers, body)

            options["process_request"] = process_request
        return original(handler, *args, **options)

    websockets.asyncio.server.serve = on_serve  # type: ignore[assignment, misc]
    try:
        yield
    finally:
        websockets.asyncio.server.serve = original  # type: ignore[misc]


def _demo(
    server: viser.ViserServer,
    panel: SessionPanel,
    scene: str,
    device: str,
    session: str | None,
    replay: str | None,
    servo_rate: float | None,
    spin: float | None = None,
) -> DemoApp:
    """Check the inputs and build the demo on ``server`` (whose page already shows ``panel``)."""
    # Imported here, with the page already served: see the module's docstring.
    from app.device.haply import CONNECT_TIMEOUT, served_device
    from app.device.spec import load_device
    from app.device.vendors import is_device_url, open_device_url
    from app.session.spec import check_servo_rate, load_session
    from app.web.replay import LogReplay
    from app.web.server import DemoApp
    from app.world.scene import load_scene

    if servo_rate is not None:
        check_servo_rate(servo_rate)
    loaded_session = load_session(session) if session is not None else None
    scene_obj = load_scene(scene)
    device_url = device if is_device_url(device) else None
    if device_url is not None:
        device_obj = served_device(device_url, loaded_session.device if loaded_session is not None else None)
        if not device_url.startswith(("ws://", "wss://")):  # served_device has reached a served one
            # Opened (and closed) once here: the loop process opens it again, but a failure there
            # is a traceback in that process and a page that waits; here it is one line, exit 2.
            open_device_url(device_url, CONNECT_TIMEOUT).close()
    else:
        device_obj = load_device(device)
    loaded_replay = LogReplay(Path(replay)) if replay is not None else None
    if loaded_replay is not None and loaded_replay.unchecked:
        print(f"warning: {loaded_replay.unchecked}", file=sys.stderr)
    app = DemoApp(server, scene_obj, device_obj, loaded_session, servo_rate, device_url, panel, spin)
    if loaded_replay is not None:
        app.show_replay(loaded_replay)
    return app


def start_demo(
    scene: str,
    device: str,
    host: str = "127.0.0.1",
    port: int = 8080,
    session: str | None = None,
    insecure: bool = False,
    replay: str | None = None,
    servo_rate: float | None = None,
    spin: float | None = None,
) -> DemoApp:
    """Start a viser server with the guide panel, check the inputs and start the demo on it;
    returns once the demo runs (non-blocking).

    On a non-loopback ``host`` the demo is served through a :class:`~app.web.access.TokenGate`
    (viser itself then listens on a private unix socket, no TCP port) unless ``insecure``;
    :attr:`DemoApp.url` is the address to open, with the token.

    ``device`` may be a device outside this process (``ws://host:port``, ``fd:N``,
    ``openhaptics:NAME``): a ``frhc device serve`` names its own device file; for another, the
    session's device file if it is Cartesian, else the vendor's shipped one (``inverse3``,
    ``omega3``, ``touch3``), gives its limits (:func:`~app.device.haply.served_device`).
    ``spin``: the share of each servo period the loop process spins (:class:`DemoApp`).

    Raises:
        ConfigError: for an unknown or malformed scene, device or session (the server is stopped
            first: nothing stays served).
        InvalidField: ``servo_rate`` outside the sessions' range (likewise).
        DeviceUnreachable: nothing answers at a ``ws://`` ``device`` (likewise).
        ListenError: ``host:port`` cannot be listened on: a busy port is refused, not swapped for
            the next free one as viser would (nothing is started, or it is stopped).
    """
    gated = not is_loopback(host) and not insecure
    inner: Path | None = None
    check_listenable(host, port)  # viser would serve on the next free port instead, the gate fail late
    # viser prints its own address box (without the token; :func:`serve` prints the address to
    # open) and "Server stopped": not on stdout, where a refused input must leave nothing.
    with redirect_stdout(io.StringIO()), script_in_page_head(SOFTWARE_NO_ANTIALIAS_JS):
        if gated:
            inner = Path(tempfile.mkdtemp(prefix="frhc-viser-")) / "viser.sock"  # the folder is 0700
            with viser_on_unix_socket(inner):
                server = viser.ViserServer(label="FRHC haptic demo", verbose=False)
        else:
            server = viser.ViserServer(host=host, port=port, label="FRHC haptic demo", verbose=False)
    guard_page_casts(server)
    app: DemoApp | None = None
    try:
        with signals_held():
            app = _demo(server, SessionPanel(server, RUNS_DIR), scene, device, session, replay, servo_rate, spin)
        if inner is not None:
            app.gate = TokenGate(host, port, inner, new_token())
        elif port and server.get_port() != port:  # taken between the check and viser's bind
            raise ListenError(host, port, OSError(errno.EADDRINUSE, "in use"))
    except BaseException:
        if app is not None:  # a signal held while it was built
            app.close()
        with redirect_stdout(io.StringIO()):
            server.stop()
        raise
    if app.gate is not None:
        app.url = f"http://{url_authority(host, app.gate.port)}/?{TOKEN_NAME}={app.gate.token}"
    else:
        if not is_loopback(host):
            print(
                f"warning: serving on {host} without a token (--insecure): anyone who can reach it can drive the demo",
                file=sys.stderr,
            )
        app.url = f"http://{url_authority(host, server.get_port())}/"
    return app


def serve(
    scene: str,
    device: str,
    host: str = "127.0.0.1",
    port: int = 8080,
    session: str | None = None,
    open_seconds: float | None = None,
    insecure: bool = False,
    replay: str | None = None,
    servo_rate: float | None = None,
    spin: float | None = None,
) -> None:
    """Serve the browser demo until interrupted (or for ``open_seconds`` seconds), printing its URL.

    Args:
        scene: Scene name in ``scenes/`` or path to a scene ``.toml``.
        device: Device name in ``devices/``, path to a ``device.toml``, or a device outside this
            process (``ws://host:port``, ``fd:N``, ``openhaptics:NAME``; see :func:`start_demo`).
        host: Bind address; anything but loopback needs the printed token (or ``insecure``).
        port: TCP port (viser moves to the next free one if it is taken; the printed URL is right).
        session: Optional session whose gains, mode, hand, accommodation and servo rate are used
            (scene and device still come from the arguments).
        open_seconds: Return after this long instead of serving forever (for tests).
        insecure: Serve a non-loopback ``host`` without a token.
        replay: A log directory to start on, in replay (the live loop runs beside it).
        servo_rate: The loop's rate (Hz) for everything the demo runs, sessions played included
            (default: the session's, else 1 kHz).
        spin: Share of each period the loop process spins (:class:`DemoApp`); None: no more than
            the pacer's default.

    Raises:
        ConfigError: for an unknown or malformed scene, device or session (nothing stays served).
    """
    app = start_demo(scene, device, host, port, session, insecure, replay, servo_rate, spin)
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
