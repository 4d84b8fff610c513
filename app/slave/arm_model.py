"""Building an arm slave: the arm file with the tool on its flange, its tuning and record, and
the links' contact spheres.

Split from :mod:`app.slave.arm` (the running slave). Frames as there.
"""

from __future__ import annotations

import dataclasses
import math
from contextlib import suppress
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import mujoco
import numpy as np

from app.errors import ConfigError
from app.mjcall import file_warnings, refuse_warned
from app.slave import arm_ik
from app.slave.arm_kernel import arm_record_dtype
from app.spatial import Array, IntArray, matrix_to_quat
from app.world.contact import ContactModel
from app.world.scene import CapsuleSpec, Scene, capsule_spheres
from app.world.scene_file import SLAVES_DIR

#: The tool's {T} on the flange: turned 180 deg about the flange's y, so {T}'s -z leaves the wrist
#: along the flange's z and, at the arms' home keyframes (flange z down, x toward the base), {T}
#: has the world's axes like every shipped scene's home.
_MOUNT_QUAT = np.array([0.0, 0.0, 1.0, 0.0])


@dataclass(frozen=True)
class ArmParams:
    """Tuning of the arm's IK and joint servos (the same for every arm; rates per second).

    Attributes:
        servo_bandwidth: Joint servo natural frequency (Hz); ``kp = M_ii w^2`` with ``M_ii`` the
            joint's inertia (armature included) at the home configuration.
        servo_damping: Joint servo damping ratio (-): ``kd = 2 zeta M_ii w``.
        k_ik: Gain (1/s) on the set-point's pose error (half of it corrected per 1 ms tick).
        lambda_max: Largest damping (-) of the least squares, reached at a singularity.
        eps_singular: Smallest singular value of J (m or rad per rad) below which damping starts.
        k_limit: Rate (1/s) at which a joint may approach its soft limit.
        k_null: Null-space pull (1/s) toward the middle of the joint ranges (redundant arms only).
        limit_margin: Soft joint limits inside the hard stops (rad).
        dead_lin, dead_rot: Dead band (m, rad) of the limit wrench.
    """

    servo_bandwidth: float = 12.0
    servo_damping: float = 1.0
    k_ik: float = 500.0
    lambda_max: float = 0.08
    eps_singular: float = 0.06
    k_limit: float = 20.0
    k_null: float = 1.0
    limit_margin: float = 0.05
    dead_lin: float = 0.001
    dead_rot: float = 0.01


@dataclass(frozen=True)
class ArmGeom:
    """One arm geom for display: MuJoCo geom ``type`` name, ``size`` (m, MuJoCo's meaning) and its
    pose ``T_w_geom`` (4, 4) in {w} (a capsule's axis is the geom's z)."""

    name: str
    type: str
    size: Array
    T_w_geom: Array


def arm_model(scene: Scene, name: str, timestep: float) -> mujoco.MjModel:
    """The arm file ``slaves/<name>/arm.xml`` compiled with the scene's tool on its flange
    (:func:`arm_spec`).

    Raises:
        ConfigError: naming the file and MuJoCo's reason when it does not compile (a link with
            zero or negative mass, an inverted ``ctrlrange``, a zero-sized geom).
    """
    spec = arm_spec(scene, name, timestep)
    try:
        return spec.compile()
    except ValueError as exc:  # MuJoCo's multi-line compiler message, naming the element and line
        raise ConfigError(SLAVES_DIR / name / "arm.xml", "<file>", " ".join(str(exc).split())[:200]) from None


def arm_spec(scene: Scene, name: str, timestep: float) -> mujoco.MjSpec:
    """The arm file with the scene's tool mounted on the flange, its sites and F/T sensors.

    Raises:
        ConfigError: naming the file and the element the arm needs and the file lacks (the
            ``flange`` site, the ``base`` body, the ``home`` keyframe with one angle per joint).
    """
    path = SLAVES_DIR / name / "arm.xml"
    try:
        with file_warnings() as warned:
            spec = mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # MuJoCo raises ValueError with a multi-line parser message
        raise ConfigError(path, "<file>", " ".join(str(exc).split())[:200]) from None
    if warned:  # a NaN: name the limit field it is in if it is in one, else the file
        with file_warnings(), suppress(ValueError):
            _check_limits(spec.copy().compile(), path)
        refuse_warned(warned, path, "<file>")
    _check_elements(spec, path)
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
    :func:`~app.slave.arm_kernel.links_near`."""
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


def place_base(model: mujoco.MjModel, data: mujoco.MjData, scene: Scene) -> tuple[Array, Array]:
    """Move the upright base so that the home keyframe puts {MRF} at the scene's home position.

    Returns the home joint angles (n,) (rad) and the base pose ``T_w_base`` (4, 4).
    """
    m, d = model, data
    q_home = m.key_qpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")].copy()
    d.qpos[:] = q_home
    mujoco.mj_kinematics(m, d)
    base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "base")
    mrf = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "mrf")
    T_w_base = np.eye(4)
    T_w_base[0:3, 3] = scene.tool.T_w_MRF_home[0:3, 3] - d.site_xpos[mrf]
    m.body_pos[base] = T_w_base[0:3, 3]
    return q_home, T_w_base


def _check_elements(spec: mujoco.MjSpec, path: Path) -> None:
    """The elements the arm is built from are there: without them the build failed in an
    AttributeError (no ``flange``), an IndexError (no ``home``) or moved the wrong body (no ``base``:
    ``mj_name2id`` gives -1, and ``body_pos[-1]`` is the last link's) and refused every reset.

    Raises:
        ConfigError: naming ``path`` and the missing element.
    """
    if spec.site("flange") is None:
        raise ConfigError(path, "site flange", "missing: the tool is mounted on a site named 'flange' on the last link")
    if spec.body("base") is None:
        raise ConfigError(
            path, "body base", "missing: the arm's root body must be named 'base' (it is moved to reach home)"
        )
    key, n = spec.key("home"), len(spec.joints)
    if key is None:
        raise ConfigError(path, "key home", "missing: a <key name='home'> with one angle per joint")
    if len(key.qpos) != n:
        raise ConfigError(path, "key home.qpos", f"needs {n} joint angles (rad), got {len(key.qpos)}")


def _check_limits(m: mujoco.MjModel, path: Path) -> None:
    """The arm's limits must be usable: MuJoCo compiles a NaN (with a warning) and a zero, and the
    arm then never moves, silently (measured: a PUMA whose velocity limits were NaN or 0 left the
    probe session without a contact and without a fault; a NaN joint range failed its first IK).

    Raises:
        ConfigError: naming ``path`` and the joint's range, ``velocity_limit`` or the motor's
            ``ctrlrange``.
    """
    name = partial(mujoco.mj_id2name, m)
    home = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    for j in range(m.nu):
        lo, hi = m.jnt_range[j]
        joint = name(mujoco.mjtObj.mjOBJ_JOINT, j)
        if not (m.jnt_limited[j] and math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ConfigError(path, f"joint {joint}.range", "needs finite limits, low < high")
        if home >= 0 and not lo <= m.key_qpos[home, j] <= hi:
            raise ConfigError(
                path,
                "key home.qpos",
                f"joint {joint} at {m.key_qpos[home, j]:.4g} rad is outside its range [{lo:.4g}, {hi:.4g}]",
            )
        for field, value in (("damping", m.dof_damping[j]), ("armature", m.dof_armature[j])):
            if not value >= 0.0:  # a negative damping feeds the joint energy
                raise ConfigError(path, f"joint {joint}.{field}", f"must be >= 0, got {value:.4g}")
        tau = m.actuator_ctrlrange[j]
        if not (np.isfinite(tau).all() and tau[1] > 0.0):
            raise ConfigError(
                path,
                f"motor {name(mujoco.mjtObj.mjOBJ_ACTUATOR, j)}.ctrlrange",
                "the torque limit must be finite and > 0",
            )
    try:
        qd_max = m.numeric("velocity_limit").data
    except KeyError:
        raise ConfigError(path, "velocity_limit", "missing: a <numeric> with one speed (rad/s) per joint") from None
    if len(qd_max) != m.nu or not (np.isfinite(qd_max).all() and (qd_max > 0.0).all()):
        raise ConfigError(path, "velocity_limit", f"needs {m.nu} finite speeds > 0 (rad/s), got {qd_max.tolist()}")


def arm_record(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    scene: Scene,
    params: ArmParams,
    links: list[int],
    spheres: tuple[IntArray, Array, Array],
) -> Array:
    """The arm's record (:func:`~app.slave.arm_kernel.arm_record_dtype`, one element) with its
    constants filled in; ``data`` holds the configuration the servo gains are tuned at.

    Raises:
        ConfigError: A joint is not a hinge on the tool's chain, which the record's Jacobian
            (:func:`~app.slave.arm_kernel.mrf_state`) assumes.
    """
    m, d = model, data
    n = m.nu
    obj = mujoco.mjtObj
    tool = mujoco.mj_name2id(m, obj.mjOBJ_BODY, "tool")
    chain = set()
    b = tool
    while b > 0:
        chain.add(b)
        b = int(m.body_parentid[b])
    hinges = m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE
    if m.njnt != n or m.nv != n or not hinges.all() or not set(m.jnt_bodyid.tolist()) <= chain:
        raise ConfigError(
            SLAVES_DIR / scene.spec.slave.kind / "arm.xml",
            "<joints>",
            "every joint must be a hinge on the flange's chain, one motor each",
        )
    _check_limits(m, SLAVES_DIR / scene.spec.slave.kind / "arm.xml")
    owner, centers, radii = spheres
    rec = np.zeros(1, dtype=arm_record_dtype(n, len(links), len(radii), m.nM))
    r = rec[0]
    rng = m.jnt_range[:n]
    r["lo"] = rng[:, 0] + params.limit_margin
    r["hi"] = rng[:, 1] - params.limit_margin
    r["mid"] = 0.5 * (rng[:, 0] + rng[:, 1])
    r["qd_max"] = m.numeric("velocity_limit").data
    r["tau_max"] = m.actuator_ctrlrange[:, 1]
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    w = 2.0 * math.pi * params.servo_bandwidth
    r["kp"] = np.diag(M) * w * w
    r["kd"] = np.diag(M) * 2.0 * params.servo_damping * w
    ik = np.zeros(5)
    ik[[arm_ik.K_IK, arm_ik.LAMBDA_MAX, arm_ik.EPS_SING, arm_ik.K_LIMIT, arm_ik.K_NULL]] = (
        params.k_ik,
        params.lambda_max,
        params.eps_singular,
        params.k_limit,
        params.k_null if n > 6 else 0.0,
    )
    r["ik"] = ik
    g = scene.spec.slave
    r["feel"] = (params.dead_lin, params.dead_rot, g.kp_lin, g.kp_rot, g.force_limit, g.torque_limit)
    r["sv"] = 1.0
    r["T"] = r["T_ref"] = np.eye(4)  # mrf_state writes the rotation and origin only
    r["links"] = links
    r["owner"], r["centers"], r["radii"] = owner, centers, radii
    r["box"] = scene_box(scene)
    r["site_mrf"] = mujoco.mj_name2id(m, obj.mjOBJ_SITE, "mrf")
    r["site_ft"] = mujoco.mj_name2id(m, obj.mjOBJ_SITE, "ft")
    r["tool"] = tool
    r["root"] = m.body_rootid[tool]
    r["sensor"] = m.sensor_adr[0]
    r["M_adr"], r["M_nnz"], r["M_col"] = m.M_rowadr, m.M_rownnz, m.M_colind
    r["jnt_body"] = m.jnt_bodyid[:n]
    return rec
