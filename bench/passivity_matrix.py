"""Issue 26's stability matrix: plain rendering and PO/PC pose-mode walls on devices, variants and hands.

Usage::

    python bench/passivity_matrix.py run OUT.jsonl [--sets tuned,held,enc] [--pc key=value ...]
        [--plain] [--window S] [--points FILE]
    python bench/passivity_matrix.py count PLAIN.jsonl PC.jsonl [--rows N] [--reference PLAIN06.jsonl]
        [--select WORST.jsonl]

``run`` presses every point of the chosen sets (``--plain``: plain rendering, else PO/PC with the
``--pc`` overrides of :class:`~app.controller.passivity.PassivitySettings`) and appends one JSON
line per press (with the judged window's course, :func:`profile`); points already in ``OUT`` are
skipped, so a run can be resumed. ``count`` prints,
per set, stable / worse than plain / the wall vanishes, under two felt-stiffness measures (below),
and the ``--rows`` PO/PC presses with the largest ripple; ``--reference``: plain rows the vanish
bar's reference comes from (an 8 s run on a few points takes it from the 0.6 s matrix);
``--select``: write up to 51 of PO/PC's worst points (worse, vanished, or stable with a ripple
over 2.5 %, every second one) for ``run --points``.

The sets (issue 26's composition as its notes describe it; the notes' scripts are not in the
repository, so the variants of the held-out set are this file's choice, made before any run):
0.25 / 1 / 2 / 4x the with-hand bound 2b/T (the released hand: the default hand's), a 1e5 N/m
surface, 0.6 s judged window after a 0.2 s hold.

- ``tuned`` (444): kraft / jpl / freflex as shipped with the six hands of
  :data:`~app.session.stability.HANDS` and released (84), and the ten variants of
  :data:`~app.device.variants.VARIANTS` with the default hand, the 100/1 hand and released (360).
- ``held`` (216): hands 250/2 and 700/5 and released on the shipped devices and on five variants
  not in ``VARIANTS`` (11- and 14-bit encoders, damping x0.75, armature +0.001, links x1.5).
- ``enc`` (420): 10 / 11 / 12 / 16 / 20-bit copies with the six hands and released.

*Worse than plain*: plain stable at the point and PO/PC not. *The wall vanishes*: PO/PC's verdict
is ``pushed`` (the grip went on into the surface), or its felt stiffness is below half the largest
felt stiffness plain rendering holds stably on the same device and hand at no larger multiple.
*Felt* is measured two ways: ``secant`` as :class:`~app.session.stability.FeltStiffness` reads
it; ``capped`` the same, no larger than the wall's design stiffness at the grip ``K_T K_P k_s``
(:func:`~app.session.stability.design_stiffness`): the rendering cannot be stiffer than it was
designed, so a secant above it is the joints' friction holding a small push (plain, Kraft, 120/3
hand, 2x: 79 kN/m at 1.2 N on a 13.6 kN/m design), not a wall a controller could be asked for.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.controller.passivity import PassivitySettings
from app.device.hand import HandParams
from app.device.variants import VARIANTS, DeviceVariant, write_variant
from app.session.metrics import SETTLE_MIN_FORCE, SETTLE_RIPPLE, SETTLE_WINDOW
from app.session.stability import (
    DRIFT_TOLERANCE,
    HANDS,
    HOLD_SECONDS,
    POSE_SECONDS,
    FeltStiffness,
    design_stiffness,
    grip_damping,
    press,
    release_time,
)
from app.session.tick import TickRecord

MULTIPLES = (0.25, 1.0, 2.0, 4.0)
DEVICES = ("kraft", "jpl", "freflex")
DEFAULT = HANDS[0]
SOFT = HANDS[1]
HELD_HANDS = (
    ("250/2", HandParams(stiffness_trans=250.0, damping_trans=2.0)),
    ("700/5", HandParams(stiffness_trans=700.0, damping_trans=5.0)),
)
HELD_VARIANTS = (
    DeviceVariant("enc11", encoder_bits=11),
    DeviceVariant("enc14", encoder_bits=14),
    DeviceVariant("damp0.75", damping_scale=0.75),
    DeviceVariant("arm0.001", armature=0.001),
    DeviceVariant("heavy1.5", mass_scale=1.5),
)
ENC_BITS = (10, 11, 12, 16, 20)
Hand = tuple[str, HandParams | None]
#: A point: ``(set, device, variant label or "", hand label, multiple)``.
Key = tuple[str, str, str, str, float]
Rows = dict[Key, dict[str, Any]]
RELEASED: Hand = ("released", None)


def points(sets: tuple[str, ...]) -> list[tuple[str, str, DeviceVariant | None, Hand, float]]:
    """``(set, device, variant or None, (hand label, hand or None = released), multiple)``."""
    out: list[tuple[str, str, DeviceVariant | None, Hand, float]] = []
    for device in DEVICES:
        combos: list[tuple[str, DeviceVariant | None, Hand]] = []
        if "tuned" in sets:
            combos += [("tuned", None, h) for h in (*HANDS, RELEASED)]
            combos += [("tuned", v, h) for v in VARIANTS for h in (DEFAULT, SOFT, RELEASED)]
        if "held" in sets:
            combos += [("held", v, h) for v in (None, *HELD_VARIANTS) for h in (*HELD_HANDS, RELEASED)]
        if "enc" in sets:
            combos += [
                ("enc", DeviceVariant(f"enc{b}", encoder_bits=b), h) for b in ENC_BITS for h in (*HANDS, RELEASED)
            ]
        out += [(s, device, v, h, m) for s, v, h in combos for m in MULTIPLES]
    return out


class Trace:
    """Tick observer: the contact force magnitude at {MRF} (N), the grip's true height (m, +z of
    the base {0}) and whether the motors saturated, on every tick from ``start`` (s) on."""

    def __init__(self, start: float) -> None:
        self._start = start
        self.rows: list[tuple[float, float, float]] = []

    def on_tick(self, tick: TickRecord) -> None:
        if tick.time >= self._start:
            force = float(np.linalg.norm(tick.contact_wrench_MRF[0:3]))
            self.rows.append((force, float(tick.reading.T_0_G[2, 3]), float(tick.out.saturation_scale < 1.0)))


def profile(trace: Trace, reference: float | None, dt: float = 1e-3) -> dict[str, Any]:
    """The judged window's course: per whole second, ``[mean force (N), peak-to-peak (N), grip
    height peak-to-peak (m), mean-crossings of the force per second]`` (``seg``), and the verdict of
    press's rule (settled, grip drift within :data:`DRIFT_TOLERANCE`, no saturated tick) on the
    first and on the last :data:`SETTLE_WINDOW` alone (``first`` / ``last``, with mean and
    peak-to-peak). ``reference``: a released press's held force (N) its ripple is judged against
    (None: held, against the mean). The slave's force limit is not judged here (see ``verdict``)."""
    a = np.array(trace.rows).reshape(-1, 3)

    def part(x: np.ndarray) -> dict[str, Any]:
        f, z = x[:, 0], x[:, 1]
        n = max(1, len(z) // 10)
        mean, ptp = float(f.mean()), float(np.ptp(f))
        settled = ptp < SETTLE_RIPPLE * (reference if reference is not None else mean)
        settled &= reference is not None or mean >= SETTLE_MIN_FORCE
        still = abs(float(z[-n:].mean() - z[:n].mean())) <= DRIFT_TOLERANCE
        return {"mean": mean, "ptp": ptp, "stable": bool(settled and still and not x[:, 2].any())}

    per_s, w = round(1.0 / dt), round(SETTLE_WINDOW / dt)
    seg = []
    for i in range(0, len(a) - per_s + 1, per_s):
        f, z = a[i : i + per_s, 0], a[i : i + per_s, 1]
        crossings = int(np.count_nonzero(np.diff(np.sign(f - f.mean()))))
        seg.append([float(f.mean()), float(np.ptp(f)), float(np.ptp(z)), crossings])
    return {"seg": seg, "first": part(a[:w]), "last": part(a[-w:])}


def key(row: dict[str, Any]) -> Key:
    """The point a press row was taken at."""
    return row["set"], row["device"], row["variant"], row["hand"], row["multiple"]


def run(args: argparse.Namespace) -> None:
    overrides: dict[str, Any] = {}
    for item in args.pc:
        name, value = item.split("=", 1)
        overrides[name] = json.loads(value)
    settings = PassivitySettings(enabled=not args.plain, **overrides)
    out = Path(args.out)
    done = {key(json.loads(line)) for line in out.read_text().splitlines()} if out.exists() else set()
    todo = points(tuple(args.sets.split(",")))
    if args.points:
        wanted = {tuple(json.loads(line)) for line in Path(args.points).read_text().splitlines()}
        todo = [p for p in todo if (p[0], p[1], p[2].label if p[2] else "", p[3][0], p[4]) in wanted]
    start = time.time()
    with tempfile.TemporaryDirectory() as tmp, out.open("a") as sink:
        paths: dict[tuple[str, str], str] = {}
        for n, (s, device, variant, (hand_label, hand), multiple) in enumerate(todo):
            label = variant.label if variant else ""
            if (s, device, label, hand_label, multiple) in done:
                continue
            if variant is not None and (device, label) not in paths:
                paths[device, label] = str(write_variant(device, variant, Path(tmp)))
            path = paths[device, label] if variant else device
            held = hand or DEFAULT[1]
            bound = 2.0 * grip_damping(path, held) / 1e-3
            per_k_t = design_stiffness(1.0, device=path)
            k_t = multiple * bound / per_k_t
            seconds = POSE_SECONDS + args.window - SETTLE_WINDOW
            trace = Trace(seconds - args.window)
            held_force = FeltStiffness((release_time(seconds, HOLD_SECONDS, args.window), seconds + 1e-9))
            r = press(
                1e5,
                "pose",
                {"k_t": [k_t] * 3 + [1.0] * 3},
                released=hand is None,
                window=args.window,
                device=path,
                passivity=settings,
                hand=held,
                observers=(trace, held_force),
            )
            row = {
                "set": s,
                "device": device,
                "variant": label,
                "hand": hand_label,
                "multiple": multiple,
                "design": multiple * bound,
                "verdict": r.verdict,
                "stable": r.stable,
                "mean": r.mean_force,
                "ripple": r.ripple,
                "felt": r.felt_stiffness,
                "drift": r.grip_drift,
                "profile": profile(trace, held_force.plateau_force(0) if hand is None else None),
            }
            sink.write(json.dumps(row) + "\n")
            sink.flush()
            if n % 50 == 0:
                print(f"{n}/{len(todo)} {time.time() - start:.0f} s", flush=True)


def load(path: str) -> Rows:
    """A ``run`` output file's rows by point."""
    return {key(r): r for r in (json.loads(line) for line in Path(path).read_text().splitlines())}


def felt(row: dict[str, Any], measure: str) -> float:
    """A press row's felt stiffness (N/m) under ``measure`` (``"secant"`` or ``"capped"``, see the
    module docstring); NaN where none was measured (a released press)."""
    f = row["felt"]
    if f is None or not math.isfinite(f):
        return math.nan
    return min(f, row["design"]) if measure == "capped" else f


def judge(plain: Rows, reference: Rows, k: Key, q: dict[str, Any], measure: str) -> tuple[bool, bool]:
    """Whether PO/PC's press ``q`` at point ``k`` is worse than plain's press there (``plain``) and
    whether its wall vanished against the largest felt stiffness (``measure``) of plain's stable
    presses in ``reference`` on the same device and hand at no larger multiple."""
    refs = [
        felt(r, measure)
        for kk, r in reference.items()
        if kk[:4] == k[:4] and kk[4] <= k[4] and r["stable"] and math.isfinite(felt(r, measure))
    ]
    f = felt(q, measure)
    low = bool(refs) and math.isfinite(f) and f < 0.5 * max(refs)
    return bool(plain[k]["stable"] and not q["stable"]), q["verdict"] == "pushed" or low


def count(args: argparse.Namespace) -> None:
    plain, pc = load(args.plain), load(args.pc_rows)
    reference = load(args.reference) if args.reference else plain
    if args.select:
        picked = [k for k in sorted(pc) if k in plain and any(judge(plain, reference, k, pc[k], "secant"))]
        picked += [k for k in sorted(pc) if pc[k]["stable"] and pc[k]["ripple"] > 0.025 * pc[k]["mean"]]
        Path(args.select).write_text("".join(json.dumps(list(k)) + "\n" for k in picked[::2][:51]))
    for measure in ("secant", "capped"):
        print(f"felt: {measure}")
        for s in ("tuned", "held", "enc"):
            keys = [k for k in pc if k[0] == s and k in plain]
            if not keys:
                continue
            stable = worse = vanish = 0
            for k in keys:
                w, v = judge(plain, reference, k, pc[k], measure)
                stable += pc[k]["stable"]
                worse += w
                vanish += v
            n_plain = sum(plain[k]["stable"] for k in keys)
            print(f"  {s:6} ({len(keys)}): plain stable {n_plain}; PO/PC {stable} / {worse} / {vanish}")
    rows = sorted(pc.values(), key=lambda r: -(r["ripple"] if math.isfinite(r["ripple"]) else 1e9))
    for r in rows[: args.rows]:
        p = plain.get(key(r), {})
        print(
            f"  {r['set']} {r['device']}_{r['variant'] or 'shipped'} {r['hand']} {r['multiple']}x: "
            f"{r['verdict']} ripple {r['ripple']:.2f} N on {r['mean']:.2f} N felt {r['felt']:.0f}; "
            f"plain {p.get('verdict')} ripple {p.get('ripple', math.nan):.2f} N"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("out")
    r.add_argument("--sets", default="tuned,held,enc")
    r.add_argument("--pc", nargs="*", default=[])
    r.add_argument("--plain", action="store_true")
    r.add_argument("--window", type=float, default=0.6)
    r.add_argument("--points")
    c = sub.add_parser("count")
    c.add_argument("plain")
    c.add_argument("pc_rows")
    c.add_argument("--rows", type=int, default=10)
    c.add_argument("--reference", help="plain rows the vanish bar's reference is taken from (default PLAIN)")
    c.add_argument("--select", help="write up to 51 of PO/PC's worst points here (for an 8 s run)")
    args = parser.parse_args()
    run(args) if args.command == "run" else count(args)


if __name__ == "__main__":
    main()
