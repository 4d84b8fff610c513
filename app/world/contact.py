"""Penalty contact between the tool's sphere set and the scene's meshes, using FCL distance.

Why this design (python-fcl 0.7.0.11, see DESIGN.md and ``tests/world/test_fcl_behaviour.py``):
FCL ``collide`` against a BVH mesh gives one contact per touched triangle (double counting on
shared edges) with unreliable depths and normals, and ``distance`` of penetrating shapes is
garbage. Its *unsigned* distance from a point to a BVH mesh is, however, exact and fast. So each
tool sphere is reduced to its centre (a zero-radius FCL sphere, the "core") and for every
(sphere, object) pair the distance d from the centre to the surface, the nearest point q and its
triangle are found. Inside/outside comes from the angle-weighted pseudonormal of the nearest
feature (face, edge or vertex; Baerentzen & Aanaes 2005), which is correct for non-convex
meshes. Penetration depth is ``r - phi`` with phi the signed distance, the normal runs from q
through the centre (outward), and there is exactly one contact per pair.

Where the distance comes from: FCL's BVH query answers a pair the first time, and whenever its
centre has left the pair's cache; each answer also gathers the pair's candidate triangles (every
triangle within ``d + 2 R`` of the centre, through a grid), and while the centre stays within R
of there the exact nearest triangle is among them, so a compiled scan of a few of them answers
instead (:mod:`app.world.contact_kernel`). In steady contact a tick makes no FCL query at all.

Pop-through: each pair remembers its last contact plane (point q, outward normal n). If a new
query's normal opposes the remembered one while the centre is behind the remembered plane, the
centre has crossed the middle of a thin part, so the remembered plane keeps giving the depth
(pushing a 1 mm plate 10 mm never flips the force). The memory is released when the depth along
it reaches 0. (A flip with the centre still in front of the plane is a real new contact, e.g.
the opposite wall of a hole.)

Culling, exact (no margin needed): the unsigned distance is 1-Lipschitz in the centre position,
so a pair found at distance d > r cannot touch until its centre has moved ``d - r``. Per object,
the pose at the last per-sphere check is kept with the smallest remaining slack; while every
sphere centre provably moved less than that (tool translation + rotation times the tool's
radius), only the spheres in contact ("hot") are evaluated, so a tick in steady contact costs
one cached scan per contact plus a few scalar operations. Objects whose bounding box is out of
reach of the tool's bounding sphere are skipped, and that test is itself redone only when the
tool has moved by the distance to the nearest far box.

Any FCL result that is non-finite or inconsistent (e.g. from a NaN pose) makes the whole result
invalid with a zero wrench; it never becomes a wrench.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TypeVar

import fcl
import numpy as np

from app.errors import ContactQueryError
from app.spatial import Array, IntArray, invert_pose
from app.world import contact_kernel as ck
from app.world.scene import Scene

ArrayT = TypeVar("ArrayT", Array, IntArray)

# Cached candidate triangles per pair, at most (more: the pair has no cache and FCL answers it).
_CACHE_MAX = 2048
_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
_ERRORS = {
    ck.ERR_POSE: "non-finite tool pose",
    ck.ERR_TWIST: "non-finite tool twist",
    ck.ERR_WRENCH: "non-finite contact wrench",
}


def _frozen(a: ArrayT) -> ArrayT:
    a.flags.writeable = False
    return a


# The empty per-contact arrays of a result without contacts, shared (read-only): building them
# anew was a good part of the cost of a free-space evaluation.
_NO_POINTS = _frozen(np.zeros((0, 3)))
_NO_DEPTHS = _frozen(np.zeros(0))
_NO_IDS = _frozen(np.zeros(0, dtype=np.int64))


@dataclass(slots=True)
class ContactResult:
    """The contact state of the tool at one pose (treat as read-only).

    Not frozen: it is built every servo substep, and a frozen dataclass's ``__init__`` cost
    several microseconds.

    Attributes:
        valid: False when a query failed or gave a non-finite result; the wrenches are then 0.
        wrench_S: Contact wrench ``[f; m]`` (N, N m) on the tool at the {S} origin in {S}, (6,).
        wrench_MRF: The same wrench at the {MRF} origin in {MRF} (Eq 6), (6,).
        force_w: Total contact force on the tool in {w} (N), (3,).
        points_w: Contact points on the object surfaces in {w} (m), (k, 3).
        normals_w: Outward object normals at those points in {w} (unit), (k, 3): the direction
            of the normal force on the tool.
        depths: Penetration depths (m), (k,).
        sphere_ids: Index of the tool sphere of each contact, (k,).
        object_ids: Index (into ``scene.objects``) of the object of each contact, (k,).
        queries: Number of (sphere, object) distance evaluations (culling diagnostics).
        fcl_queries: How many of them FCL answered (the rest scanned a pair's cached triangles).
        error: Why the result is invalid, or ``None``.
    """

    valid: bool
    wrench_S: Array
    wrench_MRF: Array
    force_w: Array
    points_w: Array = field(default_factory=lambda: _NO_POINTS)
    normals_w: Array = field(default_factory=lambda: _NO_POINTS)
    depths: Array = field(default_factory=lambda: _NO_DEPTHS)
    sphere_ids: IntArray = field(default_factory=lambda: _NO_IDS)
    object_ids: IntArray = field(default_factory=lambda: _NO_IDS)
    queries: int = 0
    fcl_queries: int = 0
    error: str | None = None

    @property
    def count(self) -> int:
        """Number of (sphere, object) pairs in contact."""
        return len(self.depths)


class ContactModel:
    """Contact wrench of the scene's tool against its objects, with per-pair memory.

    Stateful (pop-through memory, culling state, candidate caches): use one instance per
    simulated tool and call :meth:`reset` when the tool jumps. :func:`contact_wrench` is the
    stateless convenience.

    Args:
        scene: The loaded scene.
        margin: Extra distance (m) kept in the culling tests (0 is exact; the default is the
            scene's ``margin``).
    """

    def __init__(self, scene: Scene, margin: float | None = None) -> None:
        self.scene = scene
        tool = scene.tool
        self._geo = geo = scene.packed
        self._objects = scene.objects
        n, m = len(tool.radii), len(scene.objects)
        self._n = n
        self._centers_T = np.ascontiguousarray(tool.centers_T, dtype=float)
        self._radii = np.ascontiguousarray(tool.radii, dtype=float)
        self._T_MRF_T = invert_pose(tool.T_T_MRF)
        # Bounding sphere of the tool: centre c0 in {T}, radius of the centres and of the spheres.
        c0_T = tool.centers_T.mean(axis=0)
        spread = np.linalg.norm(tool.centers_T - c0_T, axis=1)
        margin = scene.spec.margin if margin is None else margin
        T_MRF_S = tool.T_MRF_S
        self._tool_p = np.zeros(ck.TP_COLS)
        self._tool_p[ck.TP_C0 : ck.TP_C0 + 3] = c0_T
        self._tool_p[ck.TP_RHO] = spread.max()
        self._tool_p[ck.TP_REACH] = np.max(spread + tool.radii) + margin
        self._tool_p[ck.TP_MARGIN] = margin
        self._tool_p[ck.TP_P_MRF_S : ck.TP_P_MRF_S + 3] = T_MRF_S[0:3, 3]
        self._tool_p[ck.TP_R_MRF_S : ck.TP_R_MRF_S + 9] = T_MRF_S[0:3, 0:3].ravel()
        self._obj_p = np.array(
            [(o.stiffness, o.damping, o.friction, *o.collision.lo, *o.collision.hi) for o in scene.objects]
        ).reshape(m, ck.OP_COLS)
        self._pair_f = np.zeros((m * n, ck.PF_COLS))
        self._pair_i = np.zeros((m * n, ck.PI_COLS), dtype=np.int64)
        # Untouched rows of np.empty cost no memory: only pairs that gather ever touch theirs.
        self._pool = np.empty((m * n, _CACHE_MAX), dtype=np.int64)
        self._obj_f = np.zeros((m, ck.OF_COLS))
        self._near = np.zeros(m, dtype=np.int64)
        self._glob_f = np.zeros(ck.GF_COLS)
        self._scratch = np.zeros((m * n, 10))
        self._todo = np.zeros(m * n, dtype=np.int64)
        self._misses = np.zeros(m * n, dtype=np.int64)
        self._out_w = np.zeros(15)
        self._out_c = np.zeros((m * n, ck.OC_COLS))
        self._out_ci = np.zeros((m * n, 2), dtype=np.int64)
        self._grid = (
            geo.tri_boxes,
            geo.grid_f,
            geo.grid_i,
            geo.grid_keys,
            geo.grid_start,
            geo.grid_tris,
            np.zeros(len(geo.faces), dtype=np.int64),
            np.zeros(1, dtype=np.int64),
        )
        self._no_twist = np.zeros(6)
        # The kernel's arguments after the pose and twist, bound once (see ck.contact_step).
        self._args = (
            self._centers_T,
            self._radii,
            self._T_MRF_T,
            self._tool_p,
            self._obj_p,
            geo.vertices,
            geo.faces,
            geo.face_normals,
            geo.face_edges,
            geo.edge_pn,
            geo.vertex_pn,
            self._pair_f,
            self._pair_i,
            self._pool,
            self._grid,
            self._obj_f,
            self._near,
            self._glob_f,
            self._scratch,
            self._todo,
            self._misses,
            self._out_w,
            self._out_c,
            self._out_ci,
        )
        self._core = fcl.CollisionObject(fcl.Sphere(0.0), fcl.Transform())
        self._request = fcl.DistanceRequest(enable_nearest_points=True)
        self.reset()

    def reset(self) -> None:
        """Forget contact memory, culling state and caches (e.g. after the tool was teleported)."""
        pf, pi = self._pair_f, self._pair_i
        pf[:, ck.PF_LAST : ck.PF_LAST + 3] = np.inf
        pf[:, ck.PF_SLACK] = -1.0
        pi[:, ck.PI_MEM] = 0
        pi[:, ck.PI_CACHE_N] = -1
        pi[:, ck.PI_FCL_TRI] = -1
        pi[:, ck.PI_HOT] = 0
        pi[:, ck.PI_NEAREST] = -1
        self._obj_f[:, ck.OF_SLACK] = -1.0
        self._glob_f[ck.GF_NEAR_SLACK] = -1.0

    @property
    def remembered(self) -> int:
        """Number of (sphere, object) pairs holding a pop-through memory plane."""
        return int(self._pair_i[:, ck.PI_MEM].sum())

    def wrench(self, T_w_MRF: Array, V_w_MRF: Array | None = None) -> ContactResult:
        """Contact wrench of the tool with {MRF} at ``T_w_MRF`` (4, 4).

        Args:
            T_w_MRF: Pose of {MRF} in {w}.
            V_w_MRF: Optional twist ``[v; w]`` (m/s, rad/s) of {MRF} in {w} coordinates (v of the
                {MRF} origin), shape (6,). Needed for contact damping and friction; without it
                the wrench is the elastic part only.

        Returns:
            A :class:`ContactResult`; ``valid`` is False (zero wrench) if any query failed.
        """
        fcl_queries = 0
        T_w_MRF = np.asarray(T_w_MRF, dtype=float)
        if V_w_MRF is not None:
            V_w_MRF = np.asarray(V_w_MRF, dtype=float)
        try:
            while True:
                code, queries, n_miss = self._step(T_w_MRF, V_w_MRF)
                if n_miss == 0:
                    break
                for k in self._misses[:n_miss].tolist():
                    self._answer(k)
                fcl_queries += n_miss
            if code < 0:
                raise ContactQueryError(_ERRORS[code])
        except ContactQueryError as exc:
            self.reset()
            return ContactResult(False, np.zeros(6), np.zeros(6), np.zeros(3), error=str(exc))
        # One copy per output block; the result's fields are views of it.
        w = self._out_w.copy()
        if code == 0:
            # Every field positional: the default factories cost microseconds on this path.
            return ContactResult(
                True,
                w[0:6],
                w[6:12],
                w[12:15],
                _NO_POINTS,
                _NO_POINTS,
                _NO_DEPTHS,
                _NO_IDS,
                _NO_IDS,
                queries,
                fcl_queries,
                None,
            )
        c = self._out_c[:code].copy()
        ids = self._out_ci[:code].copy()
        return ContactResult(
            True,
            w[0:6],
            w[6:12],
            w[12:15],
            c[:, ck.OC_P : ck.OC_P + 3],
            c[:, ck.OC_N : ck.OC_N + 3],
            c[:, ck.OC_DEPTH],
            ids[:, 0],
            ids[:, 1],
            queries,
            fcl_queries,
        )

    def _step(self, T_w_MRF: Array, V_w_MRF: Array | None) -> tuple[int, int, int]:
        if V_w_MRF is None:
            return ck.contact_step(T_w_MRF, self._no_twist, False, *self._args)
        return ck.contact_step(T_w_MRF, V_w_MRF, True, *self._args)

    def _answer(self, k: int) -> None:
        """Answer pair k's miss with FCL at its centre and gather its candidate triangles there."""
        j = k // self._n
        c = self._scratch[k, 0:3].copy()
        d, tri, q = self._fcl_distance(j, c)
        if d == 0.0:
            # On the surface FCL gives no point: query just off it (along the reported face's
            # normal, the remembered normal, then the axes: one of them leaves the surface).
            hint = self._pair_f[k, ck.PF_MEM + 3 : ck.PF_MEM + 6] if self._pair_i[k, ck.PI_MEM] else (0.0, 0.0, 1.0)
            for direction in (self._geo.face_normals[tri], hint, *_AXES):
                d2, tri2, q2 = self._fcl_distance(j, c + ck.NUDGE * np.asarray(direction))
                if d2 > 0.0:
                    tri, q = tri2, q2
                    break
            else:
                raise ContactQueryError("FCL distance degenerate at the surface in every direction")
        f = self._pair_f[k]
        f[ck.PF_FCL_C : ck.PF_FCL_C + 3] = c
        f[ck.PF_FCL_D] = d
        f[ck.PF_FCL_Q : ck.PF_FCL_Q + 3] = q
        self._pair_i[k, ck.PI_FCL_TRI] = tri
        ck.refill(
            k,
            j,
            float(c[0]),
            float(c[1]),
            float(c[2]),
            d,
            max(ck.CACHE_MIN, ck.CACHE_FRAC * d),
            self._geo.vertices,
            self._geo.faces,
            self._pair_f,
            self._pair_i,
            self._pool,
            self._grid,
        )

    def _fcl_distance(self, j: int, c: Array) -> tuple[float, int, Array]:
        """FCL unsigned distance from point c (3,) to object j: ``(d, global triangle, q (3,))``.

        d is 0 (and q meaningless) within :data:`~app.world.contact_kernel.TOUCH` of the surface.
        """
        mesh = self._objects[j].collision
        self._core.setTranslation(c)  # it needs an array (it calls astype)
        res = fcl.DistanceResult()
        d = fcl.distance(mesh.fcl_object, self._core, self._request, res)
        tri = res.b1
        if not (math.isfinite(d) and d >= 0.0 and 0 <= tri < mesh.n_faces):
            raise ContactQueryError(f"FCL distance returned d={d!r}, triangle {tri!r}")
        tri += int(self._geo.face0[j])
        if d < ck.TOUCH:
            return 0.0, tri, c  # nearest points are not filled in
        q = np.array(res.nearest_points[0], dtype=float)
        dc = float(np.linalg.norm(c - q))
        if not abs(dc - d) <= 1e-9 + 1e-6 * d:
            raise ContactQueryError(f"FCL nearest point inconsistent with its distance ({dc!r} vs {d!r})")
        return d, tri, q


def contact_wrench(scene: Scene, T_w_MRF: Array, V_w_MRF: Array | None = None) -> ContactResult:
    """Stateless contact wrench of ``scene``'s tool at ``T_w_MRF`` (4, 4); see :meth:`ContactModel.wrench`.

    Builds a fresh :class:`ContactModel` (so no pop-through memory) on each call; for a sequence
    of poses keep one model instead.
    """
    return ContactModel(scene).wrench(T_w_MRF, V_w_MRF)
