"""One tick of a :class:`~app.session.operators.ReactingOperator`, compiled with numba.

The operator's strategy (perceive late, decide the tool velocity, invert the learned rate mapping,
add tremor) is a few dozen operations on 3-vectors: in CPython with numpy they cost ~15 us a
tick, about 0.4x the servo tick they drive, and the experiment runs 200 such sessions. Here they
read and write the operator's preallocated arrays. The strategy itself is described in
:mod:`app.session.operators`; this module only follows it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numba.experimental import structref

from app.compiled import F8, I8, Arrays, ArraysType, array_type
from app.controller.assist import constant_force_rtc, hooke_rtc
from app.controller.record import RTC_CONSTANT, RTC_HOOKE
from app.device.hand import copy_and_pull
from app.slave.tool_kernel import _apply_into, mul3_into
from app.spatial import Array, IntArray, rotation_exp_into, rotation_log_into, zyx_to_matrix_into

# The strategy's constants. Their class (docs/experiment.md, "Every parameter of the physical
# model"): OVERSHOOT and CLEAR define the task (class b, reason given there); the others model the
# operator's behaviour (class a) and have no source: no stored study gives these figures.

#: Distance (m) below which the intended tool speed falls in proportion to the distance left.
SLOW_DISTANCE = 0.01
#: How far (m) past the task's goal depth the operator pushes: to the bottom of the holes (the
#: holes are 25 mm deep, the goal 20 mm: the task is to bottom the pegs out).
OVERSHOOT = 0.01
#: Time (s) without seen progress, past the goal depth, after which the pegs are seen to have bottomed out.
BOTTOM_S = 0.3
#: Height (m) above the goal at which the withdrawn tool is seen clear and the operator is done
#: (the peg tips 5 mm above the block: the task's end).
CLEAR = 0.025
#: Time (s) the operator holds the pegs at depth once they see them there.
HOLD_S = 0.3
#: Seen depth gain (m) below which, for STALL_S (s), an insertion counts as stuck.
STALL_DEPTH = 0.001
STALL_S = 1.0
#: Tool speed (m/s) over which the learned rate inverse crosses the deadband: how finely the
#: operator commands slow motion (not a numerical width: it decides whether a small lateral intent
#: leaves the deadband).
V_DB = 0.002
#: Tool angular speed (rad/s) over which the learned rate inverse crosses the rotational deadband.
W_DB = 0.02
#: Felt force, in multiples of the operator's threshold, from which they take back all of their push
#: against it (:func:`give_way_into`; between the threshold and this, in proportion to the excess).
GIVE_WAY_FULL = 2.0

#: Phases of an operator, in order; the kernel keeps the index into this.
PHASES = ("insert", "hold", "withdraw", "done")
INSERT, HOLD, WITHDRAW, DONE = range(4)
# Slots of the parameter vector (``prm``): the gains' rows (6 each), the task, the operator, the
# hand's stiffness per axis (6), and whether the return-to-centre acts now (set every tick).
K_V, DB, RTC_A, WALL_START, K_WALL, K_R, HAND_K = 0, 6, 12, 18, 24, 30, 36
GOAL, HOME, TOLERANCE, SPEED, THRESHOLD, RTC_KIND, RTC_ON, N_PRM = 42, 45, 48, 49, 50, 51, 52, 53
# Blocks of :func:`react`'s scratch ``work`` (N_WORK, 3, 3): its vectors are rows of blocks 1-2.
N_WORK = 9
# Slots of the operator's changing scalars (``state``).
SINCE, BEST_DEPTH, STALL_T, N_STATE = 0, 1, 2, 3


@njit(cache=True)
def push(ring: Array, index: IntArray, value: Array) -> Array:
    """Store ``value`` in the ring (n, k) at ``index[0]``, advance it; return the oldest sample."""
    i = index[0]
    ring[i, :] = value
    i = (i + 1) % ring.shape[0]
    index[0] = i
    return ring[i]


@njit(cache=True)
def low_pass(motor: Array, phi: Array, u: Array) -> None:
    """Advance a critically damped second-order low-pass one tick toward the input ``u`` (n,).

    ``motor`` (2, n) holds the output and its rate; ``phi`` (4,) is the row-major transition
    ``exp(A dt)`` of the state ``(y - u, y')`` (:class:`~app.session.operators.MotorLowPass`)."""
    for i in range(u.shape[0]):
        z = motor[0, i] - u[i]
        y = u[i] + phi[0] * z + phi[1] * motor[1, i]
        motor[1, i] = phi[2] * z + phi[3] * motor[1, i]
        motor[0, i] = y


@njit(cache=True)
def _toward_into(e: Array, speed: float, out: Array) -> None:
    """Velocity (m/s) toward error ``e`` (m), into ``out`` (3,): proportional within
    :data:`SLOW_DISTANCE`, capped at ``speed``."""
    n = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    gain = speed / SLOW_DISTANCE
    k = gain if n * gain <= speed else speed / n
    for a in range(3):
        out[a] = e[a] * k


@njit(cache=True)
def give_way(v: Array, felt: Array, f: float, threshold: float) -> Array:
    """:func:`give_way_into` as a new array (3,)."""
    out = np.empty(3)
    give_way_into(v, felt, f, threshold, out)
    return out


@njit(cache=True)
def give_way_into(v: Array, felt: Array, f: float, threshold: float, out: Array) -> None:
    """What the operator takes back (m/s, {w}) of their intended tool velocity ``v`` when they feel
    the force ``felt`` (N, {0} = {w} axes, magnitude ``f`` above ``threshold``): the part of ``v``
    that pushes against it, in proportion to the excess force, all of it from :data:`GIVE_WAY_FULL`
    times the threshold.

    Giving way is letting go of the push, not driving the tool the other way. In rate mode a
    velocity is a grip displacement (the learned inverse turns 44 mm/s into ~32 mm), and with
    NTRFC in contact "displacement of the hand-controller is proportional to exerted wrench"
    (Sec 4.3): taking the push back is what relieves the wrench; the slave's accommodation does
    the rest. An operator who instead moved the tool along the felt force at their own speed
    drove the pegs across the 0.2 mm clearance into the opposite wall, felt that a haptic delay
    later and swung back: a cycle the paper warns of ("the manipulator will reverse, only to be
    returned with the command from the operator's hand recovering forward", Sec 3.3), which on
    the least damped hand of the population (223 N/m, 3.7 N s/m) grew to a +-35 mm swing of the
    hand target (+-58 mm of the grip) and tripped the velocity brake. Taken back, the velocity never points along ``felt`` more
    than it did, so the yield needs no speed bound of its own. Zero when ``v`` does not push
    against the force. Written into ``out`` (3,)."""
    n0, n1, n2 = felt[0] / f, felt[1] / f, felt[2] / f
    push = -(v[0] * n0 + v[1] * n1 + v[2] * n2)
    if push <= 0.0:
        out[0] = out[1] = out[2] = 0.0
        return
    s = push * min((f / threshold - 1.0) / (GIVE_WAY_FULL - 1.0), 1.0)
    out[0], out[1], out[2] = n0 * s, n1 * s, n2 * s


@njit(cache=True)
def learned_rtc_offset(prm: Array, i: int, u: float) -> float:
    """How much further (m or rad) the trained operator sets their hand on axis ``i`` so that the grip
    still reaches ``u`` against the device's return-to-centre: the force ``F_R(u)`` (Eq 8, or
    Hooke's ``-K_R u``) over the hand's own stiffness on that axis.

    Humans learn a model of a force field they work in and compensate its forces in advance
    (Shadmehr & Mussa-Ivaldi 1994, "Adaptive representation of dynamics during learning of a motor
    task", J. Neurosci. 14(5):3208-3224); the paper's operators were "trained" (Sec 4.3). Without
    it a hand softer than ``a DB / 1`` (the CFRTC force over the deadband, 1 N / 10 mm = 100 N/m on
    the Kraft) cannot push the grip out of the deadband at all. Zero when the return-to-centre is
    off (blind: "return-to-center ... not enabled without this third switch", Sec 4.1) or the hand
    has no stiffness on the axis.
    """
    k = prm[HAND_K + i]
    if prm[RTC_ON] == 0.0 or k <= 0.0:
        return 0.0
    kind = int(prm[RTC_KIND])
    if kind == RTC_CONSTANT:
        f = constant_force_rtc(u, prm[RTC_A + i], prm[DB + i], prm[WALL_START + i], prm[K_WALL + i])
    elif kind == RTC_HOOKE:
        f = hooke_rtc(u, prm[K_R + i])
    else:
        return 0.0
    return -f / k


@njit(cache=True)
def react(
    seen_ring: Array,
    seen_i: IntArray,
    seen_R_ring: Array,
    seen_R_i: IntArray,
    felt_ring: Array,
    felt_i: IntArray,
    phase: IntArray,
    state: Array,
    aim: Array,
    tilt: Array,
    prm: Array,
    T_start: Array,
    R_home: Array,
    tremor: Array,
    motor: Array,
    phi: Array,
    work: Array,
    T_w_MRF: Array,
    T_0_G: Array,
    G_F_T: Array,
    t: float,
    tick: int,
    hand: Array,
) -> None:
    """Perceive, decide and write the hand target ``hand`` (4, 4, {0}) for the next tick.

    ``phase[0]`` indexes :data:`PHASES`; ``aim`` and ``tilt`` (3,) are halved when the operator
    looks again. The senses are rings the operator reads ``len - 1`` ticks late (:func:`push`).
    The hand's six displacements pass through the motor low-pass ``motor``, ``phi`` (:func:`low_pass`).
    ``work`` (:data:`N_WORK`, 3, 3) holds the intermediates: nothing is allocated.
    """
    speed, threshold = prm[SPEED], prm[THRESHOLD]
    tool, felt_now, e = work[1, 0], work[1, 1], work[1, 2]
    v, g, w = work[2, 0], work[2, 1], work[2, 2]
    for a in range(3):
        tool[a] = T_w_MRF[a, 3]
    seen = push(seen_ring, seen_i, tool)
    R_now = work[0].reshape(9)
    for a in range(3):
        for b in range(3):
            R_now[3 * a + b] = T_w_MRF[a, b]
    seen_R = push(seen_R_ring, seen_R_i, R_now).reshape((3, 3))
    _apply_into(T_0_G, G_F_T, felt_now)
    felt = push(felt_ring, felt_i, felt_now)
    f = math.sqrt(felt[0] * felt[0] + felt[1] * felt[1] + felt[2] * felt[2])

    # The intended tool velocity (m/s, {w}) and the phase it leads to.
    v[0] = v[1] = v[2] = 0.0
    goal_z = prm[GOAL + 2]
    if phase[0] == INSERT:
        for a in range(3):
            e[a] = prm[GOAL + a] + aim[a] - seen[a]
        e[2] -= OVERSHOOT
        deep = seen[2] <= goal_z + prm[TOLERANCE]
        if seen[2] < state[BEST_DEPTH] - STALL_DEPTH:
            state[BEST_DEPTH], state[STALL_T] = seen[2], t
            _toward_into(e, speed, v)
        elif deep and (t - state[STALL_T] > BOTTOM_S or f > threshold):
            phase[0], state[SINCE] = HOLD, t
            _toward_into(e, speed, v)
        elif not deep and t - state[STALL_T] > STALL_S:
            # Stuck above the holes: look again, misjudge by half as much, lift a little, push again.
            aim *= 0.5
            tilt *= 0.5
            state[STALL_T], state[BEST_DEPTH] = t, seen[2] + STALL_DEPTH
            v[2] = speed
        else:
            _toward_into(e, speed, v)
    elif phase[0] == HOLD:
        if t - state[SINCE] >= HOLD_S:
            phase[0] = WITHDRAW
    elif phase[0] == WITHDRAW:
        e[0], e[1], e[2] = 0.0, 0.0, prm[HOME + 2] - seen[2]
        if seen[2] >= goal_z + CLEAR:
            phase[0] = DONE
        _toward_into(e, speed, v)
    if f > threshold:
        give_way_into(v, felt, f, threshold, g)
        for a in range(3):
            v[a] = v[a] + g[a]

    # The tool angular velocity (rad/s, {MRF}): toward upright as misjudged, while inserting.
    w[0] = w[1] = w[2] = 0.0
    if phase[0] == INSERT:
        rotation_exp_into(tilt, work[4])
        mul3_into(seen_R.T, work[4], work[5])
        mul3_into(work[5], R_home, work[6])
        rotation_log_into(work[6], w)
        k = speed / SLOW_DISTANCE
        for a in range(3):
            w[a] = w[a] * k

    # The learned rate-mode inverse, with the return-to-centre's force compensated as learned,
    # through the hand's motor bandwidth, plus tremor.
    u = work[3].reshape(9)[0:6]
    for a in range(3):
        u[a] = v[a] / prm[K_V + a] + prm[DB + a] * math.tanh(v[a] / V_DB)
        u[3 + a] = w[a] / prm[K_V + 3 + a] + prm[DB + 3 + a] * math.tanh(w[a] / W_DB)
    for i in range(6):
        u[i] += learned_rtc_offset(prm, i, u[i])
    low_pass(motor, phi, u)
    k = min(tick, tremor.shape[0] - 1)
    for a in range(3):
        hand[a, 3] = T_start[a, 3] + motor[0, a] + tremor[k, a]
    zyx_to_matrix_into(motor[0, 3], motor[0, 4], motor[0, 5], work[7])
    R = work[8]
    mul3_into(T_start, work[7], R)
    for a in range(3):
        for b in range(3):
            hand[a, b] = R[a, b]


_F1, _F2, _I1 = array_type(1, F8), array_type(2, F8), array_type(1, I8)
# react's own arrays, in its order; then the loop's hand target and the simulated hand's target
# and mocap pose (pull_target's arrays).
_OWN = {"seen_ring": _F2, "seen_i": _I1, "seen_R_ring": _F2, "seen_R_i": _I1, "felt_ring": _F2, "felt_i": _I1}
_OWN |= {"phase": _I1, "state": _F1, "aim": _F1, "tilt": _F1, "prm": _F1, "T_start": _F2, "R_home": _F2}
_OWN |= {"tremor": _F2, "motor": _F2, "phi": _F1, "work": array_type(3, F8), "hand": _F2, "loop_hand": _F2}
_OWN |= {"T_hand": _F2}
_OPERATOR_ARRAYS = ArraysType([*_OWN.items(), ("mocap_pos", _F1), ("mocap_quat", _F1)])


@njit(cache=True)
def operator_arrays(
    seen_ring: Array,
    seen_i: IntArray,
    seen_R_ring: Array,
    seen_R_i: IntArray,
    felt_ring: Array,
    felt_i: IntArray,
    phase: IntArray,
    state: Array,
    aim: Array,
    tilt: Array,
    prm: Array,
    T_start: Array,
    R_home: Array,
    tremor: Array,
    motor: Array,
    phi: Array,
    work: Array,
    hand: Array,
    loop_hand: Array,
    T_hand: Array,
    mocap_pos: Array,
    mocap_quat: Array,
) -> Arrays:
    """:func:`react`'s own arrays and ``hand``, the loop's hand target and the simulated hand's
    :func:`~app.device.hand.pull_target` arrays as one :class:`~app.compiled.Arrays`; no copy."""
    a: Any = structref.new(_OPERATOR_ARRAYS)  # type: ignore[call-arg]  # an intrinsic, typed by numba
    a.seen_ring = seen_ring
    a.seen_i = seen_i
    a.seen_R_ring = seen_R_ring
    a.seen_R_i = seen_R_i
    a.felt_ring = felt_ring
    a.felt_i = felt_i
    a.phase = phase
    a.state = state
    a.aim = aim
    a.tilt = tilt
    a.prm = prm
    a.T_start = T_start
    a.R_home = R_home
    a.tremor = tremor
    a.motor = motor
    a.phi = phi
    a.work = work
    a.hand = hand
    a.loop_hand = loop_hand
    a.T_hand = T_hand
    a.mocap_pos = mocap_pos
    a.mocap_quat = mocap_quat
    return a


@njit(cache=True)
def react_and_pull(
    T_w_MRF: Array,
    T_0_G: Array,
    G_F_T: Array,
    t: float,
    tick: int,
    arrays: Arrays,
    kinematics: int,
    transmission: int,
    m: int,
    d: int,
) -> bool:
    """:func:`react` on the bundle's arrays, its hand target copied to the loop's and pulled
    (:func:`~app.device.hand.copy_and_pull` with these functions and model): the operator's tick in
    one call. False, with the hand not pulled, if the target is not finite."""
    a: Any = arrays
    hand = a.hand
    react(
        a.seen_ring, a.seen_i, a.seen_R_ring, a.seen_R_i, a.felt_ring, a.felt_i, a.phase, a.state, a.aim,
        a.tilt, a.prm, a.T_start, a.R_home, a.tremor, a.motor, a.phi, a.work, T_w_MRF, T_0_G, G_F_T, t, tick,
        hand,
    )  # fmt: skip
    return copy_and_pull(hand, a.loop_hand, a.T_hand, a.mocap_pos, a.mocap_quat, kinematics, transmission, m, d)
