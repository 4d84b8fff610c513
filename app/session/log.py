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

from app.controller.frhc import ControllerOutput
from app.session.loop import STAGES, ServoLoop
from app.spatial import Array, matrix_to_quat

XYZ = ("x", "y", "z")
POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")
DELTA_X = ("x", "y", "z", "gamma", "beta", "alpha")
WRENCH = ("fx", "fy", "fz", "mx", "my", "mz")
TWIST = ("vx", "vy", "vz", "wx", "wy", "wz")
INT_COLUMNS = ("deadman", "reference", "reflection", "contacts", "faults")


def log_columns(n_joints: int) -> list[str]:
    """Column names of the log for a device with ``n_joints`` joints, in row order."""
    joints = [f"{i}" for i in range(n_joints)]

    def group(prefix: str, names: tuple[str, ...] | list[str]) -> list[str]:
        return [f"{prefix}_{s}" for s in names]

    return [
        "t",
        *group("q", joints),
        *group("grip", POSE),
        *group("hand_target", XYZ),
        *group("delta_x", DELTA_X),
        *group("delta_x_cmd", DELTA_X),
        *group("cmd", TWIST),
        *group("tool", POSE),
        *group("F_S", WRENCH),
        *group("F_S_task", WRENCH),
        *group("F_MRF", WRENCH),
        *group("contact_MRF", WRENCH),
        *group("G_F_T", WRENCH),
        *group("G_F_R", WRENCH),
        *group("G_F_D", WRENCH),
        *group("hand_G", WRENCH),
        *group("tau_T", joints),
        *group("tau_RD", joints),
        *group("tau_RDs", joints),
        *group("tau_G", joints),
        *group("tau", joints),
        *group("tau_sat", joints),
        *group("counts", joints),
        "assist_scale",
        "saturation_scale",
        *INT_COLUMNS,
        *(f"{s}_us" for s in STAGES),
    ]


def _pose7(T: Array) -> list[float]:
    return [*T[0:3, 3].tolist(), *matrix_to_quat(T[0:3, 0:3]).tolist()]


class TickLog:
    """Writes one row per tick into ``<directory>/part-NNNNN.parquet`` files of ``chunk`` rows.

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
        self._int_columns = [name in INT_COLUMNS or name.startswith("counts_") for name in self.columns]
        self._buf = np.zeros((chunk, len(self.columns)))
        self._rows = 0
        self._parts = 0
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ticklog")
        self._pending: Future[None] | None = None

    def record(self, loop: ServoLoop, out: ControllerOutput, hand_target: Array | None) -> None:
        """Append the state after one tick."""
        sw = loop.switches
        slave = loop.slave
        reading = loop.reading
        hand = hand_target[0:3, 3].tolist() if hand_target is not None else [float("nan")] * 3
        row = [
            loop.time,
            *reading.q.tolist(),
            *_pose7(out.T_0_G),
            *hand,
            *out.vectors[0:2].ravel().tolist(),
            *out.command.twist.tolist(),
            *_pose7(slave.T_w_MRF),
            *loop.ft.wrench_S.tolist(),
            *out.F_S_task.tolist(),
            *out.F_MRF.tolist(),
            *slave.wrench_MRF_contact.tolist(),
            *out.G_F_T.tolist(),
            *out.G_F_R.tolist(),
            *out.G_F_D.tolist(),
            *reading.wrench_G.tolist(),
            *out.torques[0:6].ravel().tolist(),
            *out.counts.tolist(),
            out.assist_scale,
            out.saturation_scale,
            sw.deadman,
            sw.reference,
            sw.reflection,
            slave.contact.count,
            int(out.faults),
            *(loop.stage_ns / 1000.0).tolist(),
        ]
        self._buf[self._rows] = row
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
