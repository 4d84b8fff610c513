"""Time-domain passivity observer and controller on the device port (Hannaford & Ryu 2002), compiled.

The controller, seen from the device, is a one-port: the motors put the rendered torque ``tau_r``
(task wrench, assists and the PC's own damping: everything but gravity compensation, which
balances a conservative field) into the joints while the joints move. Passive means it never
gives out more energy than it took in.

**Observer (PO)**, per joint, from measured quantities only, no model: the torque commanded in
the last tick was held over the period (zero-order hold) while the joint moved by ``dq`` (encoder
difference), so that tick's work on the controller is exactly ``-tau_r dq``;

    E_j(n) = E_j(n-1) - tau_r,j(n-1) * (q_j(n) - q_j(n-1))     (J, or N m rad)

is the energy the controller has absorbed through joint j (>= 0 while it is passive). It runs
always, so the trace shows how active plain rendering is; optionally ``E_j`` is capped at
``energy_cap`` so a long dissipative stretch cannot bank energy for a long active one.

**Controller (PC)**, when enabled: the energy after this tick is predicted with the last joint
velocity, ``E_pred = E_j - T tau_r,j qdot_j``; if it is negative the joint gets the damping
``alpha_j = -E_pred / (T qdot_j^2)`` (``tau_PC,j = -alpha_j qdot_j``), which dissipates exactly
that excess, limited so that ``|tau_j + tau_PC,j|`` stays within ``max_torque_fraction`` of the
joint's limit and never reverses sign (it can only take energy out). Below ``min_speed`` the PC
does not act (the damping needed would be unbounded, and the excess cannot leave through a
joint that does not move).

Per joint rather than per Cartesian axis at the grip: joint torques and encoder differences are
what the controller commands and measures, so the observed energy needs no Jacobian (which is
uncertain near singularities, where activity is likeliest), and joint power sums to the grip's
power (``tau . qdot = F . J qdot``), so passive joints make a passive grip. The price is some
conservatism: energy one joint gives back is not credited to another.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

from numba import njit

from app.config import Checked, Range
from app.spatial import Array


@dataclass(frozen=True)
class PassivitySettings(Checked):
    """The passivity controller's settings (the observer always runs).

    Attributes:
        enabled: The PC adds its damping (else the energy is only observed).
        max_torque_fraction: Share (0, 1] of each joint's torque limit the total may reach
            because of the PC's damping (-).
        energy_cap: Largest energy (J; N m rad for revolute joints) a joint's observer may
            bank; inf = none.
        min_speed: Joint speed (rad/s, or m/s for slides) below which the PC does not act.
        max_damping: Largest joint damping the PC applies (N m s/rad; N s/m for slides): a
            damper acting on the last tick's velocity is itself active beyond about inertia/T.
        velocity_filter: Time constant (s) of the first-order low-pass on the encoder velocity
            the PC damps and predicts with (0 = none): one encoder count a tick is a velocity
            spike of the wrong sign half the time. The observer always uses the exact difference.
    """

    enabled: bool = False
    max_torque_fraction: Annotated[float, Range(0.0, 1.0, lo_open=True)] = 1.0
    energy_cap: Annotated[float, Range(0.0, 1e3, "J", inf_ok=True)] = math.inf
    min_speed: Annotated[float, Range(0.0, 10.0, "rad/s")] = 1e-3
    max_damping: Annotated[float, Range(0.0, 1e3, "N m s/rad")] = 1e3
    velocity_filter: Annotated[float, Range(0.0, 0.1, "s")] = 0.0


@njit(cache=True)
def observe_energy(energy: Array, tau_prev: Array, qdot: Array, dt: float, cap: float) -> float:
    """PO step: ``energy_j -= tau_prev_j * qdot_j * dt`` (then capped at ``cap``); returns the sum.

    Args:
        energy: Energy absorbed by the controller per joint (J), (n,), updated.
        tau_prev: Rendered joint torque held over the last period (N m or N), (n,).
        qdot: Joint velocity over that period, ``dq / dt`` (rad/s or m/s), (n,).
        dt: The period (s); 0 when there is no usable velocity (nothing is added).
    """
    total = 0.0
    for j in range(energy.shape[0]):
        e = energy[j] - tau_prev[j] * qdot[j] * dt
        energy[j] = min(e, cap)
        total += energy[j]
    return total


@njit(cache=True)
def filter_velocity(qdot: Array, dt: float, time_constant: float, v: Array) -> None:
    """First-order low-pass ``v += (qdot - v) dt / (time_constant + dt)`` in place, (n,) each."""
    a = dt / (time_constant + dt) if dt > 0.0 else 0.0
    for j in range(v.shape[0]):
        v[j] += a * (qdot[j] - v[j])


@njit(cache=True)
def passivity_control(
    energy: Array,
    tau_r: Array,
    qdot: Array,
    dt: float,
    min_speed: float,
    max_damping: float,
    limit: Array,
    tau: Array,
    tau_pc: Array,
) -> float:
    """PC step: per-joint damping that dissipates the predicted energy deficit; returns the largest.

    Args:
        energy: Observed energy per joint (J), (n,).
        tau_r: Rendered torque about to be applied (N m or N), (n,).
        qdot: Last joint velocity (rad/s or m/s), (n,): the predicted velocity over this tick.
        dt: Servo period (s). ``min_speed``: below it a joint gets no damping.
        max_damping: The largest ``alpha_j`` (N m s/rad or N s/m).
        limit: Largest ``|tau_j|`` the PC may lead to (N m or N), (n,).
        tau: The total joint torque (N m or N), (n,): the PC torque is added in place.
        tau_pc: The PC torque ``-alpha_j qdot_j`` (N m or N), (n,), written.

    Returns:
        The largest damping ``alpha_j`` applied (N m s/rad, or N s/m for slides).
    """
    alpha_max = 0.0
    for j in range(energy.shape[0]):
        tau_pc[j] = 0.0
        v = qdot[j]
        if not abs(v) > min_speed or not dt > 0.0:
            continue
        predicted = energy[j] - dt * tau_r[j] * v
        if predicted >= 0.0:
            continue
        t = max(predicted / (dt * v * v), -max_damping) * v  # opposes v: only dissipates
        # Keep the total within the limit; a clip that would reverse the PC's sign gives 0.
        hi = limit[j] - tau[j]
        lo = -limit[j] - tau[j]
        if t > hi:
            t = max(hi, 0.0)
        elif t < lo:
            t = min(lo, 0.0)
        tau_pc[j] = t
        tau[j] += t
        alpha_max = max(alpha_max, -t / v)
    return alpha_max
