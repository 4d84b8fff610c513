"""Building an arm slave: the arm file with the tool on its flange, and the links' contact spheres.

Split from :mod:`app.world.arm` (the servo tick). Frames as there.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import mujoco
import numpy as np

from app.errors import ConfigError
from app.spatial import Array, IntArray, matrix_to_quat
from app.world.contact import ContactModel
from app.world.scene import CapsuleSpec, Scene, capsule_spheres
from app.world.scene_file import SLAVES_DIR

#: The tool's {T} on the flange: turned 180 deg about the flange's y, so {T}'s -z leaves the wrist
#: along the flange's z and, at the arms' home keyframes (flange z down, x toward the base), {T}
#: has the world's axes like every shipped scene's home.
_MOUNT_QUAT = np.array([0.0, 0.0, 1.0, 0.0])


@dataclass(frozen=True)
class ArmGeom:
    """One arm geom for display: MuJoCo geom ``type`` name, ``size`` (m, MuJoCo's meaning) and its
    pose ``T_w_geom`` (4, 4) in {w} (a capsule's axis is the geom's z)."""

    name: str
    type: str
    size: Array
    T_w_geom: Array


def arm_spec(scene: Scene, name: str, timestep: float) -> mujoco.MjSpec:
    """The arm file with the scene's tool mounted on the flange, its sites and F/T sensors."""
    path = SLAVES_DIR / name / "arm.xml"
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # MuJoCo raises ValueError with a multi-line parser message
        raise ConfigError(path, "<file>", " ".join(str(exc).split())[:200]) from None
    spec.option.timestep = timestep
    spec.option.gravity = scene.gravity_w
    flange = spec.site("flange")
    tool = scene.tool
    quat = np.zeros(4)
    mujoco.mju_mulQuat(quat, np.asarray(flange.quat, dtype=float), _MOUNT_QUAT)
    body = flange.parent.add_body(name="tool", pos=flange.pos, quat=quat)
    I = tool.inertia_T
    body.mass = tool.mass
    body.ipos = tool.com_T
    body.fullinertia = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
    body.explicitinertial = True
    for site, T in (("ft", tool.T_T_S), ("mrf", tool.T_T_MRF)):
        body.add_site(name=site, pos=T[0:3, 3], quat=matrix_to_quat(T[0:3, 0:3]))
    for kind in (mujoco.mjtSensor.mjSENS_FORCE, mujoco.mjtSensor.mjSENS_TORQUE):
        spec.add_sensor(type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="ft")
    return spec


def link_contact_models(
    model: mujoco.MjModel, tool_body: int, scene: Scene
) -> tuple[list[int], list[ContactModel], tuple[IntArray, Array, Array]]:
    """Per arm link of ``model`` with capsules (not the tool body ``tool_body``): its body id and a
    ContactModel of its sphere chains (the link frame as {MRF}); and all the links' spheres as
    ``(owner (s,), centres (s, 3) in the link frame, radii (s,))`` for
    :func:`~app.world.arm_kernel.links_near`."""
    m = model
    links: list[int] = []
    models: list[ContactModel] = []
    owner: list[IntArray] = []
    all_c: list[Array] = []
    all_r: list[Array] = []
    for b in range(1, m.nbody):
        if b == tool_body or m.body_dofnum[b] == 0:
            continue
        centers, radii = [], []
        for gid in np.flatnonzero(m.geom_bodyid == b):
            if m.geom_type[gid] != mujoco.mjtGeom.mjGEOM_CAPSULE:
                continue
            r, half = m.geom_size[gid, 0:2]
            R = np.zeros(9)
            mujoco.mju_quat2Mat(R, m.geom_quat[gid])
            axis = R.reshape(3, 3)[:, 2] * half
            c = m.geom_pos[gid]
            chain = capsule_spheres(CapsuleSpec(tuple(c - axis), tuple(c + axis), float(r)))
            centers.append(chain)
            radii.append(np.full(len(chain), r))
        if not centers:
            continue
        C = np.concatenate(centers)
        rad = np.concatenate(radii)
        geo = dataclasses.replace(
            scene.tool, centers_T=np.ascontiguousarray(C), radii=rad, T_T_MRF=np.eye(4), T_T_S=np.eye(4)
        )
        link_scene = dataclasses.replace(scene, tool=geo)
        # The objects are the scene's: share their packed meshes (a cached property).
        link_scene.__dict__["packed"] = scene.packed
        owner.append(np.full(len(rad), len(links), dtype=np.int64))
        all_c.append(C)
        all_r.append(rad)
        links.append(b)
        models.append(ContactModel(link_scene))
    spheres = (np.concatenate(owner), np.ascontiguousarray(np.concatenate(all_c)), np.concatenate(all_r))
    return links, models, spheres


def scene_box(scene: Scene) -> tuple[Array, Array]:
    """Bounding box (lo, hi) in {w} of every object, grown by the contact margin."""
    if not scene.objects:
        return np.full(3, np.inf), np.full(3, -np.inf)
    lo = np.min([o.collision.lo for o in scene.objects], axis=0) - scene.spec.margin
    hi = np.max([o.collision.hi for o in scene.objects], axis=0) + scene.spec.margin
    return lo, hi
