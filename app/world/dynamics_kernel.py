"""The per-substep arithmetic of :mod:`app.world.dynamics` between MuJoCo's state and the contact
models, compiled with numba (numpy's small-array calls cost ~1-5 us each; a tick has dozens).

Frames: {w} the world, {B} a dynamic object's frame (MuJoCo's body frame), {MRF} the tool's.
MuJoCo's free joint: ``qpos = [p_w_B, quat_w_B (wxyz)]``, ``qvel = [v of {B}'s origin in {w},
angular velocity in {B}]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def body_frames(
    qpos: np.ndarray,
    qvel: np.ndarray,
    com_B: np.ndarray,
    reach: np.ndarray,
    T_w_MRF: np.ndarray,
    V_w_MRF: np.ndarray,
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
        qpos, qvel: MuJoCo's free-joint state, (n, 7), (n, 6).
        com_B: Centres of mass in {B} (m), (n, 3).
        reach: Each object's bounding-sphere radius about {B}'s origin (m), (n,).
        T_w_MRF, V_w_MRF: The tool's pose (4, 4) and twist ``[v; w]`` in {w} (6,).
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
