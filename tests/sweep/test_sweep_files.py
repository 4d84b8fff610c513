"""Sweep files: refused before anything runs when malformed; points expanded as written."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from sweep_helpers import frhc

from app.check import check_file
from app.errors import ConfigError
from app.sweep import load_sweep
from app.sweep.fields import parse_target
from app.sweep.spec import SWEEPS_DIR, SweepFile, SweepPlan, Vary

ROOT = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(text)
    return path


#: (sweep file body, the field the one-line error names, a word of its reason).
BAD = {
    "unknown field": ('[[vary]]\nfield = "gains.kt"\nvalues = [1.0]', "vary[0].field", "unknown field 'kt'"),
    "unknown object": (
        '[[vary]]\nfield = "scene.objects.floor.stiffness"\nvalues = [1.0]',
        "vary[0].field",
        "has: surface",
    ),
    "table not value": ('[[vary]]\nfield = "scene.slave"\nvalues = [1.0]', "vary[0].field", "table"),
    "empty range": ('[[vary]]\nfield = "duration"\nrange = [2.0, 1.0]\nsteps = 3', "vary[0].range", "empty"),
    "no steps": ('[[vary]]\nfield = "duration"\nrange = [1.0, 2.0]', "vary[0].steps", "number of values"),
    "wrong type": ('[[vary]]\nfield = "servo_rate"\nvalues = [500, "fast"]', "vary[0].values[1]", "expected a number"),
    "out of range": (
        '[[vary]]\nfield = "hand.stiffness_trans"\nvalues = [100.0, -5.0]',
        "vary[0].values[1]",
        "non-negative",
    ),
    "scene out of range": (
        '[[vary]]\nfield = "scene.objects.surface.stiffness"\nrange = [0.0, 10.0]\nsteps = 2',
        "vary[0].range",
        "positive",
    ),
    "index past the end": ('[[vary]]\nfield = "gains.k_t[5:7]"\nvalues = [1.0]', "vary[0].field", "index"),
    "pose gain rule": ('[[vary]]\nfield = "gains.k_p"\nvalues = [3.0]', "vary[0].values[0]", "must be 1"),
    "unknown device": ('[[vary]]\nfield = "device"\nvalues = ["kraft", "nope"]', "vary[0].values[1]", "nope"),
    "two sources": ('[[vary]]\nfield = "seed"\nvalues = [1]\nnormal = [0.0, 1.0]', "vary[0].values", "exactly one"),
    "no fields": ("vary = []", "vary", "1..16"),
    "unknown metric": ('metric = "speed"\n[[vary]]\nfield = "seed"\nvalues = [1]', "metric", "unknown metric"),
    "a grid value twice": (
        '[[vary]]\nfield = "gains.k_t[0:3]"\nvalues = [0.5, 2.0, 0.5]',
        "vary[0].values",
        "value 3 repeats an earlier one (0.5)",
    ),
    "a grid value twice, as an int and a float": (
        '[[vary]]\nfield = "duration"\nvalues = [1, 1.0]',
        "vary[0].values",
        "value 2 repeats an earlier one (1.0)",
    ),
    "twice": ('[[vary]]\nfield = "seed"\nvalues = [1]\n[[vary]]\nfield = "seed"\nvalues = [2]', "vary", "twice"),
    "negative samples": ('samples = -1\n[[vary]]\nfield = "seed"\nvalues = [1]', "samples", "non-negative"),
    "samples over the limit": (
        'samples = 1000001\n[[vary]]\nfield = "seed"\nvalues = [1]',
        "samples",
        "in [0, 1000000]",
    ),
    "grid over the limit": (
        '[[vary]]\nfield = "seed"\nrange = [0.0, 1e6]\nsteps = 1001\n'
        '[[vary]]\nfield = "duration"\nrange = [1.0, 2.0]\nsteps = 1000',
        "vary",
        "the grid has 1001000 points (at most 1000000)",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_sweep_file_is_refused_naming_the_field(tmp_path: Path, case: str) -> None:
    body, field, reason = BAD[case]
    path = write(tmp_path, f'base = "probe_rate"\n{body}\n')
    with pytest.raises(ConfigError) as err:
        load_sweep(path)
    assert err.value.source == str(path)
    assert err.value.field == field
    assert reason in str(err.value)


@pytest.mark.parametrize("case", sorted(BAD))
def test_check_refuses_a_bad_sweep_file_as_the_sweep_would(tmp_path: Path, case: str) -> None:
    body, field, reason = BAD[case]
    path = write(tmp_path, f'base = "probe_rate"\n{body}\n')
    with pytest.raises(ConfigError) as err:
        check_file(str(path))
    assert (err.value.source, err.value.field) == (str(path), field)
    assert reason in str(err.value)


def test_a_random_sweep_may_weight_a_value_by_repeating_it(tmp_path: Path) -> None:
    """Repeats are refused in a grid (BAD: the same points run twice), not where values are drawn."""
    path = write(tmp_path, 'base = "probe_rate"\nsamples = 3\n[[vary]]\nfield = "duration"\nvalues = [1.0, 1.0, 2.0]\n')
    assert load_sweep(path).spec.vary[0].values == (1.0, 1.0, 2.0)


def test_frhc_check_names_file_and_field_of_a_bad_sweep_in_one_line(tmp_path: Path) -> None:
    """The issue's three kinds of bad sweep file, through the command line: exit 2, one line."""
    for case in ("unknown field", "empty range", "wrong type"):
        body, field, _ = BAD[case]
        path = write(tmp_path, f'base = "probe_rate"\n{body}\n')
        res = frhc("check", str(path))
        assert res.returncode == 2, (case, res.stderr)
        assert res.stdout == ""
        assert res.stderr.count("\n") == 1, res.stderr
        assert res.stderr.startswith(f"error: {path}: field '{field}': "), res.stderr


def test_frhc_check_passes_the_shipped_sweeps_by_name() -> None:
    res = frhc("check", "probe_stiffness", "hand_and_gains")
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("ok: sweep probe_stiffness: 12 points of probe_rate")
    assert res.stdout.count("ok: sweep") == 2


def test_the_command_line_refuses_a_bad_file_in_one_line_before_running(tmp_path: Path) -> None:
    path = write(tmp_path, 'base = "probe_rate"\n[[vary]]\nfield = "tremor"\nvalues = [0.001, 1.0]\n')
    out = tmp_path / "out"
    res = frhc("sweep", str(path), "--out", str(out), "--workers", "1")
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0
    assert f"{path}: field 'vary[0].values[1]'" in res.stderr
    assert "Traceback" not in res.stderr
    assert not out.exists()


def test_a_bad_workers_count_is_refused(tmp_path: Path) -> None:
    res = frhc("sweep", "x.toml", "--workers", "-2")
    assert res.returncode == 2
    assert "--workers" in res.stderr


def test_grid_is_the_product_with_log_and_integer_spacing(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        'base = "probe_rate"\n'
        '[[vary]]\nfield = "scene.objects.surface.stiffness"\nrange = [100.0, 10000.0]\nsteps = 3\nlog = true\n'
        '[[vary]]\nfield = "seed"\nrange = [0, 10]\nsteps = 3\n'
        '[[vary]]\nfield = "mode"\nvalues = ["rate", "pose"]\n',
    )
    plan = load_sweep(path)
    points = plan.points()
    assert plan.n_points() == len(points) == 18
    assert sorted({p[0] for p in points}) == pytest.approx([100.0, 1000.0, 10000.0])
    assert sorted({p[1] for p in points}) == [0, 5, 10]
    assert all(isinstance(p[1], int) for p in points)
    assert points[0] == (pytest.approx(100.0), 0, "rate")
    assert points[1][2] == "pose"


def test_values_reach_the_session_scene_and_gains(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        'base = "probe_rate"\n'
        '[[vary]]\nfield = "scene.objects.surface.stiffness"\nvalues = [1234.0]\n'
        '[[vary]]\nfield = "gains.k_t[0:3]"\nvalues = [0.5]\n'
        '[[vary]]\nfield = "gains.k_d"\nvalues = [3.0]\n'
        '[[vary]]\nfield = "hand.stiffness_trans"\nvalues = [321.0]\n'
        '[[vary]]\nfield = "duration"\nvalues = [0.25]\n',
    )
    plan = load_sweep(path)
    session = plan.session_at(plan.points()[0])
    assert session.scene.spec.objects[0].stiffness == 1234.0
    assert session.scene.objects[0].stiffness == 1234.0
    assert session.gains.k_t == (0.5, 0.5, 0.5, 1.0, 1.0, 1.0)
    assert session.gains.k_d == (3.0,) * 6
    assert session.data.hand.stiffness_trans == 321.0
    assert session.data.n_ticks == 250
    assert session.path == ROOT / "sessions" / "probe_rate.toml"


@given(
    lo=st.floats(0.01, 100.0),
    span=st.floats(0.01, 100.0),
    n=st.integers(1, 200),
    seed=st.integers(0, 2**32 - 1),
    log=st.booleans(),
)
def test_random_samples_are_seeded_and_inside_the_range(lo: float, span: float, n: int, seed: int, log: bool) -> None:
    hi = lo + span
    spec = SweepFile("probe_rate", (Vary("duration", range=(lo, hi), log=log),), samples=n, seed=seed)
    target = parse_target("duration", {})
    plan = SweepPlan(Path("s.toml"), spec, Path("b.toml"), {}, (target,), "x")
    points = plan.points()
    assert len(points) == n == plan.n_points()
    assert points == plan.points()
    xs = np.array([p[0] for p in points])
    assert np.all((xs >= lo) & (xs <= hi))
    if n >= 50:
        # Log-uniform draws put half their mass below the geometric mean, uniform below the mean.
        mid = math.sqrt(lo * hi) if log else (lo + hi) / 2
        assert 0.2 < float(np.mean(xs < mid)) < 0.8


def test_shipped_sweep_files_load() -> None:
    for path in sorted((ROOT / "sweeps").glob("*.toml")):
        assert load_sweep(path).n_points() > 0


def test_a_base_path_is_read_beside_the_sweep_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``base = "mine.toml"`` is the sweep file's neighbour, not a file of the working directory."""
    folder = tmp_path / "study"
    folder.mkdir()
    shutil.copy(ROOT / "sessions" / "probe_rate.toml", folder / "mine.toml")
    (folder / "sweep.toml").write_text('base = "mine.toml"\n[[vary]]\nfield = "seed"\nvalues = [1, 2]\n')
    monkeypatch.chdir(tmp_path)
    assert load_sweep("study/sweep.toml").base_path == folder / "mine.toml"


def test_a_sweep_is_found_by_name_as_a_session_is(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``frhc sweep probe_stiffness`` said 'file not found' while ``frhc run probe_rate`` and ``frhc
    check probe_stiffness`` find theirs by name; a path still wins, from any working folder."""
    monkeypatch.chdir(tmp_path)
    assert load_sweep("probe_stiffness").path == SWEEPS_DIR / "probe_stiffness.toml"
    with pytest.raises(ConfigError, match=r"nosuch\.toml: field '<file>': file not found$"):
        load_sweep("nosuch")
