"""Operator-assist laws at the grip (paper Sec 3.3) and the uniform scalings of Sec 3.3-3.4.

Each law acts on one Cartesian axis of Delta X ``[x, y, z, gamma, beta, alpha]`` at a time
(the paper applies them "for each Cartesian axis independently"). They take and return Python
floats: at six elements, scalar arithmetic is several times faster than numpy calls, and these
run every servo tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def deadband(dx: float, db: float) -> float:
    """Input channel of one axis: ``dx - sign(dx) db`` outside the deadband ``|dx| <= db``, else 0.

    Args:
        dx: Delta X_i (m or rad).
        db: Deadband half-width Delta X_iDB (m or rad), >= 0.
    """
    excess = abs(dx) - db
    return math.copysign(excess, dx) if excess > 0.0 else 0.0


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
    return -math.copysign(magnitude, dx) if dx != 0.0 else 0.0


def hooke_rtc(dx: float, k_r: float) -> float:
    """Hooke's-law return-to-centre ``-K_R dx`` for one axis (the paper's first try)."""
    return -k_r * dx


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


def uniform_scale(values: Sequence[float], limits: Sequence[float]) -> float:
    """Largest ``s`` in (0, 1] with ``|s v_i| <= limit_i`` for all i (direction-keeping scaling).

    Used for the assist torques' share of capacity (Eq 11) and the final saturation (Sec 3.4).
    """
    peak = max(abs(v) / lim for v, lim in zip(values, limits, strict=True))
    return 1.0 if peak <= 1.0 else 1.0 / peak


def saturate(values: Sequence[float], limits: Sequence[float]) -> tuple[list[float], float]:
    """Uniformly scale ``values`` into ``|v_i| <= limit_i`` (Sec 3.4), keeping their direction.

    A final clamp only absorbs the last-bit rounding of ``s * v_i``, so no component ever exceeds
    its limit, even for inputs of 1e300.

    Returns:
        The scaled values and the scale factor s.
    """
    s = uniform_scale(values, limits)
    return [min(lim, max(-lim, v * s)) for v, lim in zip(values, limits, strict=True)], s
