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
from hypothesis import given
from hypothesis import strategies as st

from app.cli import main
from app.sweep.probe import (
    END_HEADERS,
    END_STREAM,
    GOAWAY,
    HEADERS,
    HTTP2_PREFACE,
    SETTINGS,
    GrpcAnswer,
    _frame,
    _header,
    _int,
    _literal_fields,
    _read,
    _read_int,
    call_grpc,
)

pytest.importorskip("ray")

TINY_SWEEP = 'base = "probe_rate"\n[[vary]]\nfield = "duration"\nvalues = [0.05]\n'


@pytest.fixture(autouse=True)
def ray_not_joined(monkeypatch: pytest.MonkeyPatch) -> None:
    """As in a new ``frhc`` process (an earlier test may have left Ray up in this one)."""
    import ray

    monkeypatch.setattr(ray, "is_initialized", lambda: False)


@contextmanager
def http2_server(reply: bytes, requests: list[bytes] | None = None) -> Iterator[int]:
    """A server on loopback that reads the preface and the client's frames up to its DATA frame
    (the call's header blocks appended to ``requests``), then sends its SETTINGS and ``reply``
    (whole frames). Yields its port."""
    listener = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        conn, _ = listener.accept()
        with conn:
            _read(conn, len(HTTP2_PREFACE))
            conn.sendall(_header(0, SETTINGS, 0, 0))
            while (frame := _frame(conn))[0] != 0:  # the call's DATA frame
                if frame[0] == HEADERS and requests is not None:
                    requests.append(frame[3])
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
        assert (call_grpc("127.0.0.1", port, 5.0) is not None) is grpc, name


#: grpc-core's answer to a call without the token its server wants: one HEADERS frame (trailers
#: only), read from a real ``ray start --head`` of Ray 2.60 with token authentication.
REFUSED = (
    b"\x88\x40\x0ccontent-type\x10application/grpc\x00\x0bgrpc-status\x0216\x00\x0cgrpc-message"
    b"\x3eInvalidAuthToken: Authentication token is missing or incorrect"
)
#: A full answer: headers, the message, then the trailers with the status.
OK_HEADERS = b"\x88\x40\x0ccontent-type\x10application/grpc"
OK_TRAILERS = b"\x00\x0bgrpc-status\x010\x00\x0cgrpc-message\x00"


@pytest.mark.parametrize(
    ("name", "reply", "answer"),
    [
        (
            "a token refused",
            _response(REFUSED),
            GrpcAnswer(16, "InvalidAuthToken: Authentication token is missing or incorrect"),
        ),
        (
            "OK, the status in trailers after the message",
            _header(len(OK_HEADERS), HEADERS, END_HEADERS, 1)
            + OK_HEADERS
            + _header(5, 0, 0, 1)
            + bytes(5)
            + _response(OK_TRAILERS),
            GrpcAnswer(0, ""),
        ),
        (
            "a Huffman-coded status: read as unknown",
            _response(b"\x88\x00\x0bgrpc-status\x81\x00"),
            GrpcAnswer(None, ""),
        ),
    ],
)
def test_the_probe_reads_the_grpc_status_and_message(name: str, reply: bytes, answer: GrpcAnswer) -> None:
    with http2_server(reply) as port:
        assert call_grpc("127.0.0.1", port, 5.0) == answer, name


def test_the_probe_sends_the_metadata_it_is_given() -> None:
    """The token goes in the call's headers as a literal field, whatever its length (an HPACK
    length of 127 or more takes more than one byte)."""
    requests: list[bytes] = []
    token = "Bearer " + "k" * 300
    with http2_server(_response(REFUSED), requests) as port:
        call_grpc("127.0.0.1", port, 5.0, (("authorization", token),))
    (block,) = requests
    fields = _literal_fields(block)
    assert fields[b"authorization"] == token.encode()
    assert fields[b"te"] == b"trailers"


@given(st.integers(0, 2**32), st.sampled_from([4, 5, 6, 7]), st.integers(0, 255))
def test_hpack_integers_read_back_as_written(value: int, prefix: int, high: int) -> None:
    """RFC 7541, 5.1: the bits above the prefix are the caller's and do not change the value."""
    first = high & ~((1 << prefix) - 1)
    encoded = _int(value, prefix, first) + b"\xff"  # a byte after it that must not be read
    assert encoded[0] & ~((1 << prefix) - 1) == first
    assert _read_int(encoded, 0, prefix) == (value, len(encoded) - 1)


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
