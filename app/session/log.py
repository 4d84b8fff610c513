"""The per-tick log: a Parquet dataset written incrementally, one part file per chunk of ticks.

Each part is a complete Parquet file when it is closed, so a crash mid-run leaves every finished
part readable: ``pyarrow.parquet.read_table(log_dir)`` or ``pandas.read_parquet(log_dir)`` open
the directory as one table.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from app.controller.layout import SCALARS, TORQUE_ROWS, TWIST_AXES, VECTOR_ROWS, WRENCH_AXES
from app.session.tick import STAGES, TickRecord
from app.spatial import Array, matrix_to_quat

XYZ = ("x", "y", "z")
POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")
INT_COLUMNS = ("deadman", "reference", "reflection", "contacts", "faults")


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


class TickLog:
    """Writes one row per tick into ``<directory>/part-NNNNN.parquet`` files of ``chunk`` rows.

    A tick observer (:meth:`~app.session.loop.ServoLoop.observe`).

    Encoding and writing a part happen on a background thread while the servo loop fills the
    next buffer, so recording does not stall a paced loop for milliseconds once a second.

    Args:
        directory: Created if missing; existing part files are removed first.
        n_joints: Joints of the device (sets the columns).
        chunk: Rows per part file (1000 = one second at 1 kHz).
    """

    def __init__(self, directory: Path, n_joints: int, chunk: int = 1000) -> None:
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        for old in directory.glob("part-*.parquet"):
            old.unlink()
        self.columns = log_columns(n_joints)
        self._at = _blocks(n_joints)
        self._int_columns = [name in INT_COLUMNS or name.startswith("counts_") for name in self.columns]
        self._buf = np.zeros((chunk, len(self.columns)))
        self._rows = 0
        self._parts = 0
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ticklog")
        self._pending: Future[None] | None = None

    def on_tick(self, tick: TickRecord) -> None:
        """Append the state after one tick."""
        out = tick.out
        reading = tick.reading
        row = self._buf[self._rows]
        c = self._at
        row[c["t"]] = tick.time
        row[c["q"]] = reading.q
        _pose7(reading.T_0_G, row[c["grip"]])
        hand = tick.hand_target
        row[c["hand_target"]] = hand[0:3, 3] if hand is not None else np.nan
        row[c["vectors"]] = out.vectors.ravel()
        row[c["cmd"]] = out.command.twist
        _pose7(tick.T_w_MRF, row[c["tool"]])
        row[c["F_S"]] = tick.ft.wrench_S
        row[c["contact_MRF"]] = tick.contact_wrench_MRF
        row[c["hand_G"]] = reading.wrench_G
        row[c["torques"]] = out.torques.ravel()
        row[c["counts"]] = out.counts
        row[c["scalars"]] = out.scalars
        row[c["switches"]] = (tick.deadman, tick.reference, tick.reflection, tick.contact.count, int(out.faults))
        row[c["stages"]] = tick.stage_ns
        row[c["stages"]] *= 1e-3
        self._rows += 1
        if self._rows == len(self._buf):
            self.flush()

    def flush(self) -> None:
        """Hand the buffered rows to the writer thread as the next part file."""
        if self._rows == 0:
            return
        self._wait()  # at most one part in flight: its rows are the buffer we are about to reuse
        rows = self._buf[: self._rows].copy()
        path = self.directory / f"part-{self._parts:05d}.parquet"
        self._pending = self._writer.submit(self._write, rows, path)
        self._parts += 1
        self._rows = 0

    def _write(self, rows: Array, path: Path) -> None:
        arrays = [
            pa.array(rows[:, i].astype(np.int32) if is_int else rows[:, i])
            for i, is_int in enumerate(self._int_columns)
        ]
        pq.write_table(pa.Table.from_arrays(arrays, names=self.columns), path)

    def _wait(self) -> None:
        if self._pending is not None:
            self._pending.result()  # re-raises a write error here, in the loop's thread
            self._pending = None

    def close(self) -> None:
        """Write what is buffered and wait until every part is on disk."""
        self.flush()
        self._wait()
        self._writer.shutdown()


def read_log(directory: Path) -> pa.Table:
    """The whole log as one Arrow table (``.to_pandas()`` for a DataFrame)."""
    return pq.read_table(directory)


def _pose7(T: Array, out: Array) -> None:
    """Position and wxyz quaternion of the pose ``T`` (4, 4) into ``out`` (7,)."""
    out[0:3] = T[0:3, 3]
    out[3:7] = matrix_to_quat(T[0:3, 0:3])
