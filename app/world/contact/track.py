"""The surface a pair entered through, followed over the mesh for as long as the centre stays
behind it (a per-sphere god-object, Zilles & Salisbury 1995, for the sphere's centre).

A penalty contact read from the geometry within the sphere's radius runs out of depth: once the
centre is more than r inside the solid nothing is within reach and the force vanishes (at
``2 k r``), and past the middle of a thin part the nearest surface is the far one, which pushes
the wrong way. Instead, each pair remembers the feature of its primary contact, and every
evaluation slides that remembered point over the surface, triangle to adjacent triangle, to the
local minimum of the distance from the centre that it reaches first (:func:`follow`): the point
a god-object constrained to the surface would settle at. While the centre is behind that
surface (phi < 0) it is the primary contact however deep the centre is, so the elastic force
``k (r - phi)`` keeps growing with the push; in front of it the exact local minima within r
(:mod:`.minima`) take over again.

The walk goes only across shared edges and around shared vertices, never across a cut (a sharp
concave edge, :mod:`app.world.collision`), and moves only to a strictly nearer triangle, so it
stops; :data:`WALK_STEPS` bounds it per evaluation (a fast stroke resumes from where it stopped
on the next tick).
"""

from __future__ import annotations

import math

from app.world.contact.bundle import tick_kernel
from app.world.contact.geometry import closest_on_triangle, feature_normal
from app.world.contact.layout import FEAT_EDGE, FEAT_FACE, FEAT_VERTEX, Records

# Triangles a remembered point may move across in one evaluation: at 1 m/s and 1 kHz a centre
# moves 1 mm a tick, a few facets of the shipped meshes.
WALK_STEPS = 64
# A neighbour is taken only if nearer by this relative margin of the squared distance: at a
# shared edge of coplanar faces the two distances agree to rounding, and the walk must not
# oscillate between them.
_NEARER = 1.0 - 1e-12
# Below this distance (m) the direction c - q is meaningless: the feature's pseudonormal gives it
# (as :data:`app.world.contact.minima.TOUCH`).
_TOUCH = 1e-9


@tick_kernel
def follow(
    verts: Records, tris: Records, edges: Records, lists: Records, t: int, cx: float, cy: float, cz: float
) -> tuple[int, float, float, float, float, float, float, float]:
    """Slide from triangle t to the nearest point of the surface it reaches first from c.

    Returns the triangle reached, the signed distance phi (m, > 0 in front of the surface), the
    nearest point q (m, {w}) and the outward normal n (unit: the direction of the force on the
    tool): ``(t, phi, qx, qy, qz, nx, ny, nz)``.
    """
    d2, qx, qy, qz, feat = closest_on_triangle(verts, tris, t, cx, cy, cz)
    for _ in range(WALK_STEPS):
        if feat == FEAT_FACE:
            break  # c projects into the face: a local minimum
        best, best_d2 = -1, d2 * _NEARER
        if feat >= FEAT_EDGE:
            fs = edges[tris[t].e[feat - FEAT_EDGE]].faces
            other = fs[1] if fs[0] == t else fs[0]
            if other >= 0:
                e2 = closest_on_triangle(verts, tris, other, cx, cy, cz)[0]
                if e2 < best_d2:
                    best, best_d2 = other, e2
        else:
            v = verts[tris[t].v[feat - FEAT_VERTEX]]
            for s in range(v.f0, v.f1):
                f = lists[s]
                if f != t:
                    e2 = closest_on_triangle(verts, tris, f, cx, cy, cz)[0]
                    if e2 < best_d2:
                        best, best_d2 = f, e2
        if best < 0:
            break
        t = best
        d2, qx, qy, qz, feat = closest_on_triangle(verts, tris, t, cx, cy, cz)
    px, py, pz = feature_normal(verts, tris, edges, t, feat)
    d = math.sqrt(d2)
    if d < _TOUCH:
        return t, 0.0, qx, qy, qz, px, py, pz
    ux, uy, uz = (cx - qx) / d, (cy - qy) / d, (cz - qz) / d
    if ux * px + uy * py + uz * pz >= 0.0:
        return t, d, qx, qy, qz, ux, uy, uz
    return t, -d, qx, qy, qz, -ux, -uy, -uz
