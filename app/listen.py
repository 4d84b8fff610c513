"""Listening on a TCP address, for the servers the command line starts (``frhc web``,
``frhc device serve``): one rule for a port that cannot be had (:class:`~app.errors.ListenError`)."""

from __future__ import annotations

import socket

from app.errors import ListenError


def listening_socket(host: str, port: int) -> socket.socket:
    """A TCP socket listening on ``host:port`` (port 0: any free one; a host name: its first
    address, IPv4 or IPv6).

    Raises:
        ListenError: the port is busy, the host is not this machine's or does not resolve, or the
            port needs privileges.
    """
    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        return socket.create_server((host, port), family=family)
    except OSError as exc:
        raise ListenError(host, port, exc) from None


def check_listenable(host: str, port: int) -> None:
    """Raise :class:`~app.errors.ListenError` unless ``host:port`` can be listened on now (for a
    server that binds by itself, such as viser, which would otherwise move on to the next port)."""
    listening_socket(host, port).close()


def url_authority(host: str, port: int) -> str:
    """``host:port`` as a URL writes it: an IPv6 address in brackets (``[::1]:8080``), a wildcard
    address (``0.0.0.0``, ``::``) as the loopback one a browser on this machine can open."""
    if host in ("0.0.0.0", "::"):
        host = "127.0.0.1"
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
