"""Where session files and logs are, and what a log directory's metadata file is called.

Names only, so that a caller that lists sessions or logs (the browser demo's first panel) does
not import the servo loop, the log writer (pyarrow) or the scene loader (trimesh, MuJoCo).
"""

from __future__ import annotations

from pathlib import Path

_ROOT = Path(__file__).resolve().parents[2]
#: The shipped session files (``*.toml``).
SESSIONS_DIR = _ROOT / "sessions"
#: Where the browser demo writes its logs (``web-<timestamp>/log``) and looks for logs to replay.
RUNS_DIR = _ROOT / "runs"
#: A log directory's metadata file (JSON): its presence marks a replayable log.
META_FILE = "_meta.json"
