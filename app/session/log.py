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
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numba import njit

from app.compiled import entry_point, is_f8
from app.controller.layout import SCALARS, TORQUE_ROWS, TWIST_AXES, VECTOR_ROWS, WRENCH_AXES
from app.errors import ConfigError
from app.session.pacer import ordinary_priority
from app.session.tick import STAGES, TickRecord
from app.spatial import Array, IntArray, quat_into

if TYPE_CHECKING:
    from app.session.loop import LoopConfig

XYZ = ("x", "y", "z")
POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")
#: ``device_link`` is :class:`~app.device.boundary.LinkStatus` (0 OK, 1 ramping, 2 stalled: the
#: watchdog zeroed the force, 3 disconnected); 0 for a joint-space plant simulated in process.
INT_COLUMNS = (
    "deadman",
    "reference",
    "reflection",
    "contacts",
    "faults",
    "watchdog_trips",
    "slave_status",
    "device_link",
)


def _group(prefix: str, names: tuple[str, ...] | list[str]) -> list[str]:
    return [f"{prefix}_{s}" for s in names]


def _layout(n_joints: int) -> list[tuple[str, list[str]]]:
    """The row's blocks in order: each block's name and its column names.

    The controller's blocks (every row of its vectors and torques, and its scale factors) are
    named from :mod:`app.controller.layout`, so the columns follow the kernel's layout.
    """
    joints = [f"{i}" for i in range(n_joints)]
    return [
        ("t", ["t"]),
        ("q", _group("q", joints)),
        ("grip", _group("grip", POSE)),
        ("hand_target", _group("hand_target", XYZ)),
        ("vectors", [c for name, axes in VECTOR_ROWS for c in _group(name, axes)]),
        ("cmd", _group("cmd", TWIST_AXES)),
        ("tool", _group("tool", POSE)),
        ("F_S", _group("F_S", WRENCH_AXES)),
        ("contact_MRF", _group("contact_MRF", WRENCH_AXES)),
        ("hand_G", _group("hand_G", WRENCH_AXES)),
        ("torques", [c for name in TORQUE_ROWS for c in _group(name, joints)]),
        ("counts", _group("counts", joints)),
        ("scalars", list(SCALARS)),
        ("switches", list(INT_COLUMNS)),
        ("link_force", ["link_force"]),
        ("stages", [f"{s}_us" for s in STAGES]),
    ]


def log_columns(n_joints: int) -> list[str]:
    """Column names of the log for a device with ``n_joints`` joints, in row order."""
    return [c for _, columns in _layout(n_joints) for c in columns]


def _blocks(n_joints: int) -> dict[str, slice]:
    """Where each block of :func:`_layout` lies in a row."""
    at: dict[str, slice] = {}
    start = 0
    for name, columns in _layout(n_joints):
        at[name] = slice(start, start + len(columns))
        start += len(columns)
    return at


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
    """

    def __init__(
        self,
        directory: Path,
        n_joints: int,
        period: float = 1e-3,
        flush_interval: float = 0.1,
        meta: dict[str, Any] | None = None,
    ) -> None:
        if not (flush_interval > 0 and period > 0):
            raise ValueError(f"flush_interval and period must be positive, got {flush_interval}, {period}")
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        for old in [*directory.glob("part-*.parquet"), *directory.glob(".part-*.tmp")]:
            old.unlink()
        write_json(directory / META_FILE, {**(meta or {}), "servo_period": period, "columns_version": 4})
        self.columns = log_columns(n_joints)
        # Where each block of the row starts, in the order of _layout (what _fill_row writes).
        self._starts = np.array([b.start for b in _blocks(n_joints).values()], dtype=np.int64)
        self._no_hand = np.full((4, 4), np.nan)
        self._hand = np.empty((4, 4))
        self._fill: Callable[..., None] | None = None
        self._int_columns = [name in INT_COLUMNS or name.startswith("counts_") for name in self.columns]
        self._buf = np.zeros((max(1, round(flush_interval / period)), len(self.columns)))
        self._rows = 0
        self._parts = 0
        # Ordinary scheduling: started by a loop at real-time priority, the writer would inherit it.
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ticklog", initializer=ordinary_priority)
        self._pending: list[Future[None]] = []

    def on_tick(self, tick: TickRecord) -> None:
        """Append the state after one tick (one compiled call: :func:`_fill_row`)."""
        out = tick.out
        reading = tick.reading
        hand = tick.hand_target
        if hand is None:
            hand = self._no_hand
        elif not is_f8(hand, (4, 4)):
            self._hand[:] = hand
            hand = self._hand
        args = (
            self._buf[self._rows], self._starts, tick.time, reading.q, reading.T_0_G, hand,
            tick.hand_target is not None, out.vectors, out.command.twist, tick.T_w_MRF, tick.ft.wrench_S,
            tick.contact_wrench_MRF, reading.wrench_G, out.torques, out.counts, out.scalars, tick.deadman,
            tick.reference, tick.reflection, tick.contact.count, int(out.faults), reading.watchdog_trips,
            tick.slave_status, int(tick.device_link), tick.link_force, tick.stage_ns,
        )  # fmt: skip
        if self._fill is None:
            # The same buffers every tick: the compiled row writer for their types, once.
            self._fill = entry_point(_fill_row, *args)
        self._fill(*args)
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
        pq.write_table(pa.Table.from_arrays(arrays, names=self.columns), tmp)
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


def read_log(directory: Path, n_joints: int | None = None) -> pa.Table:
    """The whole log as one Arrow table (``.to_pandas()`` for a DataFrame): every complete part.

    Args:
        directory: The log directory.
        n_joints: If given, every part must hold exactly :func:`log_columns` of this many joints.

    Raises:
        ConfigError: Naming the first part that is not a readable Parquet file (truncated, empty,
            random bytes) or, with ``n_joints``, whose columns are not this log's.
    """
    expected = None if n_joints is None else log_columns(n_joints)
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


@njit(cache=True)
def _pose7(T: Array, out: Array) -> None:
    """Position and wxyz quaternion of the pose ``T`` (4, 4) into ``out`` (7,)."""
    out[0], out[1], out[2] = T[0, 3], T[1, 3], T[2, 3]
    quat_into(T[0:3, 0:3], out[3:7])


@njit(cache=True)
def _put(row: Array, at: int, values: Array | IntArray) -> int:
    """Copy ``values`` (any shape, row-major) into ``row`` from ``at``; return the next index."""
    for v in values.ravel():
        row[at] = v
        at += 1
    return at


@njit(cache=True)
def _fill_row(
    row: Array,
    starts: IntArray,
    t: float,
    q: Array,
    T_0_G: Array,
    hand: Array,
    hand_on: bool,
    vectors: Array,
    twist: Array,
    T_w_MRF: Array,
    F_S: Array,
    contact_MRF: Array,
    wrench_G: Array,
    torques: Array,
    counts: IntArray,
    scalars: Array,
    deadman: bool,
    reference: bool,
    reflection: bool,
    contacts: int,
    faults: int,
    watchdog_trips: int,
    slave_status: int,
    device_link: int,
    link_force: float,
    stage_ns: IntArray,
) -> None:
    """One log row (the blocks of :func:`_layout`, starting at ``starts``) from one tick's arrays."""
    row[starts[0]] = t
    _put(row, starts[1], q)
    _pose7(T_0_G, row[starts[2] : starts[2] + 7])
    for a in range(3):
        row[starts[3] + a] = hand[a, 3] if hand_on else np.nan
    _put(row, starts[4], vectors)
    _put(row, starts[5], twist)
    _pose7(T_w_MRF, row[starts[6] : starts[6] + 7])
    _put(row, starts[7], F_S)
    _put(row, starts[8], contact_MRF)
    _put(row, starts[9], wrench_G)
    _put(row, starts[10], torques)
    _put(row, starts[11], counts)
    _put(row, starts[12], scalars)
    at = starts[13]
    row[at], row[at + 1], row[at + 2] = 1.0 if deadman else 0.0, 1.0 if reference else 0.0, 1.0 if reflection else 0.0
    row[at + 3], row[at + 4], row[at + 5], row[at + 6] = contacts, faults, watchdog_trips, slave_status
    row[at + 7] = device_link
    row[starts[14]] = link_force
    at = starts[15]
    for v in stage_ns:
        row[at] = v * 1e-3
        at += 1


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
