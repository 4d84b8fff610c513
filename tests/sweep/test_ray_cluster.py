"""The sweep engine against real Ray processes: a killed sweep, and a cluster head with token
authentication, both on loopback.

Each test starts Ray (a few seconds on an idle machine, up to a minute on a loaded one), so
there are few of them and each checks several things at once.
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from sweep_helpers import descendants, is_loopback, tcp_listeners

pytest.importorskip("ray")

#: Ray's own environment, dropped from the commands' environments here: each test sets what it means.
RAY_VARIABLES = ("RAY_ADDRESS", "RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")


def frhc_env(**ray: str) -> dict[str, str]:
    """This process's environment without Ray's variables, plus ``ray``. (``HOME`` stays: the
    numba cache is under it, and a worker without it compiles every kernel again, minutes.)"""
    env = {k: v for k, v in os.environ.items() if k not in RAY_VARIABLES}
    return {**env, **ray}


def frhc_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "app.cli", *args]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_until_gone(pids: dict[int, str], seconds: float) -> dict[int, str]:
    """The processes of ``pids`` still alive (not zombies) after up to ``seconds``."""
    end = time.monotonic() + seconds
    while True:
        alive = {}
        for pid, name in pids.items():
            try:
                state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if state != "Z":
                alive[pid] = name
        if not alive or time.monotonic() > end:
            return alive
        time.sleep(0.2)


def test_a_killed_sweep_ends_its_ray_processes_and_keeps_its_rows(tmp_path: Path) -> None:
    """``frhc sweep`` on a local Ray instance, SIGTERM once rows are on disk: while it runs,
    every Ray process it started listens on loopback only; then it exits 143 with one line that
    names the rows kept, those rows are in the parts, and none of its processes is left."""
    sweep = tmp_path / "long.toml"
    sweep.write_text(
        'base = "probe_rate"\n[[vary]]\nfield = "scene.objects.surface.stiffness"\nrange = [1000.0, 5000.0]\n'
        'steps = 200\n[[vary]]\nfield = "duration"\nvalues = [0.3]\n'
    )
    out = tmp_path / "out"
    command = frhc_command("sweep", str(sweep), "--out", str(out), "--workers", "2")
    proc = subprocess.Popen(command, env=frhc_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started: dict[int, str] = {}
    try:
        deadline = time.monotonic() + 300
        while not list((out / "parts").glob("part-*.parquet")):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no row after 300 s"
            started.update(descendants(proc.pid))
            time.sleep(0.2)
        started.update(descendants(proc.pid))
        assert {"raylet", "gcs_server"} <= set(started.values()), started
        listening = tcp_listeners([proc.pid, *started])
        assert len(listening) >= 4  # the command's own core worker, the GCS, the raylet's, each worker's
        assert all(is_loopback(address) for _, address, _ in listening), listening
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "Traceback" not in stderr
    last = stderr.strip().splitlines()[-1]
    assert last.startswith("interrupted: "), last
    assert f"of 200 points are in {out / 'parts'}" in last, last
    kept = int(last.removeprefix("interrupted: ").split()[0])
    assert 0 < kept < 200
    assert pq.read_table(out / "parts").num_rows == kept
    assert not wait_until_gone(started, 30.0)


@contextmanager
def loopback_head(home: Path) -> Iterator[tuple[str, str, subprocess.Popen[bytes]]]:
    """``ray start --head`` on 127.0.0.1 with token authentication (its own token and temp
    folder, its log in ``home``): yields its address, token and ``ray start`` process (the leader
    of the head's own process group); stopped (SIGTERM, as ``--block`` expects) at the end."""
    # Ray's session folder holds unix sockets, whose paths must stay under ~107 bytes.
    temp = Path(tempfile.mkdtemp(prefix="frhc-ray-", dir="/tmp"))
    token = secrets.token_hex(16)
    port = free_port()
    env = frhc_env(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token, RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0")
    ray = Path(sys.executable).with_name("ray")
    command = [str(ray), "start", "--head", "--block", f"--port={port}", "--node-ip-address=127.0.0.1"]
    command += ["--num-cpus=1", "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp}"]
    log = (home / "head.log").open("w")
    head = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    started: dict[int, str] = {}
    try:
        # Up once it says so: its GCS port opens before the raylet has registered, which may
        # still fail (Ray gives it 30 s).
        deadline = time.monotonic() + 180
        while "Ray runtime started." not in (home / "head.log").read_text():
            assert head.poll() is None, (home / "head.log").read_text()[-3000:]
            assert time.monotonic() < deadline, "the head did not start within 180 s"
            time.sleep(0.2)
        started = descendants(head.pid)
        yield f"127.0.0.1:{port}", token, head
    finally:
        started.update(descendants(head.pid))
        if head.poll() is None:
            head.send_signal(signal.SIGTERM)
        try:
            head.wait(60)
        finally:
            if wait_until_gone({head.pid: "ray", **started}, 10.0):
                with suppress(ProcessLookupError):
                    os.killpg(head.pid, signal.SIGKILL)  # the head's own process group, started here
            log.close()
            shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def ray_head(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """A :func:`loopback_head` for the module's tests: its address and token."""
    with loopback_head(tmp_path_factory.mktemp("head")) as (address, token, _):
        yield address, token


def test_a_sweep_joins_a_loopback_head_with_its_token_and_is_refused_in_one_line_without(
    ray_head: tuple[str, str], tmp_path: Path
) -> None:
    """Three commands at once against the head: with ``RAY_AUTH_MODE=token`` and the token the
    sweep runs on the cluster; without them, and at an address where nothing listens, each is
    one error line naming ``--address``, exit 2, and nothing else: the refused token is found by
    the probe before Ray is asked to join (Ray's join retried it for ~20 s, a warning line a
    second, before saying so)."""
    address, token = ray_head
    sweep = tmp_path / "one.toml"
    sweep.write_text('base = "probe_rate"\n[[vary]]\nfield = "duration"\nvalues = [0.05]\n')
    runs = {
        "token": (address, frhc_env(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token)),
        # An explicit address never turns token authentication on by itself: no token is sent.
        "no token": (address, frhc_env()),
        "nothing there": (f"127.0.0.1:{free_port()}", frhc_env()),
    }
    procs = {
        name: subprocess.Popen(
            frhc_command("sweep", str(sweep), "--address", where, "--workers", "0", "--out", str(tmp_path / name)),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name, (where, env) in runs.items()
    }
    results = {name: proc.communicate(timeout=300) for name, proc in procs.items()}
    codes = {name: proc.returncode for name, proc in procs.items()}

    assert codes["token"] == 0, results["token"][1]
    assert "1 points: 1 run now" in results["token"][0]
    rows = pq.read_table(tmp_path / "token" / "results.parquet").to_pylist()
    assert [r["status"] for r in rows] == ["ok"]

    for name, reason in (("no token", "refused this process's token"), ("nothing there", "no Ray cluster answers")):
        stderr = results[name][1]
        assert codes[name] == 2, stderr
        assert "Traceback" not in stderr
        error = [line for line in stderr.splitlines() if line.startswith("error: ")]
        assert len(error) == 1, stderr
        assert error[0].startswith(f"error: --address {runs[name][0]}: "), error[0]
        assert reason in error[0], error[0]
        assert stderr.strip() == error[0], stderr
    assert "RAY_AUTH_MODE=token" in results["no token"][1]


def test_a_sweep_asking_for_more_workers_than_the_cluster_has_cpus_runs_every_point(
    ray_head: tuple[str, str], tmp_path: Path
) -> None:
    """Three workers asked of the one-CPU head (``--workers`` defaults to this machine's cores,
    not the cluster's): the two Ray cannot place never load the task, and no point waits on them.
    Before, each was given points as it was asked for, and those points waited for ever (an
    experiment with a real head stopped at 6 of 8 runs)."""
    address, token = ray_head
    sweep = tmp_path / "four.toml"
    sweep.write_text('base = "probe_rate"\n[[vary]]\nfield = "duration"\nvalues = [0.05, 0.06, 0.07, 0.08]\n')
    proc = subprocess.run(
        frhc_command("sweep", str(sweep), "--address", address, "--workers", "3", "--out", str(tmp_path / "out")),
        env=frhc_env(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token),
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = pq.read_table(tmp_path / "out" / "results.parquet").to_pylist()
    assert sorted(r["status"] for r in rows) == ["ok"] * 4


def test_a_sweep_whose_head_dies_mid_run_ends_in_one_line_and_keeps_its_rows(tmp_path: Path) -> None:
    """The head's process group killed (SIGKILL) once rows are on disk: the sweep ends within
    seconds with one line naming the head, exit 2, and every row it finished is in the parts.
    Before, nothing was said for 60 s, then Ray ended the process from C++ (exit 1) with the rows
    of the last flush interval lost (a head killed mid-experiment: 13 of 16 finished runs kept)."""
    sweep = tmp_path / "long.toml"
    sweep.write_text(
        'base = "probe_rate"\n[[vary]]\nfield = "scene.objects.surface.stiffness"\nrange = [1000.0, 5000.0]\n'
        'steps = 200\n[[vary]]\nfield = "duration"\nvalues = [0.3]\n'
    )
    out = tmp_path / "out"
    with loopback_head(tmp_path) as (address, token, head):
        command = frhc_command("sweep", str(sweep), "--out", str(out), "--address", address, "--workers", "0")
        env = frhc_env(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token)
        proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 300
            while not list((out / "parts").glob("part-*.parquet")):
                assert proc.poll() is None, proc.communicate()
                assert time.monotonic() < deadline, "no row after 300 s"
                time.sleep(0.2)
            os.killpg(head.pid, signal.SIGKILL)
            killed = time.monotonic()
            _, stderr = proc.communicate(timeout=120)
            took = time.monotonic() - killed
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 2, stderr
    assert "Traceback" not in stderr
    error = [line for line in stderr.splitlines() if line.startswith("error: ")]
    assert len(error) == 1, stderr
    assert f"the Ray cluster's head at {address} stopped answering mid-run" in error[0], error[0]
    assert took < 45, took
    kept = pq.read_table(out / "parts").num_rows
    assert 0 < kept < 200
    # It ended unfinished: no table, only the parts a re-run resumes from.
    assert not (out / "results.parquet").exists()
