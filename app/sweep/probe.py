"""Does a gRPC server answer at ``host:port``? Asked before Ray is told to join a cluster there.

Ray's own join retries a wrong address for ~20 s to minutes, printing a warning line a second; this
asks once, within a timeout, over a plain socket. A Ray head's GCS and a Ray Client server are gRPC
servers (grpc-core); gRPC answers every request over HTTP/2 with ``:status 200``, even for a method
it does not know (the gRPC status then travels in ``grpc-status``), so:

- no SETTINGS frame in reply to the HTTP/2 preface: not gRPC (an HTTP/1 server, a stopped head
  whose socket accepts and never replies);
- an HTTP/2 server that answers a gRPC call with another HTTP status (a proxy's 404): not gRPC;
- a gRPC server that answers ``grpc-status`` 16 (UNAUTHENTICATED) to a call carrying the token Ray
  would send (:func:`ray_authorization`): a head with token authentication that refuses it. Ray's
  join would retry that for ~20 s, a warning line a second, before saying so.

Hand-written rather than a dependency: grpcio (~10 MB, compiled) or h2 would each serve only this
check, which needs two frames out and a few literal header fields back (RFC 9113 for the frames,
RFC 7541 for the header fields).
"""

from __future__ import annotations

import socket
from dataclasses import dataclass

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
#: The gRPC status of a call whose credentials the server refused (gRPC's status codes).
UNAUTHENTICATED = 16


@dataclass(frozen=True)
class GrpcAnswer:
    """What a gRPC server answered the probe's call.

    Attributes:
        status: Its ``grpc-status`` (0 OK, :data:`UNAUTHENTICATED`, ...), None where it could not be
            read (Huffman-coded, or in a frame not read).
        message: Its ``grpc-message`` ("" if none was read).
    """

    status: int | None
    message: str


def ray_authorization() -> tuple[tuple[str, str], ...]:
    """The gRPC metadata with which Ray would authenticate this process to a cluster (its token
    as ``authorization: Bearer ...`` where ``RAY_AUTH_MODE=token`` and a token is set), by Ray's own
    token loader; empty for none, and for a Ray without token authentication."""
    try:
        from ray._raylet import AuthenticationTokenLoader  # type: ignore[attr-defined]  # not in Ray's stub
    except ImportError:
        return ()
    loader = AuthenticationTokenLoader.instance()
    return tuple(loader.get_token_for_http_header().items()) if loader.has_token() else ()


def call_grpc(host: str, port: int, timeout: float, metadata: tuple[tuple[str, str], ...] = ()) -> GrpcAnswer | None:
    """The answer of a gRPC server at ``host:port`` to an empty call carrying ``metadata``, None if
    no gRPC server answers it with HTTP status 200 within ``timeout`` s (per read). A status sent
    Huffman-coded cannot be read here and counts as an answer (Ray then decides).

    Raises:
        OSError: no TCP connection within ``timeout``.
    """
    with socket.create_connection((host, port), timeout) as conn:
        try:
            conn.sendall(HTTP2_PREFACE)
            kind, _, _, _ = _frame(conn)
            if kind != SETTINGS:
                return None
            conn.sendall(_header(0, SETTINGS, ACK, 0) + _call(f"{host}:{port}".encode(), metadata))
            answered = False
            while True:
                kind, flags, stream, payload = _frame(conn)
                if kind in (GOAWAY, RST_STREAM) and stream in (0, 1):
                    return None
                if kind != HEADERS or stream != 1:
                    continue
                block = _block(payload, flags)
                if not answered:
                    status = _first_status(block)
                    if status is not None and status != 200:
                        return None
                    answered = True
                if flags & END_STREAM:  # the trailers (or the whole answer) hold the gRPC status
                    fields = _literal_fields(block)
                    code = fields.get(b"grpc-status")
                    return GrpcAnswer(
                        int(code) if code is not None and code.isdigit() else None,
                        fields.get(b"grpc-message", b"").decode(errors="replace"),
                    )
        except (OSError, ValueError, IndexError):  # reset, timed out, closed or garbled: no gRPC server answers
            return None


def _header(length: int, kind: int, flags: int, stream: int) -> bytes:
    """A frame's 9-byte header (RFC 9113, 4.1)."""
    return length.to_bytes(3, "big") + bytes((kind, flags)) + stream.to_bytes(4, "big")


def _int(value: int, prefix: int, first: int = 0) -> bytes:
    """``value`` as an HPACK integer with a ``prefix``-bit prefix, ``first`` the bits above it
    (RFC 7541, 5.1)."""
    mask = (1 << prefix) - 1
    if value < mask:
        return bytes((first | value,))
    out, value = [first | mask], value - mask
    while value >= 0x80:
        out.append(0x80 | value & 0x7F)
        value >>= 7
    return bytes((*out, value))


def _string(value: bytes) -> bytes:
    """An HPACK string literal, not Huffman-coded (RFC 7541, 5.2)."""
    return _int(len(value), 7) + value


def _literal(name_index: int, value: bytes) -> bytes:
    """A header field without indexing, its name from the static table (0: ``value`` follows a
    name of its own, see :func:`_field`), its value as is (RFC 7541, 6.2.2)."""
    return _int(name_index, 4) + _string(value)


def _field(name: str, value: str) -> bytes:
    """A header field without indexing, name and value as literals (RFC 7541, 6.2.2)."""
    return b"\x00" + _string(name.encode()) + _string(value.encode())


def _call(authority: bytes, metadata: tuple[tuple[str, str], ...] = ()) -> bytes:
    """The HEADERS and DATA frames of a unary gRPC call with an empty message on stream 1,
    ``metadata`` among its headers."""
    block = (
        bytes((0x83, 0x86))  # :method POST, :scheme http (static 3, 6)
        + _literal(4, PATH)  # :path
        + _literal(1, authority)  # :authority
        + _literal(31, b"application/grpc")  # content-type
        + _field("te", "trailers")
        + b"".join(_field(name, value) for name, value in metadata)
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


def _block(payload: bytes, flags: int) -> bytes:
    """A HEADERS frame's header block: its payload without padding and priority (RFC 9113, 6.2)."""
    at, end = 0, len(payload)
    if flags & PADDED:
        at, end = 1, end - payload[0]
    if flags & PRIORITY:
        at += 5
    return payload[at:end]


def _first_status(block: bytes) -> int | None:
    """The ``:status`` of a response's header block, which HPACK puts first (RFC 9113, 8.3), or
    None when it is Huffman-coded.

    Raises:
        ValueError: the first field is not ``:status``.
        IndexError: the block is cut short.
    """
    at = 0
    while block[at] & 0xE0 == 0x20:  # dynamic table size updates come before any field
        at = _read_int(block, at, 5)[1]
    first = block[at]
    if first & 0x80:  # indexed field
        index = first & 0x7F
        if index not in STATIC_STATUS:
            raise ValueError("not :status")
        return STATIC_STATUS[index]
    index, at = _read_int(block, at, 6 if first & 0x40 else 4)  # literal, with or without indexing
    if index not in STATIC_STATUS:
        raise ValueError("not :status")
    value, _ = _read_string(block, at)
    return None if value is None else int(value)


def _literal_fields(block: bytes) -> dict[bytes, bytes]:
    """The fields of a header block sent as literals with a name of their own, neither part
    Huffman-coded (as grpc-core sends ``grpc-status`` and ``grpc-message``): name -> value. Other
    fields are skipped.

    Raises:
        IndexError: the block is cut short.
    """
    fields: dict[bytes, bytes] = {}
    at = 0
    while at < len(block):
        first = block[at]
        if first & 0x80:  # indexed field
            at = _read_int(block, at, 7)[1]
            continue
        if first & 0xE0 == 0x20:  # dynamic table size update
            at = _read_int(block, at, 5)[1]
            continue
        named = first & (0x3F if first & 0x40 else 0x0F) == 0
        at = _read_int(block, at, 6 if first & 0x40 else 4)[1]
        name: bytes | None = None
        if named:
            name, at = _read_string(block, at)
        value, at = _read_string(block, at)
        if name and value is not None:
            fields[name] = value
    return fields


def _read_string(block: bytes, at: int) -> tuple[bytes | None, int]:
    """The HPACK string literal at ``at`` (None if Huffman-coded) and the offset after it."""
    huffman = block[at] & 0x80
    length, at = _read_int(block, at, 7)
    if at + length > len(block):
        raise IndexError("cut short")
    return (None if huffman else block[at : at + length]), at + length


def _read_int(block: bytes, at: int, prefix: int) -> tuple[int, int]:
    """The HPACK integer with a ``prefix``-bit prefix at ``at`` and the offset after it (RFC 7541, 5.1)."""
    mask = (1 << prefix) - 1
    value = block[at] & mask
    at += 1
    if value < mask:
        return value, at
    shift = 0
    while True:
        byte = block[at]
        at += 1
        value += (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, at
