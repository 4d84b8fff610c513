"""Command-line arguments added with the safety envelope and the web tasks: refused in one line, exit 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

FRHC = [sys.executable, "-m", "app.cli"]


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["run", "probe_rate", "--flush-interval", "0"], "--flush-interval: must be between"),
        (["run", "probe_rate", "--flush-interval", "soon"], "--flush-interval: not a number"),
        (["web", "--replay", "{tmp}/no-log-here"], "not a replayable log"),
        (["web", "--rate", "50"], "--rate: expected a servo rate in Hz: servo_rate: must be"),
        (["run", "probe_rate", "--rate", "fast"], "--rate: expected a servo rate in Hz"),
        (["web", "--spin", "0.95"], "--spin: expected a share of the period from 0 to 0.8, got '0.95'"),
        (["web", "--spin", "most"], "--spin: expected a share of the period from 0 to 0.8, got 'most'"),
        (["bench", "stability", "--window", "-1"], "--window: must be between 0.001 and 3600 s, got -1"),
        (["bench", "stability", "--window", "long"], "--window: not a number"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(tmp_path: Path, args: list[str], expected: str) -> None:
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    done = subprocess.run([*FRHC, *argv], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert "Traceback" not in done.stderr
    assert expected in lines[-1]
    assert not (tmp_path / "runs").exists()  # nothing ran
