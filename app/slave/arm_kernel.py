"""The arm slave's tick around MuJoCo (:mod:`app.slave.arm`), compiled with numba.

One servo tick of :class:`~app.slave.arm.ArmSlave` crosses from Python into compiled code three
times, whatever the arm: :func:`mrf_state` after ``mj_step1`` (the {MRF} Jacobian, pose and
twist), :func:`control` before ``mj_step2`` (the IK of :mod:`app.slave.arm_ik`, the joint servo,
the tool's contact wrench and which links are near the world) and :func:`ft_reading` after it;
with a link near the world once more, :func:`links_end` (the links' contacts, the implicit step
and ``mj_step2``), which was Python glue around the compiled parts before.
Each crossing costs about 0.1 us per argument, so everything the arm owns (its constants, the IK
state and the {MRF} buffers) is one numpy record (:func:`arm_record_dtype`) passed as a single
argument; MuJoCo's arrays are passed as they are (views of ``MjData``, fetched once).

The joint servo: ``tau = kp (q_c - q) + kd (qd_c - qd) + bias`` with ``bias`` MuJoCo's gravity
and Coriolis forces, its speed demand clamped to the joint's velocity limit (:func:`joint_servo`),
saturated at each motor's torque limit.

The contacts (the tool's and the links') are made as implicit as the substep's stability needs
(:func:`implicit_contacts`), with the ideal tool's parts (:func:`app.slave.tool_kernel.implicit_wrench`)
in the arm's joint coordinates: the tool then meets the arm's operational-space inertia, not its own mass.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.mjcall import call_model_data
from app.slave.arm_ik import (
    TORQUE,
    VELOCITY,
    cholesky,
    cholesky_solve,
    gram_cholesky,
    ik_step,
    matTvec,
    matvec,
    pose_error,
)
from app.slave.tool_kernel import (
    contact_gains,
    correction,
    implicit_acceleration,
    implicit_shares,
    mul3,
    shift_wrench,
)
from app.spatial import Array, IntArray, cross3, rotation_exp
from app.world.contact.step import contact_step_bundled

#: Slots of the MuJoCo addresses a substep is handed (:mod:`app.mjcall`): ``mj_step1``,
#: ``mj_step2``, ``mjModel*``, ``mjData*``, then the acceleration stages ``mj_step2`` runs before
#: it integrates, which :func:`implicit_contacts` runs once more for the explicit accelerations.
STEP1, STEP2, MODEL, DATA, FWD_ACTUATION, FWD_ACCELERATION, FWD_CONSTRAINT = range(7)
#: No correction for anything but the contact: the joint servos are far inside the explicit
#: step's bounds (12 Hz at 1 kHz: omega h = 0.08) and MuJoCo's Euler integrates joint damping implicitly.
_NO_OTHER = np.zeros(2)
#: Compliance (m/N and rad/(N m)) added to the diagonal of the arm's at {MRF} in :func:`bound_lead`:
#: a structure 10^4 times stiffer than the servos (about 10^5 N/m and 10^3 N m/rad at {MRF}) in
#: series with them, which keeps the solve defined at an exact singularity and changes nothing elsewhere.
_RIGID = 1e-9


def arm_record_dtype(n: int, links: int, spheres: int, n_M: int) -> np.dtype:
    """The arm's record for ``n`` hinge joints, ``links`` links with contact spheres, ``spheres``
    spheres and ``n_M`` stored entries of the joint-space inertia.

    Fields (angles rad, rates rad/s, torques N m, lengths m; {w} unless stated):

    Constants:
        lo, hi: Soft joint limits (n,). qd_max: joint velocity limits (n,). mid: the redundant
        arm's secondary goal (n,). kp, kd: servo gains (N m/rad, N m s/rad), (n,). tau_max:
        motor torque limits (n,). ik: :data:`~app.slave.arm_ik.K_IK` ... parameters (5,). feel:
        ``[dead_lin, dead_rot, kp_lin, kp_rot, f_max, t_max]`` of
        :func:`~app.slave.arm_ik.limit_wrench`. links: body ids of the links with contact spheres
        (links,). owner: index into ``links`` of each sphere (spheres,); centers: sphere centres
        in their link's frame (spheres, 3); radii (spheres,). box: ``[lo; hi]`` of every object,
        grown by the contact margin (2, 3). site_mrf, site_ft: MuJoCo site ids of {MRF} and {S};
        tool: the tool's body id; root: its root body (MuJoCo's ``cacc`` is about that body's
        subtree centre of mass); sensor: address of the force sensor in ``sensordata`` (the
        torque sensor follows).

    State:
        q_c, qd_c: Joint set-point and its rate (n,). sv: ``[sigma_min, warm start (6)]``. e: the
        set-point's pose error (6,). W_limit: the limit wrench at {MRF} (6,). jac: {MRF} Jacobian
        (6, n), rows ``[v; w]``. T, V: {MRF} pose (4, 4) and twist ``[v; w]`` (6,). T_ref,
        V_ref: the Cartesian reference pose (4, 4) and twist (6,). near: the links whose spheres
        reach ``box``, 1 or 0 (links,) (numba's records hold no bool arrays).

    MuJoCo's joint-space inertia ``mjData.M`` is compressed by rows of its lower triangle:
    ``M_adr``, ``M_nnz`` (n,) and ``M_col`` (nM,) are the model's ``M_rowadr``, ``M_rownnz`` and
    ``M_colind``; ``jnt_body`` (n,) each joint's body id.
    """
    f8, i8 = np.float64, np.int64
    fields: list[tuple[str, type, tuple[int, ...]]] = [
        *((name, f8, (n,)) for name in ("lo", "hi", "qd_max", "mid", "kp", "kd", "tau_max", "q_c", "qd_c")),
        ("ik", f8, (5,)),
        ("feel", f8, (6,)),
        ("sv", f8, (7,)),
        ("e", f8, (6,)),
        ("W_limit", f8, (6,)),
        ("jac", f8, (6, n)),
        ("T", f8, (4, 4)),
        ("V", f8, (6,)),
        ("T_ref", f8, (4, 4)),
        ("V_ref", f8, (6,)),
        ("links", i8, (links,)),
        ("near", i8, (links,)),
        ("owner", i8, (spheres,)),
        ("centers", f8, (spheres, 3)),
        ("radii", f8, (spheres,)),
        ("box", f8, (2, 3)),
        ("M_adr", i8, (n,)),
        ("M_nnz", i8, (n,)),
        ("M_col", i8, (n_M,)),
        ("jnt_body", i8, (n,)),
    ]
    scalars = [(name, i8) for name in ("site_mrf", "site_ft", "tool", "root", "sensor")]
    return np.dtype([*fields, *scalars])


@njit(cache=True)
def mrf_state(rec: Array, xanchor: Array, xaxis: Array, site_xpos: Array, site_xmat: Array, qvel: Array) -> None:
    """The {MRF} Jacobian, pose and twist of the current kinematics into ``rec`` (``jac``, ``T``, ``V``).

    Every joint is a hinge on the tool's chain (checked by the arm's constructor), so column k of
    the Jacobian is ``[a_k x (p - c_k); a_k]`` with ``a_k``, ``c_k`` MuJoCo's joint axis and anchor
    in {w} (``xaxis``, ``xanchor``, (njnt, 3)) and p the {MRF} origin; the same as ``mj_jacSite``
    without a call through the bindings.

    Args:
        rec: The arm's record (a one-element array of :func:`arm_record_dtype`).
        site_xpos, site_xmat: MuJoCo's site positions (nsite, 3) and orientations (nsite, 9).
        qvel: Joint velocities (n,).
    """
    r = rec[0]
    s = r["site_mrf"]
    J, T = r["jac"], r["T"]
    p = site_xpos[s]
    for i in range(3):
        T[i, 3] = p[i]
        for j in range(3):
            T[i, j] = site_xmat[s, 3 * i + j]
    for k in range(J.shape[1]):
        a = xaxis[k]
        v = cross3(a, p - xanchor[k])
        for i in range(3):
            J[i, k] = v[i]
            J[3 + i, k] = a[i]
    r["V"][:] = matvec(J, qvel)


@njit(cache=True)
def begin_substep(
    mj: IntArray, rec: Array, xanchor: Array, xaxis: Array, site_xpos: Array, site_xmat: Array, qvel: Array
) -> None:
    """MuJoCo's ``mj_step1`` (kinematics and forces of the present state), then :func:`mrf_state`.

    ``mj``: MuJoCo's addresses (slots :data:`STEP1` ...), (7,).
    """
    call_model_data(mj[STEP1], mj[MODEL], mj[DATA])
    mrf_state(rec, xanchor, xaxis, site_xpos, site_xmat, qvel)


@njit(cache=True)
def _largest_share(a: Array, b: Array, limit: float) -> float:
    """The largest ``s`` in [0, 1] with ``|s a + b| <= limit`` (3-vectors ``a``, ``b``), or -1 if
    even ``s = 0`` exceeds it: the upper root of ``|a|^2 s^2 + 2 (a . b) s + |b|^2 - limit^2 = 0``."""
    aa = a[0] * a[0] + a[1] * a[1] + a[2] * a[2]
    ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    c = b[0] * b[0] + b[1] * b[1] + b[2] * b[2] - limit * limit
    if c > 0.0:
        return -1.0
    if aa == 0.0:
        return 1.0
    return min(1.0, (-ab + math.sqrt(ab * ab - aa * c)) / aa)


@njit(cache=True)
def bound_lead(rec: Array) -> bool:
    """Bound the Cartesian reference's lead over the tool so that the joint servos push a blocked
    tool with at most the scene's force and torque limits, as the ideal tool's following-error
    limit does for its PD.

    A lead ``e = [e_p; e_r]`` (:func:`~app.slave.arm_ik.pose_error` of the measured {MRF} pose
    against the reference, m and rad, {w}) is, once the set-point has reached the reference and
    the tool is held, a joint deflection ``q_c - q`` with ``K_q (q_c - q) = J^T W`` (the servo
    torques balance the wrench ``W`` on the tool) and ``J (q_c - q) = e``, so ``W = K e`` with
    the arm's stiffness at {MRF} ``K = (J K_q^-1 J^T)^-1`` (``K_q = diag(kp)``, J at the
    measured joints; ``J^-T K_q J^-1`` for a 6-dof arm, and for a redundant one what its null
    space settles to). As the ideal tool scales its translational and rotational leads apart
    (``force_limit / kp_lin``, ``torque_limit / kp_rot``), so here: ``e_p`` is scaled by the
    largest share ``s_p <= 1`` that keeps the force ``s_p K_pp e_p + K_pr e_r`` within
    ``f_max`` and the torque within ``t_max``, the reference's orientation kept; only if the
    rotational lead alone asks for more are both scaled by one share. Keeping the unsaturated
    part fixed in the world matters: re-anchoring it to the tool each tick would let a tool
    whose rotation nothing resists (one sphere) creep without end. For the ideal tool's diagonal
    ``K`` this is its own limit. The reference twist is zeroed when the lead is bounded: a held
    reference asks the IK for no motion (following the tool's motion instead cancels the servos'
    damping: a blocked PUMA rang at 20 Hz, growing to 91 N, measured).

    Args:
        rec: The arm's record: ``jac``, ``T`` measured; ``kp``; ``feel`` (``f_max``, ``t_max``);
            ``T_ref``, ``V_ref`` updated in place.

    Returns:
        Whether the lead was bounded.
    """
    r = rec[0]
    J, kp, T, T_ref, V_ref, feel = r["jac"], r["kp"], r["T"], r["T_ref"], r["V_ref"], r["feel"]
    e = np.empty(6)
    pose_error(T_ref, T[0:3, 3], T[0:3, 0:3], e)
    L = gram_cholesky(J, 1.0 / kp, _RIGID)
    lin, rot = np.zeros(6), np.zeros(6)
    lin[0:3] = e[0:3]
    rot[3:6] = e[3:6]
    W_p, W_r = cholesky_solve(L, lin), cholesky_solve(L, rot)  # the wrenches of the two leads
    s_f = _largest_share(W_p[0:3], W_r[0:3], feel[4])
    s_t = _largest_share(W_p[3:6], W_r[3:6], feel[5])
    s_p, s_r = min(s_f, s_t), 1.0
    if s_p < 0.0:  # the rotational lead alone is too much: one share for both (W is linear in it)
        W = W_p + W_r
        f = math.sqrt(W[0] * W[0] + W[1] * W[1] + W[2] * W[2])
        t = math.sqrt(W[3] * W[3] + W[4] * W[4] + W[5] * W[5])
        s_p = s_r = min(1.0, feel[4] / max(f, 1e-300), feel[5] / max(t, 1e-300))
    if s_p >= 1.0:
        return False
    for i in range(3):
        T_ref[i, 3] = T[i, 3] + s_p * e[i]
    if s_r < 1.0:
        T_ref[0:3, 0:3] = mul3(rotation_exp(s_r * e[3:6]), T[0:3, 0:3])
    V_ref[:] = 0.0
    return True


@njit(cache=True)
def control(
    rec: Array,
    ik: bool,
    dt: float,
    h: float,
    qpos: Array,
    qvel: Array,
    bias: Array,
    ctrl: Array,
    xfrc: Array,
    xpos: Array,
    xmat: Array,
    xipos: Array,
    qacc: Array,
    M: Array,
    xanchor: Array,
    xaxis: Array,
    site_xpos: Array,
    site_xmat: Array,
    contact: Array,
    rows: Array,
    materials: Array,
    contact_valid: bool,
    mj: IntArray,
) -> tuple[int, bool]:
    """One substep's control: the IK (``ik``: first substep of a tick of ``dt`` s), joint servo
    into ``ctrl``, the tool's contact wrench into ``xfrc`` (cleared first) and the near links.

    Args:
        rec: The arm's record; ``jac``, ``T``, ``T_ref``, ``V_ref`` current.
        h: The substep (s).
        qpos, qvel, bias, ctrl: MuJoCo's joint angles, velocities, bias forces and controls.
        xfrc: MuJoCo's applied body wrenches (nbody, 6), ``[f; torque about the com]``.
        xpos, xmat, xipos: Body origins (nbody, 3), orientations (nbody, 9), centres of mass (nbody, 3).
        qacc, M, xanchor, xaxis, site_xpos, site_xmat, contact, rows, materials: As for
            :func:`implicit_contacts` (``rows`` the tool's alone).
        contact_valid: Whether ``contact`` is valid (an invalid one has no rows).
        mj: As for :func:`begin_substep`: with no link near the world the substep ends here
            (:func:`implicit_contacts`, ``mj_step2``); otherwise the caller adds the links'
            contact wrenches first.

    Returns:
        Status bits (:mod:`app.slave.arm_ik`) and whether any link is near the world (``rec.near``).
    """
    r = rec[0]
    n = r["q_c"].shape[0]
    status = 0
    if ik:
        status = ik_step(
            r["jac"],
            r["T_ref"],
            r["V_ref"],
            r["T"],
            qpos[:n],
            r["q_c"],
            r["qd_c"],
            r["lo"],
            r["hi"],
            r["qd_max"],
            r["mid"],
            r["ik"],
            r["sv"],
            r["feel"],
            dt,
            r["e"],
            r["W_limit"],
        )
    status |= joint_servo(
        r["q_c"], r["qd_c"], qpos[:n], qvel[:n], bias[:n], r["kp"], r["kd"], r["qd_max"], r["tau_max"], ctrl
    )
    xfrc[:] = 0.0
    if contact_valid:
        T = r["T"]
        b = r["tool"]
        body_wrench(contact[12:15], contact[9:12], T[0:3, 0:3], T[0:3, 3], xipos[b], xfrc[b])
    near = r["near"]
    links_near(xpos, xmat, r["links"], r["owner"], r["centers"], r["radii"], r["box"], near)
    any_near = near.any()
    if not any_near:
        implicit_contacts(
            mj,
            rec,
            h,
            qvel,
            qacc,
            M,
            xfrc,
            xanchor,
            xaxis,
            xipos,
            site_xpos,
            site_xmat,
            contact,
            rows,
            np.zeros(rows.shape[0], dtype=np.int64),
            np.full(1, r["tool"]),
            materials,
            np.empty((1, 6)),
        )
        call_model_data(mj[STEP2], mj[MODEL], mj[DATA])
    return status, any_near


@njit(cache=True)
def body_jacobian(rec: Array, b: int, c: Array, xanchor: Array, xaxis: Array, out: Array) -> None:
    """Into ``out`` (6, n): the Jacobian of body ``b``'s twist ``[v of the point c (m, {w}); w]``
    in the joint rates. The joints form one chain (:func:`~app.slave.arm_model.arm_record`) whose
    bodies MuJoCo numbers from the base out, so joint k moves ``b`` if its body's id is at most ``b``."""
    J_body = rec[0]["jnt_body"]
    for k in range(out.shape[1]):
        if J_body[k] > b:
            out[:, k] = 0.0
            continue
        v = cross3(xaxis[k], c - xanchor[k])
        for i in range(3):
            out[i, k] = v[i]
            out[3 + i, k] = xaxis[k, i]


@njit(cache=True)
def implicit_contacts(
    mj: IntArray,
    rec: Array,
    h: float,
    qvel: Array,
    qacc: Array,
    M: Array,
    xfrc: Array,
    xanchor: Array,
    xaxis: Array,
    xipos: Array,
    site_xpos: Array,
    site_xmat: Array,
    contact: Array,
    rows: Array,
    groups: Array,
    bodies: IntArray,
    materials: Array,
    d: Array,
) -> None:
    """Make the substep ``h`` (s) implicit in the contact stiffnesses and dampings on the arm (the
    tool's and the links') as far as its stability needs, as
    :func:`app.slave.tool_kernel.implicit_wrench` does for the ideal tool, with the same parts:
    correct ``xfrc`` and the tool's ``contact``.

    The arm's coordinates are its joints: each body ``b`` touching the world (``bodies``) adds
    ``J_b^T K_b J_b`` and ``J_b^T C_b J_b`` (:func:`body_jacobian` at its centre of mass; K_b, C_b
    of its contact rows, :func:`~app.slave.tool_kernel.contact_gains`), and the mass matrix is
    MuJoCo's joint-space inertia M_q with the motors' armature. For the tool alone the modes of
    ``M_q^-1 J^T K J`` are those of ``Lambda^-1 K``, ``Lambda = (J M_q^-1 J^T)^-1`` the arm's
    operational-space inertia at the tool: what a wrench on the tool meets through the whole arm
    (a redundant arm's null space takes none of it), not the tool's own 0.6 kg. The explicit
    accelerations ``qacc`` come from MuJoCo's own acceleration stages with every wrench of the
    substep in ``xfrc`` (servo torques, gravity, joint limits, the contacts); each body's
    correction is then ``-(hk K_b (u_b + h a_b) + hc C_b a_b)`` with its twist ``u_b = J_b qvel``
    and ``a_b = J_b qacc_implicit``, applied at its centre of mass (summed over the bodies, the
    joint-space correction). Nothing but contact is made implicit (:data:`_NO_OTHER`).

    Args:
        mj: MuJoCo's addresses (slots :data:`STEP1` ...), (7,).
        rec: The arm's record; ``jac`` and ``T`` of the substep's start.
        qvel, qacc: MuJoCo's joint velocities (n,) and accelerations (n,; overwritten with the explicit ones).
        M: MuJoCo's joint-space inertia, compressed (``mjData.M``, (nM,); record's ``M_adr``...).
        xfrc: MuJoCo's applied body wrenches (nbody, 6), every one of the substep; corrected.
        xanchor, xaxis: Joint anchors and axes (njnt, 3). xipos: body centres of mass (nbody, 3).
        site_xpos, site_xmat: Site positions (nsite, 3) and orientations (nsite, 9).
        contact: The tool's contact result's ``w`` (``wrench_S``, ``wrench_MRF``, ``force_w``),
            (15,), corrected in place to the wrench the step applied.
        rows, groups: Every touching body's contact rows (k, 9) and the index into ``bodies`` of
            each row's body (k,); ``bodies[0]`` is the tool.
        materials: The objects' materials (n, 3) (:func:`~app.slave.tool_kernel.contact_gains`).
        d: Output, each body's correction ``[force; torque about its centre of mass]`` (N, N m,
            {w}), (len(bodies), 6); zero where the explicit step is kept.
    """
    d[:, :] = 0.0
    if rows.shape[0] == 0:
        return
    r = rec[0]
    n = qvel.shape[0]
    m = bodies.shape[0]
    Js = np.empty((m, 6, n))
    KCb = np.zeros((m, 2, 6, 6))
    KC = np.zeros((4, n, n))  # joint space: [contact K, contact C, none, none]
    for g in range(m):
        c = xipos[bodies[g]]
        body_jacobian(rec, bodies[g], c, xanchor, xaxis, Js[g])
        u = matvec(Js[g], qvel)
        mine = rows[groups == g]
        contact_gains(mine, materials, c, u, KCb[g, 0], KCb[g, 1])
        for a in range(2):
            X = KCb[g, a]
            J = Js[g]
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for p in range(6):
                        for q in range(6):
                            s += J[p, i] * X[p, q] * J[q, j]
                    KC[a, i, j] += s
    Mq = np.zeros((n, n))
    for i in range(n):
        for k in range(r["M_nnz"][i]):
            j = r["M_col"][r["M_adr"][i] + k]
            Mq[i, j] = Mq[j, i] = M[r["M_adr"][i] + k]
    L = cholesky(Mq)
    Mq_inv = np.empty((n, n))
    unit = np.zeros(n)
    for a in range(n):
        unit[:] = 0.0
        unit[a] = 1.0
        Mq_inv[:, a] = cholesky_solve(L, unit)
    hk, hc = implicit_shares(h, KC, _NO_OTHER, Mq, Mq_inv)
    if hk == 0.0 and hc == 0.0:
        return  # the explicit step is stable with margin: keep it as it is
    for stage in (FWD_ACTUATION, FWD_ACCELERATION, FWD_CONSTRAINT):
        call_model_data(mj[stage], mj[MODEL], mj[DATA])
    acc = implicit_acceleration(h, hk, hc, KC[0], KC[1], Mq, qvel, matvec(Mq, qacc))
    for g in range(m):
        d[g] = -correction(hk, hc, KCb[g, 0], KCb[g, 1], matvec(Js[g], qvel), h, matvec(Js[g], acc))
        for i in range(6):
            xfrc[bodies[g], i] += d[g, i]
    c, T = xipos[bodies[0]], r["T"]
    shift_wrench(contact[6:12], d[0], T[0:3, 0:3], T[0:3, 3], c)
    s_ft = r["site_ft"]
    shift_wrench(contact[0:6], d[0], site_xmat[s_ft].reshape((3, 3)), site_xpos[s_ft], c)
    for i in range(3):
        contact[12 + i] += d[0, i]


@njit(cache=True)
def frame_twist(b: int, root: int, xpos: Array, cvel: Array, subtree_com: Array, out: Array) -> None:
    """Into ``out`` (6,): the twist ``[v; w]`` ({w}) of body ``b``'s frame origin (its contact
    model's {MRF}), as ``mj_objectVelocity`` with ``mjOBJ_XBODY`` gives it ``[w; v]``: MuJoCo's
    ``cvel`` holds v at the centre of mass of the subtree of ``root`` (``body_rootid``), so
    ``v - (p - c) x w``. (``mjOBJ_BODY``, which the links' contacts were given before, is the
    body's centre of mass's: 30-100 mm from the frame on the 7-dof arm's links.)"""
    w = cvel[b, 0:3]
    cr = cross3(xpos[b] - subtree_com[root], w)
    for a in range(3):
        out[a] = cvel[b, 3 + a] - cr[a]
        out[3 + a] = w[a]


@njit(cache=True)
def links_end(
    mj: IntArray,
    rec: Array,
    h: float,
    qvel: Array,
    qacc: Array,
    M: Array,
    xfrc: Array,
    xanchor: Array,
    xaxis: Array,
    xipos: Array,
    xpos: Array,
    xmat: Array,
    cvel: Array,
    subtree_com: Array,
    site_xpos: Array,
    site_xmat: Array,
    contact: Array,
    rows: Array,
    materials: Array,
    models: tuple,
    link_w: Array,
    link_rows: Array,
    link_count: IntArray,
) -> tuple[bool, bool]:
    """The substep's end when links are near the world (``rec.near``, after :func:`control`):
    each near link's contact wrench (its contact model's compiled step, the link's frame as
    {MRF}) into ``xfrc``; the tool's and the touching links' contacts made implicit together
    (:func:`implicit_contacts`); ``mj_step2``; each link's wrench corrected to the one the step applied.

    Args:
        mj, rec, h, qvel ... site_xmat, contact, rows, materials: As for :func:`control` (``rows``
            the tool's alone); ``cvel``, ``subtree_com``: MuJoCo's body velocities (nbody, 6)
            ``[w; v at the subtree's centre of mass]`` and those centres (nbody, 3).
        models: Each link's contact model's arrays (:class:`~app.world.contact.bundle.KernelArrays`).
        link_w: Output, each near link's contact result's ``w`` (links, 15), as the tool's ``contact``.
        link_rows: Output, the near links' contact rows (capacity, 9), link after link.
        link_count: Output, each link's contact count, or its step's error code (< 0); -1 where
            the link is not near (-1 is also the code of a non-finite pose: only ``near`` tells).

    Returns:
        Whether any link touches, and whether any link's step failed (its model must be reset).
    """
    r = rec[0]
    near, links = r["near"], r["links"]
    root = r["root"]
    T = np.eye(4)
    V = np.empty(6)
    used = 0
    touching = 0
    failed = False
    for i in range(links.shape[0]):
        link_count[i] = -1
        if near[i] == 0:
            continue
        b = links[i]
        for a in range(3):
            for c in range(3):
                T[a, c] = xmat[b, 3 * a + c]
            T[a, 3] = xpos[b, a]
        frame_twist(b, root, xpos, cvel, subtree_com, V)
        model = models[i]
        code = contact_step_bundled(T, V, True, model)
        link_count[i] = code
        if code < 0:
            link_w[i, :] = 0.0
            failed = True
            continue
        out_w = model.tool[0].out
        for a in range(15):
            link_w[i, a] = out_w[a]
        out = model.out
        for k in range(code):
            o = out[k]
            for a in range(3):
                link_rows[used + k, a] = o.p[a]
                link_rows[used + k, 3 + a] = o.n[a]
            link_rows[used + k, 6] = o.depth
            link_rows[used + k, 7] = o.sphere
            link_rows[used + k, 8] = o.obj
        used += code
        if code > 0:
            touching += 1
        body_wrench(link_w[i, 12:15], link_w[i, 9:12], T[0:3, 0:3].copy(), T[0:3, 3].copy(), xipos[b], xfrc[b])
    k0 = rows.shape[0]
    every = np.empty((k0 + used, 9))
    every[:k0] = rows
    every[k0:] = link_rows[:used]
    bodies = np.empty(1 + touching, dtype=np.int64)
    bodies[0] = r["tool"]
    groups = np.zeros(k0 + used, dtype=np.int64)
    g, at = 0, k0
    for i in range(links.shape[0]):
        if near[i] != 0 and link_count[i] > 0:
            g += 1
            bodies[g] = links[i]
            groups[at : at + link_count[i]] = g
            at += link_count[i]
    d = np.zeros((1 + touching, 6))
    implicit_contacts(
        mj, rec, h, qvel, qacc, M, xfrc, xanchor, xaxis, xipos, site_xpos, site_xmat, contact, every, groups, bodies,
        materials, d,
    )  # fmt: skip
    call_model_data(mj[STEP2], mj[MODEL], mj[DATA])
    g = 0
    for i in range(links.shape[0]):
        if near[i] != 0 and link_count[i] > 0:
            g += 1
            b = links[i]
            R = xmat[b].reshape((3, 3))
            for part in range(2):  # {S} and {MRF} are the link's frame
                shift_wrench(link_w[i, 6 * part : 6 * part + 6], d[g], R, xpos[b], xipos[b])
            for a in range(3):
                link_w[i, 12 + a] += d[g, a]
    return touching > 0, failed


@njit(cache=True)
def joint_servo(
    q_c: Array,
    qd_c: Array,
    q: Array,
    qd: Array,
    bias: Array,
    kp: Array,
    kd: Array,
    qd_max: Array,
    tau_max: Array,
    ctrl: Array,
) -> int:
    """Joint PD toward the set-point plus gravity and Coriolis feedforward, saturated; into ``ctrl`` (n,) (N m).

    The PD is written as a velocity servo, ``kd (v - qd)`` with the speed demand
    ``v = qd_c + (kp / kd) (q_c - q)``, and ``v`` is clamped to the joint's velocity limit
    ``qd_max`` (rad/s): the limit then holds for the actual speed, not only the set-point's. A
    plain PD closes the lag it built while accelerating by running faster than the set-point
    (up to 42 % over the limit on the PUMA at a reversal at speed); with the clamp the joint
    approaches the limit from below (first order, time constant ``M_ii / kd``).

    Returns:
        ``TORQUE`` if any motor saturated, ``VELOCITY`` if any speed demand was clamped, else 0.
    """
    status = 0
    for k in range(q.shape[0]):
        v = qd_c[k] + kp[k] / kd[k] * (q_c[k] - q[k])
        if v > qd_max[k]:
            v, status = qd_max[k], status | VELOCITY
        elif v < -qd_max[k]:
            v, status = -qd_max[k], status | VELOCITY
        tau = kd[k] * (v - qd[k]) + bias[k]
        if tau > tau_max[k]:
            tau, status = tau_max[k], status | TORQUE
        elif tau < -tau_max[k]:
            tau, status = -tau_max[k], status | TORQUE
        ctrl[k] = tau
    return status


@njit(cache=True)
def ft_reading(
    rec: Array,
    at_rest: bool,
    sdata: Array,
    site_xpos: Array,
    site_xmat: Array,
    cvel: Array,
    cacc: Array,
    subtree_com: Array,
    gravity_w: Array,
    wrench_S: Array,
    R_w_S: Array,
    acc_w: Array,
    omega_w: Array,
) -> None:
    """The F/T reading at {S} as :class:`~app.controller.types.FTReading` defines it, into the
    outputs ``wrench_S`` (6,), ``R_w_S`` (3, 3), ``acc_w`` (6,), ``omega_w`` (3,).

    The wrench is the opposite of MuJoCo's force and torque sensors (the force and moment, about
    the {S} origin in {S}, the parent exerts on everything outboard), plus the limit wrench
    ``rec.W_limit`` acting at the {MRF} origin. The acceleration is that of the {S} site, as
    ``mj_objectAcceleration`` computes it from the tool body's ``cvel`` and ``cacc`` (nbody, 6,
    ``[angular; linear]`` about ``subtree_com`` of the root), less the -gravity MuJoCo includes
    (an accelerometer's view); zero ``at_rest`` (a held arm).

    Args:
        rec: The arm's record (``T``, ``V`` current).
        sdata: MuJoCo's sensor data. site_xpos, site_xmat: site positions and orientations.
        gravity_w: Gravity (m/s^2), (3,).
    """
    r = rec[0]
    s, b, adr = r["site_ft"], r["tool"], r["sensor"]
    p_S = site_xpos[s]
    for i in range(3):
        for j in range(3):
            R_w_S[i, j] = site_xmat[s, 3 * i + j]
    wrench_S[:] = wrench_at(r["W_limit"], r["T"][0:3, 3], R_w_S, p_S)
    for i in range(3):
        wrench_S[i] -= sdata[adr + i]
        wrench_S[3 + i] -= sdata[adr + 3 + i]
        omega_w[i] = r["V"][3 + i]
    if at_rest:
        acc_w[:] = 0.0
        return
    # Motion vectors about the root's subtree centre of mass, moved to the {S} origin; the
    # linear part then gains omega x v (a point's classical acceleration).
    d = p_S - subtree_com[r["root"]]
    w = cvel[b, 0:3]
    v = cvel[b, 3:6] - cross3(d, w)
    alpha = cacc[b, 0:3]
    a = cacc[b, 3:6] - cross3(d, alpha) + cross3(w, v)
    for i in range(3):
        acc_w[i] = a[i] + gravity_w[i]
        acc_w[3 + i] = alpha[i]


@njit(cache=True)
def body_wrench(f_w: Array, m_local: Array, R_w_local: Array, p_w: Array, com_w: Array, xfrc: Array) -> None:
    """Add a contact wrench to a body's ``xfrc_applied`` row ``xfrc`` (6,) (force; torque about
    the centre of mass ``com_w``, {w}).

    Args:
        f_w: Force (N) in {w}. ``m_local``: moment (N m) about ``p_w`` in the frame whose
            orientation is ``R_w_local`` (3, 3) (the contact model's {MRF}).
    """
    t = matvec(R_w_local, m_local) + cross3(p_w - com_w, f_w)
    for i in range(3):
        xfrc[i] += f_w[i]
        xfrc[3 + i] += t[i]


@njit(cache=True)
def wrench_at(W_w: Array, p_from: Array, R_w_S: Array, p_S: Array) -> Array:
    """The wrench ``W_w`` (6,) ``[f; m]`` acting at ``p_from`` ({w}) as seen at the {S} origin ``p_S``, in {S}."""
    f = W_w[0:3]
    m = W_w[3:6] + cross3(p_from - p_S, f)
    out = np.empty(6)
    out[0:3] = matTvec(R_w_S, f)
    out[3:6] = matTvec(R_w_S, m)
    return out


@njit(cache=True)
def links_near(
    xpos: Array, xmat: Array, links: Array, owner: Array, centers: Array, radii: Array, box: Array, out: Array
) -> None:
    """Which links have a contact sphere reaching ``box`` (``[lo; hi]`` (2, 3), {w}), into ``out`` (k,), 1 or 0.

    Args:
        xpos, xmat: MuJoCo's body positions (nbody, 3) and orientations (nbody, 9) in {w}.
        links: Body ids of the links (k,).
        owner: Index into ``links`` of each sphere (s,). ``centers``: sphere centres (s, 3) in
            their link's frame (m); ``radii`` (s,) (m).
    """
    out[:] = 0
    for i in range(owner.shape[0]):
        k = owner[i]
        if out[k] != 0:
            continue
        b = links[k]
        R = xmat[b]
        r = radii[i]
        near = True
        for a in range(3):
            c = xpos[b, a] + R[3 * a] * centers[i, 0] + R[3 * a + 1] * centers[i, 1] + R[3 * a + 2] * centers[i, 2]
            if c + r < box[0, a] or c - r > box[1, a]:
                near = False
                break
        out[k] = 1 if near else 0
