"""The experiment keeps its finished runs when stopped (Ctrl-C, SIGTERM) and resumes from them."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.errors import ConfigError, Interrupted
from app.session.operators import sample_population
from app.study.experiment import run_experiment


def test_an_interrupted_experiment_keeps_its_runs_and_the_same_command_resumes(tmp_path: Path) -> None:
    """Ctrl-C after the third of four runs (raised where the engine hands over a row, as SIGINT
    unwinds there): one line names the 3 runs kept; re-running runs only the fourth, and every
    row equals an uninterrupted experiment's. Before, nothing was kept."""
    ops = sample_population(2, seed=5)

    def ctrl_c_after_three(done: int, total: int) -> None:
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(Interrupted) as stopped:
        run_experiment(tmp_path / "x", operators=ops, time_limit=0.3, on_run=ctrl_c_after_three)
    assert stopped.value.kept == f"3 of 4 runs are in {tmp_path / 'x' / 'parts'}; the same command resumes"
    assert sorted(p.name for p in (tmp_path / "x").glob("*.json")) == ["experiment.json"]
    calls: list[tuple[int, int]] = []
    resumed = run_experiment(tmp_path / "x", operators=ops, time_limit=0.3, on_run=lambda *a: calls.append(a))
    assert calls == [(4, 4)]
    whole = run_experiment(tmp_path / "whole", operators=ops, time_limit=0.3)
    assert resumed.rows == whole.rows
    assert resumed.table == whole.table
    with pytest.raises(ConfigError, match="holds the results of another experiment"):
        run_experiment(tmp_path / "x", operators=ops, time_limit=0.4)
