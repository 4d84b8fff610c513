"""Simulated operators: what acts on the loop before each tick (hand target and switches).

:class:`Operator` is the protocol; :class:`OperatorScript` plays a session file's timed hand
targets (smoothly interpolated) and switch events. A reacting operator is any object with a
``before_tick`` that reads the last :class:`~app.session.tick.TickRecord` (``loop.record``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numba import njit, types
from numba.experimental import structref

from app.compiled import F8, I8, Arrays, ArraysType, array_type, entry_point
from app.controller.types import Switches
from app.device.hand import copy_and_pull
from app.session.spec import SessionFile, SwitchEvent
from app.spatial import Array, IntArray, make_pose, rotation_exp_into, rotation_log_into, zyx_to_matrix

if TYPE_CHECKING:
    from app.session.loop import ServoLoop


class Operator(Protocol):
    """A simulated operator: sets the hand target and the switches before each tick."""

    def before_tick(self, loop: ServoLoop) -> None:
        """Act on ``loop`` (``set_hand_target``, ``switches``, ``press_reference``) for its next tick."""


class OperatorScript:
    """Plays a session's waypoints and switch events against simulated time.

    Args:
        data: The session file (waypoints, events, tremor, seed, time scale).
        T_0_G_start: The grip's pose when the session starts (4, 4); waypoints are relative to it.
        switches: The switches the events act on (a loop's ``switches``); a new set by default.

    Between waypoints the hand moves with a smoothstep profile (zero velocity at each waypoint),
    rotating along the geodesic. Before the first waypoint the hand holds the start pose; after
    the last it holds the last one. Tremor is a seeded, low-passed random offset (m).
    """

    TREMOR_CUTOFF_HZ = 8.0

    def __init__(self, data: SessionFile, T_0_G_start: Array, switches: Switches | None = None) -> None:
        scale = data.time_scale
        self._times = [w.t * scale for w in data.waypoints]
        R0 = T_0_G_start[0:3, 0:3]
        p0 = T_0_G_start[0:3, 3]
        self._poses = [
            make_pose(R0 @ zyx_to_matrix(*(math.radians(a) for a in w.zyx_deg)), p0 + np.array(w.position))
            for w in data.waypoints
        ] or [T_0_G_start.copy()]
        if not self._times:
            self._times = [0.0]
        self._events = sorted(data.events, key=lambda e: e.t)
        self._event_times = [e.t * scale for e in self._events]
        self._next_event = 0
        self._next_time = self._event_at(0)
        self.switches = Switches() if switches is None else switches
        self.hand_on = True
        # A grip event due and not yet applied to a loop (apply_events): True closes, False opens.
        self._grip: bool | None = None
        self._rate = data.servo_rate
        self._tremor = _tremor(data.n_ticks, data.tremor, data.seed, data.servo_rate, self.TREMOR_CUTOFF_HZ)
        self._T = np.eye(4)
        # The waypoint poses stacked, with the last repeated: the blend from it to itself holds it.
        self._stack = np.stack([*self._poses, self._poses[-1]])
        # The blend's scratch: R_a^T R_b and the rotation from R_a (3, 3), the rotation vector (3,).
        scratch = (np.empty((3, 3)), np.empty((3, 3)), np.empty(3))
        self._path = (np.array(self._times), self._stack, self._tremor, *scratch)
        # Called every tick with the same kinds of arguments: the compiled specialisations, once.
        self._pose = entry_point(_scripted_pose, *self._path, 0.0, 0, self._T)
        # The loop whose held hand before_tick moves in one compiled call (_pose_and_pull), that
        # call and its arguments; set on the first tick the hand holds (ServoLoop.hand_pull).
        self._pulled: object = None
        self._pose_and_pull: Callable[..., bool] | None = None
        self._arrays: Arrays | None = None

    def hand_target(self, t: float, tick: int) -> Array:
        """Hand-target pose ``T_0_H`` (4, 4) at time ``t`` (s); ``tick`` indexes the tremor."""
        self._pose(*self._path, t, tick, self._T)
        return self._T

    @staticmethod
    def for_loop(data: SessionFile, loop: ServoLoop) -> OperatorScript:
        """The script of ``data`` acting on ``loop``, relative to its grip pose now."""
        return OperatorScript(data, loop.reading.T_0_G.copy(), loop.switches)

    def before_tick(self, loop: ServoLoop) -> None:
        """Apply the events due by ``loop.time`` and move the hand (:class:`Operator`).

        While the hand holds the grip of a simulated device, the pose is blended and the hand
        pulled in one compiled call (:meth:`~app.session.loop.ServoLoop.hand_pull`): ~2 us a tick
        less than :meth:`hand_target` and ``set_hand_target``, the same values.
        """
        t, tick = loop.time, loop.ticks
        self.apply_due_events(loop)
        if not self.hand_on:
            loop.set_hand_target(None)
        elif loop is self._pulled and loop.record.hand_on:
            assert self._pose_and_pull is not None
            if not self._pose_and_pull(t, tick, self._arrays):
                raise ValueError("T_0_H must be a finite 4x4 pose")
        else:
            loop.set_hand_target(self.hand_target(t, tick))
            pull = loop.hand_pull()
            if pull is not None:
                hand, (T_hand, mocap_pos, mocap_quat, *functions) = pull
                model = np.array(functions, dtype=np.int64)
                self._arrays = _script_arrays(*self._path, self._T, hand, T_hand, mocap_pos, mocap_quat, model)
                self._pulled = loop
                self._pose_and_pull = entry_point(_pose_and_pull, types.float64, types.int64, self._arrays)

    def apply_due_events(self, loop: ServoLoop) -> None:
        """:meth:`apply_events` if an event is due by ``loop.time`` or a grip event waits; else
        nothing (two comparisons: called every tick)."""
        if self._next_time <= loop.time or self._grip is not None:
            self.apply_events(loop)

    def apply_events(self, loop: ServoLoop) -> None:
        """Apply the events due by ``loop.time``: the switches, and the last grip event due to
        the loop's slave (:meth:`~app.session.loop.ServoLoop.set_grip`)."""
        self.update_switches(loop.time)
        if self._grip is not None:
            loop.set_grip(self._grip)
            self._grip = None

    def update_switches(self, t: float) -> Switches:
        """Apply the events due by time ``t`` (s). A reference press sets the switch; the loop
        releases it after one tick (:meth:`~app.session.loop.ServoLoop.tick`)."""
        sw = self.switches
        while self._next_time <= t:
            self._apply(self._events[self._next_event])
            self._next_event += 1
            self._next_time = self._event_at(self._next_event)
        return sw

    def _event_at(self, i: int) -> float:
        """When event ``i`` is due (s); infinity past the last."""
        return self._event_times[i] if i < len(self._event_times) else math.inf

    def _apply(self, e: SwitchEvent) -> None:
        sw = self.switches
        if e.deadman is not None:
            sw.deadman = e.deadman
        if e.reflection is not None:
            sw.reflection = e.reflection
        if e.hand is not None:
            self.hand_on = e.hand
        if e.grip is not None:
            self._grip = e.grip
        if e.reference:
            sw.reference = True


@njit(cache=True)
def _scripted_pose(
    times: Array, poses: Array, tremor: Array, M: Array, E: Array, w: Array, t: float, tick: int, T: Array
) -> None:
    """``T`` (4, 4) = the hand target at time ``t`` (s): before the first waypoint time (``times``)
    the first pose, after the last the last, in between the smoothstep blend (:func:`_blend`, in
    the scratch ``M``, ``E``, ``w``) of the two around ``t``; plus the tremor of ``tick``."""
    n = times.shape[0]
    i = 0  # the first waypoint after t (bisect_right; a session has a few waypoints)
    while i < n and times[i] <= t:
        i += 1
    k, s = 0, 0.0
    if i == n:
        k = n - 1
    elif i > 0:
        k, s = i - 1, (t - times[i - 1]) / (times[i] - times[i - 1])
    _blend(poses, k, s * s * (3.0 - 2.0 * s), tremor, tick, T, M, E, w)


_F1, _F2, _F3 = (array_type(n, F8) for n in (1, 2, 3))
# The waypoint times, poses and tremor (_scripted_pose), its target, the loop's hand target, and
# the simulated hand's target and mocap pose (pull_target's arrays).
_SCRIPT_FIELDS = {"times": _F1, "poses": _F3, "tremor": _F2, "M": _F2, "E": _F2, "w": _F1, "T": _F2, "hand": _F2}
_SCRIPT_FIELDS |= {"T_hand": _F2, "mocap_pos": _F1, "mocap_quat": _F1}
_SCRIPT_ARRAYS = ArraysType([*_SCRIPT_FIELDS.items(), ("model", array_type(1, I8))])


@njit(cache=True)
def _script_arrays(
    times: Array,
    poses: Array,
    tremor: Array,
    M: Array,
    E: Array,
    w: Array,
    T: Array,
    hand: Array,
    T_hand: Array,
    mocap_pos: Array,
    mocap_quat: Array,
    model: IntArray,
) -> Arrays:
    """The arrays of :func:`_pose_and_pull` as one :class:`~app.compiled.Arrays`; no copy."""
    arrays: Any = structref.new(_SCRIPT_ARRAYS)  # type: ignore[call-arg]  # an intrinsic, typed by numba
    arrays.times = times
    arrays.poses = poses
    arrays.tremor = tremor
    arrays.M = M
    arrays.E = E
    arrays.w = w
    arrays.T = T
    arrays.hand = hand
    arrays.T_hand = T_hand
    arrays.mocap_pos = mocap_pos
    arrays.mocap_quat = mocap_quat
    arrays.model = model
    return arrays


@njit(cache=True)
def _pose_and_pull(t: float, tick: int, arrays: Arrays) -> bool:
    """:func:`_scripted_pose` at ``t``, ``tick`` into the bundle's ``T``, copied to the loop's
    ``hand`` (4, 4) and pulled (:func:`~app.device.hand.copy_and_pull`, the bundle's ``T_hand``,
    ``mocap_pos``, ``mocap_quat``, and its ``model``: the functions, model and data that takes);
    False if not finite."""
    a: Any = arrays
    T, f = a.T, a.model
    _scripted_pose(a.times, a.poses, a.tremor, a.M, a.E, a.w, t, tick, T)
    return copy_and_pull(T, a.hand, a.T_hand, a.mocap_pos, a.mocap_quat, f[0], f[1], f[2], f[3])


@njit(cache=True)
def _blend(poses: Array, k: int, s: float, tremor: Array, tick: int, T: Array, M: Array, E: Array, w: Array) -> None:
    """``T`` (4, 4) = waypoint pose k blended a fraction ``s`` toward pose k + 1 (position on the
    straight line, rotation along the geodesic), plus the tremor offset of ``tick`` (m): row
    ``tick`` of ``tremor`` (n, 3), its last row past the end. In the scratch ``M``, ``E`` (3, 3)
    and ``w`` (3,), indexed, never sliced: an allocation or a view costs more than this
    arithmetic (the products written out: numba's ``@`` calls BLAS, ~0.3 us each on 3x3 blocks)."""
    for i in range(3):  # M = R_a^T R_b
        for j in range(3):
            M[i, j] = (
                poses[k, 0, i] * poses[k + 1, 0, j]
                + poses[k, 1, i] * poses[k + 1, 1, j]
                + poses[k, 2, i] * poses[k + 1, 2, j]
            )
    rotation_log_into(M, w)
    for i in range(3):
        w[i] = s * w[i]
    rotation_exp_into(w, E)
    m = min(tick, tremor.shape[0] - 1)
    for i in range(3):
        for j in range(3):  # R_a E
            T[i, j] = poses[k, i, 0] * E[0, j] + poses[k, i, 1] * E[1, j] + poses[k, i, 2] * E[2, j]
        T[i, 3] = poses[k, i, 3] + s * (poses[k + 1, i, 3] - poses[k, i, 3]) + tremor[m, i]
        T[3, i] = 0.0
    T[3, 3] = 1.0


def _tremor(n: int, sigma: float, seed: int, rate: float, cutoff_hz: float) -> Array:
    """Seeded tremor offsets (m), shape (n, 3): white noise through a first-order low-pass filter,
    scaled to standard deviation ``sigma``."""
    if sigma == 0.0:
        return np.zeros((n, 3))
    rng = np.random.default_rng(seed)
    white = rng.standard_normal((n, 3))
    alpha = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz / rate)
    out = _low_pass(white, alpha)
    # Stationary standard deviation of that filter on unit white noise.
    return out * (sigma / math.sqrt(alpha / (2.0 - alpha)))


@njit(cache=True)
def _low_pass(x: Array, alpha: float) -> Array:
    """First-order low-pass of the rows of ``x`` (n, k) from zero, gain ``alpha`` a sample
    (compiled: a session's tremor is tens of thousands of rows, built at every start)."""
    out = np.empty_like(x)
    acc = np.zeros(x.shape[1])
    for i in range(x.shape[0]):
        for a in range(x.shape[1]):
            acc[a] += alpha * (x[i, a] - acc[a])
            out[i, a] = acc[a]
    return out
