"""The checks a scene object's mesh must pass before contact can trust it.

Contact (:mod:`app.world.contact`) needs an inside: it signs distances with pseudonormals, which
is only meaningful on a closed, consistently wound, outward-facing surface. So, with one rule for
every mesh whatever its orientation in space:

- non-finite vertices are refused (before any processing: trimesh would silently drop them and
  leave a hole);
- a zero-area sliver whose middle vertex lies on its long edge (a T-junction closed by a sliver,
  as mesh exporters leave them) is repaired by splitting the triangle across that long edge at
  the middle vertex; dropping the sliver alone would open the surface;
- an open surface (a boundary edge: a single triangle, a box without its top, a terrain without
  sides) is refused with the count of boundary edges, as is a surface whose triangles are not
  consistently wound or that has no volume;
- a closed surface wound inside out (negative volume) is re-oriented.

A thin sheet must be modelled as a solid with a thickness (the ``plane`` primitive is a thin box).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from app.errors import ConfigError

#: Bytes of a binary STL's header (80) and triangle count (uint32), and of one triangle record.
_STL_HEADER, _STL_TRIANGLE = 84, 50
#: The bytes one face takes in the text formats counted by scanning, and bytes read per scan step.
_FACE_TOKENS = {".stl": b"endfacet", ".obj": b"\nf "}
_SCAN_CHUNK = 1 << 22


def declared_faces(path: Path) -> int | None:
    """The number of faces ``path`` holds, from its header or a byte scan, without parsing it.

    A lower bound on its triangles (a polygon face is at least one), so comparing it with a limit
    before trimesh builds the mesh refuses nothing a full load would accept: a binary STL's
    triangle count (80-byte header + uint32, when the file size agrees), a PLY's ``element face N``
    header line, the ``endfacet`` keywords of an ASCII STL or the ``f`` lines of an OBJ (counted
    in 4 MiB chunks, about a second for the 256 MiB file limit). None for other formats.
    """
    suffix = path.suffix.lower()
    with path.open("rb") as fh:
        head = fh.read(_STL_HEADER)
        if suffix == ".stl" and len(head) == _STL_HEADER:
            n = int.from_bytes(head[80:84], "little")
            if _STL_HEADER + _STL_TRIANGLE * n == path.stat().st_size:
                return n
        if suffix == ".ply":
            fh.seek(0)
            for line in iter(lambda: fh.readline(256), b""):
                words = line.split()
                if words[:2] == [b"element", b"face"] and len(words) == 3 and words[2].isdigit():
                    return int(words[2])
                if not words or words[0] == b"end_header":
                    return None
            return None
        token = _FACE_TOKENS.get(suffix)
        if token is None:
            return None
        fh.seek(0)
        count, tail = 0, b""
        while chunk := fh.read(_SCAN_CHUNK):
            buf = tail + chunk
            count += buf.count(token)
            tail = buf[-(len(token) - 1) :]  # shorter than a token: never counted twice
        return count


def checked_mesh(mesh: trimesh.Trimesh, source: str | Path, field: str) -> trimesh.Trimesh:
    """Validate and normalise an object's mesh as read (unprocessed); return the mesh to use.

    Args:
        mesh: The mesh as loaded, vertices in its object frame (m), not yet processed.
        source: The scene file, for the error.
        field: Dotted field of the mesh, for the error (``objects[2].mesh``).

    Raises:
        ConfigError: Non-finite vertices, no faces, zero area or volume, an open or
            inconsistently wound surface, naming ``source`` and ``field``.
    """
    vertices = np.asarray(mesh.vertices, dtype=float)
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise ConfigError(source, field, f"{int(bad.sum())} non-finite vertices (first at index {int(np.argmax(bad))})")
    mesh = trimesh.Trimesh(vertices, np.asarray(mesh.faces), process=True)
    mesh.remove_unreferenced_vertices()
    mesh = _split_slivers(mesh)
    mesh.update_faces(mesh.nondegenerate_faces())
    if len(mesh.faces) == 0 or float(mesh.area) <= 1e-12:
        raise ConfigError(source, field, "degenerate mesh: no faces or zero area")
    if not mesh.is_watertight:
        # Edges used by one face only (or by more than two) leave the inside undefined.
        edges = np.sort(mesh.edges, axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        open_edges = int(np.sum(counts != 2))
        raise ConfigError(
            source,
            field,
            f"mesh is not closed ({open_edges} edges without exactly two faces): contact needs a closed "
            "surface; give a thin sheet a thickness (e.g. the plane primitive)",
        )
    if not mesh.is_winding_consistent:
        raise ConfigError(source, field, "mesh triangles are not consistently wound (inside undefined)")
    if abs(float(mesh.volume)) <= 1e-18 or float(np.ptp(mesh.vertices, axis=0).min()) <= 1e-9:
        raise ConfigError(source, field, "degenerate mesh: flat, zero volume (no inside)")
    if mesh.volume < 0:
        mesh.invert()  # wound inside out: outward normals are what contact signs with
    return mesh


def _split_slivers(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` with each zero-area sliver of three distinct vertices removed and the triangle
    across its long edge split at its middle vertex, so that every edge keeps its two faces.

    The sliver (a, b, c) with c on edge ab closes a T-junction: the face across ab, (b, a, d) in
    its winding, becomes (b, c, d) and (c, a, d). Slivers with a repeated vertex (collapsed to a
    segment by the vertex merge) use each of their edges both ways and are dropped as they are.
    """
    degenerate = ~mesh.nondegenerate_faces()
    if not degenerate.any():
        return mesh
    faces = [list(f) for f in mesh.faces]
    v = np.asarray(mesh.vertices)
    dropped: set[int] = set()
    for i in np.flatnonzero(degenerate):
        f = faces[i]
        if len(set(f)) < 3:
            continue
        # The long edge (a, b) in the sliver's winding, and its middle vertex c.
        k = int(np.argmax([np.linalg.norm(v[f[(j + 1) % 3]] - v[f[j]]) for j in range(3)]))
        a, b, c = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
        across = next(
            (
                j
                for j, g in enumerate(faces)
                if j != i and j not in dropped and any(g[m] == b and g[(m + 1) % 3] == a for m in range(3))
            ),
            None,
        )
        if across is None:
            continue  # nothing to split: left to the closedness check, which reports it
        g = faces[across]
        m = next(m for m in range(3) if g[m] == b)
        d = g[(m + 2) % 3]
        faces[across] = [b, c, d]
        faces.append([c, a, d])
        dropped.add(int(i))
    keep = [f for j, f in enumerate(faces) if j not in dropped]
    return trimesh.Trimesh(v, np.array(keep, dtype=np.int64), process=False)
