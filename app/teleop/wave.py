"""Wave variables (Niemeyer & Slotine 1991): force reflection that stays passive under any constant delay.

At a port with velocity ``xdot`` (m/s) and force ``F`` (N) going *into* the channel, the wave
variables with impedance ``b`` (N s/m) are

    u = (b xdot + F) / sqrt(2 b)        (the wave going out)
    v = (b xdot - F) / sqrt(2 b)        (the wave coming in)

(units sqrt(W)), so the power into the channel is ``xdot F = (u^2 - v^2) / 2``. A delay line only
stores waves, so the channel's energy is the integral of ``(u_m^2 - v_m^2 + v_s^2 - u_s^2) / 2``
over time, which with ``u_s(t) = u_m(t - T)`` and ``v_m(t) = v_s(t - T)`` is the energy in
flight: it never goes negative, whatever T. The identity holds per tick for the values each end
computes, so the sampled channel is passive too; what can still create energy is how each end
meets its own sampled hardware, and the two corrections below deal with that:

- The slave port (:func:`slave`) moves before its force is measured: the force it pairs with its
  velocity is last tick's plus the most this tick's move can add (tracking stiffness times the
  tick). Without that, a stiff environment answers with a one-tick-old force, a negative damper
  of half its stiffness times the tick, and every echo comes back larger.
- Each end low-passes the wave it receives (:func:`app.filters.lowpass`, gain at most 1): the
  master's velocity filter, the device's zero-order hold and the slave's mass make the ends
  reflect some frequencies with gain above 1; the filters take that energy out of the waves, most
  of all the echoes bouncing between a hand-held grip and a rigid surface (one every round trip).

The master knows its velocity and receives ``v``: it sends ``u`` and feels ``F`` (:func:`master`).
The slave receives ``u`` and knows its force on the environment: it moves at ``xdot`` and sends
``v`` back (:func:`slave`). Each acts per axis on (3,) arrays in the slave world {w};
:mod:`app.teleop.link` says which velocity and force each end uses.

The cost is transparency: the channel behaves like a line of impedance b, so the operator feels
the environment through the line's compliance (it grows with the delay and with 1/b), feels a
damper b when moving freely, and the slave's position drifts from the master's by what the
line gave way during contact (the felt stiffness in ``frhc bench stability``).
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


def slave(u_s: Array, F_prev: Array, b: float, c: float, xdot_s: Array, F_s: Array, v_s: Array) -> None:
    """Slave side: from the arriving wave ``u_s`` (sqrt(W)) and the force ``F_prev`` (N) the slave
    exerted on the environment last tick, the velocity command ``xdot_s`` (m/s), the port force
    ``F_s`` (N) and the wave to send back ``v_s``. All (3,); ``xdot_s``, ``F_s`` and ``v_s`` are
    written.

    The slave moves this tick before its force is measured, so the port force is the last one
    plus ``c xdot_s``, with ``c`` (N s/m) the most force a tick's motion adds per unit velocity
    (the slave's tracking stiffness times the tick). Solving ``xdot_s = (r u_s - F_s) / b`` for
    both gives ``xdot_s = (r u_s - F_prev) / (b + c)``. With ``c = 0`` a stiff environment would
    see the one-tick-old force, which is a negative damper of half its stiffness times the tick:
    it returns each wave slightly larger than it came (an echo that grows).
    """
    r = math.sqrt(2.0 * b)
    for i in range(3):
        xdot_s[i] = (r * u_s[i] - F_prev[i]) / (b + c)
        F_s[i] = F_prev[i] + c * xdot_s[i]
        v_s[i] = u_s[i] - 2.0 * F_s[i] / r
