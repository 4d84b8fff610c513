"""Operator-assist laws at the grip (paper Sec 3.3) and the uniform scalings of Sec 3.3-3.4.

The laws act on one Cartesian axis of Delta X ``[x, y, z, gamma, beta, alpha]`` at a time (the
paper applies them "for each Cartesian axis independently"). They are compiled with numba so the
servo-tick kernel (:mod:`app.controller.kernel`) calls them at machine speed; from Python they
are ordinary functions of floats and arrays.
"""

from __future__ import annotations

import math

from numba import njit

from app.spatial import Array


@njit(cache=True)
def deadband(dx: float, db: float) -> float:
    """Input channel of one axis: ``dx - sign(dx) db`` outside the deadband ``|dx| <= db``, else 0.

    Args:
        dx: Delta X_i (m or rad).
        db: Deadband half-width Delta X_iDB (m or rad), >= 0.
    """
    excess = abs(dx) - db
    return math.copysign(excess, dx) if excess > 0.0 else 0.0


@njit(cache=True)
def constant_force_rtc(dx: float, a: float, db: float, wall_start: float, k_wall: float) -> float:
    """Constant-force return-to-centre for one axis (Eq 8, Fig. 4): odd in dx and continuous.

    With ``u = |dx|``: ``-sign(dx) a u^2`` inside the deadband (the parabolic wall the operator
    must overcome to command the axis), ``-sign(dx) a db^2`` over the working range (constant
    force), and beyond ``wall_start`` an added stiff spring ``k_wall (u - wall_start)`` (the
    paper's optional third zone at the workspace edge).

    Args:
        dx: Delta X_i (m or rad).
        a: Parabolic constant a_i (N/m^2 or N m/rad^2).
        db: Deadband half-width (m or rad).
        wall_start: Where the wall begins (m or rad); ``inf`` for no wall.
        k_wall: Wall stiffness (N/m or N m/rad).

    Returns:
        The grip force (N) or moment (N m) for this axis.
    """
    u = abs(dx)
    inner = min(u, db)
    magnitude = a * inner * inner
    if u > wall_start:
        magnitude += k_wall * (u - wall_start)
    if dx == 0.0:
        return 0.0
    return -math.copysign(magnitude, dx)


@njit(cache=True)
def hooke_rtc(dx: float, k_r: float) -> float:
    """Hooke's-law return-to-centre ``-K_R dx`` for one axis (the paper's first try)."""
    return -k_r * dx


@njit(cache=True)
def damping(dx: float, dx_prev: float, k_d: float, dt: float, angular: bool) -> float:
    """Damping for one axis, ``-K_D (dx - dx_prev) / dt`` (Eq 9 per unit time).

    Dividing the per-cycle difference by the period ``dt`` (s) keeps K_D in N s/m or N m s/rad,
    so a gain means the same at any servo rate. For an angle the difference is wrapped into
    [-pi, pi) so crossing +-pi does not read as a full turn.
    """
    diff = dx - dx_prev
    if angular:
        diff = (diff + math.pi) % (2.0 * math.pi) - math.pi
    return -k_d * diff / dt


@njit(cache=True)
def uniform_scale(values: Array, limits: Array) -> float:
    """Largest ``s`` in (0, 1] with ``|s v_i| <= limit_i`` for all i (direction-keeping scaling).

    Used for the assist torques' share of capacity (Eq 11) and the final saturation (Sec 3.4).
    """
    peak = 0.0
    for i in range(values.shape[0]):
        peak = max(peak, abs(values[i]) / limits[i])
    return 1.0 if peak <= 1.0 else 1.0 / peak


@njit(cache=True)
def saturate(values: Array, limits: Array, out: Array) -> float:
    """Uniformly scale ``values`` into ``|v_i| <= limit_i`` (Sec 3.4), keeping their direction.

    Writes the result into ``out`` and returns the scale factor. A final clamp only absorbs the
    last-bit rounding of ``s * v_i``, so no component ever exceeds its limit, even for 1e300.
    """
    s = uniform_scale(values, limits)
    for i in range(values.shape[0]):
        out[i] = min(limits[i], max(-limits[i], values[i] * s))
    return s
