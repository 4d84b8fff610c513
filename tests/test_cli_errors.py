"""Command-line arguments refused in one line (exit 2); Ctrl-C stops a command in one line (exit 130), keeping its work."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from app.cli import main

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


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["device", "serve", "--port", "-1"], "--port: expected a TCP port from 0 to 65535, got '-1'"),
        (["web", "--port", "99999"], "--port: expected a TCP port from 0 to 65535, got '99999'"),
        (["web", "--host", "no-such-host.invalid"], "--host: cannot resolve 'no-such-host.invalid'"),
        (["zwidth", "--rate", "0"], "--rate: expected a servo rate in Hz: servo_rate: must be"),
        (["zwidth", "--rate", "nan"], "--rate: expected a servo rate in Hz: servo_rate: must not be NaN"),
        (["zwidth", "--delay-ms", "-1"], "--delay-ms: expected a one-way delay in ms: delay_ms: must be non-negative"),
        (["zwidth", "--delay-ms", "soon"], "--delay-ms: expected a one-way delay in ms: not a number: 'soon'"),
        (["zwidth", "--renderers", ""], "--renderers: expected at least one value, got ''"),
        (["zwidth", "--dampings", ","], "--dampings: expected at least one value, got ','"),
        (["experiment", "--operators", "0"], "--operators: must be between 1 and 10000000, got 0"),
        (["run", "probe_rate", "--out", ""], "--out: expected a folder name, got an empty one"),
        (["sweep", "probe_stiffness", "--out", " "], "--out: expected a folder name, got an empty one"),
    ],
)
def test_arguments_out_of_range_are_refused_before_anything_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], args: list[str], expected: str
) -> None:
    """Found running every command with bad arguments: these ran (zwidth on a 0 Hz rate, every edge
    failing; an experiment of no operator; a run written into the working folder) or ended in a
    traceback (a port outside 0-65535, an address that does not resolve). Parsed in this process:
    anything but argparse's refusal escapes and fails the test."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert expected in err[-1]
    assert list(tmp_path.iterdir()) == []


def _interrupt_when(proc: subprocess.Popen[str], ready: Callable[[], bool]) -> tuple[str, str]:
    """SIGINT to ``proc`` once ``ready()`` (polled); its output once it has exited."""
    deadline = time.monotonic() + 120
    while not ready():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=60)


@pytest.fixture
def sigint_heard() -> Iterator[None]:
    """Children started in the test hear SIGINT, as from a terminal: a command run in the
    background by a shell without job control (``nohup make test &``) inherits SIGINT ignored,
    and a Python started so never raises KeyboardInterrupt, so the Ctrl-C tests would test the
    harness. Only an ignored signal is inherited across exec, so un-ignoring it here is enough."""
    before = signal.getsignal(signal.SIGINT)
    if before is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


@pytest.mark.usefixtures("sigint_heard")
def test_ctrl_c_during_a_run_keeps_its_log_and_says_so(tmp_path: Path) -> None:
    """SIGINT once the first part of the log is on disk (a paced run, 5 s long): exit 130, one line
    naming the log and how far it goes, no traceback; the log holds those ticks."""
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [*FRHC, "run", "probe_rate", "--out", str(out), "--realtime", "--no-plots"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )
    _, stderr = _interrupt_when(proc, lambda: any((out / "log").glob("part-*.parquet")))
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    last = stderr.strip().splitlines()[-1]
    t = pq.read_table(out / "log", columns=["t"]).column("t").to_pylist()
    assert 0.0 < t[-1] < 4.0
    assert (
        last
        == f"interrupted: the log of the first {t[-1]:.3f} s is in {out / 'log'}/ (no summary; frhc web --replay {out} shows it)"
    )
    assert not (out / "summary.json").exists()


# Sends SIGINT to its own process when ``networkx`` is first imported: inside trimesh's guard
# ``try: from networkx import Graph / except BaseException`` (trimesh/base.py), as a Ctrl-C in the
# first second of ``frhc run`` lands.
CTRL_C_IN_TRIMESH = """
import os, signal, sys
class CtrlC:
    def find_spec(self, name, path=None, target=None):
        if name == "networkx":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None
sys.meta_path.insert(0, CtrlC())
from app.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.usefixtures("sigint_heard")
def test_ctrl_c_inside_a_third_party_import_guard_still_stops_the_command(tmp_path: Path) -> None:
    """Before, the KeyboardInterrupt was swallowed by trimesh's guard and the whole session ran
    (exit 0); the command's imports now hold the signal and deliver it after them."""
    done = subprocess.run(
        [sys.executable, "-c", CTRL_C_IN_TRIMESH, "run", "probe_rate", "--out", "r", "--no-plots"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert done.returncode == 130, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "r").exists()
