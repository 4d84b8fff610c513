"""The log's tail: what a run that stops without closing its log (a crash) leaves readable."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.errors import ConfigError
from app.session.log import META_FILE, TickLog, read_log
from app.session.loop import LoopConfig, ServoLoop
from app.session.script import OperatorScript
from app.session.spec import load_session


def _open_log(tmp_path: Path, ticks: int) -> tuple[TickLog, np.ndarray]:
    """A probe loop logging ``ticks`` ticks (100 per flush, 250 per part), left open as a crash
    leaves it once the writer has caught up; returns the log and every row it was given."""
    session = load_session("probe_rate")
    loop = ServoLoop(LoopConfig.from_session(session))
    log = loop.observe(TickLog(tmp_path, loop.controller.out.n, loop.dt, 0.1, part_interval=0.25))
    operator = OperatorScript.for_loop(session.data, loop)
    rows = []
    for _ in range(ticks):
        operator.before_tick(loop)
        rows.append(loop.tick().state()[: len(log.columns)].copy())
    for future in log._pending:  # the writer has done what it was handed (nothing closes the log)
        future.result()
    return log, np.array(rows)


def _values(table: object) -> np.ndarray:
    return np.column_stack([table.column(c).to_numpy().astype(float) for c in table.column_names])  # type: ignore[attr-defined]


def test_a_log_left_open_reads_back_every_flushed_row(tmp_path: Path) -> None:
    """730 ticks: parts of 300 rows (whole flushes past 250) at 300 and 600, the tail holds the
    flush of 700; the 30 rows never flushed are the loss (under 0.1 s)."""
    log, rows = _open_log(tmp_path, 730)
    assert sorted(p.name for p in tmp_path.glob("part-*.parquet")) == ["part-00000.parquet", "part-00001.parquet"]
    table = read_log(tmp_path, 6)
    assert table.num_rows == 700
    np.testing.assert_array_equal(_values(table), rows[:700])
    # A write cut short by the crash: the partial row is not part of the log.
    with (tmp_path / "_tail-00002.f8").open("ab") as tail:
        tail.write(b"\x01" * 20)
    assert read_log(tmp_path).num_rows == 700
    assert read_log(str(tmp_path)).num_rows == 700  # the folder as typed, not a Path
    log.close()
    assert not list(tmp_path.glob("_tail-*"))
    np.testing.assert_array_equal(_values(read_log(tmp_path, 6)), rows)


def test_a_tail_whose_part_was_written_is_not_read_twice(tmp_path: Path) -> None:
    """A crash between writing a part and deleting its tail leaves both: the rows count once."""
    log, rows = _open_log(tmp_path, 300)
    (tmp_path / "_tail-00000.f8").write_bytes(rows[:300].tobytes())
    np.testing.assert_array_equal(_values(read_log(tmp_path)), rows)
    log.close()


def test_a_tail_without_its_columns_fails_naming_the_meta_file(tmp_path: Path) -> None:
    log, _ = _open_log(tmp_path, 120)
    meta = json.loads((tmp_path / META_FILE).read_text())
    del meta["columns"]
    (tmp_path / META_FILE).write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match="columns"):
        read_log(tmp_path)
    log.close()
