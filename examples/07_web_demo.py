"""A minimal browser demo: the probe scene on the Kraft-like device, served by viser.

Open the printed URL, drag the hand-target gizmo down, then tick Deadman and Reflection: the
tool moves into the surface and the wrench arrows appear. ``make demo`` (``frhc web``) is the
full version with the same parts.

    .venv/bin/python examples/07_web_demo.py [seconds]
"""

import os
import sys

from app.web.server import serve

seconds = float(sys.argv[1]) if len(sys.argv) > 1 else (8.0 if os.environ.get("FRHC_EXAMPLE_FAST") else None)
serve("probe", "kraft", port=8097, open_seconds=seconds)
