"""The access token in front of a demo served beyond loopback (a real gate and a real viser server)."""

from __future__ import annotations

import http.client
import time

import pytest
from web_helpers import listening_tcp_ports

from app.web.access import TOKEN_NAME, token_in_request
from app.web.headless import free_port
from app.web.launch import start_demo


@pytest.mark.parametrize(
    ("head", "ok"),
    [
        (b"GET /?frhc_token=abc HTTP/1.1\r\nHost: x\r\n\r\n", True),
        (b"GET /assets/x.js HTTP/1.1\r\nCookie: a=1; frhc_token=abc\r\n\r\n", True),
        (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", False),
        (b"GET /?frhc_token=abd HTTP/1.1\r\n\r\n", False),
        (b"GET /?frhc_token= HTTP/1.1\r\n\r\n", False),
        (b"garbage\r\n\r\n", False),
    ],
)
def test_token_is_found_in_query_or_cookie(head: bytes, ok: bool) -> None:
    assert token_in_request(head, "abc") is ok


def _get(port: int, path: str, headers: dict[str, str] | None = None) -> http.client.HTTPResponse:
    connection = http.client.HTTPConnection("127.0.0.2", port, timeout=30)
    connection.request("GET", path, headers=headers or {})
    return connection.getresponse()


def test_non_loopback_host_requires_the_token() -> None:
    """Served on 0.0.0.0 the page answers only with the token (URL, then the cookie it sets)."""
    before = listening_tcp_ports()
    app = start_demo("probe", "kraft", host="0.0.0.0", port=free_port())
    assert app.gate is not None
    try:
        assert f"{TOKEN_NAME}={app.gate.token}" in app.url
        port = app.gate.port
        end = time.monotonic() + 30
        while True:
            try:
                refused = _get(port, "/")
                break
            except OSError:
                assert time.monotonic() < end
                time.sleep(0.2)
        assert refused.status == 403
        assert _get(port, f"/?{TOKEN_NAME}=wrong").status == 403
        ok = _get(port, f"/?{TOKEN_NAME}={app.gate.token}")
        assert ok.status == 200
        assert "html" in ok.read(200).decode("latin-1").lower()
        cookie = ok.getheader("Set-Cookie")
        assert cookie is not None
        assert cookie.startswith(f"{TOKEN_NAME}={app.gate.token}")
        assert _get(port, "/", {"Cookie": cookie.split(";")[0]}).status == 200
        # Nothing else of the demo listens on TCP: viser is on a unix socket in a folder only
        # this user may enter, so no plain request reaches it around the gate.
        assert listening_tcp_ports() - before == {port}
        assert app.gate.target.exists()
        assert app.gate.target.parent.stat().st_mode & 0o777 == 0o700
    finally:
        app.close()
        app.server.stop()
    assert not app.gate.target.parent.exists()
