"""Collision data of the static meshes: FCL BVHs, pseudonormals, and the packed arrays and grid the
compiled contact kernel reads.

Built once per object when a scene loads (building the BVH of a 1M-triangle mesh takes seconds)
and shared, read-only, by every :class:`~app.world.contact.ContactModel` of that scene.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import fcl
import numpy as np
import trimesh

from app.spatial import Array, IntArray
from app.world.contact_kernel import grid_entries

# Grid cells per object: at most this many along the longest side, and no smaller than the median
# triangle (size sqrt(2 area): long thin triangles count by their width, so the walls of a hole do
# not make the cells as big as the hole), so a cell holds a few triangles.
_GRID_CELLS = 128


class CollisionMesh:
    """A mesh in {w} as an FCL BVH plus face, edge and vertex pseudonormals (Baerentzen & Aanaes 2005).

    Args:
        mesh: Triangle mesh with vertices in {w} (m); watertight with outward normals for a
            meaningful inside.
    """

    __slots__ = (
        "edge_pn",
        "edges",
        "face_edges",
        "face_normals",
        "faces",
        "fcl_object",
        "hi",
        "lo",
        "n_faces",
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
        self.edges = len(mesh.edges_unique)
        edge_pn = np.zeros((self.edges, 3))
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


@dataclass(frozen=True)
class PackedMeshes:
    """Every object's mesh in one set of arrays, indices global, as :mod:`app.world.contact_kernel` reads them.

    Attributes:
        vertices, vertex_pn: Vertices (m, {w}) and their pseudonormals, (V, 3).
        faces, face_normals, face_edges: Vertex indices (F, 3), unit normals (F, 3), edge indices (F, 3).
        edge_pn: Edge pseudonormals, (E, 3).
        tri_boxes: Bounding box of each triangle: minimum (3) and maximum (3) corner (m), (F, 6).
        face0: Object j owns triangles ``face0[j]:face0[j + 1]``, (m + 1,).
        grid_f, grid_i: Per object, the grid's origin (3) and cell size (m), and its cells per axis
            (3) and first key, (m, 4) each.
        grid_keys, grid_start, grid_tris: The occupied cells' keys (sorted), where each cell's
            triangles start in ``grid_tris`` (one more entry than keys), and the triangles.
    """

    vertices: Array
    faces: IntArray
    face_normals: Array
    face_edges: IntArray
    edge_pn: Array
    vertex_pn: Array
    tri_boxes: Array
    face0: IntArray
    grid_f: Array
    grid_i: IntArray
    grid_keys: IntArray
    grid_start: IntArray
    grid_tris: IntArray


def pack_meshes(meshes: Sequence[CollisionMesh]) -> PackedMeshes:
    """Concatenate the meshes (offsetting their indices) and build one uniform grid per object."""
    v0 = np.cumsum([0, *(len(c.vertices) for c in meshes)])
    e0 = np.cumsum([0, *(c.edges for c in meshes)])
    face0 = np.cumsum([0, *(c.n_faces for c in meshes)]).astype(np.int64)

    def cat(parts: list[Array]) -> Array:
        return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros((0, 3)), dtype=float)

    def cat_int(parts: list[IntArray]) -> IntArray:
        return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros((0, 3)), dtype=np.int64)

    vertices = cat([c.vertices for c in meshes])
    faces = cat_int([c.faces + v0[k] for k, c in enumerate(meshes)])
    corners = vertices[faces]
    grid_f = np.zeros((len(meshes), 4))
    grid_i = np.zeros((len(meshes), 4), dtype=np.int64)
    base = 0
    for j, c in enumerate(meshes):
        extent = c.hi - c.lo
        ab = c.vertices[c.faces[:, 1]] - c.vertices[c.faces[:, 0]]
        ac = c.vertices[c.faces[:, 2]] - c.vertices[c.faces[:, 0]]
        tri_size = np.sqrt(np.linalg.norm(np.cross(ab, ac), axis=1))  # sqrt(2 area)
        h = max(float(extent.max()) / _GRID_CELLS, float(np.median(tri_size)), 1e-9)
        dims = np.floor(extent / h).astype(np.int64) + 1
        grid_f[j] = (*c.lo, h)
        grid_i[j] = (*dims, base)
        base += int(np.prod(dims))
    keys, tris = grid_entries(vertices, faces, face0, grid_f, grid_i)
    order = np.argsort(keys, kind="stable")
    keys, tris = keys[order], tris[order]
    grid_keys, first = np.unique(keys, return_index=True)
    return PackedMeshes(
        vertices=vertices,
        faces=faces,
        face_normals=cat([c.face_normals for c in meshes]),
        face_edges=cat_int([c.face_edges + e0[k] for k, c in enumerate(meshes)]),
        edge_pn=cat([c.edge_pn for c in meshes]),
        vertex_pn=cat([c.vertex_pn for c in meshes]),
        tri_boxes=np.ascontiguousarray(np.column_stack([corners.min(axis=1), corners.max(axis=1)])),
        face0=face0,
        grid_f=grid_f,
        grid_i=grid_i,
        grid_keys=np.ascontiguousarray(grid_keys, dtype=np.int64),
        grid_start=np.append(first, len(keys)).astype(np.int64),
        grid_tris=np.ascontiguousarray(tris, dtype=np.int64),
    )
