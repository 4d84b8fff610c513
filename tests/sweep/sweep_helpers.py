"""The ``frhc`` command line as the sweep tests call it, the processes and listening sockets
a command started (Linux ``/proc``), and a task whose loading ends the worker process."""

from __future__ import annotations

import ipaddress
import os
import subprocess
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any


def frhc(*args: str) -> subprocess.CompletedProcess[str]:
    """Run ``frhc ARGS...`` in a fresh interpreter; returns its exit code, stdout and stderr."""
    return subprocess.run(
        [sys.executable, "-m", "app.cli", *args], capture_output=True, text=True, timeout=300, check=False
    )


def descendants(root: int) -> dict[int, str]:
    """Every live process below ``root`` (children, their children...): pid -> name, from /proc."""
    children: dict[int, list[int]] = {}
    names: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        # "pid (name) state ppid ...": the name may hold spaces and parentheses.
        name, after = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :].split()
        names[int(entry.name)] = name
        children.setdefault(int(after[1]), []).append(int(entry.name))
    found: dict[int, str] = {}
    todo = [root]
    while todo:
        for pid in children.get(todo.pop(), []):
            found[pid] = names[pid]
            todo.append(pid)
    return found


def tcp_listeners(pids: Iterable[int]) -> list[tuple[int, ipaddress.IPv4Address | ipaddress.IPv6Address, int]]:
    """The listening TCP sockets of ``pids``: (pid, address, port), from /proc/net/tcp and tcp6."""
    inodes: dict[str, int] = {}
    for pid in pids:
        try:
            fds = list(Path(f"/proc/{pid}/fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                link = os.readlink(fd)
            except OSError:
                continue
            if link.startswith("socket:["):
                inodes[link[8:-1]] = pid
    found = []
    for table in ("tcp", "tcp6"):
        for line in Path(f"/proc/net/{table}").read_text().splitlines()[1:]:
            f = line.split()
            if f[3] != "0A" or f[9] not in inodes:  # 0A: LISTEN
                continue
            hex_addr, hex_port = f[1].split(":")
            # The kernel prints each 32-bit word of the address in host (little-endian) order.
            raw = b"".join(bytes.fromhex(hex_addr[i : i + 8])[::-1] for i in range(0, len(hex_addr), 8))
            found.append((inodes[f[9]], ipaddress.ip_address(raw), int(hex_port, 16)))
    return found


def is_loopback(address: ipaddress.IPv4Address | ipaddress.IPv6Address) -> bool:
    """127.0.0.0/8, ::1, or 127.x as an IPv4-mapped IPv6 address (a dual-stack socket's)."""
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        return address.ipv4_mapped.is_loopback
    return address.is_loopback


def _load_or_die(marks: str, deaths: int, task: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """``task``, unless one of the first ``deaths`` loads in any process: that one ends its process.

    Each load claims the next free mark file ``death-<i>`` in ``marks`` (created exclusively, so
    two processes never claim the same one); a load that claims one exits at once, before the
    worker runs any point, as a worker does that dies while it starts on a loaded machine.
    """
    for i in range(deaths):
        try:
            os.close(os.open(os.path.join(marks, f"death-{i}"), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            continue
        os._exit(3)
    return task


class DiesLoading:
    """A task whose first ``deaths`` unpicklings (one per engine worker it is handed to) end the
    worker's process (:func:`_load_or_die`); the others load ``task`` itself.

    Pickle it by value (``ray.cloudpickle.register_pickle_by_value`` on this module): Ray's
    workers cannot import the tests' helper modules.
    """

    def __init__(self, marks: Path, deaths: int, task: Callable[[Any], Any]) -> None:
        self.marks, self.deaths, self.task = str(marks), deaths, task

    def __call__(self, payload: Any) -> Any:
        return self.task(payload)

    def __reduce__(self) -> tuple[Callable[..., Any], tuple[str, int, Callable[[Any], Any]]]:
        return _load_or_die, (self.marks, self.deaths, self.task)
