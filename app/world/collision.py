"""Collision data of one static mesh: its FCL BVH and the pseudonormals deciding inside/outside.

Built once per object when a scene loads (building the BVH of a 1M-triangle mesh takes seconds)
and shared, read-only, by every :class:`~app.world.contact.ContactModel` of that scene.
"""

from __future__ import annotations

import fcl
import numpy as np
import trimesh

# Barycentric tolerance deciding that the nearest point lies on an edge or a vertex.
_BARY_TOL = 1e-7


class CollisionMesh:
    """A mesh in {w} as an FCL BVH plus face, edge and vertex pseudonormals (Baerentzen & Aanaes 2005).

    Args:
        mesh: Triangle mesh with vertices in {w} (m); watertight with outward normals for a
            meaningful inside.
    """

    __slots__ = (
        "edge_pn",
        "face_edges",
        "face_normals",
        "faces",
        "fcl_object",
        "hi",
        "lo",
        "n_faces",
        "tri_centers",
        "tri_radii",
        "vertex_pn",
        "vertices",
    )

    def __init__(self, mesh: trimesh.Trimesh) -> None:
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
        # Bounding ball of each triangle (centroid, farthest vertex): the candidate filter of the
        # contact model's cached nearest-triangle queries.
        corners = self.vertices[self.faces]
        self.tri_centers = np.ascontiguousarray(corners.mean(axis=1))
        self.tri_radii = np.linalg.norm(corners - self.tri_centers[:, None, :], axis=2).max(axis=1) * (1.0 + 1e-9)
        self.lo = self.vertices.min(axis=0)
        self.hi = self.vertices.max(axis=0)

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
