"""Every output-folder and replay-log failure is one line naming the path, exit 2, no traceback.

The conditions are real ones: a regular file where the folder should be (or above it), a folder
under ``/proc`` (nothing can be created there, even by root, who ignores permission bits), a
name longer than the file system allows, and a tiny tmpfs mounted full or read-only (skipped
with the reason when this machine may not mount). The damaged logs are a real log of
``frhc run`` with one part truncated, overwritten or emptied, ``_meta.json`` without its
device, and a part of another column layout.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from app.cli import main
from app.device.spec import load_device
from app.errors import ConfigError
from app.session.log import PART_SECONDS
from app.session.run import run_session
from app.session.spec import load_session
from app.web.replay import LogReplay
from app.world.scene import load_scene

FRHC = [sys.executable, "-m", "app.cli"]

TINY_SWEEP = """\
base = "{base}"
metric = "peak_contact_force_N"

[[vary]]
field = "duration"
values = [0.2, 0.3]
"""


def frhc_fails(args: list[str], cwd: Path) -> str:
    """Run ``frhc args`` in a child process; assert exit 2, no traceback; return the last stderr line."""
    done = subprocess.run([*FRHC, *args], capture_output=True, text=True, timeout=300, cwd=cwd, check=False)
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.stdout == ""
    # A progress bar may precede the error (a disk fills during the run): the error is the last line.
    return done.stderr.rstrip("\n").splitlines()[-1].split("\r")[-1]


def main_fails(args: list[str], cwd: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> str:
    """:func:`frhc_fails` in this process (the same ``main``, without a child's imports): an exception
    other than the one-line error would escape here and fail the test."""
    monkeypatch.chdir(cwd)
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == ""
    return err.rstrip("\n").splitlines()[-1].split("\r")[-1]


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Path]:
    """A folder holding a 64 KiB tmpfs mounted at ``full`` (filled up) and one mounted read-only at ``ro``."""
    mounted = []
    try:
        for name, options in (("full", "size=64k"), ("ro", "ro,size=64k")):
            point = tmp_path / name
            point.mkdir()
            done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(point)], capture_output=True)
            if done.returncode != 0:
                pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
            mounted.append(point)
        _fill(tmp_path / "full" / "filler")
        yield tmp_path
    finally:
        for m in mounted:
            subprocess.run(["umount", str(m)], check=True)


def _fill(path: Path) -> None:
    """Write zeros to ``path`` until its file system is full."""

    def write_forever(fh: BinaryIO) -> None:
        while True:
            fh.write(b"\0" * 4096)

    with path.open("wb", buffering=0) as fh, pytest.raises(OSError, match="No space left"):
        write_forever(fh)


def bad_outs(tmp_path: Path) -> dict[str, tuple[str, str]]:
    """--out value -> (the path the error names, its reason)."""
    (tmp_path / "a_file").write_text("")
    long_name = "n" * 300
    return {
        "a_file": ("a_file", "a file is in the way of the folder"),
        "a_file/sub": ("a_file/sub", "a file is in the way of the folder"),
        "/proc/frhc_out": ("/proc/frhc_out", "No such file or directory"),
        long_name: (long_name, "File name too long"),
    }


def test_run_out_folder_failures_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    for out, (named, reason) in bad_outs(tmp_path).items():
        line = main_fails(["run", "probe_rate", "--no-plots", "--out", out], tmp_path, capsys, monkeypatch)
        assert line == f"error: {named}: field '--out': cannot write the output: {reason}"
    # And once in a child process: nothing but the one line reaches the terminal.
    line = frhc_fails(["run", "probe_rate", "--no-plots", "--out", "a_file/sub"], tmp_path)
    assert line == "error: a_file/sub: field '--out': cannot write the output: a file is in the way of the folder"


def test_sweep_out_folder_failures_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    sweep = tmp_path / "tiny.toml"
    sweep.write_text(TINY_SWEEP.format(base="probe_rate"))
    for out, (named, reason) in bad_outs(tmp_path).items():
        line = main_fails(["sweep", str(sweep), "--workers", "1", "--out", out], tmp_path, capsys, monkeypatch)
        assert line == f"error: {named}: field '--out': cannot write the output: {reason}"


def test_full_and_read_only_file_systems_are_one_line(
    tmpfs: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    sweep = tmpfs / "tiny.toml"
    sweep.write_text(TINY_SWEEP.format(base="probe_rate"))
    commands = {
        "run": ["run", "probe_rate", "--no-plots", "--out"],
        "sweep": ["sweep", str(sweep), "--workers", "1", "--out"],
    }
    for name, command in commands.items():
        line = main_fails([*command, f"full/{name}"], tmpfs, capsys, monkeypatch)
        assert line == f"error: full/{name}: field '--out': cannot write the output: No space left on device"
        line = main_fails([*command, f"ro/{name}"], tmpfs, capsys, monkeypatch)
        assert line == f"error: ro/{name}: field '--out': cannot write the output: Read-only file system"


@pytest.fixture(scope="module")
def log_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real three-part log of a probe session (two parts of PART_SECONDS and a last one)."""
    out = tmp_path_factory.mktemp("run")
    session = load_session("probe_rate").with_changes(duration=2 * PART_SECONDS + 0.2)
    run_session(session, out_dir=out, plots=False)
    assert len(list((out / "log").glob("part-*.parquet"))) == 3
    return out / "log"


def _meta_edits() -> dict[str, tuple[str, object, str, str]]:
    """Damage to ``_meta.json``: ``how`` -> (its key, the new value or None to remove it, the
    field the error names, the start of its reason)."""
    jpl, bowl = load_device("jpl").path, load_scene("bowl").path
    return {
        "meta without device": ("device", None, "device", "missing"),
        # A kraft log said to be jpl's (same 6 joints and columns).
        "meta names another device": (
            "device",
            str(jpl),
            "device",
            f"{jpl} is not the device this log was run on (its device_identity",
        ),
        "device identity not a string": ("device_identity", 7, "device_identity", "expected a string, got 7"),
        # A probe log said to be the bowl's (no moving objects in either).
        "meta names another scene": (
            "scene",
            str(bowl),
            "scene",
            f"{bowl} is not the scene this log was run on (its scene_identity",
        ),
        "scene identity not a string": ("scene_identity", [1], "scene_identity", "expected a string, got [1]"),
    }


def _damage(log: Path, how: str) -> tuple[Path, str, str]:
    """Damage the copy ``log`` as ``how`` says; return (the file named, the field, the reason)."""
    parts = sorted(log.glob("part-*.parquet"))
    meta = log / "_meta.json"
    if how == "last part truncated":
        parts[-1].write_bytes(parts[-1].read_bytes()[:-100])
        return parts[-1], "<file>", "not a readable log part"
    if how == "random bytes":
        parts[1].write_bytes(bytes(range(256)) * 16)
        return parts[1], "<file>", "not a readable log part"
    if how == "0-byte part":
        parts[0].write_bytes(b"")
        return parts[0], "<file>", "not a readable log part"
    edits = _meta_edits()
    if how in edits:
        key, value, field, reason = edits[how]
        data = json.loads(meta.read_text())
        if value is None:
            del data[key]
        else:
            data[key] = value
        meta.write_text(json.dumps(data))
        return meta, field, reason
    if how == "meta not an object":
        meta.write_text("[1, 2]")
        return meta, "<file>", "expected a JSON object"
    # The four below replayed (a gap in time, or a traceback) before harden8.
    if how == "middle part missing":
        parts[1].unlink()
        return parts[1], "<file>", "missing (the log goes on at part-00002.parquet)"
    if how == "integer column stored as float":
        table = pq.read_table(parts[2])
        i = table.column_names.index("faults")
        pq.write_table(table.set_column(i, "faults", table.column("faults").cast("float64")), parts[2])
        return parts[2], "<file>", "not a log part: column faults is double, not int32"
    if how == "text column":
        table = pq.read_table(parts[0])
        i = table.column_names.index("ramp")
        pq.write_table(table.set_column(i, "ramp", table.column("ramp").cast("string")), parts[0])
        return parts[0], "<file>", "not a log part: column ramp is string, not double"
    if how == "times not finite":
        table = pq.read_table(parts[1])
        nan = pa.array(np.full(table.num_rows, np.nan))
        pq.write_table(table.set_column(table.column_names.index("t"), "t", nan), parts[1])
        return log, "t", f"{table.num_rows} of "
    assert how == "part with other columns"
    table = pq.read_table(parts[1])
    pq.write_table(table.drop_columns(["t"]).append_column("time", table.column("t")), parts[1])
    return parts[1], "<file>", "not a part of a 6-joint log (missing t; unknown time)"


@pytest.mark.parametrize(
    "how",
    [
        "last part truncated",
        "random bytes",
        "0-byte part",
        "meta without device",
        "meta names another device",
        "device identity not a string",
        "meta names another scene",
        "scene identity not a string",
        "meta not an object",
        "part with other columns",
        "middle part missing",
        "integer column stored as float",
        "text column",
        "times not finite",
    ],
)
def test_replay_of_a_damaged_log_is_one_line(
    tmp_path: Path, log_dir: Path, how: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    log = tmp_path / "log"
    shutil.copytree(log_dir, log)
    named, field, reason = _damage(log, how)
    line = main_fails(["web", "--replay", str(log), "--port", "0"], tmp_path, capsys, monkeypatch)
    assert line.startswith(f"error: {named}: field '{field}': {reason}"), line


def test_a_log_from_before_identities_replays_with_a_note(tmp_path: Path, log_dir: Path) -> None:
    log = tmp_path / "log"
    shutil.copytree(log_dir, log)
    meta = log / "_meta.json"
    data = json.loads(meta.read_text())
    assert data["device_identity"] == load_device("kraft").identity
    assert data["scene_identity"] == load_scene("probe").identity
    del data["device_identity"], data["scene_identity"]
    meta.write_text(json.dumps(data))
    replay = LogReplay(log)
    assert replay.unchecked == (
        f"{meta} has no device_identity (an older log): {load_device('kraft').path} is taken as the device it ran"
        f" · {meta} has no scene_identity (an older log): {load_scene('probe').path} is taken as the scene it ran"
    )
    assert LogReplay(log_dir).unchecked == ""


def test_a_log_of_an_edited_scene_is_refused(tmp_path: Path, log_dir: Path) -> None:
    """The scene file the log names is edited after the run: a wall made softer is another world,
    a new name is not."""
    scene = tmp_path / "probe.toml"
    text = load_scene("probe").path.read_text()  # type: ignore[union-attr]
    scene.write_text(text)
    log = tmp_path / "log"
    shutil.copytree(log_dir, log)
    meta = log / "_meta.json"
    data = json.loads(meta.read_text())
    data["scene"] = str(scene)
    meta.write_text(json.dumps(data))
    assert LogReplay(log).unchecked == ""
    scene.write_text(text.replace('name = "probe"', 'name = "renamed probe"', 1))
    assert LogReplay(log).unchecked == ""
    stiffness = re.search(r"^stiffness = .*$", text, re.MULTILINE)
    assert stiffness is not None
    scene.write_text(text.replace(stiffness.group(0), "stiffness = 123.0", 1))
    with pytest.raises(ConfigError, match=f"{scene} is not the scene this log was run on"):
        LogReplay(log)


def test_a_toml_bomb_is_refused_in_one_line_with_bounded_memory(tmp_path: Path) -> None:
    """A 200 KB file with one dotted key of 100,000 parts (> 6 GB inside ``tomllib`` before)."""
    bomb = tmp_path / "b.toml"
    bomb.write_text("a" + ".a" * 100_000 + " = 1\n")
    err = tmp_path / "stderr"
    with err.open("w") as stderr:
        child = subprocess.Popen([*FRHC, "check", str(bomb)], cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=stderr)
    # This child's own peak (wait4), not the largest of every child the suite has run.
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    assert child.returncode == 2
    lines = err.read_text()
    assert "Traceback" not in lines
    line = lines.rstrip("\n").splitlines()[-1]
    assert line == f"error: {bomb}: field '<file>': not valid TOML: a dotted key of more than 32 parts (line 1)"
    # The command's imports: 0.3 GB, or 1.03 GB in a fresh clone whose kernels compile on first
    # import; not the bomb (> 6 GB before, past 1.6 GB in 55 s at 20,000 parts).
    assert usage.ru_maxrss < 2_000_000
