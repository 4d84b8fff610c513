"""frhc zwidth: the stability edge by bisection, its table and plot, and its command line."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq

from app.study.zwidth import TABLE_HEADER, ZWidthPoint, zwidth


def test_edge_brackets_the_onset_and_is_written(tmp_path: Path) -> None:
    """Plain rendering at K_D = 4 N s/m: stable at the low end, oscillating at the high end, and
    the bisected bracket between them; the table and the plot are written."""
    (edge,) = zwidth(tmp_path, renderers=("plain",), dampings=(4.0,), iterations=2)
    assert 0.25 <= edge.k_t_stable < edge.k_t_unstable <= 64.0
    assert edge.k_t_unstable / edge.k_t_stable < 64.0 / 0.25  # the bisection narrowed it
    assert edge.felt_stiffness > 0
    assert edge.points == 2 + 2
    table = pq.read_table(tmp_path / "zwidth.parquet")
    assert table.num_rows == 1
    assert table["renderer"][0].as_py() == "plain"
    assert (tmp_path / "zwidth.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bisections_on_ray_give_the_serial_edges(tmp_path: Path, local_ray: None) -> None:
    """The independent bisections run as points of the sweep engine: two Ray workers give the
    edges (and table) of the serial run, in the same order."""
    serial = zwidth(tmp_path / "serial", renderers=("plain",), dampings=(4.0, 16.0), iterations=1)
    on_ray = zwidth(tmp_path / "ray", renderers=("plain",), dampings=(4.0, 16.0), iterations=1, workers=2)
    assert [e.damping for e in on_ray] == [4.0, 16.0]
    assert all(e.error == "" and e.points == 3 for e in on_ray)
    assert on_ray == serial
    assert pq.read_table(tmp_path / "ray" / "zwidth.parquet").equals(
        pq.read_table(tmp_path / "serial" / "zwidth.parquet")
    )


def test_bad_arguments_are_refused_in_one_line(tmp_path: Path) -> None:
    bad = (["--renderers", "plain,magic"], ["--dampings", "4,-1"], ["--iterations", "0"], ["--hand", "400"])
    for args in (*bad, ["--hand", "400,-1"], ["--hand", "let-go"]):
        done = subprocess.run(
            [sys.executable, "-m", "app.cli", "zwidth", *args, "--out", str(tmp_path)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 2, args
        assert "Traceback" not in done.stderr
        assert "zwidth: error: argument" in done.stderr.strip().splitlines()[-1]


def test_an_edge_prints_words_where_there_is_no_number() -> None:
    """The command's rows: a bracket prints its numbers; no stable K_T prints ``none`` (was
    ``nan``), a renderer stable up to the top prints ``not reached`` (was ``inf``), a failed
    bisection prints ``-`` and its error."""
    bracket = ZWidthPoint("plain", 4.0, 1.5, 1234.4, 3.0, 4)
    assert bracket.line().split() == ["plain", "4", "1.5", "1,234", "3"]
    never = ZWidthPoint("pc", 16.0, math.nan, math.nan, 0.25, 1)
    assert never.line().split() == ["pc", "16", "none", "-", "0.25"]
    always = ZWidthPoint("wave", 0.0, 64.0, 5e4, math.inf, 2)
    assert always.line().split() == ["wave", "0", "64", "50,000", "not", "reached"]
    failed = ZWidthPoint("plain", 4.0, math.nan, math.nan, math.nan, 0, "worker died")
    assert failed.line().split() == ["plain", "4", "none", "-", "-", "failed:", "worker", "died"]
    for edge in (bracket, never, always, failed):
        assert len(edge.line().split("   failed:")[0]) == len(TABLE_HEADER)  # the columns line up
