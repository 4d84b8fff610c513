"""Penalty contact between the tool's sphere set and the scene's meshes, using FCL distance.

Why this design (python-fcl 0.7.0.11, see DESIGN.md and ``tests/world/test_fcl_behaviour.py``):
FCL ``collide`` against a BVH mesh gives one contact per touched triangle (double counting on
shared edges) with unreliable depths and normals, and ``distance`` of penetrating shapes is
garbage. Its *unsigned* distance from a point to a BVH mesh is, however, exact and fast. So each
tool sphere is reduced to its centre (a zero-radius FCL sphere, the "core") and for every
(sphere, object) pair one ``distance`` query gives the distance d from the centre to the
surface, the nearest point q and its triangle. Inside/outside comes from the angle-weighted
pseudonormal of the nearest feature (face, edge or vertex; Baerentzen & Aanaes 2005), which is
correct for non-convex meshes. Penetration depth is ``r - phi`` with phi the signed distance,
the normal runs from q through the centre (outward), and there is exactly one contact per pair.

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
radius), only the spheres in contact ("hot") are queried, so a tick in steady contact costs one
query per contact plus a few scalar operations. Objects whose bounding box is out of reach of
the tool's bounding sphere are skipped, and that test is itself redone only when the tool has
moved by the distance to the nearest far box.

Any FCL result that is non-finite or inconsistent (e.g. from a NaN pose) makes the whole result
invalid with a zero wrench; it never becomes a wrench.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import fcl
import numpy as np

from app.errors import ContactQueryError
from app.spatial import Array, IntArray, invert_pose
from app.world.collision import CollisionMesh
from app.world.kernel import nearest_triangle, triangles_within
from app.world.scene import Scene

# Below this distance (m) the nearest-point direction is numerically meaningless and FCL's
# zero-radius query may report uninitialised memory: the centre is treated as on the surface.
_TOUCH = 1e-9
# Offset (m) of the re-query used when the centre lies exactly on the surface.
_NUDGE = 1e-6
# Tangential speed (m/s) below which friction is viscous (regularised Coulomb).
_V_SLIP = 1e-3
_FAR = 1e30  # 'never queried' centre position (m)
_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
# Cached candidate triangles (see ContactModel._distance): only for meshes this small (the filter
# is a pass over every triangle), at most this many candidates, valid while the centre moves less
# than max(_CACHE_MIN, _CACHE_FRAC * d) from where they were gathered.
_CACHE_FACES = 20000
_CACHE_MAX = 2048
_CACHE_MIN = 1e-4
_CACHE_FRAC = 0.02


def _frozen(a: Array) -> Array:
    a.flags.writeable = False
    return a


# The empty per-contact arrays of a result without contacts, shared (read-only): building them
# anew was a good part of the cost of a free-space evaluation.
_NO_POINTS = _frozen(np.zeros((0, 3)))
_NO_DEPTHS = _frozen(np.zeros(0))
_NO_IDS = _frozen(np.zeros(0, dtype=int))


@dataclass(frozen=True)
class ContactResult:
    """The contact state of the tool at one pose.

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
        queries: Number of FCL distance queries this evaluation made (culling diagnostics).
        error: Why the result is invalid, or ``None``.
    """

    valid: bool
    wrench_S: Array
    wrench_MRF: Array
    force_w: Array
    points_w: Array = field(default_factory=lambda: _NO_POINTS)
    normals_w: Array = field(default_factory=lambda: _NO_POINTS)
    depths: Array = field(default_factory=lambda: _NO_DEPTHS)
    sphere_ids: Array = field(default_factory=lambda: _NO_IDS)
    object_ids: Array = field(default_factory=lambda: _NO_IDS)
    queries: int = 0
    error: str | None = None

    @property
    def count(self) -> int:
        """Number of (sphere, object) pairs in contact."""
        return len(self.depths)


class ContactModel:
    """Contact wrench of the scene's tool against its objects, with per-pair memory.

    Stateful (pop-through memory, culling caches): use one instance per simulated tool and call
    :meth:`reset` when the tool jumps. :func:`contact_wrench` is the stateless convenience.

    Args:
        scene: The loaded scene.
        margin: Extra distance (m) kept in the culling tests (0 is exact; the default is the
            scene's ``margin``).
    """

    def __init__(self, scene: Scene, margin: float | None = None) -> None:
        self.scene = scene
        tool = scene.tool
        self._margin = scene.spec.margin if margin is None else margin
        self._centers_T = tool.centers_T
        self._centers_T_list = [tuple(c) for c in tool.centers_T.tolist()]
        self._radii = tool.radii.tolist()
        self._T_MRF_T = invert_pose(tool.T_T_MRF)
        self._T_MRF_S = tool.T_MRF_S
        self._R_MRF_S = self._T_MRF_S[0:3, 0:3].tolist()
        self._p_MRF_S = self._T_MRF_S[0:3, 3].tolist()
        # Bounding sphere of the tool: centre c0 in {T}, radius of the centres and of the spheres.
        self._c0_T = tool.centers_T.mean(axis=0)
        spread = np.linalg.norm(tool.centers_T - self._c0_T, axis=1)
        self._rho = float(spread.max())
        self._reach = float(np.max(spread + tool.radii)) + self._margin
        self._objects = list(scene.objects)
        self._meshes = [o.collision for o in scene.objects]
        self._lo = np.array([c.lo for c in self._meshes]).reshape(-1, 3)
        self._hi = np.array([c.hi for c in self._meshes]).reshape(-1, 3)
        n, m = len(self._radii), len(self._objects)
        # Per pair: centre at the last query and how far it may move before the next is needed.
        self._last_c = np.full((m, n, 3), _FAR)
        self._slack = np.full((m, n), -1.0)
        # Per object: a base tool pose (c0, R) and the distance any sphere centre may move from it
        # before the per-sphere test must run again; meanwhile only its "hot" spheres are queried.
        self._base_c0 = [(0.0, 0.0, 0.0)] * m
        self._base_R: list[list[float]] = [[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]] * m
        self._obj_slack = [-1.0] * m
        self._hot: list[list[int]] = [[] for _ in range(m)]
        # Objects within reach of the tool's bounding sphere, valid while c0 moves < _near_slack.
        self._near: list[int] = []
        self._near_c0 = (0.0, 0.0, 0.0)
        self._near_slack = -1.0
        self._memory: dict[int, tuple[float, float, float, float, float, float]] = {}
        # Per pair: (centre, radius of validity, candidate triangles or None) of the nearest-triangle cache.
        self._cache: dict[int, tuple[float, float, float, float, IntArray | None]] = {}
        self._core = fcl.CollisionObject(fcl.Sphere(0.0), fcl.Transform())
        self._request = fcl.DistanceRequest(enable_nearest_points=True)

    def reset(self) -> None:
        """Forget contact memory and culling caches (e.g. after the tool was teleported)."""
        self._last_c.fill(_FAR)
        self._slack.fill(-1.0)
        self._obj_slack = [-1.0] * len(self._objects)
        self._near_slack = -1.0
        self._memory.clear()
        self._cache.clear()

    def _distance(self, obj: CollisionMesh, c: Array, key: int = -1) -> tuple[float, int, float, float, float]:
        """Unsigned distance from point c (3,) to the mesh: (d, triangle, q) with q in {w}.

        FCL's BVH query, or, for pair ``key``, an exact scan of cached candidate triangles: FCL
        gave distance d0 at centre c0, so while |c - c0| <= R the nearest triangle (at most
        d0 + R from c) is within d0 + 2R of c0, and the cache holds every triangle whose bounding
        ball reaches that far. Inside a hole every wall triangle is nearly equidistant from the
        centre, so FCL cannot prune and the scan of a few hundred triangles is several times faster.
        """
        cached = self._cache.get(key) if key >= 0 else None
        if cached is not None:
            x0, y0, z0, R, cand = cached
            cx, cy, cz = c.tolist()
            if (cx - x0) ** 2 + (cy - y0) ** 2 + (cz - z0) ** 2 <= R * R:
                if cand is None:
                    return self._fcl_distance(obj, c)
                d, tri, qx, qy, qz = nearest_triangle(obj.vertices, obj.faces, cand, cx, cy, cz)
                if not (math.isfinite(d) and 0 <= tri < obj.n_faces):
                    raise ContactQueryError(f"cached distance returned d={d!r}, triangle {tri!r}")
                if d < _TOUCH:
                    return 0.0, tri, math.nan, math.nan, math.nan
                return d, tri, qx, qy, qz
        out = self._fcl_distance(obj, c)
        if key >= 0 and obj.n_faces <= _CACHE_FACES:
            d = out[0]
            R = max(_CACHE_MIN, _CACHE_FRAC * d)
            cx, cy, cz = c.tolist()
            cand = triangles_within(
                obj.vertices, obj.faces, obj.tri_centers, obj.tri_radii, cx, cy, cz, d + 2.0 * R + 1e-9 + 1e-6 * d
            )
            self._cache[key] = (cx, cy, cz, R, cand if len(cand) <= _CACHE_MAX else None)
        return out

    def _fcl_distance(self, obj: CollisionMesh, c: Array) -> tuple[float, int, float, float, float]:
        """FCL unsigned distance from point c (3,) to the mesh: (d, triangle, q) with q in {w}."""
        self._core.setTranslation(c)  # it needs an array (it calls astype)
        res = fcl.DistanceResult()
        d = fcl.distance(obj.fcl_object, self._core, self._request, res)
        tri = res.b1
        if not (math.isfinite(d) and d >= 0.0 and 0 <= tri < obj.n_faces):
            raise ContactQueryError(f"FCL distance returned d={d!r}, triangle {tri!r}")
        if d < _TOUCH:
            return 0.0, tri, math.nan, math.nan, math.nan  # nearest points are not filled in
        qx, qy, qz = res.nearest_points[0].tolist()
        cx, cy, cz = c.tolist()
        dc = math.sqrt((cx - qx) ** 2 + (cy - qy) ** 2 + (cz - qz) ** 2)
        if not abs(dc - d) <= 1e-9 + 1e-6 * d:
            raise ContactQueryError(f"FCL nearest point inconsistent with its distance ({dc!r} vs {d!r})")
        return d, tri, qx, qy, qz

    def _signed(
        self, obj: CollisionMesh, c: Array, hint: tuple[float, float, float], key: int = -1
    ) -> tuple[float, float, float, float, float, float, float]:
        """Signed distance phi (> 0 outside), nearest point q and outward normal n at centre c."""
        d, tri, qx, qy, qz = self._distance(obj, c, key)
        cx, cy, cz = c.tolist()
        if d == 0.0:
            # On the surface: FCL gives no point, so query just off it (along the reported face's
            # normal, the remembered normal, then the axes: one of them leaves the surface).
            for direction in (obj.face_normals[tri], hint, *_AXES):
                d2, tri2, qx, qy, qz = self._distance(obj, c + _NUDGE * np.asarray(direction))
                if d2 > 0.0:
                    nx, ny, nz = obj.pseudonormal(tri2, qx, qy, qz)
                    return 0.0, qx, qy, qz, nx, ny, nz
            raise ContactQueryError("FCL distance degenerate at the surface in every direction")
        ux, uy, uz = (cx - qx) / d, (cy - qy) / d, (cz - qz) / d
        fx, fy, fz = obj.face_normals[tri].tolist()
        s = ux * fx + uy * fy + uz * fz
        if abs(s) < 0.9999:
            # q is on an edge or a vertex: only the feature's pseudonormal gives the right side.
            fx, fy, fz = obj.pseudonormal(tri, qx, qy, qz)
            s = ux * fx + uy * fy + uz * fz
        if s >= 0.0:
            return d, qx, qy, qz, ux, uy, uz
        return -d, qx, qy, qz, -ux, -uy, -uz

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
        try:
            return self._wrench(T_w_MRF, V_w_MRF)
        except ContactQueryError as exc:
            self.reset()
            return ContactResult(False, np.zeros(6), np.zeros(6), np.zeros(3), error=str(exc))

    def _near_objects(self, c0: tuple[float, float, float]) -> list[int]:
        """Objects whose bounding box the tool's bounding sphere (centre c0 in {w}) may reach."""
        dx, dy, dz = c0[0] - self._near_c0[0], c0[1] - self._near_c0[1], c0[2] - self._near_c0[2]
        if self._near_slack > 0.0 and dx * dx + dy * dy + dz * dz < self._near_slack * self._near_slack:
            return self._near
        c = np.array(c0)
        gap = np.maximum(self._lo - c, 0.0) + np.maximum(c - self._hi, 0.0)
        dist = np.sqrt(np.einsum("ij,ij->i", gap, gap)) - self._reach
        memory_objects = {key // len(self._radii) for key in self._memory}
        near = dist <= 0.0
        self._near = sorted(set(np.flatnonzero(near).tolist()) | memory_objects)
        self._near_slack = float(dist[~near].min()) if (~near).any() else math.inf
        self._near_c0 = c0
        return self._near

    def _wrench(self, T_w_MRF: Array, V_w_MRF: Array | None) -> ContactResult:
        T = T_w_MRF.tolist()
        if not math.isfinite(sum(T[0]) + sum(T[1]) + sum(T[2])):
            raise ContactQueryError("non-finite tool pose")
        if V_w_MRF is not None:
            vx, vy, vz, wx, wy, wz = V_w_MRF.tolist()
            if not math.isfinite(vx + vy + vz + wx + wy + wz):
                raise ContactQueryError("non-finite tool twist")
        T_w_T = T_w_MRF @ self._T_MRF_T
        (r00, r01, r02, tx), (r10, r11, r12, ty), (r20, r21, r22, tz), _ = T_w_T.tolist()
        R_now = [r00, r01, r02, r10, r11, r12, r20, r21, r22]
        ax, ay, az = self._c0_T.tolist()
        c0 = (
            r00 * ax + r01 * ay + r02 * az + tx,
            r10 * ax + r11 * ay + r12 * az + ty,
            r20 * ax + r21 * ay + r22 * az + tz,
        )
        pmx, pmy, pmz = T[0][3], T[1][3], T[2][3]
        C_w: Array | None = None  # all sphere centres in {w}, computed only if some object needs them
        pts: list[tuple[float, float, float]] = []
        nrm: list[tuple[float, float, float]] = []
        dep: list[float] = []
        sid: list[int] = []
        oid: list[int] = []
        Fx = Fy = Fz = Mx = My = Mz = 0.0  # force on the tool and moment about the {MRF} origin, in {w}
        queries = 0
        for j in self._near_objects(c0):
            # Largest displacement of any sphere centre since object j's base pose: c0 translation
            # plus rotation about c0 (|(R - R0) y| = 2 sin(theta/2) |y|).
            bc = self._base_c0[j]
            dx, dy, dz = c0[0] - bc[0], c0[1] - bc[1], c0[2] - bc[2]
            b = self._base_R[j]
            cos_sum = (  # trace(R_now R_base^T) = 1 + 2 cos(theta)
                R_now[0] * b[0] + R_now[1] * b[1] + R_now[2] * b[2]
                + R_now[3] * b[3] + R_now[4] * b[4] + R_now[5] * b[5]
                + R_now[6] * b[6] + R_now[7] * b[7] + R_now[8] * b[8]
            )  # fmt: skip
            moved = math.sqrt(dx * dx + dy * dy + dz * dz) + self._rho * math.sqrt(max(0.0, 3.0 - cos_sum))
            if moved < self._obj_slack[j]:
                todo = self._hot[j]
            else:
                if C_w is None:
                    C_w = self._centers_T @ T_w_T[0:3, 0:3].T + T_w_T[0:3, 3]
                diff = C_w - self._last_c[j]
                todo = np.flatnonzero(np.sqrt(np.einsum("ij,ij->i", diff, diff)) >= self._slack[j]).tolist()
            for i in todo:
                x, y, z = self._centers_T_list[i]
                cx = r00 * x + r01 * y + r02 * z + tx
                cy = r10 * x + r11 * y + r12 * z + ty
                cz = r20 * x + r21 * y + r22 * z + tz
                queries += 1
                hit = self._pair(j, i, cx, cy, cz)
                if hit is None:
                    continue
                depth, nx, ny, nz = hit
                obj = self._objects[j]
                fn = obj.stiffness * depth
                fx = fy = fz = 0.0
                if V_w_MRF is not None:
                    rx, ry, rz = cx - pmx, cy - pmy, cz - pmz
                    ux = vx + wy * rz - wz * ry
                    uy = vy + wz * rx - wx * rz
                    uz = vz + wx * ry - wy * rx
                    un = ux * nx + uy * ny + uz * nz
                    fn = max(0.0, fn - obj.damping * un)
                    if obj.friction > 0.0:
                        ex, ey, ez = ux - un * nx, uy - un * ny, uz - un * nz
                        scale = -obj.friction * fn / max(math.sqrt(ex * ex + ey * ey + ez * ez), _V_SLIP)
                        fx, fy, fz = scale * ex, scale * ey, scale * ez
                fx += fn * nx
                fy += fn * ny
                fz += fn * nz
                s = self._radii[i] - depth  # contact point on the surface: centre minus (r - depth) along n
                px, py, pz = cx - s * nx, cy - s * ny, cz - s * nz
                rx, ry, rz = px - pmx, py - pmy, pz - pmz
                Fx += fx
                Fy += fy
                Fz += fz
                Mx += ry * fz - rz * fy
                My += rz * fx - rx * fz
                Mz += rx * fy - ry * fx
                pts.append((px, py, pz))
                nrm.append((nx, ny, nz))
                dep.append(depth)
                sid.append(i)
                oid.append(j)
            if moved >= self._obj_slack[j]:
                self._rebase(j, c0, R_now, C_w)
        if not math.isfinite(Fx + Fy + Fz + Mx + My + Mz):
            raise ContactQueryError("non-finite contact wrench")
        # {w} -> {MRF} (transpose of R_w_MRF), then Eq 6 backwards for the moment about {S}.
        (a00, a01, a02, _), (a10, a11, a12, _), (a20, a21, a22, _), _ = T
        fmx = a00 * Fx + a10 * Fy + a20 * Fz
        fmy = a01 * Fx + a11 * Fy + a21 * Fz
        fmz = a02 * Fx + a12 * Fy + a22 * Fz
        mmx = a00 * Mx + a10 * My + a20 * Mz
        mmy = a01 * Mx + a11 * My + a21 * Mz
        mmz = a02 * Mx + a12 * My + a22 * Mz
        sx, sy, sz = self._p_MRF_S
        ox, oy, oz = mmx - (sy * fmz - sz * fmy), mmy - (sz * fmx - sx * fmz), mmz - (sx * fmy - sy * fmx)
        (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = self._R_MRF_S
        wrench_S = np.array(
            (
                b00 * fmx + b10 * fmy + b20 * fmz,
                b01 * fmx + b11 * fmy + b21 * fmz,
                b02 * fmx + b12 * fmy + b22 * fmz,
                b00 * ox + b10 * oy + b20 * oz,
                b01 * ox + b11 * oy + b21 * oz,
                b02 * ox + b12 * oy + b22 * oz,
            )
        )
        wrench_MRF = np.array((fmx, fmy, fmz, mmx, mmy, mmz))
        if not dep:
            return ContactResult(True, wrench_S, wrench_MRF, np.array((Fx, Fy, Fz)), queries=queries)
        return ContactResult(
            True,
            wrench_S,
            wrench_MRF,
            np.array((Fx, Fy, Fz)),
            np.array(pts),
            np.array(nrm),
            np.array(dep),
            np.array(sid, dtype=int),
            np.array(oid, dtype=int),
            queries,
        )

    def _rebase(self, j: int, c0: tuple[float, float, float], R_now: list[float], C_w: Array | None) -> None:
        """Make the current tool pose object j's base: hot spheres and the slack of the others."""
        assert C_w is not None
        diff = C_w - self._last_c[j]
        slack = self._slack[j]
        remaining = slack - np.sqrt(np.einsum("ij,ij->i", diff, diff))
        cold = slack >= 0.0
        self._hot[j] = np.flatnonzero(~cold).tolist()
        self._obj_slack[j] = float(remaining[cold].min()) if cold.any() else math.inf
        self._base_c0[j] = c0
        self._base_R[j] = R_now

    def _pair(self, j: int, i: int, cx: float, cy: float, cz: float) -> tuple[float, float, float, float] | None:
        """Query sphere i against object j; update its memory and slack. ``(depth, n)`` or None."""
        r = self._radii[i]
        key = j * len(self._radii) + i
        mem = self._memory.get(key)
        hint = (mem[3], mem[4], mem[5]) if mem is not None else (0.0, 0.0, 1.0)
        c = np.array((cx, cy, cz))
        phi, qx, qy, qz, nx, ny, nz = self._signed(self._meshes[j], c, hint, key)
        self._last_c[j, i] = c
        in_memory = False
        if mem is not None and nx * mem[3] + ny * mem[4] + nz * mem[5] < 0.0:
            s0 = (cx - mem[0]) * mem[3] + (cy - mem[1]) * mem[4] + (cz - mem[2]) * mem[5]
            if s0 < 0.0:
                # Normal flipped with the centre behind the remembered surface: it crossed the middle
                # of a thin part (pop-through). A flip in front of it is a real new contact.
                qx, qy, qz, nx, ny, nz = mem
                phi = s0
                in_memory = True
        depth = r - phi
        if depth <= 0.0:
            if mem is not None:
                del self._memory[key]
            gap = phi - r - self._margin
            self._slack[j, i] = gap if gap > 0.0 else -1.0
            return None
        if not in_memory:
            self._memory[key] = (qx, qy, qz, nx, ny, nz)
        self._slack[j, i] = -1.0
        return depth, nx, ny, nz


def contact_wrench(scene: Scene, T_w_MRF: Array, V_w_MRF: Array | None = None) -> ContactResult:
    """Stateless contact wrench of ``scene``'s tool at ``T_w_MRF`` (4, 4); see :meth:`ContactModel.wrench`.

    Builds a fresh :class:`ContactModel` (so no pop-through memory) on each call; for a sequence
    of poses keep one model instead.
    """
    return ContactModel(scene).wrench(T_w_MRF, V_w_MRF)
