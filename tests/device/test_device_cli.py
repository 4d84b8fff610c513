"""`frhc device serve` and `--device ADDRESS`: bad input and absent devices are refused in one
line naming what is wrong, exit 2, no traceback, nothing run."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.cli import main
from app.device.haply import served_device
from app.device.vendors import open_device_url
from app.errors import InputError


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["device", "serve", "--device", "jpl"], "field 'cartesian': serving a device needs its [cartesian] table"),
        (["device", "serve", "--rate", "0"], "--rate must be in [10, 20000] Hz, got 0"),
        (
            ["run", "probe_rate", "--device", "ws://127.0.0.1:1"],
            "no usable Inverse Service at ws://127.0.0.1:1: cannot connect",
        ),
        (["run", "probe_rate", "--device", "fd:"], "forcedimension-core is not installed (pip install 'frhc[fd]')"),
        (["run", "probe_rate", "--device", "openhaptics:"], "pyOpenHaptics is not installed"),
        # The web demo's loop process failed alone: a traceback, and the page waited (harden8).
        (["web", "--device", "fd:", "--port", "0"], "forcedimension-core is not installed (pip install 'frhc[fd]')"),
        (["web", "--device", "openhaptics:Left", "--port", "0"], "pyOpenHaptics is not installed"),
    ],
)
def test_device_errors_are_one_line_exit_2(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert expected in err
    assert list(tmp_path.iterdir()) == []  # no empty output folder left behind (runs/probe_rate was)


@pytest.mark.parametrize(
    ("address", "expected"),
    [
        ("usb:1", "not a device address: 'usb:1' (ws://host:port, fd:N, openhaptics:NAME)"),
        ("fd:left", "fd:N needs a device number, got 'fd:left'"),
        # These four gave a ValueError traceback from the URL parser (harden8).
        ("ws://localhost:port", "bad device address 'ws://localhost:port': Port could not be cast to integer"),
        ("ws://localhost:99999", "bad device address 'ws://localhost:99999': Port out of range 0-65535"),
        ("ws://localhost:-1", "bad device address 'ws://localhost:-1': Port could not be cast to integer"),
        ("ws://[::1", "bad device address 'ws://[::1': Invalid IPv6 URL"),
        # websockets reads port 0 as "the default" (80): it was tried there.
        ("ws://localhost:0", "bad device address 'ws://localhost:0': port 0 (ports are 1-65535)"),
        ("ws://", "bad device address 'ws://': ws:// isn't a valid URI: hostname isn't provided"),
    ],
)
def test_an_address_that_is_no_device_is_refused_by_the_argument_parser(
    address: str, expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as done:
        main(["run", "probe_rate", "--device", address])
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith(f"frhc run: error: argument --device: {expected}")


@pytest.mark.parametrize("address", ["ws://localhost:port", "ws://[::1", "ws://localhost:0"])
def test_the_web_demo_and_the_loop_check_the_address_too(address: str) -> None:
    """``frhc web --device`` takes device names as well, so its address reaches
    :func:`served_device` unparsed; the loop's :func:`open_device_url` is public too."""
    with pytest.raises(InputError, match="bad device address"):
        served_device(address, None)
    with pytest.raises(InputError, match="bad device address"):
        open_device_url(address, 1e-3)
