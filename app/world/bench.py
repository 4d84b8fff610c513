"""Contact-wrench timing: median and p99 per case, as a text table.

Cases: the default tool of each shipped scene held in contact (``static``: the same pose every
call; ``moving``: a random walk of 20 um / 0.01 deg steps, as a hand moves at 1 kHz), and stroked
at 1 m/s (``1 m/s``: moving is 1 mm a call back and forth over 20 mm in contact); the probe
tool pressed into icospheres of about 1k, 10k, 100k and 1M triangles; the probe scene with 1, 10
and 100 objects (all but the surface far away). The slave's step is timed by ``frhc bench arm``.

For each shipped scene MuJoCo's own collision runs beside ours on the same moving path: the
tool's spheres as sphere geoms on a free body, the objects as mesh geoms (MuJoCo collides with
their convex hulls, so its answer is wrong inside holes and bowls), timed over
``mj_kinematics`` + ``mj_collision``.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import trimesh

from app.spatial import Array, invert_pose, make_pose, zyx_to_matrix
from app.world.contact import ContactModel
from app.world.scene import ObjectSpec, Pose, Scene, build_scene, load_scene

# Pose of {MRF} in contact for each shipped scene (m, Z-Y-X rad), see scenes/*.toml.
CONTACT_POSES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "probe": ((0.0, 0.0, 0.004), (0.0, 0.0, 0.0)),  # tip 1 mm into the surface
    "peg_in_hole": ((0.0007, 0.0, -0.01), (0.0, 0.0, 0.0)),  # pegs 15 mm into the holes, 0.2 mm into the walls
    "bowl": ((0.02, 0.0, -0.0535), (0.0, 0.0, 0.0)),  # tip 2 mm into the cavity wall
    "large_mesh": ((0.03, 0.02, 0.002), (0.0, 0.0, 0.0)),  # tip on the terrain's bumps
}
# The 1 m/s strokes: {MRF} pose in contact and the stroke's direction, back and forth +-10 mm at
# 1 mm per call (a hand's speed at 1 kHz).
STROKES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "probe": ((0.0, 0.0, 0.004), (1.0, 0.0, 0.0)),  # tip 1 mm into the surface
    "peg_in_hole": ((0.015, 0.0, -0.001), (0.0, 1.0, 0.0)),  # both peg tips 1 mm into the top face
    "bowl": ((0.0, 0.0, -0.056), (1.0, 0.0, 0.0)),  # tip 1 mm into the cavity's floor, across it
    "large_mesh": ((0.03, 0.02, 0.002), (1.0, 0.0, 0.0)),  # across the terrain's bumps
}
STROKE_STEP = 1e-3  # m per call


def _time(fn: Callable[[int], object], n: int) -> tuple[float, float]:
    """Median and p99 (us) of ``fn(k)`` over ``n`` calls, after a warm-up."""
    for k in range(min(50, n)):
        fn(k)
    t = np.empty(n)
    clock = time.perf_counter_ns
    for k in range(n):
        t0 = clock()
        fn(k)
        t[k] = clock() - t0
    return float(np.median(t)) / 1e3, float(np.percentile(t, 99)) / 1e3


def _walk(T0: Array, n: int, seed: int = 0) -> list[Array]:
    """A random walk of ``n`` poses around ``T0``: 20 um and 0.01 deg per step, bounded to +-0.2 mm."""
    rng = np.random.default_rng(seed)
    p = np.zeros(3)
    a = np.zeros(3)
    poses = []
    for _ in range(n):
        p = np.clip(p + rng.normal(0.0, 2e-5, 3), -2e-4, 2e-4)
        a = np.clip(a + rng.normal(0.0, 1.7e-4, 3), -3e-3, 3e-3)
        poses.append(T0 @ make_pose(zyx_to_matrix(*a), p))
    return poses


def _stroke(T0: Array, direction: tuple[float, float, float], n: int) -> list[Array]:
    """``n`` poses of a stroke back and forth along ``direction`` through ``T0``: +-10 mm, 1 mm a call."""
    period = 40  # calls per round trip of 2 x 20 mm
    u = np.array(direction)
    poses = []
    for k in range(n):
        phase = k % period
        s = STROKE_STEP * (phase if phase <= period // 2 else period - phase) - 0.01
        T = T0.copy()
        T[0:3, 3] += s * u
        poses.append(T)
    return poses


def _contact_row(
    label: str, scene: Scene, T: Array, n: int, mujoco: bool = False, stroke: tuple[float, float, float] | None = None
) -> list[str]:
    model = ContactModel(scene)
    res = model.wrench(T)
    if not res.valid or res.count == 0:
        raise RuntimeError(f"benchmark pose for {label} is not in contact")
    static = _time(lambda _k: model.wrench(T), n)
    poses = _walk(T, n + 50) if stroke is None else _stroke(T, stroke, n + 50)
    model.reset()
    tris = sum(len(o.mesh.faces) for o in scene.objects)
    row = [label, f"{tris}", f"{len(scene.tool.radii)}", f"{res.count}", *(f"{v:.1f}" for v in static)]
    if not mujoco:
        return [*row, *(f"{v:.1f}" for v in _time(lambda k: model.wrench(poses[k]), n)), "", "", ""]
    step, contacts = _mujoco_collision(scene, poses)
    # Alternate the two on the same path, call by call: a burst of load on the machine then
    # slows both alike instead of one of them.
    ours, theirs = _time_pair(lambda k: model.wrench(poses[k]), step, n)
    return [*row, *(f"{v:.1f}" for v in ours), f"{contacts}", *(f"{v:.1f}" for v in theirs)]


def _time_pair(
    fa: Callable[[int], object], fb: Callable[[int], object], n: int
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Median and p99 (us) of ``fa(k)`` and of ``fb(k)``, called alternately, after a warm-up."""
    for k in range(min(50, n)):
        fa(k)
        fb(k)
    t = np.empty((2, n))
    clock = time.perf_counter_ns
    for k in range(n):
        t0 = clock()
        fa(k)
        t1 = clock()
        fb(k)
        t[0, k], t[1, k] = t1 - t0, clock() - t1
    med, p99 = np.median(t, axis=1) / 1e3, np.percentile(t, 99, axis=1) / 1e3
    return (float(med[0]), float(p99[0])), (float(med[1]), float(p99[1]))


def _mujoco_collision(scene: Scene, poses: list[Array]) -> tuple[Callable[[int], object], int]:
    """MuJoCo's collision of the scene's tool spheres (a free body) with its meshes (their convex
    hulls): a function running ``mj_kinematics`` + ``mj_collision`` at ``poses[k]``, and the
    number of contacts MuJoCo finds at the first pose."""
    import tempfile

    import mujoco

    tool = scene.tool
    T_MRF_T = invert_pose(tool.T_T_MRF)
    with tempfile.TemporaryDirectory() as tmp:
        assets, geoms = [], []
        for j, o in enumerate(scene.objects):
            path = f"{tmp}/m{j}.stl"
            o.mesh.export(path)
            assets.append(f'<mesh name="m{j}" file="{path}"/>')
            geoms.append(f'<geom type="mesh" mesh="m{j}"/>')
        spheres = "".join(
            f'<geom type="sphere" size="{float(r)!r}" pos="{" ".join(repr(float(x)) for x in c)}"/>'
            for c, r in zip(tool.centers_T, tool.radii, strict=True)
        )
        xml = (
            f"<mujoco><asset>{''.join(assets)}</asset><worldbody>{''.join(geoms)}"
            f'<body name="tool"><freejoint/>{spheres}</body></worldbody></mujoco>'
        )
        mj_model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(mj_model)
    qpos = np.zeros((len(poses), 7))
    for k, T in enumerate(poses):
        T_w_T = T @ T_MRF_T
        qpos[k, 0:3] = T_w_T[0:3, 3]
        mujoco.mju_mat2Quat(qpos[k, 3:7], T_w_T[0:3, 0:3].ravel())

    def step(k: int) -> None:
        data.qpos[:] = qpos[k]
        mujoco.mj_kinematics(mj_model, data)
        mujoco.mj_collision(mj_model, data)

    step(0)
    return step, int(data.ncon)


def _probe_scene(objects: list[ObjectSpec]) -> Scene:
    base = load_scene("probe").spec
    return build_scene(type(base)(name="bench", tool=base.tool, objects=tuple(objects), slave=base.slave))


def _icosphere_scene(subdivisions: int, path_dir: str) -> Scene:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.1)
    mesh.apply_translation((0.0, 0.0, -0.1))  # top at z = 0, like the probe surface
    path = f"{path_dir}/ico{subdivisions}.ply"
    mesh.export(path)
    return _probe_scene([ObjectSpec(name="ico", mesh=path, stiffness=3000.0)])


def run(quick: bool = False) -> str:
    """Run every case; return the table. ``quick`` uses fewer calls and skips the 1M mesh."""
    import tempfile

    n = 500 if quick else 3000
    header = ["case", "triangles", "spheres", "contacts", "static med", "static p99", "moving med", "moving p99"]
    header += ["mujoco contacts", "mujoco moving med", "mujoco moving p99"]
    rows: list[list[str]] = []
    for name, (p, a) in CONTACT_POSES.items():
        T = make_pose(zyx_to_matrix(*a), np.array(p))
        rows.append(_contact_row(f"scene {name}", load_scene(name), T, n, mujoco=True))
    for name, (p, u) in STROKES.items():
        T = make_pose(np.eye(3), np.array(p))
        rows.append(_contact_row(f"scene {name} 1 m/s", load_scene(name), T, n, mujoco=True, stroke=u))
    T_probe = make_pose(np.eye(3), np.array(CONTACT_POSES["probe"][0]))
    with tempfile.TemporaryDirectory() as tmp:
        for sub in (3, 5, 6) if quick else (3, 5, 6, 8):
            rows.append(_contact_row(f"icosphere sub {sub}", _icosphere_scene(sub, tmp), T_probe, n))
    surface = load_scene("probe").spec.objects[0]
    for count in (1, 10, 100):
        far = [
            ObjectSpec(
                name=f"far{i}",
                box=(0.05, 0.05, 0.05),
                pose=Pose((0.5 + 0.1 * (i % 10), 0.1 * (i // 10), 0.0)),
                stiffness=3000.0,
            )
            for i in range(count - 1)
        ]
        rows.append(_contact_row(f"{count} objects", _probe_scene([surface, *far]), T_probe, n))
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(lines) + "\n" + _FOOTNOTE


# What each timing counts, printed under the table: the two sides do not do the same work.
_FOOTNOTE = (
    "(times in microseconds per call, median and 99th percentile.\n"
    " ours: ContactModel.wrench: input checks, culling, every local minimum of every sphere within\n"
    " reach, forces and the wrench at {S} and {MRF}, and the result object.\n"
    " mujoco: write qpos, mj_kinematics + mj_collision: contact points only (no forces), against the\n"
    " meshes' convex hulls. Both on the same spheres and the same moving path, called alternately.)"
)
