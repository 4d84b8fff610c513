"""Collision data of the static meshes, built once per object when a scene loads and shared,
read-only, by every :class:`~app.world.contact.ContactModel` of the scene.

Each closed mesh is *cut along its sharp concave edges* (concave, normals more than
:data:`CUT_ANGLE_DEG` apart): such an edge becomes one boundary edge per side, and a vertex whose
faces the cuts separate into several fans is duplicated per fan, so each side keeps its own
pseudonormals there. The contact model then treats the two sides of a sharp inside corner like
two objects touching (see :mod:`app.world.contact`). Gentler concave edges stay joined and carry
the tangent of their angle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import trimesh

from app.spatial import Array, IntArray
from app.world.contact.grid import crease_lists, grid_entries
from app.world.contact.layout import CELL, EDGE, OBJECT, TRIANGLE, VERTEX

# Concave edges whose face normals differ by more than this are cut (two contacts); gentler ones
# are blended (one contact). The faceting of tessellated curved surfaces stays well below it.
CUT_ANGLE_DEG = 30.0
# Grid cells per object: at most this many along the longest side, and no smaller than the median
# triangle (size sqrt(2 area)), so a cell holds a few triangles.
_GRID_CELLS = 128


def _unit(v: Array) -> Array:
    return v / np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]


class CollisionMesh:
    """A closed mesh in {w}, cut along its sharp concave edges, with pseudonormals and adjacency.

    Args:
        mesh: Closed, consistently wound triangle mesh with outward normals, vertices in {w} (m)
            (see :func:`app.world.mesh_check.checked_mesh`).

    Attributes:
        vertices: Vertices (m), (V, 3); a vertex whose faces cuts separate appears once per fan.
        vertex_origin: The input's vertex each one is a copy of (V,): the copies of a vertex across
            a cut share it.
        faces: Vertex indices (F, 3), in the input's face order.
        face_normals: Outward unit normals (F, 3).
        face_edges: Edge k of face f joins ``faces[f, k]`` and ``faces[f, (k + 1) % 3]``, (F, 3).
        edge_faces: The faces of each edge, -1 where the mesh was cut, (E, 2).
        edge_pn, vertex_pn: Edge and angle-weighted vertex pseudonormals (E, 3), (V, 3).
        edge_tan: tan of the angle between the normals of a gentle concave edge, else 0, (E,).
        edge_inward: ``[f, k]`` is the unit vector in face f normal to its edge k, pointing inside, (F, 3, 3).
        edge_inward_across: The same for the face across edge k (0 on a cut), (F, 3, 3).
        vertex_faces, vertex_face_start: Faces around vertex v are
            ``vertex_faces[vertex_face_start[v]:vertex_face_start[v + 1]]`` (sorted).
        n_faces, lo, hi: Face count and bounding box (m).
    """

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        faces0 = np.asarray(mesh.faces, dtype=np.int64)
        self.n_faces = nf = len(faces0)
        self.face_normals = np.asarray(mesh.face_normals, dtype=float)
        # Cut: union the corners (face, vertex) of faces joined by an uncut edge; each class of
        # corners becomes one vertex.
        adj = np.asarray(mesh.face_adjacency, dtype=np.int64)
        adj_edges = np.asarray(mesh.face_adjacency_edges, dtype=np.int64)
        concave = ~np.asarray(mesh.face_adjacency_convex, dtype=bool)
        angles = np.asarray(mesh.face_adjacency_angles, dtype=float)
        keep = ~(concave & (angles > math.radians(CUT_ANGLE_DEG)))
        cut_pairs = np.sort(adj[~keep], axis=1)
        rows, cols = [], []
        for side in range(2):
            v = adj_edges[keep, side]
            f, g = adj[keep, 0], adj[keep, 1]
            rows.append(3 * f + np.argmax(faces0[f] == v[:, None], axis=1))
            cols.append(3 * g + np.argmax(faces0[g] == v[:, None], axis=1))
        r, c = np.concatenate(rows), np.concatenate(cols)
        graph = scipy.sparse.coo_matrix((np.ones(len(r)), (r, c)), shape=(3 * nf, 3 * nf))
        _, corner_label = scipy.sparse.csgraph.connected_components(graph, directed=False)
        # Corners of one original vertex in one class share a label; relabel compactly.
        labels, inverse = np.unique(corner_label, return_inverse=True)
        corner_vertex = faces0.ravel()
        self.faces = inverse.reshape(nf, 3).astype(np.int64)
        vertices = np.zeros((len(labels), 3))
        vertices[inverse] = np.asarray(mesh.vertices, dtype=float)[corner_vertex]
        self.vertices = vertices
        self.vertex_origin = np.zeros(len(labels), dtype=np.int64)
        self.vertex_origin[inverse] = corner_vertex
        self._edges(cut_pairs)
        self._pseudonormals()
        self.lo = self.vertices.min(axis=0)
        self.hi = self.vertices.max(axis=0)

    def _edges(self, cut_pairs: IntArray) -> None:
        """Edges, their faces, and the gentle creases; a cut edge becomes one boundary edge per side
        (its end vertices are split only where the cut separates their faces into two fans)."""
        nf = self.n_faces
        pairs = np.stack([self.faces, np.roll(self.faces, -1, axis=1)], axis=2).reshape(-1, 2)
        unique, inverse = np.unique(np.sort(pairs, axis=1), axis=0, return_inverse=True)
        inverse = inverse.ravel()
        edge_faces = np.full((len(unique), 2), -1, dtype=np.int64)
        owner = np.repeat(np.arange(nf), 3)
        order = np.argsort(inverse, kind="stable")
        e_sorted = inverse[order]
        first = np.r_[True, e_sorted[1:] != e_sorted[:-1]]
        edge_faces[e_sorted[first], 0] = owner[order][first]
        edge_faces[e_sorted[~first], 1] = owner[order][~first]
        both = np.flatnonzero(edge_faces[:, 1] >= 0)
        key = np.sort(edge_faces[both], axis=1) @ np.array([nf, 1])
        cut = both[np.isin(key, cut_pairs @ np.array([nf, 1]))]
        # The second face of a cut edge gets a new edge of its own.
        new_ids = len(unique) + np.arange(len(cut))
        second = edge_faces[cut, 1]
        slot = np.argmax(inverse.reshape(nf, 3)[second] == cut[:, None], axis=1)
        face_edges = inverse.reshape(nf, 3).astype(np.int64)
        face_edges[second, slot] = new_ids
        edge_faces[cut, 1] = -1
        edge_faces = np.vstack([edge_faces, np.column_stack([second, np.full(len(cut), -1)])])
        unique = np.vstack([unique, unique[cut]])
        self.face_edges = face_edges
        self.edge_faces = edge_faces
        # Inward edge normals of each face, and those of the face across each edge.
        corners = self.vertices[self.faces]
        along = np.roll(corners, -1, axis=1) - corners  # edge k: corner k -> corner k + 1
        self.edge_inward = _unit(np.cross(np.repeat(self.face_normals, 3, axis=0), along.reshape(-1, 3))).reshape(
            nf, 3, 3
        )
        across = np.zeros((nf, 3, 3))
        for k in range(3):
            e = face_edges[:, k]
            other = np.where(edge_faces[e, 0] == np.arange(nf), edge_faces[e, 1], edge_faces[e, 0])
            has = other >= 0
            slot = np.argmax(face_edges[other[has]] == e[has, None], axis=1)
            across[has, k] = self.edge_inward[other[has], slot]
        self.edge_inward_across = across
        # Gentle concave creases: both faces present, the second face bends towards the first's normal.
        tan = np.zeros(len(unique))
        both = np.flatnonzero(edge_faces[:, 1] >= 0)
        f, g = edge_faces[both, 0], edge_faces[both, 1]
        nf_, ng = self.face_normals[f], self.face_normals[g]
        centroid_g = self.vertices[self.faces[g]].mean(axis=1)
        a = self.vertices[unique[both, 0]]
        bend = np.einsum("ij,ij->i", centroid_g - a, nf_)
        cos = np.clip(np.einsum("ij,ij->i", nf_, ng), -1.0, 1.0)
        angle = np.arccos(cos)
        gentle = (bend > 0.0) & (angle > 1e-9)
        tan[both[gentle]] = np.tan(angle[gentle])
        self.edge_tan = tan

    def _pseudonormals(self) -> None:
        fe = self.face_edges.ravel()
        edge_pn = np.zeros((len(self.edge_faces), 3))
        np.add.at(edge_pn, fe, np.repeat(self.face_normals, 3, axis=0))
        self.edge_pn = _unit(edge_pn)
        tri = self.vertices[self.faces]
        vertex_pn = np.zeros_like(self.vertices)
        weighted = trimesh.triangles.angles(tri)[:, :, None] * self.face_normals[:, None, :]
        np.add.at(vertex_pn, self.faces.ravel(), weighted.reshape(-1, 3))
        self.vertex_pn = _unit(vertex_pn)
        corner_v = self.faces.ravel()
        order = np.argsort(corner_v, kind="stable")
        self.vertex_faces = (order // 3).astype(np.int64)
        self.vertex_face_start = np.searchsorted(corner_v[order], np.arange(len(self.vertices) + 1)).astype(np.int64)


@dataclass(frozen=True)
class PackedMeshes:
    """Every object's mesh in the record arrays of :mod:`app.world.contact.layout`, indices global.

    Attributes:
        tris, verts, edges: Per triangle, vertex and edge records (TRIANGLE, VERTEX, EDGE).
        face0: Object j owns triangles ``face0[j]:face0[j + 1]``, (m + 1,).
        objs: Per-object records (OBJECT) with the contact law unset and the grid filled in:
            a template each contact model copies.
        cells: The occupied grid cells (CELL, with a sentinel row).
        lists: Triangle lists: the faces around each vertex (``verts.f0:f1``), then each grid
            cell's triangles (``cells.start``), then each object's column table
            (``objs.grid_cols``), (L,).
    """

    tris: np.ndarray
    verts: np.ndarray
    edges: np.ndarray
    face0: IntArray
    objs: np.ndarray
    cells: np.ndarray
    lists: IntArray


def pack_meshes(meshes: Sequence[CollisionMesh]) -> PackedMeshes:
    """Concatenate the meshes (offsetting their indices) and build one uniform grid per object."""
    v0 = np.cumsum([0, *(len(c.vertices) for c in meshes)])
    e0 = np.cumsum([0, *(len(c.edge_faces) for c in meshes)])
    face0 = np.cumsum([0, *(c.n_faces for c in meshes)]).astype(np.int64)
    tris = np.zeros(face0[-1], dtype=TRIANGLE)
    verts = np.zeros(v0[-1], dtype=VERTEX)
    edges = np.zeros(e0[-1], dtype=EDGE)
    vertex_faces: list[IntArray] = []
    objs = np.zeros(len(meshes), dtype=OBJECT)
    base = 0
    for j, c in enumerate(meshes):
        fs = slice(face0[j], face0[j + 1])
        tris["v"][fs] = c.faces + v0[j]
        tris["e"][fs] = c.face_edges + e0[j]
        tris["n"][fs] = c.face_normals
        tris["off"][fs] = np.einsum("ij,ij->i", c.face_normals, c.vertices[c.faces[:, 0]])
        corners = c.vertices[c.faces]
        tris["box"][fs] = np.column_stack([corners.min(axis=1), corners.max(axis=1)])
        tris["m"][fs] = c.edge_inward
        tris["m_adj"][fs] = c.edge_inward_across
        along = np.roll(corners, -1, axis=1) - corners
        tris["len"][fs] = np.linalg.norm(along, axis=2)
        tris["u"][fs] = along / tris["len"][fs][:, :, None]
        vs = slice(v0[j], v0[j + 1])
        verts["p"][vs] = c.vertices
        verts["pn"][vs] = c.vertex_pn
        verts["weld"][vs] = c.vertex_origin + v0[j]
        offset = sum(len(x) for x in vertex_faces)
        verts["f0"][vs] = c.vertex_face_start[:-1] + offset
        verts["f1"][vs] = c.vertex_face_start[1:] + offset
        vertex_faces.append(c.vertex_faces + face0[j])
        es = slice(e0[j], e0[j + 1])
        edges["pn"][es] = c.edge_pn
        edges["faces"][es] = np.where(c.edge_faces >= 0, c.edge_faces + face0[j], -1)
        edges["tan"][es] = c.edge_tan
        extent = c.hi - c.lo
        tri_size = np.sqrt(
            np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
        )
        h = max(float(extent.max()) / _GRID_CELLS, float(np.median(tri_size)), 1e-9)
        dims = np.floor(extent / h).astype(np.int64) + 1
        o = objs[j]
        o["box"] = np.concatenate([c.lo, c.hi])
        o["prune"] = 1
        o["faces"] = face0[j], face0[j + 1]
        o["grid_origin"], o["grid_h"], o["grid_dims"], o["grid_base"] = c.lo, h, dims, base
        base += int(np.prod(dims))
    keys, grid_tris = grid_entries(verts, tris, face0, objs)
    order = np.argsort(keys, kind="stable")
    keys, grid_tris = keys[order], grid_tris[order]
    unique, first = np.unique(keys, return_index=True)
    around = np.concatenate(vertex_faces) if vertex_faces else np.zeros(0, dtype=np.int64)
    index = np.arange(len(tris))
    for k in range(3):
        fs = edges["faces"][tris["e"][:, k]]
        other = np.where(fs[:, 0] == index, fs[:, 1], fs[:, 0])
        tris["own"] |= ((other < 0) | (other > index)).astype(np.int64) << k
        tris["own"] |= (around[verts["f0"][tris["v"][:, k]]] == index).astype(np.int64) << (3 + k)
    edges["v"][tris["e"].ravel()] = np.column_stack([tris["v"].ravel(), np.roll(tris["v"], -1, axis=1).ravel()])
    # Each vertex's gentle concave edges (as a compressed row list), then each triangle's.
    gentle = edges["tan"][tris["e"]] > 0.0  # (F, 3)
    ends = np.stack([tris["v"], np.roll(tris["v"], -1, axis=1)], axis=2)[gentle]  # (G, 2)
    pairs = np.unique(np.column_stack([ends.ravel(), np.repeat(tris["e"][gentle], 2)]), axis=0).reshape(-1, 2)
    v_start = np.searchsorted(pairs[:, 0], np.arange(len(verts) + 1)).astype(np.int64)
    crease_lists(tris, edges, v_start, np.ascontiguousarray(pairs[:, 1], dtype=np.int64), tris["creases"])
    cells = np.zeros(len(unique) + 1, dtype=CELL)
    cells["key"][:-1] = unique
    cells["key"][-1] = np.iinfo(np.int64).max
    cells["start"] = np.append(first, len(keys)) + len(around)
    # Each object's column table after the grid's triangle lists: the first occupied cell of each
    # (x, y) column or beyond.
    tables = []
    at = len(around) + len(keys)
    for o in objs:
        nx, ny, nz = o["grid_dims"]
        columns = o["grid_base"] + np.arange(nx * ny, dtype=np.int64) * nz
        o["grid_cols"] = at
        tables.append(np.searchsorted(unique, columns).astype(np.int64))
        at += nx * ny
    return PackedMeshes(
        tris=tris,
        verts=verts,
        edges=edges,
        face0=face0,
        objs=objs,
        cells=cells,
        lists=np.ascontiguousarray(np.concatenate([around, grid_tris, *tables]), dtype=np.int64),
    )
