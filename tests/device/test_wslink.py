"""The device link's WebSocket transport (:mod:`app.device.wslink`) against websockets' own
server and client: the wire protocol is RFC 6455 whichever side is ours, so a real Haply Inverse
Service is reached as before. All over loopback."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import pytest
from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.sync.client import ClientConnection, connect
from websockets.sync.server import Server, ServerConnection, serve

from app.device.haply import DeviceServer
from app.device.wslink import WsLink

WAIT = 5.0  # s: generous bound on a loopback reply on a loaded machine (not a timing assertion)


def _scripted(ws: ServerConnection) -> None:
    """What a server may do to a client: fragment a message, ping, send two at once, close."""
    for text in ws:
        assert isinstance(text, str)  # the client sends text messages only
        if text == "fragments":
            ws.send(["frag", "men", "ted"])  # one message in three frames
        elif text == "ping then two":
            ws.ping(b"x")
            ws.send("first")
            ws.send("second")
        elif text == "bye":
            ws.close(1001, "going away")
        else:
            ws.send(f"echo {text}")


@pytest.fixture
def websockets_server() -> Iterator[Server]:
    server = serve(_scripted, "127.0.0.1", 0, ping_interval=None, compression=None)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server
    server.shutdown()
    thread.join(WAIT)


def test_client_link_talks_to_a_websockets_server(websockets_server: Server) -> None:
    link = WsLink.connect(f"ws://127.0.0.1:{websockets_server.socket.getsockname()[1]}", WAIT)
    link.send("hello")
    assert link.recv(WAIT) == "echo hello"
    link.send("fragments")
    assert link.recv(WAIT) == "fragmented"
    with pytest.raises(TimeoutError):
        link.recv(0.0)  # nothing more was sent
    link.send("ping then two")  # our pong goes out unasked, between the messages
    assert link.recv(WAIT) == "first"
    assert link.recv(WAIT) == "second"
    link.send("after")
    assert link.recv(WAIT) == "echo after"
    link.send("polled")  # polling the socket first: the same messages, the same order
    assert link.recv(WAIT, spin=WAIT) == "echo polled"
    link.send("fragments")
    assert link.recv_latest(WAIT, spin=WAIT) == "fragmented"
    with pytest.raises(TimeoutError):
        link.recv(0.01, spin=1.0)  # the poll ends with the wait: nothing came
    link.send("bye")
    with pytest.raises(ConnectionClosed) as closed:
        link.recv(WAIT)
    assert closed.value.rcvd is not None
    assert closed.value.rcvd.code == 1001
    with pytest.raises(ConnectionClosed):
        link.send("too late")


def test_recv_latest_keeps_only_the_newest_of_the_messages_already_arrived() -> None:
    """Both ends ours. The server sends three states before the client reads: a client a period
    late takes the newest only (on Linux, loopback bytes are in the peer's queue when send returns)."""
    with socket.create_server(("127.0.0.1", 0)) as listener:
        sent = threading.Event()
        served: list[WsLink] = []

        def serve_one() -> None:
            sock, _ = listener.accept()
            link = WsLink.accept(sock, WAIT)
            served.append(link)
            for text in ("old", "older", "newest"):
                link.send(text)
            sent.set()

        thread = threading.Thread(target=serve_one, daemon=True)
        thread.start()
        client = WsLink.connect(f"ws://127.0.0.1:{listener.getsockname()[1]}", WAIT)
        assert sent.wait(WAIT)
        assert client.recv_latest(WAIT) == "newest"
        with pytest.raises(TimeoutError):
            client.recv(0.0)
        served[0].close(1000)
        with pytest.raises(ConnectionClosed) as closed:
            client.recv(WAIT)
        assert closed.value.rcvd is not None
        assert closed.value.rcvd.code == 1000
        thread.join(WAIT)


def test_connect_refuses_a_port_without_a_websocket_server_in_one_exception() -> None:
    with socket.create_server(("127.0.0.1", 0)) as plain:
        port = plain.getsockname()[1]

        def answer_http() -> None:
            conn, _ = plain.accept()
            with conn:
                conn.recv(4096)
                conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\nok")

        thread = threading.Thread(target=answer_http, daemon=True)
        thread.start()
        with pytest.raises(InvalidHandshake):
            WsLink.connect(f"ws://127.0.0.1:{port}", WAIT)
        thread.join(WAIT)
    with pytest.raises(ConnectionRefusedError):  # the port is closed now
        WsLink.connect(f"ws://127.0.0.1:{port}", WAIT)


def test_device_server_refuses_a_second_client_with_code_1013() -> None:
    from app.device.cartesian_sim import SimCartesianDevice
    from app.device.spec import load_device

    server = DeviceServer(SimCartesianDevice(load_device("touch3")), port=0).start()
    try:
        url = f"ws://127.0.0.1:{server.port}"
        with connect(url, ping_interval=None) as first:
            first.recv(timeout=WAIT)  # the first client holds the device
            with connect(url, ping_interval=None) as second, pytest.raises(ConnectionClosed) as refused:
                second.recv(timeout=WAIT)
        assert refused.value.rcvd is not None
        assert refused.value.rcvd.code == 1013
    finally:
        server.shutdown()


def _hold(url: str) -> ClientConnection:
    """A raw client holding the served device at ``url`` (its first state received). The server's
    thread may not yet have seen the last holder's close and refuse with 1013: try again then."""
    deadline = time.monotonic() + WAIT
    while True:
        ws = connect(url, ping_interval=None)
        try:
            ws.recv(timeout=WAIT)
            return ws
        except ConnectionClosed as exc:
            ws.close()
            if exc.rcvd is None or exc.rcvd.code != 1013 or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_a_client_refused_with_1013_tries_again_until_the_device_is_free_and_no_longer() -> None:
    """``frhc run --device ws://...`` connects twice (``served_device`` looks at the served device,
    then the run opens its own); on a loaded machine the server's thread had not yet seen the first
    close, refused the second with 1013 and the run ended in 'another client controls the device'
    (the loopback session test's flaky failure). The client now tries again, for up to
    ``CONNECT_TIMEOUT``, while refused with 1013: it takes the device once the holder leaves
    0.3 s later, and still gives up, naming the holder, when it does not leave."""
    from app.device.cartesian_sim import SimCartesianDevice
    from app.device.haply import CONNECT_TIMEOUT, DeviceUnreachable, HaplyClient
    from app.device.spec import load_device

    server = DeviceServer(SimCartesianDevice(load_device("touch3")), port=0).start()
    try:
        url = f"ws://127.0.0.1:{server.port}"
        with _hold(url) as holder:
            leaves = threading.Timer(0.3, holder.close)
            leaves.start()
            client = HaplyClient(url, period=CONNECT_TIMEOUT)
            leaves.join()
        assert client.served is not None
        assert client.served.device == "touch3"
        client.close()
        # The holder gets the device once the server has seen the client's close.
        with _hold(url), pytest.raises(DeviceUnreachable, match=r"1013 .*another client controls the device"):
            HaplyClient(url, period=CONNECT_TIMEOUT)
    finally:
        server.shutdown()


def test_device_server_listens_on_an_ipv6_host_and_names_it_as_a_url_does() -> None:
    """``frhc device serve --host ::1``: refused before ('Address family for hostname not
    supported': the listener was IPv4 only); now served, named ``ws://[::1]:P`` (brackets, as
    a URL needs them), and a client reaches it at that name."""
    from app.device.cartesian_sim import SimCartesianDevice
    from app.device.haply import HaplyClient
    from app.device.spec import load_device
    from app.listen import url_authority

    if not socket.has_ipv6:
        pytest.skip("no IPv6 on this machine")
    assert url_authority("::1", 80) == "[::1]:80"
    assert url_authority("::", 80) == url_authority("0.0.0.0", 80) == "127.0.0.1:80"
    assert url_authority("localhost", 80) == "localhost:80"
    server = DeviceServer(SimCartesianDevice(load_device("touch3")), host="::1", port=0).start()
    try:
        client = HaplyClient(f"ws://{url_authority('::1', server.port)}", period=WAIT)
        assert client.served is not None
        assert client.served.device == "touch3"
        client.close()
    finally:
        server.shutdown()
