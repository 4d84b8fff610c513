"""Run a sweep: every point an ordinary headless session, its metrics one row of the results.

Example::

    from app.sweep import load_sweep, run_sweep
    report = run_sweep(load_sweep("sweeps/probe_stiffness.toml"), Path("runs/sweep"), workers=2)
    print(report.table.to_pandas())   # or pyarrow's own methods
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from app.errors import ConfigError, EngineError
from app.session.run import run_session
from app.sweep.engine import Engine
from app.sweep.results import METRICS, ResultsWriter, arrow_schema, metrics_row
from app.sweep.spec import SweepPlan


@dataclass(frozen=True)
class SweepPoint:
    """The task of a sweep's points: runs the base session with one point's values (picklable).

    Called with the point's values (one per varied field); returns its fields and metrics.
    """

    plan: SweepPlan

    def __call__(self, values: tuple[Any, ...]) -> dict[str, Any]:
        result = run_session(self.plan.session_at(values), out_dir=None, plots=False)
        return metrics_row(result.summary)


@dataclass(frozen=True)
class SweepReport:
    """What a sweep wrote.

    Attributes:
        results: ``results.parquet``.
        table: Its rows (sorted by point).
        plot: The plot, if one was drawn.
        ran, skipped, failed: Points run now, points already finished, failed points (all runs).
    """

    results: Path
    table: pa.Table
    plot: Path | None
    ran: int
    skipped: int
    failed: int


def run_sweep(
    plan: SweepPlan,
    out_dir: Path,
    workers: int = 1,
    address: str | None = None,
    metric: str | None = None,
    progress: bool = False,
) -> SweepReport:
    """Run the points of ``plan`` not yet in ``out_dir``; write the table and a plot of ``metric``.

    Args:
        plan: From :func:`app.sweep.spec.load_sweep`.
        out_dir: Output directory; re-running into it skips the finished points.
        workers: Parallel workers (1 = serially, without Ray); see :class:`app.sweep.engine.Engine`.
        address: A Ray cluster to join (None = ``RAY_ADDRESS``, else local).
        metric: Metric to plot (default: the sweep file's ``metric``).
        progress: Show a progress bar.

    Raises:
        ConfigError: ``metric`` is unknown, or ``out_dir`` holds another sweep.
        Interrupted: on SIGINT or SIGTERM (a ``KeyboardInterrupt``), once the finished rows are
            written to ``out_dir/parts`` (a re-run resumes from them); it says how many.
    """
    metric = metric or plan.spec.metric
    if metric not in METRICS:
        raise ConfigError("--metric", "metric", f"unknown metric '{metric}' (known: {', '.join(METRICS)})")
    schema = arrow_schema({t.field: t.kind for t in plan.targets}, METRICS)
    identity = {"fingerprint": plan.fingerprint, "fields": list(plan.fields), "points": plan.n_points()}
    writer = ResultsWriter(out_dir, schema, identity, plan.path)
    done = writer.finished()
    points = plan.points()
    todo = [(i, p) for i, p in enumerate(points) if i not in done]
    ran = 0
    try:
        with (
            # The bar starts once the engine is up: a cluster that does not answer is one line.
            Engine(workers, address) as engine,
            tqdm(total=len(points), initial=len(points) - len(todo), unit="point", disable=not progress) as bar,
        ):
            for index, row in engine.run(SweepPoint(plan), todo):
                writer.add({"point": index, **dict(zip(plan.fields, points[index], strict=True)), **row})
                ran += 1
                bar.update(1)
    except KeyboardInterrupt as exc:
        # The engine has ended its workers (and its Ray instance) on the way here.
        raise writer.interrupted(exc, len(points) - len(todo) + ran, len(points)) from None
    except EngineError:
        writer.abandon()
        raise
    results = writer.close()
    table = pq.read_table(results)
    failed = sum(1 for s in table.column("status").to_pylist() if s != "ok")
    from app.sweep.plots import plot_sweep

    plot = plot_sweep(table, plan.fields, metric, out_dir / f"{metric}.png")
    return SweepReport(results, table, plot, ran, len(points) - len(todo), failed)
