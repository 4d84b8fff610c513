"""The per-tick log: a Parquet dataset written incrementally, one part file per flush interval.

Crash safety: a part is written under a hidden temporary name (``.part-NNNNN.parquet.tmp``) and
renamed to ``part-NNNNN.parquet`` only once complete, and the rename is atomic, so a crash at any
moment (``kill -9`` included) leaves only complete parts under their final names, and at most one
flush interval of ticks (0.1 s by default) is lost. Readers ignore the temporary files (pyarrow
skips names starting with ``.`` or ``_``, so also the log's ``_meta.json``): ``read_log(log_dir)``, ``pyarrow.parquet.read_table(log_dir)``
or ``pandas.read_parquet(log_dir)`` open the directory as one table.
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


#: The log's description beside its parts (see :class:`TickLog`).
META_FILE = "_meta.json"
#: Parts handed to the writer thread and not yet on disk before ``flush`` waits (bounds memory if
#: the disk stalls; the loop never waits while the writer keeps up).
MAX_PENDING_PARTS = 64


class TickLog:
    """Writes one row per tick into ``<directory>/part-NNNNN.parquet`` files, one per flush interval.

    A tick observer (:meth:`~app.session.loop.ServoLoop.observe`).

    Encoding and writing a part happen on a background thread while the servo loop fills the
    next buffer, so recording does not stall a paced loop.

    Args:
        directory: Created if missing; existing part files are removed first.
        n_joints: Joints of the device (sets the columns).
        period: Servo period (s).
        flush_interval: Simulated seconds of ticks per part: the most a crash can lose.
        meta: What produced the log (scene, device, session files...), written to ``_meta.json``
            beside the parts: a replay rebuilds the view from it (:func:`loop_meta`).
        objects: Names of the scene's dynamic objects (``scene.bodies`` order): one pose block
            each, as in the loop's state row.
    """

    def __init__(
        self,
        directory: Path,
        n_joints: int,
        period: float = 1e-3,
        flush_interval: float = 0.1,
        meta: dict[str, Any] | None = None,
        objects: tuple[str, ...] = (),
    ) -> None:
        if not (flush_interval > 0 and period > 0):
            raise ValueError(f"flush_interval and period must be positive, got {flush_interval}, {period}")
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        for old in [*directory.glob("part-*.parquet"), *directory.glob(".part-*.tmp")]:
            old.unlink()
        write_json(directory / META_FILE, {**(meta or {}), "servo_period": period, "columns_version": 4})
        self.columns = log_columns(n_joints, objects)
        self._width = len(self.columns)
        self._int_columns = [name in INT_COLUMNS or name.startswith("counts_") for name in self.columns]
        self._buf = np.zeros((max(1, round(flush_interval / period)), len(self.columns)))
        self._rows = 0
        self._parts = 0
        # Ordinary scheduling at the lowest niceness: started by a loop at real-time priority, the
        # writer would inherit it; at nice 0 it stalls an unpaced loop on the same CPU.
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ticklog", initializer=background_priority)
        self._pending: list[Future[None]] = []

    def on_tick(self, tick: TickRecord) -> None:
        """Append the state after one tick: the logged part of its state row, in one copy."""
        self._buf[self._rows] = tick.state()[: self._width]
        self._rows += 1
        if self._rows == len(self._buf):
            self.flush()

    def flush(self) -> None:
        """Hand the buffered rows to the writer thread as the next part file."""
        if self._rows == 0:
            return
        self._collect(wait=len(self._pending) >= MAX_PENDING_PARTS)
        rows = self._buf[: self._rows].copy()
        name = f"part-{self._parts:05d}.parquet"
        self._pending.append(self._writer.submit(self._write, rows, self.directory / f".{name}.tmp", name))
        self._parts += 1
        self._rows = 0

    def _write(self, rows: Array, tmp: Path, name: str) -> None:
        arrays = [
            pa.array(rows[:, i].astype(np.int32) if is_int else rows[:, i])
            for i, is_int in enumerate(self._int_columns)
        ]
        # Neither dictionaries nor per-column statistics: nothing reads them (the log is read
        # whole), and with them a 100-row part of peg_ntrfc's 175 columns took 4.2 ms of CPU
        # instead of 2.7 and 143 kB instead of 118 (the writer shares the loop's CPU).
        table = pa.Table.from_arrays(arrays, names=self.columns)
        pq.write_table(table, tmp, use_dictionary=False, write_statistics=False)
        os.replace(tmp, tmp.with_name(name))

    def _collect(self, wait: bool) -> None:
        """Forget finished writes, re-raising a write error here in the loop's thread; with
        ``wait``, first wait for the oldest."""
        if wait and self._pending:
            self._pending[0].result()
        while self._pending and self._pending[0].done():
            self._pending.pop(0).result()

    def close(self) -> None:
        """Write what is buffered and wait until every part is on disk."""
        self.flush()
        for future in self._pending:
            future.result()
        self._pending.clear()
        self._writer.shutdown()


def read_log(directory: Path, n_joints: int | None = None, objects: tuple[str, ...] = ()) -> pa.Table:
    """The whole log as one Arrow table (``.to_pandas()`` for a DataFrame): every complete part.

    Args:
        directory: The log directory.
        n_joints: If given, every part must hold exactly :func:`log_columns` of this many joints
            and of the dynamic objects named ``objects``.

    Raises:
        ConfigError: Naming the first part that is not a readable Parquet file (truncated, empty,
            random bytes) or, with ``n_joints``, whose columns are not this log's.
    """
    expected = None if n_joints is None else log_columns(n_joints, objects)
    tables = []
    for part in sorted(directory.glob("part-*.parquet")):
        try:
            table = pq.read_table(part)
        except (pa.ArrowException, OSError) as exc:
            reason = " ".join(str(exc).split())[:200]
            raise ConfigError(part, "<file>", f"not a readable log part: {reason}") from None
        if expected is not None and table.column_names != expected:
            missing = sorted(set(expected) - set(table.column_names))
            extra = sorted(set(table.column_names) - set(expected))
            diff = f"missing {', '.join(missing[:3]) or 'none'}; unknown {', '.join(extra[:3]) or 'none'}"
            raise ConfigError(part, "<file>", f"not a part of a {n_joints}-joint log ({diff})")
        tables.append(table)
    if not tables:
        raise ConfigError(directory, "<file>", "the log has no parts")
    return pa.concat_tables(tables)


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
        "session": None if session is None else str(session),
        "mode": config.gains.mode,
        # The q_* columns of a Cartesian device's log are its grip pose's coordinates.
        "cartesian": config.cartesian,
        "device_url": config.device_url,
    }
