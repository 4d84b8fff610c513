"""A ``--address`` where no Ray head answers, without starting Ray: one line, exit 2, no folder
left claimed by a run that never ran. (Joining a real head: test_ray_cluster.py.)"""

from __future__ import annotations

import http.server
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from app.cli import main

pytest.importorskip("ray")

TINY_SWEEP = 'base = "probe_rate"\n[[vary]]\nfield = "duration"\nvalues = [0.05]\n'


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:
        """Nothing on stderr, where the test counts the command's lines."""


@pytest.fixture(autouse=True)
def ray_not_joined(monkeypatch: pytest.MonkeyPatch) -> None:
    """As in a new ``frhc`` process: the engine joins only when Ray is not up in this process,
    and an earlier test of the suite may have left a local instance running."""
    import ray

    monkeypatch.setattr(ray, "is_initialized", lambda: False)


@pytest.fixture
def not_heads() -> Iterator[dict[str, str]]:
    """Addresses where something listens that is no Ray head: a web server, and a socket that
    accepts (the kernel's backlog) and never replies, as a stopped head does."""
    web = http.server.ThreadingHTTPServer(("127.0.0.1", 0), QuietHandler)
    thread = threading.Thread(target=web.serve_forever, daemon=True)
    thread.start()
    silent = socket.create_server(("127.0.0.1", 0))
    try:
        yield {
            "web server": f"127.0.0.1:{web.server_address[1]}",
            "silent": f"127.0.0.1:{silent.getsockname()[1]}",
        }
    finally:
        web.shutdown()
        web.server_close()
        silent.close()


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1, err  # no progress bar, no Ray warnings before it
    return err.strip()


def test_nothing_listening_is_one_line_for_each_command_and_leaves_no_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with socket.create_server(("127.0.0.1", 0)) as s:
        nothing = f"127.0.0.1:{s.getsockname()[1]}"  # free once closed
    sweep = tmp_path / "tiny.toml"
    sweep.write_text(TINY_SWEEP)
    commands = {
        "sweep": ["sweep", str(sweep)],
        "experiment": ["experiment", "--operators", "1"],
        "zwidth": ["zwidth", "--renderers", "plain", "--dampings", "0"],
    }
    for name, command in commands.items():
        out = tmp_path / name
        line = _refused([*command, "--address", nothing, "--out", str(out)], capsys)
        assert line.startswith(f"error: --address {nothing}: no Ray cluster answers there"), line
        assert not out.exists(), f"{name} left {sorted(p.name for p in out.rglob('*'))}"


def test_a_server_that_is_no_ray_head_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], not_heads: dict[str, str]
) -> None:
    """Before harden9 Ray was asked to join them: minutes of retries, a warning line a second."""
    sweep = tmp_path / "tiny.toml"
    sweep.write_text(TINY_SWEEP)
    for name, address in not_heads.items():
        line = _refused(["sweep", str(sweep), "--address", address, "--out", str(tmp_path / name)], capsys)
        assert line.startswith(f"error: --address {address}: something listens there, but it is not a Ray"), line
        assert not (tmp_path / name).exists()
