"""One WebSocket connection driven in the calling thread: the transport of the device link.

The servo loop exchanges one small text message each way per period with the device
(:mod:`app.device.haply`). websockets' sync API reads every connection in a background thread and
hands each message to the caller through a queue: one extra thread wake-up per message, on each
side. On a loaded 2-core machine each wake-up can wait a scheduler slice, and the round trip's
p99 was 1.25 ms (``frhc bench device``, issue 29). :class:`WsLink` keeps the same wire protocol
(RFC 6455 through websockets' Sans-I/O :class:`~websockets.client.ClientProtocol` and
:class:`~websockets.server.ServerProtocol`, so a real Haply Inverse Service is reached as before)
on a blocking socket with ``TCP_NODELAY`` read by the thread that waits for the message: the
kernel wakes that thread directly when the bytes arrive.

Not thread-safe: one thread uses a link at a time (a server may close it from another thread with
:meth:`WsLink.abort`, as a pulled cable would).
"""

from __future__ import annotations

import contextlib
import os
import socket
import time
from collections import deque

from websockets.client import ClientProtocol
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidMessage
from websockets.frames import Frame, Opcode
from websockets.http11 import Request, Response
from websockets.protocol import Protocol, State
from websockets.server import ServerProtocol
from websockets.uri import parse_uri

#: Bytes read from the socket at a time (a device message is a few hundred bytes).
READ_SIZE = 65536


class WsLink:
    """An open WebSocket connection on ``sock`` with the Sans-I/O ``protocol`` (after its handshake).

    Use :meth:`connect` (client) or :meth:`accept` (server) to make one.
    """

    def __init__(self, sock: socket.socket, protocol: Protocol) -> None:
        self.sock = sock
        self.protocol = protocol
        self.remote_address = sock.getpeername()
        self._messages: deque[str] = deque()
        self._fragments: list[bytes] = []  # a message's frames so far
        self._closed = False

    @staticmethod
    def connect(url: str, timeout: float) -> WsLink:
        """Open a connection to ``url`` (``ws://host:port/path``) within ``timeout`` seconds.

        Raises:
            InvalidURI: ``url`` is not a ``ws://`` address.
            InvalidHandshake: the server answered, but not as a WebSocket server.
            OSError, TimeoutError: no server there, or no answer in time.
        """
        uri = parse_uri(url)
        sock = socket.create_connection((uri.host, uri.port), timeout=timeout)
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            protocol = ClientProtocol(uri)
            protocol.send_request(protocol.connect())
            link = WsLink(sock, protocol)
            link._handshake(Response, timeout)
        except BaseException:
            sock.close()
            raise
        return link

    @staticmethod
    def accept(sock: socket.socket, timeout: float) -> WsLink:
        """Answer the handshake of the client connected on ``sock`` within ``timeout`` seconds.

        Raises:
            InvalidHandshake: the client did not open a WebSocket.
            OSError, TimeoutError: the client went away or said nothing in time.
        """
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            protocol = ServerProtocol()
            link = WsLink(sock, protocol)
            request = link._handshake(Request, timeout)
            assert isinstance(request, Request)
            protocol.send_response(protocol.accept(request))
            link._flush()
            if protocol.handshake_exc is not None:
                raise protocol.handshake_exc
        except BaseException:
            sock.close()
            raise
        return link

    def _handshake(self, kind: type[Request] | type[Response], timeout: float) -> Request | Response:
        """Send what the protocol queued and read until the other side's ``kind`` arrives."""
        self._flush()
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                raise TimeoutError("no WebSocket handshake in time")
            self.sock.settimeout(remaining)
            data = self.sock.recv(READ_SIZE)
            if not data:
                raise InvalidMessage("connection closed during the WebSocket handshake")
            self.protocol.receive_data(data)
            found = None
            for event in self.protocol.events_received():
                if isinstance(event, kind):
                    found = event
                elif isinstance(event, Frame):  # a message right behind the handshake
                    self._take(event)
            exc = self.protocol.handshake_exc
            if exc is not None:
                raise exc if isinstance(exc, InvalidHandshake) else InvalidMessage(str(exc))
            if found is not None:
                return found

    def send(self, text: str) -> None:
        """Send one text message.

        Raises:
            ConnectionClosed: the connection is closed.
        """
        if self._closed or self.protocol.state is not State.OPEN:
            raise self._closed_exc()
        self.protocol.send_text(text.encode())
        try:
            self._flush()
        except OSError:
            raise self._lost() from None

    def recv(self, timeout: float, spin: float = 0.0, yield_cpu: bool = False) -> str:
        """The next text message, waiting up to ``timeout`` seconds (0: only what has arrived).

        For the first ``spin`` seconds of the wait the socket is polled without blocking, so the
        thread keeps its CPU: a blocked thread is woken when the bytes arrive, and on a loaded
        machine a thread at ordinary priority may then wait a scheduler slice (milliseconds) for a
        CPU (and an idle virtual CPU takes its time to wake). With ``yield_cpu`` each poll yields
        the CPU to a thread of the same real-time priority waiting for it (a device server on
        this CPU); only for a real-time thread: under the ordinary policy a yield hands the CPU
        to any other task. The rest of the wait, if any, blocks.

        Raises:
            TimeoutError: none arrived in time.
            ConnectionClosed: the connection closed (a close frame, or the socket's end).
        """
        messages = self._messages
        sock = self.sock
        clock = time.monotonic
        now = clock()
        deadline = now + timeout
        spin_until = now + min(spin, timeout)
        while not messages:
            if self._closed:  # after the messages that came before the close
                raise self._closed_exc()
            now = clock()
            spinning = now < spin_until
            remaining = deadline - now
            sock.settimeout(0.0 if spinning or remaining <= 0.0 else remaining)
            try:
                data = sock.recv(READ_SIZE)
            except (TimeoutError, BlockingIOError):
                if spinning:
                    if yield_cpu:
                        os.sched_yield()
                    continue
                raise TimeoutError("no message in time") from None
            except OSError:
                raise self._lost() from None
            self._receive(data)
        return messages.popleft()

    def recv_latest(self, timeout: float, spin: float = 0.0, yield_cpu: bool = False) -> str:
        """The newest message: the next one (waiting up to ``timeout`` s, polling for the first
        ``spin`` s: :meth:`recv`), or a later one already arrived behind it (a late message and
        its successor: only the successor counts)."""
        text = self.recv(timeout, spin, yield_cpu)
        while True:
            try:
                text = self.recv(0.0)
            except TimeoutError:
                return text

    def close(self, code: int = 1000, reason: str = "") -> None:
        """Send a close frame (best effort) and close the socket."""
        if not self._closed and self.protocol.state is State.OPEN:
            self.protocol.send_close(code, reason)
            with contextlib.suppress(OSError):
                self._flush()
        self.abort()

    def abort(self) -> None:
        """Close the socket without a close frame (the other side sees the connection drop)."""
        self._closed = True
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()

    def _receive(self, data: bytes) -> None:
        protocol = self.protocol
        if data:
            protocol.receive_data(data)
        else:
            protocol.receive_eof()
        for event in protocol.events_received():
            if isinstance(event, Frame):
                self._take(event)
        with contextlib.suppress(OSError):
            self._flush()  # pongs and the close handshake's reply
        if not data or protocol.close_rcvd is not None or protocol.state is State.CLOSED:
            self.abort()

    def _take(self, frame: Frame) -> None:
        """Collect data frames into messages (control frames are the protocol's own business)."""
        if frame.opcode in (Opcode.TEXT, Opcode.BINARY):
            self._fragments = [bytes(frame.data)]
        elif frame.opcode is Opcode.CONT:
            self._fragments.append(bytes(frame.data))
        else:
            return
        if frame.fin:
            # A binary message that is not UTF-8 must not end the connection with a decoding
            # error: its bad bytes become U+FFFD, and the reader refuses it as it does any garbage.
            self._messages.append(b"".join(self._fragments).decode(errors="replace"))
            self._fragments = []

    def _flush(self) -> None:
        for chunk in self.protocol.data_to_send():
            if chunk:
                self.sock.sendall(chunk)
            else:  # the protocol is done sending: half-close
                self.sock.shutdown(socket.SHUT_WR)

    def _lost(self) -> ConnectionClosed:
        """Close the socket; the exception that says why."""
        exc = self._closed_exc()
        self.abort()
        return exc

    def _closed_exc(self) -> ConnectionClosed:
        p = self.protocol
        rcvd, sent = p.close_rcvd, p.close_sent
        return ConnectionClosed(rcvd, sent, p.close_rcvd_then_sent if rcvd is not None and sent is not None else None)
