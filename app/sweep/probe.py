"""Does a gRPC server answer at ``host:port``? Asked before Ray is told to join a cluster there.

Ray's own join retries a wrong address for ~20 s to minutes, printing a warning line a second; this
asks once, within a timeout, over a plain socket. A Ray head's GCS and a Ray Client server are gRPC
servers (grpc-core); gRPC answers every request over HTTP/2 with ``:status 200``, even for a method
it does not know (the gRPC status then travels in ``grpc-status``), so:

- no SETTINGS frame in reply to the HTTP/2 preface: not gRPC (an HTTP/1 server, a stopped head
  whose socket accepts and never replies);
- an HTTP/2 server that answers a gRPC call with another HTTP status (a proxy's 404): not gRPC.

Hand-written rather than a dependency: grpcio (~10 MB, compiled) or h2 would each serve only this
check, which needs two frames out and the first header field of one frame back (RFC 9113 for the
frames, RFC 7541 for the header field).
"""

from __future__ import annotations

import socket

#: An HTTP/2 client's connection preface and an empty SETTINGS frame (RFC 9113, 3.4 and 6.5).
HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes((0, 0, 0, 4, 0, 0, 0, 0, 0))
#: Frame types (RFC 9113, 6).
DATA, HEADERS, RST_STREAM, SETTINGS, GOAWAY = 0, 1, 3, 4, 7
#: Frame flags (RFC 9113, 6.1-6.2).
END_STREAM, ACK, END_HEADERS, PADDED, PRIORITY = 0x1, 0x1, 0x4, 0x8, 0x20
#: A method every Ray head's GCS serves; any path would do, since gRPC answers 200 to unknown ones.
PATH = b"/ray.rpc.NodeInfoGcsService/GetClusterId"
#: HPACK's static table entries holding ``:status`` (RFC 7541, Appendix A): index -> status.
STATIC_STATUS = {8: 200, 9: 204, 10: 206, 11: 304, 12: 400, 13: 404, 14: 500}


def answers_grpc(host: str, port: int, timeout: float) -> bool:
    """Whether a gRPC server at ``host:port`` answers an empty call with HTTP status 200 within
    ``timeout`` s (per read). A status sent Huffman-coded cannot be read here and counts as an
    answer (Ray then decides).

    Raises:
        OSError: no TCP connection within ``timeout``.
    """
    with socket.create_connection((host, port), timeout) as conn:
        try:
            conn.sendall(HTTP2_PREFACE)
            kind, _, _, _ = _frame(conn)
            if kind != SETTINGS:
                return False
            conn.sendall(_header(0, SETTINGS, ACK, 0) + _call(f"{host}:{port}".encode()))
            while True:
                kind, flags, stream, payload = _frame(conn)
                if kind in (GOAWAY, RST_STREAM) and stream in (0, 1):
                    return False
                if kind == HEADERS and stream == 1:
                    status = _first_status(payload, flags)
                    return status is None or status == 200
        except (OSError, ValueError, IndexError):  # reset, timed out, closed or garbled: no gRPC server answers
            return False


def _header(length: int, kind: int, flags: int, stream: int) -> bytes:
    """A frame's 9-byte header (RFC 9113, 4.1)."""
    return length.to_bytes(3, "big") + bytes((kind, flags)) + stream.to_bytes(4, "big")


def _literal(name_index: int, value: bytes) -> bytes:
    """A header field without indexing, its name from the static table, its value as is (RFC 7541,
    6.2.2; name indices below 15 and values shorter than 127 bytes, as all used here)."""
    return bytes((name_index, len(value))) + value


def _call(authority: bytes) -> bytes:
    """The HEADERS and DATA frames of a unary gRPC call with an empty message on stream 1."""
    block = (
        bytes((0x83, 0x86))  # :method POST, :scheme http (static 3, 6)
        + _literal(4, PATH)  # :path
        + _literal(1, authority)  # :authority
        + b"\x0f\x10\x10application/grpc"  # content-type (static 31: 15 + 16 in a 4-bit prefix)
        + b"\x00\x02te\x08trailers"
    )
    message = bytes(5)  # not compressed, length 0
    return _header(len(block), HEADERS, END_HEADERS, 1) + block + _header(len(message), DATA, END_STREAM, 1) + message


def _frame(conn: socket.socket) -> tuple[int, int, int, bytes]:
    """The next frame: its type, flags, stream and payload.

    Raises:
        ValueError: the connection closed mid-frame.
    """
    head = _read(conn, 9)
    length = int.from_bytes(head[0:3], "big")
    return head[3], head[4], int.from_bytes(head[5:9], "big") & 0x7FFFFFFF, _read(conn, length)


def _read(conn: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise ValueError("closed")
        data += chunk
    return data


def _first_status(payload: bytes, flags: int) -> int | None:
    """The ``:status`` of a response's HEADERS frame, which HPACK puts first (RFC 9113, 8.3), or
    None when it is Huffman-coded.

    Raises:
        ValueError: the first field is not ``:status``, or the block is cut short.
    """
    at = 0
    if flags & PADDED:
        at += 1
    if flags & PRIORITY:
        at += 5
    while payload[at] & 0xE0 == 0x20:  # dynamic table size updates come before any field
        at = _skip_int(payload, at, 5)
    first = payload[at]
    if first & 0x80:  # indexed field
        index = first & 0x7F
        if index not in STATIC_STATUS:
            raise ValueError("not :status")
        return STATIC_STATUS[index]
    index = first & (0x3F if first & 0x40 else 0x0F)  # literal, with or without indexing
    if index not in STATIC_STATUS:
        raise ValueError("not :status")
    size = payload[at + 1]
    if size & 0x80:
        return None
    return int(payload[at + 2 : at + 2 + size])


def _skip_int(payload: bytes, at: int, prefix: int) -> int:
    """The offset after an HPACK integer with a ``prefix``-bit prefix at ``at`` (RFC 7541, 5.1)."""
    mask = (1 << prefix) - 1
    if payload[at] & mask != mask:
        return at + 1
    at += 1
    while payload[at] & 0x80:
        at += 1
    return at + 1
