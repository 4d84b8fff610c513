"""Running sweeps: rows as on a serial run when on Ray, resume, failing points, plots, the engine."""

from __future__ import annotations

import operator
import os
from functools import partial
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import sweep_helpers
from sweep_helpers import DiesLoading, frhc

from app.errors import EngineError
from app.sweep import load_sweep, run_sweep
from app.sweep.engine import MAX_START_DEATHS, run_points

#: Six short probe sessions; tremor drawn from a normal distribution, so some draws are negative
#: (out of its range): those points fail alone, with the one-line error naming the field.
SWEEP = """
base = "probe_rate"
samples = 6
seed = 3
metric = "peak_contact_force_N"

[[vary]]
field = "tremor"
normal = [0.0005, 0.002]

[[vary]]
field = "scene.objects.surface.stiffness"
range = [1000.0, 5000.0]

[[vary]]
field = "duration"
values = [0.12]
"""


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sweep") / "s.toml"
    path.write_text(SWEEP)
    return path


@pytest.fixture(scope="module")
def serial(sweep_file: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("serial")
    run_sweep(load_sweep(sweep_file), out, workers=1)
    return out


def test_a_failing_point_is_a_row_with_its_error_and_the_sweep_goes_on(serial: Path) -> None:
    table = pq.read_table(serial / "results.parquet").to_pylist()
    assert [r["point"] for r in table] == list(range(6))
    bad = [r for r in table if r["tremor"] < 0]
    good = [r for r in table if r["tremor"] >= 0]
    assert bad
    assert good
    for r in bad:
        assert r["status"] == "error"
        assert "field 'tremor'" in r["error"]
        assert "non-negative" in r["error"]
        assert r["work_eq13"] is None
    for r in good:
        assert r["status"] == "ok"
        assert r["error"] == ""
        assert r["simulated_s"] == pytest.approx(0.12)
        assert 1000.0 <= r["scene.objects.surface.stiffness"] <= 5000.0
    assert (serial / "peak_contact_force_N.png").stat().st_size > 0


def test_frhc_sweep_names_each_failed_point_with_its_values_and_error(sweep_file: Path, serial: Path) -> None:
    """The command prints one line per failed point (its index, varied values and error), here
    on a re-run that resumes every point. Before, only their count ('see the 'error' column')."""
    res = frhc("sweep", str(sweep_file), "--out", str(serial), "--workers", "1")
    assert res.returncode == 0, res.stderr
    bad = [r for r in pq.read_table(serial / "results.parquet").to_pylist() if r["status"] != "ok"]
    assert bad
    lines = [line.strip() for line in res.stdout.splitlines() if line.startswith("  point ")]
    assert len(lines) == len(bad), res.stdout
    for line, r in zip(lines, bad, strict=True):
        assert line.startswith(f"point {r['point']} (tremor={r['tremor']:g}, "), line
        assert line.endswith(f"): {r['error']}"), line


def test_ray_gives_the_serial_rows(sweep_file: Path, serial: Path, tmp_path: Path, local_ray: None) -> None:
    report = run_sweep(load_sweep(sweep_file), tmp_path, workers=2)
    assert report.ran == 6
    assert report.table.equals(pq.read_table(serial / "results.parquet"))


def test_resume_runs_only_the_missing_points(sweep_file: Path, serial: Path, tmp_path: Path, local_ray: None) -> None:
    full = pq.read_table(serial / "results.parquet")
    (tmp_path / "parts").mkdir()
    (tmp_path / "sweep.json").write_text((serial / "sweep.json").read_text())
    pq.write_table(full.slice(0, 4), tmp_path / "parts" / "part-000000.parquet")
    report = run_sweep(load_sweep(sweep_file), tmp_path, workers=2)
    assert (report.ran, report.skipped) == (2, 4)
    assert report.table.equals(full)
    again = run_sweep(load_sweep(sweep_file), tmp_path, workers=1)
    assert (again.ran, again.skipped) == (0, 6)
    assert again.table.equals(full)


def test_an_output_directory_of_another_sweep_is_refused(sweep_file: Path, serial: Path, tmp_path: Path) -> None:
    other = tmp_path / "other.toml"
    other.write_text(SWEEP.replace("seed = 3", "seed = 4"))
    res = frhc("sweep", str(other), "--out", str(serial), "--workers", "1")
    assert res.returncode == 2
    assert "holds the results of another sweep" in res.stderr


def test_command_line_grid_sweep_with_a_heatmap(tmp_path: Path) -> None:
    path = tmp_path / "grid.toml"
    path.write_text(
        'base = "probe_rate"\n[[vary]]\nfield = "gains.k_t[0:3]"\nvalues = [0.5, 1.0]\n'
        '[[vary]]\nfield = "servo_rate"\nvalues = [500.0, 1000.0]\n[[vary]]\nfield = "duration"\nvalues = [0.1]\n'
    )
    res = frhc("sweep", str(path), "--out", str(tmp_path / "o"), "--workers", "1")
    assert res.returncode == 0, res.stderr
    assert "4 points: 4 run now, 0 resumed" in res.stdout
    rows = pq.read_table(tmp_path / "o" / "results.parquet").to_pylist()
    assert [(r["gains.k_t[0:3]"], r["servo_rate"], r["status"]) for r in rows] == [
        (0.5, 500.0, "ok"),
        (0.5, 1000.0, "ok"),
        (1.0, 500.0, "ok"),
        (1.0, 1000.0, "ok"),
    ]
    # 0.1 s at 500 Hz is 50 ticks, at 1 kHz 100.
    assert [round(r["simulated_s"] * r["servo_rate"]) for r in rows] == [50, 100, 50, 100]
    assert (tmp_path / "o" / "work_eq13.png").stat().st_size > 0


def test_the_engine_turns_exceptions_and_dead_workers_into_rows(local_ray: None) -> None:
    """``operator.call`` is the task and each payload a call: ``dict`` of pairs makes a row, of an
    integer raises TypeError; ``os._exit`` kills the real Ray worker process running it (and
    the one it is tried again on). Every other point, queued behind it or not, gives its row."""
    points = [
        (0, partial(dict, [("a", 0)])),
        (1, partial(dict, 7)),
        (2, partial(os._exit, 3)),
        *[(k, partial(dict, [("a", k)])) for k in range(3, 10)],
    ]
    rows = dict(run_points(operator.call, points, workers=2))
    assert sorted(rows) == list(range(10))
    assert rows[1]["status"] == "error"
    assert rows[1]["error"].startswith("TypeError")
    assert rows[2]["status"] == "error"
    assert rows[2]["error"].startswith("worker died running this point")
    for k in (0, *range(3, 10)):
        assert rows[k] == {"a": k, "status": "ok", "error": ""}


def test_an_address_other_than_the_cluster_this_process_joined_is_refused(local_ray: None) -> None:
    """A library user who already started Ray asks for another cluster: one line naming the
    address and the cluster joined (before: the address was ignored and the points ran on the
    local instance). The joined cluster's own address, written as ``localhost``, runs."""
    import ray

    joined = ray.get_runtime_context().gcs_address
    other = "127.0.0.1:1" if not joined.endswith(":1") else "127.0.0.1:2"
    with pytest.raises(EngineError) as refused:
        list(run_points(operator.call, [(0, partial(dict, a=0))], workers=1, address=other))
    assert str(refused.value) == (
        f"--address {other}: this process has already joined the Ray cluster at {joined}, "
        "and Ray joins one cluster a process (ray.shutdown() first)"
    )
    same = joined.replace("127.0.0.1", "localhost")
    rows = dict(run_points(operator.call, [(0, partial(dict, a=0))], workers=1, address=same))
    assert rows == {0: {"a": 0, "status": "ok", "error": ""}}


def test_a_worker_that_dies_while_it_starts_charges_no_point(local_ray: None, tmp_path: Path) -> None:
    """The first three workers to load the task die doing so, before running anything, as a
    worker may while it starts on a loaded machine: both first workers, and the replacement of
    the one the only point was queued on (whatever the order the loads come in, that point's
    worker dies twice). The point ran nowhere, so it is not charged with a kill: its row comes
    back. (The engine that charged the first point on a dead worker that did not come back made
    it a "worker died running this point" row, every time.)"""
    ray = pytest.importorskip("ray")
    ray.cloudpickle.register_pickle_by_value(sweep_helpers)
    try:
        rows = dict(run_points(DiesLoading(tmp_path, 3, operator.call), [(0, partial(dict, [("a", 0)]))], workers=2))
    finally:
        ray.cloudpickle.unregister_pickle_by_value(sweep_helpers)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["death-0", "death-1", "death-2"]
    assert rows == {0: {"a": 0, "status": "ok", "error": ""}}


def test_workers_that_always_die_while_they_start_stop_the_run(local_ray: None, tmp_path: Path) -> None:
    """A task no worker can load (every unpickling ends the process): the engine replaces the dead
    workers until one slot has lost MAX_START_DEATHS in a row, then stops the run with one line
    instead of replacing workers for ever. Two slots: 4 to 8 workers died (one slot's fourth,
    the other's up to three and a replacement loading as the run stops)."""
    ray = pytest.importorskip("ray")
    ray.cloudpickle.register_pickle_by_value(sweep_helpers)
    try:
        with pytest.raises(EngineError, match=f"^{MAX_START_DEATHS} workers in a row died while loading the task"):
            dict(run_points(DiesLoading(tmp_path, 1000, operator.call), [(0, partial(dict, [("a", 0)]))], workers=2))
    finally:
        ray.cloudpickle.unregister_pickle_by_value(sweep_helpers)
    assert MAX_START_DEATHS <= len(list(tmp_path.iterdir())) <= 2 * MAX_START_DEATHS
