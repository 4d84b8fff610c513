"""Run a session from Python and read its log.

Runs the default probing session headlessly (the same as ``frhc run sessions/probe_rate.toml``),
then opens the per-tick Parquet log with pyarrow: one row per servo tick, columns such as
``t``, ``contact_MRF_fz`` (N), ``G_F_T_fz`` (N, felt at the grip) and ``tool_z`` (m).

    .venv/bin/python examples/01_run_session.py
"""

import os
import tempfile
from pathlib import Path

import numpy as np

from app.session import load_session, run_session
from app.session.log import read_log

FAST = bool(os.environ.get("FRHC_EXAMPLE_FAST"))

session = load_session("probe_rate")
if FAST:
    session = session.with_changes(duration=2.0)

with tempfile.TemporaryDirectory() as tmp:
    result = run_session(session, out_dir=Path(tmp), plots=not FAST)
    table = read_log(result.log_dir)  # a pyarrow.Table; .to_pandas() if pandas is installed
    t = table["t"].to_numpy()
    force = table["contact_MRF_fz"].to_numpy()
    felt = table["G_F_T_fz"].to_numpy()

print(f"{table.num_rows} ticks, {len(table.column_names)} columns")
print(f"work on the environment (Eq 13): {result.summary['work_eq13']:.4f} J")
i = int(np.argmax(force))
print(f"peak contact force {force[i]:.2f} N at t = {t[i]:.3f} s; felt at the grip {felt[i]:.2f} N")
print(f"median tick {result.summary['timing']['tick']['median_us']:.1f} us")
