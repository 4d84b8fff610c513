"""The paper's Table I experiment (Sec 4.3) with a population of operators that react.

Dual peg-in-the-holes, FRHC/NTRFC (wrench reflection plus slave accommodation,
``sessions/peg_ntrfc.toml``) against "blind" (neither, ``peg_blind.toml``). Each operator is a
:class:`~app.session.operators.ReactingOperator` drawn from literature ranges
(:func:`~app.session.operators.sample_population`, seeded); each runs both conditions once, as
points of the sweep engine (:func:`app.sweep.engine.run_points`: serially or on Ray, the same rows).

A run counts only if the task completes (both pegs 20 mm deep) within the time limit: a failed
run is reported as failed and its work is not averaged in. Reported per run: the work on the
environment (Eq 13) and its split into the term along the insertion axis ({MRF} z, the pegs'
axis) and the other five, the peak contact force, completion and its time. The table shows the
paper's layout for the first three operators, then the population (completion rates, medians and
quartiles, where the work goes, and the blind/NTRFC work ratio of every operator who completed
both), then every operator on one line. The chart (``table1.png``, 1600 x 1000 px) shows the
same. The paper measured lower work with FRHC/NTRFC for each of its three subjects (Table I:
1.66/2.55/1.51 J blind against 0.59/0.61/0.42 J, ratios 2.8 to 4.2). ``docs/experiment.md`` says
where every parameter of the task and the operators comes from, and how the result compares.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pyarrow.parquet as pq
from matplotlib.ticker import MaxNLocator
from tqdm import tqdm

from app.errors import EngineError
from app.session.log import write_json
from app.session.operators import OperatorParams, ReactingOperator, sample_population
from app.session.run import run_session
from app.session.spec import Session, load_session
from app.world.scene import with_home_offset

CONDITIONS = {"FRHC/NTRFC": "peg_ntrfc", "No Force Info": "peg_blind"}
NTRFC, BLIND = CONDITIONS
#: The paper's Table I (J) per condition, subjects 1-3.
PAPER = {NTRFC: (0.59, 0.61, 0.42), BLIND: (1.66, 2.55, 1.51)}
#: Index of the insertion axis among Eq 13's six {MRF} axes: the pegs point along {MRF} -z.
INSERTION_AXIS = 2
#: Longest simulated time (s) a run may take; an operator who has not finished by then failed.
TIME_LIMIT = 12.0
#: The columns of a run's row (:meth:`ExperimentPoint.__call__`) and their types.
RUN_METRICS: dict[str, type] = {
    "work_eq13": float,
    "peak_contact_force_N": float,
    "completed": bool,
    "completion_time_s": float,
    "simulated_s": float,
    "fault_ticks": int,
    "work_axial_J": float,
    "work_other_J": float,
}
#: The operator's parameters as columns of the results, with their types.
OPERATOR_COLUMNS: dict[str, type] = {k: type(v) for k, v in dataclasses.asdict(OperatorParams("")).items()}


@dataclass(frozen=True)
class ExperimentPoint:
    """One operator in one condition: the engine's task (picklable). Returns the run's row."""

    time_limit: float = TIME_LIMIT
    slave: str | None = None

    def session(self, op: OperatorParams, condition: str) -> Session:
        """The session of ``op`` in ``condition``: their hand, the time limit, and the tool starting
        over where they believe the holes are (the scene's home moved by their aim error), as a
        person positions the pegs by eye before pushing them in."""
        base = load_session(CONDITIONS[condition]).with_changes(slave=self.slave)
        hand = dataclasses.replace(base.data.hand, stiffness_trans=op.stiffness_trans, damping_trans=op.damping_trans)
        session = base.with_changes(hand=hand, duration=self.time_limit, seed=op.seed)
        return dataclasses.replace(session, scene=with_home_offset(session.scene, op.aim_offset()))

    def __call__(self, payload: tuple[OperatorParams, str]) -> dict[str, Any]:
        op, condition = payload
        session = self.session(op, condition)
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
            # Eq 13's terms are per {MRF} axis; z is the pegs' axis, the insertion.
            "work_axial_J": s["work_per_axis"][INSERTION_AXIS],
            "work_other_J": s["work_eq13"] - s["work_per_axis"][INSERTION_AXIS],
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

    Each run's row is kept in ``out_dir/parts`` as it finishes (:class:`app.sweep.results.ResultsWriter`):
    running the same experiment into ``out_dir`` again runs only the runs missing there.

    Raises:
        ConfigError: ``out_dir`` holds another experiment (other operators, time limit or slave).
        Interrupted: on SIGINT or SIGTERM, once the finished rows are kept; it says how many.
    """
    from app.sweep.engine import Engine
    from app.sweep.results import ResultsWriter, arrow_schema

    out_dir.mkdir(parents=True, exist_ok=True)
    ops = tuple(operators) if operators is not None else sample_population(n_operators, seed)
    points = [(k, (op, cond)) for k, (op, cond) in enumerate((op, c) for op in ops for c in CONDITIONS)]
    task = ExperimentPoint(time_limit, slave)
    # Rows are kept as they finish (a Ctrl-C keeps them; the same command resumes), in a folder
    # that holds this population, time limit and slave only.
    described = json.dumps([[dataclasses.asdict(op) for op in ops], dataclasses.asdict(task), CONDITIONS])
    identity = {"experiment": hashlib.sha256(described.encode()).hexdigest()[:16], "points": len(points)}
    schema = arrow_schema({"operator": str, "condition": str, **OPERATOR_COLUMNS}, RUN_METRICS)
    writer = ResultsWriter(out_dir, schema, identity, "frhc experiment", kind="experiment", field="--out")
    done = writer.finished()
    todo = [p for p in points if p[0] not in done]
    try:
        with (
            # The bar starts once the engine is up: a cluster that does not answer is one line.
            Engine(workers, address) as engine,
            tqdm(total=len(points), initial=len(done), unit="run", disable=not progress) as bar,
        ):
            for index, row in engine.run(task, todo):
                op, cond = points[index][1]
                writer.add({"point": index, "operator": op.name, "condition": cond, **dataclasses.asdict(op), **row})
                done.add(index)
                bar.update(1)
                if on_run is not None:
                    on_run(len(done), len(points))
    except KeyboardInterrupt as exc:
        # The engine has ended its workers (and its Ray instance) on the way here.
        raise writer.interrupted(exc, len(done), len(points), "runs") from None
    except EngineError:
        writer.abandon()
        raise
    results = writer.close()
    rows = pq.read_table(results).to_pylist()
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


def _quartiles(values: Sequence[float]) -> dict[str, float | None]:
    """Median and quartiles of ``values`` (None for none)."""
    if not len(values):
        return {"median": None, "p25": None, "p75": None}
    p25, median, p75 = (float(v) for v in np.percentile(values, [25, 50, 75]))
    return {"median": median, "p25": p25, "p75": p75}


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for cond in CONDITIONS:
        runs = _runs(rows, cond)
        done = [r for r in runs if _ok(r)]
        work = [r["work_eq13"] for r in done]
        axial = [r["work_axial_J"] for r in done]
        out[cond] = {
            "runs": len(runs),
            "completed": len(done),
            "errors": sum(1 for r in runs if r.get("status") != "ok"),
            "work_J": _quartiles(work),
            "work_axial_J": _quartiles(axial),
            "work_other_J": _quartiles([r["work_other_J"] for r in done]),
            # Where the work goes: the share along the insertion of the population's total.
            "axial_share": float(sum(axial) / sum(work)) if done and sum(work) > 0 else None,
            "peak_force_N": _quartiles([r["peak_contact_force_N"] for r in done]),
            "median_time_s": _quartiles([r["completion_time_s"] for r in done])["median"],
            "paper_J": list(PAPER[cond]),
        }
    rs = list(ratios(rows).values())
    q = _quartiles(rs)
    p25, p75 = q["p25"], q["p75"]
    out["ratio_blind_over_ntrfc"] = {
        "operators": len(rs),
        **q,
        # How many times the upper quartile is the lower: the spread of the middle half.
        "iqr_factor": p75 / p25 if p25 and p75 is not None else None,
        "fraction_above_1": float(np.mean(np.array(rs) > 1.0)) if rs else None,
        "paper": [b / n for b, n in zip(PAPER[BLIND], PAPER[NTRFC], strict=True)],
    }
    return out


def _cell(r: dict[str, Any] | None, detail: bool = False) -> str:
    """One run in a table cell, or why there is none: work, peak force and completion time (22
    characters), or with ``detail`` work (along the insertion + the rest) and peak force (34)."""
    if r is None or r.get("status") != "ok" or not r["completed"]:
        why = "-" if r is None else "error" if r.get("status") != "ok" else "failed"
        return f"{why:<34}" if detail else f"{why:>22}"
    if detail:
        return (
            f"{r['work_eq13']:8.3g} J ({r['work_axial_J']:7.2g} + {r['work_other_J']:7.2g}) "
            f"{r['peak_contact_force_N']:5.1f} N"
        )
    return f"{r['work_eq13']:>8.2g} J {r['peak_contact_force_N']:>5.1f} N {r['completion_time_s']:>4.1f}s"


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _spread(q: dict[str, float | None], spec: str) -> str:
    """Median (quartiles), or "-" for no values."""
    if q["median"] is None:
        return "-"
    return f"{_fmt(q['median'], spec)} ({_fmt(q['p25'], spec)}-{_fmt(q['p75'], spec)})"


def _table(rows: list[dict[str, Any]], summary: dict[str, Any]) -> str:
    operators = list(dict.fromkeys(r["operator"] for r in rows))
    names = operators[:3]
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
    lines += [
        "",
        f"Population of {len(operators)} operators, over completed runs: median (quartiles); "
        "work along the insertion + the rest:",
    ]
    for cond in CONDITIONS:
        s = summary[cond]
        errors = f" ({s['errors']} errors)" if s["errors"] else ""
        share = "-" if s["axial_share"] is None else f"{100 * s['axial_share']:.0f} %"
        paper = "/".join(f"{w:g}" for w in s["paper_J"])
        lines += [
            f"  {cond:<14} completed {s['completed']}/{s['runs']}{errors}, time {_fmt(s['median_time_s'], '.2f')} s",
            f"    work {_spread(s['work_J'], '.3g')} J (paper {paper} J); along the insertion "
            f"{_spread(s['work_axial_J'], '.3g')} J, the rest {_spread(s['work_other_J'], '.3g')} J; "
            f"{share} of all work along the insertion",
            f"    peak force {_spread(s['peak_force_N'], '.1f')} N",
        ]
    r = summary["ratio_blind_over_ntrfc"]
    if r["operators"]:
        paper = "/".join(f"{v:.1f}" for v in r["paper"])
        lines.append(
            f"  blind / NTRFC work over {r['operators']} operators who completed both: median {r['median']:.3g} "
            f"(quartiles {r['p25']:.3g} to {r['p75']:.3g}, a factor {r['iqr_factor']:.3g}); lower work with "
            f"FRHC/NTRFC for {100 * r['fraction_above_1']:.0f} % of them (paper: every subject, ratios {paper})"
        )
    lines += ["", "Per operator: work (along the insertion + the rest), peak force; blind / NTRFC work", ""]
    lines.append(f"{'':<14}{NTRFC:<36}{BLIND:<36}ratio")
    by_cond = {cond: {r["operator"]: r for r in _runs(rows, cond)} for cond in CONDITIONS}
    for name in operators:
        ratio = f"{rs[name]:.3g}" if name in rs else "-"
        lines.append(
            f"{name:<14}" + "".join(f"{_cell(by_cond[c].get(name), detail=True)}  " for c in CONDITIONS) + ratio
        )
    return "\n".join(lines)


#: Colour of each condition in the chart.
COLOURS = {NTRFC: "tab:blue", BLIND: "tab:orange"}


def _chart(rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> Path:
    """Table I as a 1600 x 1000 px figure: work per operator, where the work goes, peak forces
    and the blind/NTRFC ratio, each beside the paper's values."""
    plt.rcParams.update({"font.size": 12})
    fig, axes = plt.subplots(2, 2, figsize=(16, 10))
    ax_op, ax_split, ax_force, ax_ratio = axes.ravel()
    rs = ratios(rows)
    names = sorted(rs, key=rs.__getitem__)
    work = {c: {r["operator"]: r for r in _runs(rows, c) if _ok(r)} for c in CONDITIONS}
    x = np.arange(len(names))
    for cond in CONDITIONS:
        s = summary[cond]
        label = f"{cond} ({s['completed']}/{s['runs']} completed)"
        ax_op.semilogy(x, [max(work[cond][n]["work_eq13"], 1e-9) for n in names], "o", color=COLOURS[cond], label=label)
        lo, hi = min(PAPER[cond]), max(PAPER[cond])
        ax_op.axhspan(lo, hi, color=COLOURS[cond], alpha=0.15, label=f"paper, {cond}: {lo:g}-{hi:g} J")
    ax_op.set_xlim(-0.5, max(len(names), 1) - 0.5)
    ax_op.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax_op.set_xlabel("operator (who completed both), sorted by the blind / NTRFC ratio")
    ax_op.set_ylabel("work, Eq 13 (J)")
    ax_op.set_title("Work per operator")
    # Room above the paper's bands for the legend.
    ax_op.set_ylim(top=100.0)
    ax_op.legend(fontsize=10, loc="upper right", ncol=2)
    groups = [(c, key) for c in CONDITIONS for key in ("work_axial_J", "work_other_J")]
    data = [[max(r[key], 1e-9) for r in work[c].values()] for c, key in groups]
    if all(data):
        box = ax_split.boxplot(data, patch_artist=True, widths=0.6)
        for patch, (cond, _) in zip(box["boxes"], groups, strict=True):
            patch.set_facecolor(COLOURS[cond])
            patch.set_alpha(0.5)
    ax_split.set_yscale("log")
    ax_split.set_xticks(
        range(1, 5), [f"{c}\n{'along insertion' if k == 'work_axial_J' else 'the rest'}" for c, k in groups]
    )
    ax_split.set_ylabel("work (J)")
    ax_split.set_title("Where the work goes: along the insertion ({MRF} z), the other 5 axes")
    forces = [[r["peak_contact_force_N"] for r in work[c].values()] for c in CONDITIONS]
    if all(forces):
        box = ax_force.boxplot(forces, patch_artist=True, widths=0.6)
        for patch, cond in zip(box["boxes"], CONDITIONS, strict=True):
            patch.set_facecolor(COLOURS[cond])
            patch.set_alpha(0.5)
    ax_force.set_xticks(range(1, 3), list(CONDITIONS))
    ax_force.set_ylabel("peak contact force (N)")
    ax_force.set_title("Peak contact force per run")
    values = np.array([rs[n] for n in names])
    r = summary["ratio_blind_over_ntrfc"]
    if len(values):
        lo, hi = max(values.min(), 1e-3) / 1.1, values.max() * 1.1
        ax_ratio.hist(values, bins=np.geomspace(lo, hi, 25), color="tab:gray")
        ax_ratio.axvspan(min(r["paper"]), max(r["paper"]), color="tab:green", alpha=0.3, label="paper's 3 subjects")
        ax_ratio.axvline(r["median"], color="k", lw=2, label=f"median {r['median']:.3g}")
        for q in (r["p25"], r["p75"]):
            ax_ratio.axvline(q, color="k", lw=1, ls="--")
        ax_ratio.axvline(1.0, color="tab:red", lw=1, label="equal work")
        ax_ratio.set_xscale("log")
        ax_ratio.legend(fontsize=10)
    ax_ratio.set_xlabel("blind / NTRFC work, per operator (quartiles dashed)")
    ax_ratio.set_ylabel("operators")
    ax_ratio.set_title("Work ratio")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.suptitle(f"Table I: dual peg-in-the-holes, {len({r['operator'] for r in rows})} simulated operators")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
