"""The per-substep arithmetic of :mod:`app.world.dynamics` between MuJoCo's state and the contact
models, compiled with numba (numpy's small-array calls cost ~1-5 us each; a tick has dozens).

Frames: {w} the world, {B} a dynamic object's frame (MuJoCo's body frame), {MRF} the tool's.
MuJoCo's free joint: ``qpos = [p_w_B, quat_w_B (wxyz)]``, ``qvel = [v of {B}'s origin in {w},
angular velocity in {B}]``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from app.mjcall import call_model_data
from app.world.contact.step import contact_step_bundled

#: The pose of the static objects' contacts (already in {w}).
_IDENTITY = np.eye(4)


@njit(cache=True)
def body_frames(
    T_w_MRF: np.ndarray,
    V_w_MRF: np.ndarray,
    qpos: np.ndarray,
    qvel: np.ndarray,
    com_B: np.ndarray,
    reach: np.ndarray,
    tool_reach: float,
    T_w_B: np.ndarray,
    c_w: np.ndarray,
    vel_w: np.ndarray,
    T_B_MRF: np.ndarray,
    V_B: np.ndarray,
    near: np.ndarray,
) -> None:
    """Every object's pose, centre of mass and twist in {w}, and the tool seen from it.

    Args:
        T_w_MRF, V_w_MRF: The tool's pose (4, 4) and twist ``[v; w]`` in {w} (6,).
        qpos, qvel: MuJoCo's free-joint state, (n, 7), (n, 6).
        com_B: Centres of mass in {B} (m), (n, 3).
        reach: Each object's bounding-sphere radius about {B}'s origin (m), (n,).
        tool_reach: Radius (m) about {MRF}'s origin within which the tool's spheres lie.
        T_w_B, c_w, vel_w: Out: poses (n, 4, 4), centres of mass (n, 3), twists ``[v of the
            origin; w]`` in {w} (n, 6).
        T_B_MRF, V_B: Out: the tool's pose in {B} (n, 4, 4) and its twist relative to the object
            in {B} axes (v of {MRF}'s origin as seen from {B}; w relative), (n, 6).
        near: Out: 1 where the tool's bounding sphere meets the object's, else 0, (n,).
    """
    for b in range(qpos.shape[0]):
        w, x, y, z = qpos[b, 3], qpos[b, 4], qpos[b, 5], qpos[b, 6]
        s = 2.0 / (w * w + x * x + y * y + z * z)
        R = T_w_B[b]
        R[0, 0], R[0, 1], R[0, 2] = 1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)
        R[1, 0], R[1, 1], R[1, 2] = s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x)
        R[2, 0], R[2, 1], R[2, 2] = s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)
        for a in range(3):
            R[a, 3] = qpos[b, a]
            R[3, a] = 0.0
        R[3, 3] = 1.0
        for a in range(3):
            c_w[b, a] = R[a, 0] * com_B[b, 0] + R[a, 1] * com_B[b, 1] + R[a, 2] * com_B[b, 2] + R[a, 3]
            vel_w[b, a] = qvel[b, a]
            vel_w[b, 3 + a] = R[a, 0] * qvel[b, 3] + R[a, 1] * qvel[b, 4] + R[a, 2] * qvel[b, 5]
        dx, dy, dz = T_w_MRF[0, 3] - R[0, 3], T_w_MRF[1, 3] - R[1, 3], T_w_MRF[2, 3] - R[2, 3]
        near[b] = 1 if math.sqrt(dx * dx + dy * dy + dz * dz) <= reach[b] + tool_reach else 0
        # T_B_MRF = R^T (T_w_MRF - origin)
        P = T_B_MRF[b]
        for a in range(3):
            for c in range(4):
                t = T_w_MRF[0, c] * R[0, a] + T_w_MRF[1, c] * R[1, a] + T_w_MRF[2, c] * R[2, a]
                if c == 3:
                    t -= R[0, 3] * R[0, a] + R[1, 3] * R[1, a] + R[2, 3] * R[2, a]
                P[a, c] = t
            P[3, a] = 0.0
        P[3, 3] = 1.0
        # Relative twist: v_MRF - v_o - w_o x (p_MRF - p_o), w_MRF - w_o, in {B} axes.
        wx, wy, wz = vel_w[b, 3], vel_w[b, 4], vel_w[b, 5]
        ux = V_w_MRF[0] - vel_w[b, 0] - (wy * dz - wz * dy)
        uy = V_w_MRF[1] - vel_w[b, 1] - (wz * dx - wx * dz)
        uz = V_w_MRF[2] - vel_w[b, 2] - (wx * dy - wy * dx)
        rx, ry, rz = V_w_MRF[3] - wx, V_w_MRF[4] - wy, V_w_MRF[5] - wz
        for a in range(3):
            V_B[b, a] = R[0, a] * ux + R[1, a] * uy + R[2, a] * uz
            V_B[b, 3 + a] = R[0, a] * rx + R[1, a] * ry + R[2, a] * rz


@njit(cache=True)
def add_reaction(
    b: int, T_w_B: np.ndarray, c_w: np.ndarray, T_w_MRF: np.ndarray, r: np.ndarray, w: np.ndarray, xfrc: np.ndarray
) -> None:
    """Add object b's contact result ``r`` (a ``ContactResult.w`` computed in {B}, (15,)) to the
    tool's ``w`` (15,) and set its reaction on the object, ``xfrc[b]`` (force; torque about the
    centre of mass ``c_w[b]``; {w}).

    ``r``'s wrenches at {S} and {MRF} are in the tool's own axes, so they add as they are; its
    force is in {B} axes and is turned to {w}.
    """
    R = T_w_B[b]
    for a in range(12):
        w[a] += r[a]
    F = np.empty(3)
    M = np.empty(3)
    for a in range(3):
        F[a] = R[a, 0] * r[12] + R[a, 1] * r[13] + R[a, 2] * r[14]
        M[a] = T_w_MRF[a, 0] * r[9] + T_w_MRF[a, 1] * r[10] + T_w_MRF[a, 2] * r[11]
        w[12 + a] += F[a]
    dx, dy, dz = T_w_MRF[0, 3] - c_w[b, 0], T_w_MRF[1, 3] - c_w[b, 1], T_w_MRF[2, 3] - c_w[b, 2]
    xfrc[b, 0], xfrc[b, 1], xfrc[b, 2] = -F[0], -F[1], -F[2]
    xfrc[b, 3] = -(M[0] + dy * F[2] - dz * F[1])
    xfrc[b, 4] = -(M[1] + dz * F[0] - dx * F[2])
    xfrc[b, 5] = -(M[2] + dx * F[1] - dy * F[0])


@njit(cache=True)
def _copy_contacts(src: Any, count: int, T_w_B: np.ndarray, obj_offset: float, rows: np.ndarray, at: int) -> int:
    """Append a contact model's first ``count`` output records ``src`` to ``rows`` (k, 9) from row
    ``at``, points and normals taken from {B} to {w} by ``T_w_B`` (the identity for the static
    model), object ids shifted by ``obj_offset``; returns the new row count."""
    for k in range(count):
        c = src[k]
        row = rows[at + k]
        for a in range(3):
            row[a] = T_w_B[a, 0] * c.p[0] + T_w_B[a, 1] * c.p[1] + T_w_B[a, 2] * c.p[2] + T_w_B[a, 3]
            row[3 + a] = T_w_B[a, 0] * c.n[0] + T_w_B[a, 1] * c.n[1] + T_w_B[a, 2] * c.n[2]
        row[6] = c.depth
        row[7] = c.sphere
        row[8] = c.obj + obj_offset
    return at + count


@njit(cache=True)
def moving_wrench(
    T_w_MRF: np.ndarray,
    V_w_MRF: np.ndarray,
    has_twist: bool,
    static: Any,
    bodies: Any,
    frames: Any,
    xfrc: np.ndarray,
    n_static: int,
    grip: np.ndarray,
    T_MRF_H: np.ndarray,
    T_MRF_S: np.ndarray,
    w: np.ndarray,
    rows: np.ndarray,
    counts: np.ndarray,
) -> int:
    """The tool's contact with the static objects and every dynamic one near it, in one call.

    Evaluates the static contact model (``static``, a
    :class:`~app.world.contact.bundle.KernelArrays`) at ``T_w_MRF``, refreshes the objects'
    frames (``frames``: :func:`body_frames`'s arguments after the pose and twist), evaluates each near object's model (``bodies``,
    a tuple of them, each built on its object in {B}) at the tool's pose and relative twist in
    {B}, and sums: ``w`` (15,) the tool's total (as ``ContactResult.w``), ``rows`` the contacts in
    {w} (static first; object ids of dynamic object b are ``n_static + b``), ``xfrc`` (n, 6) the
    reaction on each object (:func:`add_reaction`; zero for the others), ``counts`` (4,) the
    models' summed queries and gathers, and (below) the model that failed and the row count. ``grip`` ``[held object or -1, its gains]``: an
    object held is not touched by the tool's spheres but by the grip (:func:`add_grip`, its
    pose in {MRF} held ``T_MRF_H``; ``T_MRF_S`` the sensor's pose in {MRF}).

    Returns the number of contact rows (also ``counts[3]``), or a model's ``ERR_*`` code (< 0)
    with ``counts[2]`` the model that failed (-1 the static one, else the object's index);
    ``xfrc`` and ``counts[3]`` are then zero.
    """
    xfrc[:] = 0.0
    counts[2] = -1
    counts[3] = 0
    code = contact_step_bundled(T_w_MRF, V_w_MRF, has_twist, static)
    if code < 0:
        return code
    tool = static.tool[0]
    for a in range(15):
        w[a] = tool.out[a]
    counts[0], counts[1] = tool.counts[0], tool.counts[1]
    n_rows = _copy_contacts(static.out, code, _IDENTITY, 0.0, rows, 0)
    body_frames(T_w_MRF, V_w_MRF, *frames)
    _, _, com_B, _, _, T_w_B, c_w, vel_w, T_B_MRF, V_B, near = frames
    held = int(grip[0])
    if held >= 0:
        near[held] = 0
        add_grip(held, grip, T_MRF_H, T_MRF_S, T_w_B, c_w, vel_w, com_B, T_w_MRF, V_w_MRF, w, xfrc)
    for b in range(len(bodies)):
        if not near[b]:
            continue
        model = bodies[b]
        code = contact_step_bundled(T_B_MRF[b], V_B[b], has_twist, model)
        if code < 0:
            xfrc[:] = 0.0
            counts[2] = b
            return code
        tool = model.tool[0]
        counts[0] += tool.counts[0]
        counts[1] += tool.counts[1]
        if code == 0:
            continue
        add_reaction(b, T_w_B, c_w, T_w_MRF, tool.out, w, xfrc)
        n_rows = _copy_contacts(model.out, code, T_w_B[b], n_static + b, rows, n_rows)
    counts[3] = n_rows
    return n_rows


@njit(cache=True)
def add_grip(
    b: int,
    grip: np.ndarray,
    T_MRF_H: np.ndarray,
    T_MRF_S: np.ndarray,
    T_w_B: np.ndarray,
    c_w: np.ndarray,
    vel_w: np.ndarray,
    com_B: np.ndarray,
    T_w_MRF: np.ndarray,
    V_w_MRF: np.ndarray,
    w: np.ndarray,
    xfrc: np.ndarray,
) -> None:
    """The grip holding object b at ``T_MRF_H`` (its frame {B} held in {MRF}): a spring-damper
    between the object and where the tool carries it, critically damped at the natural frequency
    ``grip[1]`` (rad/s) in every direction: on the centre of mass ``F = m (omega^2 e + 2 omega
    de/dt)`` (``grip[2]`` = m, kg), about it ``M = I (omega^2 theta + 2 omega dtheta/dt)`` with
    I the inertia in {w} (from ``grip[3:12]``, the inertia in {B}, kg m^2) and theta the rotation
    error. F and M (on the object at its centre of mass, {w}) are added to ``xfrc[b]``, and -F
    at the same point and -M to the tool's ``w`` (15,): equal and opposite at the same instant,
    as a contact's."""
    R, P = T_w_B[b], T_w_MRF
    omega, mass = grip[1], grip[2]
    # Target pose of {B}: T_w_MRF T_MRF_H (Rt, pt); its centre of mass ct.
    Rt = np.empty((3, 3))
    ct = np.empty(3)
    for a in range(3):
        for c in range(3):
            Rt[a, c] = P[a, 0] * T_MRF_H[0, c] + P[a, 1] * T_MRF_H[1, c] + P[a, 2] * T_MRF_H[2, c]
    for a in range(3):
        pt = P[a, 0] * T_MRF_H[0, 3] + P[a, 1] * T_MRF_H[1, 3] + P[a, 2] * T_MRF_H[2, 3] + P[a, 3]
        ct[a] = Rt[a, 0] * com_B[b, 0] + Rt[a, 1] * com_B[b, 1] + Rt[a, 2] * com_B[b, 2] + pt
    # Velocities of the target and of the centre of mass; rotation error: the axis-angle vector
    # of Rt R^T from its skew part (the grip holds it to small angles).
    rt = ct - P[0:3, 3]
    r = c_w[b] - R[0:3, 3]
    vt = V_w_MRF[0:3] + np.cross(V_w_MRF[3:6], rt)
    vb = vel_w[b, 0:3] + np.cross(vel_w[b, 3:6], r)
    E = np.empty((3, 3))
    for a in range(3):
        for c in range(3):
            E[a, c] = Rt[a, 0] * R[c, 0] + Rt[a, 1] * R[c, 1] + Rt[a, 2] * R[c, 2]
    theta = (0.5 * (E[2, 1] - E[1, 2]), 0.5 * (E[0, 2] - E[2, 0]), 0.5 * (E[1, 0] - E[0, 1]))
    # The angular acceleration the spring asks for, in {B} axes, then M = R I_B alpha_B.
    alpha = np.empty(3)
    for a in range(3):
        alpha[a] = omega * omega * theta[a] + 2.0 * omega * (V_w_MRF[3 + a] - vel_w[b, 3 + a])
    F = np.empty(3)
    M = np.empty(3)
    for a in range(3):
        F[a] = mass * (omega * omega * (ct[a] - c_w[b, a]) + 2.0 * omega * (vt[a] - vb[a]))
        M[a] = 0.0
        for c in range(3):
            # (R I_B R^T alpha)_a
            ia = 0.0
            for e in range(3):
                ia += grip[3 + 3 * c + e] * (R[0, e] * alpha[0] + R[1, e] * alpha[1] + R[2, e] * alpha[2])
            M[a] += R[a, c] * ia
    for a in range(3):
        xfrc[b, a] += F[a]
        xfrc[b, 3 + a] += M[a]
    # On the tool: -F at the object's centre of mass and -M, about {MRF}'s origin in {w}; then
    # w's blocks as app.world.contact.force.write_wrench makes them ({S}, {MRF}, {w}).
    M_w = -M - np.cross(r + R[0:3, 3] - P[0:3, 3], F)
    f_m = np.empty(3)
    m_m = np.empty(3)
    for a in range(3):
        f_m[a] = -(P[0, a] * F[0] + P[1, a] * F[1] + P[2, a] * F[2])
        m_m[a] = P[0, a] * M_w[0] + P[1, a] * M_w[1] + P[2, a] * M_w[2]
    m_o = m_m - np.cross(T_MRF_S[0:3, 3], f_m)
    for a in range(3):
        w[a] += T_MRF_S[0, a] * f_m[0] + T_MRF_S[1, a] * f_m[1] + T_MRF_S[2, a] * f_m[2]
        w[3 + a] += T_MRF_S[0, a] * m_o[0] + T_MRF_S[1, a] * m_o[1] + T_MRF_S[2, a] * m_o[2]
        w[6 + a] += f_m[a]
        w[9 + a] += m_m[a]
        w[12 + a] -= F[a]


@njit(cache=True)
def world_step(mj: np.ndarray, xfrc: np.ndarray) -> None:
    """One MuJoCo step of the objects' world (``mj``: ``[mj_step, mjModel*, mjData*]`` addresses,
    :mod:`app.mjcall`), then the tool's reaction ``xfrc`` (n, 6) cleared: it acts for one step."""
    call_model_data(mj[0], mj[1], mj[2])
    xfrc[:] = 0.0
