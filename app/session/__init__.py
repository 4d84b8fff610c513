"""Headless scripted sessions: the servo loop, operator scripts, logs, metrics, the experiment."""

from app.session.loop import LoopConfig, ServoLoop
from app.session.run import SessionResult, run_session
from app.session.spec import Session, load_session

__all__ = ["LoopConfig", "ServoLoop", "Session", "SessionResult", "load_session", "run_session"]
