"""The first-order low-pass shared by the rooms, compiled: the passivity controller's joint velocity
(:mod:`app.controller.passivity`) and the waves arriving at each end of the delayed channel
(:mod:`app.teleop.link`).

``y += a (x - y)`` with ``a = dt / (tau + dt)``: the backward-Euler discretisation of
``tau y' = x - y``. For ``0 < a <= 1`` its gain is at most 1 at every frequency and exactly 1 at
zero, so it passes steady values and never amplifies: the sum of ``y^2`` never exceeds that of
``x^2`` plus the stored ``(1 - a) / a y^2``. On waves that is Niemeyer & Slotine's wave filtering:
it removes wave energy, never adds it.
"""

from __future__ import annotations

from numba import njit

from app.spatial import Array


@njit(cache=True)
def lowpass_gain(dt: float, time_constant: float) -> float:
    """The per-tick gain ``a = dt / (time_constant + dt)`` of a low-pass of ``time_constant`` (s)
    sampled every ``dt`` (s): 1 (no filtering) for a zero time constant, 0 (hold) when no time
    passed (``dt <= 0``, or NaN: an unusable period)."""
    return dt / (time_constant + dt) if dt > 0.0 else 0.0


@njit(cache=True)
def lowpass(x: Array, a: float, y: Array) -> None:
    """One step ``y += a (x - y)`` in place; ``x`` and ``y`` of the same shape (n,)."""
    for i in range(y.shape[0]):
        y[i] += a * (x[i] - y[i])
