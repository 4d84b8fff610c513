"""Headless scripted sessions: the servo loop, operator scripts, logs, metrics, the experiment.

The names below are imported on first use (PEP 562): ``import app.session.spec`` (a session
file's fields) or ``app.session.log`` must not build the servo loop's modules (numba kernels,
the slave), which the browser demo imports only after its first panel is up.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from app.session.loop import LoopConfig, ServoLoop
    from app.session.run import SessionResult, run_session
    from app.session.spec import Session, load_session

__all__ = ["LoopConfig", "ServoLoop", "Session", "SessionResult", "load_session", "run_session"]

#: Where each public name lives.
_HOME = {
    "LoopConfig": "app.session.loop",
    "ServoLoop": "app.session.loop",
    "SessionResult": "app.session.run",
    "run_session": "app.session.run",
    "Session": "app.session.spec",
    "load_session": "app.session.spec",
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'app.session' has no attribute {name!r}")
    return getattr(importlib.import_module(home), name)
