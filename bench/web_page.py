"""The browser demo as a visitor meets it: first panel, page update rate, bytes per second live and
in replay, and the README's screenshots.

Starts the demo on a free port and opens it in headless chromium (1400x900), then:

1. reloads the page and times it until the panel's first folder is visible;
2. presses the probe tool onto the surface (deadman and reflection on, hand 3 cm down) and, for
   ``seconds``, counts the status block's changes the page painted (the page's update rate), the
   3D frames it drew, and the bytes the page's websocket receives;
3. the same while the hand drags the grip round a 2 cm circle once every 2 s (everything in the
   3D view moves every frame, so each frame costs the page a 3D render), with why: the server's
   panel redraws a second, its status updates that reached the page a second, and chromium's CPU
   per 3D frame (GPU process, renderer, browser; from ``/proc``). The hand is moved by the server
   (as :meth:`DemoApp.move_hand_target`, at the UI rate), not by pointer events: the gizmo's pose
   then reaches the page with the scene's other nodes, where a drag in the page moves it there;
4. records the live page's loop during 2 and 3, replays the same stretches of that log at 1x and
   counts the same bytes (same run, side by side); for each, what the server sent by kind of
   message (:class:`SentByKind`);
5. with ``--screenshots``, writes the README's screenshots to ``assets/web/`` (exact-colour PNGs);
6. with ``--trace``, records chromium's own trace while it counts the update rate while dragging
   and prints where the page's time went (:func:`trace_split`): its main thread waiting for the
   WebGL frame to be read back (the GPU process rendering it in software), running JavaScript
   (the messages applied, React, three.js), and the GPU process's share in WebGL.

Run from the repository root:
    .venv/bin/python bench/web_page.py [seconds] [--screenshots] [--trace]
Goals: first panel <= 3 s on a quiet machine, update rate >= 30 Hz (the UI's rate), replay bytes/s
within 2x of the live page's. The update rate is the status block's changes the page painted a
second: each is a state of the loop the visitor saw. It is at most the 3D frames drawn a second
while the view moves (viser's page takes in a window with a scene update only in a 3D frame) and
at most the status updates that reached it (the server's panel redraws, less those viser's
message buffer dropped as superseded before it sent them); all three are printed.
"""

from __future__ import annotations

import collections
import contextlib
import json
import math
import os
import re
import shutil
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import msgspec
from PIL import Image
from viser.infra._messages import Message

from app.errors import ConfigError
from app.web.headless import open_page, press_probe, running_demo
from app.web.replay import LogReplay
from app.web.server import UI_RATE, DemoApp
from app.world.scene import ASSETS_DIR

#: Where the README's screenshots go.
SHOT_DIR = ASSETS_DIR / "web"
#: Seconds to let the tool reach the surface (or a replay start) before measuring.
SETTLE_SECONDS = 3.0

#: Milliseconds of waiting in playwright that deliver the frame events already received.
DRAIN_MS = 300

#: Counts, over ``seconds``, the status block's text changes the page painted (checked once per
#: painted frame, in ``requestAnimationFrame``: a change is counted once however many updates came
#: between two paints), the 3D frames viser's renderer drew (three.js's frame counter, through
#: viser's own test hook ``__viserTestpoints``) and the status updates that reached the page
#: (pushed on viser's message queue, ``window.__viserMutable.messageQueue``, after its websocket
#: worker). A 4 ms ``setInterval`` poll counted fewer changes: while the view moves the page
#: paints back to back and the poll's timer task often got no turn between two paints (dragging:
#: 7.7 against 10.3 painted changes/s in the same window; pressed: the same).
COUNT_STATUS_JS = """(seconds) => new Promise((done) => {
  const text = () => {
    const block = [...document.querySelectorAll('pre, code')].find(e => e.innerText.includes('Hz simulated'));
    return block ? block.innerText : '';
  };
  const renderer = window.__viserTestpoints.rendererInfo.render;
  const frames = renderer.frame;
  let changes = 0, last = text(), stop = false;
  const paint = () => {
    const now = text();
    if (now !== last) { changes += 1; last = now; }
    if (!stop) requestAnimationFrame(paint);
  };
  const queue = window.__viserMutable.messageQueue;
  let arrived = 0;
  queue.push = function (...messages) {
    for (const m of messages) {
      const text = m.type === 'GuiUpdateMessage' && m.updates ? (m.updates.content ?? m.updates._markdown) : undefined;
      if (typeof text === 'string' && text.includes('Hz simulated')) arrived += 1;
    }
    return Array.prototype.push.apply(this, messages);
  };
  requestAnimationFrame(paint);
  setTimeout(() => {
    stop = true;
    delete queue.push;
    done([changes / seconds, (renderer.frame - frames) / seconds, arrived / seconds]);
  }, seconds * 1000);
})"""

#: Clock ticks per second of ``/proc/<pid>/stat``'s CPU times.
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def chromium_processes() -> dict[int, str]:
    """This process's chromium descendants by pid: ``gpu`` (the GPU process, where software WebGL
    runs), ``renderer`` (the page's), ``browser`` and the rest by chromium's ``--type``."""
    children: dict[int, list[int]] = collections.defaultdict(list)
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        children[int(stat.rsplit(")", 1)[1].split()[1])].append(int(entry.name))
    found: dict[int, str] = {}
    todo = [os.getpid()]
    while todo:
        for pid in children.get(todo.pop(), []):
            try:
                command = Path(f"/proc/{pid}/cmdline").read_bytes()  # chromium rewrites its own as one line
            except OSError:
                continue
            if b"chromium" in command.split(b"\0")[0].split(b" ")[0]:
                kind = re.search(rb"--type=([\w-]+)", command)
                found[pid] = (
                    "browser" if kind is None else {"gpu-process": "gpu"}.get(kind[1].decode(), kind[1].decode())
                )
            todo.append(pid)
    return found


def cpu_seconds(processes: dict[int, str]) -> collections.Counter[str]:
    """CPU seconds (user + system) used so far by ``processes``, summed by kind."""
    total: collections.Counter[str] = collections.Counter()
    for pid, kind in processes.items():
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total[kind] += (int(fields[11]) + int(fields[12])) / CLOCK_TICKS
    return total


class ByteCounter:
    """Bytes the page receives on its websockets (frames' payloads)."""

    def __init__(self, page: Any) -> None:
        self.bytes = 0
        self.frames = 0
        self.page = page
        page.on("websocket", self._socket)

    def _socket(self, ws: Any) -> None:
        ws.on("framereceived", self._frame)

    def _frame(self, payload: bytes | str) -> None:
        self.bytes += len(payload)
        self.frames += 1

    def rate(self, seconds: float) -> tuple[float, float]:
        """Bytes and websocket messages per second over the next ``seconds`` (waiting in
        playwright, which delivers the frame events only while one of its calls runs)."""
        # Frames received since the last playwright call are delivered first: they belong to
        # before the window (counting them inflated every figure by whatever came in while the
        # bench slept or recorded a session, and the replay's most: 2.06x live in one run).
        self.page.wait_for_timeout(DRAIN_MS)
        before, frames = self.bytes, self.frames
        self.page.wait_for_timeout(seconds * 1000)
        return (self.bytes - before) / seconds, (self.frames - frames) / seconds


class SentByKind:
    """Bytes the server sends, by kind of message: the message's class and, for an update, the
    properties it changes (``GuiUpdateMessage:content``). Counted as each message is serialized
    for a page's websocket (what the message buffer keeps after culling superseded updates):
    its msgpack size before the window's zstd plus its raw arrays. viser has no hook for this,
    so ``Message.as_serializable_dict`` is wrapped while the bench runs."""

    def __init__(self) -> None:
        self.bytes: collections.Counter[str] = collections.Counter()
        self.count: collections.Counter[str] = collections.Counter()
        self._lock = threading.Lock()
        original = Message.as_serializable_dict
        counter = self

        def counted(message: Message, binary_buffers: list[memoryview] | None = None) -> dict[str, Any]:
            start = len(binary_buffers) if binary_buffers is not None else 0
            out = original(message, binary_buffers)
            size = len(msgspec.msgpack.encode(out))
            if binary_buffers is not None:
                size += sum(b.nbytes for b in binary_buffers[start:])
            kind = type(message).__name__
            updates = getattr(message, "updates", None)
            if isinstance(updates, dict):
                kind += ":" + ",".join(sorted(updates))
            with counter._lock:
                counter.bytes[kind] += size
                counter.count[kind] += 1
            return out

        Message.as_serializable_dict = counted  # type: ignore[method-assign,assignment]
        self._original, self._counted = original, counted

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Count nothing in the block: the counting encodes every message a second time in viser's
        event loop, which sends the page its windows (windows sent later merge updates, and the
        page then paints fewer of them)."""
        Message.as_serializable_dict = self._original  # type: ignore[method-assign]
        try:
            yield
        finally:
            Message.as_serializable_dict = self._counted  # type: ignore[method-assign,assignment]

    def snapshot(self) -> tuple[collections.Counter[str], collections.Counter[str]]:
        with self._lock:
            return collections.Counter(self.bytes), collections.Counter(self.count)

    def since(self, before: tuple[collections.Counter[str], collections.Counter[str]], seconds: float) -> str:
        """Lines of kB/s and messages/s by kind since ``before`` (a :meth:`snapshot`), largest first."""
        now_bytes, now_count = self.snapshot()
        rows = sorted(((now_bytes[k] - before[0][k], now_count[k] - before[1][k], k) for k in now_bytes), reverse=True)
        return "\n".join(f"    {b / seconds / 1000:8.1f} kB/s {n / seconds:6.1f} /s  {k}" for b, n, k in rows if b > 0)


#: Chromium trace categories for :func:`trace_split`.
TRACE_CATEGORIES = ["devtools.timeline", "disabled-by-default-devtools.timeline", "gpu", "toplevel"]
#: What :func:`trace_split` reports: (thread name, event name, what it is).
TRACE_PARTS = (
    ("CrRendererMain", "ThreadControllerImpl::RunTask", "page main thread busy"),
    ("CrRendererMain", "GLES2::ReadPixels", "  waiting for the WebGL frame's read-back"),
    ("CrRendererMain", "FunctionCall", "  running JavaScript"),
    ("CrGpuMain", "WebGL", "GPU process executing WebGL (software)"),
)


def trace_split(raw: bytes) -> str:
    """Lines of the share of the time a chromium trace (JSON ``raw``) spans that each of
    :data:`TRACE_PARTS` took: the durations of its complete events, an event inside another of
    the same name on the same thread (a nested run loop) counted once."""
    events = json.loads(raw)["traceEvents"]
    threads = {
        (e["pid"], e["tid"]): e["args"]["name"] for e in events if e.get("ph") == "M" and e.get("name") == "thread_name"
    }
    complete = sorted((e for e in events if e.get("ph") == "X" and "dur" in e), key=lambda e: e["ts"])
    span = max(e["ts"] + e["dur"] for e in complete) - complete[0]["ts"]
    total: collections.Counter[tuple[str, str]] = collections.Counter()
    ends: dict[tuple[int, int, str], float] = {}
    for e in complete:
        key = (e["pid"], e["tid"], e["name"])
        if e["ts"] >= ends.get(key, -math.inf):
            total[(threads.get((e["pid"], e["tid"]), ""), e["name"])] += e["dur"]
            ends[key] = e["ts"] + e["dur"]
    return "\n".join(f"    {total[(thread, name)] / span:6.1%}  {what}" for thread, name, what in TRACE_PARTS)


def drag_circle(app: DemoApp, stop: threading.Event, radius: float = 0.02, period: float = 2.0) -> None:
    """Move the hand target round a horizontal circle about where it is, at the UI rate, until ``stop``."""
    assert app.rt.snapshot.T_0_H is not None
    centre = app.rt.snapshot.T_0_H.copy()
    start = time.monotonic()
    while not stop.wait(1.0 / UI_RATE):
        angle = 2.0 * math.pi * (time.monotonic() - start) / period
        T_0_H = centre.copy()
        T_0_H[0, 3] += radius * math.cos(angle)
        T_0_H[1, 3] += radius * math.sin(angle)
        app.move_hand_target(T_0_H)


def screenshot(app: DemoApp, page: Any, name: str, preset: str = "both") -> Path:
    """A PNG in ``assets/web/<name>.png`` (the README's; exact colours, 140-270 KB: a 128-colour
    palette made them 3-4x smaller and shifted the rarer colours, the arrows' and the gizmo's) of
    the demo in a second page like ``page``, opened with ``?fixedDpr=1``: its 3D view at full resolution and
    antialiased, as a browser with a GPU draws it (headless chromium renders in software, where
    the page draws at :data:`~app.web.camera.SOFTWARE_PIXEL_RATIO` without antialiasing, fixed
    when the page makes its WebGL context); its camera on ``preset``."""
    before = set(app.server.get_clients())
    shot = page.context.browser.new_page(viewport=page.viewport_size)
    try:
        shot.goto(f"http://127.0.0.1:{app.server.get_port()}/?fixedDpr=1")
        shot.get_by_text("Hz simulated").first.wait_for(timeout=60_000)
        shot.wait_for_timeout(2000)  # the camera fitted to the page's canvas, the notice shown
        close = shot.locator(".mantine-Notification-closeButton")  # viser's "software WebGL" notice
        for i in range(close.count()):
            close.nth(i).dispatch_event("click")
        for client_id, client in app.server.get_clients().items():
            if client_id not in before:
                app.frame_camera(client, preset)
        shot.wait_for_timeout(3000)
        SHOT_DIR.mkdir(parents=True, exist_ok=True)
        raw = SHOT_DIR / f"{name}.raw.png"
        shot.screenshot(path=str(raw))
    finally:
        shot.close()
    out = SHOT_DIR / f"{name}.png"
    Image.open(raw).convert("RGB").save(out, optimize=True)
    raw.unlink()
    return out


def recorded_log(directory: Path) -> LogReplay:
    """The log the demo is closing in ``directory`` once it can be read (the loop closes it after
    its current tick; the writer then flushes its last part)."""
    end = time.monotonic() + 60.0
    while True:
        try:
            return LogReplay(directory)
        except (ConfigError, OSError, ValueError):
            if time.monotonic() > end:
                raise
            time.sleep(0.2)


def main(seconds: float, shots: bool, trace: bool) -> None:
    sent = SentByKind()
    with running_demo() as app:
        with open_page(f"http://127.0.0.1:{app.server.get_port()}/") as page:
            page.get_by_text("Deadman [D]").first.wait_for(timeout=60_000)
            counter = ByteCounter(page)
            start = time.monotonic()
            page.reload()
            page.get_by_text("Start here").first.wait_for(timeout=60_000)
            first_panel = time.monotonic() - start
            page.get_by_text("Hz simulated").first.wait_for(timeout=60_000)
            press_probe(app)
            time.sleep(SETTLE_SECONDS)
            # The live page is recorded, and the replay of that log measured against it.
            log_dir = app.toggle_recording()
            assert log_dir is not None
            pressed_at = app.rt.snapshot.time
            mark = sent.snapshot()
            live, live_messages = counter.rate(seconds)
            live_kinds = sent.since(mark, seconds)
            with sent.paused():
                update_hz, pressed_frames, _ = page.evaluate(COUNT_STATUS_JS, seconds)
            if shots:
                print("wrote", screenshot(app, page, "probe_contact"))
            stop = threading.Event()
            dragger = threading.Thread(target=drag_circle, args=(app, stop), daemon=True)
            dragger.start()
            time.sleep(1.0)
            dragged_at = app.rt.snapshot.time
            mark = sent.snapshot()
            moving, _ = counter.rate(seconds)
            moving_kinds = sent.since(mark, seconds)
            browser = page.context.browser
            if trace:
                browser.start_tracing(page=page, categories=TRACE_CATEGORIES)
            chromium = chromium_processes()
            cpu_before, redraws_before = cpu_seconds(chromium), app.controls.redraws
            with sent.paused():
                moving_hz, moving_frames, moving_arrived = page.evaluate(COUNT_STATUS_JS, seconds)
            panel_hz = (app.controls.redraws - redraws_before) / seconds
            cpu_used = cpu_seconds(chromium) - cpu_before
            split = trace_split(browser.stop_tracing()) if trace else ""
            stop.set()
            dragger.join()
            app.toggle_recording()
            app.show_replay(recorded_log(log_dir))
            player = app.player
            assert player is not None
            replays = []
            for at in (pressed_at, dragged_at):  # the same stretches of the log as measured live
                player.seek(at)
                player.playing = True
                mark = sent.snapshot()
                replayed, _ = counter.rate(seconds)
                replays.append((replayed, sent.since(mark, seconds), at, player.cursor))
            replay_pressed, replay_dragged = replays[0][0], replays[1][0]
            if shots:
                player.seek(pressed_at + 1.0)
                time.sleep(1.0)
                print("wrote", screenshot(app, page, "replay"))
                app.close_replay()
                app.play_session("peg_ntrfc")
                end = time.monotonic() + 120.0
                while app.rt.snapshot.F_MRF[2] < 2.0 and time.monotonic() < end:
                    time.sleep(0.01)
                app.pause(True)
                print("wrote", screenshot(app, page, "peg_contact", "world"))
        shutil.rmtree(log_dir.parent)
        print(f"first panel visible  {first_panel:6.2f} s after a reload (goal <= 3 s on a quiet machine)")
        print(f"messages received    {live_messages:6.1f} /s (websocket messages to the page, live)")
        print(f"page update rate     {update_hz:6.1f} Hz (status redraws the page painted over {seconds:g} s)")
        print(f"  while dragging     {moving_hz:6.1f} Hz (the hand circling: the 3D view moves every frame)")
        print(
            f"3D frames drawn      {pressed_frames:6.1f} /s pressed, {moving_frames:.1f} /s dragging (with viser's "
            "settle frames, drawn for 250 ms after any scene message whether or not another came)"
        )
        per_frame = 1000.0 / max(moving_frames * seconds, 1.0)
        print(
            f"  dragging, why     the server redrew the panel {panel_hz:.1f} /s, its status updates reached "
            f"the page {moving_arrived:.1f} /s; chromium's CPU a 3D frame: GPU process "
            f"{per_frame * cpu_used['gpu']:.1f} ms, renderer {per_frame * cpu_used['renderer']:.1f} ms, "
            f"browser {per_frame * cpu_used['browser']:.1f} ms"
        )
        if trace:
            print(f"  where the page's time went while dragging (chromium's trace):\n{split}")
        print(f"live page            {live / 1000:8.1f} kB/s (probe pressed: arrows, contacts, plots)")
        print(f"  while dragging     {moving / 1000:8.1f} kB/s")
        print(
            f"replay at 1x         {replay_pressed / 1000:8.1f} kB/s = {replay_pressed / live:.2f}x live pressed; "
            f"dragging {replay_dragged / 1000:.1f} kB/s = {replay_dragged / moving:.2f}x live dragging "
            "(the same stretches of the live page's log, same run)"
        )
        print(f"sent by kind (msgpack before zstd + arrays), live pressed:\n{live_kinds}")
        print(f"  live dragging:\n{moving_kinds}")
        for name, (_, kinds, at, cursor) in zip(("pressed", "dragging"), replays, strict=True):
            print(f"  replay of {name} (log t {at:.2f} -> {cursor:.2f} s):\n{kinds}")
        print(f"load average {os.getloadavg()[0]:.2f} (1 min) at the end")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(float(args[0]) if args else 10.0, "--screenshots" in sys.argv, "--trace" in sys.argv)
