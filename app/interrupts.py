"""Holding SIGINT and SIGTERM while third-party code that cannot be interrupted safely runs.

Shared by the command line (:mod:`app.cli`: a command's imports) and the web demo's launch
(:mod:`app.web.launch`: the demo's build with the page already served).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM until the block ends, then deliver them to the handlers in place
    before (in the main thread only: elsewhere Python cannot set handlers, and does not run them).

    Some third-party imports catch ``BaseException`` (trimesh's guards for optional dependencies):
    a ``KeyboardInterrupt`` raised inside them is swallowed and the program goes on after the
    signal (the web demo served on; ``frhc run`` ran its whole session). Others turn it into
    another error (MuJoCo's extension: ``ImportError: initialization failed``). Held, the signal
    arrives once the block is done, where it unwinds as Ctrl-C should.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous = {s: signal.signal(s, lambda signum, _: held.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for signum in dict.fromkeys(held):
            signal.raise_signal(signum)
