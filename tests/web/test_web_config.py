"""The web entry point refuses bad input before any server starts, and serves for a bounded time."""

from __future__ import annotations

import pytest

from app.errors import ConfigError
from app.web import server
from app.web.headless import free_port


@pytest.fixture
def no_server(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("a server was started")

    monkeypatch.setattr(server.viser, "ViserServer", refuse)


@pytest.mark.usefixtures("no_server")
@pytest.mark.parametrize(
    ("scene", "device", "session", "field"),
    [
        ("no_such_scene", "kraft", None, "<file>"),
        ("probe", "no_such_device", None, "<file>"),
        ("probe", "kraft", "no_such_session", None),
    ],
)
def test_unknown_names_raise_config_error_before_serving(
    scene: str, device: str, session: str | None, field: str | None
) -> None:
    with pytest.raises(ConfigError) as info:
        server.serve(scene, device, session=session, open_seconds=0.0)
    if field is not None:
        assert info.value.field == field


def test_loopback_detection() -> None:
    assert server.is_loopback("127.0.0.1")
    assert server.is_loopback("localhost")
    assert server.is_loopback("::1")
    assert not server.is_loopback("0.0.0.0")
    assert not server.is_loopback("192.168.1.10")


def test_serve_prints_url_and_returns(capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    server.serve("probe", "kraft", port=port, open_seconds=0.5)
    assert f"http://127.0.0.1:{port}/" in capsys.readouterr().out
