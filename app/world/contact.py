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
query's normal opposes the remembered one, the centre has crossed the middle of a thin part, so
the remembered plane keeps giving the depth (pushing a 1 mm plate 10 mm never flips the force).
The memory is released when the depth along it reaches 0.

Culling: the unsigned distance is 1-Lipschitz in the centre position, so a pair found at
distance d > r cannot touch until its centre has moved ``d - r``; the query is skipped until
then. Objects whose bounding box is out of reach of the tool's bounding sphere are skipped too.

Any FCL result that is non-finite or inconsistent (e.g. from a NaN pose) makes the whole result
invalid with a zero wrench; it never becomes a wrench.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import fcl
import numpy as np
import trimesh

from app.errors import ContactQueryError
from app.spatial import Array, invert_pose
from app.world.scene import Scene, WorldObject

# Below this distance (m) the nearest-point direction is numerically meaningless and FCL's
# zero-radius query may report uninitialised memory: the centre is treated as on the surface.
_TOUCH = 1e-9
# Offset (m) of the re-query used when the centre lies exactly on the surface.
_NUDGE = 1e-6
# Barycentric tolerance deciding that the nearest point lies on an edge or a vertex.
_BARY_TOL = 1e-7
# Tangential speed (m/s) below which friction is viscous (regularised Coulomb).
_V_SLIP = 1e-3
_FAR = 1e30


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
    points_w: Array = field(default_factory=lambda: np.zeros((0, 3)))
    normals_w: Array = field(default_factory=lambda: np.zeros((0, 3)))
    depths: Array = field(default_factory=lambda: np.zeros(0))
    sphere_ids: Array = field(default_factory=lambda: np.zeros(0, dtype=int))
    object_ids: Array = field(default_factory=lambda: np.zeros(0, dtype=int))
    queries: int = 0
    error: str | None = None

    @property
    def count(self) -> int:
        """Number of (sphere, object) pairs in contact."""
        return len(self.depths)


class _ObjectData:
    """An object's FCL model and the per-feature pseudonormals used for inside/outside."""

    __slots__ = (
        "damping",
        "edge_pn",
        "face_edges",
        "face_normals",
        "faces",
        "friction",
        "fcl_object",
        "hi",
        "lo",
        "n_faces",
        "stiffness",
        "vertex_pn",
        "vertices",
    )

    def __init__(self, obj: WorldObject) -> None:
        mesh: trimesh.Trimesh = obj.mesh
        self.vertices = np.asarray(mesh.vertices, dtype=float)
        self.faces = np.asarray(mesh.faces, dtype=np.int64)
        self.n_faces = len(self.faces)
        self.face_normals = np.asarray(mesh.face_normals, dtype=float)
        # Edge pseudonormal: sum of the adjacent face normals. Vertex: angle-weighted sum.
        self.face_edges = np.asarray(mesh.faces_unique_edges, dtype=np.int64)
        edge_pn = np.zeros((len(mesh.edges_unique), 3))
        np.add.at(edge_pn, self.face_edges.ravel(), np.repeat(self.face_normals, 3, axis=0))
        vertex_pn = np.zeros_like(self.vertices)
        weighted = np.asarray(mesh.face_angles)[:, :, None] * self.face_normals[:, None, :]
        np.add.at(vertex_pn, self.faces.ravel(), weighted.reshape(-1, 3))
        self.edge_pn = edge_pn / np.maximum(np.linalg.norm(edge_pn, axis=1), 1e-300)[:, None]
        self.vertex_pn = vertex_pn / np.maximum(np.linalg.norm(vertex_pn, axis=1), 1e-300)[:, None]
        bvh = fcl.BVHModel()
        bvh.beginModel(len(self.vertices), self.n_faces)
        bvh.addSubModel(self.vertices, self.faces)
        bvh.endModel()
        self.fcl_object = fcl.CollisionObject(bvh, fcl.Transform())
        self.lo = self.vertices.min(axis=0)
        self.hi = self.vertices.max(axis=0)
        self.stiffness = obj.stiffness
        self.damping = obj.damping
        self.friction = obj.friction

    def pseudonormal(self, tri: int, qx: float, qy: float, qz: float) -> tuple[float, float, float]:
        """Outward pseudonormal of the feature of triangle ``tri`` nearest to point q (in {w})."""
        ia, ib, ic = self.faces[tri].tolist()
        ax, ay, az = self.vertices[ia].tolist()
        bx, by, bz = self.vertices[ib].tolist()
        cx, cy, cz = self.vertices[ic].tolist()
        v0x, v0y, v0z = bx - ax, by - ay, bz - az
        v1x, v1y, v1z = cx - ax, cy - ay, cz - az
        v2x, v2y, v2z = qx - ax, qy - ay, qz - az
        d00 = v0x * v0x + v0y * v0y + v0z * v0z
        d01 = v0x * v1x + v0y * v1y + v0z * v1z
        d11 = v1x * v1x + v1y * v1y + v1z * v1z
        d20 = v2x * v0x + v2y * v0y + v2z * v0z
        d21 = v2x * v1x + v2y * v1y + v2z * v1z
        den = d00 * d11 - d01 * d01
        l1 = (d11 * d20 - d01 * d21) / den
        l2 = (d00 * d21 - d01 * d20) / den
        bary = (1.0 - l1 - l2, l1, l2)
        small = [k for k in range(3) if bary[k] < _BARY_TOL]
        if len(small) >= 2:
            k = 3 - small[0] - small[1]  # the one vertex that is not ~0
            n = self.vertex_pn[(ia, ib, ic)[k]]
        elif len(small) == 1:
            # faces_unique_edges lists edges (v0 v1), (v1 v2), (v2 v0): the one opposite vertex k is k+1.
            n = self.edge_pn[self.face_edges[tri, (small[0] + 1) % 3]]
        else:
            n = self.face_normals[tri]
        nx, ny, nz = n.tolist()
        return nx, ny, nz


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
        self._radii = tool.radii.tolist()
        self._T_MRF_T = invert_pose(tool.T_T_MRF)
        self._T_T_S = tool.T_T_S
        self._T_MRF_S = tool.T_MRF_S
        self._c0_T = tool.centers_T.mean(axis=0)
        self._reach = float(np.max(np.linalg.norm(tool.centers_T - self._c0_T, axis=1) + tool.radii)) + self._margin
        self._objects = [_ObjectData(o) for o in scene.objects]
        self._lo = np.array([o.lo for o in self._objects]).reshape(-1, 3)
        self._hi = np.array([o.hi for o in self._objects]).reshape(-1, 3)
        n, m = len(self._radii), len(self._objects)
        self._last_c = np.full((m, n, 3), _FAR)
        self._slack2 = np.full((m, n), -1.0)
        self._memory: dict[int, tuple[float, float, float, float, float, float]] = {}
        self._memory_objects = np.zeros(m, dtype=np.int64)
        self._core = fcl.CollisionObject(fcl.Sphere(0.0), fcl.Transform())
        self._request = fcl.DistanceRequest(enable_nearest_points=True)
        self._zero6 = np.zeros(6)

    def reset(self) -> None:
        """Forget contact memory and culling caches (e.g. after the tool was teleported)."""
        self._last_c.fill(_FAR)
        self._slack2.fill(-1.0)
        self._memory.clear()
        self._memory_objects.fill(0)

    def _distance(self, obj: _ObjectData, c: Array) -> tuple[float, int, float, float, float]:
        """FCL unsigned distance from point c (3,) to the mesh: (d, triangle, q) with q in {w}."""
        self._core.setTranslation(c)
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
        self, obj: _ObjectData, c: Array, hint: tuple[float, float, float]
    ) -> tuple[float, float, float, float, float, float, float]:
        """Signed distance phi (> 0 outside), nearest point q and outward normal n at centre c."""
        d, tri, qx, qy, qz = self._distance(obj, c)
        cx, cy, cz = c.tolist()
        if d == 0.0:
            # On the surface: FCL gives no point, so query just off it and take that nearest point.
            nudged = c + _NUDGE * np.array(hint)
            d2, tri, qx, qy, qz = self._distance(obj, nudged)
            if d2 == 0.0:
                raise ContactQueryError("FCL distance degenerate at the surface twice")
            nx, ny, nz = obj.pseudonormal(tri, qx, qy, qz)
            return 0.0, qx, qy, qz, nx, ny, nz
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
            zero = self._zero6.copy()
            return ContactResult(False, zero, zero.copy(), np.zeros(3), error=str(exc))

    def _wrench(self, T_w_MRF: Array, V_w_MRF: Array | None) -> ContactResult:
        if not np.isfinite(T_w_MRF).all() or (V_w_MRF is not None and not np.isfinite(V_w_MRF).all()):
            raise ContactQueryError("non-finite tool pose or twist")
        T_w_T = T_w_MRF @ self._T_MRF_T
        R_w_T = T_w_T[0:3, 0:3]
        p_w_T = T_w_T[0:3, 3]
        C_w = self._centers_T @ R_w_T.T + p_w_T
        # Objects whose box is beyond the reach of the tool's bounding sphere (or holding memory).
        c0 = R_w_T @ self._c0_T + p_w_T
        gap = np.maximum(self._lo - c0, 0.0) + np.maximum(c0 - self._hi, 0.0)
        near = np.flatnonzero((np.einsum("ij,ij->i", gap, gap) <= self._reach * self._reach) | (self._memory_objects > 0))
        pmx, pmy, pmz = T_w_MRF[0:3, 3].tolist()
        if V_w_MRF is not None:
            vx, vy, vz, wx, wy, wz = V_w_MRF.tolist()
        n_spheres = len(self._radii)
        pts: list[tuple[float, float, float]] = []
        nrm: list[tuple[float, float, float]] = []
        dep: list[float] = []
        sid: list[int] = []
        oid: list[int] = []
        Fx = Fy = Fz = Mx = My = Mz = 0.0  # force on the tool and moment about the {MRF} origin, in {w}
        queries = 0
        for j in near.tolist():
            obj = self._objects[j]
            diff = C_w - self._last_c[j]
            for i in np.flatnonzero(np.einsum("ij,ij->i", diff, diff) >= self._slack2[j]).tolist():
                c = C_w[i]
                r = self._radii[i]
                key = j * n_spheres + i
                mem = self._memory.get(key)
                hint = (mem[3], mem[4], mem[5]) if mem is not None else (0.0, 0.0, 1.0)
                phi, qx, qy, qz, nx, ny, nz = self._signed(obj, c, hint)
                queries += 1
                self._last_c[j, i] = c
                cx, cy, cz = c.tolist()
                if mem is not None and nx * mem[3] + ny * mem[4] + nz * mem[5] < 0.0:
                    # Normal flipped: the centre crossed the middle of a thin part; keep the old plane.
                    qx, qy, qz, nx, ny, nz = mem
                    phi = (cx - qx) * nx + (cy - qy) * ny + (cz - qz) * nz
                    in_memory = True
                else:
                    in_memory = False
                depth = r - phi
                if depth <= 0.0:
                    if mem is not None:
                        del self._memory[key]
                        self._memory_objects[j] -= 1
                    gap_ij = phi - r - self._margin
                    self._slack2[j, i] = gap_ij * gap_ij if gap_ij > 0.0 else -1.0
                    continue
                if not in_memory:
                    if mem is None:
                        self._memory_objects[j] += 1
                    self._memory[key] = (qx, qy, qz, nx, ny, nz)
                self._slack2[j, i] = -1.0
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
                        tx, ty, tz = ux - un * nx, uy - un * ny, uz - un * nz
                        scale = -obj.friction * fn / max(math.sqrt(tx * tx + ty * ty + tz * tz), _V_SLIP)
                        fx, fy, fz = scale * tx, scale * ty, scale * tz
                fx += fn * nx
                fy += fn * ny
                fz += fn * nz
                s = r - depth  # contact point on the surface: centre minus (r - depth) along n
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
        F_w = np.array((Fx, Fy, Fz))
        M_w = np.array((Mx, My, Mz))
        if not (np.isfinite(F_w).all() and np.isfinite(M_w).all()):
            raise ContactQueryError("non-finite contact wrench")
        R_w_MRF = T_w_MRF[0:3, 0:3]
        wrench_MRF = np.concatenate((F_w @ R_w_MRF, M_w @ R_w_MRF))
        # Moment about {S}: m_S = m_MRF - p_MRF_S x f (all in {MRF}), then rotate into {S}.
        R_MRF_S = self._T_MRF_S[0:3, 0:3]
        f_MRF = wrench_MRF[0:3]
        m_about_S = wrench_MRF[3:6] - np.cross(self._T_MRF_S[0:3, 3], f_MRF)
        wrench_S = np.concatenate((f_MRF @ R_MRF_S, m_about_S @ R_MRF_S))
        k = len(dep)
        return ContactResult(
            True,
            wrench_S,
            wrench_MRF,
            F_w,
            np.array(pts).reshape(k, 3),
            np.array(nrm).reshape(k, 3),
            np.array(dep),
            np.array(sid, dtype=int),
            np.array(oid, dtype=int),
            queries,
        )


def contact_wrench(scene: Scene, T_w_MRF: Array, V_w_MRF: Array | None = None) -> ContactResult:
    """Stateless contact wrench of ``scene``'s tool at ``T_w_MRF`` (4, 4); see :meth:`ContactModel.wrench`.

    Builds a fresh :class:`ContactModel` (so no pop-through memory) on each call; for a sequence
    of poses keep one model instead.
    """
    return ContactModel(scene).wrench(T_w_MRF, V_w_MRF)
