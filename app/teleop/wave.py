"""Wave variables (Niemeyer & Slotine 1991): force reflection that stays passive under any constant delay.

At a port with velocity ``xdot`` (m/s) and force ``F`` (N) going *into* the channel, the wave
variables with impedance ``b`` (N s/m) are

    u = (b xdot + F) / sqrt(2 b)        (the wave going out)
    v = (b xdot - F) / sqrt(2 b)        (the wave coming in)

so the power into the channel is ``xdot F = (u^2 - v^2) / 2``. A delay line only stores waves,
so the channel's energy is the integral of ``(u_m^2 - v_m^2 + v_s^2 - u_s^2) / 2`` over time,
which with ``u_s(t) = u_m(t - T)`` and ``v_m(t) = v_s(t - T)`` is the energy in flight: it never
goes negative, whatever T.

The master knows its velocity and receives ``v``: it sends ``u`` and feels ``F`` (:func:`master`).
The slave receives ``u`` and measures its force on the environment: it moves at ``xdot`` and
sends ``v`` back (:func:`slave`). Each acts per axis on (3,) arrays in the slave world {w}.

The cost is transparency: the channel behaves like a line of impedance b, so the operator feels
the environment through a compliance that grows with the delay (felt stiffness below the true
one), and positions drift apart when waves are lost; :func:`app.session.stability` reports it.
"""

from __future__ import annotations

import math

from app.spatial import Array


def master(xdot_m: Array, v_m: Array, b: float, u_m: Array, F_m: Array) -> None:
    """Master side: from its velocity ``xdot_m`` (m/s) and the arriving wave ``v_m`` (sqrt(W)), the
    wave to send ``u_m`` and the force ``F_m`` (N) the operator pushes into the channel (the
    device renders ``-F_m``). All (3,); ``u_m`` and ``F_m`` are written."""
    r = math.sqrt(2.0 * b)
    for i in range(3):
        F_m[i] = b * xdot_m[i] - r * v_m[i]
        u_m[i] = r * xdot_m[i] - v_m[i]


def slave(u_s: Array, F_s: Array, b: float, xdot_s: Array, v_s: Array) -> None:
    """Slave side: from the arriving wave ``u_s`` and the force ``F_s`` (N) the slave exerts on the
    environment, the velocity command ``xdot_s`` (m/s) and the wave to send back ``v_s``. All
    (3,); ``xdot_s`` and ``v_s`` are written."""
    r = math.sqrt(2.0 * b)
    for i in range(3):
        xdot_s[i] = (r * u_s[i] - F_s[i]) / b
        v_s[i] = u_s[i] - 2.0 * F_s[i] / r
