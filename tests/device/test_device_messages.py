"""A served device that sends garbage: refused at the connect in one line naming the field, and
mid-run a missed sample (zero force, said once per run of bad messages), never a traceback nor a
non-finite pose. The misbehaving service is websockets' own server sending scripted messages (a
stand-in for a faulty Inverse Service, which cannot be here), or ``frhc device serve`` whose
state messages are spoiled for a few periods."""

from __future__ import annotations

import logging
import re
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from device_helpers import make_served_loop, press_into_contact
from websockets.sync.server import Server, ServerConnection, serve

from app.cli import main
from app.device.boundary import LinkStatus
from app.device.haply import DeviceServer, DeviceUnreachable, HaplyClient, state_message
from app.device.wslink import WsLink

GOOD = state_message("dev", np.eye(4), (False, False, False), None)
WAIT = 5.0  # s: bound on a loopback reply on a loaded machine (not a timing assertion)


def _spoiled(old: str, new: str) -> str:
    assert old in GOOD
    return GOOD.replace(old, new, 1)


@pytest.fixture
def first_message() -> Iterator[tuple[list[str | bytes], int]]:
    """A server that opens every connection with ``messages[0]`` (set by the test)."""
    messages: list[str | bytes] = [GOOD]

    def handler(ws: ServerConnection) -> None:
        ws.send(messages[0])
        for _ in ws:
            pass

    server: Server = serve(handler, "127.0.0.1", 0, ping_interval=None, compression=None)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield messages, server.socket.getsockname()[1]
    server.shutdown()
    thread.join(WAIT)


@pytest.mark.parametrize(
    ("message", "expected"),
    [
        ("hello", "JSON is malformed"),
        (GOOD[:40], "Input data was truncated"),
        # Gave a UnicodeDecodeError traceback inside the connect (harden8).
        (b"\xff\xfe", "JSON is malformed"),
        # float("nan") of a string: a NaN pose reached the controller (harden8).
        (_spoiled('"x":0.0', '"x":"nan"'), "Expected `float`, got `str` - at `$.inverse3[0].state.cursor_position.x`"),
        (_spoiled('"x":0.0', '"x":1e999'), "Number out of range - at `$.inverse3[0].state.cursor_position.x`"),
        (_spoiled('"x":0.0', '"x":true'), "Expected `float`, got `bool`"),
        # bool("false") is True: it held the deadman (harden8).
        (
            _spoiled('"a":false', '"a":"false"'),
            "Expected `bool`, got `str` - at `$.wireless_verse_grip[0].state.buttons.a`",
        ),
        (_spoiled('"w":1.0', '"w":0.0'), "zero orientation quaternion"),
        # A non-object extension gave a TypeError traceback (harden8).
        (GOOD[:-1] + ',"frhc_sim":"x"}', "Expected `object | null`, got `str` - at `$.frhc_sim`"),
        (
            GOOD[:-1] + ',"frhc_sim":{"device":"touch3","hand_wrench":[1,2]}}',
            "length >= 6 - at `$.frhc_sim.hand_wrench`",
        ),
        # A command where a state belongs (a device of the other kind: a client, not a service).
        (
            '{"inverse3":[{"device_id":"x","commands":{"set_cursor_force":{"values":{"x":0,"y":0,"z":0}}}}]}',
            "missing required field `state` - at `$.inverse3[0]`",
        ),
    ],
)
def test_a_service_whose_first_state_is_unusable_is_refused_in_one_line_naming_the_field(
    first_message: tuple[list[str | bytes], int], message: str | bytes, expected: str
) -> None:
    messages, port = first_message
    messages[0] = message
    with pytest.raises(DeviceUnreachable) as refused:
        HaplyClient(f"ws://127.0.0.1:{port}", 0.1)
    text = str(refused.value)
    assert "\n" not in text
    assert text.startswith(f"no usable Inverse Service at ws://127.0.0.1:{port}: no usable first state")
    assert expected in text


def test_frhc_run_against_a_service_sending_garbage_exits_2_in_one_line(
    first_message: tuple[list[str | bytes], int], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    messages, port = first_message
    messages[0] = _spoiled('"x":0.0', '"x":"nan"')
    assert main(["run", "probe_rate", "--out", str(tmp_path / "out"), "--device", f"ws://127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"error: no usable Inverse Service at ws://127.0.0.1:{port}")
    assert "cursor_position.x" in err[-1]
    assert not list((tmp_path / "out").rglob("*"))  # no log begun (the folder itself is made first)


def test_a_binary_message_that_is_not_utf8_is_read_not_raised(first_message: tuple[list[str | bytes], int]) -> None:
    messages, port = first_message
    messages[0] = b"\xff{}"
    link = WsLink.connect(f"ws://127.0.0.1:{port}", WAIT)
    assert link.recv(WAIT) == "\ufffd{}"
    link.close()


def test_bad_states_mid_contact_zero_the_force_said_once_and_the_force_ramps_back(
    served: DeviceServer, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    loop = make_served_loop(served.port)
    press_into_contact(loop)
    assert np.linalg.norm(loop.wrench[:3]) > 0.0
    good_state = served._state
    bad = 0

    def spoiled_state() -> str:  # a NaN position, as a string: what float() would have let in
        nonlocal bad
        bad += 1
        return good_state().replace('"cursor_position":{"x":', '"cursor_position":{"x":"nan","was":', 1)

    caplog.set_level(logging.WARNING, logger="app.device.haply")
    monkeypatch.setattr(served, "_state", spoiled_state)
    for _ in range(50):  # until 5 spoiled states were read (one already on its way may come first)
        loop.tick()
        if bad >= 6:
            break
    assert not loop.reading.fresh
    assert loop.reading.status == LinkStatus.STALLED
    np.testing.assert_array_equal(loop.wrench, 0.0)
    assert np.isfinite(loop.reading.T_0_G).all()
    monkeypatch.setattr(served, "_state", good_state)
    for _ in range(100):
        loop.tick()
        if loop.reading.fresh:
            break
    assert loop.reading.status == LinkStatus.RAMPING
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 2, said
    assert (
        "Expected `float`, got `str` - at `$.inverse3[0].state.cursor_position.x`); zero force until a good one"
        in said[0]
    )
    again = re.search(r"good state again after (\d+) bad$", said[1])
    assert again is not None
    assert 5 <= int(again.group(1)) <= bad
    loop.close()


FRHC_RUN = [sys.executable, "-m", "app.cli", "run", "probe_rate", "--out"]


def test_frhc_run_with_no_service_at_the_device_address_prints_one_line(tmp_path: Path) -> None:
    """Nothing listening at ``--device``: exit 2 and the error alone on stderr. The client's own
    log line of the failed connect ('device ws://...: cannot connect ...', what ``frhc run
    --device`` prints of the link's changes mid-run) came first and said it twice."""
    with socket.socket() as s:  # a port nothing listens on: bound, never listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        done = subprocess.run(
            [*FRHC_RUN, str(tmp_path / "out"), "--device", f"ws://127.0.0.1:{port}"],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        f"error: no usable Inverse Service at ws://127.0.0.1:{port}: cannot connect ([Errno 111] Connection refused) "
        "(is `frhc device serve` or Haply's service running?)"
    ]
