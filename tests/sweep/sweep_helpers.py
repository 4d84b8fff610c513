"""The ``frhc`` command line as the sweep tests call it."""

from __future__ import annotations

import subprocess
import sys


def frhc(*args: str) -> subprocess.CompletedProcess[str]:
    """Run ``frhc ARGS...`` in a fresh interpreter; returns its exit code, stdout and stderr."""
    return subprocess.run(
        [sys.executable, "-m", "app.cli", *args], capture_output=True, text=True, timeout=300, check=False
    )
