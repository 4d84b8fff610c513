"""Command-line arguments refused in one line (exit 2); Ctrl-C stops a command in one line (exit 130), keeping its work."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from app.cli import build_parser, main

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
        (["zwidth", "--dampings", "0,4,0.0"], "--dampings: value 3 repeats an earlier one (0.0) in '0,4,0.0'"),
        (["zwidth", "--renderers", "pc,plain,pc"], "--renderers: value 3 repeats an earlier one ('pc')"),
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


def _options_taking_a_value() -> list[tuple[list[str], str]]:
    """Every option of every ``frhc`` command that takes one value: (the command with its
    positionals filled, the option)."""
    commands: list[tuple[list[str], argparse.ArgumentParser]] = []

    def walk(prefix: list[str], parser: argparse.ArgumentParser) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk([*prefix, name], sub)
                return
        commands.append((prefix, parser))

    walk([], build_parser())
    found = []
    for prefix, parser in commands:
        positionals = [
            "x" for a in parser._actions if not a.option_strings and not isinstance(a, argparse._SubParsersAction)
        ]
        for action in parser._actions:
            if action.option_strings and action.nargs is None and action.type is not None:
                found.append(([*prefix, *positionals], action.option_strings[-1]))
    return found


def _parse(argv: list[str], capsys: pytest.CaptureFixture[str]) -> object:
    try:
        return vars(build_parser().parse_args(argv))
    except SystemExit as exc:
        return exc.code, capsys.readouterr().err.strip().splitlines()[-1]


@pytest.mark.parametrize("value", ["-1", "-1,5", "-1e3", "-.5"])
def test_every_option_takes_a_value_starting_with_a_minus_as_with_an_equals_sign(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--hand -1,5`` was refused as 'expected one argument' (argparse took ``-1,5``, not a plain
    negative number, for an option) while ``--hand=-1,5`` reached the option's own check. Now both
    forms give the same answer, for every option of every command that takes a value."""
    options = _options_taking_a_value()
    assert "--hand" in {o for _, o in options}
    assert len(options) > 20
    for command, option in options:
        if option == "--host":
            continue  # its check resolves the name (a DNS look-up): the same either way, not parsed here
        spaced = _parse([*command, option, value], capsys)
        assert spaced == _parse([*command, f"{option}={value}"], capsys), (command, option)
        if isinstance(spaced, tuple):
            assert "expected one argument" not in spaced[1]


def test_check_of_several_files_says_each_and_exits_2_if_any_failed(capsys: pytest.CaptureFixture[str]) -> None:
    """``frhc check nosuch probe_rate`` stopped at the first bad file: the others were never
    checked and nothing said so. Now one line each, in order, and exit 2."""
    assert main(["check", "nosuch", "probe_rate", "also-nosuch"]) == 2
    out, err = capsys.readouterr()
    assert out.startswith("ok: session probe_rate")
    assert err.splitlines() == [
        "error: nosuch: field '<file>': no such file, device, scene, session or sweep",
        "error: also-nosuch: field '<file>': no such file, device, scene, session or sweep",
    ]


@pytest.mark.parametrize(
    "args",
    [
        ["run", ""],
        ["sweep", " "],
        ["check", "probe_rate", ""],
        ["calibrate", ""],
        ["device", "serve", "--device", ""],
        ["web", "--scene", ""],
        ["web", "--device", ""],
        ["web", "--session", ""],
        ["web", "--replay", ""],
        ["zwidth", "--device", ""],
    ],
)
def test_an_empty_file_name_is_refused_as_empty(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], args: list[str]
) -> None:
    """An empty name meant the working folder, and each command said something else of it ('.: is a
    directory', 'scenes/.toml: no such scene', 'device.toml: no such device'). Parsed in this process."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(": expected a name or a path, got an empty one")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["web"], ["web", "--host", "0.0.0.0"], ["device", "serve"]])
def test_both_servers_refuse_a_busy_port_in_one_line_and_say_so_in_help(
    command: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """``frhc web`` and ``frhc device serve`` started on a taken port (a second copy of either):
    refused, exit 2, one line naming the address and what to do; ``--help`` says so. Before,
    ``frhc web`` served on the next free port (a URL other than the one asked for) and with
    ``--host 0.0.0.0`` failed with a traceback; ``frhc device serve`` refused."""
    import socket

    with socket.create_server(("0.0.0.0", 0)) as holder:
        port = holder.getsockname()[1]
        assert main([*command, "--port", str(port)]) == 2
    host = command[2] if "--host" in command else "127.0.0.1"
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"error: cannot listen on {host}:{port}: Address already in use "
        "(another server holds it: choose another --port, or --port 0 for any free one)"
    ]
    with pytest.raises(SystemExit):
        main([*command, "--help"])
    assert "a busy port is refused, not swapped for another" in " ".join(capsys.readouterr().out.split())
