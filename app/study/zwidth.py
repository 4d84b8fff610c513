"""The Z-width of a design (Colgate & Brown 1994): the largest stable felt stiffness per damping.

For a device, servo rate, delay and renderer, each point presses the probe tool into a stiff
surface in pose mode (the probe session's push, :func:`~app.session.stability.press`); the felt
stiffness is set by the task-wrench gain K_T (felt ~ K_T K_P k_s, with k_s the slave's tracking
spring in series with the surface) and the rendered damping by the controller's translational
K_D. A point is *stable* when the contact force settles: its peak-to-peak over the last 0.6 s
is below 5 % of its mean (:data:`~app.session.metrics.SETTLE_RIPPLE`), the motors did not
saturate while the hand held its pushes (a wall held at the motors' limit settles as a constant
force would, and renders no stiffness) and the slave stayed below its force limit
(:attr:`~app.session.stability.PressResult.stable`). For each damping value the
largest stable K_T is found by bisection in log space between ``k_t_low`` (must be stable) and
``k_t_high`` (must oscillate).

Renderers: ``plain`` (the paper's controller), ``pc`` (with the passivity controller,
:mod:`app.controller.passivity`), ``wave`` (wave variables across the delayed channel,
:mod:`app.teleop.wave`). Every point is an ordinary headless session run by
:func:`~app.session.stability.press`. Each (renderer, damping) bisection is sequential but
independent of the others, so :func:`zwidth` runs the bisections as the points of the sweep
engine (:func:`app.sweep.engine.run_points`: serially or on Ray, the same edges).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from app.controller.passivity import PassivitySettings
from app.device.hand import HandParams
from app.session.stability import PressResult, press
from app.teleop.channel import ChannelSettings

Renderer = Literal["plain", "pc", "wave"]
RENDERERS: tuple[str, ...] = get_args(Renderer)
#: Surface stiffness of every point (N/m): stiff, so the felt stiffness is set by K_T.
SURFACE_STIFFNESS = 1e5
#: The hand of a Z-width unless another is given.
DEFAULT_HAND = HandParams()


@dataclass(frozen=True)
class ZWidthPoint:
    """The stability edge of one renderer at one damping.

    Attributes:
        renderer: ``plain``, ``pc`` or ``wave``. damping: Rendered translational damping K_D (N s/m).
        k_t_stable: Largest K_T found stable (NaN if even ``k_t_low`` is not).
        felt_stiffness: Felt stiffness measured at ``k_t_stable`` (N/m, NaN if none).
        k_t_unstable: Smallest K_T found unstable (inf if even ``k_t_high`` is stable).
        points: Sessions run for this edge.
        error: Why the bisection failed (one line; the numbers are then NaN), empty when it ran.
    """

    renderer: str
    damping: float
    k_t_stable: float
    felt_stiffness: float
    k_t_unstable: float
    points: int
    error: str = ""

    def line(self) -> str:
        """The edge as a row under :data:`TABLE_HEADER`: ``none`` where no K_T was stable, ``not
        reached`` where none oscillated (rather than NaN and inf)."""
        stable = "none" if math.isnan(self.k_t_stable) else f"{self.k_t_stable:.3g}"
        felt = "-" if math.isnan(self.felt_stiffness) else f"{self.felt_stiffness:,.0f}"
        if math.isnan(self.k_t_unstable):
            unstable = "-"
        else:
            unstable = "not reached" if math.isinf(self.k_t_unstable) else f"{self.k_t_unstable:.3g}"
        row = f"{self.renderer:<9} {self.damping:>12g} {stable:>19} {felt:>12} {unstable:>18}"
        return row + (f"   failed: {self.error}" if self.error else "")


#: The header of :meth:`ZWidthPoint.line`'s rows.
TABLE_HEADER = (
    f"{'renderer':<9} {'K_D (N s/m)':>12} {'largest stable K_T':>19} {'felt (N/m)':>12} {'oscillates at K_T':>18}"
)


def _press(
    k_t: float, damping: float, renderer: str, device: str, servo_rate: float, delay_ms: float, hand: HandParams | None
) -> PressResult:
    gains: dict[str, Any] = {"k_t": [k_t] * 3 + [1.0] * 3, "k_d": [damping] * 3 + [0.02] * 3}
    channel = ChannelSettings(delay_ms=delay_ms, coupling="wave" if renderer == "wave" else "direct")
    return press(
        SURFACE_STIFFNESS,
        "pose",
        gains=gains,
        device=device,
        servo_rate=servo_rate,
        passivity=PassivitySettings(enabled=renderer == "pc"),
        channel=channel,
        hand=hand or HandParams(),
        released=hand is None,
    )


def stability_edge(
    renderer: str,
    damping: float,
    device: str = "kraft",
    servo_rate: float = 1000.0,
    delay_ms: float = 0.0,
    k_t_low: float = 0.25,
    k_t_high: float = 64.0,
    iterations: int = 5,
    hand: HandParams | None = DEFAULT_HAND,
) -> ZWidthPoint:
    """Bisect (in log K_T) for the largest stable K_T of ``renderer`` at ``damping`` (N s/m),
    pushed by ``hand`` (None: the default hand, which lets go after the first push, see
    :func:`~app.session.stability.press`)."""
    if renderer not in RENDERERS:
        raise ValueError(f"renderer must be one of {RENDERERS}, got {renderer!r}")
    run = 0

    def stable(k_t: float) -> tuple[bool, float]:
        nonlocal run
        run += 1
        r = _press(k_t, damping, renderer, device, servo_rate, delay_ms, hand)
        return r.stable, r.felt_stiffness

    ok_low, felt_low = stable(k_t_low)
    if not ok_low:
        return ZWidthPoint(renderer, damping, math.nan, math.nan, k_t_low, run)
    ok_high, felt_high = stable(k_t_high)
    if ok_high:
        return ZWidthPoint(renderer, damping, k_t_high, felt_high, math.inf, run)
    lo, hi, felt = k_t_low, k_t_high, felt_low
    for _ in range(iterations):
        mid = math.sqrt(lo * hi)
        ok, felt_mid = stable(mid)
        if ok:
            lo, felt = mid, felt_mid
        else:
            hi = mid
    return ZWidthPoint(renderer, damping, lo, felt, hi, run)


@dataclass(frozen=True)
class EdgeTask:
    """One bisection as a point of the sweep engine (picklable): payload ``(renderer, damping)``.

    Attributes:
        device: Device name. servo_rate: Servo rate (Hz). delay_ms: One-way channel delay (ms).
        iterations: Bisection steps after the two ends.
        hand: The operator's hand (None: let go after the first push).
    """

    device: str
    servo_rate: float
    delay_ms: float
    iterations: int
    hand: HandParams | None = DEFAULT_HAND

    def __call__(self, payload: tuple[str, float]) -> dict[str, Any]:
        renderer, damping = payload
        edge = stability_edge(
            renderer, damping, self.device, self.servo_rate, self.delay_ms, iterations=self.iterations, hand=self.hand
        )
        return dataclasses.asdict(edge)


def zwidth(
    out_dir: Path,
    renderers: tuple[str, ...] = ("plain", "pc"),
    dampings: tuple[float, ...] = (0.0, 4.0, 16.0),
    device: str = "kraft",
    servo_rate: float = 1000.0,
    delay_ms: float = 0.0,
    iterations: int = 5,
    progress: bool = False,
    workers: int = 1,
    address: str | None = None,
    hand: HandParams | None = DEFAULT_HAND,
) -> list[ZWidthPoint]:
    """Every (renderer, damping) edge; writes ``zwidth.parquet`` and ``zwidth.png`` to ``out_dir``.

    ``hand`` pushes every press (None: the default hand, let go after the first push).

    The edges are bisected in parallel on the sweep engine's ``workers`` (1 = serially in this
    process) and ``address`` (a Ray cluster; see :func:`app.sweep.engine.run_points`). An edge
    whose bisection fails is kept, with NaN numbers and its ``error``.
    """
    from app.sweep.engine import Engine

    out_dir.mkdir(parents=True, exist_ok=True)
    pairs = [(renderer, damping) for renderer in renderers for damping in dampings]
    task = EdgeTask(device, servo_rate, delay_ms, iterations, hand)
    found: dict[int, ZWidthPoint] = {}
    with (
        # The bar starts once the engine is up: a cluster that does not answer is one line.
        Engine(workers, address) as engine,
        tqdm(total=len(pairs), unit="edge", disable=not progress) as bar,
    ):
        for index, row in engine.run(task, enumerate(pairs)):
            renderer, damping = pairs[index]
            if row["status"] == "ok":
                found[index] = ZWidthPoint(**{k: row[k] for k in ZWidthPoint.__dataclass_fields__})
            else:
                found[index] = ZWidthPoint(renderer, damping, math.nan, math.nan, math.nan, 0, row["error"])
            bar.update(1)
    edges = [found[i] for i in range(len(pairs))]
    columns = {name: [getattr(e, name) for e in edges] for name in ZWidthPoint.__dataclass_fields__}
    table = pa.table({**columns, "device": [device] * len(edges), "servo_rate": [servo_rate] * len(edges)})
    table = table.append_column("delay_ms", pa.array([delay_ms] * len(edges)))
    pq.write_table(table, out_dir / "zwidth.parquet")
    held = "released" if hand is None else f"hand {hand.stiffness_trans:g} N/m, {hand.damping_trans:g} N s/m"
    _plot(edges, out_dir / "zwidth.png", f"{device}, {servo_rate:g} Hz, delay {delay_ms:g} ms each way, {held}")
    return edges


def _plot(edges: list[ZWidthPoint], path: Path, title: str) -> None:
    fig, ax = plt.subplots(figsize=(6, 4))
    for renderer in dict.fromkeys(e.renderer for e in edges):
        mine = [e for e in edges if e.renderer == renderer]
        ax.plot([e.damping for e in mine], [e.felt_stiffness for e in mine], "o-", label=renderer)
    ax.set_xlabel("rendered damping K_D (N s/m)")
    ax.set_ylabel("largest stable felt stiffness (N/m)")
    ax.set_yscale("log")
    ax.set_title(f"Z-width: {title}")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
