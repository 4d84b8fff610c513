"""The results table of a sweep: Parquet parts written as points finish, one table at the end.

Layout of an output directory::

    sweep.json              the sweep's fingerprint, fields and metrics (a resume must match it);
                            ``experiment.json`` for an experiment (``kind``)
    parts/part-000003.parquet  rows as they finished (atomic: written under a hidden name, renamed)
    results.parquet         every row, sorted by point, written when the sweep ends
    <metric>.png            the plot

Columns: ``point`` (its index in the sweep), the varied fields (named as written in the sweep
file), the metrics, ``status`` (``"ok"`` or ``"error"``) and ``error`` (one line, empty when ok).
A crash loses at most the rows of one flush interval; a re-run reads the parts and skips the
points they hold.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from app.errors import ConfigError, Interrupted

#: Summary metrics of a point: the results' columns after the varied fields, with their types.
METRICS: dict[str, type] = {
    "work_eq13": float,
    "peak_contact_force_N": float,
    "peak_contact_moment_Nm": float,
    "rms_contact_force_N": float,
    "contact_fraction": float,
    "task_completed": bool,
    "task_time_s": float,
    "fault_ticks": int,
    "saturated_ticks": int,
    "watchdog_trips": int,
    "simulated_s": float,
}


def metrics_row(summary: dict[str, Any]) -> dict[str, Any]:
    """The :data:`METRICS` of a session summary (``task_*`` None without a task)."""
    task = summary.get("task") or {}
    return {
        "work_eq13": summary["work_eq13"],
        "peak_contact_force_N": summary["peak_contact_force_N"],
        "peak_contact_moment_Nm": summary["peak_contact_moment_Nm"],
        "rms_contact_force_N": summary["rms_contact_force_N"],
        "contact_fraction": summary["contact_fraction"],
        "task_completed": task.get("completed"),
        "task_time_s": task.get("time_s"),
        "fault_ticks": sum(summary["faults"].values()),
        "saturated_ticks": summary["saturated_ticks"],
        "watchdog_trips": summary["watchdog_trips"],
        "simulated_s": summary["simulated_s"],
    }


_ARROW: dict[type, pa.DataType] = {float: pa.float64(), int: pa.int64(), bool: pa.bool_(), str: pa.string()}


def arrow_schema(fields: dict[str, type], metrics: dict[str, type]) -> pa.Schema:
    """The table's schema: ``point``, the fields, the metrics, ``status``, ``error``.

    A field of kind ``list`` (a whole vector) is stored as its JSON text.
    """
    cols = [pa.field("point", pa.int64())]
    cols += [pa.field(name, _ARROW.get(kind, pa.string())) for name, kind in {**fields, **metrics}.items()]
    cols += [pa.field("status", pa.string()), pa.field("error", pa.string())]
    return pa.schema(cols)


def _cell(value: Any, dtype: pa.DataType) -> Any:
    if value is None:
        return None
    if dtype == pa.string() and not isinstance(value, str):
        return json.dumps(value)
    if dtype == pa.float64():
        return float(value)
    return value


class ResultsWriter:
    """Collects rows and writes them as Parquet parts every ``flush_s`` seconds (and at close).

    Args:
        out_dir: The sweep's output directory.
        schema: From :func:`arrow_schema`.
        identity: What makes two runs the same sweep (fingerprint, fields): checked against a
            ``<kind>.json`` already in ``out_dir``.
        source, field: The sweep file and its field (or the command and its argument), named in
            the error when ``out_dir`` holds another sweep.
        flush_s: Longest time (s) a finished row waits in memory.
        kind: What the rows are the results of (``sweep``, ``experiment``), for messages.
    """

    def __init__(
        self,
        out_dir: Path,
        schema: pa.Schema,
        identity: dict[str, Any],
        source: str | Path,
        flush_s: float = 2.0,
        kind: str = "sweep",
        field: str = "<file>",
    ) -> None:
        self.out_dir = out_dir
        self.parts = out_dir / "parts"
        self.schema = schema
        self.flush_s = flush_s
        meta = out_dir / f"{kind}.json"
        if meta.exists():
            old = json.loads(meta.read_text())
            if old != identity:
                raise ConfigError(
                    source, field, f"{out_dir} holds the results of another {kind}; give another --out or remove it"
                )
        # What this writer adds to the folder, identity file first (:meth:`discard`).
        self._made = [q for q in (meta, self.parts) if not q.exists()]
        self.parts.mkdir(parents=True, exist_ok=True)
        meta.write_text(json.dumps(identity, indent=1))
        self._rows: list[dict[str, Any]] = []
        self._last = time.monotonic()
        self._n_parts = len(list(self.parts.glob("part-*.parquet")))

    def finished(self) -> set[int]:
        """Points already in the parts (a resumed sweep skips them)."""
        files = sorted(self.parts.glob("part-*.parquet"))
        if not files:
            return set()
        return set(pq.read_table(files, columns=["point"]).column("point").to_pylist())

    def add(self, row: dict[str, Any]) -> None:
        self._rows.append(row)
        if time.monotonic() - self._last >= self.flush_s:
            self.flush()

    def flush(self) -> None:
        """Write the rows held as one part (under a hidden name, then renamed)."""
        self._last = time.monotonic()
        if not self._rows:
            return
        columns = {f.name: [_cell(r.get(f.name), f.type) for r in self._rows] for f in self.schema}
        table = pa.table(columns, schema=self.schema)
        name = f"part-{self._n_parts:06d}.parquet"
        tmp = self.parts / f".{name}.tmp"
        pq.write_table(table, tmp)
        os.replace(tmp, self.parts / name)
        self._n_parts += 1
        self._rows.clear()

    def abandon(self) -> None:
        """The run stops unfinished because its engine failed (a Ray cluster that does not answer,
        workers that die while loading): the rows held are written (a re-run resumes from them),
        and if the run kept none at all, the identity file and parts folder this writer made are
        removed, so no folder is claimed by results that do not exist (what was there is kept)."""
        self.flush()
        if self._n_parts:
            return
        for made in self._made:
            with contextlib.suppress(OSError):  # not empty, or gone: nothing of ours to remove
                made.rmdir() if made.is_dir() else made.unlink()

    def interrupted(self, exc: KeyboardInterrupt, done: int, total: int, unit: str = "points") -> Interrupted:
        """Flush the rows held; the :class:`~app.errors.Interrupted` to raise for ``exc`` (SIGINT or
        SIGTERM), saying that ``done`` of ``total`` ``unit`` are kept and a re-run resumes."""
        self.flush()
        signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
        return Interrupted(signum, f"{done} of {total} {unit} are in {self.parts}; the same command resumes")

    def close(self) -> Path:
        """Flush, then write ``results.parquet`` (every part, sorted by point); returns its path."""
        self.flush()
        files = sorted(self.parts.glob("part-*.parquet"))
        table = pq.read_table(files, schema=self.schema) if files else self.schema.empty_table()
        table = table.sort_by("point")
        path = self.out_dir / "results.parquet"
        tmp = self.out_dir / ".results.parquet.tmp"
        pq.write_table(table, tmp)
        os.replace(tmp, path)
        return path
