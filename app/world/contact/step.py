"""One contact evaluation (:func:`contact_step`), compiled with numba: culling, the local minima
of each remaining (sphere, object) pair, which of them push, the surfaces held behind (:mod:`.track`), and the wrench.

Culling, exact (no margin needed): the distance to a mesh is 1-Lipschitz in the centre, so a pair
whose distance is at least d > r cannot touch until its centre has moved ``d - r``. Per object,
the pose at the last per-sphere check is kept with the smallest remaining slack; while every
sphere centre provably moved less than that (tool translation + rotation times the tool's
radius), only the spheres in contact ("hot") are evaluated. Objects whose bounding box is out of
reach of the tool's bounding sphere are skipped, and that test is itself redone only when the
tool has moved by the distance to the nearest far box.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.world.contact.bundle import borrowed, tick_kernel
from app.world.contact.force import contact_force, write_wrench
from app.world.contact.geometry import box_distance2, closest_on_triangle
from app.world.contact.layout import (
    ERR_OVERFLOW,
    ERR_POSE,
    ERR_ROTATION,
    ERR_TWIST,
    ERR_WRENCH,
    FEAT_EDGE,
    FEAT_FACE,
    FEAT_VERTEX,
    Record,
    Records,
)
from app.world.contact.minima import NEAR_FRAC, TOUCH, ensure_cache, local_minima, share_vertex
from app.world.contact.track import follow

# Largest deviation of R^T R from the identity (and of the last row from [0 0 0 1]) accepted as a
# rigid pose: double-precision rotations from quaternions or products stay far below it.
ROTATION_TOL = 1e-6
# A fast stroke's pair evaluations are spread: at most PREFETCH pairs a call are evaluated ahead
# of time when their slack would run out within PREFETCH_TICKS ticks at the current speed, once
# the tool moves more than NEAR_FRAC of its smallest sphere radius a tick (0.25 mm for the
# shipped 5 mm tip: 0.25 m/s at 1 kHz).
PREFETCH = 2
PREFETCH_TICKS = 4.0
# A secondary minimum whose point is this far (m) behind the plane of a remembered surface the
# centre is behind is beyond that surface (rounding allowance of points on a shared edge).
_BEYOND = 1e-9
# An entry feature's face whose normal is this near a right angle to the entry normal (cosine)
# takes no part in the hand-over (:func:`_held`): the entry line lies in its plane.
_GRAZE = 1e-6


@tick_kernel
def _rigid(T: np.ndarray) -> int:
    """0 for a finite rigid pose (4, 4), ERR_POSE if non-finite, ERR_ROTATION if not rigid."""
    for a in range(4):
        for b in range(4):
            if not math.isfinite(T[a, b]):
                return ERR_POSE
    if abs(T[3, 0]) + abs(T[3, 1]) + abs(T[3, 2]) + abs(T[3, 3] - 1.0) > ROTATION_TOL:
        return ERR_ROTATION
    for a in range(3):
        for b in range(a, 3):
            dot = T[0, a] * T[0, b] + T[1, a] * T[1, b] + T[2, a] * T[2, b]
            if abs(dot - (1.0 if a == b else 0.0)) > ROTATION_TOL:
                return ERR_ROTATION
    det = (
        T[0, 0] * (T[1, 1] * T[2, 2] - T[1, 2] * T[2, 1])
        - T[0, 1] * (T[1, 0] * T[2, 2] - T[1, 2] * T[2, 0])
        + T[0, 2] * (T[1, 0] * T[2, 1] - T[1, 1] * T[2, 0])
    )
    return 0 if det > 0.0 else ERR_ROTATION


@tick_kernel
def _emit(
    out: Records,
    n_c: int,
    i: int,
    j: int,
    obj: Record,
    depth: float,
    px: float,
    py: float,
    pz: float,
    nx: float,
    ny: float,
    nz: float,
    T: np.ndarray,
    has_twist: bool,
    V: np.ndarray,
    FM: np.ndarray,
) -> int:
    """Write one contact to ``out[n_c]`` and add its force and moment about {MRF} to ``FM`` (6,)."""
    rx, ry, rz = px - T[0, 3], py - T[1, 3], pz - T[2, 3]
    fx, fy, fz = contact_force(obj.k, obj.b, obj.mu, depth, nx, ny, nz, rx, ry, rz, has_twist, V)
    FM[0] += fx
    FM[1] += fy
    FM[2] += fz
    FM[3] += ry * fz - rz * fy
    FM[4] += rz * fx - rx * fz
    FM[5] += rx * fy - ry * fx
    o = out[n_c]
    o.p[0], o.p[1], o.p[2] = px, py, pz
    o.n[0], o.n[1], o.n[2] = nx, ny, nz
    o.depth = depth
    o.sphere = i
    o.obj = j
    return n_c + 1


@njit(cache=True, inline="always")
def _entry_span(pair: Record, verts: Records, tris: Records) -> tuple[int, int]:
    """The range of s for :func:`_entry_face`: the faces around the pair's entry edge or vertex."""
    if pair.ent_f >= FEAT_EDGE:
        return 0, 2
    v = verts[tris[pair.ent_t].v[pair.ent_f - FEAT_VERTEX]]
    return v.f0, v.f1


@njit(cache=True, inline="always")
def _entry_face(pair: Record, tris: Records, edges: Records, lists: np.ndarray, s: int) -> int:
    """Face s of the pair's entry edge (s = 0, 1; -1 across a cut) or vertex (``lists[s]``)."""
    if pair.ent_f >= FEAT_EDGE:
        return edges[tris[pair.ent_t].e[pair.ent_f - FEAT_EDGE]].faces[s]
    return lists[s]


@njit(cache=True, inline="always")
def _beyond_entry(
    pair: Record, verts: Records, tris: Records, edges: Records, lists: np.ndarray, p: np.ndarray
) -> bool:
    """Whether point p (m, {w}) is behind the plane of every face around the pair's entry edge or
    vertex: in the material's side of the entry, as the far side of a plate entered at its rim
    is (the surface round a convex entry falls away below its tangent plane, so that plane alone
    would cut off the faces beside it: a gear notch's root corners, 64 um below the plane of the
    crease at the middle of its root, 5 mm to the side)."""
    q = pair.ent_q
    s0, s1 = _entry_span(pair, verts, tris)
    for s in range(s0, s1):
        f = _entry_face(pair, tris, edges, lists, s)
        if f >= 0:
            n = tris[f].n
            if (p[0] - q[0]) * n[0] + (p[1] - q[1]) * n[1] + (p[2] - q[2]) * n[2] >= -_BEYOND:
                return False
    return True


@njit(cache=True, inline="always")
def _hand_over(
    n: np.ndarray,
    e: np.ndarray,
    vx: float,
    vy: float,
    vz: float,
    he: float,
    w: float,
    gx: float,
    gy: float,
    gz: float,
) -> tuple[float, float, float, float]:
    """The weight w of the held entry (:func:`_held`) and its gradient g (1/m) times one face's
    factor ``S(tau) = x^2 (3 - 2x)``, x = tau clamped to [0, 1], ``tau = h_i / (a h_e)``, for the
    face of outward normal n, the entry normal e (``a = e . n``), the centre at v from the entry
    point, ``h_i = -v . n`` and ``h_e = -v . e`` > 0 its depths below the two planes;
    ``grad tau = (h_i e - h_e n) / (a h_e^2)``. A face at right angles or more to e (a <= _GRAZE)
    takes no part: the entry line lies in its plane."""
    a = e[0] * n[0] + e[1] * n[1] + e[2] * n[2]
    if a <= _GRAZE:
        return w, gx, gy, gz
    hi = -(vx * n[0] + vy * n[1] + vz * n[2])
    tau = hi / (a * he)
    if tau >= 1.0:
        return w, gx, gy, gz
    if tau <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    si = tau * tau * (3.0 - 2.0 * tau)
    ds = 6.0 * tau * (1.0 - tau) / (a * he * he)
    sx, sy, sz = ds * (hi * e[0] - he * n[0]), ds * (hi * e[1] - he * n[1]), ds * (hi * e[2] - he * n[2])
    return w * si, gx * si + w * sx, gy * si + w * sy, gz * si + w * sz


@tick_kernel
def _held(
    pair: Record,
    r: float,
    verts: Records,
    tris: Records,
    edges: Records,
    lists: np.ndarray,
    phi: float,
    qx: float,
    qy: float,
    qz: float,
    nx: float,
    ny: float,
    nz: float,
) -> tuple[float, float, float, float, float, float, float]:
    """The contact of a centre behind the surface it entered through a convex edge or vertex:
    ``(depth, p, n)``, with the followed surface's ``(phi, q, n)`` given.

    Outside, near an edge, the force is ``k (r - d)`` along the direction from the edge to the
    centre; the followed face's force just inside is ``k r`` along the face's normal, so a push
    through the edge lost ``1 - cos`` of the angle between them (29 % on a box's edge pushed
    along the bisector), and the face picked there could be the one the push grazes (87 % on a
    right-angled prism's edge pushed 11 degrees off one face's normal). Instead the entry is held
    as a plane, the tangent plane of the entry point's sphere-swept edge (Zilles & Salisbury's
    god-object held at an edge by both of its faces): its potential ``U_e = k/2 (r + h_e)^2``, h_e
    the depth below the plane, is blended with the followed face's ``U_f = k/2 (r + h_f)^2`` as
    ``U = w U_e + (1 - w) U_f``, w the product over the entry feature's faces i of
    ``S(h_i / (a_i h_e))``, ``a_i = e . n_i``: 1 on the line through the entry point along its
    normal, where ``h_i = a_i h_e``, and 0 on each face's plane, where U meets the outside field.
    The force ``-grad U`` is that of a potential (no work round a closed path), continuous, and
    along a push through the entry point ``k (r + s)``, s the distance past it: it never falls.
    """
    e, eq = pair.ent_n, pair.ent_q
    c = pair.c
    vx, vy, vz = c[0] - eq[0], c[1] - eq[1], c[2] - eq[2]
    he = -(vx * e[0] + vy * e[1] + vz * e[2])
    hf = -phi
    w = 1.0
    gx = gy = gz = 0.0
    if he > TOUCH:
        s0, s1 = _entry_span(pair, verts, tris)
        for s in range(s0, s1):
            f = _entry_face(pair, tris, edges, lists, s)
            if f >= 0:
                w, gx, gy, gz = _hand_over(tris[f].n, e, vx, vy, vz, he, w, gx, gy, gz)
    he = max(he, 0.0)
    de, df = r + he, r + hf
    dU = 0.5 * (de * de - df * df)
    fx = w * de * e[0] + (1.0 - w) * df * nx - dU * gx
    fy = w * de * e[1] + (1.0 - w) * df * ny - dU * gy
    fz = w * de * e[2] + (1.0 - w) * df * nz - dU * gz
    depth = math.sqrt(fx * fx + fy * fy + fz * fz)
    px, py, pz = w * eq[0] + (1.0 - w) * qx, w * eq[1] + (1.0 - w) * qy, w * eq[2] + (1.0 - w) * qz
    if depth <= 0.0:
        return 0.0, px, py, pz, nx, ny, nz
    return depth, px, py, pz, fx / depth, fy / depth, fz / depth


@tick_kernel
def _pair_contacts(
    pair: Record,
    i: int,
    j: int,
    r: float,
    obj: Record,
    verts: Records,
    tris: Records,
    edges: Records,
    lists: np.ndarray,
    out: Records,
    n_c: int,
    T: np.ndarray,
    has_twist: bool,
    V: np.ndarray,
    FM: np.ndarray,
) -> int:
    """The contacts of a pair from its local minima and its remembered surface; updates the
    memory; returns the new count.

    The remembered surface is followed first (:func:`~app.world.contact.track.follow`): while
    the centre is behind it (phi < 0) it is the primary contact, with depth ``r - phi`` however
    deep, and the other minima push only from in front and from in front of its plane (a face
    beyond it is the far side of the material: the underside of a plate pushed through).
    A surface entered through a convex edge or vertex is held as that entry (:func:`_held`), and
    then the other minima push only if not behind every plane of the entry's faces, and never
    further in. Otherwise the nearest minimum is the primary: it pushes from in front (phi >= 0) or from
    behind (phi < 0, a centre found inside the solid with nothing remembered); every other
    minimum pushes only from in front, and the primary becomes the memory. Weighted minima
    (crease bands) are merged into one contact.
    """
    n_min = pair.n_min
    c = pair.c
    behind = held = False
    ex = ey = ez = 0.0  # the held contact's normal
    if pair.mem == 1:
        t, phi, qx, qy, qz, nx, ny, nz = follow(verts, tris, edges, lists, pair.mem_t, c[0], c[1], c[2])
        if phi < 0.0:
            behind = True
            pair.mem_t = t
            pair.mem_q[0], pair.mem_q[1], pair.mem_q[2] = qx, qy, qz
            pair.mem_n[0], pair.mem_n[1], pair.mem_n[2] = nx, ny, nz
        elif phi == 0.0:
            # The followed point is the centre itself (closer than TOUCH): the geometry does not
            # tell the side there, the remembered contact plane does (two boxes side by side
            # pushed exactly down their seam: the centre runs down both side faces, and taking
            # that as "in front" dropped both top faces, 30 N then 0 N to the bottom).
            mq, mn = pair.mem_q, pair.mem_n
            s = (c[0] - mq[0]) * mn[0] + (c[1] - mq[1]) * mn[1] + (c[2] - mq[2]) * mn[2]
            # Entered through an edge or vertex, the centre on it is on its entry line: held
            # (both faces touched there pushed k r each, along their own normals).
            if s < -TOUCH or (pair.ent == 1 and s <= TOUCH):
                s = min(s, 0.0)
                behind = True
                phi, nx, ny, nz = s, mn[0], mn[1], mn[2]
                qx, qy, qz = c[0] - s * nx, c[1] - s * ny, c[2] - s * nz
    if not behind:
        if n_min == 0:
            pair.mem = 0
            return n_c
        prim = 0
        for e in range(1, n_min):
            if abs(pair.min_phi[e]) < abs(pair.min_phi[prim]):
                prim = e
        phi = pair.min_phi[prim]
        nx, ny, nz = pair.min_n[prim, 0], pair.min_n[prim, 1], pair.min_n[prim, 2]
        qx, qy, qz = pair.min_q[prim, 0], pair.min_q[prim, 1], pair.min_q[prim, 2]
        if r - phi <= 0.0:
            pair.mem = 0
        elif not (phi == 0.0 and pair.mem == 1):
            # A touch (the centre on the surface) keeps the remembered plane: its normal would be
            # only the touched feature's (at the seam above, a side face's).
            pair.mem = 1
            pair.mem_q[0], pair.mem_q[1], pair.mem_q[2] = qx, qy, qz
            pair.mem_n[0], pair.mem_n[1], pair.mem_n[2] = nx, ny, nz
            pair.mem_t = pair.min_t[prim]
            # An edge or vertex seen from in front (its normal the direction to the centre)
            # is held as the entry if the centre passes it (:func:`_held`).
            pair.ent = 1 if pair.min_f[prim] != FEAT_FACE and phi > TOUCH else 0
            pair.ent_q[0], pair.ent_q[1], pair.ent_q[2] = qx, qy, qz
            pair.ent_n[0], pair.ent_n[1], pair.ent_n[2] = nx, ny, nz
            pair.ent_t = pair.min_t[prim]
            pair.ent_f = pair.min_f[prim]
            if pair.ent == 1:
                # Followed from the entry's face most nearly facing the centre: past the edge the
                # followed face is the one the push goes in through, not one it grazes (from a
                # box's top face, walked round its far edge onto its far side, a push through a
                # 10 mm box 7 degrees off its side's normal went out of the far side at 32 N).
                best = -2.0
                s0, s1 = _entry_span(pair, verts, tris)
                for sf in range(s0, s1):
                    f = _entry_face(pair, tris, edges, lists, sf)
                    if f >= 0:
                        fn = tris[f].n
                        a = fn[0] * nx + fn[1] * ny + fn[2] * nz
                        if a > best:
                            best, pair.mem_t = a, f
    else:
        prim = -1
        held = pair.ent == 1
        if held:
            depth, px, py, pz, ex, ey, ez = _held(pair, r, verts, tris, edges, lists, phi, qx, qy, qz, nx, ny, nz)
            n_c = _emit(out, n_c, i, j, obj, depth, px, py, pz, ex, ey, ez, T, has_twist, V, FM)
        else:
            n_c = _emit(out, n_c, i, j, obj, r - phi, qx, qy, qz, nx, ny, nz, T, has_twist, V, FM)
    # Which minima push (bit e of ``pushes``), and which of them are in a crease band (``soft``,
    # 0 < w < 1). A band's minima, with every other face minimum sharing a vertex with one of them
    # (a partner past its band's far edge, w = 1), are one contact: the force of the potential
    # ``U = k/2 sum(w_i depth_i^2) / W`` (W = sum w_i, the weights normalised: near a vertex of a
    # tessellated curved surface several faces hold a minimum at once, and their raw weights add
    # up to more than one), so that the field is conservative across the band and continuous at
    # its edges: the weighted mean of depth * normal, ``s / W``, plus
    # ``-(1 / 2W) sum (depth_i^2 - D2) grad w_i``, D2 the weighted mean of depth^2; the point is
    # the weighted mean of the points.
    pushes = soft = 0
    for e in range(n_min):
        if e != prim:
            mq = pair.min_q[e]
            if pair.min_phi[e] < 0.0 or r - pair.min_phi[e] <= 0.0:
                continue
            if held:
                if pair.min_phi[e] <= TOUCH or _beyond_entry(pair, verts, tris, edges, lists, mq):
                    continue  # (touching: the centre on the entry, whose faces it touches there)
            elif behind and (mq[0] - qx) * nx + (mq[1] - qy) * ny + (mq[2] - qz) * nz < -_BEYOND:
                continue
        elif r - phi <= 0.0:
            continue
        pushes |= 1 << e
        if 0.0 < pair.min_w[e] < 1.0 and not (e == prim and phi < 0.0):
            soft |= 1 << e
    blend = soft
    if soft:
        for e in range(n_min):
            if pushes & (1 << e) and not soft & (1 << e) and pair.min_f[e] == FEAT_FACE and phi >= 0.0:
                for f in range(n_min):
                    if soft & (1 << f) and share_vertex(tris, pair.min_t[e], pair.min_t[f]):
                        blend |= 1 << e
    sx = sy = sz = spx = spy = spz = sw = 0.0
    sd2 = gx = gy = gz = hx = hy = hz = 0.0  # sum w depth^2, sum grad w, sum depth^2 grad w
    for e in range(n_min):
        if not pushes & (1 << e):
            continue
        if e == prim:
            depth = r - phi
            mx, my, mz = nx, ny, nz
        else:
            depth = r - pair.min_phi[e]
            mx, my, mz = pair.min_n[e, 0], pair.min_n[e, 1], pair.min_n[e, 2]
        back = r - depth  # the contact point: the centre moved back along n to the surface
        px, py, pz = c[0] - back * mx, c[1] - back * my, c[2] - back * mz
        if held and not blend & (1 << e):
            # Beside a held entry, material never pushes the tool further in: the part of its
            # force against the held contact's normal is dropped (continuously: a gear notch's
            # root corners, passed by a centre held on the crease at the root's middle, turn
            # from pushing out to pushing in, 9 N/mm along the push).
            along = mx * ex + my * ey + mz * ez
            if along < 0.0:
                mx, my, mz = mx - along * ex, my - along * ey, mz - along * ez
                scale = math.sqrt(mx * mx + my * my + mz * mz)
                if scale <= 0.0:
                    continue
                depth *= scale
                mx, my, mz = mx / scale, my / scale, mz / scale
        if not blend & (1 << e):
            n_c = _emit(out, n_c, i, j, obj, depth, px, py, pz, mx, my, mz, T, has_twist, V, FM)
            continue
        w = pair.min_w[e]
        sx += w * depth * mx
        sy += w * depth * my
        sz += w * depth * mz
        spx += w * px
        spy += w * py
        spz += w * pz
        sw += w
        g = pair.min_g[e]
        d2 = depth * depth
        sd2 += w * d2
        gx += g[0]
        gy += g[1]
        gz += g[2]
        hx += d2 * g[0]
        hy += d2 * g[1]
        hz += d2 * g[2]
    if sw > 0.0:
        mean2 = sd2 / sw
        half = 0.5 / sw
        vx = sx / sw - half * (hx - mean2 * gx)
        vy = sy / sw - half * (hy - mean2 * gy)
        vz = sz / sw - half * (hz - mean2 * gz)
        depth = math.sqrt(vx * vx + vy * vy + vz * vz)
        if depth > 0.0:
            n_c = _emit(
                out, n_c, i, j, obj, depth, spx / sw, spy / sw, spz / sw, vx / depth, vy / depth, vz / depth,
                T, has_twist, V, FM,
            )  # fmt: skip
    return n_c


@tick_kernel
def _enter_from_nearest(
    pair: Record, o: Record, verts: Records, tris: Records, edges: Records, lists: np.ndarray
) -> None:
    """A pair with no history whose centre is more than r from every surface of object ``o``
    (a model just reset, or the stateless :func:`~app.world.contact.model.contact_wrench`) and
    inside the object's box: if the centre is inside the solid, remember its nearest surface, as
    if the tool had entered there (the nearest point over every triangle: once per reset)."""
    c = pair.c
    best, best2 = -1, math.inf
    for t in range(o.faces[0], o.faces[1]):
        d2 = closest_on_triangle(verts, tris, t, c[0], c[1], c[2])[0]
        if d2 < best2:
            best, best2 = t, d2
    if best < 0:
        return
    t, phi, qx, qy, qz, nx, ny, nz = follow(verts, tris, edges, lists, best, c[0], c[1], c[2])
    if phi < 0.0:
        pair.mem = 1
        pair.ent = 0
        pair.mem_t = t
        pair.mem_q[0], pair.mem_q[1], pair.mem_q[2] = qx, qy, qz
        pair.mem_n[0], pair.mem_n[1], pair.mem_n[2] = nx, ny, nz


@njit(cache=True, inline="always")
def _place(pair: Record, R: np.ndarray, p: np.ndarray) -> None:
    """The pair's sphere centre in {w}, ``pair.c = R c_T + p``, for the tool pose ``(R, p)`` of {T}."""
    s = pair.c_T
    for a in range(3):
        pair.c[a] = R[a, 0] * s[0] + R[a, 1] * s[1] + R[a, 2] * s[2] + p[a]


@tick_kernel
def _evaluate(
    pair: Record,
    k: int,
    i: int,
    j: int,
    o: Record,
    tool: Record,
    verts: Records,
    tris: Records,
    edges: Records,
    cells: Records,
    lists: np.ndarray,
    stamp: np.ndarray,
    pool: np.ndarray,
    out: Records,
    n_c: int,
    T: np.ndarray,
    has_twist: bool,
    V: np.ndarray,
    FM: np.ndarray,
) -> tuple[int, int]:
    """Evaluate pair k (sphere i, object j) at its centre ``pair.c``: refill its cache if needed,
    find its minima, add its contacts, and set its slack (how far it may move before it can
    touch; -1 while in contact). Returns the new contact count (ERR_OVERFLOW if the cache
    overflowed) and whether it gathered (0 or 1)."""
    r = pair.r
    g = ensure_cache(pair, k, o, r, verts, tris, cells, lists, stamp, tool, pool)
    if g < 0:
        return ERR_OVERFLOW, 0
    bound = local_minima(pair, tool, pool[k], r, verts, tris, edges, lists)
    box = box_distance2(o.box, pair.c[0], pair.c[1], pair.c[2])
    if pair.fresh:
        pair.fresh = 0
        if pair.mem == 0 and pair.n_min == 0 and box == 0.0:
            _enter_from_nearest(pair, o, verts, tris, edges, lists)
    bound = max(bound, math.sqrt(box))
    for a in range(3):
        pair.last[a] = pair.c[a]
    before = n_c
    n_c = _pair_contacts(pair, i, j, r, o, verts, tris, edges, lists, out, n_c, T, has_twist, V, FM)
    gap = bound - r - tool.margin
    pair.slack = gap if (n_c == before and pair.mem == 0 and gap > 0.0) else -1.0
    return n_c, g


@tick_kernel
def contact_step(
    T: np.ndarray,
    V: np.ndarray,
    has_twist: bool,
    tool_a: Records,
    objs: Records,
    pairs: Records,
    pool: np.ndarray,
    out: Records,
    verts: Records,
    tris: Records,
    edges: Records,
    cells: Records,
    lists: np.ndarray,
    stamp: np.ndarray,
) -> int:
    """One contact evaluation with {MRF} at ``T`` = T_w_MRF (4, 4) and twist ``V`` (6,) if ``has_twist``.

    The record arrays are those of :mod:`app.world.contact.layout`: ``tool_a`` (1,), ``objs``
    (m,), ``pairs`` (m n,), ``pool`` (m n, cache size) of candidate triangles, ``out``
    (m n MAX_PER_PAIR,) contacts, the packed geometry (:class:`~app.world.collision.PackedMeshes`),
    and ``stamp`` (F + V,), the scratch of candidate gathers.

    Returns the number of contacts written to ``out`` (the wrench is in the tool record), or an
    ``ERR_*`` code (< 0).
    """
    tool = tool_a[0]
    code = _rigid(T)
    if code < 0:
        return code
    if has_twist:
        for a in range(6):
            if not math.isfinite(V[a]):
                return ERR_TWIST
    m = objs.shape[0]
    n = pairs.shape[0] // m if m else 0
    # R_w_T, p_w_T = T_w_MRF T_MRF_T
    Tm = tool.T_MRF_T
    R, p, c0 = tool.R_w_T, tool.p_w_T, tool.c0_w  # scratch in the record: no allocation per call
    for a in range(3):
        for b in range(3):
            R[a, b] = T[a, 0] * Tm[0, b] + T[a, 1] * Tm[1, b] + T[a, 2] * Tm[2, b]
        p[a] = T[a, 0] * Tm[0, 3] + T[a, 1] * Tm[1, 3] + T[a, 2] * Tm[2, 3] + T[a, 3]
    for a in range(3):
        c0[a] = R[a, 0] * tool.c0[0] + R[a, 1] * tool.c0[1] + R[a, 2] * tool.c0[2] + p[a]

    # Objects within reach of the tool's bounding sphere (or holding a remembered surface).
    dx, dy, dz = c0[0] - tool.near_c0[0], c0[1] - tool.near_c0[1], c0[2] - tool.near_c0[2]
    if not (tool.near_slack > 0.0 and dx * dx + dy * dy + dz * dz < tool.near_slack**2):
        near_slack = math.inf
        for j in range(m):
            o = objs[j]
            dist = math.sqrt(box_distance2(o.box, c0[0], c0[1], c0[2])) - tool.reach
            o.near = 1 if dist <= 0.0 else 0
            if dist > 0.0:
                near_slack = min(near_slack, dist)
            for i in range(n):
                if pairs[j * n + i].mem:
                    o.near = 1
        for a in range(3):
            tool.near_c0[a] = c0[a]
        tool.near_slack = near_slack

    FM = tool.FM  # force on the tool and moment about the {MRF} origin, {w}
    FM[:] = 0.0
    n_c = 0
    queries = gathers = 0
    rho = tool.rho
    for j in range(m):
        o = objs[j]
        if not o.near:
            continue
        cos_sum = 0.0  # trace(R_now R_base^T) = 1 + 2 cos(theta)
        for a in range(3):
            for b in range(3):
                cos_sum += R[a, b] * o.base_R[a, b]
        dx, dy, dz = c0[0] - o.base_c0[0], c0[1] - o.base_c0[1], c0[2] - o.base_c0[2]
        # Largest displacement of any sphere centre since the base pose: the translation of c0
        # plus the rotation about it (|(R - R0) y| = 2 sin(theta/2) |y|).
        moved = math.sqrt(dx * dx + dy * dy + dz * dz) + rho * math.sqrt(max(0.0, 3.0 - cos_sum))
        full = moved >= o.slack
        o.ahead = o.slack - moved  # a lower bound of what its pairs out of contact may still move
        for i in range(n):
            k = j * n + i
            pair = pairs[k]
            if not (full or pair.hot):
                continue  # its centre is only needed at the next full check
            _place(pair, R, p)
            if full:
                ex, ey, ez = pair.c[0] - pair.last[0], pair.c[1] - pair.last[1], pair.c[2] - pair.last[2]
                if math.sqrt(ex * ex + ey * ey + ez * ez) < pair.slack:
                    continue
            queries += 1
            n_c, g = _evaluate(pair, k, i, j, o, tool, verts, tris, edges, cells, lists, stamp, pool, out, n_c, T,
                               has_twist, V, FM)  # fmt: skip
            if n_c < 0:
                return n_c
            gathers += g
        if full:
            # Rebase: the spheres in contact (slack < 0) become hot; the others may move their
            # remaining slack from here before the next full check.
            remaining = math.inf
            for i in range(n):
                pair = pairs[j * n + i]
                pair.hot = 1 if pair.slack < 0.0 else 0
                if not pair.hot:
                    ex, ey, ez = pair.c[0] - pair.last[0], pair.c[1] - pair.last[1], pair.c[2] - pair.last[2]
                    remaining = min(remaining, pair.slack - math.sqrt(ex * ex + ey * ey + ez * ez))
            o.slack = o.ahead = remaining
            for a in range(3):
                o.base_c0[a] = c0[a]
                for b in range(3):
                    o.base_R[a, b] = R[a, b]
    # Spread the work of a fast stroke: evaluate now the pairs whose slack runs out within
    # PREFETCH_TICKS ticks at the last tick's speed (PREFETCH at most, the soonest first), so
    # that a rigid tool's spheres do not all come due on one tick. Evaluating a pair early is
    # exact, like any evaluation.
    dx, dy, dz = c0[0] - tool.prev_c0[0], c0[1] - tool.prev_c0[1], c0[2] - tool.prev_c0[2]
    cos_sum = 0.0
    for a in range(3):
        for b in range(3):
            cos_sum += R[a, b] * tool.prev_R[a, b]
            tool.prev_R[a, b] = R[a, b]
        tool.prev_c0[a] = c0[a]
    step = math.sqrt(dx * dx + dy * dy + dz * dz) + rho * math.sqrt(max(0.0, 3.0 - cos_sum))
    horizon = PREFETCH_TICKS * step
    # Slower than NEAR_FRAC r a tick, a pair comes due rarely and alone: no search.
    for _ in range(PREFETCH if step > NEAR_FRAC * tool.r_min else 0):
        best, best_rem = -1, horizon
        for j in range(m):
            o = objs[j]
            if not o.near or o.ahead >= best_rem:
                continue
            for i in range(n):
                pair = pairs[j * n + i]
                if pair.hot or pair.slack <= 0.0:
                    continue
                s = pair.c_T
                cx = R[0, 0] * s[0] + R[0, 1] * s[1] + R[0, 2] * s[2] + p[0]
                cy = R[1, 0] * s[0] + R[1, 1] * s[1] + R[1, 2] * s[2] + p[1]
                cz = R[2, 0] * s[0] + R[2, 1] * s[1] + R[2, 2] * s[2] + p[2]
                moved2 = (cx - pair.last[0]) ** 2 + (cy - pair.last[1]) ** 2 + (cz - pair.last[2]) ** 2
                if moved2 == 0.0:
                    continue  # evaluated on this call
                rem = pair.slack - math.sqrt(moved2)
                if rem < best_rem:
                    best, best_rem = j * n + i, rem
        if best < 0:
            break
        j, i = best // n, best % n
        pair = pairs[best]
        _place(pair, R, p)
        queries += 1
        n_c, g = _evaluate(pair, best, i, j, objs[j], tool, verts, tris, edges, cells, lists, stamp, pool, out, n_c, T,
                           has_twist, V, FM)  # fmt: skip
        if n_c < 0:
            return n_c
        gathers += g
        pair.hot = 1 if pair.slack < 0.0 else 0
    tool.counts[0] = queries
    tool.counts[1] = gathers
    if not math.isfinite(FM[0] + FM[1] + FM[2] + FM[3] + FM[4] + FM[5]):
        return ERR_WRENCH
    write_wrench(tool, T, FM[0:3], FM[3:6])
    return n_c


@njit(cache=True)
def contact_step_bundled(T: np.ndarray, V: np.ndarray, has_twist: bool, a: Record) -> int:
    """:func:`contact_step` with the model's arrays as one :class:`~app.world.contact.bundle.KernelArrays`
    (entered for about 0.45 us less), each :func:`~app.world.contact.bundle.borrowed` (the
    bundle keeps them alive): no atomic reference counting on their views."""
    b = borrowed
    return contact_step(
        b(T), b(V), has_twist, b(a.tool), b(a.objs), b(a.pairs), b(a.pool), b(a.out), b(a.verts), b(a.tris),
        b(a.edges), b(a.cells), b(a.lists), b(a.stamp),
    )  # fmt: skip
