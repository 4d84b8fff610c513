"""Uniform grid of triangle bounding boxes per object, and the range query that fills a pair's
candidate cache from it.

Object j's grid has origin ``objs[j].grid_origin``, cell size ``grid_h`` (m) and ``grid_dims``
cells per axis; cell (x, y, z) has key ``grid_base + (x ny + y) nz + z``. ``cells`` lists the
occupied keys in increasing order, each with the start of its triangles in ``lists``. The
object's column table, ``lists[grid_cols + x ny + y]``, is the row of ``cells`` of the first
occupied cell of column (x, y) or beyond: a gather finds a column's cells without a search.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.world.contact.bundle import tick_kernel
from app.world.contact.geometry import box_distance2, closest_on_triangle, doze, may_hold_minimum
from app.world.contact.layout import Record, Records

# A gather covering more grid cells than this fails (the sphere is far larger than the cells).
MAX_CELLS = 1 << 16


@tick_kernel
def cell_index(x: float, origin: float, h: float, n: int) -> int:
    """Grid cell index of coordinate x, clamped to [0, n - 1] (monotone in x)."""
    # Clamp before the integer conversion: a far coordinate must not overflow it.
    return math.floor(min(max((x - origin) / h, 0.0), n - 1.0))


@njit(cache=True, inline="always")
def _touches(verts: Records, tris: Records, t: int, o: Record, x: int, y: int, z: int) -> bool:
    """Whether triangle t may meet grid cell (x, y, z) of object o: it comes within the cell's
    circumscribed sphere (conservative: a long sliver's bounding box covers many cells it misses)."""
    h = o.grid_h
    g = o.grid_origin
    d2 = closest_on_triangle(verts, tris, t, g[0] + (x + 0.5) * h, g[1] + (y + 0.5) * h, g[2] + (z + 0.5) * h)[0]
    return d2 <= 0.75 * h * h * (1.0 + 1e-9)


@njit(cache=True)
def grid_entries(verts: Records, tris: Records, face0: np.ndarray, objs: Records) -> tuple:
    """(cell key, triangle) for every grid cell each triangle may meet, as two int arrays."""
    m = face0.shape[0] - 1
    nf = tris.shape[0]
    counts = np.zeros(nf, dtype=np.int64)
    lo_c = np.empty((nf, 3), dtype=np.int64)
    hi_c = np.empty((nf, 3), dtype=np.int64)
    for j in range(m):
        o = objs[j]
        for t in range(face0[j], face0[j + 1]):
            for a in range(3):
                lo_c[t, a] = cell_index(tris[t].box[a], o.grid_origin[a], o.grid_h, o.grid_dims[a])
                hi_c[t, a] = cell_index(tris[t].box[3 + a], o.grid_origin[a], o.grid_h, o.grid_dims[a])
            for x in range(lo_c[t, 0], hi_c[t, 0] + 1):
                for y in range(lo_c[t, 1], hi_c[t, 1] + 1):
                    for z in range(lo_c[t, 2], hi_c[t, 2] + 1):
                        counts[t] += _touches(verts, tris, t, o, x, y, z)
    keys = np.empty(counts.sum(), dtype=np.int64)
    out = np.empty(keys.shape[0], dtype=np.int64)
    e = 0
    for j in range(m):
        o = objs[j]
        ny, nz, base = o.grid_dims[1], o.grid_dims[2], o.grid_base
        for t in range(face0[j], face0[j + 1]):
            for x in range(lo_c[t, 0], hi_c[t, 0] + 1):
                for y in range(lo_c[t, 1], hi_c[t, 1] + 1):
                    for z in range(lo_c[t, 2], hi_c[t, 2] + 1):
                        if _touches(verts, tris, t, o, x, y, z):
                            keys[e] = base + (x * ny + y) * nz + z
                            out[e] = t
                            e += 1
    return keys, out


@njit(cache=True)
def crease_lists(tris: Records, edges: Records, v_start: np.ndarray, v_edges: np.ndarray, creases: np.ndarray) -> None:
    """Fill ``creases`` (F, MAX_CREASES) with each triangle's gentle concave edges (``tan`` > 0)
    that have an end at one of its vertices: its own first, then the others, -1 after the last.
    Vertex v's gentle edges are ``v_edges[v_start[v]:v_start[v + 1]]``."""
    cap = creases.shape[1]
    for t in range(tris.shape[0]):
        n = 0
        for k in range(3):
            e = tris[t].e[k]
            if edges[e].tan > 0.0 and n < cap:
                creases[t, n] = e
                n += 1
        for k in range(3):
            v = tris[t].v[k]
            for s in range(v_start[v], v_start[v + 1]):
                e = v_edges[s]
                seen = False
                for m in range(n):
                    seen = seen or creases[t, m] == e
                if not seen and n < cap:
                    creases[t, n] = e
                    n += 1
        for m in range(n, cap):
            creases[t, m] = -1


@tick_kernel
def gather(
    obj: Record,
    cx: float,
    cy: float,
    cz: float,
    reach: float,
    R: float,
    cap: float,
    retry: float,
    verts: Records,
    tris: Records,
    cells: Records,
    lists: np.ndarray,
    stamp: np.ndarray,
    serial: int,
    out: np.ndarray,
) -> int:
    """Write into ``out`` the triangles of object ``obj`` (a record) within ``reach`` of c that
    may hold a local minimum of the distance for a centre within R of c
    (:func:`~app.world.contact.geometry.may_hold_minimum`, unless ``obj.prune`` is 0); return
    their count. On a finely tessellated surface that leaves a few triangles of the many under
    the sphere. Each gets its dormancy from c (:func:`~app.world.contact.geometry.doze`): how far
    the centre may move before it can hold a minimum within ``cap`` (<= reach - R), or ``retry``.

    ``lists`` holds the grid's triangles (``cells.start``) and the faces around each vertex.
    ``stamp`` (F + V,) marks the triangles this gather (number ``serial``) has seen: a long
    triangle spans many cells, and one load per visit is far cheaper than deciding which cell
    owns it; its last V entries memoise the pruning test's vertex cones.
    Returns -1 if they do not fit in ``out`` or the search box covers more than ``MAX_CELLS`` cells.
    """
    h = obj.grid_h
    g, dims = obj.grid_origin, obj.grid_dims
    # The cells the search box covers, from lo to hi along each axis.
    lo = (
        cell_index(cx - reach, g[0], h, dims[0]),
        cell_index(cy - reach, g[1], h, dims[1]),
        cell_index(cz - reach, g[2], h, dims[2]),
    )
    hi = (
        cell_index(cx + reach, g[0], h, dims[0]),
        cell_index(cy + reach, g[1], h, dims[1]),
        cell_index(cz + reach, g[2], h, dims[2]),
    )
    if (hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1) > MAX_CELLS:
        return -1
    ny, nz, base, cols = dims[1], dims[2], obj.grid_base, obj.grid_cols
    cones = stamp[tris.shape[0] :]
    n = 0
    n_keys = cells.shape[0] - 1  # the last row is a sentinel
    reach2 = reach * reach
    for x in range(lo[0], hi[0] + 1):
        for y in range(lo[1], hi[1] + 1):
            # The column's cells have consecutive keys, from its first occupied one (the table).
            first = base + (x * ny + y) * nz + lo[2]
            last = first + hi[2] - lo[2]
            s = lists[cols + x * ny + y]
            while s < n_keys and cells[s].key < first:
                s += 1
            while s < n_keys and cells[s].key <= last:
                for e in range(cells[s].start, cells[s + 1].start):
                    t = lists[e]
                    if stamp[t] == serial:
                        continue
                    stamp[t] = serial
                    if box_distance2(tris[t].box, cx, cy, cz) > reach2:
                        continue
                    # The exact distance first: the pruning test walks the faces around each
                    # vertex, hundreds at the centre of a fan (a hole's bottom).
                    d2 = closest_on_triangle(verts, tris, t, cx, cy, cz)[0]
                    if d2 > reach2:
                        continue
                    if obj.prune and not may_hold_minimum(verts, tris, lists, t, cx, cy, cz, R, cones, serial):
                        continue
                    if n == out.shape[0]:
                        return -1
                    cand = out[n]
                    cand.t = t
                    if obj.prune:
                        doze(cand, verts, tris, lists, cx, cy, cz, math.sqrt(d2) - cap, retry)
                    else:
                        cand.mu = -math.inf  # every candidate scanned every time
                    n += 1
                s += 1
    return n
