"""Real-time check of the browser demo: servo rate and period jitter with a browser connected.

Starts the demo on a free port, opens it in headless chromium, presses the probe tool onto the
surface (deadman and reflection on, hand 3 cm down: contact, arrows and plots all updating), then
measures for N seconds and prints the loop's own timing statistics. With ``--play`` the page
instead plays the peg session (its scripted operator drives the loop, as "Try the peg task"
does) during the measurement; with ``--replay`` it also replays a log in the page at the same
time (the replay runs in the server process and must not disturb the loop).

Run from the repository root:
    .venv/bin/python bench/web_realtime.py [seconds] [--no-browser] [--play] [--replay]
Goal: achieved rate within 1 % of 1 kHz and period jitter p99 <= 0.5 ms.
"""

from __future__ import annotations

import contextlib
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.session.run import run_session
from app.session.spec import load_session
from app.web.headless import CHROMIUM, free_port, open_page, press_probe
from app.web.launch import start_demo

#: Seconds to let the tool reach the surface before measuring.
SETTLE_SECONDS = 3.0


def main(seconds: float, browser: bool, play: bool, replay: bool) -> int:
    app = start_demo("probe", "kraft", port=free_port())
    try:
        if not app.rt.wait_running():
            print("the servo loop process did not start", file=sys.stderr)
            return 1
        page_context = open_page(f"http://127.0.0.1:{app.server.get_port()}/") if browser else contextlib.nullcontext()
        with page_context as page:
            if page is not None:
                page.get_by_text("Deadman [D]").first.wait_for(timeout=30_000)
            if replay:
                with tempfile.TemporaryDirectory() as tmp:
                    run_session(load_session("probe_rate"), out_dir=Path(tmp), plots=False)
                    app.open_replay(tmp)
                assert app.player is not None
                app.player.playing = True
            if play:
                app.play_session("peg_ntrfc")
            else:
                press_probe(app)
            time.sleep(SETTLE_SECONDS)
            ticks_before = app.rt.stats().counted
            time.sleep(seconds)
            stats = app.rt.stats(last=round(seconds * 1000.0))
            snap = app.rt.snapshot
        nominal = 1.0 / app.rt.loop.dt
        doing = "playing peg_ntrfc" if play else "probe pressed by the hand"
        print(
            f"browser: {'headless chromium' if browser else 'none'}   scheduling: {app.rt.scheduling}   loop: {doing}"
        )
        if replay:
            print("a log was replaying in the page during the measurement")
        print(f"measured {stats.ticks} periods over {seconds:g} s ({ticks_before} ticks ran before measuring)")
        print(
            f"achieved rate   {stats.rate_hz:9.2f} Hz   ({100 * (stats.rate_hz / nominal - 1):+.2f} % of {nominal:g} Hz)"
        )
        print(f"period median   {stats.period_p50_us:9.1f} us")
        print(f"jitter p99      {stats.jitter_p99_us:9.1f} us   (|period - dt|; max {stats.jitter_max_us:.0f} us)")
        print(f"tick compute    {stats.tick_p50_us:9.1f} us median, {stats.tick_p99_us:.1f} us p99")
        print(f"schedule slips  {stats.slips}")
        print(f"task force at the end: {snap.F_MRF[2]:.2f} N ({len(snap.contact_points_w)} contacts)")
        ok = abs(stats.rate_hz / nominal - 1) <= 0.01 and stats.jitter_p99_us <= 500.0
        print("goal (rate within 1 %, jitter p99 <= 0.5 ms):", "met" if ok else "NOT met")
        return 0
    finally:
        app.close()
        app.server.stop()


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    use_browser = "--no-browser" not in sys.argv[1:]
    if use_browser and not CHROMIUM.exists():
        sys.exit(f"{CHROMIUM} is missing: install Debian's chromium (or pass --no-browser)")
    sys.exit(main(float(args[0]) if args else 10.0, use_browser, "--play" in sys.argv, "--replay" in sys.argv))
