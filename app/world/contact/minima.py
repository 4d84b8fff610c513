"""Per (sphere, object) pair: the candidate cache and the local minima of the distance within reach.

A pair's cache (a row of ``pool``) holds every triangle within ``r + 2 R`` of the centre it was
gathered at that may hold a local minimum for a centre within R of there
(:func:`~app.world.contact.geometry.may_hold_minimum`); while the centre stays within R, every
local minimum of the distance within ``r + R`` lies on a cached triangle.
:func:`local_minima` scans the cache and keeps, per triangle, its nearest point q if q is a local
minimum of the distance over the (cut) surface:

- q inside the face: always;
- q on an edge: if the face across it (none on a cut) is not strictly nearer; reported by the
  lower-numbered face only;
- q at a vertex: if no face around it is strictly nearer; reported by its first face only.

Each minimum is signed by its feature's pseudonormal (phi > 0 outside) and weighted: a minimum
inside a face near a gentle concave crease gets ``min(1, dist(q, crease) / (d tan theta))``. At
such a crease two faces both hold a minimum in a band ``d tan theta`` wide; across the band the
two weights go linearly from (1, 0) to (0, 1), so the pair of them is one continuous contact
instead of a doubled one.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.world.contact.bundle import tick_kernel
from app.world.contact.geometry import (
    closest_on_triangle,
    dormancy,
    feature_normal,
    segment_offset,
    settle,
    spread_retry,
)
from app.world.contact.grid import gather
from app.world.contact.layout import (
    FEAT_EDGE,
    FEAT_FACE,
    FEAT_VERTEX,
    MAX_CREASES,
    MAX_EDGE_MINIMA,
    MAX_PER_PAIR,
    Record,
    Records,
)

# Below this distance (m) the direction c - q is meaningless: the centre is on the surface and
# the feature's pseudonormal gives the direction.
TOUCH = 1e-9
# Distance (m) under which two nearest points are one (the same point computed from two faces).
_SAME_POINT = 1e-10
# Rounding allowance (m) of the lower bounds of a triangle's distance (from its plane and edge
# lines) against the nearest point computed from the vertices (1e-16 relative at coordinates
# under 1 km): a candidate is skipped only if it certainly is no nearer.
_PLANE_SLACK = 1e-12
# Edge or vertex minima along one crease with normals closer than the cut angle are one contact
# (cos of 30 degrees, app.world.collision.CUT_ANGLE_DEG).
_PARTNER_COS = 0.8660254037844387
# Bits of ``TRIANGLE.own`` for edge k and its two ends (vertex k and k + 1 mod 3).
_EDGE_AND_ENDS = (0b011001, 0b110010, 0b101100)
# A pair's cache stays valid while its centre moves less than CACHE_FRAC * r from where it was
# gathered: larger means fewer gathers on the move, each of more triangles (most of them dormant
# in a scan, so a scan costs little more).
CACHE_FRAC = 0.075
# A scan finds the distance to the mesh up to (1 + NEAR_FRAC) r (the culling bound of a pair out
# of contact: it need not be checked until it has moved NEAR_FRAC r).
NEAR_FRAC = 0.05
# A candidate that may hold a minimum (or would wake within this distance) is asked its dormancy
# bound again after its centre has moved RETRY_FRAC r (spread by triangle): 19 to 31 um for a
# 6 mm peg, less than a hand's step per 1 kHz tick (~30 um on the benchmark's walk), so the
# candidates awake on a hole's wall are asked on nearly every tick, a steady cost, rather than
# most of them at once on a longer step (a quarter of NEAR_FRAC: peg_in_hole moving p99 1 us
# higher, median 0.3 us lower).
RETRY_FRAC = 0.1 * NEAR_FRAC


@njit(cache=True, inline="always")
def _holds(
    verts: Records, tris: Records, f: int, qx: float, qy: float, qz: float, cx: float, cy: float, cz: float
) -> bool:
    """True if face f's nearest point to c is q too (so f is not nearer): c does not project
    into f, and f's nearest feature passes through q (within rounding)."""
    _, fx, fy, fz, feat = closest_on_triangle(verts, tris, f, cx, cy, cz)
    return feat != FEAT_FACE and (fx - qx) ** 2 + (fy - qy) ** 2 + (fz - qz) ** 2 <= _SAME_POINT * _SAME_POINT


@njit(cache=True, inline="always")
def _is_local_min(
    verts: Records,
    tris: Records,
    edges: Records,
    vertex_faces: np.ndarray,
    t: int,
    feat: int,
    qx: float,
    qy: float,
    qz: float,
    cx: float,
    cy: float,
    cz: float,
) -> bool:
    """Whether triangle t's nearest point q (on feature ``feat``) is a local minimum of the
    distance over the surface that t reports (the owner of a shared feature).

    The tests compare features, not distances: off a shared edge by delta, the distances differ
    by only delta^2 / 2 d, which no tolerance on them could resolve.
    """
    if feat == FEAT_FACE:
        return True
    if feat >= FEAT_EDGE:
        fs = edges[tris[t].e[feat - FEAT_EDGE]].faces
        other = fs[1] if fs[0] == t else fs[0]
        if other < 0:
            return True
        return other > t and _holds(verts, tris, other, qx, qy, qz, cx, cy, cz)
    v = verts[tris[t].v[feat - 1]]
    if vertex_faces[v.f0] != t:
        return False
    for s in range(v.f0 + 1, v.f1):  # noqa: SIM110 (no generators in numba)
        if not _holds(verts, tris, vertex_faces[s], qx, qy, qz, cx, cy, cz):
            return False
    return True


@njit(cache=True, inline="always")
def _crease_weight(
    verts: Records, tris: Records, edges: Records, t: int, d: float, qx: float, qy: float, qz: float
) -> tuple[float, float, float, float]:
    """Weight of a minimum inside face t at distance d (in front): how far q is across the band
    of each gentle concave crease at t's vertices (1 outside every band), and its gradient with
    respect to the centre (1/m, {w}): ``(w, gx, gy, gz)``.

    The creases are every gentle concave edge from one of t's vertices (``tri.creases``), not only
    t's own edges: the other half of a quad split along a diagonal touches its neighbour's crease
    at a vertex, and a minimum crossing the diagonal must keep its weight (a jump in it would make
    the field create energy around a loop). In a band ``w = x^2 (3 - 2 x)`` with
    ``x = s / (d tan)``, s the distance of q from the crease edge: the two sides' weights still
    add up to one across a band (``w(x) + w(1 - x) = 1``), and w is flat at both edges of the
    band, so the contact's force (which has a ``grad w`` term,
    :func:`~app.world.contact.step._pair_contacts`) is continuous where a minimum enters or leaves.
    q moves with the centre within the face's plane and d along its normal n, so
    ``grad x = P u / (d tan) - x n / d``, u the unit vector from the edge to q and P the projection
    on the plane.
    """
    w, gx, gy, gz = 1.0, 0.0, 0.0, 0.0
    tri = tris[t]
    n = tri.n
    for m in range(MAX_CREASES):
        e = tri.creases[m]
        if e < 0:
            break
        edge = edges[e]
        band = d * edge.tan
        ox, oy, oz = segment_offset(verts, edge.v[0], edge.v[1], qx, qy, qz)
        dist2 = ox * ox + oy * oy + oz * oz
        if dist2 >= band * band:
            continue
        dist = math.sqrt(dist2)
        x = dist / band
        if x * x * (3.0 - 2.0 * x) < w:
            w = x * x * (3.0 - 2.0 * x)
            gx = gy = gz = 0.0  # on the crease (x = 0) w is flat
            if dist > TOUCH:
                ux, uy, uz = ox / dist, oy / dist, oz / dist
                un = ux * n[0] + uy * n[1] + uz * n[2]
                slope = 6.0 * x * (1.0 - x)  # dw/dx
                gx = slope * ((ux - un * n[0]) / band - x * n[0] / d)
                gy = slope * ((uy - un * n[1]) / band - x * n[1] / d)
                gz = slope * ((uz - un * n[2]) / band - x * n[2] / d)
    return w, gx, gy, gz


@njit(cache=True, inline="always")
def _farthest(phi: np.ndarray) -> int:
    """Slot of the largest ``|phi|`` of a full set of minima, (MAX_PER_PAIR,)."""
    slot = 0
    for e in range(1, MAX_PER_PAIR):
        if abs(phi[e]) > abs(phi[slot]):
            slot = e
    return slot


@njit(cache=True, inline="always")
def _worst(phi: np.ndarray, n_min: int) -> float:
    """The largest ``|phi|`` of ``n_min`` kept minima if the set is full, else inf."""
    return abs(phi[_farthest(phi)]) if n_min == MAX_PER_PAIR else math.inf


@njit(cache=True, inline="always")
def _keep(
    pair: Record,
    n_min: int,
    qx: float,
    qy: float,
    qz: float,
    nx: float,
    ny: float,
    nz: float,
    phi: float,
    t: int,
    feat: int,
) -> int:
    """Keep a minimum among the pair's ``n_min`` (the nearest MAX_PER_PAIR); returns the new count.
    The same minimum reported twice (rounding at a shared edge) counts once."""
    for e in range(n_min):
        mq, mn = pair.min_q[e], pair.min_n[e]
        if (qx - mq[0]) ** 2 + (qy - mq[1]) ** 2 + (qz - mq[2]) ** 2 <= _SAME_POINT**2 and (
            nx * mn[0] + ny * mn[1] + nz * mn[2] > 0.999
        ):
            return n_min
    slot = n_min
    if n_min == MAX_PER_PAIR:
        # Full: replace the farthest if this one is nearer.
        slot = _farthest(pair.min_phi)
        if abs(pair.min_phi[slot]) <= abs(phi):
            return n_min
    else:
        n_min += 1
    pair.min_q[slot, 0], pair.min_q[slot, 1], pair.min_q[slot, 2] = qx, qy, qz
    pair.min_n[slot, 0], pair.min_n[slot, 1], pair.min_n[slot, 2] = nx, ny, nz
    pair.min_phi[slot] = phi
    pair.min_t[slot] = t
    pair.min_f[slot] = feat
    return n_min


@njit(cache=True, inline="always")
def _collect(
    tool: Record,
    verts: Records,
    tris: Records,
    n_em: int,
    qx: float,
    qy: float,
    qz: float,
    nx: float,
    ny: float,
    nz: float,
    phi: float,
    t: int,
    feat: int,
) -> int:
    """Add an edge or vertex minimum to the tool's scratch (``em_*``, nearest first through
    ``em_order``; when full, it replaces the farthest if nearer); returns the new count."""
    d = abs(phi)
    order = tool.em_order
    if n_em == MAX_EDGE_MINIMA:
        slot = order[n_em - 1]
        if abs(tool.em_phi[slot]) <= d:
            return n_em
        n_em -= 1
    else:
        slot = n_em
    # Insert by distance (few at a time: they arrive as the scan finds them).
    a = n_em
    while a > 0 and abs(tool.em_phi[order[a - 1]]) > d:
        order[a] = order[a - 1]
        a -= 1
    order[a] = slot
    tool.em_q[slot, 0], tool.em_q[slot, 1], tool.em_q[slot, 2] = qx, qy, qz
    tool.em_n[slot, 0], tool.em_n[slot, 1], tool.em_n[slot, 2] = nx, ny, nz
    tool.em_phi[slot] = phi
    tool.em_t[slot] = t
    tool.em_f[slot] = feat
    v = tris[t].v
    if feat >= FEAT_EDGE:
        k = feat - FEAT_EDGE
        tool.em_ends[slot, 0], tool.em_ends[slot, 1] = verts[v[k]].weld, verts[v[(k + 1) % 3]].weld
    else:
        w = verts[v[feat - FEAT_VERTEX]].weld
        tool.em_ends[slot, 0], tool.em_ends[slot, 1] = w, w
    return n_em + 1


@njit(cache=True, inline="always")
def share_vertex(tris: Records, a: int, b: int) -> bool:
    """Whether triangles a and b share a vertex (never across a cut: each side has its own copies)."""
    va, vb = tris[a].v, tris[b].v
    for x in range(3):
        for y in range(3):
            if va[x] == vb[y]:
                return True
    return False


@tick_kernel
def ensure_cache(
    pair: Record,
    k: int,
    obj: Record,
    r: float,
    verts: Records,
    tris: Records,
    cells: Records,
    lists: np.ndarray,
    stamp: np.ndarray,
    tool: Record,
    pool: np.ndarray,
) -> int:
    """Refill pair k's cache at its current centre unless that is within the cache's radius.

    Returns 1 if it gathered, 0 if the cache was valid, -1 if the candidates overflowed.
    """
    c = pair.c
    R = CACHE_FRAC * r
    if pair.cache_n >= 0:
        ex, ey, ez = c[0] - pair.cache_c[0], c[1] - pair.cache_c[1], c[2] - pair.cache_c[2]
        if ex * ex + ey * ey + ez * ez <= R * R:
            return 0
    tool.serial += 1
    reach, cap, retry = r + 2.0 * R, r * (1.0 + NEAR_FRAC), RETRY_FRAC * r
    n = gather(obj, c[0], c[1], c[2], reach, R, cap, retry, verts, tris, cells, lists, stamp, tool.serial, pool[k])
    pair.cache_n = n
    for a in range(3):
        pair.cache_c[a] = c[a]
    return 1 if n >= 0 else -1


@tick_kernel
def local_minima(
    pair: Record,
    tool: Record,
    pool_k: np.ndarray,
    r: float,
    verts: Records,
    tris: Records,
    edges: Records,
    lists: np.ndarray,
) -> float:
    """Fill ``pair.min_*`` with the local minima of the distance within r of ``pair.c`` (the
    nearest :data:`MAX_PER_PAIR`); return a lower bound (m) of the distance to the mesh. ``tool``
    lends its scratch (``em_*``) to the edge and vertex minima."""
    cx, cy, cz = pair.c[0], pair.c[1], pair.c[2]
    r2 = r * r
    n_min = 0
    # The nearest point is a local minimum: within r + R, it is on a cached triangle (the cache
    # covers r + 2 R around its centre), and within the cap, on one awake; otherwise it is
    # farther than the cap.
    cap = r * (1.0 + NEAR_FRAC)
    nearest2 = cap * cap
    # Start from last time's nearest triangle: with the distance to the mesh known from the
    # outset, the lower bounds below skip nearly every other triangle of a pair out of contact.
    near_t = pair.near_t
    if near_t >= 0:
        nearest2 = min(nearest2, closest_on_triangle(verts, tris, near_t, cx, cy, cz)[0])
    # |phi| of the farthest face minimum kept once MAX_PER_PAIR are kept (inf before): a candidate
    # no nearer changes nothing (it would not be kept, nor, along a crease, lie between two nearer
    # minima), so it is skipped unprocessed. On a finely tessellated concave surface (a hole's
    # wall) every facet under the sphere holds a minimum, and most end at this test or at the
    # plane test below.
    worst = math.inf
    # Least lower bound of the distance of the candidates skipped as no nearer than r or than
    # ``worst``: they cannot hold a kept minimum, so their exact distance is not worth a
    # nearest-point search (above a hole's rim, every rim triangle is a little beyond r), and
    # the bound returned is the lesser of this and the nearest distance found.
    floor2 = math.inf
    n_em = 0  # edge and vertex minima collected in the tool's scratch, merged after the scan
    # A candidate is dormant while the centre is within ``mu`` of its ``ref``: it then holds no
    # local minimum within the cap (nor is nearer than that), so skipping it changes nothing;
    # the order of the others is kept. A candidate found idle after it woke (or after the centre
    # moved ``-mu`` since it was last asked) dozes off again from here.
    retry = RETRY_FRAC * r
    for s in range(pair.cache_n):
        cand = pool_k[s]
        mu = cand.mu
        ex, ey, ez = cx - cand.ref[0], cy - cand.ref[1], cz - cand.ref[2]
        far2 = ex * ex + ey * ey + ez * ez
        if mu > 0.0 and far2 < mu * mu:
            continue
        wake = far2 >= mu * mu
        t = cand.t
        tri = tris[t]
        # The distance to the face's plane bounds the distance to the triangle from below, and
        # is three products away (the slack covers rounding, so a skip is never a change).
        plane = abs(cx * tri.n[0] + cy * tri.n[1] + cz * tri.n[2] - tri.off) - _PLANE_SLACK
        if plane > 0.0 and (plane >= worst or plane * plane >= r2):
            floor2 = min(floor2, plane * plane)
            if wake:
                # This test is cheaper than a dormancy bound: keep taking it until ``spread``.
                cand.mu = -spread_retry(t, retry)
                cand.ref[0], cand.ref[1], cand.ref[2] = cx, cy, cz
            continue
        region = spread = 0.0  # used only if it woke
        if wake:
            # Its dormancy bound next (with the plane distance for a gap), cheaper than the tests
            # below: on a hole's wall or rim a step of the centre wakes dozens of candidates at
            # once, and many go straight back to sleep. Otherwise the bound stands by for the
            # tests' verdict (``settle``).
            spread = spread_retry(t, retry)
            region = dormancy(verts, tris, lists, t, cx, cy, cz, plane - cap, spread)
            if region > spread:
                cand.mu = region
                cand.ref[0], cand.ref[1], cand.ref[2] = cx, cy, cz
                continue
        box = tri.box
        gx = max(box[0] - cx, 0.0, cx - box[3])  # the gaps to the triangle's box along each axis
        gy = max(box[1] - cy, 0.0, cy - box[4])
        gz = max(box[2] - cz, 0.0, cz - box[5])
        box2 = gx * gx + gy * gy + gz * gz
        if box2 >= r2:
            floor2 = min(floor2, box2)
            if wake:
                settle(cand, region, math.sqrt(box2) - cap, spread, cx, cy, cz)
            continue
        # Where c projects, from the inward edge normals: inside the face, the nearest point is
        # the projection. Beyond exactly one edge and abreast of it, the nearest point is on that
        # edge, and if c also projects into the face across it that face is nearer right there:
        # no minimum on t. Either way no full nearest-point search.
        outside = 0
        reject = False
        beyond = 0.0  # how far c is beyond the farthest edge line, in the face's plane
        near = 0  # the edges c may be beyond and their ends (bits as ``tri.own``)
        for k in range(3):
            a = verts[tri.v[k]].p
            ex, ey, ez = cx - a[0], cy - a[1], cz - a[2]
            m = tri.m[k]
            inward = ex * m[0] + ey * m[1] + ez * m[2]
            if inward < _PLANE_SLACK:
                near |= _EDGE_AND_ENDS[k]
            if inward < 0.0:
                outside += 1
                beyond = max(beyond, -inward)
                ma = tri.m_adj[k]
                if ex * ma[0] + ey * ma[1] + ez * ma[2] > 0.0:
                    b = verts[tri.v[(k + 1) % 3]].p
                    bx, by, bz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
                    u = ex * bx + ey * by + ez * bz
                    reject = 0.0 < u < bx * bx + by * by + bz * bz
        # With c clearly beyond an edge line, the nearest point is on an edge c is beyond or at an
        # end of one: if t reports none of those features, it holds no minimum (on a hole's rim,
        # most wall facets and top triangles).
        if (outside == 1 and reject) or (beyond > _PLANE_SLACK and tri.own & near == 0):
            if wake:
                settle(cand, region, plane - cap, spread, cx, cy, cz)
            continue
        if outside > 0:
            # The distance is at least the hypotenuse of the plane distance and of a bound on
            # the offset within the plane: ``beyond`` (the triangle is on the inner side of each
            # edge line), or an axis's box gap less what the plane-normal part can take of it
            # (above a vertical wall's top: the height). Above a hole's rim, the wall facets
            # below are thus skipped without a nearest-point search.
            up = plane + 2.0 * _PLANE_SLACK  # at least the plane distance
            n = tri.n
            aside = max(gx - up * abs(n[0]), gy - up * abs(n[1]), gz - up * abs(n[2]), beyond) - _PLANE_SLACK
            bound2 = max(plane, 0.0) ** 2 + (aside * aside if aside > 0.0 else 0.0)
            if bound2 >= r2 or math.sqrt(bound2) >= worst:
                floor2 = min(floor2, bound2)
                if wake:
                    settle(cand, region, math.sqrt(bound2) - cap, spread, cx, cy, cz)
                continue
        if outside == 0:
            a = verts[tri.v[0]].p
            sd = (cx - a[0]) * tri.n[0] + (cy - a[1]) * tri.n[1] + (cz - a[2]) * tri.n[2]
            d2, qx, qy, qz, feat = sd * sd, cx - sd * tri.n[0], cy - sd * tri.n[1], cz - sd * tri.n[2], FEAT_FACE
        else:
            d2, qx, qy, qz, feat = closest_on_triangle(verts, tris, t, cx, cy, cz)
        if d2 < nearest2:
            nearest2, near_t = d2, t
        d = math.sqrt(d2)
        if wake:
            # Whether or not it holds a minimum, its bound is asked again once the centre has moved
            # ``spread`` from here (one that does, left at its old reference, was asked every tick).
            settle(cand, region, d - cap, spread, cx, cy, cz)
        if d2 >= r2 or d >= worst or not _is_local_min(verts, tris, edges, lists, t, feat, qx, qy, qz, cx, cy, cz):
            continue
        if d < TOUCH:
            phi = 0.0
            nx, ny, nz = feature_normal(verts, tris, edges, t, feat)
        else:
            ux, uy, uz = (cx - qx) / d, (cy - qy) / d, (cz - qz) / d
            # Inside a face c - q is along the face normal; elsewhere only the pseudonormal tells the side.
            px, py, pz = feature_normal(verts, tris, edges, t, feat)
            if ux * px + uy * py + uz * pz >= 0.0:
                phi, nx, ny, nz = d, ux, uy, uz
            else:
                phi, nx, ny, nz = -d, -ux, -uy, -uz
        if feat == FEAT_FACE:
            n_min = _keep(pair, n_min, qx, qy, qz, nx, ny, nz, phi, t, feat)
            worst = _worst(pair.min_phi, n_min)
        else:
            n_em = _collect(tool, verts, tris, n_em, qx, qy, qz, nx, ny, nz, phi, t, feat)
    # Edge and vertex minima along one gentle crease are one contact, the nearest: a polygonal rim
    # seen from inside holds one minimum per segment near the sphere (each a local minimum of the
    # polygon's distance, the vertices between local maxima), all at nearly one depth. Nearest
    # first, each joins the crease of a nearer one it shares a (welded) end with, if its normal is
    # within the cut angle of that crease's nearest; else it is a contact of its own. Along a
    # crease the distance falls to its nearest point and rises beyond (a polygon inscribed in a
    # smooth one), so the nearer ones are joined before the farther, whatever the scan order
    # (merged pairwise in scan order, every other segment of a rim survived: up to 4 contacts of
    # one depth, 4 times the force, issue 25's wall9 round).
    order = tool.em_order
    for a in range(n_em):
        e = order[a]
        tool.em_rep[e] = e
        ends = tool.em_ends[e]
        for b in range(a):
            f = order[b]
            o = tool.em_ends[f]
            if not (ends[0] == o[0] or ends[0] == o[1] or ends[1] == o[0] or ends[1] == o[1]):
                continue
            rep = tool.em_rep[f]
            mn = tool.em_n[rep]
            if tool.em_n[e, 0] * mn[0] + tool.em_n[e, 1] * mn[1] + tool.em_n[e, 2] * mn[2] > _PARTNER_COS:
                tool.em_rep[e] = rep
                break
        if tool.em_rep[e] == e:
            q, m = tool.em_q[e], tool.em_n[e]
            phi = tool.em_phi[e]
            n_min = _keep(pair, n_min, q[0], q[1], q[2], m[0], m[1], m[2], phi, tool.em_t[e], tool.em_f[e])
    # The weights of the minima kept (a face minimum near a gentle concave crease), only now: on
    # a hole's wall most minima found are displaced by nearer ones later in the scan.
    for e in range(n_min):
        w, gx, gy, gz = 1.0, 0.0, 0.0, 0.0
        d = abs(pair.min_phi[e])
        if pair.min_f[e] == FEAT_FACE and d >= TOUCH:
            q = pair.min_q[e]
            w, gx, gy, gz = _crease_weight(verts, tris, edges, pair.min_t[e], d, q[0], q[1], q[2])
        pair.min_w[e] = w
        pair.min_g[e, 0], pair.min_g[e, 1], pair.min_g[e, 2] = gx, gy, gz
    pair.n_min = n_min
    pair.near_t = near_t
    return math.sqrt(max(min(nearest2, floor2), 0.0))
