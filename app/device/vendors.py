"""Real Cartesian devices through their vendors' Python bindings (optional extras).

- **Force Dimension** (omega, delta, sigma, lambda; Novint Falcon through the same SDK) via
  ``forcedimension-core`` (``pip install 'frhc[fd]'``), ctypes bindings of the Force Dimension
  SDK's ``libdhd``: ``dhd.openID(index)``, ``dhd.getSystemName``, ``dhd.hasActiveWrist``,
  ``dhd.enableForce``, ``dhd.getPosition(out)`` (m), ``dhd.getOrientationFrame(out)`` (3x3),
  ``dhd.getButton(index)`` (1 pressed, 0 not, -1 error), ``dhd.setForceAndTorque(f, t)`` (N, N m),
  ``dhd.close``, each with an ``ID`` keyword; all return -1 on error. Names and signatures as in
  ``forcedimension_core/dhd/__init__.py`` of forcedimension-core 1.0.0
  (github.com/EmDash00/forcedimension_core-python, a9e6784); its ``runtime`` module raises
  ImportError at import when libdhd is absent. The SDK's frame is the device base with z up; it
  is taken as {0} as it is.
- **3D Systems Touch** (and other OpenHaptics devices) via ``pyOpenHaptics``
  (``pip install 'frhc[openhaptics]'``), ctypes bindings of OpenHaptics' ``libHD``:
  ``hd.init_device`` (None when it fails), ``hd.enable_force``, ``hd.start_scheduler``,
  ``hd_callback.hd_callback`` (runs a function inside ``hd.begin_frame``/``hd.end_frame``),
  ``hd_callback.hdAsyncSheduler`` (sic; schedules it every servo tick), ``hd.get_transform``
  (HD_CURRENT_TRANSFORM: a ctypes 4x4 of doubles, column-major, translation in row 3, mm),
  ``hd.get_buttons`` (HD_CURRENT_BUTTONS bits), ``hd.set_force`` (HD_CURRENT_FORCE, N),
  ``hd.stop_scheduler``, ``hd.close_device``: ``pyOpenHaptics/hd.py`` and ``hd_callback.py`` of
  pyOpenHaptics 1.0.1 (github.com/mikelitu/pyOpenHaptics, 3eafad1), which load ``libHD.so``
  with ctypes at import (OSError when absent). OpenHaptics' frame has y up and z toward the user;
  {0} has z up: ``p_0 = (x, -z, y)``, and forces map back the same way.

Each refuses in one line, naming what is missing, when the Python package or its native library
is absent (:class:`DeviceUnavailable`); nothing here pretends a device is attached. Buttons:
button 0 (FD) / button 1 (Touch) is the deadman, the next one the reference switch, a third (FD)
toggles reflection (``docs/conventions.md``, "Devices"); the gravity compensation is the SDK's.

The devices are selected with ``--device fd:`` (``fd:N`` for the N-th device) or
``--device openhaptics:`` (``openhaptics:NAME`` for a named device); the session's device file
gives the ``[cartesian]`` limits if it has that table, else the vendor's shipped one
(:func:`vendor_device`: ``omega3``, ``touch3``).
"""

from __future__ import annotations

import importlib
import threading
from types import ModuleType
from typing import Any, Literal
from urllib.parse import urlsplit

import numpy as np
from websockets.exceptions import InvalidURI
from websockets.uri import parse_uri

from app.device.boundary import CartesianDevice, CartesianReading, LinkStatus
from app.errors import FrhcError, InputError
from app.spatial import Array

#: OpenHaptics' axes in {0}: column i is OpenHaptics' axis i (x right, y up, z toward the user)
#: in {0} (x right, y away from the user, z up).
C_0_HD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: OpenHaptics' lengths are millimetres.
MM = 1e-3
#: Bits of HD_CURRENT_BUTTONS (HD_DEVICE_BUTTON_1, _2).
HD_BUTTON_1, HD_BUTTON_2 = 1, 2
#: How long (s) to wait for OpenHaptics' scheduler's first frame (and for the last, on closing).
FIRST_FRAME_TIMEOUT = 1.0


class DeviceUnavailable(FrhcError):
    """A vendor backend's package, native library or device is not here."""


def _load(module: str, package: str, extra: str, native: str) -> ModuleType:
    """Import a vendor binding, or refuse in one line naming what is missing."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError:
        raise DeviceUnavailable(
            f"{package} is not installed (pip install 'frhc[{extra}]'), and it needs {native}"
        ) from None
    except (ImportError, OSError) as exc:  # the bindings load the native library at import
        raise DeviceUnavailable(f"{package} cannot load {native}: {exc}") from None


class ForceDimensionDevice:
    """A Force Dimension device through ``forcedimension_core.dhd``.

    Args:
        index: Which device (0: the first); its dhd id is what ``dhd.openID`` returns.
    """

    kind: Literal["cartesian"] = "cartesian"

    def __init__(self, index: int = 0) -> None:
        self.dhd: Any = _load(
            "forcedimension_core.dhd", "forcedimension-core", "fd", "the Force Dimension SDK's libdhd"
        )
        dhd = self.dhd
        self.id = dhd.openID(index)
        if self.id < 0:
            raise DeviceUnavailable(f"Force Dimension: no device {index} ({dhd.errorGetLastStr()})")
        self.name = f"Force Dimension {dhd.getSystemName(ID=self.id)}"
        self.torque_capable = bool(dhd.hasActiveWrist(ID=self.id))
        dhd.enableForce(True, ID=self.id)
        self.reading = CartesianReading()
        self._pos = [0.0, 0.0, 0.0]
        self._R = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        self.step(np.zeros(6), 0.0)

    def reset(self) -> CartesianReading:
        return self.step(np.zeros(6), 0.0)

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """A real hand holds a real device: nothing to do."""

    def step(self, wrench_0: Array, dt: float) -> CartesianReading:
        """Set the force (and moment, with an active wrist) in N and N m, then read the pose."""
        dhd, ID, r = self.dhd, self.id, self.reading
        torque = wrench_0[3:6] if self.torque_capable else (0.0, 0.0, 0.0)
        ok = dhd.setForceAndTorque(list(wrench_0[0:3]), list(torque), ID=ID) >= 0
        ok = ok and dhd.getPosition(out=self._pos, ID=ID) >= 0
        ok = ok and dhd.getOrientationFrame(out=self._R, ID=ID) >= 0
        if not ok:
            r.fresh = False
            r.status = LinkStatus.DISCONNECTED
            return r
        r.set_pose(np.array(self._R, dtype=float), np.array(self._pos, dtype=float))
        # getButton is -1 on an error: only 1 is a press (an error must not hold the deadman).
        r.buttons = tuple(dhd.getButton(i, ID=ID) == 1 for i in range(3))
        r.fresh = True
        if r.status == LinkStatus.DISCONNECTED:
            r.status = LinkStatus.RAMPING
        return r

    def close(self) -> None:
        self.dhd.setForceAndTorque([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], ID=self.id)
        self.dhd.close(ID=self.id)


class TouchDevice:
    """A 3D Systems Touch (or another OpenHaptics device) through ``pyOpenHaptics``.

    OpenHaptics reads and sets a device's state only inside a haptic frame run by its own servo
    scheduler thread (the HDAPI programmer's guide; pyOpenHaptics' ``hd_callback`` opens and closes
    the frame around a callback). So the frame is not run from the servo loop: an asynchronous
    scheduler callback renders the last force the loop sent and takes a sample; :meth:`step`
    hands it the new force and waits up to ``period`` for the sample of a frame that rendered it.

    Args:
        name: The OpenHaptics device name ("Default Device").
        period: How long (s) :meth:`step` waits for the scheduler's next frame before the sample
            counts as missed (the guard then zeroes the force).
    """

    kind: Literal["cartesian"] = "cartesian"
    #: The Touch renders forces only (its gimbal is sensed, not actuated).
    torque_capable = False

    def __init__(self, name: str = "Default Device", period: float = 1e-3) -> None:
        what = ("pyOpenHaptics", "openhaptics", "OpenHaptics' libHD")
        self.hd: Any = _load("pyOpenHaptics.hd", *what)
        scheduling: Any = _load("pyOpenHaptics.hd_callback", *what)
        hd = self.hd
        self.handle = hd.init_device(name)
        if self.handle is None:
            raise DeviceUnavailable(f"OpenHaptics: cannot initialise device {name!r}")
        self.name = f"OpenHaptics {hd.get_model()}"
        self.period = period
        self.reading = CartesianReading()
        self._frames = threading.Condition()
        # Shared with the scheduler's thread, under _frames: the force it renders (N, HD axes),
        # its last sample (HD_CURRENT_TRANSFORM row-major, mm; HD_CURRENT_BUTTONS) and a count.
        self._force_hd = [0.0, 0.0, 0.0]
        self._T_hd = np.eye(4)
        self._buttons = 0
        self._frame_count = 0
        self._taken = 0
        # The ctypes callback must outlive the scheduler: kept here.
        self._callback = scheduling.hd_callback(self._frame)
        hd.enable_force()
        hd.start_scheduler()
        scheduling.hdAsyncSheduler(self._callback)
        if not self._next_frame(FIRST_FRAME_TIMEOUT):
            self._stop()
            raise DeviceUnavailable(f"OpenHaptics: no servo frame from {name!r} within {FIRST_FRAME_TIMEOUT:g} s")

    def _frame(self) -> None:
        """One haptic frame, in OpenHaptics' scheduler thread (the frame is open around it)."""
        hd = self.hd
        T = np.array(hd.get_transform(), dtype=float).reshape(4, 4).T  # column-major -> row-major
        buttons = int(hd.get_buttons())
        with self._frames:
            hd.set_force(self._force_hd)
            self._T_hd[:] = T
            self._buttons = buttons
            self._frame_count += 1
            self._frames.notify()

    def _next_frame(self, timeout: float) -> bool:
        """Wait (holding nothing on return) for a frame after the last one taken; take its sample
        into :attr:`reading`. False if none came within ``timeout`` s."""
        r = self.reading
        with self._frames:
            if not self._frames.wait_for(lambda: self._frame_count > self._taken, timeout):
                r.fresh = False
                return False
            self._taken = self._frame_count
            T = self._T_hd.copy()
            buttons = self._buttons
        r.set_pose(C_0_HD @ T[:3, :3] @ C_0_HD.T, C_0_HD @ T[:3, 3] * MM)
        r.buttons = (bool(buttons & HD_BUTTON_1), bool(buttons & HD_BUTTON_2), False)
        r.fresh = True
        if r.status == LinkStatus.DISCONNECTED:
            r.status = LinkStatus.RAMPING
        return True

    def reset(self) -> CartesianReading:
        return self.step(np.zeros(6), 0.0)

    def set_hand_target(self, T_0_H: Array | None) -> None:
        """A real hand holds a real device: nothing to do."""

    def step(self, wrench_0: Array, dt: float) -> CartesianReading:
        """Hand the force (N, {0}; moments dropped) to the scheduler in OpenHaptics' axes and wait
        up to one period for a frame that rendered it."""
        force_hd = [float(v) for v in C_0_HD.T @ wrench_0[0:3]]
        with self._frames:
            self._force_hd = force_hd
        self._next_frame(self.period)
        return self.reading

    def close(self) -> None:
        """Zero the force, wait for a frame to render it, stop the scheduler and the device."""
        with self._frames:
            self._force_hd = [0.0, 0.0, 0.0]
        self._next_frame(FIRST_FRAME_TIMEOUT)
        self._stop()

    def _stop(self) -> None:
        self.hd.stop_scheduler()
        self.hd.close_device(self.handle)


#: The ``--device`` prefixes of devices that are not simulated here, each with the shipped device
#: file that gives such a device its ``[cartesian]`` limits and gains when the session names no
#: Cartesian device: a Haply Inverse3 behind a ``ws://`` Inverse Service, a Force Dimension
#: omega.3 for ``fd:``, a Touch for ``openhaptics:`` (``devices/README.md``).
VENDOR_DEVICES = {"ws://": "inverse3", "wss://": "inverse3", "fd:": "omega3", "openhaptics:": "touch3"}
URL_PREFIXES = tuple(VENDOR_DEVICES)


def vendor_device(url: str) -> str:
    """The shipped device file (a name) for the device at ``url`` (:data:`VENDOR_DEVICES`).

    Raises:
        InputError: ``url`` is not a device address.
    """
    for prefix, name in VENDOR_DEVICES.items():
        if url.startswith(prefix):
            return name
    raise InputError(f"not a device address: {url!r} (ws://host:port, fd:N, openhaptics:NAME)")


def check_device_url(url: str) -> str:
    """``url`` if it is a well-formed device address (:func:`open_device_url`), else a one-line
    :class:`InputError` naming what is wrong; nothing is opened or resolved.

    Raises:
        InputError: not a device address, a ``ws://`` address without a host or with a port
            outside 1-65535, or ``fd:`` with something other than a device number.
    """
    vendor_device(url)  # one of the address kinds, else "not a device address"
    if url.startswith(("ws://", "wss://")):
        try:
            parse_uri(url)
            port = urlsplit(url).port  # websockets takes an explicit port 0 for the default
        except (InvalidURI, ValueError) as exc:
            raise InputError(f"bad device address {url!r}: {exc}") from None
        if port == 0:
            raise InputError(f"bad device address {url!r}: port 0 (ports are 1-65535)")
    elif url.startswith("fd:") and not (url[3:] or "0").isdigit():
        raise InputError(f"fd:N needs a device number, got {url!r}")
    return url


def is_device_url(name: str) -> bool:
    """Whether a ``--device`` value names a device outside this process (``ws://``, ``fd:``,
    ``openhaptics:``) rather than a device file."""
    return name.startswith(URL_PREFIXES)


def open_device_url(url: str, period: float) -> CartesianDevice:
    """The Cartesian device behind ``url``: a served one (``ws://host:port``, whose samples are
    waited for up to ``period`` s), a Force Dimension device (``fd:`` or ``fd:N``) or an
    OpenHaptics device (``openhaptics:`` or ``openhaptics:NAME``).

    Raises:
        DeviceUnavailable: its runtime or the device is not here (one line naming which).
        InputError: ``url`` is none of these.
    """
    check_device_url(url)
    if url.startswith(("ws://", "wss://")):
        from app.device.haply import HaplyClient

        return HaplyClient(url, period)
    if url.startswith("fd:"):
        return ForceDimensionDevice(int(url[3:] or "0"))
    return TouchDevice(url[len("openhaptics:") :] or "Default Device", period)
