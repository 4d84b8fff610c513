"""The contact model's per-tick work (:class:`~app.world.contact.ContactModel`), compiled with numba.

One :func:`contact_step` evaluates the tool's sphere set against every object: it culls, looks up
each remaining (object, sphere) pair's nearest triangle in that pair's cached candidate set,
signs the distance with the nearest feature's pseudonormal, applies pop-through memory, sums the
penalty wrench, and updates the culling state. A pair whose cache cannot answer (first contact,
or the sphere centre left the cache's radius of validity) is a *miss*: the step then changes no
state and returns the misses, :class:`~app.world.contact.ContactModel` answers each with one FCL
distance query and refills the pair's cache with :func:`gather`, and the step runs again. In
CPython this bookkeeping cost tens of microseconds a tick (Python overhead per pair); here it is
a few, most of it argument unboxing.

The cache is exact (no tolerance): FCL gave distance d0 at centre c0, so while ``|c - c0| <= R``
the nearest triangle (at most ``d0 + R`` from c) lies within ``d0 + 2 R`` of c0, and the cache
holds every triangle that close, found through a uniform grid of triangle bounding boxes per
object (python-fcl exposes no range query). Layouts of the packed arrays are the column
constants below; geometry comes from :class:`~app.world.collision.PackedMeshes`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.spatial import Array, IntArray

# Columns of the per-pair float state ``pair_f`` (P = objects x spheres rows, pair k = j n + i).
PF_LAST = 0  # 0:3 sphere centre (m, {w}) at the pair's last evaluation
PF_SLACK = 3  # distance (m) the centre may move from there before it can touch; -1 = query every tick
PF_MEM = 4  # 4:10 pop-through memory: contact point q (3) and outward normal n (3), {w}
PF_CACHE_C = 10  # 10:13 centre (m, {w}) the candidate cache was gathered at
PF_CACHE_R = 13  # its radius of validity (m)
PF_FCL_C = 14  # 14:17 centre of the pair's last FCL answer
PF_FCL_D = 17  # FCL distance there (m); 0 = on the surface (then q/tri come from a nudged query)
PF_FCL_Q = 18  # 18:21 FCL nearest point
PF_LAST_D = 21  # unsigned distance (m) to the mesh at PF_LAST
PF_COLS = 22
# Columns of the per-pair int state ``pair_i``.
PI_MEM = 0  # 1 while the memory holds a plane
PI_CACHE_N = 1  # number of cached candidates in ``pool[k]``; -1 = no cache
PI_FCL_TRI = 2  # global triangle of the FCL answer; -1 = none
PI_HOT = 3  # 1 if the sphere is queried every tick while its object's slack holds
PI_NEAREST = 4  # triangle nearest to the centre at the pair's last scan (-1: none): the next scan's seed
PI_COLS = 5
# Columns of the per-object float state ``obj_f``.
OF_BASE_C0 = 0  # 0:3 tool bounding-sphere centre at the object's base pose
OF_BASE_R = 3  # 3:12 tool rotation (row-major) at the base pose
OF_SLACK = 12  # distance any sphere centre may move from the base pose before a full check; -1 = now
OF_COLS = 13
# Columns of the per-object parameters ``obj_p``.
OP_K, OP_B, OP_MU = 0, 1, 2  # stiffness (N/m), damping (N s/m), friction coefficient (-)
OP_LO = 3  # 3:6 bounding box minimum (m, {w})
OP_HI = 6  # 6:9 maximum
OP_COLS = 9
# Slots of the global float state ``glob_f``: tool centre at the last near-object test and its slack.
GF_NEAR_C0 = 0
GF_NEAR_SLACK = 3
GF_COLS = 4
# Slots of the tool constants ``tool_p``: bounding-sphere centre in {T} (3), radius of the centres,
# reach (bounding radius of the spheres plus margin), margin, and {S} in {MRF}: p (3), R row-major (9).
TP_C0, TP_RHO, TP_REACH, TP_MARGIN, TP_P_MRF_S, TP_R_MRF_S = 0, 3, 4, 5, 6, 9
TP_COLS = 18
# Output slots of ``out_w``: wrench at {S} in {S}, at {MRF} in {MRF}, total force in {w}.
OW_S, OW_MRF, OW_F = 0, 6, 12
# Columns of the per-contact outputs ``out_c``: point (3), outward normal (3), depth; and of
# ``out_ci``: sphere, object.
OC_P, OC_N, OC_DEPTH = 0, 3, 6
OC_COLS = 7
# Return codes of :func:`contact_step` (besides >= 0 for success).
ERR_POSE, ERR_TWIST, ERR_WRENCH = -1, -2, -3

# Below this distance (m) the nearest-point direction is numerically meaningless (and FCL's
# zero-radius query may report uninitialised memory): the centre is treated as on the surface.
TOUCH = 1e-9
# Offset (m) of the re-query used when the centre lies exactly on the surface.
NUDGE = 1e-6
# Tangential speed (m/s) below which friction is viscous (regularised Coulomb).
_V_SLIP = 1e-3
# Barycentric tolerance deciding that the nearest point lies on an edge or a vertex.
_BARY_TOL = 1e-7
# A gather visiting more grid cells than this gives up (the pair is far: FCL answers it each time).
_MAX_CELLS = 4096
# A pair's candidate cache stays valid while its centre moves less than max(CACHE_MIN, CACHE_FRAC * d)
# (m) from where it was gathered (d: the distance there). A larger radius means fewer gathers on
# the move but more triangles to scan each tick.
CACHE_MIN = 1e-4
CACHE_FRAC = 0.05


@njit(cache=True)
def closest_on_triangle(
    vertices: Array, faces: IntArray, t: int, cx: float, cy: float, cz: float
) -> tuple[float, float, float, float, bool]:
    """Squared distance from c to triangle t, its nearest point q, and whether q is inside the face
    (not on an edge or a vertex; then ``c - q`` is along the face normal). Ericson 5.1.5."""
    ia, ib, ic = faces[t, 0], faces[t, 1], faces[t, 2]
    ax, ay, az = vertices[ia, 0], vertices[ia, 1], vertices[ia, 2]
    abx, aby, abz = vertices[ib, 0] - ax, vertices[ib, 1] - ay, vertices[ib, 2] - az
    acx, acy, acz = vertices[ic, 0] - ax, vertices[ic, 1] - ay, vertices[ic, 2] - az
    apx, apy, apz = cx - ax, cy - ay, cz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    interior = False
    if d1 <= 0.0 and d2 <= 0.0:
        u, v = 0.0, 0.0
    else:
        bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        if d3 >= 0.0 and d4 <= d3:
            u, v = 1.0, 0.0
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                u, v = d1 / (d1 - d3), 0.0
            else:
                cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
                d5 = abx * cpx + aby * cpy + abz * cpz
                d6 = acx * cpx + acy * cpy + acz * cpz
                if d6 >= 0.0 and d5 <= d6:
                    u, v = 0.0, 1.0
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        u, v = 0.0, d2 / (d2 - d6)
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                            u, v = 1.0 - w, w
                        else:
                            den = 1.0 / (va + vb + vc)
                            u, v = vb * den, vc * den
                            interior = True
    qx = ax + u * abx + v * acx
    qy = ay + u * aby + v * acy
    qz = az + u * abz + v * acz
    return (cx - qx) ** 2 + (cy - qy) ** 2 + (cz - qz) ** 2, qx, qy, qz, interior


@njit(cache=True)
def pseudonormal(
    vertices: Array,
    faces: IntArray,
    face_normals: Array,
    face_edges: IntArray,
    edge_pn: Array,
    vertex_pn: Array,
    t: int,
    qx: float,
    qy: float,
    qz: float,
) -> tuple[float, float, float]:
    """Outward pseudonormal of the feature (face, edge or vertex) of triangle t nearest to point q."""
    ia, ib, ic = faces[t, 0], faces[t, 1], faces[t, 2]
    ax, ay, az = vertices[ia, 0], vertices[ia, 1], vertices[ia, 2]
    v0x, v0y, v0z = vertices[ib, 0] - ax, vertices[ib, 1] - ay, vertices[ib, 2] - az
    v1x, v1y, v1z = vertices[ic, 0] - ax, vertices[ic, 1] - ay, vertices[ic, 2] - az
    v2x, v2y, v2z = qx - ax, qy - ay, qz - az
    d00 = v0x * v0x + v0y * v0y + v0z * v0z
    d01 = v0x * v1x + v0y * v1y + v0z * v1z
    d11 = v1x * v1x + v1y * v1y + v1z * v1z
    d20 = v2x * v0x + v2y * v0y + v2z * v0z
    d21 = v2x * v1x + v2y * v1y + v2z * v1z
    den = d00 * d11 - d01 * d01
    l1 = (d11 * d20 - d01 * d21) / den
    l2 = (d00 * d21 - d01 * d20) / den
    small0, small1, small2 = 1.0 - l1 - l2 < _BARY_TOL, l1 < _BARY_TOL, l2 < _BARY_TOL
    n_small = int(small0) + int(small1) + int(small2)
    if n_small >= 2:  # at the one vertex whose coordinate is not ~0
        v = ia if not small0 else (ib if not small1 else ic)
        return vertex_pn[v, 0], vertex_pn[v, 1], vertex_pn[v, 2]
    if n_small == 1:
        # The edge opposite vertex k; face_edges lists (v0 v1), (v1 v2), (v2 v0), so it is k + 1.
        k = 0 if small0 else (1 if small1 else 2)
        e = face_edges[t, (k + 1) % 3]
        return edge_pn[e, 0], edge_pn[e, 1], edge_pn[e, 2]
    return face_normals[t, 0], face_normals[t, 1], face_normals[t, 2]


@njit(cache=True)
def grid_entries(
    vertices: Array, faces: IntArray, face0: IntArray, grid_f: Array, grid_i: IntArray
) -> tuple[IntArray, IntArray]:
    """(cell key, triangle) for every grid cell each triangle's bounding box overlaps.

    Object j's grid has origin ``grid_f[j, 0:3]``, cell size ``grid_f[j, 3]`` (m), ``grid_i[j, 0:3]``
    cells per axis and keys from ``grid_i[j, 3]`` on (cell (x, y, z) is ``base + (x ny + y) nz + z``).
    """
    m = face0.shape[0] - 1
    counts = np.zeros(faces.shape[0], dtype=np.int64)
    lo_c = np.empty((faces.shape[0], 3), dtype=np.int64)
    hi_c = np.empty((faces.shape[0], 3), dtype=np.int64)
    for j in range(m):
        for t in range(face0[j], face0[j + 1]):
            n = 1
            for a in range(3):
                lo = min(vertices[faces[t, 0], a], vertices[faces[t, 1], a], vertices[faces[t, 2], a])
                hi = max(vertices[faces[t, 0], a], vertices[faces[t, 1], a], vertices[faces[t, 2], a])
                lo_c[t, a] = _cell(lo, grid_f[j, a], grid_f[j, 3], grid_i[j, a])
                hi_c[t, a] = _cell(hi, grid_f[j, a], grid_f[j, 3], grid_i[j, a])
                n *= hi_c[t, a] - lo_c[t, a] + 1
            counts[t] = n
    keys = np.empty(counts.sum(), dtype=np.int64)
    tris = np.empty(keys.shape[0], dtype=np.int64)
    e = 0
    for j in range(m):
        ny, nz, base = grid_i[j, 1], grid_i[j, 2], grid_i[j, 3]
        for t in range(face0[j], face0[j + 1]):
            for x in range(lo_c[t, 0], hi_c[t, 0] + 1):
                for y in range(lo_c[t, 1], hi_c[t, 1] + 1):
                    for z in range(lo_c[t, 2], hi_c[t, 2] + 1):
                        keys[e] = base + (x * ny + y) * nz + z
                        tris[e] = t
                        e += 1
    return keys, tris


@njit(cache=True)
def _cell(x: float, origin: float, h: float, n: int) -> int:
    """Grid cell index of coordinate x, clamped to [0, n - 1] (monotone in x)."""
    # Clamp before the integer conversion: a far coordinate must not overflow it.
    return math.floor(min(max((x - origin) / h, 0.0), n - 1.0))


# The grid and its scratch, as one argument: triangle bounding boxes (F, 6), grid_f, grid_i,
# grid_keys, grid_start, grid_tris (see :class:`~app.world.collision.PackedMeshes`), the per-triangle
# stamps of a gather (F,), and the last stamp used (1,).
GridArgs = tuple[Array, Array, IntArray, IntArray, IntArray, IntArray, IntArray, IntArray]


@njit(cache=True)
def _box_distance2(boxes: Array, t: int, cx: float, cy: float, cz: float) -> float:
    """Squared distance from c to box t (rows: minimum (3), maximum (3)); a lower bound for its triangle."""
    dx = max(boxes[t, 0] - cx, 0.0, cx - boxes[t, 3])
    dy = max(boxes[t, 1] - cy, 0.0, cy - boxes[t, 4])
    dz = max(boxes[t, 2] - cz, 0.0, cz - boxes[t, 5])
    return dx * dx + dy * dy + dz * dz


@njit(cache=True)
def gather(
    j: int,
    cx: float,
    cy: float,
    cz: float,
    reach: float,
    vertices: Array,
    faces: IntArray,
    grid: GridArgs,
    out: IntArray,
) -> int:
    """Write into ``out`` every triangle of object j within distance ``reach`` of c; return the count.

    -1 if they do not fit in ``out`` or the search box covers more than ``_MAX_CELLS`` cells.
    """
    tri_boxes, grid_f, grid_i, grid_keys, grid_start, grid_tris, stamp, serial = grid
    h = grid_f[j, 3]
    lo = np.empty(3, dtype=np.int64)
    hi = np.empty(3, dtype=np.int64)
    cells = 1
    for a, x in enumerate((cx, cy, cz)):
        lo[a] = _cell(x - reach, grid_f[j, a], h, grid_i[j, a])
        hi[a] = _cell(x + reach, grid_f[j, a], h, grid_i[j, a])
        cells *= hi[a] - lo[a] + 1
    if cells > _MAX_CELLS:
        return -1
    # A triangle spans several cells: stamp it with this gather's number the first time it is seen.
    serial[0] += 1
    mark = serial[0]
    ny, nz, base = grid_i[j, 1], grid_i[j, 2], grid_i[j, 3]
    n = 0
    n_keys = grid_keys.shape[0]
    for x in range(lo[0], hi[0] + 1):
        for y in range(lo[1], hi[1] + 1):
            # The column's cells have consecutive keys: one search finds its first occupied cell.
            first = base + (x * ny + y) * nz + lo[2]
            last = first + hi[2] - lo[2]
            s = np.searchsorted(grid_keys, first)
            while s < n_keys and grid_keys[s] <= last:
                s += 1
                for e in range(grid_start[s - 1], grid_start[s]):
                    t = grid_tris[e]
                    if stamp[t] == mark:
                        continue
                    stamp[t] = mark
                    if _box_distance2(tri_boxes, t, cx, cy, cz) > reach * reach:
                        continue
                    if closest_on_triangle(vertices, faces, t, cx, cy, cz)[0] > reach * reach:
                        continue
                    if n == out.shape[0]:
                        return -1
                    out[n] = t
                    n += 1
    return n


@njit(cache=True)
def refill(
    k: int,
    j: int,
    cx: float,
    cy: float,
    cz: float,
    d: float,
    R: float,
    vertices: Array,
    faces: IntArray,
    pair_f: Array,
    pair_i: IntArray,
    pool: IntArray,
    grid: GridArgs,
) -> int:
    """Regather pair k's (object j) candidate cache at centre c, valid for radius R, given that the
    distance from c to the mesh is at most d; returns the count (-1: no cache, too many)."""
    n = gather(j, cx, cy, cz, d + 2.0 * R + 1e-9 + 1e-6 * d, vertices, faces, grid, pool[k])
    f = pair_f[k]
    f[PF_CACHE_C], f[PF_CACHE_C + 1], f[PF_CACHE_C + 2] = cx, cy, cz
    f[PF_CACHE_R] = R
    pair_i[k, PI_CACHE_N] = n
    return n


@njit(cache=True)
def _scan(
    vertices: Array,
    faces: IntArray,
    boxes: Array,
    pool_k: IntArray,
    n: int,
    seed: int,
    cx: float,
    cy: float,
    cz: float,
) -> tuple[float, int, float, float, float, bool]:
    """Nearest point to c on the n cached candidates: ``(d, triangle, q, inside the face)``.

    Starting from triangle ``seed`` (the last nearest, -1 for none) lets the bounding-box test skip
    most candidates: between ticks the nearest triangle rarely changes.
    """
    best = math.inf
    best_t = -1
    bx = by = bz = 0.0
    best_in = False
    if seed >= 0:
        best, bx, by, bz, best_in = closest_on_triangle(vertices, faces, seed, cx, cy, cz)
        best_t = seed
    for s in range(n):
        t = pool_k[s]
        if _box_distance2(boxes, t, cx, cy, cz) >= best:
            continue
        dd, qx, qy, qz, interior = closest_on_triangle(vertices, faces, t, cx, cy, cz)
        if dd < best:
            best, best_t, bx, by, bz, best_in = dd, t, qx, qy, qz, interior
    return math.sqrt(best), best_t, bx, by, bz, best_in


_MISS = (False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True)
def _lookup(
    k: int,
    cx: float,
    cy: float,
    cz: float,
    hx: float,
    hy: float,
    hz: float,
    vertices: Array,
    faces: IntArray,
    face_normals: Array,
    face_edges: IntArray,
    edge_pn: Array,
    vertex_pn: Array,
    pair_f: Array,
    pair_i: IntArray,
    pool: IntArray,
    j: int,
    grid: GridArgs,
) -> tuple[bool, float, float, float, float, float, float, float]:
    """Signed distance of pair k's centre c: ``(found, phi, q (3), n (3))``; found False is a miss.

    phi > 0 outside; n is the outward normal at q. ``h`` is the hint for a centre exactly on the
    surface (the remembered normal): the re-query goes off the surface along the face normal,
    the hint, then the axes. A centre that left its cache regathers it here when the distance at
    the pair's last evaluation bounds the new one (the distance is 1-Lipschitz); only a pair
    without one (never evaluated, or too many triangles in reach) is a miss for FCL. The nearest
    point on FCL's triangle is recomputed here, so both sources give identical numbers.
    """
    f = pair_f[k]
    if pair_i[k, PI_FCL_TRI] >= 0 and f[PF_FCL_C] == cx and f[PF_FCL_C + 1] == cy and f[PF_FCL_C + 2] == cz:
        t = pair_i[k, PI_FCL_TRI]
        if f[PF_FCL_D] == 0.0:
            d, qx, qy, qz, interior = 0.0, f[PF_FCL_Q], f[PF_FCL_Q + 1], f[PF_FCL_Q + 2], False
        else:
            dd, qx, qy, qz, interior = closest_on_triangle(vertices, faces, t, cx, cy, cz)
            d = math.sqrt(dd)
    else:
        n = pair_i[k, PI_CACHE_N]
        R = f[PF_CACHE_R]
        ex, ey, ez = cx - f[PF_CACHE_C], cy - f[PF_CACHE_C + 1], cz - f[PF_CACHE_C + 2]
        if n < 0 or ex * ex + ey * ey + ez * ez > R * R:
            ex, ey, ez = cx - f[PF_LAST], cy - f[PF_LAST + 1], cz - f[PF_LAST + 2]
            bound = f[PF_LAST_D] + math.sqrt(ex * ex + ey * ey + ez * ez)
            if not bound < math.inf:
                return _MISS
            R = max(CACHE_MIN, CACHE_FRAC * bound)
            n = refill(k, j, cx, cy, cz, bound, R, vertices, faces, pair_f, pair_i, pool, grid)
            if n < 0:
                return _MISS
        d, t, qx, qy, qz, interior = _scan(vertices, faces, grid[0], pool[k], n, pair_i[k, PI_NEAREST], cx, cy, cz)
        if t < 0:
            return _MISS
        pair_i[k, PI_NEAREST] = t
        if d < TOUCH:
            resolved = False
            for s in range(5):
                if s == 0:
                    ux, uy, uz = face_normals[t, 0], face_normals[t, 1], face_normals[t, 2]
                elif s == 1:
                    ux, uy, uz = hx, hy, hz
                else:
                    ux, uy, uz = 1.0 if s == 2 else 0.0, 1.0 if s == 3 else 0.0, 1.0 if s == 4 else 0.0
                nx, ny, nz = cx + NUDGE * ux, cy + NUDGE * uy, cz + NUDGE * uz
                ex, ey, ez = nx - f[PF_CACHE_C], ny - f[PF_CACHE_C + 1], nz - f[PF_CACHE_C + 2]
                if ex * ex + ey * ey + ez * ez > R * R:
                    return _MISS
                d2, t2, qx2, qy2, qz2, _ = _scan(vertices, faces, grid[0], pool[k], n, t, nx, ny, nz)
                if d2 >= TOUCH:
                    d, t, qx, qy, qz, interior = 0.0, t2, qx2, qy2, qz2, False
                    resolved = True
                    break
            if not resolved:
                return _MISS
    if d == 0.0:
        nx, ny, nz = pseudonormal(vertices, faces, face_normals, face_edges, edge_pn, vertex_pn, t, qx, qy, qz)
        return True, 0.0, qx, qy, qz, nx, ny, nz
    if interior:
        # c - q is along the face normal: take the direction u from it exactly, not from q.
        fx, fy, fz = face_normals[t, 0], face_normals[t, 1], face_normals[t, 2]
        s = (cx - qx) * fx + (cy - qy) * fy + (cz - qz) * fz
        ux, uy, uz = (fx, fy, fz) if s >= 0.0 else (-fx, -fy, -fz)
    else:
        # q is on an edge or a vertex: only the feature's pseudonormal gives the right side.
        ux, uy, uz = (cx - qx) / d, (cy - qy) / d, (cz - qz) / d
        fx, fy, fz = pseudonormal(vertices, faces, face_normals, face_edges, edge_pn, vertex_pn, t, qx, qy, qz)
        s = ux * fx + uy * fy + uz * fz
    if s >= 0.0:
        return True, d, qx, qy, qz, ux, uy, uz
    return True, -d, qx, qy, qz, -ux, -uy, -uz


@njit(cache=True)
def contact_step(
    T_w_MRF: Array,
    V_w_MRF: Array,
    has_twist: bool,
    centers_T: Array,
    radii: Array,
    T_MRF_T: Array,
    tool_p: Array,
    obj_p: Array,
    vertices: Array,
    faces: IntArray,
    face_normals: Array,
    face_edges: IntArray,
    edge_pn: Array,
    vertex_pn: Array,
    pair_f: Array,
    pair_i: IntArray,
    pool: IntArray,
    grid: GridArgs,
    obj_f: Array,
    near: IntArray,
    glob_f: Array,
    scratch: Array,
    todo: IntArray,
    misses: IntArray,
    out_w: Array,
    out_c: Array,
    out_ci: IntArray,
) -> tuple[int, int, int]:
    """One contact evaluation at ``T_w_MRF`` (4, 4), twist ``V_w_MRF`` (6,) if ``has_twist``.

    Returns ``(code, queries, n_miss)``. ``code >= 0`` is the number of contacts, written to
    ``out_c`` (rows, columns ``OC_*``) and ``out_ci`` (sphere, object), with the wrench in ``out_w`` (slots ``OW_*``) and the state
    updated. ``n_miss > 0``: the state is unchanged and ``misses[:n_miss]`` lists the pairs whose
    cache cannot answer (their centres are in ``scratch[k, 0:3]``). ``code < 0``: an ``ERR_*``.
    ``queries`` counts the pair distance evaluations. ``scratch`` (P, 10) and ``todo`` (P,)
    are work space.
    """
    n = radii.shape[0]
    m = obj_p.shape[0]
    for a in range(3):
        for b in range(4):
            if not math.isfinite(T_w_MRF[a, b]):
                return ERR_POSE, 0, 0
    vx = vy = vz = wx = wy = wz = 0.0
    if has_twist:
        vx, vy, vz, wx, wy, wz = V_w_MRF[0], V_w_MRF[1], V_w_MRF[2], V_w_MRF[3], V_w_MRF[4], V_w_MRF[5]
        if not math.isfinite(vx + vy + vz + wx + wy + wz):
            return ERR_TWIST, 0, 0
    # T_w_T = T_w_MRF T_MRF_T
    R = np.empty(9)
    for a in range(3):
        for b in range(3):
            R[3 * a + b] = T_w_MRF[a, 0] * T_MRF_T[0, b] + T_w_MRF[a, 1] * T_MRF_T[1, b] + T_w_MRF[a, 2] * T_MRF_T[2, b]
    tx = T_w_MRF[0, 0] * T_MRF_T[0, 3] + T_w_MRF[0, 1] * T_MRF_T[1, 3] + T_w_MRF[0, 2] * T_MRF_T[2, 3] + T_w_MRF[0, 3]
    ty = T_w_MRF[1, 0] * T_MRF_T[0, 3] + T_w_MRF[1, 1] * T_MRF_T[1, 3] + T_w_MRF[1, 2] * T_MRF_T[2, 3] + T_w_MRF[1, 3]
    tz = T_w_MRF[2, 0] * T_MRF_T[0, 3] + T_w_MRF[2, 1] * T_MRF_T[1, 3] + T_w_MRF[2, 2] * T_MRF_T[2, 3] + T_w_MRF[2, 3]
    ax, ay, az = tool_p[TP_C0], tool_p[TP_C0 + 1], tool_p[TP_C0 + 2]
    c0x = R[0] * ax + R[1] * ay + R[2] * az + tx
    c0y = R[3] * ax + R[4] * ay + R[5] * az + ty
    c0z = R[6] * ax + R[7] * ay + R[8] * az + tz

    # Objects within reach of the tool's bounding sphere (or holding a pop-through memory).
    dx, dy, dz = c0x - glob_f[GF_NEAR_C0], c0y - glob_f[GF_NEAR_C0 + 1], c0z - glob_f[GF_NEAR_C0 + 2]
    near_slack = glob_f[GF_NEAR_SLACK]
    if not (near_slack > 0.0 and dx * dx + dy * dy + dz * dz < near_slack * near_slack):
        near_slack = math.inf
        for j in range(m):
            g2 = 0.0
            for a, c in enumerate((c0x, c0y, c0z)):
                g = max(obj_p[j, OP_LO + a] - c, 0.0) + max(c - obj_p[j, OP_HI + a], 0.0)
                g2 += g * g
            dist = math.sqrt(g2) - tool_p[TP_REACH]
            near[j] = 1 if dist <= 0.0 else 0
            if dist > 0.0:
                near_slack = min(near_slack, dist)
            for i in range(n):
                if pair_i[j * n + i, PI_MEM]:
                    near[j] = 1
        glob_f[GF_NEAR_C0], glob_f[GF_NEAR_C0 + 1], glob_f[GF_NEAR_C0 + 2] = c0x, c0y, c0z
        glob_f[GF_NEAR_SLACK] = near_slack

    # Phase 1, no state change: the pairs to evaluate and their signed distances, or the misses.
    # scratch[k]: centre (3), phi, q (3), n (3).
    n_todo = 0
    n_miss = 0
    rho = tool_p[TP_RHO]
    for j in range(m):
        if not near[j]:
            continue
        of = obj_f[j]
        dx, dy, dz = c0x - of[OF_BASE_C0], c0y - of[OF_BASE_C0 + 1], c0z - of[OF_BASE_C0 + 2]
        cos_sum = 0.0  # trace(R_now R_base^T) = 1 + 2 cos(theta)
        for a in range(9):
            cos_sum += R[a] * of[OF_BASE_R + a]
        # Largest displacement of any sphere centre since the base pose: the translation of c0
        # plus the rotation about it (|(R - R0) y| = 2 sin(theta/2) |y|).
        moved = math.sqrt(dx * dx + dy * dy + dz * dz) + rho * math.sqrt(max(0.0, 3.0 - cos_sum))
        full = moved >= of[OF_SLACK]
        for i in range(n):
            k = j * n + i
            x, y, z = centers_T[i, 0], centers_T[i, 1], centers_T[i, 2]
            cx = R[0] * x + R[1] * y + R[2] * z + tx
            cy = R[3] * x + R[4] * y + R[5] * z + ty
            cz = R[6] * x + R[7] * y + R[8] * z + tz
            sc = scratch[k]
            sc[0], sc[1], sc[2] = cx, cy, cz
            if full:
                pf = pair_f[k]
                ex, ey, ez = cx - pf[PF_LAST], cy - pf[PF_LAST + 1], cz - pf[PF_LAST + 2]
                if math.sqrt(ex * ex + ey * ey + ez * ez) < pf[PF_SLACK]:
                    continue
            elif not pair_i[k, PI_HOT]:
                continue
            todo[n_todo] = k
            n_todo += 1
            hx, hy, hz = 0.0, 0.0, 1.0
            if pair_i[k, PI_MEM]:
                hx, hy, hz = pair_f[k, PF_MEM + 3], pair_f[k, PF_MEM + 4], pair_f[k, PF_MEM + 5]
            found, phi, qx, qy, qz, nx, ny, nz = _lookup(
                k, cx, cy, cz, hx, hy, hz, vertices, faces, face_normals, face_edges, edge_pn, vertex_pn,
                pair_f, pair_i, pool, j, grid,
            )  # fmt: skip
            if not found:
                misses[n_miss] = k
                n_miss += 1
                continue
            sc[3], sc[4], sc[5], sc[6], sc[7], sc[8], sc[9] = phi, qx, qy, qz, nx, ny, nz
    if n_miss > 0:
        return 0, n_todo, n_miss

    # Phase 2: memory, slack, forces; then each fully checked object's new base pose.
    pmx, pmy, pmz = T_w_MRF[0, 3], T_w_MRF[1, 3], T_w_MRF[2, 3]
    Fx = Fy = Fz = Mx = My = Mz = 0.0  # force on the tool and moment about the {MRF} origin, {w}
    n_c = 0
    margin = tool_p[TP_MARGIN]
    for s in range(n_todo):
        k = todo[s]
        j, i = k // n, k % n
        sc = scratch[k]
        pf = pair_f[k]
        cx, cy, cz, phi = sc[0], sc[1], sc[2], sc[3]
        qx, qy, qz, nx, ny, nz = sc[4], sc[5], sc[6], sc[7], sc[8], sc[9]
        pf[PF_LAST], pf[PF_LAST + 1], pf[PF_LAST + 2] = cx, cy, cz
        pf[PF_LAST_D] = abs(phi)
        mem = pair_i[k, PI_MEM] == 1
        in_memory = False
        if mem and nx * pf[PF_MEM + 3] + ny * pf[PF_MEM + 4] + nz * pf[PF_MEM + 5] < 0.0:
            s0 = (cx - pf[PF_MEM]) * pf[PF_MEM + 3] + (cy - pf[PF_MEM + 1]) * pf[PF_MEM + 4]
            s0 += (cz - pf[PF_MEM + 2]) * pf[PF_MEM + 5]
            if s0 < 0.0:
                # Normal flipped with the centre behind the remembered surface: it crossed the
                # middle of a thin part (pop-through). A flip in front of it is a real new contact.
                qx, qy, qz = pf[PF_MEM], pf[PF_MEM + 1], pf[PF_MEM + 2]
                nx, ny, nz = pf[PF_MEM + 3], pf[PF_MEM + 4], pf[PF_MEM + 5]
                phi = s0
                in_memory = True
        depth = radii[i] - phi
        if depth <= 0.0:
            pair_i[k, PI_MEM] = 0
            gap = phi - radii[i] - margin
            pf[PF_SLACK] = gap if gap > 0.0 else -1.0
            continue
        if not in_memory:
            pf[PF_MEM], pf[PF_MEM + 1], pf[PF_MEM + 2] = qx, qy, qz
            pf[PF_MEM + 3], pf[PF_MEM + 4], pf[PF_MEM + 5] = nx, ny, nz
            pair_i[k, PI_MEM] = 1
        pf[PF_SLACK] = -1.0
        fn = obj_p[j, OP_K] * depth
        fx = fy = fz = 0.0
        if has_twist:
            rx, ry, rz = cx - pmx, cy - pmy, cz - pmz
            ux = vx + wy * rz - wz * ry
            uy = vy + wz * rx - wx * rz
            uz = vz + wx * ry - wy * rx
            un = ux * nx + uy * ny + uz * nz
            fn = max(0.0, fn - obj_p[j, OP_B] * un)
            mu = obj_p[j, OP_MU]
            if mu > 0.0:
                ex, ey, ez = ux - un * nx, uy - un * ny, uz - un * nz
                scale = -mu * fn / max(math.sqrt(ex * ex + ey * ey + ez * ez), _V_SLIP)
                fx, fy, fz = scale * ex, scale * ey, scale * ez
        fx += fn * nx
        fy += fn * ny
        fz += fn * nz
        back = radii[i] - depth  # contact point on the surface: centre minus (r - depth) along n
        px, py, pz = cx - back * nx, cy - back * ny, cz - back * nz
        rx, ry, rz = px - pmx, py - pmy, pz - pmz
        Fx += fx
        Fy += fy
        Fz += fz
        Mx += ry * fz - rz * fy
        My += rz * fx - rx * fz
        Mz += rx * fy - ry * fx
        oc = out_c[n_c]
        oc[OC_P], oc[OC_P + 1], oc[OC_P + 2] = px, py, pz
        oc[OC_N], oc[OC_N + 1], oc[OC_N + 2] = nx, ny, nz
        oc[OC_DEPTH] = depth
        out_ci[n_c, 0], out_ci[n_c, 1] = i, j
        n_c += 1
    for j in range(m):
        if not near[j]:
            continue
        of = obj_f[j]
        dx, dy, dz = c0x - of[OF_BASE_C0], c0y - of[OF_BASE_C0 + 1], c0z - of[OF_BASE_C0 + 2]
        cos_sum = 0.0
        for a in range(9):
            cos_sum += R[a] * of[OF_BASE_R + a]
        if math.sqrt(dx * dx + dy * dy + dz * dz) + rho * math.sqrt(max(0.0, 3.0 - cos_sum)) < of[OF_SLACK]:
            continue
        # Rebase: the spheres in contact (slack < 0) become hot; the others may move their remaining
        # slack from here before the next full check.
        remaining = math.inf
        for i in range(n):
            k = j * n + i
            pf = pair_f[k]
            hot = pf[PF_SLACK] < 0.0
            pair_i[k, PI_HOT] = 1 if hot else 0
            if not hot:
                ex, ey, ez = (
                    scratch[k, 0] - pf[PF_LAST],
                    scratch[k, 1] - pf[PF_LAST + 1],
                    scratch[k, 2] - pf[PF_LAST + 2],
                )
                remaining = min(remaining, pf[PF_SLACK] - math.sqrt(ex * ex + ey * ey + ez * ez))
        of[OF_SLACK] = remaining
        of[OF_BASE_C0], of[OF_BASE_C0 + 1], of[OF_BASE_C0 + 2] = c0x, c0y, c0z
        for a in range(9):
            of[OF_BASE_R + a] = R[a]
    if not math.isfinite(Fx + Fy + Fz + Mx + My + Mz):
        return ERR_WRENCH, n_todo, 0
    # {w} -> {MRF} (transpose of R_w_MRF), then Eq 6 backwards for the moment about {S}.
    for a in range(3):
        out_w[OW_MRF + a] = T_w_MRF[0, a] * Fx + T_w_MRF[1, a] * Fy + T_w_MRF[2, a] * Fz
        out_w[OW_MRF + 3 + a] = T_w_MRF[0, a] * Mx + T_w_MRF[1, a] * My + T_w_MRF[2, a] * Mz
    fmx, fmy, fmz = out_w[OW_MRF], out_w[OW_MRF + 1], out_w[OW_MRF + 2]
    sx, sy, sz = tool_p[TP_P_MRF_S], tool_p[TP_P_MRF_S + 1], tool_p[TP_P_MRF_S + 2]
    ox = out_w[OW_MRF + 3] - (sy * fmz - sz * fmy)
    oy = out_w[OW_MRF + 4] - (sz * fmx - sx * fmz)
    oz = out_w[OW_MRF + 5] - (sx * fmy - sy * fmx)
    b = TP_R_MRF_S
    for a in range(3):
        out_w[OW_S + a] = tool_p[b + a] * fmx + tool_p[b + 3 + a] * fmy + tool_p[b + 6 + a] * fmz
        out_w[OW_S + 3 + a] = tool_p[b + a] * ox + tool_p[b + 3 + a] * oy + tool_p[b + 6 + a] * oz
    out_w[OW_F], out_w[OW_F + 1], out_w[OW_F + 2] = Fx, Fy, Fz
    return n_c, n_todo, 0
