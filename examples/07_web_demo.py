"""A minimal browser demo: the probe scene on the Kraft-like device, served by viser.

Open the printed URL, drag the hand-target gizmo down, then tick Deadman and Reflection: the
tool moves into the surface and the wrench arrows appear. ``make demo`` (``frhc web``) is the
full version with the same parts.

The servo loop runs in a child process started with ``spawn``, which imports this file again:
keep the demo under ``if __name__ == "__main__":``.

    .venv/bin/python examples/07_web_demo.py [seconds]
"""

import os
import sys
import time

from app.web.launch import start_demo


def main(seconds: float | None) -> None:
    app = start_demo("probe", "kraft", port=8097)
    try:
        print(f"FRHC haptic demo: {app.url}  (Ctrl+C to stop)", flush=True)
        if not app.rt.wait_running():
            sys.exit("the servo loop did not start")
        time.sleep(seconds if seconds is not None else 1e9)
        stats = app.rt.stats()
        print(
            f"servo loop: {stats.rate_hz:.1f} Hz over the last {stats.ticks} ticks, jitter p99 {stats.jitter_p99_us:.0f} us"
        )
    except KeyboardInterrupt:
        pass
    finally:
        app.close()
        app.server.stop()


if __name__ == "__main__":
    fast = 5.0 if os.environ.get("FRHC_EXAMPLE_FAST") else None
    main(float(sys.argv[1]) if len(sys.argv) > 1 else fast)
