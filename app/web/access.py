"""An access token in front of the demo when it is served beyond this machine.

Whoever reaches the demo's port can drive the device, so ``frhc web --host`` with a non-loopback
address serves through :class:`TokenGate`: the gate, on the public address, relays a connection
to viser only if the connection's first request carries the token, as ``?frhc_token=...`` in the
URL (the printed URL has it) or as the cookie the gate sets on that first visit (so the page's own
asset and websocket requests, which do not repeat the query, pass too). Anything else gets
``403 Forbidden``. ``--insecure`` skips the gate.

viser itself then listens on no TCP port at all but on a unix socket in a fresh folder only this
user may enter (:func:`viser_on_unix_socket`): an inner loopback port would let any local process
(any user's) drive the demo without the token, around the gate.

Hand-written rather than a reverse-proxy library: it relays bytes after one header check (about
a hundred lines of asyncio), and viser has no authentication hook of its own.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import secrets
import shutil
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from http.cookies import SimpleCookie
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import websockets.asyncio.server

from app.errors import ListenError

#: Name of the query parameter and of the cookie that carry the token.
TOKEN_NAME = "frhc_token"
#: Longest request head read before the check (bytes).
MAX_HEAD = 64 * 1024
#: Seconds a client may take to send its request head.
HEAD_TIMEOUT = 10.0

_FORBIDDEN = (
    b"HTTP/1.1 403 Forbidden\r\nContent-Type: text/plain; charset=utf-8\r\nConnection: close\r\n"
    b"Content-Length: 57\r\n\r\nForbidden: open the URL with the token frhc web printed.\n"
)


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) only reaches this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    """A fresh random token (URL-safe, 128 bits)."""
    return secrets.token_urlsafe(16)


def token_in_request(head: bytes, token: str) -> bool:
    """Whether the HTTP request head ``head`` carries ``token`` in its query or its cookie."""
    try:
        lines = head.decode("latin-1").split("\r\n")
        _, target, _ = lines[0].split(" ", 2)
    except ValueError:
        return False
    offered = parse_qs(urlsplit(target).query).get(TOKEN_NAME, [])
    for line in lines[1:]:
        name, _, value = line.partition(":")
        if name.strip().lower() == "cookie":
            cookie: SimpleCookie = SimpleCookie()
            cookie.load(value.strip())
            if TOKEN_NAME in cookie:
                offered.append(cookie[TOKEN_NAME].value)
    return any(hmac.compare_digest(o.encode(), token.encode()) for o in offered)


def _with_cookie(head: bytes, token: str) -> bytes:
    """The response head ``head`` with the token cookie set (for the page's later requests)."""
    end = head.index(b"\r\n")
    cookie = f"\r\nSet-Cookie: {TOKEN_NAME}={token}; Path=/; HttpOnly; SameSite=Strict".encode()
    return head[:end] + cookie + head[end:]


@contextmanager
def viser_on_unix_socket(path: Path) -> Iterator[None]:
    """A viser server constructed inside the block listens on the unix socket ``path``, not TCP.

    viser has no option for it: its server thread calls ``websockets.asyncio.server.serve(handler,
    host, port, **options)`` before its constructor returns; inside the block that call is
    ``unix_serve(handler, path, **options)``, with viser's own options (its HTTP handler for the
    page, its subprotocols). Only that constructor may run inside the block.
    """
    original = websockets.asyncio.server.serve

    def on_socket(handler: Any, host: object, port: object, **options: Any) -> Any:
        return original(handler, unix=True, path=str(path), **options)  # what unix_serve does

    websockets.asyncio.server.serve = on_socket  # type: ignore[assignment, misc]
    try:
        yield
    finally:
        websockets.asyncio.server.serve = original  # type: ignore[misc]


class TokenGate:
    """Relays ``host:port`` to the viser server on the unix socket ``target`` for token holders.

    Args:
        host, port: Public address to listen on (port 0: any free one, see :attr:`port`).
        target: viser's unix socket (:func:`viser_on_unix_socket`), in a folder of its own that
            the gate removes when it closes.
        token: The access token.

    Raises:
        ListenError: ``host:port`` cannot be listened on.
    """

    def __init__(self, host: str, port: int, target: Path, token: str) -> None:
        self.token = token
        self.target = target
        self._loop = asyncio.new_event_loop()
        try:
            self._server = self._loop.run_until_complete(asyncio.start_server(self._serve, host, port))
        except OSError as exc:
            self._loop.close()
            raise ListenError(host, port, exc) from None
        self.port: int = self._server.sockets[0].getsockname()[1]
        self._thread = threading.Thread(target=self._loop.run_forever, name="token-gate", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop listening (open relays end with their connections)."""

        async def shutdown() -> None:
            self._server.close()
            await self._server.wait_closed()

        asyncio.run_coroutine_threadsafe(shutdown(), self._loop).result(timeout=5.0)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5.0)
        shutil.rmtree(self.target.parent, ignore_errors=True)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT)
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError, ConnectionError):
            writer.close()
            return
        if len(head) > MAX_HEAD or not token_in_request(head, self.token):
            writer.write(_FORBIDDEN)
            await writer.drain()
            writer.close()
            return
        try:
            up_reader, up_writer = await asyncio.open_unix_connection(self.target)
        except OSError:
            writer.close()
            return
        up_writer.write(head)
        try:
            first = await up_reader.readuntil(b"\r\n\r\n")
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
            writer.close()
            up_writer.close()
            return
        writer.write(_with_cookie(first, self.token))
        await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except ConnectionError:
        pass
    finally:
        writer.close()
