"""`frhc device serve` and `--device ADDRESS`: bad input and absent devices are refused in one
line naming what is wrong, exit 2, no traceback, nothing run."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.cli import main


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["device", "serve", "--device", "jpl"], "field 'cartesian': serving a device needs its [cartesian] table"),
        (["device", "serve", "--rate", "0"], "--rate must be in [10, 20000] Hz, got 0"),
        (["run", "probe_rate", "--device", "ws://127.0.0.1:1"], "no Inverse Service answers at ws://127.0.0.1:1"),
        (["run", "probe_rate", "--device", "fd:"], "forcedimension-core is not installed (pip install 'frhc[fd]')"),
        (["run", "probe_rate", "--device", "openhaptics:"], "pyOpenHaptics is not installed"),
        (["run", "probe_rate", "--device", "fd:left"], "fd:N needs a device number, got 'fd:left'"),
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


def test_an_address_that_is_no_device_is_refused_by_the_argument_parser(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["run", "probe_rate", "--device", "usb:1"])
    assert done.value.code == 2
    assert "expected ws://host:port, fd:N or openhaptics:NAME, got 'usb:1'" in capsys.readouterr().err
