"""The named bundles the compiled contact kernels read and write: numpy record layouts.

Every array a kernel takes is a record array whose fields carry the names below (numba reads
record fields by name at the speed of plain arrays). Unboxing costs about 0.1 us per array at
every kernel call, so related data shares one record array instead of being passed as a long
list of columns; a NamedTuple of arrays would cost more than the arrays themselves.

Units: m, N, s; points and directions in {w} unless a field says otherwise.
"""

from __future__ import annotations

from typing import Any

import numpy as np

# mypy cannot see the field names of a record dtype: a record (one row, fields as attributes in
# numba) and a record array are typed with these aliases; the dtypes below document the fields.
Record = Any
Records = Any

# Contacts kept per (sphere, object) pair at most (the nearest ones): a sphere in the corner of
# a box pocket touches three faces.
MAX_PER_PAIR = 4

# Edge and vertex minima a pair evaluation collects at most before merging those along one crease
# (:func:`app.world.contact.minima.local_minima`); beyond, the farthest are forgotten. A 6 mm peg
# sphere nearly level with the 256-segment bore/chamfer crease of peg_block sees some 30.
MAX_EDGE_MINIMA = 64

# Gentle concave creases listed per triangle at most (a vertex of valence 6 on a tessellated
# surface gives a triangle 12 edges from its vertices); more are dropped, its own edges kept.
MAX_CREASES = 16

# Feature codes of a triangle's nearest point: its face, a vertex (slot 0..2) or an edge (slot
# 0..2: edge k joins vertex k and vertex k + 1 mod 3).
FEAT_FACE = 0
FEAT_VERTEX = 1  # + slot
FEAT_EDGE = 4  # + slot

# The tool: constants, the global culling state and the outputs of the last evaluation.
TOOL = np.dtype(
    [
        ("c0", "f8", (3,)),  # centre of the tool's bounding sphere, in {T}
        ("rho", "f8"),  # largest distance of a sphere centre from c0
        ("reach", "f8"),  # bounding radius of the spheres themselves plus the margin
        ("r_min", "f8"),  # the smallest sphere radius
        ("margin", "f8"),  # extra culling distance (0 is exact)
        ("T_MRF_T", "f8", (4, 4)),  # pose of {T} in {MRF}
        ("p_MRF_S", "f8", (3,)),  # origin of {S} in {MRF}
        ("R_MRF_S", "f8", (3, 3)),  # axes of {S} in {MRF}
        ("R_w_T", "f8", (3, 3)),  # scratch of an evaluation: the tool pose,
        ("p_w_T", "f8", (3,)),
        ("c0_w", "f8", (3,)),  # its bounding-sphere centre in {w},
        ("FM", "f8", (6,)),  # and the total force and moment about {MRF} in {w}
        ("near_c0", "f8", (3,)),  # bounding-sphere centre at the last near-object test, {w}
        ("near_slack", "f8"),  # how far it may move before the next test; -1: test now
        ("serial", "i8"),  # number of the last candidate gather (see ``stamp`` in the step)
        ("prev_c0", "f8", (3,)),  # bounding-sphere centre and rotation at the previous call,
        ("prev_R", "f8", (3, 3)),  # for the speed of the tool (pair evaluations spread ahead)
        # Outputs: the contact wrench on the tool at {S} in {S} (0:6), the same at {MRF} in {MRF}
        # (6:12), the total contact force in {w} (12:15); pair evaluations of the last call and
        # how many of them refilled their candidate cache.
        ("out", "f8", (15,)),
        ("counts", "i8", (2,)),
        # Scratch of a pair evaluation: its edge and vertex minima (as the pair's ``min_*``), nearest
        # first through ``em_order``; the welded ends of each one's feature (an edge's two, a
        # vertex's twice); and the minimum each merged into (its crease's nearest).
        ("em_q", "f8", (MAX_EDGE_MINIMA, 3)),
        ("em_n", "f8", (MAX_EDGE_MINIMA, 3)),
        ("em_phi", "f8", (MAX_EDGE_MINIMA,)),
        ("em_t", "i8", (MAX_EDGE_MINIMA,)),
        ("em_f", "i8", (MAX_EDGE_MINIMA,)),
        ("em_ends", "i8", (MAX_EDGE_MINIMA, 2)),
        ("em_order", "i8", (MAX_EDGE_MINIMA,)),
        ("em_rep", "i8", (MAX_EDGE_MINIMA,)),
    ],
    align=True,
)

# One object: contact law, bounding box, grid, and its culling state.
OBJECT = np.dtype(
    [
        ("k", "f8"),  # stiffness (N/m)
        ("b", "f8"),  # damping (N s/m)
        ("mu", "f8"),  # Coulomb friction coefficient
        ("box", "f8", (6,)),  # bounding box: minimum (3), maximum (3)
        ("grid_origin", "f8", (3,)),  # the object's uniform grid: origin, cell size, cells per axis,
        ("grid_h", "f8"),
        ("grid_dims", "i8", (3,)),
        ("grid_base", "i8"),  # key of its first cell in the shared sorted key list
        ("grid_cols", "i8"),  # where its column table starts in ``lists`` (see app.world.contact.grid)
        ("prune", "i8"),  # 1: cache only triangles that may hold a local minimum; 0: every one in reach
        ("faces", "i8", (2,)),  # its triangles: faces[0]:faces[1]
        ("near", "i8"),  # 1 while the tool's bounding sphere may reach the bounding box
        ("base_c0", "f8", (3,)),  # tool bounding-sphere centre at the last per-sphere check
        ("base_R", "f8", (3, 3)),  # tool rotation R_w_T there
        ("slack", "f8"),  # how far any sphere centre may move from there before a full check
        ("ahead", "f8"),  # at the last call, a lower bound of how far its pairs out of contact may move
    ],
    align=True,
)

# One (sphere, object) pair, k = object * spheres + sphere: culling, candidate cache, the
# remembered surface, and the local minima found by the current evaluation.
PAIR = np.dtype(
    [
        ("c_T", "f8", (3,)),  # the sphere: centre in {T}
        ("r", "f8"),  # and radius
        ("c", "f8", (3,)),  # sphere centre at the current evaluation
        ("last", "f8", (3,)),  # centre at the pair's last evaluation
        ("slack", "f8"),  # distance the centre may move from ``last`` before it can touch; -1: every tick
        ("hot", "i8"),  # 1: evaluated every tick while its object's slack holds
        ("cache_c", "f8", (3,)),  # centre the candidate cache was gathered at
        ("cache_n", "i8"),  # candidates in the pool row; -1: no cache
        ("near_t", "i8"),  # nearest triangle at the last evaluation (-1: none): checked first
        ("fresh", "i8"),  # 1 until its first evaluation after a reset (no history yet)
        ("mem", "i8"),  # 1 while a surface is remembered (app.world.contact.track)
        ("mem_q", "f8", (3,)),  # its point and outward normal
        ("mem_n", "f8", (3,)),
        ("mem_t", "i8"),  # its triangle, from which the next evaluation follows the surface
        # The entry: the primary contact at the last evaluation in front of the surface, when it
        # was an edge or vertex (``ent`` = 1; app.world.contact.step._held): its point, normal
        # (the direction from that point to the centre), triangle and feature (FEAT_*).
        ("ent", "i8"),
        ("ent_q", "f8", (3,)),
        ("ent_n", "f8", (3,)),
        ("ent_t", "i8"),
        ("ent_f", "i8"),
        ("n_min", "i8"),  # local minima of the distance within reach, this evaluation
        ("min_q", "f8", (MAX_PER_PAIR, 3)),  # their points,
        ("min_n", "f8", (MAX_PER_PAIR, 3)),  # outward normals,
        ("min_phi", "f8", (MAX_PER_PAIR,)),  # signed distances of the centre (> 0 outside),
        ("min_w", "f8", (MAX_PER_PAIR,)),  # weights (< 1 only in the band of a gentle concave crease)
        ("min_g", "f8", (MAX_PER_PAIR, 3)),  # gradients of the weights in the centre (1/m)
        ("min_t", "i8", (MAX_PER_PAIR,)),  # triangles,
        ("min_f", "i8", (MAX_PER_PAIR,)),  # and features (FEAT_*)
    ],
    align=True,
)

# One triangle of the packed meshes (global indices).
TRIANGLE = np.dtype(
    [
        ("v", "i8", (3,)),  # vertices
        ("e", "i8", (3,)),  # edges: e[k] joins v[k] and v[(k + 1) % 3]
        ("n", "f8", (3,)),  # outward unit normal
        ("off", "f8"),  # the face's plane is n . x = off
        ("box", "f8", (6,)),  # bounding box: minimum (3), maximum (3)
        ("m", "f8", (3, 3)),  # m[k]: unit vector in the face, normal to edge k, pointing inside
        ("m_adj", "f8", (3, 3)),  # m_adj[k]: the same for the face across edge k (0 on a cut)
        # The features it reports (minima): bit k edge k (the lower-numbered of its faces reports
        # a shared edge), bit 3 + k vertex k (its first face reports a vertex).
        ("own", "i8"),
        ("len", "f8", (3,)),  # len[k]: length of edge k
        ("u", "f8", (3, 3)),  # u[k]: unit vector along edge k, from v[k] to v[(k + 1) % 3]
        # The gentle concave creases with an end at one of its vertices (edge indices, its own
        # first, -1 after the last): the bands a face minimum's weight is taken across.
        ("creases", "i8", (MAX_CREASES,)),
    ],
    align=True,
)

# One cached candidate of a pair (a row of the pool): its triangle, and how far the centre may
# move from ``ref`` before that triangle can hold a local minimum within ``r + R`` (mu > 0: the
# scan skips it until then), or, mu <= 0, how far before it is worth asking again (-mu).
CANDIDATE = np.dtype([("t", "i8"), ("mu", "f8"), ("ref", "f8", (3,))], align=True)

# One vertex: position, angle-weighted pseudonormal, its faces ``lists[f0:f1]``, and ``weld``:
# the same for each copy of a vertex across a cut (each side of a cut has its own copy).
VERTEX = np.dtype([("p", "f8", (3,)), ("pn", "f8", (3,)), ("f0", "i8"), ("f1", "i8"), ("weld", "i8")], align=True)

# One edge: pseudonormal, its faces (-1: none, a boundary where the mesh was cut), ``tan`` > 0
# for a gentle concave crease (tan of the angle between its faces' normals), and its two ends.
EDGE = np.dtype([("pn", "f8", (3,)), ("faces", "i8", (2,)), ("tan", "f8"), ("v", "i8", (2,))], align=True)

# One occupied grid cell: key and where its triangles start in ``lists`` (a last sentinel row
# closes the list).
CELL = np.dtype([("key", "i8"), ("start", "i8")], align=True)

# One output contact.
CONTACT = np.dtype(
    [
        ("p", "f8", (3,)),  # point on the object surface
        ("n", "f8", (3,)),  # outward object normal (direction of the normal force on the tool)
        ("depth", "f8"),  # effective penetration depth (m): the elastic force is k * depth
        # Tool sphere and object indices, as floats: a contact is one row of 9 floats, copied
        # out with the others in one block.
        ("sphere", "f8"),
        ("obj", "f8"),
    ],
    align=True,
)

# Return codes of the step (>= 0: the number of contacts).
ERR_POSE = -1  # non-finite pose: an invalid reading
ERR_TWIST = -2  # non-finite twist: an invalid reading
ERR_WRENCH = -3  # non-finite wrench: an invalid reading
ERR_ROTATION = -4  # not a rigid pose (rotation not orthonormal, reflection, bad last row): misuse
ERR_OVERFLOW = -5  # too many triangles within a sphere's reach for the candidate cache
