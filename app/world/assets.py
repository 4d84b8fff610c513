"""Generator of the meshes in ``assets/`` used by the shipped scenes.

Run ``python -m app.world.assets`` to (re)write them. Booleans use trimesh's manifold3d engine,
so every mesh is watertight with outward normals. Units are metres; each mesh is written in its
own object frame (the scene file places it).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

from app.world.scene import ASSETS_DIR

# Dual peg-in-the-holes (paper Sec 4.3, which gives no dimensions): 12 mm pegs PEG_SPACING apart
# along x in holes with the ISO 286 / ANSI B4.2 "loose running" fit H11/c11 at 12 mm nominal: hole
# +0/+110 um, shaft -95/-205 um, diametral clearance 95-315 um; the pegs (radius PEG_RADIUS, the
# shaft's nominal) are kept and the hole takes the fit's mean clearance, 205 um, as 102.5 um radial.
PEG_RADIUS = 0.006
HOLE_RADIUS = PEG_RADIUS + 0.205e-3 / 2
PEG_SPACING = 0.06
HOLE_DEPTH = 0.025
# 45-degree entry chamfer on each hole, CHAMFER (m) wide and deep: Whitney (1982), "Quasi-static
# assembly of compliantly supported rigid parts", J. Dyn. Syst. Meas. Control 104:65-77, analyses
# the entry over 45-degree chamfers: a chamfer catches a lateral error up to its width plus the
# clearance. The width: the paper gives none. The American National Standard for straight pins
# (ASME B18.8.2) gives a 1/2 in (12.7 mm) chamfered pin a chamfer length of 0.020-0.040 in
# (0.51-1.02 mm; secondary: its Table 1 as reprinted in "Shop Reference for Students and
# Apprentices", 2nd ed., globalspec.com "Pins"); 1 mm is the top of that range, and a machining
# vendor's chamfer guide (yqunique.com, "standard chamfer sizes") gives 1 mm x 45 deg as a usual
# CNC default. The standard chamfers the pin; here the hole is chamfered (the pegs' ends are round).
# 1 mm catches 1.1 mm, less than half of the operators' lateral misalignment range
# (app/session/operators.py); the others land on the top face and search.
CHAMFER = 0.001
#: Radius (m) of a hole's rim on the block's top face, where its chamfer starts.
RIM_RADIUS = HOLE_RADIUS + CHAMFER
BLOCK_EXTENTS = (0.14, 0.08, 0.04)  # top face at z = 0 in the object frame

BOWL_OUTER_RADIUS = 0.08
BOWL_HEIGHT = 0.08  # deeper than the cavity, so the bowl has a bottom
BOWL_CAVITY_RADIUS = 0.06  # spherical cavity centred on the top face (z = 0)

TERRAIN_EXTENTS = (0.3, 0.3, 0.04)  # top face at z = 0 before the bumps
TERRAIN_BUMP = 0.008  # amplitude (m) of the smooth bumps
TERRAIN_SUBDIVISIONS = 7  # 12 * 4**7 = 196608 triangles


def peg_block() -> trimesh.Trimesh:
    """A block with two blind round holes, each with a 45-degree entry chamfer; top face at z = 0,
    holes at x = +-PEG_SPACING/2."""
    block = trimesh.creation.box(extents=BLOCK_EXTENTS)
    block.apply_translation((0.0, 0.0, -BLOCK_EXTENTS[2] / 2))
    # The cutter's profile (radius, z), revolved about z: the bore, the chamfer's cone from
    # (HOLE_RADIUS, -CHAMFER) through the rim (RIM_RADIUS, 0), continued above the top face so the
    # boolean cuts cleanly.
    above = 0.002
    profile = [
        (0.0, -HOLE_DEPTH),
        (HOLE_RADIUS, -HOLE_DEPTH),
        (HOLE_RADIUS, -CHAMFER),
        (RIM_RADIUS + above, above),
        (0.0, above),
    ]
    holes = []
    for x in (-PEG_SPACING / 2, PEG_SPACING / 2):
        # 256 sections: the polygon's inscribed radius is within 0.5 um of HOLE_RADIUS.
        hole = trimesh.creation.revolve(np.array(profile), sections=256)
        hole.apply_translation((x, 0.0, 0.0))
        holes.append(hole)
    return trimesh.boolean.difference([block, *holes], engine="manifold")


def bowl() -> trimesh.Trimesh:
    """A cylinder with a hemispherical cavity of BOWL_CAVITY_RADIUS centred on its top face (z = 0)."""
    body = trimesh.creation.cylinder(radius=BOWL_OUTER_RADIUS, height=BOWL_HEIGHT, sections=128)
    body.apply_translation((0.0, 0.0, -BOWL_HEIGHT / 2))
    cavity = trimesh.creation.icosphere(subdivisions=5, radius=BOWL_CAVITY_RADIUS)
    return trimesh.boolean.difference([body, cavity], engine="manifold")


def terrain() -> trimesh.Trimesh:
    """A slab whose top face (z = 0) carries smooth bumps; over 100k triangles."""
    ex, ey, ez = TERRAIN_EXTENTS
    slab = trimesh.creation.box(extents=TERRAIN_EXTENTS)
    slab.apply_translation((0.0, 0.0, -ez / 2))
    v, f = slab.vertices, slab.faces
    for _ in range(TERRAIN_SUBDIVISIONS):
        v, f = trimesh.remesh.subdivide(v, f)
    v = np.array(v)
    top = v[:, 2] > -1e-9
    x, y = v[top, 0] / ex, v[top, 1] / ey  # in [-0.5, 0.5]
    # Bumps vanish at the border so the side walls stay planar and the mesh stays closed.
    envelope = np.cos(math.pi * x) * np.cos(math.pi * y)
    v[top, 2] = TERRAIN_BUMP * envelope * np.sin(6 * math.pi * x) * np.cos(4 * math.pi * y)
    return trimesh.Trimesh(v, f, process=True)


MESHES = {"peg_block.ply": peg_block, "bowl.ply": bowl, "terrain.ply": terrain}


def write_all(directory: Path = ASSETS_DIR) -> list[Path]:
    """Write every mesh of :data:`MESHES` (binary PLY) into ``directory``; return the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, make in MESHES.items():
        mesh = make()
        if not mesh.is_watertight:
            raise RuntimeError(f"{name}: generated mesh is not watertight")
        path = directory / name
        mesh.export(path, encoding="binary")
        paths.append(path)
    return paths


if __name__ == "__main__":
    for p in write_all():
        m = trimesh.load_mesh(p)
        print(f"{p.relative_to(ASSETS_DIR.parent)}: {len(m.faces)} triangles, {p.stat().st_size / 1e6:.2f} MB")
