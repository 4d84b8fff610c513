"""Whole sessions: determinism, logs that survive a crash, the command line and its errors."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from app.errors import ConfigError
from app.session import load_session, run_session
from app.session.log import PART_SECONDS, read_log
from app.session.loop import ServoLoop
from app.session.script import Operator, OperatorScript
from app.session.spec import SESSIONS_DIR

FRHC = [sys.executable, "-m", "app.cli"]


def frhc(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*FRHC, *args], capture_output=True, text=True, timeout=300, cwd=cwd, check=False)


def test_same_file_and_seed_give_an_identical_log(tmp_path: Path) -> None:
    """Everything but the wall-clock timing columns (*_us) is bit-identical between two runs."""
    session = load_session("peg_ntrfc").with_changes(duration=0.6)
    tables = []
    for k in range(2):
        run_session(session, out_dir=tmp_path / f"run{k}", plots=False)
        table = pq.read_table(tmp_path / f"run{k}" / "log")
        tables.append(table.drop([c for c in table.column_names if c.endswith("_us")]))
    assert tables[0].num_rows == 600
    assert tables[0].equals(tables[1])
    other = run_session(session.with_changes(seed=99), out_dir=tmp_path / "other", plots=False)
    assert other.log_dir is not None
    t_other = pq.read_table(other.log_dir)
    assert not np.array_equal(t_other.column("hand_target_x").to_numpy(), tables[0].column("hand_target_x").to_numpy())


def test_cli_run_writes_log_summary_and_plot(tmp_path: Path) -> None:
    session = tmp_path / "short.toml"
    session.write_text((SESSIONS_DIR / "probe_rate.toml").read_text().replace("duration = 5.0", "duration = 1.2"))
    res = frhc("run", str(session), "--out", str(tmp_path / "out"))
    assert res.returncode == 0, res.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["ticks"] == 1200
    assert set(summary) >= {"work_eq13", "peak_contact_force_N", "rms_contact_force_N", "faults", "timing"}
    table = pq.read_table(tmp_path / "out" / "log")
    assert table.num_rows == 1200
    assert {"t", "q_0", "delta_x_z", "F_MRF_fz", "tau_sat_5", "counts_0", "tick_us", "faults"} <= set(
        table.column_names
    )
    png = (tmp_path / "out" / "session.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_killed_run_leaves_a_readable_log(tmp_path: Path, seed: int) -> None:
    """kill -9 at a random moment of a paced run: every completed part reads back, none is torn,
    and the tail gathered since the last part is recovered in whole ticks, one after the other.
    (Not in whole flushes: Linux stops a write to a file between pages when the process is
    killed, so a flush of 0.1 s cut by the kill keeps the rows it wrote; seen once, 78 of 100.)"""
    session = tmp_path / "long.toml"
    session.write_text((SESSIONS_DIR / "probe_rate.toml").read_text().replace("duration = 5.0", "duration = 120.0"))
    out = tmp_path / "out"
    command = [*FRHC, "run", str(session), "--out", str(out), "--realtime", "--flush-interval", "0.1"]
    proc = subprocess.Popen(command, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not list((out / "log").glob("part-*.parquet")) and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(np.random.default_rng(seed).uniform(0.3, 1.5))
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    parts = sorted((out / "log").glob("part-*.parquet"))
    table = read_log(out / "log")
    assert len(parts) >= 1
    # Every finished part (PART_SECONDS of ticks each), then the tail's rows.
    assert table.num_rows > round(PART_SECONDS / 1e-3) * len(parts)
    t = np.sort(table.column("t").to_numpy())
    np.testing.assert_allclose(t[0], 1e-3, rtol=1e-9)
    np.testing.assert_allclose(np.diff(t), 1e-3, rtol=1e-6)


BAD_SESSIONS = {
    "unknown scene": ('scene = "probe"', 'scene = "moon"', "scene"),
    "unknown device": ('device = "kraft"', 'device = "phantom"', "device"),
    "negative duration": ("duration = 5.0", "duration = -1.0", "duration"),
    "unknown field": ("seed = 0", "seed = 0\nspeed = 3", "speed"),
    "non-monotonic waypoints": ("t = 1.0\n", "t = 0.2\n", "waypoints[1].t"),
    "bad gain": ("accommodation = true", "accommodation = true\n[gains]\nk_v = [1.0, 2.0]", "gains.k_v"),
}


@pytest.mark.parametrize("case", list(BAD_SESSIONS))
def test_bad_session_files_fail_before_running_with_one_line(tmp_path: Path, case: str) -> None:
    old, new, field = BAD_SESSIONS[case]
    text = (SESSIONS_DIR / "probe_rate.toml").read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    res = frhc("run", str(path), "--out", str(tmp_path / "out"))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert str(path) in lines[0]
    assert f"field '{field}'" in lines[0]
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out").exists()  # nothing ran


def test_check_subcommand(tmp_path: Path) -> None:
    res = frhc("check", "kraft", "probe", "probe_rate")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count("ok:") == 3
    bad = tmp_path / "broken.toml"
    bad.write_text("duration = [")
    res = frhc("check", str(bad))
    assert res.returncode == 2
    assert "not valid TOML" in res.stderr


def test_every_subcommand_has_help() -> None:
    for sub in ("run", "experiment", "bench", "check", "calibrate", "web"):
        res = frhc(sub, "--help")
        assert res.returncode == 0
        assert "usage: frhc" in res.stdout


def test_a_run_whose_device_goes_unstable_stops_it_and_says_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The device plant's joint speed turned NaN at 0.1 s of a 0.3 s run: the plant stops (motors
    off, encoders held) and the summary's ``device_fault`` says why, with nothing printed or
    written by MuJoCo; a clean run's is None. Before, the run went on silently from MuJoCo's reset
    of the device to its zero angles."""
    monkeypatch.chdir(tmp_path)
    session = load_session("probe_rate").with_changes(duration=0.3)

    class Spoiled:
        """The session's own script, with the plant's state spoiled once before its 100th tick."""

        def __init__(self, loop: ServoLoop) -> None:
            self.script, self.ticks = OperatorScript.for_loop(session.data, loop), 0

        def before_tick(self, loop: ServoLoop) -> None:
            self.ticks += 1
            if self.ticks == 100:
                loop.plant.data.qvel[loop.plant.dof_slice.start] = math.nan
            self.script.before_tick(loop)

    def spoiled(loop: ServoLoop) -> Operator:
        return Spoiled(loop)

    result = run_session(session, out_dir=None, plots=False, operator=spoiled)
    assert "went unstable" in result.summary["device_fault"]
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert run_session(session, out_dir=None, plots=False).summary["device_fault"] is None


def test_an_event_due_at_or_after_the_run_end_is_named_by_run_and_check(tmp_path: Path) -> None:
    """Events stretched by ``time_scale`` to the end (0.5 s x 2 = 1.0 s of a 1.0 s run) or past
    it never fire: ``frhc check`` and ``frhc run`` each say so in one line naming the file and
    field, and still run. Before, such an event was dropped silently."""
    path = tmp_path / "late.toml"
    path.write_text(
        'scene = "probe"\ndevice = "kraft"\nduration = 1.0\ntime_scale = 2.0\n'
        "[[events]]\nt = 0.1\ndeadman = true\n[[events]]\nt = 0.5\nreflection = true\n"
        "[[events]]\nt = 30.0\ndeadman = false\n"
    )
    assert load_session(path).notices == (
        f"{path}: field 'events[1].t': due at 1 s, at or after the run's end (1 s): it never fires",
        f"{path}: field 'events[2].t': due at 60 s, at or after the run's end (1 s): it never fires",
    )
    check = frhc("check", str(path))
    assert check.returncode == 0, check.stderr
    assert check.stdout.splitlines()[1:] == [f"warning: {n}" for n in load_session(path).notices]
    run = frhc("run", str(path), "--out", str(tmp_path / "out"), "--no-plots")
    assert run.returncode == 0, run.stderr
    assert [line for line in run.stderr.splitlines() if line.startswith("warning: ")] == [
        f"warning: {n}" for n in load_session(path).notices
    ]
    assert load_session("probe_rate").notices == ()


def test_the_passivity_controller_asked_of_a_cartesian_device_is_one_line(tmp_path: Path) -> None:
    """``[passivity] enabled = true`` with a device driven through its Cartesian interface (the
    touch3 file, or any device behind ``--device``): refused naming ``passivity.enabled``, exit
    2. Before, ``frhc run`` ended in a ValueError traceback from the controller and ``frhc check``
    called it a model MuJoCo refuses."""
    path = tmp_path / "pc.toml"
    path.write_text('scene = "probe"\ndevice = "touch3"\nduration = 0.2\n[passivity]\nenabled = true\n')
    with pytest.raises(ConfigError) as info:
        load_session(path)
    assert info.value.field == "passivity.enabled"
    assert "touch3 is driven through its Cartesian interface" in str(info.value)
    joint = tmp_path / "pc_joint.toml"
    joint.write_text(path.read_text().replace("touch3", "kraft"))
    assert load_session(joint).data.passivity.enabled
    for args in (("run", str(path)), ("check", str(path)), ("run", str(joint), "--device", "ws://127.0.0.1:9")):
        res = frhc(*args, "--out", str(tmp_path / "out")) if args[0] == "run" else frhc(*args)
        assert res.returncode == 2, res.stderr
        assert "Traceback" not in res.stderr
        assert res.stderr.strip().splitlines()[-1].startswith(f"error: {args[1]}: field 'passivity.enabled': "), (
            res.stderr
        )


@pytest.mark.parametrize("device", ["kraft", "jpl", "freflex"])
def test_the_probe_session_at_20_khz_has_no_fault_tick(device: str) -> None:
    """The shipped probe session at the highest servo rate a session takes, on the devices whose
    8192-count wrist encoders read one count in 50 us as 15.3 rad/s (twice the brake's limit): the
    joints never come near the limit (measured: one count per >= 1 ms), so no tick may brake.
    Before: 948 / 135 / 2925 OVERSPEED ticks in 1.5 s."""
    session = load_session("probe_rate").with_changes(device=device, servo_rate=20000.0, duration=1.5)
    result = run_session(session, plots=False)
    assert result.summary["faults"] == {}
