"""Haply's Inverse Service protocol: a client backend, and a server for simulated devices.

Haply's Inverse Service is a local WebSocket server (default ``ws://localhost:10001``) that streams
JSON device state and takes JSON commands. The fields used here are those of Isaac Lab's open
client (``isaaclab/devices/haply/se3_haply.py``):

- state: ``inverse3[i].device_id``, ``inverse3[i].state.cursor_position.{x,y,z}`` (m);
  ``wireless_verse_grip[i].state.orientation.{x,y,z,w}`` (quaternion) and ``.buttons.{a,b,c}``;
- command: ``{"inverse3": [{"device_id": ..., "commands": {"set_cursor_force": {"values":
  {"x", "y", "z"}}}}]}`` (N).

The exchange is the same as Isaac Lab's: every state message is answered by one command.

:class:`DeviceServer` (``frhc device serve``) serves a simulated device over this protocol, with
one extension that a real Inverse Service neither sends nor needs: a top-level ``"frhc_sim"``
object. In the state it names the device and its period (``{"device", "period", "time"}``); in a
command it carries the simulated operator's hand target (``{"hand_target": 16 numbers, row-major
4x4 in {0}, or null}``), so that scripted sessions drive a served device as they drive one in
process. A hand target that is not a rigid pose (:func:`~app.spatial.pose_error`) is a bad command
like any other: the connection is closed (1003, naming the field), the force zeroed, and the hand
holds the last target it accepted. A served simulation is **synchronous**: it advances one period per command, so a loop
over loopback reproduces the in-process run. With no command for ``watchdog`` seconds, or as soon
as the connection closes, it sets the commanded force to zero (and with a client connected but
silent, it runs on in real time under zero force).

:class:`HaplyClient` is a :class:`~app.device.boundary.CartesianDevice` talking to either: a real
Inverse Service (Inverse3 + VerseGrip) or ``frhc device serve``. Frames: positions and forces are
taken in the device base {0} as the service reports them (for a real Inverse3, its own base axes:
check them against ``docs/conventions.md`` before the first contact).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import math
import os
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import msgspec
import numpy as np
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from app.device.boundary import CartesianReading, LinkStatus
from app.device.cartesian_sim import SimCartesianDevice
from app.device.guard import limited
from app.device.plant import WATCHDOG
from app.device.spec import DeviceSpec, load_device
from app.device.vendors import check_device_url, vendor_device
from app.device.wslink import WsLink
from app.errors import FrhcError
from app.listen import listening_socket
from app.spatial import Array, matrix_to_quat, pose_error, quat_to_matrix

log = logging.getLogger(__name__)

#: Haply's Inverse Service default address.
DEFAULT_URL = "ws://localhost:10001"
#: How long a connect (handshake and first state) may take before it counts as failed (s).
CONNECT_TIMEOUT = 1.0
#: Time between reconnection attempts while disconnected (s).
RETRY_INTERVAL = 0.1
#: The most a real-time client polls for a state before blocking (s). Polling (yielding to its
#: equals) halved the median round trip against a served device at the same priority (``frhc
#: bench device``: a blocked thread's wake-up, and an idle virtual CPU's, cost ~250 us on the
#: 2-CPU VM); bounded because at real-time priority it keeps a device server at ordinary
#: priority off this CPU meanwhile. 0.3 ms covers the median reply.
REALTIME_SPIN = 300e-6
#: The most simulated time (s) a silent served device catches up at once, after its thread was
#: held up (a loaded machine): the rest of the gap is skipped, not run in a burst.
RUN_ON_CATCH_UP = 0.1
#: How often the server's accept loop looks whether it was shut down (s).
ACCEPT_POLL = 0.1


def realtime_thread() -> bool:
    """Whether the calling thread runs under real-time scheduling (``SCHED_FIFO`` or ``SCHED_RR``)."""
    try:
        return os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR)
    except (OSError, AttributeError):
        return False


class DeviceUnreachable(FrhcError):
    """No device answered at a ``--device ws://...`` address."""


# The messages are written from templates and read with msgspec's JSON decoder: per message a
# few microseconds instead of the ~20 us of building dicts for json.dumps and of json.loads
# (measured on touch3's state: ``frhc bench device``'s notes, issue 29). Floats are written as
# ``repr`` writes them, as json.dumps does.
_STATE = (
    '{"inverse3":[{"device_id":%s,"state":{"cursor_position":{"x":%r,"y":%r,"z":%r}}}],'
    '"wireless_verse_grip":[{"device_id":%s,"state":{"orientation":{"x":%r,"y":%r,"z":%r,"w":%r},'
    '"buttons":{"a":%s,"b":%s,"c":%s}}}]'
)
_COMMAND = '{"inverse3":[{"device_id":%s,"commands":{"set_cursor_force":{"values":{"x":%r,"y":%r,"z":%r}}}}]'
_encode = msgspec.json.Encoder().encode


@functools.lru_cache(maxsize=16)
def _quoted(text: str) -> str:
    """``text`` as a JSON string (a device's id: the same few every message)."""
    return json.dumps(text)


def _bool(value: bool) -> str:
    return "true" if value else "false"


def state_message(device_id: str, T_0_G: Array, buttons: tuple[bool, bool, bool], sim: dict[str, Any] | None) -> str:
    """A state message: the grip position (m) and orientation in {0}, and the buttons (a, b, c)."""
    w, x, y, z = matrix_to_quat(T_0_G[:3, :3]).tolist()
    px, py, pz = T_0_G[:3, 3].tolist()
    a, b, c = buttons
    grip = _quoted(f"{device_id}-grip")
    text = _STATE % (_quoted(device_id), px, py, pz, grip, x, y, z, w, _bool(a), _bool(b), _bool(c))
    if sim is not None:
        text += ',"frhc_sim":' + _encode(sim).decode()
    return text + "}"


def force_command(device_id: str, force: Array, hand_target: Array | None, sim: bool) -> str:
    """A command message setting the cursor force (N, {0}); with ``sim``, the hand target too."""
    fx, fy, fz = force[:3].tolist()
    text = _COMMAND % (_quoted(device_id), fx, fy, fz)
    if sim:
        target = "null" if hand_target is None else _encode(hand_target.ravel().tolist()).decode()
        text += ',"frhc_sim":{"hand_target":' + target + "}"
    return text + "}"


class _Xyz(msgspec.Struct):
    x: float
    y: float
    z: float


class _Quaternion(msgspec.Struct):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class _Buttons(msgspec.Struct):
    a: bool = False
    b: bool = False
    c: bool = False


class _GripState(msgspec.Struct):
    orientation: _Quaternion | None = None
    buttons: _Buttons = msgspec.field(default_factory=_Buttons)


class _Grip(msgspec.Struct):
    state: _GripState = msgspec.field(default_factory=_GripState)


class _Inverse3State(msgspec.Struct):
    cursor_position: _Xyz


class _Inverse3(msgspec.Struct):
    device_id: str | int
    state: _Inverse3State


class SimInfo(msgspec.Struct):
    """What ``frhc device serve`` says of itself in each state (``"frhc_sim"``): the device file's
    name, the simulation's period (s), its time (s) and the simulated hand's wrench on the grip
    (N, N m, {0})."""

    device: str
    period: float = 0.0
    time: float | None = None
    hand_wrench: Annotated[list[float], msgspec.Meta(min_length=6, max_length=6)] | None = None


class _State(msgspec.Struct):
    inverse3: Annotated[list[_Inverse3], msgspec.Meta(min_length=1)]
    wireless_verse_grip: list[_Grip] = msgspec.field(default_factory=list)
    frhc_sim: SimInfo | None = None


class _SetForce(msgspec.Struct):
    values: _Xyz


class _Commands(msgspec.Struct):
    set_cursor_force: _SetForce


class _Inverse3Command(msgspec.Struct):
    commands: _Commands


class _SimCommand(msgspec.Struct):
    hand_target: Annotated[list[float], msgspec.Meta(min_length=16, max_length=16)] | None = None


class _Command(msgspec.Struct):
    inverse3: Annotated[list[_Inverse3Command], msgspec.Meta(min_length=1)]
    frhc_sim: _SimCommand | None = None


# Typed decoders: a field of the wrong type (a string or a boolean for a number, a number for a
# button), a missing one or a number JSON cannot hold as a double is refused, naming its path, so
# what reaches the controller is finite and of the kind the protocol says.
_decode_state = msgspec.json.Decoder(_State).decode
_decode_command = msgspec.json.Decoder(_Command).decode


@dataclass
class ParsedState:
    """What a state message said. Position in m, orientation as a rotation matrix, both in {0}."""

    device_id: str
    position: Array
    R: Array
    buttons: tuple[bool, bool, bool] | None
    sim: SimInfo | None = None


def parse_state(text: str | bytes) -> ParsedState:
    """Read a state message; raises ValueError naming the field that is missing or wrong."""
    try:
        data = _decode_state(text)
    except msgspec.DecodeError as exc:
        raise ValueError(f"bad state message ({exc})") from None
    inv = data.inverse3[0]
    p = inv.state.cursor_position
    R = np.eye(3)
    buttons = None
    if data.wireless_verse_grip:
        state = data.wireless_verse_grip[0].state
        o = state.orientation
        if o is not None:
            q = np.array([o.w, o.x, o.y, o.z])
            norm = float(np.linalg.norm(q))
            if not norm > 1e-9:  # nothing to normalise: no rotation is meant
                raise ValueError("bad state message (zero orientation quaternion - at `$.wireless_verse_grip[0]`)")
            R = quat_to_matrix(q / norm)
        b = state.buttons
        buttons = (b.a, b.b, b.c)
    return ParsedState(str(inv.device_id), np.array([p.x, p.y, p.z]), R, buttons, data.frhc_sim)


def parse_command(text: str | bytes) -> tuple[Array, Array | None, bool]:
    """Read a command: the force (N, (3,)), the simulated hand target ((4, 4) or None) and
    whether the message carried the ``frhc_sim`` extension. Raises ValueError naming the field,
    for a hand target too that is not a rigid pose (:func:`~app.spatial.pose_error`, the check
    of the slave's pose commands): a scaled, sheared or mirrored one would be pulled toward."""
    try:
        data = _decode_command(text)
    except msgspec.DecodeError as exc:
        raise ValueError(f"bad command ({exc})") from None
    v = data.inverse3[0].commands.set_cursor_force.values
    sim = data.frhc_sim
    target = None
    if sim is not None and sim.hand_target is not None:
        target = np.array(sim.hand_target, dtype=float).reshape(4, 4)
        why = pose_error(target, "$.frhc_sim.hand_target")
        if why is not None:
            raise ValueError(why)
    return np.array([v.x, v.y, v.z]), target, sim is not None


def served_device(url: str, session_device: DeviceSpec | None) -> DeviceSpec:
    """The device file for the device at ``url``: for ``frhc device serve``, the served
    simulation's own (it names it); otherwise (a real Inverse Service, ``fd:``, ``openhaptics:``)
    ``session_device`` if it is a Cartesian device (``interface = "cartesian"``), else the vendor's
    shipped file (:func:`~app.device.vendors.vendor_device`: ``inverse3``, ``omega3``, ``touch3``).
    A joint-space device's ``[cartesian]`` table (kraft's 15 N, for serving it) is not taken for
    another device's limits.

    Raises:
        InputError: ``url`` is not a well-formed device address.
        DeviceUnreachable: nothing usable answers at a ``ws://`` address.
    """
    check_device_url(url)
    if url.startswith(("ws://", "wss://")):
        client = HaplyClient(url, period=CONNECT_TIMEOUT)
        served = client.served
        client.disconnect()  # it sent no force: nothing to zero, and a served simulation stays put
        if served is not None:
            return load_device(served.device)
    if session_device is not None and session_device.data.interface == "cartesian":
        spec = session_device
    else:
        spec = load_device(vendor_device(url))
    log.info("device %s: limits and gains from %s", url, spec.path)
    return spec


class HaplyClient:
    """A Cartesian device reached over the Inverse Service protocol (a real one, or ``frhc device serve``).

    Args:
        url: ``ws://host:port``.
        period: The servo period (s): a state not received within it is a missed sample (the
            guard then sends zero).
        spin: How long (s) each wait for a state polls the socket before blocking
            (:meth:`WsLink.recv <app.device.wslink.WsLink.recv>`; a real-time thread yields to
            its equals at each poll); None: the whole wait when the calling thread runs at
            ordinary scheduling, at most :data:`REALTIME_SPIN` under real-time scheduling. A
            device server in the same Python process needs the GIL that polling holds (for up
            to the interpreter's 5 ms switch interval): give such a client 0.

    Attributes:
        device_id: The Inverse3's id, as the service named it.
        served: What ``frhc device serve`` said of itself (:class:`SimInfo`), or None for a real
            Inverse Service.
        why: Why the last connect failed (one line), or "".
    """

    kind: Literal["cartesian"] = "cartesian"
    #: The Inverse3 renders forces only.
    torque_capable = False

    def __init__(self, url: str, period: float, spin: float | None = None) -> None:
        self.url = url
        self.period = period
        self.spin = spin
        self.reading = CartesianReading()
        self.name = url
        self.device_id = ""
        self.served: SimInfo | None = None
        self.why = ""
        self._ws: WsLink | None = None
        self._hand: Array | None = None
        self._last_attempt = -math.inf
        self._bad_states = 0  # bad state messages in a row (logged when the run starts and ends)
        #: Whether the last connect was refused with 1013 ("try again later": another client holds
        #: the device, perhaps one whose close the server has not yet seen).
        self._try_again = False
        busy_until = time.monotonic() + CONNECT_TIMEOUT
        while not self.connect(say=False):  # a failure here is said by the error raised
            if self._try_again and time.monotonic() < busy_until:
                time.sleep(RETRY_INTERVAL)
                continue
            raise DeviceUnreachable(
                f"no usable Inverse Service at {url}: {self.why} (is `frhc device serve` or Haply's service running?)"
            )

    def connect(self, say: bool = True) -> bool:
        """(Re)connect and read the first state; False (status DISCONNECTED) if it failed, which
        is logged (at INFO, as ``frhc run --device`` prints the link's changes) if ``say``.

        The first connect, in the constructor, is tried again every :data:`RETRY_INTERVAL` for
        up to :data:`CONNECT_TIMEOUT` while the service refuses with 1013 ("try again later"):
        ``frhc device serve`` serves one client at a time, and a client that has just closed
        (:func:`served_device`'s look at the served device, before a run opens its own) still
        holds it until the server's thread has seen the close, which a loaded machine delays.
        """
        self._last_attempt = time.monotonic()
        self._try_again = False
        self._drop()
        try:
            ws = WsLink.connect(self.url, CONNECT_TIMEOUT)
        except (OSError, TimeoutError, InvalidHandshake, InvalidURI, ValueError) as exc:
            self.why = f"cannot connect ({exc})"
            if say:
                log.info("device %s: %s", self.url, self.why)
            return False
        try:
            first = parse_state(ws.recv(CONNECT_TIMEOUT))
        except (TimeoutError, ConnectionClosed, ValueError) as exc:
            self._try_again = isinstance(exc, ConnectionClosed) and exc.rcvd is not None and exc.rcvd.code == 1013
            self.why = f"no usable first state ({exc})"
            if say:
                log.info("device %s: %s", self.url, self.why)
            ws.close()
            return False
        self.why = ""
        self._ws = ws
        self.device_id = first.device_id
        self.served = first.sim
        self.name = f"{first.sim.device} at {self.url}" if first.sim else f"Inverse3 {first.device_id}"
        self._take(first)
        return True

    def disconnect(self) -> None:
        """Close the connection without a last command (:meth:`close` sends zero force first)."""
        self._drop()

    def _drop(self) -> None:
        if self._ws is not None:
            self._ws.close()
            self._ws = None
        r = self.reading
        r.fresh = False
        r.status = LinkStatus.DISCONNECTED

    def _take(self, state: ParsedState) -> None:
        r = self.reading
        r.set_pose(state.R, state.position)
        r.buttons = state.buttons
        sim = state.sim
        if sim is not None:
            if sim.time is not None:
                r.time = sim.time
            if sim.hand_wrench is not None:
                r.wrench_G[:] = sim.hand_wrench
        r.fresh = True
        if r.status == LinkStatus.DISCONNECTED:
            r.status = LinkStatus.RAMPING

    def reset(self) -> CartesianReading:
        """Reconnect if the connection is down; the device stays where it is (a served simulation
        is not sent home: it is a device like any other). The loop's guard zeroes the force."""
        if self._ws is None:
            self.connect()
        return self.reading

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """Sent to a served simulation with the next command; a real device ignores it."""
        if T_0_H is None:
            self._hand = None
        else:
            if self._hand is None:
                self._hand = np.eye(4)
            self._hand[:] = T_0_H

    def step(self, wrench_0: Array, dt: float) -> CartesianReading:
        """Send the force ``wrench_0[:3]`` (N, {0}; moments are not sent to an Inverse3) and wait
        up to one period for the next state."""
        r = self.reading
        ws = self._ws
        if ws is None:
            if time.monotonic() - self._last_attempt >= RETRY_INTERVAL:
                self.connect()
            else:
                r.fresh = False
            return r
        try:
            ws.send(force_command(self.device_id, wrench_0[:3], self._hand, self.served is not None))
            realtime = realtime_thread()
            spin = self.spin
            if spin is None:
                spin = min(REALTIME_SPIN, self.period) if realtime else self.period
            state = parse_state(ws.recv_latest(self.period, spin, yield_cpu=realtime))
        except TimeoutError:
            r.fresh = False
        except (ConnectionClosed, OSError) as exc:
            log.info("device %s: connection lost (%s)", self.url, exc)
            self._drop()
        except ValueError as exc:
            # A missed sample (the guard sends zero): said once per run of bad messages, not
            # once a period.
            if self._bad_states == 0:
                log.warning("device %s: %s; zero force until a good one", self.url, exc)
            self._bad_states += 1
            r.fresh = False
        else:
            if self._bad_states:
                log.warning("device %s: good state again after %d bad", self.url, self._bad_states)
                self._bad_states = 0
            self._take(state)
        return r

    def close(self) -> None:
        """Send zero force, then close the connection."""
        if self._ws is not None:
            with contextlib.suppress(ConnectionClosed, OSError):
                self._ws.send(force_command(self.device_id, np.zeros(3), self._hand, self.served is not None))
        self._drop()


@dataclass
class ServerEvent:
    """Something the server did to the force: ``reason`` is "disconnect" or "watchdog";
    ``at`` its time on ``time.perf_counter`` (s)."""

    reason: str
    at: float


@dataclass
class ServerLog:
    """What :class:`DeviceServer` did, for tests and the benchmark (times on ``time.perf_counter``).

    Attributes:
        commanded: The force the device renders now (N, {0}), (3,).
        events: Every zeroing of the force, in order.
        commands: Commands received.
        connections: Clients accepted.
    """

    commanded: Array = field(default_factory=lambda: np.zeros(3))
    events: list[ServerEvent] = field(default_factory=list)
    commands: int = 0
    connections: int = 0


class DeviceServer:
    """Serve a simulated device over the Inverse Service protocol (``frhc device serve``).

    Args:
        device: The simulated device (:class:`SimCartesianDevice`).
        host, port: Where to listen (port 0: any free port; see :attr:`port`).
        period: The simulation's period (s).
        watchdog: Silence (s) after which the force is zeroed and the device runs on without it.

    One client controls the device at a time; a second connection is closed with code 1013.

    Raises:
        ListenError: ``host:port`` cannot be listened on (a busy port is refused, not swapped).
    """

    def __init__(
        self,
        device: SimCartesianDevice,
        host: str = "127.0.0.1",
        port: int = 10001,
        period: float = 1e-3,
        watchdog: float = WATCHDOG,
    ) -> None:
        self.device = device
        self.period = period
        self.watchdog = watchdog
        self.log = ServerLog()
        spec = device.spec.data.cartesian
        assert spec is not None  # SimCartesianDevice refuses a device without the table
        self._force_limit = spec.force_limit
        self._busy = threading.Lock()
        self._paused = threading.Event()
        #: Set whenever the force is zeroed (tests wait on it).
        self.zeroed = threading.Event()
        self._conn: WsLink | None = None
        self._listener = listening_socket(host, port)
        self._listener.settimeout(ACCEPT_POLL)
        self.port: int = self._listener.getsockname()[1]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> DeviceServer:
        """Serve in a background thread (for tests and benchmarks); returns self."""
        self._thread = threading.Thread(target=self.serve_forever, name="device-serve", daemon=True)
        self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Accept clients in this thread until :meth:`shutdown` (or Ctrl-C); each is served in a
        thread of its own, which reads its socket itself (:mod:`app.device.wslink`)."""
        try:
            while not self._stop.is_set():
                try:
                    sock, _ = self._listener.accept()
                except TimeoutError:
                    continue
                threading.Thread(target=self._connection, args=(sock,), name="device-client", daemon=True).start()
        finally:
            self._listener.close()

    def shutdown(self) -> None:
        """Stop accepting, drop the client (its force is zeroed) and wait for the accept loop."""
        self._stop.set()
        self.drop_client()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def drop_client(self) -> None:
        """Close the controlling client's connection without a close frame, as a pulled cable would."""
        conn = self._conn
        if conn is not None:
            conn.abort()

    def pause_stream(self, paused: bool) -> None:
        """Stop (or resume) answering commands, as a stalled device stream would (tests)."""
        if paused:
            self._paused.set()
        else:
            self._paused.clear()

    def _state(self) -> str:
        r = self.device.reading
        sim = {
            "device": self.device.name,
            "period": self.period,
            "time": r.time,
            "hand_wrench": r.wrench_G.tolist(),
        }
        return state_message(f"sim-{self.device.name}", r.T_0_G, (False, False, False), sim)

    def _zero(self, reason: str) -> None:
        if np.any(self.log.commanded):
            self.log.commanded[:] = 0.0
            self.log.events.append(ServerEvent(reason, time.perf_counter()))
            log.info("device %s: force zeroed (%s)", self.device.name, reason)
        self.zeroed.set()

    def _connection(self, sock: socket.socket) -> None:
        try:
            ws = WsLink.accept(sock, CONNECT_TIMEOUT)
        except (OSError, TimeoutError, InvalidHandshake) as exc:
            log.info("device %s: no WebSocket handshake (%s)", self.device.name, exc)
            return
        self._handle(ws)

    def _handle(self, ws: WsLink) -> None:
        if not self._busy.acquire(blocking=False):
            ws.close(1013, "another client controls the device")
            return
        try:
            self._conn = ws
            self.log.connections += 1
            log.info("device %s: client connected from %s", self.device.name, ws.remote_address)
            wrench = np.zeros(6)
            ws.send(self._state())
            # Wall-clock time (s, monotonic) of the last command, and how far the silent device has
            # run on since the watchdog tripped (None before). A receive that times out returns a
            # period or more later (much more on a loaded machine): counting timeouts would zero the
            # force late and run the device on slower than real time.
            heard = time.monotonic()
            ran: float | None = None
            while True:
                try:
                    text = ws.recv(self.period)
                except TimeoutError:
                    now = time.monotonic()
                    if now - heard >= self.watchdog:
                        self._zero("watchdog")
                        wrench[:] = 0.0
                        if ran is None:
                            ran = heard + self.watchdog
                        periods = int((now - ran) / self.period)
                        for _ in range(min(periods, round(RUN_ON_CATCH_UP / self.period))):
                            self.device.step(wrench, self.period)
                        ran += periods * self.period
                    continue
                if self._paused.is_set():
                    continue
                force, target, _ = parse_command(text)
                heard, ran = time.monotonic(), None
                self.log.commands += 1
                self.device.set_hand_target(target)
                # The device's own limit, whatever the client sent (as a vendor's firmware does).
                limited(force, self._force_limit, 1.0, self.log.commanded)
                wrench[:3] = self.log.commanded
                self.device.step(wrench, self.period)
                ws.send(self._state())
        except ConnectionClosed:
            pass
        except ValueError as exc:
            ws.close(1003, str(exc)[:120])
        finally:
            self._conn = None
            self._zero("disconnect")
            self._busy.release()
