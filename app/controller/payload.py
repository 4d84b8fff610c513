"""The slave payload's loads on the F/T reading (paper Sec 3.2, Fig. 3 "remove payload"), compiled.

A wrist sensor reads the contact wrench plus the weight of everything outboard of it, minus that
mass's d'Alembert (inertial) load. The controller reflects only the contact part, so it adds the
inertial load back (:func:`add_inertial_load`, optional: it needs the slave's accelerations) and
subtracts the weight (:func:`remove_weight`). Both act in place on the wrench ``[f; m]`` (N, N m)
at the {S} origin in {S} axes.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.spatial import Array, cross3


@njit(cache=True)
def remove_weight(R_w_S: Array, gravity_w: Array, mass: float, com_S: Array, F_S: Array) -> None:
    """Subtract the payload's weight from ``F_S`` (6,) in place.

    Args:
        R_w_S: Sensor orientation in the slave world {w} (3, 3): gives gravity in {S}.
        gravity_w: Gravity in {w} (m/s^2), (3,).
        mass: Payload mass outboard of the sensor (kg).
        com_S: Its centre of mass in {S} (m), (3,).
        F_S: The reading at {S} in {S} (N, N m), (6,), updated.
    """
    lx = mass * (R_w_S[0, 0] * gravity_w[0] + R_w_S[1, 0] * gravity_w[1] + R_w_S[2, 0] * gravity_w[2])
    ly = mass * (R_w_S[0, 1] * gravity_w[0] + R_w_S[1, 1] * gravity_w[1] + R_w_S[2, 1] * gravity_w[2])
    lz = mass * (R_w_S[0, 2] * gravity_w[0] + R_w_S[1, 2] * gravity_w[1] + R_w_S[2, 2] * gravity_w[2])
    cx, cy, cz = com_S[0], com_S[1], com_S[2]
    F_S[0] -= lx
    F_S[1] -= ly
    F_S[2] -= lz
    F_S[3] -= cy * lz - cz * ly
    F_S[4] -= cz * lx - cx * lz
    F_S[5] -= cx * ly - cy * lx


@njit(cache=True)
def add_inertial_load(
    R_w_S: Array, acc_w: Array, omega_w: Array, mass: float, com_S: Array, inertia_S: Array, F_S: Array
) -> None:
    """Add the payload's inertial load back to the reading ``F_S`` (6,) in place.

    The sensor reads minus the payload's d'Alembert load; :func:`remove_weight` then removes the
    weight.

    Args:
        R_w_S: Sensor orientation in the slave world (3, 3).
        acc_w: Linear acceleration of {S}'s origin and angular acceleration, in {w} (m/s^2,
            rad/s^2), (6,). ``omega_w``: angular velocity in {w} (rad/s), (3,).
        mass, com_S, inertia_S: The payload's mass (kg), centre of mass in {S} (m) and inertia
            about it in {S} axes (kg m^2).
        F_S: Wrench at {S} in {S} (N, N m), (6,), updated.
    """
    R_S_w = R_w_S.T
    w_S = _mat_vec(R_S_w, omega_w)
    alpha_S = _mat_vec(R_S_w, acc_w[3:6])
    a_com = _mat_vec(R_S_w, acc_w[0:3]) + cross3(alpha_S, com_S) + cross3(w_S, cross3(w_S, com_S))
    f = mass * a_com
    m_com = cross3(com_S, f)
    m_alpha = _mat_vec(inertia_S, alpha_S)
    m_gyro = cross3(w_S, _mat_vec(inertia_S, w_S))
    for i in range(3):
        F_S[i] = F_S[i] + f[i]
        F_S[3 + i] = F_S[3 + i] + m_com[i] + m_alpha[i] + m_gyro[i]


@njit(cache=True)
def _mat_vec(M: Array, v: Array) -> Array:
    """``M @ v`` for a (3, 3) matrix of any layout and a (3,) vector (numba's ``@`` needs BLAS)."""
    out = np.empty(3)
    for i in range(3):
        out[i] = M[i, 0] * v[0] + M[i, 1] * v[1] + M[i, 2] * v[2]
    return out
