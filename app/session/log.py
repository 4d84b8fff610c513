"""The per-tick log: a Parquet dataset written incrementally, with a raw tail that bounds a crash's loss.

Every flush interval (0.1 s of ticks by default) the loop hands its buffered rows to a writer
thread, which appends them to the log's tail, ``_tail-NNNNN.f8`` (the rows' float64 bytes, one
write), and keeps them for the next part. Once :data:`PART_SECONDS` of ticks are kept it writes them
as ``part-NNNNN.parquet`` and deletes that tail: a Parquet file costs ~2 ms of CPU whatever its
length (175 columns, each with its own chunk and page headers), so 100-row parts took ~24 us of
the writer's CPU per tick and 2000-row parts ~3.

Crash safety: a part is written under a hidden temporary name (``.part-NNNNN.parquet.tmp``) and
renamed to ``part-NNNNN.parquet`` only once complete, and the rename is atomic; the tail's rows
are in the kernel's page cache once their write returns, so a crash at any moment (``kill -9``
included) loses at most one flush interval of ticks. :func:`read_log` reads the parts and the tail
of the part that was never written (whole rows; its columns are in ``_meta.json``). Other
readers see the complete parts only: they ignore names starting with ``.`` or ``_``, so
``pyarrow.parquet.read_table(log_dir)`` or ``pandas.read_parquet(log_dir)`` open a finished log's
directory as one table.
"""

from __future__ import annotations

import json
import math
import os
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from app.errors import ConfigError
from app.session.files import META_FILE  # the log's description beside its parts (:class:`TickLog`)
from app.session.pacer import background_priority
from app.session.state import INT_COLUMNS, StateBlock
from app.session.tick import TickRecord
from app.spatial import Array

if TYPE_CHECKING:
    from app.session.loop import LoopConfig


def log_columns(n_joints: int, objects: tuple[str, ...] = ()) -> list[str]:
    """Column names of the log for a device with ``n_joints`` joints and a scene whose dynamic
    objects are named ``objects``, in row order: the logged blocks of the tick's state row
    (:func:`~app.session.state.state_layout`)."""
    block = StateBlock(n_joints, objects)
    return block.names[: block.n_logged]


#: Simulated seconds of ticks per Parquet part (the tail holds the part being gathered).
PART_SECONDS = 2.0
#: Flushes handed to the writer thread and not yet written before ``flush`` waits (bounds memory
#: if the disk stalls; the loop never waits while the writer keeps up).
MAX_PENDING_FLUSHES = 64


class TickLog:
    """Writes one row per tick into ``<directory>/part-NNNNN.parquet`` files (module docstring).

    A tick observer (:meth:`~app.session.loop.ServoLoop.observe`).

    Appending to the tail and encoding a part happen on a background thread while the servo loop
    fills the next buffer, so recording does not stall a paced loop.

    Args:
        directory: Created if missing; existing parts and tails are removed first.
        n_joints: Joints of the device (sets the columns).
        period: Servo period (s).
        flush_interval: Simulated seconds of ticks per write to the tail: the most a crash can lose.
        meta: What produced the log (scene, device, session files...), written to ``_meta.json``
            beside the parts: a replay rebuilds the view from it (:func:`loop_meta`).
        objects: Names of the scene's dynamic objects (``scene.bodies`` order): one pose block
            each, as in the loop's state row.
        part_interval: Simulated seconds of ticks per Parquet part (at least ``flush_interval``).
    """

    def __init__(
        self,
        directory: Path,
        n_joints: int,
        period: float = 1e-3,
        flush_interval: float = 0.1,
        meta: dict[str, Any] | None = None,
        objects: tuple[str, ...] = (),
        part_interval: float = PART_SECONDS,
    ) -> None:
        if not (flush_interval > 0 and period > 0):
            raise ValueError(f"flush_interval and period must be positive, got {flush_interval}, {period}")
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        for old in [*directory.glob("part-*.parquet"), *directory.glob(".part-*.tmp"), *directory.glob("_tail-*")]:
            old.unlink()
        self.columns = log_columns(n_joints, objects)
        meta = {**(meta or {}), "servo_period": period, "columns_version": 4, "columns": self.columns}
        write_json(directory / META_FILE, meta)
        self._width = len(self.columns)
        self._buf = np.zeros((max(1, round(flush_interval / period)), len(self.columns)))
        self._rows = 0
        self._part_rows = max(len(self._buf), round(part_interval / period))
        # The writer thread's state: the rows of the part being gathered, its tail file.
        self._kept: list[Array] = []
        self._n_kept = 0
        self._parts = 0
        self._tail: int | None = None
        # Ordinary scheduling at the lowest niceness: started by a loop at real-time priority, the
        # writer would inherit it; at nice 0 it stalls an unpaced loop on the same CPU.
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ticklog", initializer=background_priority)
        self._pending: list[Future[None]] = []

    def on_tick(self, tick: TickRecord) -> None:
        """Append the state after one tick: the logged part of its state row, in one copy."""
        self._buf[self._rows] = tick.state()[: self._width]
        self.row_written()

    @property
    def buffer(self) -> Array:
        """The rows not yet handed to the writer, (rows, columns): for an observer that writes the
        next row itself (:class:`~app.session.metrics.SessionMetrics`' ``log``) at :attr:`rows`,
        then calls :meth:`row_written`."""
        return self._buf

    @property
    def rows(self) -> int:
        """Where the next row goes in :attr:`buffer`."""
        return self._rows

    def row_written(self) -> None:
        """The row at :attr:`rows` holds the next tick: count it; hand the buffer to the writer when full."""
        self._rows += 1
        if self._rows == len(self._buf):
            self.flush()

    def flush(self) -> None:
        """Hand the buffered rows to the writer thread (appended to the tail at once)."""
        if self._rows == 0:
            return
        self._collect(wait=len(self._pending) >= MAX_PENDING_FLUSHES)
        self._pending.append(self._writer.submit(self._append, self._buf[: self._rows].copy()))
        self._rows = 0

    def _append(self, rows: Array) -> None:
        """Writer thread: append ``rows`` to the tail; write the part once it has its ticks."""
        if self._tail is None:
            self._tail = os.open(self.directory / _tail_name(self._parts), os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        data = rows.data.cast("B")
        while data:  # a regular file takes the whole write unless the disk fills (then it raises)
            data = data[os.write(self._tail, data) :]
        self._kept.append(rows)
        self._n_kept += len(rows)
        if self._n_kept >= self._part_rows:
            self._write_part()

    def _write_part(self) -> None:
        """Writer thread: the kept rows as the next part, then its tail deleted."""
        if not self._kept:
            return
        # Column-major: each column is contiguous, so Arrow takes it without a copy.
        rows = np.asfortranarray(np.concatenate(self._kept))
        name = f"part-{self._parts:05d}.parquet"
        tmp = self.directory / f".{name}.tmp"
        # Neither dictionaries nor per-column statistics: nothing reads them (the log is read
        # whole), and with them a 100-row part of peg_ntrfc's 175 columns took 4.2 ms of CPU
        # instead of 2.7 and 143 kB instead of 118 (the writer shares the loop's CPU).
        pq.write_table(_table(rows, self.columns), tmp, use_dictionary=False, write_statistics=False)
        os.replace(tmp, tmp.with_name(name))
        if self._tail is not None:
            os.close(self._tail)
            self._tail = None
        # After the rename: a crash in between leaves both, and readers skip a tail whose part exists.
        (self.directory / _tail_name(self._parts)).unlink(missing_ok=True)
        self._parts += 1
        self._kept.clear()
        self._n_kept = 0

    def _collect(self, wait: bool) -> None:
        """Forget finished writes, re-raising a write error here in the loop's thread; with
        ``wait``, first wait for the oldest."""
        if wait and self._pending:
            self._pending[0].result()
        while self._pending and self._pending[0].done():
            self._pending.pop(0).result()

    def close(self) -> None:
        """Write what is buffered as the last part and wait until every part is on disk."""
        self.flush()
        self._pending.append(self._writer.submit(self._write_part))
        try:
            for future in self._pending:
                future.result()
        finally:
            self._pending.clear()
            self._writer.shutdown()
            if self._tail is not None:  # a write failed (the disk is full): the tail stays as it is
                os.close(self._tail)
                self._tail = None


def _tail_name(part: int) -> str:
    """The tail holding the rows of part ``part`` until that part is written."""
    return f"_tail-{part:05d}.f8"


def _is_int(name: str) -> bool:
    """Whether the log stores column ``name`` as int32 (else float64)."""
    return name in INT_COLUMNS or name.startswith("counts_")


def _table(rows: Array, columns: list[str]) -> pa.Table:
    """The log's table of ``rows`` (n, len(columns)): the integer columns as int32."""
    arrays = [pa.array(rows[:, i].astype(np.int32) if _is_int(name) else rows[:, i]) for i, name in enumerate(columns)]
    return pa.Table.from_arrays(arrays, names=columns)


def _wrong_type(table: pa.Table) -> str | None:
    """The first column of ``table`` not of the type the log writes it as, described; else None."""
    for name, kind in zip(table.column_names, table.schema.types, strict=True):
        expected = pa.int32() if _is_int(name) else pa.float64()
        if kind != expected:
            return f"column {name} is {kind}, not {expected}"
    return None


def read_log(directory: Path | str, n_joints: int | None = None, objects: tuple[str, ...] = ()) -> pa.Table:
    """The whole log as one Arrow table (``.to_pandas()`` for a DataFrame): every complete part,
    then the whole rows of the tail of a run that stopped before writing its last part (a crash).

    Args:
        directory: The log directory (a path or its text, as a user types it).
        n_joints: If given, every part must hold exactly :func:`log_columns` of this many joints
            and of the dynamic objects named ``objects``.

    Raises:
        ConfigError: Naming the first part that is missing (the parts are numbered from 0 without
            a gap), is not a readable Parquet file (truncated, empty, random bytes), holds a
            column of another type than the log writes, or, with ``n_joints``, whose columns are
            not this log's.
    """
    directory = Path(directory)
    expected = None if n_joints is None else log_columns(n_joints, objects)
    tables: list[pa.Table] = []
    for k, part in enumerate(sorted(directory.glob("part-*.parquet"))):
        if part.name != f"part-{k:05d}.parquet":
            raise ConfigError(
                directory / f"part-{k:05d}.parquet", "<file>", f"missing (the log goes on at {part.name})"
            )
        try:
            table = pq.read_table(part)
        except (pa.ArrowException, OSError) as exc:
            reason = " ".join(str(exc).split())[:200]
            raise ConfigError(part, "<file>", f"not a readable log part: {reason}") from None
        wrong = _wrong_type(table)
        if wrong is not None:
            raise ConfigError(part, "<file>", f"not a log part: {wrong}")
        if expected is not None and table.column_names != expected:
            missing = sorted(set(expected) - set(table.column_names))
            extra = sorted(set(table.column_names) - set(expected))
            diff = f"missing {', '.join(missing[:3]) or 'none'}; unknown {', '.join(extra[:3]) or 'none'}"
            raise ConfigError(part, "<file>", f"not a part of a {n_joints}-joint log ({diff})")
        if tables and table.column_names != tables[0].column_names:  # parts of two logs
            raise ConfigError(part, "<file>", "its columns are not those of part-00000.parquet")
        tables.append(table)
    tail = directory / _tail_name(len(tables))
    if tail.exists():
        tables.append(_read_tail(tail, directory / META_FILE, tables[0].schema if tables else None))
    if not tables:
        raise ConfigError(directory, "<file>", "the log has no parts")
    return pa.concat_tables(tables)


def _read_tail(tail: Path, meta: Path, schema: pa.Schema | None) -> pa.Table:
    """The whole rows of a tail (:class:`TickLog`), with the columns ``meta`` names."""
    try:
        columns = json.loads(meta.read_text())["columns"]
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError(meta, "columns", "missing or unreadable: the log's tail cannot be read") from None
    if schema is not None and schema.names != columns:
        raise ConfigError(tail, "<file>", "its columns (in _meta.json) are not those of the log's parts")
    data = tail.read_bytes()
    width = 8 * len(columns)
    # A crash during a write leaves a partial last row: it is not part of the log.
    rows = np.frombuffer(data, dtype=np.float64, count=len(data) // width * len(columns)).reshape(-1, len(columns))
    return _table(np.asfortranarray(rows), columns)


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as JSON atomically (temporary file, then rename); non-finite floats become null.

    JSON has no NaN or infinity (Python's ``Infinity`` is not JSON): a non-finite value means
    "undefined" here, e.g. a peak force of a run whose contact model failed.
    """
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(_finite_json(data), indent=2, allow_nan=False))
    os.replace(tmp, path)


def _finite_json(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_json(v) for v in value]
    return value


def loop_meta(config: LoopConfig, session: Path | None = None) -> dict[str, Any]:
    """The ``_meta.json`` of a log of a loop built from ``config`` (files as strings, or None)."""
    return {
        "scene": None if config.scene.path is None else str(config.scene.path),
        "device": str(config.device.path),
        # What the device file held when the log was run: a replay refuses a file that differs.
        "device_identity": config.device.identity,
        # And the scene file's world (meshes, contact parameters, tool): likewise.
        "scene_identity": config.scene.identity,
        "session": None if session is None else str(session),
        "mode": config.gains.mode,
        # The q_* columns of a Cartesian device's log are its grip pose's coordinates.
        "cartesian": config.cartesian,
        "device_url": config.device_url,
    }
