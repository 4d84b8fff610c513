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


def fresh_folder(parent: Path, name: str) -> Path:
    """Create and return ``parent / name``, or ``name-2``, ``name-3``, ... if taken: a folder no
    earlier run wrote (two recordings started within one second of a timestamped name would
    otherwise share one, and the second would delete the first one's log).

    Raises:
        OSError: ``parent`` cannot be created or written.
    """
    parent.mkdir(parents=True, exist_ok=True)
    for k in range(1, 10_000):
        folder = parent / (name if k == 1 else f"{name}-{k}")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise FileExistsError(f"{parent / name}: 9999 folders of that name exist")
