"""The force law of one contact and the wrench of all of them, compiled with numba.

Penalty contact: the normal force is ``k depth - b u_n``, clamped at 0 (no sticking), plus a
regularised Coulomb friction ``-mu f_n u_t / max(|u_t|, V_SLIP)``, where u is the velocity of the
tool's material point at the contact point p (``v + w x (p - p_MRF)``, {w}): a spinning tool
slips on the floor even when its sphere centre is still.
"""

from __future__ import annotations

import math

import numpy as np

from app.world.contact.bundle import tick_kernel
from app.world.contact.layout import Record

# Tangential speed (m/s) below which friction is viscous (regularised Coulomb).
V_SLIP = 1e-3


@tick_kernel
def contact_force(
    k: float,
    b: float,
    mu: float,
    depth: float,
    nx: float,
    ny: float,
    nz: float,
    rx: float,
    ry: float,
    rz: float,
    has_twist: bool,
    V: np.ndarray,
) -> tuple[float, float, float]:
    """Force (N, {w}) on the tool of one contact of effective ``depth`` (m) and outward normal n.

    ``r`` is the contact point relative to the {MRF} origin (m, {w}); ``V`` the {MRF} twist
    ``[v; w]`` in {w}, used only ``if has_twist``.
    """
    fn = k * depth
    if not has_twist:
        return fn * nx, fn * ny, fn * nz
    ux = V[0] + V[4] * rz - V[5] * ry
    uy = V[1] + V[5] * rx - V[3] * rz
    uz = V[2] + V[3] * ry - V[4] * rx
    un = ux * nx + uy * ny + uz * nz
    fn = max(0.0, fn - b * un)
    fx, fy, fz = fn * nx, fn * ny, fn * nz
    if mu > 0.0:
        ex, ey, ez = ux - un * nx, uy - un * ny, uz - un * nz
        scale = -mu * fn / max(math.sqrt(ex * ex + ey * ey + ez * ez), V_SLIP)
        fx += scale * ex
        fy += scale * ey
        fz += scale * ez
    return fx, fy, fz


@tick_kernel
def write_wrench(tool: Record, T_w_MRF: np.ndarray, F: np.ndarray, M: np.ndarray) -> None:
    """Store the total force F and moment M about the {MRF} origin (both {w}, (3,)) as the tool's
    outputs ``tool.out``: wrench at {S} in {S} (Eq 6 backwards), at {MRF} in {MRF}, force in {w}."""
    out = tool.out
    for a in range(3):
        out[6 + a] = T_w_MRF[0, a] * F[0] + T_w_MRF[1, a] * F[1] + T_w_MRF[2, a] * F[2]
        out[9 + a] = T_w_MRF[0, a] * M[0] + T_w_MRF[1, a] * M[1] + T_w_MRF[2, a] * M[2]
        out[12 + a] = F[a]
    s = tool.p_MRF_S
    ox = out[9] - (s[1] * out[8] - s[2] * out[7])
    oy = out[10] - (s[2] * out[6] - s[0] * out[8])
    oz = out[11] - (s[0] * out[7] - s[1] * out[6])
    Rs = tool.R_MRF_S
    for a in range(3):
        out[a] = Rs[0, a] * out[6] + Rs[1, a] * out[7] + Rs[2, a] * out[8]
        out[3 + a] = Rs[0, a] * ox + Rs[1, a] * oy + Rs[2, a] * oz
