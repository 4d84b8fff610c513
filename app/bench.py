"""Benchmarks behind ``frhc bench``: each prints medians and p99 of the hot paths.

Speed goals live here, not in timed tests: the figures depend on the machine.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from app.session.loop import STAGES
from app.teleop.channel import Coupling


def _stats(ns: np.ndarray) -> str:
    us = ns / 1000.0
    return f"median {np.median(us):8.1f} us   p99 {np.percentile(us, 99):8.1f} us   (n={len(us)})"


def bench_controller(quick: bool = False) -> str:
    """Controller step on the Kraft-like device, rate mode, reflecting a contact, >= 10k steps."""
    from app.controller.frhc import FRHCController
    from app.controller.types import FTReading, Switches
    from app.device.spec import load_device
    from app.world.scene import load_scene
    from app.world.slave import VirtualSlave

    device = load_device("kraft")
    slave = VirtualSlave(load_scene("probe")).slave_model()
    ctrl = FRHCController(device, device.data.gains, slave)
    n = 3000 if quick else 20000
    rng = np.random.default_rng(0)
    q0 = np.array(device.data.home)
    walk = q0 + np.cumsum(rng.normal(scale=2e-4, size=(n, device.n_joints)), axis=0) + 0.05
    ft = FTReading(wrench_S=np.array([0.5, -0.2, 4.0, 0.01, 0.02, 0.0]))
    sw = Switches(deadman=True, reflection=True)
    ns = np.empty(n, dtype=np.int64)
    for i in range(n):
        t0 = time.perf_counter_ns()
        ctrl.step(walk[i], sw, ft, 1e-3)
        ns[i] = time.perf_counter_ns() - t0
    return f"controller step (kraft, rate mode, reflecting): {_stats(ns)}"


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
    return "\n".join(lines)


def bench_arm(quick: bool = False) -> str:
    """Arm slaves (issue 15 bars): slave step alone, then the whole tick on ``probe`` with each arm."""
    from app.controller.types import SlaveCommand
    from app.session.run import run_session
    from app.session.spec import load_session
    from app.world.scene import load_scene, with_slave
    from app.world.slave_api import make_slave

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


def bench_stability(quick: bool = False) -> str:
    """Whole-loop contact stability: surface stiffness sweep (rate mode) and felt stiffness (pose mode).

    In pose mode the operator feels roughly ``K_T K_P k_s``, with ``k_s`` the slave's tracking
    spring in series with the surface; the sampled-data passivity bound for a virtual wall is
    ``K < 2 b / T`` with b the physical damping at the grip (device joints plus the hand).
    """
    from app.device.plant import DevicePlant
    from app.device.spec import load_device
    from app.session.spec import load_session
    from app.session.stability import press

    session = load_session("probe_rate")
    kp = session.scene.spec.slave.kp_lin
    k_p = session.gains.k_p[2]
    plant_model = DevicePlant(load_device("kraft")).model
    b_device = float(np.max(plant_model.dof_damping)) / 0.25**2  # joint damping over a ~25 cm lever
    b = b_device + session.data.hand.damping_trans
    lines = ["contact stability, probe pushed 3 cm by the hand, reflection on (settled: ripple < 5 % of mean)"]
    stiffnesses = (3e3, 3e4, 3e5) if quick else (3e3, 1e4, 3e4, 1e5, 3e5, 1e6)
    for k in stiffnesses:
        r = press(k, "rate")
        lines.append(
            f"  rate mode, surface {k:9.0f} N/m: force {r.mean_force:7.2f} N, ripple {r.ripple:8.3f} N, "
            f"{'settled' if r.settled else 'OSCILLATES'}"
        )
    k_surface = 1e5
    k_series = kp * k_surface / (kp + k_surface)
    lines.append(
        f"  passivity bound 2b/T with b = {b:.1f} N s/m (device ~{b_device:.1f} + hand): {2 * b / 1e-3:,.0f} N/m"
    )
    for k_t in (1.0, 4.0, 16.0) if quick else (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        r = press(k_surface, "pose", gains={"k_t": [k_t] * 3 + [1.0] * 3})
        felt = k_t * k_p * k_series
        lines.append(
            f"  pose mode, K_T {k_t:4.0f}: felt stiffness ~{felt:9,.0f} N/m ({felt / (2 * b / 1e-3):4.2f} x bound), "
            f"ripple {r.ripple:8.3f} N, {'settled' if r.settled else 'OSCILLATES'}"
        )
    lines.extend(_delay_lines(quick))
    return "\n".join(lines)


def _delay_lines(quick: bool) -> list[str]:
    """The probe press in pose mode through a delayed channel: direct reflection against wave variables.

    Against a rigid slave a wave channel of impedance b and one-way delay T feels, at low
    frequency, like a spring ``b / T`` in series with the slave's (Niemeyer & Slotine): the
    operator feels about ``K_T K_P / (1 / k_s + T / b)`` where direct reflection without delay
    gives ``K_T K_P k_s``. The measured felt stiffness counts the grip's travel from the tick the
    tool touched, which a delayed slave does a round trip late, so it reads high under delay.
    """
    from app.session.spec import load_session
    from app.session.stability import BAR_DELAY_MS, delayed_press
    from app.teleop.channel import ChannelSettings

    session = load_session("probe_rate")
    kp = session.scene.spec.slave.kp_lin
    k_series = kp * 1e5 / (kp + 1e5)
    scale = session.gains.k_t[2] * session.gains.k_p[2]
    b = ChannelSettings().wave_impedance

    def line(label: str, coupling: Coupling, delay_ms: float) -> str:
        r = delayed_press(coupling, delay_ms)
        expected = scale / (1.0 / k_series + delay_ms * 1e-3 / b) if coupling == "wave" else scale * k_series
        return (
            f"  {label:<22} force {r.mean_force:6.2f} N, ripple {r.ripple:7.3f} N, "
            f"{'settled' if r.settled else 'OSCILLATES':>10}, felt stiffness {r.felt_stiffness:7,.0f} N/m "
            f"(expected ~{expected:,.0f})"
        )

    lines = [
        f"delayed channel, pose mode, surface 100000 N/m, K_T 1, {BAR_DELAY_MS:.0f} ms each way "
        f"(wave impedance b = {b:g} N s/m)"
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


BENCHES: dict[str, Callable[[bool], str]] = {
    "controller": bench_controller,
    "plant": _plant,
    "contact": _contact,
    "tick": bench_tick,
    "arm": bench_arm,
    "stability": bench_stability,
    "sweep": _sweep,
}


def run(what: str = "all", quick: bool = False) -> str:
    """Run one benchmark (or ``"all"``) and return its report."""
    names = list(BENCHES) if what == "all" else [what]
    return "\n\n".join(BENCHES[name](quick) for name in names)
