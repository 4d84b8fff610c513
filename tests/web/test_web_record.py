"""The demo's Record button: every recording keeps its own log."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import pytest
from web_helpers import wait_until

import app.web.server as server_module
from app.session.log import read_log
from app.web.headless import free_port
from app.web.launch import start_demo


class _SameSecond:
    """``datetime`` whose ``now`` is one fixed second: two clicks within it."""

    @staticmethod
    def now() -> datetime:
        return datetime(2026, 1, 2, 3, 4, 5)


def test_two_recordings_in_one_second_keep_both_logs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Record, Stop, Record, Stop within one second: two folders, each with its own ticks. Before,
    both were runs/web-<second>/log, and the second recording deleted the first one's parts."""
    monkeypatch.setattr(server_module, "RUNS_DIR", tmp_path)
    monkeypatch.setattr(server_module, "datetime", _SameSecond)
    app = start_demo("probe", "kraft", port=free_port())
    try:
        assert app.rt.wait_running()
        logs = []
        for _ in range(2):
            directory = app.toggle_recording()
            assert directory is not None
            start = app.rt.stats().counted
            wait_until(lambda s=start: app.rt.stats().counted > s + 1500, "the loop ran 1.5 s of ticks")  # type: ignore[misc]
            assert app.toggle_recording() is None
            logs.append(directory)
        assert logs[0] != logs[1]
        assert sorted(p.name for p in tmp_path.iterdir()) == ["web-20260102-030405", "web-20260102-030405-2"]
        for directory in logs:
            wait_until(lambda d=directory: (d / "part-00000.parquet").exists(), f"{directory} has its first part")  # type: ignore[misc]
            assert read_log(directory).num_rows >= 1000
    finally:
        app.close()
        app.server.stop()


def test_a_runs_folder_that_cannot_be_made_is_said_on_the_page(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Record with ``runs/`` blocked (a file in the way): the page says so, the loop runs on."""
    (tmp_path / "afile").write_text("")
    monkeypatch.setattr(server_module, "RUNS_DIR", tmp_path / "afile" / "runs")
    app = start_demo("probe", "kraft", port=free_port())
    try:
        assert app.rt.wait_running()
        app.controls._toggle_record()
        assert app.controls.record_status.content.startswith("**cannot record:** [Errno 20] Not a directory")
        assert app.controls.record.label == "Record"
        start = app.rt.stats().counted
        wait_until(lambda: app.rt.stats().counted > start + 100, "the loop runs on")
        assert app.rt.ended() is None
    finally:
        app.close()
        app.server.stop()
