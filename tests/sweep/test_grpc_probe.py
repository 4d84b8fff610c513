"""The gRPC probe asked before Ray joins a cluster (app/sweep/probe.py), against HTTP/2 servers
written here that answer a call with a known first header field, as a proxy, a plain HTTP/2 web
server and a gRPC server do. A real Ray head's answer: test_ray_cluster.py (the same probe runs
before every join there)."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from app.cli import main
from app.sweep.probe import (
    END_HEADERS,
    END_STREAM,
    GOAWAY,
    HEADERS,
    HTTP2_PREFACE,
    SETTINGS,
    _frame,
    _header,
    _read,
    answers_grpc,
)

pytest.importorskip("ray")

TINY_SWEEP = 'base = "probe_rate"\n[[vary]]\nfield = "duration"\nvalues = [0.05]\n'


@pytest.fixture(autouse=True)
def ray_not_joined(monkeypatch: pytest.MonkeyPatch) -> None:
    """As in a new ``frhc`` process (an earlier test may have left Ray up in this one)."""
    import ray

    monkeypatch.setattr(ray, "is_initialized", lambda: False)


@contextmanager
def http2_server(reply: bytes) -> Iterator[int]:
    """A server on loopback that reads the preface and the client's frames up to its DATA frame,
    then sends its SETTINGS and ``reply`` (whole frames). Yields its port."""
    listener = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        conn, _ = listener.accept()
        with conn:
            _read(conn, len(HTTP2_PREFACE))
            conn.sendall(_header(0, SETTINGS, 0, 0))
            while _frame(conn)[0] != 0:  # the call's DATA frame
                pass
            conn.sendall(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield listener.getsockname()[1]
    finally:
        listener.close()
        thread.join(timeout=5)


def _response(block: bytes) -> bytes:
    return _header(len(block), HEADERS, END_HEADERS | END_STREAM, 1) + block


@pytest.mark.parametrize(
    ("name", "reply", "grpc"),
    [
        ("gRPC: :status 200 indexed, as grpc-core sends it", _response(b"\x88"), True),
        ("a proxy's 404, indexed (the reply seen from this sandbox's outbound proxy)", _response(b"\x8d"), False),
        ("a 503 as a literal with indexing", _response(b"\x48\x03503"), False),
        ("a 200 as a literal without indexing after a table size update", _response(b"\x3f\xe1\x1f\x08\x03200"), True),
        ("a Huffman-coded status: not readable here, Ray decides", _response(b"\x48\x82\x10\x01"), True),
        ("GOAWAY instead of an answer", _header(8, GOAWAY, 0, 0) + bytes(8), False),
        ("a first field that is not :status", _response(b"\x82"), False),
    ],
)
def test_the_probe_reads_the_status_of_the_answer(name: str, reply: bytes, grpc: bool) -> None:
    with http2_server(reply) as port:
        assert answers_grpc("127.0.0.1", port, 5.0) is grpc, name


def test_an_http2_server_that_is_no_ray_head_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: Ray was asked to join, printed a warning line a second for ~20 s, then failed."""
    sweep = tmp_path / "tiny.toml"
    sweep.write_text(TINY_SWEEP)
    with http2_server(_response(b"\x8d")) as port:
        address = f"127.0.0.1:{port}"
        assert main(["sweep", str(sweep), "--address", address, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"error: --address {address}: something listens there, but it is not a Ray"), err
    assert not (tmp_path / "out").exists()


def test_another_scheme_is_not_a_cluster_address(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep = tmp_path / "tiny.toml"
    sweep.write_text(TINY_SWEEP)
    assert main(["sweep", str(sweep), "--address", "http://127.0.0.1:8265", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --address http://127.0.0.1:8265: not a Ray cluster address (host:port of its head, or 'auto')"
