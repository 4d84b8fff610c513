"""Triangle geometry of the contact kernels: nearest point on a triangle and the pseudonormal of
the feature it lies on (Baerentzen & Aanaes 2005). Arrays are the records of
:mod:`app.world.contact.layout`; points in {w} (m).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.world.contact.bundle import tick_kernel
from app.world.contact.layout import FEAT_EDGE, FEAT_FACE, FEAT_VERTEX, Record, Records

# Rounding allowance (m) of a dormancy bound (:func:`dormancy`).
_PLANE_ROUNDING = 1e-12
# A dormancy bound walks the edges around a vertex of at most this many faces (a fan's centre
# has hundreds).
_CONE_FACES = 16


@njit(cache=True, inline="always")
def closest_on_triangle(
    verts: Records, tris: Records, t: int, cx: float, cy: float, cz: float
) -> tuple[float, float, float, float, int]:
    """Squared distance from c to triangle t, its nearest point q, and the feature q lies on.

    The feature is ``FEAT_FACE`` (q inside the face, ``c - q`` along the normal),
    ``FEAT_VERTEX + k`` or ``FEAT_EDGE + k`` (edge k joins vertex k and k + 1), from the Voronoi
    regions of Ericson, *Real-Time Collision Detection*, 5.1.5.
    """
    tv = tris[t].v
    a, b, c = verts[tv[0]].p, verts[tv[1]].p, verts[tv[2]].p
    ax, ay, az = a[0], a[1], a[2]
    abx, aby, abz = b[0] - ax, b[1] - ay, b[2] - az
    acx, acy, acz = c[0] - ax, c[1] - ay, c[2] - az
    apx, apy, apz = cx - ax, cy - ay, cz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        u, v, feat = 0.0, 0.0, FEAT_VERTEX
    else:
        bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        if d3 >= 0.0 and d4 <= d3:
            u, v, feat = 1.0, 0.0, FEAT_VERTEX + 1
        else:
            vc = d1 * d4 - d3 * d2
            if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                u, v, feat = d1 / (d1 - d3), 0.0, FEAT_EDGE
            else:
                cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
                d5 = abx * cpx + aby * cpy + abz * cpz
                d6 = acx * cpx + acy * cpy + acz * cpz
                if d6 >= 0.0 and d5 <= d6:
                    u, v, feat = 0.0, 1.0, FEAT_VERTEX + 2
                else:
                    vb = d5 * d2 - d1 * d6
                    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                        u, v, feat = 0.0, d2 / (d2 - d6), FEAT_EDGE + 2
                    else:
                        va = d3 * d6 - d5 * d4
                        if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                            u, v, feat = 1.0 - w, w, FEAT_EDGE + 1
                        else:
                            den = 1.0 / (va + vb + vc)
                            u, v, feat = vb * den, vc * den, FEAT_FACE
    qx = ax + u * abx + v * acx
    qy = ay + u * aby + v * acy
    qz = az + u * abz + v * acz
    return (cx - qx) ** 2 + (cy - qy) ** 2 + (cz - qz) ** 2, qx, qy, qz, feat


@njit(cache=True, inline="always")
def feature_normal(verts: Records, tris: Records, edges: Records, t: int, feat: int) -> tuple[float, float, float]:
    """Outward pseudonormal of feature ``feat`` of triangle t (face normal, edge or vertex pseudonormal)."""
    if feat == FEAT_FACE:
        n = tris[t].n
    elif feat < FEAT_EDGE:
        n = verts[tris[t].v[feat - FEAT_VERTEX]].pn
    else:
        n = edges[tris[t].e[feat - FEAT_EDGE]].pn
    return n[0], n[1], n[2]


@njit(cache=True, inline="always")
def segment_offset(verts: Records, i0: int, i1: int, qx: float, qy: float, qz: float) -> tuple[float, float, float]:
    """Vector (m) from the nearest point of the segment joining vertices i0 and i1 to point q."""
    a, b = verts[i0].p, verts[i1].p
    ex, ey, ez = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    px, py, pz = qx - a[0], qy - a[1], qz - a[2]
    ee = ex * ex + ey * ey + ez * ez
    s = min(max((px * ex + py * ey + pz * ez) / ee, 0.0), 1.0) if ee > 0.0 else 0.0
    return px - s * ex, py - s * ey, pz - s * ez


@njit(cache=True, inline="always")
def box_distance2(box: np.ndarray, cx: float, cy: float, cz: float) -> float:
    """Squared distance from c to an axis-aligned box (minimum (3), maximum (3)): a lower bound for its triangle."""
    dx = max(box[0] - cx, 0.0, cx - box[3])
    dy = max(box[1] - cy, 0.0, cy - box[4])
    dz = max(box[2] - cz, 0.0, cz - box[5])
    return dx * dx + dy * dy + dz * dz


@tick_kernel
def _in_vertex_cone(
    verts: Records, tris: Records, vertex_faces: np.ndarray, v: int, cx: float, cy: float, cz: float, R: float
) -> bool:
    """Whether c makes no angle below 90 degrees (relaxed by R) with any edge from vertex v."""
    p = verts[v].p
    ex, ey, ez = cx - p[0], cy - p[1], cz - p[2]
    for s in range(verts[v].f0, verts[v].f1):  # every edge from the vertex, through its faces
        f = tris[vertex_faces[s]]
        x = 0 if f.v[0] == v else (1 if f.v[1] == v else 2)
        # The edges to the next corner (x, leaving the vertex) and from the previous one
        # ((x + 2) % 3, arriving at it).
        u, w = f.u[x], f.u[(x + 2) % 3]
        if ex * u[0] + ey * u[1] + ez * u[2] > R or -(ex * w[0] + ey * w[1] + ez * w[2]) > R:
            return False
    return True


@tick_kernel
def may_hold_minimum(
    verts: Records,
    tris: Records,
    vertex_faces: np.ndarray,
    t: int,
    cx: float,
    cy: float,
    cz: float,
    R: float,
    cones: np.ndarray,
    serial: int,
) -> bool:
    """Whether triangle t can hold a local minimum of the distance for some centre within R of c.

    ``cones`` (V,) memoises the vertex-cone test for one (c, R), numbered ``serial`` (> 0):
    ``2 serial + result``. It walks every face around the vertex, and a fan's centre (a hole's
    bottom) has hundreds, each a triangle asking the same question.

    The local minima of :mod:`app.world.contact.minima` lie where c is in a feature's Voronoi
    region: inside the face's prism, in an edge's wedge (c does not project into either face
    across it, and projects onto the segment), or in a vertex's cone (c makes no acute angle with
    any edge from it). Each test is a set of signed distances to planes, 1-Lipschitz in c, so
    relaxing every one by R covers every centre within R; the test does not depend on which side
    of the surface c is. Only the features t reports count (:mod:`app.world.contact.minima`: a
    shared edge by its lower-numbered face, a vertex by its first face): on a hole's rim, the wall
    facets below the rim edges are left out.
    """
    tri = tris[t]
    inside_prism = True
    own = tri.own
    for k in range(3):
        a = verts[tri.v[k]].p
        ex, ey, ez = cx - a[0], cy - a[1], cz - a[2]
        m = tri.m[k]
        s = ex * m[0] + ey * m[1] + ez * m[2]
        if s < -R:
            inside_prism = False
        if s <= R and own >> k & 1:
            # c may be beyond edge k: in its wedge if it does not project into the face across
            # it either (none on a cut: m_adj is 0), and projects onto the segment.
            ma = tri.m_adj[k]
            if ex * ma[0] + ey * ma[1] + ez * ma[2] <= R:
                u = tri.u[k]
                along = ex * u[0] + ey * u[1] + ez * u[2]
                if -R <= along <= tri.len[k] + R:
                    return True
    if inside_prism:
        return True
    for k in range(3):
        # A vertex's cone lies within t's own corner region there: test that first (two edges).
        if not own >> (3 + k) & 1:
            continue
        v = tri.v[k]
        p = verts[v].p
        ex, ey, ez = cx - p[0], cy - p[1], cz - p[2]
        u, w = tri.u[k], tri.u[(k + 2) % 3]  # the edges leaving vertex k and arriving at it
        if ex * u[0] + ey * u[1] + ez * u[2] <= R and -(ex * w[0] + ey * w[1] + ez * w[2]) <= R:
            if cones[v] >> 1 != serial:
                cones[v] = 2 * serial + _in_vertex_cone(verts, tris, vertex_faces, v, cx, cy, cz, R)
            if cones[v] & 1:
                return True
    return False


@tick_kernel
def dormancy(
    verts: Records,
    tris: Records,
    vertex_faces: np.ndarray,
    t: int,
    cx: float,
    cy: float,
    cz: float,
    gap: float,
    floor: float,
) -> float:
    """How far (m) c may move before triangle t can hold a local minimum it reports, or one nearer
    than its distance less ``gap`` (m): a lower bound of the distance from c to the Voronoi regions
    of t's face and of the edges and vertices it reports (a vertex's cone from every edge around
    it, or, around more than ``_CONE_FACES`` faces, from t's own two), or ``gap`` if that is
    larger; at most 0 when c is in one of them. Once the result is known to be at most ``floor``
    (m), a value at most ``floor`` is returned at once: a caller that treats every such result
    alike (:func:`doze`) need not wait for the exact one.

    Each region is an intersection of half-spaces, and the largest signed distance to their
    planes bounds the distance to it from below (:func:`may_hold_minimum` relaxes the same planes).
    """
    tri = tris[t]
    own = tri.own
    p0, p1, p2 = verts[tri.v[0]].p, verts[tri.v[1]].p, verts[tri.v[2]].p
    face = -math.inf  # the face's prism: inside every edge's plane
    for k, a in ((0, p0), (1, p1), (2, p2)):
        m = tri.m[k]
        face = max(face, (a[0] - cx) * m[0] + (a[1] - cy) * m[1] + (a[2] - cz) * m[2])
    best = face
    # The result is max(best, gap) less the rounding allowance, and best only decreases: once
    # that is at most floor, so is the result (near a hole's axis most candidates stop at their
    # face's prism or first edge, before any vertex-cone walk).
    if max(best, gap) - _PLANE_ROUNDING <= floor:
        return floor
    u = tri.u
    for k, a in ((0, p0), (1, p1), (2, p2)):
        if not own >> k & 1 and not own >> (3 + k) & 1:
            continue
        ex, ey, ez = cx - a[0], cy - a[1], cz - a[2]
        along_b = ex * u[k, 0] + ey * u[k, 1] + ez * u[k, 2]  # along edge k, from vertex k
        if own >> k & 1:
            # Edge k's wedge: beyond it in both faces' planes, abreast of the segment.
            m, ma = tri.m[k], tri.m_adj[k]
            s = ex * m[0] + ey * m[1] + ez * m[2]
            best = min(best, max(s, ex * ma[0] + ey * ma[1] + ez * ma[2], -along_b, along_b - tri.len[k]))
            if max(best, gap) - _PLANE_ROUNDING <= floor:
                return floor
        if own >> (3 + k) & 1:
            # Vertex k's cone: c makes no acute angle with any edge from it (t's own two first;
            # edge k + 2 ends at vertex k).
            j = (k + 2) % 3
            cone = max(along_b, -(ex * u[j, 0] + ey * u[j, 1] + ez * u[j, 2]))
            v = tri.v[k]
            f0, f1 = verts[v].f0, verts[v].f1
            if cone < best and f1 - f0 <= _CONE_FACES:
                for e in range(f0, f1):  # every edge from the vertex, through its faces
                    f = tris[vertex_faces[e]]
                    x = 0 if f.v[0] == v else (1 if f.v[1] == v else 2)
                    fu = f.u[x]  # f's edge x leaves the vertex
                    cone = max(cone, ex * fu[0] + ey * fu[1] + ez * fu[2])
                    if cone >= best:
                        break
            best = min(best, cone)
            if max(best, gap) - _PLANE_ROUNDING <= floor:
                return floor
    # Less a rounding allowance: the planes of the bound and the nearest-point search round
    # differently, by far less than this at coordinates under 1 km.
    mu = max(best, gap) - _PLANE_ROUNDING
    return mu if mu == mu else -math.inf  # a degenerate triangle (NaN) is never skipped


@njit(cache=True, inline="always")
def spread_retry(t: int, retry: float) -> float:
    """``retry`` (m) spread over [0.75, 1.25] of itself by triangle t: candidates dozing off
    together (a gather) do not all wake on the same tick."""
    return retry * (0.75 + 0.5 * ((t * 40503) & 1023) / 1024.0)


@njit(cache=True, inline="always")
def settle(cand: Record, region: float, gap: float, spread: float, cx: float, cy: float, cz: float) -> None:
    """Set a cached candidate's dormancy from c: skipped while the centre is within ``mu`` of c,
    or, if it may hold a minimum already or would wake within ``spread`` (m), taken every time
    until the centre has moved that far. ``region`` is :func:`dormancy` with a gap known earlier
    (-inf for a degenerate triangle, never skipped; any value at most ``spread`` once known to be
    so) and ``gap`` (m) a gap found since: mu is what :func:`dormancy` would give with the larger
    of the two (subtracting the rounding allowance commutes with the maximum)."""
    mu = max(region, gap - _PLANE_ROUNDING) if region > -math.inf else -math.inf
    cand.mu = mu if mu > spread else -spread
    cand.ref[0], cand.ref[1], cand.ref[2] = cx, cy, cz


@tick_kernel
def doze(
    cand: Record,
    verts: Records,
    tris: Records,
    vertex_faces: np.ndarray,
    cx: float,
    cy: float,
    cz: float,
    gap: float,
    retry: float,
) -> None:
    """Set a cached candidate's dormancy (:func:`dormancy`, :func:`settle`) from c, with the
    retry distance ``retry`` (m) spread by triangle."""
    spread = spread_retry(cand.t, retry)
    settle(cand, dormancy(verts, tris, vertex_faces, cand.t, cx, cy, cz, -math.inf, spread), gap, spread, cx, cy, cz)
