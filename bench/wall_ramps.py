"""Ramps into convex edges, corners and notches: the largest drop of the force against the push.

Each ramp pushes a one-sphere tool (r = 5 mm, k = 3000 N/m: the shipped tip and stiffness) a
fixed step per call along a straight line into a mesh until the force against the push reaches
40 N (the shipped slave limit), then pulls it back along the same line. Printed per family: the
largest drop of the force along the push below its running maximum (N, and relative to that
maximum), the ramp where it happens, and the largest force pushing the tool *further in* on the
way back. A wall that holds has 0 for both.

Families (each line through a feature point, then the same line moved sideways by ``offset``):
- ``prism<beta>``: a prism whose top edge has an interior dihedral angle beta (60, 90, 120, 150
  degrees), pushed in the plane normal to the edge at entry angles across the edge's normal cone
  (``a`` = 0 along one face's normal, 1 along the other's), and tilted along the edge;
- ``box<size>``: boxes of several sizes, an edge swept as above;
- ``corner``: a box's vertex, along the diagonal and off it;
- ``gear``: the notch and a tooth tip of tests/world/test_contact_depth.py's gear.

Usage: ``python bench/wall_ramps.py [--family NAME ...] [--speeds 0.01,0.1,1,3]``; speeds in m/s
at 1 kHz (step = speed * 1 ms).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from world.test_contact_depth import _gear as gear
from world.test_contact_depth import _prism as prism
from world_helpers import make_scene, sphere_tool

from app.world import ContactModel
from app.world.scene import ObjectSpec

K = 3000.0  # N/m
R = 0.005  # m
LIMIT = 40.0  # N
OFFSETS = (0.0, 1e-5, 1e-4, 5e-4, 2e-3)  # m, sideways from the feature point


@dataclass(frozen=True)
class Ramp:
    """One straight push: the family, a label, the mesh, a point the line passes through (m, {w})
    and its direction (unit)."""

    family: str
    label: str
    mesh: trimesh.Trimesh
    through: np.ndarray
    u: np.ndarray


def box(size: float) -> trimesh.Trimesh:
    """A bar of square section ``size`` and 12 cm long along y, its top-front edge on the y axis
    (x < 0, z < 0 inside): long enough for a push tilted 45 degrees along the edge."""
    b = trimesh.creation.box(extents=(size, 0.12, size))
    b.apply_translation((-size / 2, 0.0, -size / 2))
    return b


def _edge_sweep(family: str, mesh: trimesh.Trimesh, n1: np.ndarray, n2: np.ndarray) -> Iterator[Ramp]:
    """Lines through the edge on the y axis: in its normal plane at fractions a of the way from
    n1 to n2 (the outward normals of its faces), and tilted 30 and 45 degrees along the edge."""
    for a in np.linspace(0.0, 1.0, 9):
        m = (1 - a) * n1 + a * n2
        m /= np.linalg.norm(m)
        for tilt in (0.0, 30.0, 45.0):
            t = math.radians(tilt)
            u = -(math.cos(t) * m + math.sin(t) * np.array([0.0, 1.0, 0.0]))
            yield Ramp(family, f"a={a:.3f} tilt={tilt:.0f}", mesh, np.zeros(3), u)


def ramps(families: set[str] | None) -> Iterator[Ramp]:
    def want(f: str) -> bool:
        return families is None or any(f.startswith(x) for x in families)

    for beta in (60.0, 90.0, 120.0, 150.0):
        if want(f"prism{beta:.0f}"):
            h = math.radians(beta) / 2
            n1 = np.array([-math.cos(h), 0.0, math.sin(h)])
            n2 = np.array([math.cos(h), 0.0, math.sin(h)])
            yield from _edge_sweep(f"prism{beta:.0f}", prism(beta), n1, n2)
    for size in (0.01, 0.03, 0.1):
        if want(f"box{size * 1000:.0f}"):
            yield from _edge_sweep(f"box{size * 1000:.0f}", box(size), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]))
    if want("corner"):
        b = trimesh.creation.box(extents=(0.03, 0.03, 0.03))
        b.apply_translation((-0.015, 0.0, -0.015))
        v = np.array([0.0, -0.015, 0.0])  # the vertex at x = 0, y = -15 mm, z = 0 (outward +x, -y, +z)
        for d in ((1, -1, 1), (1, -0.5, 0.8), (1, -0.2, 0.3), (0.3, -1, 0.6), (1, -1, 0.1)):
            u = -np.array(d, dtype=float) / np.linalg.norm(d)
            yield Ramp("corner", f"d={d}", b, v, u)
    if want("gear"):
        g = gear()
        yield Ramp("gear", "notch", g, np.array([0.03, 0.0, 0.01]), np.array([-1.0, 0.0, 0.0]))
        a = 0.5 * math.pi / 12
        tip = np.array([0.036 * math.cos(a), 0.036 * math.sin(a), 0.01])
        for deg in (0.0, 20.0, 45.0):
            b = a + math.radians(deg)
            yield Ramp("gear", f"tooth {deg:.0f}", g, tip, -np.array([math.cos(b), math.sin(b), 0.0]))
        # A tooth's top corner (its tip edge meets the gear's top face), along the bisector.
        corner = np.array([0.036 * math.cos(0.35 * 2 * math.pi / 24), 0.036 * math.sin(0.35 * 2 * math.pi / 24), 0.02])
        out = np.array([math.cos(0.35 * 2 * math.pi / 24), math.sin(0.35 * 2 * math.pi / 24), 1.0])
        yield Ramp("gear", "tooth top edge", g, corner, -out / np.linalg.norm(out))


def run_ramp(model: ContactModel, through: np.ndarray, u: np.ndarray, step: float) -> tuple[np.ndarray, float]:
    """Forces against the push (N) on the way in, and the largest force along the push on the way back."""
    model.reset()
    T = np.eye(4)
    T[0:3, 3] = through - (R + 0.002) * u
    pushed = []
    for _ in range(int(0.05 / step)):
        pushed.append(-float(model.wrench(T).force_w @ u))
        if pushed[-1] >= LIMIT:
            break
        T[0:3, 3] += step * u
    back = 0.0
    for _ in range(len(pushed) - 1):
        T[0:3, 3] -= step * u
        back = max(back, float(model.wrench(T).force_w @ u))
    return np.array(pushed), back


def drop(forces: np.ndarray) -> tuple[float, float, int]:
    """Largest fall below the running maximum (N), that maximum (N), and the call it is met at."""
    peak = np.maximum.accumulate(forces)
    fall = peak - forces
    i = int(np.argmax(fall))
    return float(fall[i]), float(peak[i]), i


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", nargs="*", help="families to run (prefixes); default all")
    parser.add_argument("--speeds", default="0.1", help="comma-separated speeds, m/s at 1 kHz")
    parser.add_argument("--offsets", default=",".join(str(o) for o in OFFSETS), help="comma-separated offsets, m")
    parser.add_argument("--verbose", action="store_true", help="one line per ramp")
    args = parser.parse_args()
    speeds = [float(s) for s in args.speeds.split(",")]
    offsets = [float(s) for s in args.offsets.split(",")]
    models: dict[int, ContactModel] = {}
    rows: dict[tuple[str, float, float], tuple[float, float, str, float, int]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for ramp in ramps(set(args.family) if args.family else None):
            key = id(ramp.mesh)
            if key not in models:
                path = Path(tmp) / f"m{len(models)}.ply"
                ramp.mesh.export(path)
                scene = make_scene([ObjectSpec(name="m", mesh=str(path), stiffness=K)], sphere_tool(R))
                models[key] = ContactModel(scene)
            # Sideways: perpendicular to u, in the plane of u and the edge's normal plane's z.
            side = np.cross(ramp.u, np.array([0.0, 1.0, 0.0]))
            if np.linalg.norm(side) < 1e-9:
                side = np.cross(ramp.u, np.array([1.0, 0.0, 0.0]))
            side /= np.linalg.norm(side)
            for speed in speeds:
                for off in offsets:
                    for sign in (1.0, -1.0) if off else (1.0,):
                        f, back = run_ramp(models[key], ramp.through + sign * off * side, ramp.u, speed * 1e-3)
                        fall, peak, at = drop(f)
                        reached = f[-1] >= LIMIT
                        if args.verbose:
                            print(f"{ramp.family:10s} {ramp.label:24s} v={speed:<5g} off={sign * off:+.0e} "
                                  f"drop {fall:6.3f} N of {peak:6.2f} ({fall / max(peak, 1e-12):5.1%}) "
                                  f"at {(at * speed * 1e-3 - R - 0.002) * 1e3:+6.2f} mm "
                                  f"back {back:6.3f} N {'' if reached else 'NOT REACHED'}")  # fmt: skip
                        k = (ramp.family, speed, off)
                        # A line that misses the solid (beside a face) never reaches the limit:
                        # counted, not measured.
                        rel = fall / max(peak, 1e-12) if reached else -1.0
                        old = rows.get(k, (-1.0, 0.0, "", 0.0, 0))
                        n = old[4] + (0 if reached else 1)
                        back = back if reached else 0.0
                        if rel > old[0]:
                            rows[k] = (rel, fall, ramp.label, max(back, old[3]), n)
                        else:
                            rows[k] = (old[0], old[1], old[2], max(back, old[3]), n)
    print(
        f"{'family':10s} {'speed':>6s} {'offset':>7s} {'worst drop':>10s} {'(N)':>7s}  {'where':24s} {'back (N)':>8s} unreached"
    )
    for (fam, speed, off), (rel, fall, label, back, n) in rows.items():
        print(f"{fam:10s} {speed:6g} {off:7.0e} {rel:10.1%} {fall:7.3f}  {label:24s} {back:8.3f} {n}")


if __name__ == "__main__":
    main()
