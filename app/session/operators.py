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
2. Force threshold: a felt force above ``force_threshold`` (N) is given way to: the operator takes
   back the part of their intended velocity that pushes against it, in proportion to the excess
   force, all of it from twice the threshold; they never drive the tool along the force
   (:func:`~app.session.operator_kernel.give_way`).
3. Searching: when the seen tool has not gone deeper by :data:`STALL_DEPTH` in :data:`STALL_S` while
   inserting, the operator looks again and halves their aim and tilt errors (lifts, re-aims,
   pushes again).
4. The hand target is the start grip pose displaced by the rate-mode inverse the operator has
   learned, ``d = v / K_V + DB tanh(v / V_DB)`` per axis (the deadband is crossed smoothly; for
   the rotation ``W_DB`` in place of ``V_DB``, and ``d`` as the grip's Z-Y-X angles from its start,
   which Eq 5 maps to ``w`` for small angles), set further out by the return-to-centre force
   the trained operator has learned to expect at ``d`` over their hand's stiffness, while it acts
   (:func:`~app.session.operator_kernel.learned_rtc_offset`: Shadmehr & Mussa-Ivaldi 1994),
   passed through the hand's motor bandwidth
   (:class:`MotorLowPass`: a person's voluntary output cannot step, so a change of intent, e.g.
   insert to hold, or a yield, moves the hand within a few tens of milliseconds, not in one tick),
   plus a seeded physiological tremor.

Parameter ranges of the population (:data:`POPULATION`) and their sources:

- Hand stiffness 63-533 N/m and damping 3.7-27.6 N s/m (were 150-800 N/m and 5-25 N s/m after
  Mussa-Ivaldi, Hogan & Bizzi (1985) and Tsuji et al. (1995), never verified): the arm element
  (k2, b2) of the lumped arm-and-hand model that Fu & Cavusoglu (2012), "Human-arm-and-hand-
  dynamic model with variability analyses for a stylus-based haptic interface", IEEE Trans. SMC-B
  42(6):1633-1644, identified on 15 subjects holding a Phantom Premium 1.5a at 1-3 N grip force in
  three axes (nominal k2 170 N/m, b2 11 N s/m). Secondary: the paper's first page was reached
  (stored page, dokumen.tips), the figures only through a public repository's literature ledger
  that quotes them. The model's grasp element (k1 228-1043 N/m in series, a stylus pinch) is
  left out: the Kraft's grip is held in the fist. One measured trial lies inside the range: van
  Beek, Bergmann Tiest, Mugge & Kappers (2015), Sci. Rep. 5:18004, Fig. 3 caption, K = 135 N/m,
  B = 6.45 N s/m, M = 0.554 kg.
- Visual reaction delay 0.15-0.25 s: simple visual reaction times (Welford (1980), *Reaction
  Times*, Academic Press; Card, Moran & Newell (1983), *The Psychology of Human-Computer
  Interaction*, the perceive-decide-act cycle of ~240 ms with a range of ~100-470 ms). Confirmed
  (secondary): Kosinski, "A literature review on reaction time" (Clemson University), simple
  reaction time to light ~190 ms for college-age people, after Welford (1980).
- Haptic reaction delay 0.06-0.15 s: long-latency responses of the hand to a load change,
  Johansson & Westling (1987), Exp. Brain Res. 66:141-154 (grip responses ~60-100 ms), and
  voluntary reactions to kinesthetic stimuli (~120-150 ms). The lower bound is confirmed by Cole &
  Abbs (1988), J. Neurophysiol. 60(4):1513-1522, abstract: grip force increases "from 60 to 90 ms
  after onset of the load force increase". The upper bound is derived (secondary): Chernikoff &
  Taylor (1952), "Reaction time to kinesthetic stimulation resulting from sudden arm
  displacement", abstract: the kinesthetic reaction time lies "within the range" of kinesthetic,
  auditory and tactual key-release reactions; auditory "muscular" simple reactions take 123-137 ms
  (Lange, tabulated by Titchener (1895), "Simple reactions", Mind).
- Force threshold 1-5 N: contact forces of a few newtons held in force-reflecting peg-in-hole
  insertions, Hannaford, Wood, McAffee & Zak (1991), IEEE Trans. SMC 21(3):620-633 (not
  verified from stored material). Not to be confused with the force discrimination threshold,
  a just-noticeable difference of about 7 % over 2.5-10 N (Pang, Tan & Durlach (1991), abstract):
  this threshold is the force a person tolerates before giving way, a behaviour.
- Tremor 5.4-126 um (standard deviation, low-passed at 8 Hz): postural hand tremor of 97 normal
  subjects, "A normative study of postural tremor of the hand", Arch. Neurol. 39(6):358-362
  (1982), abstract: 0.0015-0.035 g peak at the dominant frequency, about 7 Hz. As displacement,
  ``a / (2 pi 7 Hz)^2`` = 7.6-178 um amplitude, over sqrt(2) for the standard deviation (a
  derivation from the abstract's figures). Was 0.1-0.5 mm after Elble & Koller (1990), *Tremor*,
  not verified.
- Lateral misalignment up to 2.5 mm and angular misalignment up to 1 degree: the part-location
  errors a remote centre compliance is built to absorb in robotic peg-in-hole assembly (+-2.5 mm
  lateral, +-1 degree; "Remote center compliance", https://probsee.com/p/remote_center_compliance,
  after Whitney (1982), J. Dyn. Syst. Meas. Control 104:65-77, whose analysis takes the initial
  lateral and angular errors as the two inputs of an insertion). Here they are the operator's
  misjudgement of where the holes are and of upright, drawn uniformly up to those bounds.
- Motor bandwidth 5.63-9.20 Hz (:data:`MOTOR_BANDWIDTH`): the hand's acceleration-impulse
  bandwidth in goal-directed target acquisition, Draper (1994), "Hand acceleration impulse
  bandwidth during target acquisition: implications for teleoperator bandwidth requirements",
  IEEE Trans. SMC 24(6):931-936, abstract: master controllers must pass "higher than 9.20 Hz" to
  capture hand trajectories, "shoulder" joints "only ... 5.63 Hz". Was 5-10 Hz after Shimoga
  (1993), "A survey of perceptual feedback issues in dexterous telemanipulation: Part I", Proc.
  IEEE VRAIS, pp. 263-270, whose figures could not be verified from stored material (only an
  abstract saying the hand's input/output bandwidths are asymmetric). Drawn from its own random
  stream (:func:`sample_population`), so it leaves every other value of every operator as it was.
- Approach speed 20-50 mm/s: *not* from the literature (no stored source gives a teleoperated
  insertion speed): the operator's behaviour without a source, spanning a careful to a brisk
  insertion. Nothing here is fitted to the paper's Table I. Every value's class (physical model,
  design choice, numerical) and status: ``docs/experiment.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated

import numpy as np

from app.compiled import entry_point, is_f8
from app.config import Checked, Range
from app.controller.layout import RTC_LAWS
from app.session import operator_kernel as kernel
from app.session.operator_kernel import (  # noqa: F401 (the strategy's constants, documented there)
    BOTTOM_S,
    CLEAR,
    HOLD_S,
    OVERSHOOT,
    SLOW_DISTANCE,
    STALL_DEPTH,
    STALL_S,
    V_DB,
    W_DB,
)
from app.session.script import OperatorScript, _tremor
from app.session.spec import Session
from app.spatial import Array

if TYPE_CHECKING:
    from app.session.loop import ServoLoop

#: Ranges (lo, hi) the population is drawn from, uniformly (sources in the module docstring).
POPULATION: dict[str, tuple[float, float]] = {
    "stiffness_trans": (63.0, 533.0),
    "damping_trans": (3.7, 27.6),
    "visual_delay": (0.15, 0.25),
    "haptic_delay": (0.06, 0.15),
    "force_threshold": (1.0, 5.0),
    "tremor": (5.4e-6, 1.26e-4),
    "speed": (0.02, 0.05),
    "aim_error": (0.0, 0.0025),
    "tilt_error": (0.0, math.radians(1.0)),
}
#: Range (lo, hi) of the operators' motor bandwidth (Hz), drawn uniformly from its own stream:
#: Draper (1994)'s hand acceleration bandwidths, 5.63 Hz ("shoulder") to 9.20 Hz (module docstring).
MOTOR_BANDWIDTH = (5.63, 9.20)


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
    """What a sense reports ``delay`` seconds late: a ring of the last samples, shape (n, 3)
    (advanced by :func:`~app.session.operator_kernel.push`, in the operator's compiled tick)."""

    def __init__(self, delay: float, dt: float, first: Array) -> None:
        self.ring = np.tile(first, (max(1, round(delay / dt)) + 1, 1))
        self.index = np.zeros(1, dtype=np.int64)

    def push(self, value: Array) -> Array:
        """Store this tick's sample; return the one from ``delay`` ago."""
        return kernel.push(self.ring, self.index, value)


class MotorLowPass:
    """A hand's voluntary motion: a critically damped second-order low-pass, both poles at
    ``2 pi bandwidth`` (rad/s), on a vector signal (here the hand target's six displacements from
    its start, m and rad).

    The step is exact for an input held over the tick (the state ``(y - u, y')`` advances by
    ``exp(A dt)``, ``A = [[0, 1], [-w^2, -2 w]]``), so a step of the input gives
    ``y(t) = u (1 - (1 + w t) e^(-w t))`` at the ticks, with no overshoot and a continuous
    velocity, at any rate. ``bandwidth = inf`` passes the input through. The operator's compiled
    tick advances the same arrays (:func:`~app.session.operator_kernel.low_pass`).

    Attributes:
        state: Output and its rate, shape (2, n).
        phi: The transition ``exp(A dt)``, row-major, shape (4,).
    """

    def __init__(self, bandwidth: float, dt: float, first: Array) -> None:
        w = 2.0 * math.pi * bandwidth
        if math.isinf(w):
            self.phi = np.zeros(4)
        else:
            e = math.exp(-w * dt)
            self.phi = e * np.array([1.0 + w * dt, dt, -w * w * dt, 1.0 - w * dt])
        first = np.asarray(first, dtype=float)
        self.state = np.zeros((2, first.shape[0]))
        self.state[0] = first

    def push(self, u: Array) -> Array:
        """Advance one tick toward the input ``u``; return the output (a view valid until the next push)."""
        kernel.low_pass(self.state, self.phi, np.asarray(u, dtype=float))
        return self.state[0]


class ReactingOperator:
    """A person driving the tool to the scene's task goal in rate mode (see the module docstring).

    The per-tick strategy runs compiled (:func:`app.session.operator_kernel.react`) on the
    operator's own arrays.

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
        self._T_start = loop.reading.T_0_G.copy()
        self._hand = self._T_start.copy()
        tool = loop.record.T_w_MRF[0:3, 3].copy()
        prm = np.zeros(kernel.N_PRM)
        gains, hand = session.gains, session.data.hand
        prm[kernel.K_V : kernel.K_V + 6] = gains.k_v
        prm[kernel.DB : kernel.DB + 6] = gains.deadband
        prm[kernel.RTC_A : kernel.RTC_A + 6] = gains.rtc_a
        prm[kernel.WALL_START : kernel.WALL_START + 6] = gains.wall_start
        prm[kernel.K_WALL : kernel.K_WALL + 6] = gains.k_wall
        prm[kernel.K_R : kernel.K_R + 6] = gains.k_r
        prm[kernel.HAND_K : kernel.HAND_K + 6] = (hand.stiffness_trans,) * 3 + (hand.stiffness_rot,) * 3
        prm[kernel.RTC_KIND] = RTC_LAWS.index(gains.rtc)
        prm[kernel.GOAL : kernel.GOAL + 3] = task.goal.matrix()[0:3, 3]
        prm[kernel.HOME : kernel.HOME + 3] = tool
        prm[kernel.TOLERANCE], prm[kernel.SPEED] = task.position_tolerance, params.speed
        prm[kernel.THRESHOLD] = params.force_threshold
        self._aim = params.aim_offset()
        self._tilt = params.tilt_error * np.array([math.cos(params.tilt_axis), math.sin(params.tilt_axis), 0.0])
        R_home = loop.record.T_w_MRF[0:3, 0:3].copy()
        seen = _Delayed(params.visual_delay, loop.dt, tool)
        seen_R = _Delayed(params.visual_delay, loop.dt, R_home.ravel())
        felt = _Delayed(params.haptic_delay, loop.dt, np.zeros(3))
        tremor = _tremor(session.data.n_ticks, params.tremor, params.seed, 1.0 / loop.dt, 8.0)
        motor = MotorLowPass(params.motor_bandwidth, loop.dt, np.zeros(6))
        self._phase = np.array([kernel.INSERT], dtype=np.int64)
        state = np.zeros(kernel.N_STATE)
        state[kernel.BEST_DEPTH] = tool[2]
        # Every argument but the record's arrays, the time and the tick: the operator's own arrays.
        self._own = (
            seen.ring, seen.index, seen_R.ring, seen_R.index, felt.ring, felt.index, self._phase, state,
            self._aim, self._tilt, prm, self._T_start, R_home, tremor, motor.state, motor.phi,
            np.zeros((kernel.N_WORK, 3, 3)),
        )  # fmt: skip
        # Where the record's arrays are copied when they are not C-contiguous float64 (a kernel
        # compiled for those would misread them).
        self._copies = (np.empty((4, 4)), np.empty((4, 4)), np.empty(6))
        # The record's arrays of the last tick when all three passed that check: the same objects
        # every tick (the rooms' buffers), so the check is an identity test after the first.
        self._checked: tuple[object, ...] = ()
        self._prm = prm
        self._rtc_on = 0.0
        self._react = entry_point(kernel.react, *self._own, *self._copies, 0.0, 0, self._hand)
        # The loop whose held hand before_tick moves in one compiled call with the strategy
        # (kernel.react_and_pull), that call and its last arguments; set on the first tick the
        # hand holds (ServoLoop.hand_pull).
        self._pulled: object = None
        self._react_and_pull: Callable[..., bool] | None = None
        self._pull_args: tuple[object, ...] = ()

    @property
    def phase(self) -> str:
        """``"insert"``, ``"hold"``, ``"withdraw"`` or ``"done"``."""
        return kernel.PHASES[int(self._phase[0])]

    @property
    def finished(self) -> bool:
        """True once withdrawn."""
        return bool(self._phase[0] == kernel.DONE)

    def before_tick(self, loop: ServoLoop) -> None:
        """Perceive (delayed), decide the intended tool velocity, set the hand target."""
        self._switches.apply_due_events(loop)
        sw = self._switches.switches
        rtc_on = 1.0 if sw.deadman and sw.reflection else 0.0
        if rtc_on != self._rtc_on:
            self._prm[kernel.RTC_ON] = self._rtc_on = rtc_on
        rec = loop.record
        T_w_MRF, T_0_G, G_F_T = rec.T_w_MRF, rec.reading.T_0_G, rec.out.G_F_T
        checked = self._checked
        if not checked or T_w_MRF is not checked[0] or T_0_G is not checked[1] or G_F_T is not checked[2]:
            T_w_MRF, T_0_G, G_F_T = self._check(T_w_MRF, T_0_G, G_F_T)
        t, tick = loop.time, loop.ticks  # a float and an int, as the kernels were compiled for
        if loop is self._pulled and rec.hand_on:
            assert self._react_and_pull is not None
            if not self._react_and_pull(T_w_MRF, T_0_G, G_F_T, t, tick, *self._pull_args):
                raise ValueError("T_0_H must be a finite 4x4 pose")
            return
        self._react(*self._own, T_w_MRF, T_0_G, G_F_T, t, tick, self._hand)
        loop.set_hand_target(self._hand)
        pull = loop.hand_pull()
        if pull is not None:
            loop_hand, (T_hand, mocap_pos, mocap_quat, *functions) = pull
            arrays = kernel.operator_arrays(*self._own, self._hand, loop_hand, T_hand, mocap_pos, mocap_quat)
            self._pulled, self._pull_args = loop, (arrays, *functions)
            self._react_and_pull = entry_point(kernel.react_and_pull, T_w_MRF, T_0_G, G_F_T, t, tick, *self._pull_args)

    def _check(self, T_w_MRF: Array, T_0_G: Array, G_F_T: Array) -> tuple[Array, Array, Array]:
        """The record's arrays as the kernels take them: each that is not a C-contiguous float64
        array of its shape copied into one that is; remembered when none had to be."""
        given = (T_w_MRF, T_0_G, G_F_T)
        taken = tuple(
            a if is_f8(a, copy.shape) else _filled(copy, a) for a, copy in zip(given, self._copies, strict=True)
        )
        self._checked = given if all(t is a for t, a in zip(taken, given, strict=True)) else ()
        return taken[0], taken[1], taken[2]


def _filled(copy: Array, a: Array) -> Array:
    """``copy`` holding ``a``'s values."""
    copy[:] = a
    return copy
