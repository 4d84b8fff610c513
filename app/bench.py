"""Benchmarks behind ``frhc bench``: each prints medians and p99 of the hot paths.

Speed goals live here, not in timed tests: the figures depend on the machine.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from app.device.hand import HandParams
from app.session.loop import STAGES
from app.session.metrics import SETTLE_WINDOW
from app.session.stability import PressResult
from app.session.tick import TickRecord
from app.spatial import Array, IntArray
from app.teleop.channel import Coupling

if TYPE_CHECKING:
    from app.device.haply import HaplyClient
    from app.session.pacer import Pacer

#: The hand of a stability row unless another is given.
DEFAULT_HAND = HandParams()


def _stats(ns: np.ndarray) -> str:
    us = ns / 1000.0
    return f"median {np.median(us):8.1f} us   p99 {np.percentile(us, 99):8.1f} us   (n={len(us)})"


def bench_controller(quick: bool = False) -> str:
    """Controller step on the Kraft-like device reflecting a contact, >= 10k steps, in rate mode and
    in pose mode (where the PC also holds the slave's command, :func:`~app.controller.passivity.coupling_hold`),
    with the passivity controller off and on (interleaved blocks of the same walk, so all four see
    the same machine load); the PO/PC's cost is the difference of the medians in each mode."""
    from dataclasses import replace

    from app.controller.frhc import FRHCController
    from app.controller.layout import Mode
    from app.controller.passivity import PassivitySettings
    from app.controller.types import FTReading, Switches
    from app.device.spec import load_device
    from app.slave.tool import VirtualSlave
    from app.world.scene import load_scene

    device = load_device("kraft")
    slave = VirtualSlave(load_scene("probe")).slave_model()
    modes: tuple[Mode, ...] = ("rate", "pose")
    ctrls = [
        FRHCController(device, replace(device.data.gains, mode=mode), slave, passivity=PassivitySettings(enabled=on))
        for mode in modes
        for on in (False, True)
    ]
    n, block = (3000, 500) if quick else (20000, 1000)
    rng = np.random.default_rng(0)
    q0 = np.array(device.data.home)
    walk = q0 + np.cumsum(rng.normal(scale=2e-4, size=(n, device.n_joints)), axis=0) + 0.05
    ft = FTReading(wrench_S=np.array([0.5, -0.2, 4.0, 0.01, 0.02, 0.0]))
    sw = Switches(deadman=True, reflection=True)
    ns = np.empty((len(ctrls), n), dtype=np.int64)
    for start in range(0, n, block):
        for c, ctrl in enumerate(ctrls):
            for i in range(start, min(start + block, n)):
                t0 = time.perf_counter_ns()
                ctrl.step(walk[i], sw, ft, 1e-3)
                ns[c, i] = time.perf_counter_ns() - t0
    lines = []
    for k, mode in enumerate(modes):
        off, on = ns[2 * k], ns[2 * k + 1]
        added = (np.median(on) - np.median(off)) / 1000.0
        lines += [
            f"controller step (kraft, {mode} mode, reflecting):          {_stats(off)}",
            f"controller step, PO/PC on (adds {added:+.2f} us to the median): {_stats(on)}",
        ]
    return "\n".join(lines)


def bench_tick(quick: bool = False) -> str:
    """Whole servo tick per stage, scripted probing on the default scene and the large mesh."""
    from app.session.run import run_session
    from app.session.spec import load_session

    lines = ["servo tick per stage (headless, no logging):"]
    for scene in ("probe", "large_mesh"):
        session = load_session("probe_rate").with_changes(scene=scene, duration=1.5 if quick else 5.0)
        s = run_session(session, out_dir=None).summary
        lines.append(f"  scene {scene}: contact fraction {s['contact_fraction']:.2f}")
        for name in STAGES:
            t = s["timing"][name]
            lines.append(f"    {name:<11} median {t['median_us']:8.1f} us   p99 {t['p99_us']:8.1f} us")
        lines.append(f"    real-time factor at 1 kHz (1 ms / median tick): {s['real_time_factor']:.1f}")
    lines.append("the tick as run (scripted operator, metrics; frhc run also logs to Parquet), per loop iteration:")
    for name in ("probe_rate", "peg_ntrfc"):
        for logged in (True, False):
            session = load_session(name).with_changes(duration=1.5 if quick else 5.0)
            lap = _Laps(session.data.n_ticks)
            with tempfile.TemporaryDirectory() as tmp:
                out_dir = Path(tmp) if logged else None
                s = run_session(session, out_dir=out_dir, plots=False, observers=(lap,)).summary
            bare = s["timing"]["tick"]["median_us"]
            med, p99 = lap.stats()
            how = "with log (frhc run)    " if logged else "no log (sweep, study)  "
            lines.append(
                f"  {name + ':':<12}{how}median {med:6.1f} us   p99 {p99:6.1f} us   "
                f"({med / bare:.2f}x its bare tick, median {bare:.1f} us)"
            )
    lines.extend(_web_loop_lines(quick))
    return "\n".join(lines)


def _web_loop_lines(quick: bool) -> list[str]:
    """The browser demo's loop as it runs (its own process, paced to the wall clock, publishing
    snapshots, playing a session's script; no browser): compute per tick against the same
    session's bare tick headless, achieved rate, period jitter and the loop process's CPU, at
    1 kHz and at 4 kHz, and at 1 kHz spinning :data:`WEB_SPIN` of each period (``frhc web --spin``).

    Each row also gives the bare tick of the same session run headless *paced* at that rate
    (``frhc run --realtime``, :data:`WEB_PACED_SECONDS`): a tick that starts after a wait runs
    slower than one straight after another (its code and data left the caches while it waited),
    whatever the loop does around it, so the demo's compute over that paced bare tick is what
    the web loop itself adds."""
    from app.session.loop import LoopConfig
    from app.session.run import run_session
    from app.session.spec import load_session
    from app.web.realtime import RealtimeLoop

    lines = ["the browser demo's loop (own process, paced, snapshots, session playing; no browser):"]
    cases: list[tuple[str, float, float | None]] = [
        ("probe_rate", 1000.0, None),
        ("probe_rate", 1000.0, WEB_SPIN),
        ("peg_ntrfc", 1000.0, None),
        ("probe_rate", 4000.0, None),
    ]
    for name, rate, spin in [c for c in cases if c[0] == "probe_rate"] if quick else cases:
        session = load_session(name).with_changes(servo_rate=rate)
        bare = run_session(session, out_dir=None, plots=False).summary["timing"]["tick"]["median_us"]
        paced_run = session.with_changes(duration=WEB_PACED_SECONDS)
        paced = run_session(paced_run, out_dir=None, plots=False, realtime=True).summary["timing"]["tick"]["median_us"]
        rt = RealtimeLoop(LoopConfig.from_session(session), spin=spin)
        rt.start()
        try:
            if not rt.wait_running():
                lines.append(f"  {name} at {rate / 1000:g} kHz: the loop process did not start")
                continue
            rt.play(session)
            time.sleep(WEB_SETTLE_SECONDS)
            cpu0, wall0 = rt.cpu_seconds(), time.monotonic()
            time.sleep(WEB_MEASURE_SECONDS)
            cpu1, wall1 = rt.cpu_seconds(), time.monotonic()
            st = rt.stats(last=round(WEB_MEASURE_SECONDS * rate))
            scheduling = rt.scheduling
        finally:
            rt.stop()
        cpu = "?" if cpu0 is None or cpu1 is None else f"{100 * (cpu1 - cpu0) / (wall1 - wall0):.0f} %"
        how = f"{rate / 1000:g} kHz" + ("" if spin is None else f", spin {spin:g}")
        lines.append(
            f"  {name} at {how} ({scheduling}): compute median {st.tick_p50_us:6.1f} us "
            f"p99 {st.tick_p99_us:7.1f} us ({st.tick_p50_us / bare:.2f}x its bare tick, median {bare:.1f} us; "
            f"{st.tick_p50_us / paced:.2f}x its bare tick paced headless, median {paced:.1f} us); "
            f"rate {st.rate_hz:8.1f} Hz ({100 * (st.rate_hz / rate - 1):+.2f} %), jitter p99 {st.jitter_p99_us:6.1f} us; "
            f"loop process CPU {cpu} of a core"
        )
    return lines


#: The web loop rows: seconds of the played session let run before, then measured.
WEB_SETTLE_SECONDS = 1.0
WEB_MEASURE_SECONDS = 3.0
#: Simulated (and, paced, wall-clock) seconds of the headless paced run each web loop row compares with.
WEB_PACED_SECONDS = 3.0
#: The share of each period the spinning web loop row spins (``frhc web --spin``).
WEB_SPIN = 0.8


class _Laps:
    """A tick observer (added last) timing whole loop iterations: operator, tick and observers."""

    def __init__(self, n: int) -> None:
        self._t = np.zeros(n, dtype=np.int64)
        self._k = 0

    def on_tick(self, tick: TickRecord) -> None:
        if self._k < len(self._t):
            self._t[self._k] = time.perf_counter_ns()
        self._k += 1

    def stats(self) -> tuple[float, float]:
        """Median and p99 (us) of the intervals between ticks, past the first 100."""
        laps = np.diff(self._t[100 : self._k]) / 1e3
        return float(np.median(laps)), float(np.percentile(laps, 99))


def bench_arm(quick: bool = False) -> str:
    """Arm slaves (issue 15 bars): slave step alone, then the whole tick on ``probe`` with each arm."""
    from app.controller.types import SlaveCommand
    from app.session.run import run_session
    from app.session.spec import load_session
    from app.slave.api import make_slave
    from app.world.scene import load_scene, with_slave

    lines = ["slave step (probe, rate command down onto the surface, NTRFC on; first 500 steps not timed):"]
    n = 3000 if quick else 20000
    command = SlaveCommand(active=True, mode="rate", twist=np.array([0.01, 0.0, -0.02, 0.0, 0.0, 0.1]))
    for kind in ("tool", "puma560", "redundant7"):
        slave = make_slave(with_slave(load_scene("probe"), kind))
        ns = np.empty(n, dtype=np.int64)
        for i in range(n + 500):
            t0 = time.perf_counter_ns()
            slave.step(command)
            if i >= 500:
                ns[i - 500] = time.perf_counter_ns() - t0
        lines.append(f"  {kind:<11} {_stats(ns)}")
    lines.append("servo tick with an arm (probe_rate session, headless, no logging):")
    for kind in ("puma560", "redundant7"):
        session = load_session("probe_rate").with_changes(slave=kind, duration=1.5 if quick else 5.0)
        s = run_session(session, out_dir=None).summary
        t = s["timing"]
        lines.append(
            f"  {kind:<11} slave median {t['slave']['median_us']:6.1f} us, tick median {t['tick']['median_us']:6.1f} us "
            f"(p99 {t['tick']['p99_us']:7.1f} us), real-time factor {s['real_time_factor']:.1f}"
        )
    return "\n".join(lines)


def bench_stability(quick: bool = False, window: float = SETTLE_WINDOW) -> str:
    """Whole-loop contact stability: surface stiffness sweep (rate mode), then plain and PO/PC walls
    (pose mode) at multiples of each device's passivity bound.

    In pose mode the wall's design stiffness at the grip is ``K_T K_P k_s``, with ``k_s`` the
    slave's tracking spring in series with the surface; the sampled-data passivity bound for a
    virtual wall is ``K < 2 b / T`` with b the physical damping at the grip (device joints plus
    the hand, :func:`~app.session.stability.grip_damping`). Felt stiffness is the secant between
    the press's two plateaus of rendered force and grip position
    (:class:`~app.session.stability.FeltStiffness`). *Stable* is settled with the motors and the
    slave within their limits (:attr:`~app.session.stability.PressResult.stable`); otherwise the
    row says why (:attr:`~app.session.stability.PressResult.verdict`): OSCILLATES, DRIFTS (a steady
    force, but the grip not at rest: a released tool still coasting off the wall), SATURATED (the
    motors at their limit through the judged window: the device lacks the capacity for the push,
    gravity compensation is scaled down with the wall, not a stability failure) or PUSHED IN (the
    hand pushed the slave through to its force limit, or the grip on into the surface, with the
    motors within capacity). Each device runs as shipped with each hand of :data:`~app.session.stability.HANDS`
    and with the hand let go, and as each variant of :data:`~app.device.variants.VARIANTS` (20-bit
    encoders separate the quantisation limit from the passivity bound). ``window``: how long (s)
    the hand holds each wall while its force is judged (the issue's bar: 8 s).
    """
    from app.device.variants import VARIANTS, DeviceVariant, write_variant
    from app.session.stability import DRIFT_TOLERANCE, HANDS, press

    lines = ["contact stability, probe pushed by the hand, reflection on (settled: ripple < 5 % of mean)"]
    stiffnesses = (3e3, 3e4, 3e5) if quick else (3e3, 1e4, 3e4, 1e5, 3e5, 1e6)
    for k in stiffnesses:
        r = press(k, "rate")
        lines.append(
            f"  rate mode, surface {k:9.0f} N/m: force {r.mean_force:7.2f} N, ripple {r.ripple:8.3f} N, "
            f"{'settled' if r.settled else 'OSCILLATES'}"
        )
    multiples = (1.0, 3.0) if quick else (0.25, 0.5, 1.0, 2.0, 3.0, 4.0)
    lines.append(
        f"  pose mode, two pushes (~2.5 N, ~8 N at the grip); stable: settled, grip at rest (< {1e3 * DRIFT_TOLERANCE:g} mm over the "
        "window), motors and slave within limits; felt: secant between the pushes; grip: its travel over the "
        "window (+ out of the surface); released: the hand lets go after the first push"
    )
    hands = HANDS[:2] if quick else HANDS
    variants = (DeviceVariant("enc20", encoder_bits=20),) if quick else VARIANTS
    with tempfile.TemporaryDirectory() as tmp:
        for device in ("kraft",) if quick else ("kraft", "jpl", "freflex"):
            for hand_label, hand in hands:
                lines.extend(_wall_rows(f"{device}, hand {hand_label}", device, multiples, hand, window))
            lines.extend(_wall_rows(f"{device}, hand released", device, multiples, None, window))
            for variant in variants:
                path = str(write_variant(device, variant, Path(tmp)))
                lines.extend(_wall_rows(f"{device}_{variant.label}", path, multiples, window=window))
    lines.extend(_rate_lines(quick))
    lines.extend(_delay_lines(quick))
    return "\n".join(lines)


def _wall_rows(
    label: str,
    device: str,
    multiples: tuple[float, ...],
    hand: HandParams | None = DEFAULT_HAND,
    window: float = SETTLE_WINDOW,
) -> list[str]:
    """Plain and PO/PC pose-mode walls on ``device`` (a name or a device file) at ``multiples`` of
    its passivity bound with ``hand`` (None: the default hand, let go after the first push); for
    each renderer the multiples it is stable at and the largest up to which it is stable at every
    multiple (on coarse encoders the stable set has gaps). The bound with the hand and the
    device-only one (the hand let go) are printed side by side; multiples are of the first."""
    from app.controller.passivity import PassivitySettings
    from app.session.stability import design_stiffness, device_bound, grip_damping, press

    held = hand or DEFAULT_HAND
    b = grip_damping(device, held)
    bound = 2.0 * b / 1e-3
    per_k_t = design_stiffness(1.0, device=device)
    lines = [
        f"  {label}: bound 2b/T with the hand {bound:,.0f} N/m (b = {b:.2f} N s/m at the grip), "
        f"device only {device_bound(device):,.0f} N/m"
    ]
    stable: dict[str, list[float]] = {"plain": [], "PO/PC": []}
    for multiple in multiples:
        k_t = multiple * bound / per_k_t
        cells = []
        for name, enabled in (("plain", False), ("PO/PC", True)):
            gains = {"k_t": [k_t] * 3 + [1.0] * 3}
            passivity = PassivitySettings(enabled=enabled)
            r = press(
                1e5, "pose", gains, released=hand is None, window=window, device=device, passivity=passivity, hand=held
            )
            if r.stable:
                stable[name].append(multiple)
            cells.append(f"{name} {_judged(r)}")
        lines.append(f"    design {multiple:4.2f} x bound, K_T {k_t:5.2f}: " + " | ".join(cells))
    for name, good in stable.items():
        upto = 0.0
        for multiple in multiples:
            if multiple not in good:
                break
            upto = multiple
        listed = ", ".join(f"{m:g}" for m in good) or "none"
        run = f"at every tested multiple up to {upto:g} x" if upto else "not at the smallest tested multiple"
        lines.append(f"    {name}: stable at {listed} x bound; {run}")
    return lines


#: How the bench prints each :attr:`~app.session.stability.PressResult.verdict`.
_VERDICT_WORDS = {
    "stable": "stable",
    "oscillating": "OSCILLATES",
    "drifting": "DRIFTS",
    "saturated": "SATURATED",
    "pushed": "PUSHED IN",
}


def _judged(r: PressResult) -> str:
    """A press's verdict, ripple, felt stiffness and the grip's travel over the judged window
    (:attr:`~app.session.stability.PressResult.grip_drift`, + out of the surface), in fixed width."""
    state = _VERDICT_WORDS[r.verdict]
    return (
        f"{state:>10} (ripple {r.ripple:6.2f} N, felt {r.felt_stiffness:7,.0f} N/m, grip {1e3 * r.grip_drift:+7.2f} mm)"
    )


#: Servo rates (Hz) of the stability bench's rate rows and of ``frhc web --rate``'s examples.
RATES = (1000.0, 2000.0, 4000.0)


def _rate_lines(quick: bool) -> list[str]:
    """Plain pose-mode walls designed at multiples of the 1 kHz bound (default hand), rendered at
    each of :data:`RATES` (the gains are physical, so the design is the same wall at every rate).

    The sampled-data bound ``2 b / T`` grows with the rate; measured, the stiffness a plain wall
    holds does not (kraft: 0.5 x the 1 kHz bound stable at 1 and 4 kHz, 1 x oscillating at both,
    ripple 5.7 and 4.7 N): in pose mode the limit of this position-force loop is the slave's
    tracking spring and mass between the grip and the wall, not the sampling."""
    from app.session.stability import RELEASED, design_stiffness, grip_damping, press

    lines = ["servo rate: plain pose-mode walls (default hand) designed at multiples of the 1 kHz bound, at each rate"]
    rates = " / ".join(f"{rate / 1000:g}" for rate in RATES)
    for device in ("kraft",) if quick else ("kraft", "jpl", "freflex"):
        # The bound 2 b / T at each rate, b with the default hand and with the hand let go.
        b_hand, b_alone = grip_damping(device), grip_damping(device, RELEASED)
        with_hand = " / ".join(f"{2.0 * b_hand * rate:,.0f}" for rate in RATES)
        alone = " / ".join(f"{2.0 * b_alone * rate:,.0f}" for rate in RATES)
        lines.append(f"  {device}: bound 2b/T at {rates} kHz: with the hand {with_hand} N/m, device only {alone} N/m")
        per_k_t = design_stiffness(1.0, device=device)
        for multiple in (1.0,) if quick else (0.5, 1.0, 2.0):
            k_t = multiple * 2.0 * b_hand * RATES[0] / per_k_t
            cells = []
            for rate in RATES:
                gains = {"k_t": [k_t] * 3 + [1.0] * 3}
                r = press(1e5, "pose", device=device, gains=gains, servo_rate=rate)
                cells.append(f"{rate / 1000:g} kHz {_judged(r)}")
            lines.append(f"    design {multiple:g} x the 1 kHz bound: " + " | ".join(cells))
    return lines


def _delay_lines(quick: bool) -> list[str]:
    """The probe press in pose mode through a delayed channel: direct reflection against wave variables.

    The felt stiffness is the secant between the press's two plateaus
    (:class:`~app.session.stability.FeltStiffness`), so it depends on no contact point. Against a
    slave of stiffness ``k_s`` (its tracking spring in series with the surface) a wave channel of
    impedance b and one-way delay T gives way by ``(T + tau) / b`` per newton once the waves are
    steady, ``tau = 1 / (2 pi wave_cutoff_hz)`` being the lag each end's low-pass on the arriving
    wave adds to the delay (the integral of ``u - u`` delayed by ``T + tau`` is ``(T + tau) u``;
    Niemeyer & Slotine's line compliance ``T / b`` with the filters counted). So the operator
    feels about ``K_T K_P / (1 / k_s + (T + tau) / b)``, where direct reflection gives
    ``K_T K_P k_s`` (when it settles). Measured (kraft, ``frhc bench stability``), the secant
    agrees with this: wave variables ~1,050 N/m without delay against ~1,030 expected, ~680 N/m
    at 50 ms each way against ~680; direct reflection without delay ~6,150 against ~5,800.
    Without the ``tau`` term the wave figures would be expected ~5.5 x and ~2.2 x too high. A
    press that did not settle has no steady plateau and its felt figure means little: direct
    reflection at 50 ms each way bounces on the surface; wave variables overshoot once after
    each push (the operator meets the wall a round trip late), which is why a delayed press holds
    its second push six round trips longer before it is judged
    (:func:`~app.session.stability.delayed_press`).
    """
    from app.session.spec import load_session
    from app.session.stability import BAR_DELAY_MS, delayed_press, design_stiffness
    from app.teleop.channel import ChannelSettings

    gains = load_session("probe_rate").gains
    scale = gains.k_t[2] * gains.k_p[2]
    direct = design_stiffness(gains.k_t[2])  # K_T K_P k_s
    settings = ChannelSettings()
    b = settings.wave_impedance
    tau = settings.wave_lag

    def line(label: str, coupling: Coupling, delay_ms: float) -> str:
        r = delayed_press(coupling, delay_ms)
        expected = scale / (scale / direct + (delay_ms * 1e-3 + tau) / b) if coupling == "wave" else direct
        return (
            f"  {label:<22} force {r.mean_force:6.2f} N, ripple {r.ripple:7.3f} N, "
            f"{'settled' if r.settled else 'OSCILLATES':>10}, felt stiffness {r.felt_stiffness:7,.0f} N/m "
            f"(expected ~{expected:,.0f})"
        )

    lines = [
        f"delayed channel, pose mode, surface 100000 N/m, K_T 1, {BAR_DELAY_MS:.0f} ms each way "
        f"(wave impedance b = {b:g} N s/m, wave low-pass lag tau = {tau * 1e3:.0f} ms); expected felt stiffness: "
        "direct K_T K_P k_s, wave K_T K_P / (1/k_s + (T + tau)/b)"
    ]
    lines.append(line("no delay (for scale)", "direct", 0.0))
    lines.append(line("direct", "direct", BAR_DELAY_MS))
    lines.append(line("wave variables", "wave", BAR_DELAY_MS))
    for delay in () if quick else (0.0, 25.0, 100.0, 200.0):
        lines.append(line(f"wave, {delay:.0f} ms each way", "wave", delay))
    return lines


def _sweep(quick: bool) -> str:
    from app.sweep.bench import run

    return run(quick=quick)


def _plant(quick: bool) -> str:
    from app.device.bench import run

    return run(quick=quick)


def _contact(quick: bool) -> str:
    from app.world.bench import run

    return run(quick=quick)


def bench_device(quick: bool = False) -> str:
    """The device boundary over loopback: a client paced at 1 kHz against ``frhc device serve``
    (touch3, in its own process, at the real-time priority it asks for), and connection loss to
    zero force (server in this process).

    The client runs four ways, alternated in rounds of 1,000 periods so that all see the same
    machine load: at this process's scheduling and at the priority the web demo's loop process
    asks for (:func:`~app.session.pacer.raise_priority`), each blocking on the socket for the
    reply and polling it first (``HaplyClient``'s default: the whole wait at ordinary scheduling,
    up to :data:`~app.device.haply.REALTIME_SPIN` under real time). Rate and jitter are the
    pacer's (period start to start); the added latency is each round trip (command sent to state
    received) less the median cost of the same device step in process. The load average is
    printed before and after.
    """
    import re
    import subprocess
    import sys

    from app.device.cartesian_sim import SimCartesianDevice
    from app.device.haply import DeviceServer, HaplyClient
    from app.device.spec import load_device
    from app.session.pacer import SCHEDULING, Pacer, raised_priority

    spec = load_device("touch3")
    local = SimCartesianDevice(spec)
    push = np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    step_ns = np.empty(2000, dtype=np.int64)
    for i in range(len(step_ns)):
        t0 = time.perf_counter_ns()
        local.step(push, 1e-3)
        step_ns[i] = time.perf_counter_ns() - t0
    step_us = float(np.median(step_ns)) / 1e3
    rounds, per_round = (2, 1000) if quick else (8, 1000)
    load_before = os.getloadavg()

    cmd = [sys.executable, "-m", "app.cli", "device", "serve", "--device", "touch3", "--port", "0"]
    server = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    lines = [
        f"device boundary over loopback (touch3 served by `frhc device serve`, client paced at 1 kHz, "
        f"{rounds} alternated rounds of {per_round} periods per row; added latency = round trip - "
        f"{step_us:.1f} us device step):"
    ]
    # (raised, spin): spin None is the client's default (poll the whole wait at ordinary scheduling,
    # up to REALTIME_SPIN under real time).
    configs = [(False, 0.0), (False, None), (True, 0.0), (True, None)]
    rtt: dict[tuple[bool, float | None], list[IntArray]] = {c: [] for c in configs}
    periods: dict[tuple[bool, float | None], list[IntArray]] = {c: [] for c in configs}
    stalls = dict.fromkeys(configs, 0)
    got = 0
    try:
        assert server.stdout is not None
        banner = server.stdout.readline()
        found = re.search(r"ws://[\d.]+:(\d+) \(([^)]*)\)", banner)
        if found is None:
            raise RuntimeError(f"frhc device serve did not print its address: {banner!r}")
        client = HaplyClient(f"ws://127.0.0.1:{found.group(1)}", period=1e-3)
        lines[0] += f" server {found.group(2)}"
        for _ in range(rounds):
            for raise_client, spin in configs:
                client.spin = spin
                with raised_priority() if raise_client else nullcontext(0) as level:
                    got = max(got, level)
                    pacer = Pacer(1e-3)
                    trips, late = _paced_round_trips(client, pacer, push, per_round)
                stats = pacer.rings
                count = min(int(stats.counters[0]), per_round)
                periods[raise_client, spin].append(stats.periods[1:count].copy())
                rtt[raise_client, spin].append(trips)
                stalls[raise_client, spin] += late
        client.close()
    finally:
        server.terminate()
        server.wait(timeout=10)
    load_after = os.getloadavg()
    for raise_client, spin in configs:
        label = SCHEDULING[got] if raise_client else "as started"
        how = "blocking" if spin == 0.0 else "polling (default)"
        lines.append(
            f"  client {label}, {how}:\n"
            + _round_trip_row(
                np.concatenate(periods[raise_client, spin]), np.concatenate(rtt[raise_client, spin]),
                stalls[raise_client, spin], step_us,
            )
        )  # fmt: skip
    lines.append(
        "  load average (1, 5, 15 min) before "
        + ", ".join(f"{v:.2f}" for v in load_before)
        + "; after "
        + ", ".join(f"{v:.2f}" for v in load_after)
        + f" ({os.cpu_count()} CPUs)"
    )

    # The served device's thread is started raised, as `frhc device serve` runs (it inherits this
    # thread's scheduling): the device's own processor would zero its force whatever else runs.
    loss_us = []
    with raised_priority() as got:
        served = DeviceServer(SimCartesianDevice(spec), port=0).start()
        try:
            for _ in range(5 if quick else 20):
                served.zeroed.clear()
                client = HaplyClient(f"ws://127.0.0.1:{served.port}", period=1e-3)
                for _ in range(20):
                    client.step(push, 1e-3)
                t_loss = time.perf_counter()
                client.disconnect()
                served.zeroed.wait(1.0)
                loss_us.append((served.log.events[-1].at - t_loss) * 1e6)
        finally:
            served.shutdown()
    lines.append(
        f"  connection loss to zero force (server in this process, {SCHEDULING[got]}, n={len(loss_us)}): "
        f"median {np.median(loss_us):7.1f} us   max {np.max(loss_us):7.1f} us"
    )
    return "\n".join(lines)


def _paced_round_trips(client: HaplyClient, pacer: Pacer, push: Array, n: int) -> tuple[IntArray, int]:
    """``n`` periods of ``client.step`` paced by ``pacer``: each round trip (ns) and how many
    replies came later than the period (the watchdog's zero)."""
    rtt = np.empty(n, dtype=np.int64)
    stalls = 0
    for i in range(n):
        pacer.wait()
        t0 = time.perf_counter_ns()
        stalls += not client.step(push, 1e-3).fresh
        rtt[i] = time.perf_counter_ns() - t0
        pacer.done()
    return rtt, stalls


def _round_trip_row(periods_ns: IntArray, rtt_ns: IntArray, stalls: int, step_us: float) -> str:
    """Rate, jitter, round trip and added latency of one client configuration (all its rounds)."""
    periods = periods_ns / 1e3
    rate = len(periods) / (periods.sum() * 1e-6)
    jitter = np.abs(periods - 1000.0)
    added = rtt_ns / 1e3 - step_us
    return (
        f"    rate {rate:8.1f} Hz ({100 * (rate / 1000 - 1):+.2f} %)   jitter p99 {np.percentile(jitter, 99):7.1f} us   "
        f"late replies (watchdog) {stalls}/{len(rtt_ns)}\n"
        f"    round trip median {np.median(rtt_ns) / 1e3:7.1f} us   p99 {np.percentile(rtt_ns, 99) / 1e3:7.1f} us   "
        f"added latency median {np.median(added):7.1f} us   p99 {np.percentile(added, 99):7.1f} us"
    )


def bench_moving(quick: bool = False) -> str:
    """Dynamic objects (issue 30 bars). The whole tick of ``probe_rate`` (every object static) and
    of ``stack_topple`` (three dynamic blocks, in contact with each other and the table
    throughout, until the stylus topples them), alternated in rounds in one run so both see the
    same machine load; then the object-object contact each way: MuJoCo's (the moving world's
    step on the standing stack, tool away) and python-fcl's (``fcl_contacts``, a box on a slab)."""
    import fcl
    import trimesh

    from app.session.run import run_session
    from app.session.spec import load_session
    from app.world.dynamics import MovingWorld, _bvh, fcl_contacts
    from app.world.scene import load_scene

    rounds, duration = (2, 1.5) if quick else (4, 3.0)
    ticks: dict[str, list[float]] = {"probe_rate": [], "stack_topple": []}
    for _ in range(rounds):
        for name, got in ticks.items():
            s = run_session(load_session(name).with_changes(duration=duration), out_dir=None).summary
            got.append(s["timing"]["tick"]["median_us"])
    probe, stack = float(np.median(ticks["probe_rate"])), float(np.median(ticks["stack_topple"]))
    lines = [
        f"whole tick, median of {rounds} alternated runs of {duration:g} s (headless, no logging):",
        f"  probe_rate (all static)             median {probe:7.1f} us   rounds {ticks['probe_rate']}",
        f"  stack_topple (3 dynamic in contact) median {stack:7.1f} us   rounds {ticks['stack_topple']}",
        f"  ratio {stack / probe:.2f}x, real-time factor of the stack at 1 kHz {1000.0 / stack:.1f}",
    ]
    n = 500 if quick else 3000
    world = MovingWorld(load_scene("stack_topple"), 1e-3)
    lines.append(
        f"moving world step, three stacked blocks (MuJoCo collision): {_stats(_timed(lambda: world.step(1e-3), n))}"
    )
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    a, b = _bvh(box), _bvh(trimesh.creation.box(extents=(1.0, 1.0, 0.1)))
    T = np.eye(4)
    T[0:3, 3] = 0.01, 0.02, 0.098
    a.setTransform(fcl.Transform(T[0:3, 0:3], T[0:3, 3]))
    verts = np.asarray(box.vertices, dtype=float)
    lines.append(
        f"fcl_contacts, a box sunk 2 mm on a slab (BVH-BVH):           {_stats(_timed(lambda: fcl_contacts(a, b, verts, T), n))}"
    )
    return "\n".join(lines)


def _timed(fn: Callable[[], object], n: int) -> np.ndarray:
    """Nanoseconds of n calls of fn, after n // 10 untimed ones."""
    for _ in range(n // 10):
        fn()
    ns = np.empty(n, dtype=np.int64)
    for i in range(n):
        t0 = time.perf_counter_ns()
        fn()
        ns[i] = time.perf_counter_ns() - t0
    return ns


BENCHES: dict[str, Callable[[bool], str]] = {
    "controller": bench_controller,
    "plant": _plant,
    "contact": _contact,
    "tick": bench_tick,
    "arm": bench_arm,
    "stability": bench_stability,
    "sweep": _sweep,
    "device": bench_device,
    "moving": bench_moving,
}


def run(what: str = "all", quick: bool = False, window: float | None = None) -> str:
    """Run one benchmark (or ``"all"``) and return its report; ``window`` (s): the stability
    bench's judged hold (:func:`bench_stability`; None = the settling window)."""
    names = list(BENCHES) if what == "all" else [what]
    judged = SETTLE_WINDOW if window is None else window
    return "\n\n".join(
        bench_stability(quick, judged) if name == "stability" else BENCHES[name](quick) for name in names
    )
