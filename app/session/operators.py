"""Simulated operators that close the loop: they see the tool late and feel the grip force.

The shipped scripts (:class:`~app.session.script.OperatorScript`) move the hand along fixed
waypoints, so a result depends on the script more than on the feedback. A
:class:`ReactingOperator` instead drives the tool to the scene's task goal in rate mode the way a
person would: from what they *see*, the tool's position a visual reaction delay ago, and, when
the wrench is reflected, from what they *feel* at the grip a (shorter) haptic delay ago. Blind,
the felt force is zero and only vision acts. Besides these deliberate reactions, the hand's own
impedance (:class:`~app.device.hand.HandParams`) yields to the grip force at once.

The strategy, per tick, in the base frame {0} (its axes are the slave world's, ``docs/conventions.md``):

1. Intent: a tool velocity toward the goal as seen, ``v = e * speed / SLOW_DISTANCE`` capped at
   ``speed`` (m/s), with ``e`` the goal (misjudged laterally by ``aim_error``, and
   :data:`OVERSHOOT` deeper: the operator inserts until the pegs bottom out) minus the seen tool
   position; and, while inserting, a tool angular velocity ``w = e_R * speed / SLOW_DISTANCE``
   (rad/s, {MRF} axes) toward the orientation they take for upright, misjudged by ``tilt_error``
   about a horizontal axis, with ``e_R`` the rotation vector from the seen tool orientation to it.
   Phases: insert until, past the goal depth, the tool is seen to stop (:data:`BOTTOM_S`) or a
   force above the threshold is felt; hold :data:`HOLD_S`; withdraw toward the start height until
   seen :data:`CLEAR` above the goal; done.
2. Force threshold: a felt force above ``force_threshold`` (N) is yielded to: the operator moves
   along it at ``speed`` per threshold of excess force, at most :data:`YIELD_MAX` times ``speed``.
3. Searching: when the seen tool has not gone deeper by :data:`STALL_DEPTH` in :data:`STALL_S` while
   inserting, the operator looks again and halves their aim and tilt errors (lifts, re-aims,
   pushes again).
4. The hand target is the start grip pose displaced by the rate-mode inverse the operator has
   learned, ``d = v / K_V + DB tanh(v / V_DB)`` per axis (the deadband is crossed smoothly; for
   the rotation ``W_DB`` in place of ``V_DB``, and ``d`` as the grip's Z-Y-X angles from its start,
   which Eq 5 maps to ``w`` for small angles), passed through the hand's motor bandwidth
   (:class:`MotorLowPass`: a person's voluntary output cannot step, so a change of intent, e.g.
   insert to hold, or a yield, moves the hand within a few tens of milliseconds, not in one tick),
   plus a seeded physiological tremor.

Parameter ranges of the population (:data:`POPULATION`) and their sources:

- Hand stiffness 150-800 N/m and damping 5-25 N s/m: endpoint impedance of the human arm in
  maintained posture, Mussa-Ivaldi, Hogan & Bizzi (1985), J. Neurosci. 5(10):2732-2743, and
  Tsuji, Morasso, Goto & Ito (1995), Biol. Cybern. 72:475-485.
- Visual reaction delay 0.15-0.25 s: simple visual reaction times (Welford (1980), *Reaction
  Times*, Academic Press; Card, Moran & Newell (1983), *The Psychology of Human-Computer
  Interaction*, the perceive-decide-act cycle of ~240 ms with a range of ~100-470 ms).
- Haptic reaction delay 0.06-0.15 s: long-latency responses of the hand to a load change,
  Johansson & Westling (1987), Exp. Brain Res. 66:141-154 (grip responses ~60-100 ms), and
  voluntary reactions to kinesthetic stimuli (~120-150 ms).
- Force threshold 1-5 N: contact forces of a few newtons held in force-reflecting peg-in-hole
  insertions, Hannaford, Wood, McAffee & Zak (1991), IEEE Trans. SMC 21(3):620-633.
- Tremor 0.1-0.5 mm (standard deviation, low-passed at 8 Hz): physiological hand tremor, Elble &
  Koller (1990), *Tremor*, Johns Hopkins University Press.
- Lateral misalignment up to 2.5 mm and angular misalignment up to 1 degree: the part-location
  errors a remote centre compliance is built to absorb in robotic peg-in-hole assembly (+-2.5 mm
  lateral, +-1 degree; "Remote center compliance", https://probsee.com/p/remote_center_compliance,
  after Whitney (1982), J. Dyn. Syst. Meas. Control 104:65-77, whose analysis takes the initial
  lateral and angular errors as the two inputs of an insertion). Here they are the operator's
  misjudgement of where the holes are and of upright, drawn uniformly up to those bounds.
- Motor bandwidth 5-10 Hz (:data:`MOTOR_BANDWIDTH`): the band over which the human hand can
  issue motion and force commands, Shimoga (1993), "A survey of perceptual feedback issues in
  dexterous telemanipulation: Part I. Finger force feedback", Proc. IEEE VRAIS, pp. 263-270
  (the hand's output bandwidth of 5-10 Hz against its sensing bandwidth of 20-30 Hz for force
  and up to ~320 Hz for touch). The citation is from the lead's brief; the stored material
  reached here confirms only that Shimoga's survey treats the hand's asymmetric input/output
  bandwidths, not the figures. Drawn from its own random stream (:func:`sample_population`), so
  adding it left every other value of every operator as it was.
- Approach speed 20-50 mm/s: *not* from the literature; a task choice spanning a careful to a
  brisk insertion. Nothing here is fitted to the paper's Table I.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated

import numpy as np

from app.config import Checked, Range
from app.session.script import OperatorScript, _tremor
from app.session.spec import Session
from app.spatial import Array, rotation_exp, rotation_log, zyx_to_matrix

if TYPE_CHECKING:
    from app.session.loop import ServoLoop

#: Distance (m) below which the intended tool speed falls in proportion to the distance left.
SLOW_DISTANCE = 0.01
#: How far (m) past the task's goal depth the operator pushes: to the bottom of the holes.
OVERSHOOT = 0.01
#: Time (s) without seen progress, past the goal depth, after which the pegs are seen to have bottomed out.
BOTTOM_S = 0.3
#: Height (m) above the goal at which the withdrawn tool is seen clear and the operator is done.
CLEAR = 0.025
#: Time (s) the operator holds the pegs at depth once they see them there.
HOLD_S = 0.3
#: Seen depth gain (m) below which, for STALL_S (s), an insertion counts as stuck.
STALL_DEPTH = 0.001
STALL_S = 1.0
#: Fastest deliberate yield, in units of the operator's own speed: a person gives way to a felt
#: force no faster than they move by choice (a modelling bound, not from a source). Unbounded, a
#: 1.35 N threshold meeting 15 N sent the hand target 0.38 m out and tripped the velocity brake.
YIELD_MAX = 1.0
#: Tool speed (m/s) over which the learned rate inverse crosses the deadband.
V_DB = 0.002
#: Tool angular speed (rad/s) over which the learned rate inverse crosses the rotational deadband.
W_DB = 0.02

#: Ranges (lo, hi) the population is drawn from, uniformly (sources in the module docstring).
POPULATION: dict[str, tuple[float, float]] = {
    "stiffness_trans": (150.0, 800.0),
    "damping_trans": (5.0, 25.0),
    "visual_delay": (0.15, 0.25),
    "haptic_delay": (0.06, 0.15),
    "force_threshold": (1.0, 5.0),
    "tremor": (1e-4, 5e-4),
    "speed": (0.02, 0.05),
    "aim_error": (0.0, 0.0025),
    "tilt_error": (0.0, math.radians(1.0)),
}
#: Range (lo, hi) of the operators' motor bandwidth (Hz), drawn uniformly from its own stream.
MOTOR_BANDWIDTH = (5.0, 10.0)


@dataclass(frozen=True)
class OperatorParams(Checked):
    """One simulated person (sources of the ranges in the module docstring).

    Attributes:
        name: Label in tables.
        stiffness_trans: Hand stiffness (N/m), translational.
        damping_trans: Hand damping (N s/m), translational.
        visual_delay: Delay (s) of what they see (the tool's position).
        haptic_delay: Delay (s) of what they feel (the reflected grip force).
        force_threshold: Felt force (N) above which they yield.
        tremor: Standard deviation (m) of their hand tremor.
        speed: Tool speed (m/s) they aim for.
        aim_error: Lateral misjudgement (m) of where the goal is, at angle ``aim_angle`` (rad).
        aim_angle: Direction of the misjudgement in the x-y plane (rad).
        tilt_error: Angular misjudgement (rad) of upright: the tool orientation they steer to is
            tilted by this about the horizontal axis at ``tilt_axis``.
        tilt_axis: Direction (rad) of that axis in the x-y plane.
        seed: Seed of their tremor.
        motor_bandwidth: Corner frequency (Hz) of their voluntary hand motion
            (:class:`MotorLowPass`); ``inf``: a hand that follows its intent within the tick.
    """

    name: str
    stiffness_trans: Annotated[float, Range(0.0, 1e4, "N/m")] = 400.0
    damping_trans: Annotated[float, Range(0.0, 1e3, "N s/m")] = 10.0
    visual_delay: Annotated[float, Range(0.0, 1.0, "s")] = 0.2
    haptic_delay: Annotated[float, Range(0.0, 1.0, "s")] = 0.1
    force_threshold: Annotated[float, Range(0.0, 100.0, "N", lo_open=True)] = 3.0
    tremor: Annotated[float, Range(0.0, 0.01, "m")] = 3e-4
    speed: Annotated[float, Range(0.0, 1.0, "m/s", lo_open=True)] = 0.03
    aim_error: Annotated[float, Range(0.0, 0.1, "m")] = 0.001
    aim_angle: Annotated[float, Range(-10.0, 10.0, "rad")] = 0.0
    tilt_error: Annotated[float, Range(0.0, 0.5, "rad")] = 0.0
    tilt_axis: Annotated[float, Range(-10.0, 10.0, "rad")] = 0.0
    seed: Annotated[int, Range(0, 2**32 - 1)] = 0
    motor_bandwidth: Annotated[float, Range(0.0, 1e3, "Hz", lo_open=True, inf_ok=True)] = 7.5

    def aim_offset(self) -> Array:
        """Where this operator believes the goal is, relative to where it is (m, {w}, shape (3,))."""
        return self.aim_error * np.array([math.cos(self.aim_angle), math.sin(self.aim_angle), 0.0])


def sample_population(n: int, seed: int = 0) -> tuple[OperatorParams, ...]:
    """``n`` operators drawn uniformly from :data:`POPULATION` and :data:`MOTOR_BANDWIDTH` (the same
    for the same seed). The bandwidth comes from a stream of its own (a child of ``seed``), so the
    other values are those drawn before it was added."""
    rng = np.random.default_rng(seed)
    motor = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0]).uniform(*MOTOR_BANDWIDTH, n)
    out = []
    for i in range(n):
        values = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in POPULATION.items()}
        aim_angle, tilt_axis = (float(a) for a in rng.uniform(-math.pi, math.pi, 2))
        op_seed = int(rng.integers(2**32))
        out.append(
            OperatorParams(
                f"Operator {i + 1}",
                **values,
                aim_angle=aim_angle,
                tilt_axis=tilt_axis,
                seed=op_seed,
                motor_bandwidth=float(motor[i]),
            )
        )
    return tuple(out)


class _Delayed:
    """What a sense reports ``delay`` seconds late: a ring of the last samples, shape (n, 3)."""

    def __init__(self, delay: float, dt: float, first: Array) -> None:
        self._ring = np.tile(first, (max(1, round(delay / dt)) + 1, 1))
        self._i = 0

    def push(self, value: Array) -> Array:
        """Store this tick's sample; return the one from ``delay`` ago."""
        ring = self._ring
        ring[self._i] = value
        self._i = (self._i + 1) % len(ring)
        return ring[self._i]


class MotorLowPass:
    """A hand's voluntary motion: a critically damped second-order low-pass, both poles at
    ``2 pi bandwidth`` (rad/s), on a vector signal (here the hand target's six displacements from
    its start, m and rad).

    The step is exact for an input held over the tick (the state ``(y - u, y')`` advances by
    ``exp(A dt)``, ``A = [[0, 1], [-w^2, -2 w]]``), so a step of the input gives
    ``y(t) = u (1 - (1 + w t) e^(-w t))`` at the ticks, with no overshoot and a continuous
    velocity, at any rate. ``bandwidth = inf`` passes the input through.
    """

    def __init__(self, bandwidth: float, dt: float, first: Array) -> None:
        w = 2.0 * math.pi * bandwidth
        if math.isinf(w):
            self._phi = np.zeros((2, 2))
        else:
            e = math.exp(-w * dt)
            self._phi = e * np.array([[1.0 + w * dt, dt], [-w * w * dt, 1.0 - w * dt]])
        self._y = np.array(first, dtype=float)
        self._v = np.zeros_like(self._y)

    def push(self, u: Array) -> Array:
        """Advance one tick toward the input ``u``; return the output (a view valid until the next push)."""
        (p00, p01), (p10, p11) = self._phi
        z = self._y - u
        self._y = u + p00 * z + p01 * self._v
        self._v = p10 * z + p11 * self._v
        return self._y


class ReactingOperator:
    """A person driving the tool to the scene's task goal in rate mode (see the module docstring).

    Args:
        params: Who.
        session: The session (its task goal, switch events, gains and rate).
        loop: The loop it acts on (its grip pose now is the start).

    Attributes:
        phase: ``"insert"``, ``"hold"``, ``"withdraw"`` or ``"done"``.
        finished: True once withdrawn (a session may stop there).
    """

    def __init__(self, params: OperatorParams, session: Session, loop: ServoLoop) -> None:
        task = session.scene.spec.task
        if task is None:
            raise ValueError(f"scene '{session.scene.name}' has no task for a reacting operator to do")
        if session.gains.mode != "rate":
            raise ValueError("a reacting operator drives the tool in rate mode")
        self.params = params
        self._switches = OperatorScript.for_loop(session.data, loop)
        self._dt = loop.dt
        self._T_start = loop.reading.T_0_G.copy()
        self._hand = self._T_start.copy()
        self._k_v = np.array(session.gains.k_v)
        self._db = np.array(session.gains.deadband)
        tool = loop.record.T_w_MRF[0:3, 3].copy()
        self._home = tool
        self._goal = task.goal.matrix()[0:3, 3]
        self._tolerance = task.position_tolerance
        self._aim = params.aim_offset()
        self._tilt = params.tilt_error * np.array([math.cos(params.tilt_axis), math.sin(params.tilt_axis), 0.0])
        self._R_home = loop.record.T_w_MRF[0:3, 0:3].copy()
        self._seen = _Delayed(params.visual_delay, loop.dt, tool)
        self._seen_R = _Delayed(params.visual_delay, loop.dt, self._R_home.ravel())
        self._felt = _Delayed(params.haptic_delay, loop.dt, np.zeros(3))
        self._tremor = _tremor(session.data.n_ticks, params.tremor, params.seed, 1.0 / loop.dt, 8.0)
        self._motor = MotorLowPass(params.motor_bandwidth, loop.dt, np.zeros(6))
        self._since = 0.0
        self._best_depth = tool[2]
        self._stall_t = 0.0
        self.phase = "insert"
        self.finished = False

    def before_tick(self, loop: ServoLoop) -> None:
        """Perceive (delayed), decide the intended tool velocity, set the hand target."""
        self._switches.update_switches(loop.time)
        rec = loop.record
        seen = self._seen.push(rec.T_w_MRF[0:3, 3])
        seen_R = self._seen_R.push(rec.T_w_MRF[0:3, 0:3].ravel()).reshape(3, 3)
        felt = self._felt.push(rec.reading.T_0_G[0:3, 0:3] @ rec.out.G_F_T[0:3])
        f = float(np.linalg.norm(felt))
        v = self._intent(seen, f, loop.time)
        if f > self.params.force_threshold:
            v = v + felt / f * self.params.speed * min(f / self.params.force_threshold - 1.0, YIELD_MAX)
        w = self._turn(seen_R)
        d = v / self._k_v[0:3] + self._db[0:3] * np.tanh(v / V_DB)
        a = w / self._k_v[3:6] + self._db[3:6] * np.tanh(w / W_DB)
        d, a = np.split(self._motor.push(np.concatenate((d, a))), 2)
        hand = self._hand
        hand[0:3, 3] = self._T_start[0:3, 3] + d + self._tremor[min(loop.ticks, len(self._tremor) - 1)]
        hand[0:3, 0:3] = self._T_start[0:3, 0:3] @ zyx_to_matrix(a[0], a[1], a[2])
        loop.set_hand_target(hand)

    def _turn(self, seen_R: Array) -> Array:
        """The tool angular velocity (rad/s, {MRF} axes) the operator wants while inserting, from the
        seen tool orientation ``seen_R`` (3, 3): toward upright as they misjudge it; none after."""
        if self.phase != "insert":
            return np.zeros(3)
        e = rotation_log(seen_R.T @ rotation_exp(self._tilt) @ self._R_home)
        return e * (self.params.speed / SLOW_DISTANCE)

    def _intent(self, seen: Array, felt: float, t: float) -> Array:
        """The tool velocity (m/s, {w}) the operator wants, from the seen tool position ``seen`` (m)
        and the felt force magnitude ``felt`` (N)."""
        if self.phase == "insert":
            e = self._goal + self._aim - seen
            e[2] -= OVERSHOOT
            deep = seen[2] <= self._goal[2] + self._tolerance
            if seen[2] < self._best_depth - STALL_DEPTH:
                self._best_depth, self._stall_t = float(seen[2]), t
            elif deep and (t - self._stall_t > BOTTOM_S or felt > self.params.force_threshold):
                self.phase, self._since = "hold", t
            elif not deep and t - self._stall_t > STALL_S:
                # Stuck above the holes: look again, misjudge by half as much, lift a little, push again.
                self._aim = self._aim * 0.5
                self._tilt = self._tilt * 0.5
                self._stall_t, self._best_depth = t, float(seen[2]) + STALL_DEPTH
                return np.array([0.0, 0.0, self.params.speed])
            return self._toward(e)
        if self.phase == "hold":
            if t - self._since >= HOLD_S:
                self.phase = "withdraw"
            return np.zeros(3)
        if self.phase == "withdraw":
            e = self._home - seen
            if seen[2] >= self._goal[2] + CLEAR:
                self.phase = "done"
                self.finished = True
            return self._toward(np.array([0.0, 0.0, e[2]]))
        return np.zeros(3)

    def _toward(self, e: Array) -> Array:
        """Velocity (m/s) toward error ``e`` (m): proportional near, capped at the operator's speed."""
        n = float(np.linalg.norm(e))
        gain = self.params.speed / SLOW_DISTANCE
        return e * gain if n * gain <= self.params.speed else e * (self.params.speed / n)
