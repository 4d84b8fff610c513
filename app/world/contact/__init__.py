"""Penalty contact between the tool's sphere set and the scene's closed meshes.

Public API: :class:`ContactModel` (stateful, one per simulated tool), :func:`contact_wrench`
(stateless), :class:`ContactResult`.

The model, per (sphere of radius r, object) pair, with c the sphere centre:

1. **Contacts are the local minima of the distance from c over the mesh surface within r**
   (:mod:`.minima`): a face whose plane projection of c falls inside it, or an edge or vertex
   that no adjacent face beats, each reported once however many triangles share it. One sphere
   can thus touch an object at several places (the floor and the wall of a pocket), each with
   its own point, outward normal and depth ``r - phi``; phi is the signed distance, signed by
   the feature's angle-weighted pseudonormal (Baerentzen & Aanaes 2005).
2. **Sharp inside corners act like two objects.** At load (:mod:`app.world.collision`) a mesh
   is cut along its concave edges sharper than 30 degrees; each side keeps its own normals
   there, so a sphere in an inside corner feels each face's ``normal * depth`` as if the faces
   belonged to two objects, continuously as it moves (at an L-shaped block's corner 3 mm from
   both faces of a 5 mm sphere: ``k (-2 mm, 0, 2 mm)``, not one face or the other).
3. **Gentle concave creases blend, conservatively.** Where a tessellated concave surface (a
   bowl, a hole's wall) bends by theta, two faces both hold a minimum in a band ``d tan theta``
   wide (the band of every gentle crease at one of a face's vertices, so the two halves of a
   split quad agree); their weights go smoothly across it (``x^2 (3 - 2x)``, flat at both edges)
   and add up to one, and the contact is the force of the potential
   ``k/2 sum(w_i depth_i^2) / sum(w_i)``: neither doubled nor jumping from facet to facet, and
   the elastic field is conservative (no work around a closed path in contact, to rounding: a
   torus's saddle side gave 2.8e-5 J a 3 mm loop with the earlier linear blend of forces).
4. **Which minima push.** The nearest is the primary: it pushes from in front (phi >= 0) or from
   behind (phi < 0: the centre is inside the solid, depth ``r - phi > r``). Any other minimum
   pushes only from in front: a face seen from behind while the centre is outside is the far
   side of material (the underside of a plate being pressed from above). At most four contacts
   per pair, the nearest.
5. **The surface entered is held however deep** (per pair, :mod:`.track`): the pair remembers its
   primary contact's feature and, at every evaluation, slides it over the mesh (across shared
   edges and vertices, never a cut) to the nearest surface point it reaches first from the
   centre, as a god-object constrained to the surface would (Zilles & Salisbury 1995). While
   the centre is behind that surface it is the primary, with depth ``r - phi`` growing without
   limit, and the other minima push only from in front of both themselves and its plane. So the
   force along a push never falls (a plate pushed 10 mm past its far face still pushes back out
   of its top), a fast stroke never pops through a thin part, and a tool let go deep inside
   comes back out where it went in. **Invariant: a non-zero force on a sphere implies mesh
   geometry within its radius, or a surface it entered from in front and has stayed behind
   since**. A pair with no history (a model just reset, or the stateless :func:`contact_wrench`)
   whose centre is more than r inside a solid takes the solid's nearest surface as the one it
   entered (a search over the object's triangles, once per reset): a tool teleported inside is
   pushed out by the nearest way, and a stateless deep pose is read past the middle of a part
   as pushed in from the far side (only a sequence of poses knows better).
   **Through a convex edge or vertex the entry is held** (:func:`.step._held`): outside, near
   an edge, the force is ``k (r - d)`` along the perpendicular from the edge; the face followed
   past it pushed ``k r`` along its own normal, 29 % less along a box edge's bisector, and could
   be the face the push grazes. So the pair keeps the tangent plane of the sphere-swept edge at
   the entry (the direction from the edge to the centre at its last evaluation in front) and
   blends its potential ``k/2 (r + h_e)^2`` with the followed face's, weight 1 on the line
   through the entry point along that direction and 0 on every face's plane: a push straight
   through an edge or vertex, at any angle, feels ``k (r + s)`` along its entry direction,
   continuous with the outside and never falling; the field stays a gradient.
6. **Degenerate positions** (a centre exactly on a face, an edge, a vertex, the corner of a
   pocket) push along the pseudonormal of each feature touched with depth r.
7. **Force law** (:mod:`.force`): ``k depth - b u_n`` clamped at 0, and regularised Coulomb
   friction, with u the velocity of the tool's material point at the contact point.

Inputs: a non-finite pose or twist gives an invalid, zero reading (a servo loop must survive
it); a wrong shape or a pose that is not a rigid transform raises
:class:`~app.errors.ContactInputError`.

Speed: every per-tick step runs in one compiled call (:mod:`.step`), entered without numba's
per-call argument typing, its arrays bundled as one argument and used as borrowed views by
kernels compiled without numba's runtime, so without any reference counting (:mod:`.bundle`).
Culling is exact (the distance is 1-Lipschitz in the centre); each pair caches the triangles that may hold a local
minimum while its centre stays within ``R = 0.075 r`` of where they were gathered (every triangle
within ``r + 2 R`` whose face, edge or vertex Voronoi region, for the features it reports, comes
within R, found through a per-object grid, :mod:`.grid`, in which a triangle is filed only in the
cells it may meet and each column's first cell is indexed). On a fast stroke (more than
``NEAR_FRAC r`` a tick) the pairs whose slack would run out within four ticks are evaluated a few
at a time ahead of it, so that a rigid tool's spheres do not all come due on one tick. Each cached triangle is dormant while
the centre stays nearer where it was last looked at than a lower bound of its distance to those
regions (or of its distance less ``1.05 r``), so a tick in steady contact scans a handful of
triangles per sphere, even on a million-triangle mesh; the scan starts from the pair's last
nearest triangle and skips, on lower bounds of their distance (plane, edge lines, box), the
triangles that cannot change the result.

Limits: a push passing beside a convex edge or vertex at a distance under r still loses force
along it just before it enters, as the perpendicular from the edge turns from the push to the
normal of the face it goes in through (the sphere rolls over the edge): as the line nears the
edge, up to 1 - cos of the angle between that normal and the push (29 % on a box edge's bisector,
47 % 14 degrees off it entering the far face, 0 for the line through the edge). That is the
geometry outside the solid, kept: no field exact there can avoid it.
Across the hand-over from a held entry to the face the gradient of the weight can make the force
larger than either part (61 N 0.7 mm under a box's top entered 15 degrees off its edge's bisector,
on a loop 4 mm past the edge, where the face alone gives 17 N and the entry 27 N).
A tool that entered through an edge and leaves through the other face steps by about ``k r``
(26-28 N at 3000 N/m and 5 mm, any entry angle, in 10 um moves). Two hand-overs were measured
and not shipped (branches wall12 and wall13): (a) hold ``k (r + s)`` on the entry line, (b) meet
``k r n`` on each face's plane, (c) be a gradient with a bounded force: no field has all three.
Blending potentials keeps (a)-(c) only with a bulge of at least ``k (r + s/2) / theta`` across a
wedge of angle theta (wall12: exits fixed above 20 degrees only, the bulge 25 % higher); blending
forces removes the step at every angle (28 -> 0.6-7 N) and the bulge, but gives back up to 2.3e-2
J round a 1 mm loop 3 mm past the edge, 5-19x what the Kraft, the least cited hand and the
contact damping dissipate on it at 0.01-0.1 m/s (wall13), and made passive by a depth shortfall
it drains the held wall instead (24 N -> 0 in seven loops). Most such steps are not edge entries
anyway: a push passing 20 um beside the edge is a face entry and steps 23-28 N too, as a
god-object's proxy would snap round the dilated edge.
A sharp-cornered part hidden behind less than r of material still pushes (as a second
object would); with the centre inside the solid, a secondary contact can switch on or off where
the plane of a cut face extends into the material (the force is continuous outside the solid,
away from the medial axis); one surface per pair is held behind (deep in an inside corner, the
other face pushes only while the centre is in front of it); edge or vertex minima on neighbouring triangles less than 30 degrees
apart count as one (the nearer); at most four contacts per pair; more than 4096 cached
triangles within a sphere's reach is an invalid reading.
"""

from app.world.contact.model import ContactModel, ContactResult, contact_wrench

__all__ = ["ContactModel", "ContactResult", "contact_wrench"]
