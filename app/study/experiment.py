"""The paper's Table I experiment (Sec 4.3) with a population of operators that react.

Dual peg-in-the-holes, FRHC/NTRFC (wrench reflection plus slave accommodation,
``sessions/peg_ntrfc.toml``) against "blind" (neither, ``peg_blind.toml``). Each operator is a
:class:`~app.session.operators.ReactingOperator` drawn from literature ranges
(:func:`~app.session.operators.sample_population`, seeded); each runs both conditions once, as
points of the sweep engine (:func:`app.sweep.engine.run_points`: serially or on Ray, the same rows).

A run counts only if the task completes (both pegs 20 mm deep) within the time limit: a failed
run is reported as failed and its work is not averaged in. Reported per run: the work on the
environment (Eq 13), the peak contact force, completion and its time. The table shows the
paper's layout for the first three operators, then the population: completion rates, medians,
and the blind/NTRFC work ratio of every operator who completed both. The paper measured lower
work with FRHC/NTRFC for each of its three subjects (Table I: 1.66/2.55/1.51 J blind against
0.59/0.61/0.42 J, ratios 2.8 to 4.2).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from app.session.log import write_json
from app.session.operators import OperatorParams, ReactingOperator, sample_population
from app.session.run import run_session
from app.session.spec import load_session

CONDITIONS = {"FRHC/NTRFC": "peg_ntrfc", "No Force Info": "peg_blind"}
NTRFC, BLIND = CONDITIONS
#: Longest simulated time (s) a run may take; an operator who has not finished by then failed.
TIME_LIMIT = 12.0


@dataclass(frozen=True)
class ExperimentPoint:
    """One operator in one condition: the engine's task (picklable). Returns the run's row."""

    time_limit: float = TIME_LIMIT
    slave: str | None = None

    def __call__(self, payload: tuple[OperatorParams, str]) -> dict[str, Any]:
        op, condition = payload
        base = load_session(CONDITIONS[condition]).with_changes(slave=self.slave)
        hand = dataclasses.replace(base.data.hand, stiffness_trans=op.stiffness_trans, damping_trans=op.damping_trans)
        session = base.with_changes(hand=hand, duration=self.time_limit, seed=op.seed)
        s = run_session(
            session, out_dir=None, plots=False, operator=lambda loop: ReactingOperator(op, session, loop)
        ).summary
        return {
            "work_eq13": s["work_eq13"],
            "peak_contact_force_N": s["peak_contact_force_N"],
            "completed": bool(s["task"]["completed"]),
            "completion_time_s": s["task"]["time_s"],
            "simulated_s": s["simulated_s"],
            "fault_ticks": sum(s["faults"].values()),
        }


@dataclass(frozen=True)
class ExperimentReport:
    """What the experiment wrote: the table's text, the plot, the JSON summary and every row."""

    table: str
    chart: Path
    json_path: Path
    results: Path
    rows: list[dict[str, Any]]


def run_experiment(
    out_dir: Path,
    n_operators: int = 100,
    seed: int = 0,
    operators: Sequence[OperatorParams] | None = None,
    time_limit: float = TIME_LIMIT,
    workers: int = 1,
    address: str | None = None,
    progress: bool = False,
    on_run: Callable[[int, int], None] | None = None,
    slave: str | None = None,
) -> ExperimentReport:
    """Run every operator in both conditions; write ``results.parquet``, ``table1.txt``,
    ``table1.json`` and ``table1.png`` to ``out_dir``.

    Args:
        out_dir: Output directory.
        n_operators, seed: Size and seed of the population drawn when ``operators`` is None.
        operators: Your own operators instead.
        time_limit: Simulated seconds (s) a run may take before it counts as failed.
        workers, address: The engine's workers and Ray cluster (:func:`app.sweep.engine.run_points`).
        progress: Show a progress bar.
        on_run: Called with (runs done, total) after each run (e.g. to show progress in the web page).
        slave: Replaces the scene's slave (``"tool"`` or an arm in ``slaves/``): the paper ran the
            same task with a PUMA 560 and a redundant arm.
    """
    from app.sweep.engine import run_points

    out_dir.mkdir(parents=True, exist_ok=True)
    ops = tuple(operators) if operators is not None else sample_population(n_operators, seed)
    points = [(k, (op, cond)) for k, (op, cond) in enumerate((op, c) for op in ops for c in CONDITIONS)]
    rows: list[dict[str, Any]] = []
    with tqdm(total=len(points), unit="run", disable=not progress) as bar:
        for index, row in run_points(ExperimentPoint(time_limit, slave), points, workers, address):
            op, cond = points[index][1]
            rows.append({"point": index, "operator": op.name, "condition": cond, **dataclasses.asdict(op), **row})
            bar.update(1)
            if on_run is not None:
                on_run(len(rows), len(points))
    rows.sort(key=lambda r: r["point"])
    results = out_dir / "results.parquet"
    pq.write_table(pa.Table.from_pylist(rows), results)
    summary = _summary(rows)
    table = _table(rows, summary)
    chart = _chart(rows, summary, out_dir / "table1.png")
    json_path = out_dir / "table1.json"
    write_json(json_path, {"population": summary, "table": table})
    (out_dir / "table1.txt").write_text(table + "\n")
    return ExperimentReport(table, chart, json_path, results, rows)


def _runs(rows: list[dict[str, Any]], cond: str) -> list[dict[str, Any]]:
    return [r for r in rows if r["condition"] == cond]


def _ok(r: dict[str, Any]) -> bool:
    return r.get("status") == "ok" and bool(r.get("completed"))


def ratios(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Blind / NTRFC work per operator who completed both conditions."""
    by_op: dict[str, dict[str, float]] = {}
    for r in rows:
        if _ok(r):
            by_op.setdefault(r["operator"], {})[r["condition"]] = r["work_eq13"]
    return {op: w[BLIND] / max(w[NTRFC], 1e-12) for op, w in by_op.items() if len(w) == 2}


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for cond in CONDITIONS:
        runs = _runs(rows, cond)
        done = [r for r in runs if _ok(r)]

        def median(key: str, done: list[dict[str, Any]] = done) -> float | None:
            return float(np.median([r[key] for r in done])) if done else None

        out[cond] = {
            "runs": len(runs),
            "completed": len(done),
            "errors": sum(1 for r in runs if r.get("status") != "ok"),
            "median_work_J": median("work_eq13"),
            "median_peak_force_N": median("peak_contact_force_N"),
            "median_time_s": median("completion_time_s"),
        }
    rs = list(ratios(rows).values())
    out["ratio_blind_over_ntrfc"] = {
        "operators": len(rs),
        "median": float(np.median(rs)) if rs else None,
        "p25": float(np.percentile(rs, 25)) if rs else None,
        "p75": float(np.percentile(rs, 75)) if rs else None,
        "fraction_above_1": float(np.mean(np.array(rs) > 1.0)) if rs else None,
    }
    return out


def _cell(r: dict[str, Any] | None) -> str:
    if r is None:
        return f"{'-':>22}"
    if r.get("status") != "ok":
        return f"{'error':>22}"
    if not r["completed"]:
        return f"{'failed':>22}"
    return f"{r['work_eq13']:>8.2g} J {r['peak_contact_force_N']:>5.1f} N {r['completion_time_s']:>4.1f}s"


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _table(rows: list[dict[str, Any]], summary: dict[str, Any]) -> str:
    names = list(dict.fromkeys(r["operator"] for r in rows))[:3]
    lines = [
        "Dual peg-in-the-holes, reacting operators: work (Eq 13), peak contact force, completion time",
        "",
        f"{'':<16}" + "".join(f"{n:>22}" for n in names),
    ]
    for cond in CONDITIONS:
        found = {r["operator"]: r for r in _runs(rows, cond)}
        lines.append(f"{cond:<16}" + "".join(_cell(found.get(n)) for n in names))
    rs = ratios(rows)
    lines.append(f"{'blind / NTRFC':<16}" + "".join(f"{rs[n]:>22.2f}" if n in rs else f"{'-':>22}" for n in names))
    lines += ["", f"Population of {len({r['operator'] for r in rows})} operators (medians over completed runs):"]
    for cond in CONDITIONS:
        s = summary[cond]
        errors = f" ({s['errors']} errors)" if s["errors"] else ""
        lines.append(
            f"  {cond:<14} completed {s['completed']}/{s['runs']}{errors}, work {_fmt(s['median_work_J'], '.3g')} J, "
            f"peak force {_fmt(s['median_peak_force_N'], '.1f')} N, time {_fmt(s['median_time_s'], '.2f')} s"
        )
    r = summary["ratio_blind_over_ntrfc"]
    if r["operators"]:
        lines.append(
            f"  blind / NTRFC work over {r['operators']} operators who completed both: median {r['median']:.2f} "
            f"(quartiles {r['p25']:.2f} to {r['p75']:.2f}); lower work with FRHC/NTRFC for "
            f"{100 * r['fraction_above_1']:.0f} % of them (paper: every subject, ratios 2.8 to 4.2)"
        )
    return "\n".join(lines)


def _chart(rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> Path:
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for cond in CONDITIONS:
        done = [r for r in _runs(rows, cond) if _ok(r)]
        work = np.array([max(r["work_eq13"], 1e-6) for r in done])
        label = f"{cond} ({len(done)}/{summary[cond]['runs']} completed)"
        if len(work):
            axes[0].hist(work, bins=np.geomspace(work.min(), work.max() * 1.01 + 1e-9, 20), alpha=0.6, label=label)
            axes[1].hist([r["peak_contact_force_N"] for r in done], bins=20, alpha=0.6, label=cond)
    axes[0].set_xscale("log")
    axes[0].set_xlabel("work on the environment, Eq 13 (J)")
    if axes[0].patches:
        axes[0].legend(fontsize=8)
    axes[1].set_xlabel("peak contact force (N)")
    rs = np.array(list(ratios(rows).values()))
    if len(rs):
        axes[2].hist(rs, bins=np.geomspace(max(rs.min(), 1e-3), rs.max() * 1.01 + 1e-9, 20))
        axes[2].set_xscale("log")
        axes[2].axvspan(2.8, 4.2, color="tab:green", alpha=0.2, label="paper's 3 subjects")
        axes[2].axvline(1.0, color="k", lw=0.8)
        axes[2].legend(fontsize=8)
    axes[2].set_xlabel("work ratio blind / NTRFC, per operator")
    for ax in axes:
        ax.set_ylabel("runs" if ax is not axes[2] else "operators")
        ax.grid(alpha=0.3)
    fig.suptitle("Dual peg-in-the-holes over a population of reacting operators")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
