"""The Force Dimension and OpenHaptics adapters, against stand-ins of their Python modules.

The stand-ins are for hardware that cannot be here: ``forcedimension_core.dhd`` and
``pyOpenHaptics.hd`` are ctypes bindings of native SDKs (libdhd, libHD) that talk to a device on
USB. Each stand-in records every call and answers as the SDK documents (units, frames, return
codes), so these tests check what the adapters send and how they read: units (m, mm, N), frames
(OpenHaptics' y-up axes), force signs, the boundary's force limit and the button mapping. The
OpenHaptics stand-in runs its scheduled callback in a thread every millisecond, as OpenHaptics'
servo scheduler does, each call inside begin_frame/end_frame as ``pyOpenHaptics.hd_callback``
wraps it.
"""

from __future__ import annotations

import ctypes
import sys
import threading
import time
import types
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

from app.controller.types import Switches
from app.device.boundary import LinkStatus
from app.device.guard import ForceGuard
from app.device.spec import CartesianSpec
from app.device.vendors import DeviceUnavailable, ForceDimensionDevice, TouchDevice, open_device_url
from app.errors import InputError


class FakeDhd:
    """Stand-in for ``forcedimension_core.dhd`` (an omega.3: no active wrist, 1 button pressed)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []
        self.position = [0.01, -0.02, 0.03]  # m
        self.frame = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
        self.buttons = [1, 0, 0]  # dhd.getButton: 1 pressed, 0 not, -1 an error
        self.fail = False

    def openID(self, index: int) -> int:
        self.calls.append(("openID", index))
        return 3

    def errorGetLastStr(self) -> str:
        return "no device"

    def getSystemName(self, ID: int = -1) -> str:
        return "omega.3"

    def hasActiveWrist(self, ID: int = -1) -> bool:
        return False

    def enableForce(self, enable: bool, ID: int = -1) -> int:
        self.calls.append(("enableForce", (enable, ID)))
        return 0

    def setForceAndTorque(self, f: list[float], t: list[float], ID: int = -1) -> int:
        self.calls.append(("setForceAndTorque", (list(f), list(t), ID)))
        return -1 if self.fail else 0

    def getPosition(self, out: list[float], ID: int = -1) -> int:
        out[:] = self.position
        return 0

    def getOrientationFrame(self, out: list[list[float]], ID: int = -1) -> int:
        for row, src in zip(out, self.frame, strict=True):
            row[:] = src
        return 0

    def getButton(self, index: int, ID: int = -1) -> int:
        return self.buttons[index]

    def close(self, ID: int = -1) -> int:
        self.calls.append(("close", ID))
        return 0


class FakeHd:
    """Stand-in for ``pyOpenHaptics.hd`` (a Touch): HD_CURRENT_TRANSFORM is a ctypes 4x4 of
    doubles, column-major (translation in row 3), in mm, in OpenHaptics' axes (x right, y up, z
    toward the user)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []
        R_hd = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # 90 deg about y_hd
        T = np.eye(4)
        T[:3, :3] = R_hd
        T[:3, 3] = [10.0, 20.0, 30.0]  # mm
        row = ctypes.c_double * 4
        self.transform = (row * 4)(*(row(*column) for column in T.T))  # hduMatrix
        self.buttons = 2  # HD_DEVICE_BUTTON_2
        self.scheduled: Callable[[], None] | None = None
        self.frames = 0
        self._running = False
        self._thread: threading.Thread | None = None
        self._frame_lock = threading.Lock()

    def init_device(self, name: str) -> int:
        self.calls.append(("init_device", name))
        return 7

    def get_model(self) -> str:
        return "Touch"

    def enable_force(self) -> None:
        self.calls.append(("enable_force", None))

    def start_scheduler(self) -> None:
        self.calls.append(("start_scheduler", None))
        self._running = True
        self._thread = threading.Thread(target=self._servo, daemon=True)
        self._thread.start()

    def _servo(self) -> None:
        while self._running:
            with self._frame_lock:
                if self.scheduled is not None:
                    self.scheduled()
            time.sleep(1e-3)

    def drop_callback(self) -> None:
        """Unschedule the callback, as OpenHaptics does after an error in it; returns after any
        frame in progress."""
        with self._frame_lock:
            self.scheduled = None

    def stop_scheduler(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join()
        self.calls.append(("stop_scheduler", None))

    def begin_frame(self, handle: int) -> None:
        self.calls.append(("begin_frame", handle))

    def end_frame(self, handle: int) -> None:
        self.calls.append(("end_frame", handle))
        self.frames += 1

    def get_transform(self) -> Any:
        return self.transform

    def get_buttons(self) -> int:
        return self.buttons

    def set_force(self, feedback: list[float]) -> None:
        self.calls.append(("set_force", list(feedback)))

    def close_device(self, handle: int) -> None:
        self.calls.append(("close_device", handle))

    def settle(self) -> None:
        """Wait until a whole frame ran after now (bounded), so the next sample sees what the
        test just changed."""
        start = self.frames
        for _ in range(5000):
            if self.frames >= start + 2:
                return
            time.sleep(1e-3)
        raise AssertionError("the stand-in scheduler stopped")


def fake_hd_callback(hd: FakeHd) -> types.ModuleType:
    """Stand-in for ``pyOpenHaptics.hd_callback``: the callback in a frame; scheduling it."""
    module = types.ModuleType("pyOpenHaptics.hd_callback")

    def hd_callback(function: Callable[[], None]) -> Callable[[], None]:
        def framed() -> None:
            hd.begin_frame(7)
            function()
            hd.end_frame(7)

        return framed

    def schedule(callback: Callable[[], None]) -> None:
        hd.scheduled = callback

    module.hd_callback = hd_callback  # type: ignore[attr-defined]
    module.hdAsyncSheduler = schedule  # type: ignore[attr-defined]
    return module


@pytest.fixture
def dhd(monkeypatch: pytest.MonkeyPatch) -> FakeDhd:
    fake = FakeDhd()
    package = types.ModuleType("forcedimension_core")
    monkeypatch.setitem(sys.modules, "forcedimension_core", package)
    monkeypatch.setitem(sys.modules, "forcedimension_core.dhd", fake)  # type: ignore[arg-type]
    return fake


@pytest.fixture
def hd(monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeHd]:
    fake = FakeHd()
    monkeypatch.setitem(sys.modules, "pyOpenHaptics", types.ModuleType("pyOpenHaptics"))
    monkeypatch.setitem(sys.modules, "pyOpenHaptics.hd", fake)  # type: ignore[arg-type]
    monkeypatch.setitem(sys.modules, "pyOpenHaptics.hd_callback", fake_hd_callback(fake))
    yield fake
    fake.stop_scheduler()  # a test that did not close its device


def forces_sent(fake: FakeDhd | FakeHd) -> list[Any]:
    return [args for name, args in fake.calls if name in ("setForceAndTorque", "set_force")]


# -- refusing without the runtime ---------------------------------------------------------------


def test_each_backend_refuses_in_one_line_naming_the_missing_runtime(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "forcedimension_core.dhd", None)  # import fails
    monkeypatch.setitem(sys.modules, "pyOpenHaptics.hd", None)
    with pytest.raises(DeviceUnavailable) as fd:
        ForceDimensionDevice()
    assert (
        str(fd.value)
        == "forcedimension-core is not installed (pip install 'frhc[fd]'), and it needs the Force Dimension SDK's libdhd"
    )
    with pytest.raises(DeviceUnavailable) as oh:
        TouchDevice()
    assert "\n" not in str(oh.value)
    assert "pyOpenHaptics is not installed (pip install 'frhc[openhaptics]')" in str(oh.value)
    assert "libHD" in str(oh.value)


def test_a_native_library_that_fails_to_load_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    def failing_import(name: str) -> None:
        raise OSError("libdhd.so.3: cannot open shared object file")

    monkeypatch.setattr("app.device.vendors.importlib.import_module", failing_import)
    with pytest.raises(
        DeviceUnavailable, match=r"forcedimension-core cannot load the Force Dimension SDK's libdhd: libdhd\.so\.3"
    ):
        ForceDimensionDevice()


def test_a_binding_whose_runtime_finds_no_native_library_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    """forcedimension-core's runtime raises ImportError (not ModuleNotFoundError) at import when
    libdhd is missing: the package is there, the library is not."""

    def failing_import(name: str) -> None:
        raise ImportError("There were problems loading libdrd.")

    monkeypatch.setattr("app.device.vendors.importlib.import_module", failing_import)
    with pytest.raises(DeviceUnavailable, match=r"^forcedimension-core cannot load the Force Dimension SDK's libdhd"):
        ForceDimensionDevice()


def test_force_dimension_button_error_is_not_a_press(dhd: FakeDhd) -> None:
    device = ForceDimensionDevice()
    dhd.buttons = [-1, 1, -1]
    assert device.step(np.zeros(6), 1e-3).buttons == (False, True, False)  # -1 must not hold the deadman


def test_device_addresses_are_checked() -> None:
    with pytest.raises(InputError, match="fd:N needs a device number"):
        open_device_url("fd:first", 1e-3)
    with pytest.raises(InputError, match="not a device address"):
        open_device_url("usb:0", 1e-3)


# -- Force Dimension ------------------------------------------------------------------------------


def test_force_dimension_reads_metres_and_its_frame_as_is_and_sends_newtons(dhd: FakeDhd) -> None:
    device = open_device_url("fd:2", 1e-3)
    assert isinstance(device, ForceDimensionDevice)
    assert ("openID", 2) in dhd.calls
    assert ("enableForce", (True, 3)) in dhd.calls
    assert not device.torque_capable
    r = device.step(np.array([1.0, -2.0, 3.0, 0.1, 0.2, 0.3]), 1e-3)
    np.testing.assert_array_equal(r.T_0_G[:3, 3], [0.01, -0.02, 0.03])
    np.testing.assert_array_equal(r.T_0_G[:3, :3], dhd.frame)
    # Force in N along {0} = the SDK's axes, sign kept; no moment to a device without an active wrist.
    assert forces_sent(dhd)[-1] == ([1.0, -2.0, 3.0], [0.0, 0.0, 0.0], 3)
    assert r.buttons == (True, False, False)
    assert r.fresh


def test_force_dimension_error_is_a_lost_device_and_close_zeroes_the_force(dhd: FakeDhd) -> None:
    device = ForceDimensionDevice()
    dhd.fail = True
    assert device.step(np.zeros(6), 1e-3).status == LinkStatus.DISCONNECTED
    device.close()
    assert forces_sent(dhd)[-1] == ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 3)
    assert dhd.calls[-1] == ("close", 3)


# -- OpenHaptics ---------------------------------------------------------------------------------


def test_touch_converts_millimetres_and_y_up_axes_into_the_base_frame(hd: FakeHd) -> None:
    device = open_device_url("openhaptics:", 1e-3)
    assert isinstance(device, TouchDevice)
    assert ("init_device", "Default Device") in hd.calls
    r = device.reading
    # (x, y, z)_hd = (10, 20, 30) mm -> {0} (x, -z, y) in m.
    np.testing.assert_allclose(r.T_0_G[:3, 3], [0.010, -0.030, 0.020])
    # The stylus turned 90 deg about OpenHaptics' vertical y is turned 90 deg about {0}'s z.
    np.testing.assert_allclose(r.T_0_G[:3, :3], [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-15)


def test_touch_force_goes_out_in_openhaptics_axes_from_the_schedulers_frames(hd: FakeHd) -> None:
    device = TouchDevice(period=5.0)
    device.step(np.array([1.0, 2.0, 3.0, 0.5, 0.5, 0.5]), 1e-3)
    calls = list(hd.calls)
    # {0} up (z) is OpenHaptics' y; {0} y (away from the user) is -z_hd. No moments (3-dof force).
    np.testing.assert_allclose(forces_sent(hd)[-1], [1.0, 3.0, -2.0])
    # Every force is set inside a frame the scheduler ran (never from the servo loop's thread).
    framed = [i for i, (name, _) in enumerate(calls) if name == "set_force" and i + 1 < len(calls)]
    assert framed
    assert all(calls[i - 1][0] == "begin_frame" and calls[i + 1][0] == "end_frame" for i in framed)
    device.close()
    assert hd.calls[-2:] == [("stop_scheduler", None), ("close_device", 7)]
    assert forces_sent(hd)[-1] == [0.0, 0.0, 0.0]  # rendered before the scheduler stopped


def test_touch_buttons_map_to_deadman_and_reference(hd: FakeHd) -> None:
    device = TouchDevice(period=5.0)
    assert device.reading.buttons == (False, True, False)  # button 2 held: the reference switch
    hd.buttons = 1
    hd.settle()
    assert device.step(np.zeros(6), 1e-3).buttons == (True, False, False)  # button 1: deadman
    device.close()


def test_touch_without_frames_is_a_missed_sample(hd: FakeHd) -> None:
    """The scheduler stops calling back (OpenHaptics drops a callback after an error): the
    sample is not fresh, and the guard zeroes the force."""
    device = TouchDevice(period=0.05)
    hd.drop_callback()
    device.step(np.zeros(6), 1e-3)  # takes a frame that ran before the drop, if one did
    assert not device.step(np.zeros(6), 1e-3).fresh
    device.close()  # no frame renders the zero: it gives up after FIRST_FRAME_TIMEOUT and stops
    assert hd.calls[-2:] == [("stop_scheduler", None), ("close_device", 7)]


def test_touch_receives_at_most_its_force_limit_through_the_guard(hd: FakeHd) -> None:
    """The boundary's guard, as the servo loop applies it, between the controller and the SDK."""
    device = TouchDevice(period=5.0)
    guard = ForceGuard(CartesianSpec(force_limit=3.3, ramp_time=0.0), device.torque_capable)
    device.step(guard.apply(np.array([0.0, 0.0, -40.0, 0.0, 0.0, 1.0]), device.reading, 1e-3), 1e-3)
    np.testing.assert_allclose(forces_sent(hd)[-1], [0.0, -3.3, 0.0])  # down in {0} is -y_hd
    device.close()


def test_device_buttons_drive_the_loops_switches(hd: FakeHd) -> None:
    """Button 1 holds the deadman; a press of button 2 is a reference press, for one tick."""
    from app.device.spec import load_device
    from app.session.loop import LoopConfig, ServoLoop
    from app.world.scene import load_scene

    spec = load_device("touch3")
    config = LoopConfig(spec, load_scene("probe"), spec.data.gains, device_url="openhaptics:", sample_wait=5.0)
    loop = ServoLoop(config)
    hd.buttons = 1 | 2
    hd.settle()
    rec = loop.tick()
    assert (rec.deadman, rec.reference) == (True, True)
    rec = loop.tick()
    assert (rec.deadman, rec.reference) == (True, False)  # held, not pressed again
    hd.buttons = 0
    hd.settle()
    rec = loop.tick()
    assert (rec.deadman, rec.reference) == (False, False)
    assert loop.switches == Switches()  # the page's own switches are untouched
    loop.close()
    assert hd.calls[-1] == ("close_device", 7)
