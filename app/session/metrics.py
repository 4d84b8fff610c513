"""Session metrics: the work of Eq 13, contact force statistics, task completion, faults, timing."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit

from app.compiled import entry_point
from app.controller.types import Fault
from app.session.tick import STAGES, TickRecord
from app.slave.arm import ArmStatus
from app.spatial import Array, rotation_log
from app.world.scene import TaskSpec
from app.world.scene_file import within_goal

#: Seconds at the end of a session over which the contact force's settling is judged (s).
SETTLE_WINDOW = 0.6
#: Settled: the contact force's peak-to-peak over the window below this fraction of its mean (-).
SETTLE_RIPPLE = 0.05
#: ... and its mean at least this (N): a press that never reaches the surface is not a settled
#: contact (a ripple of 0 below 5 % of a mean of 0 would otherwise pass).
SETTLE_MIN_FORCE = 0.1


def work_increment(T_prev: Array, T: Array, F_prev: Array, F: Array) -> Array:
    """One trapezoid step of Eq 13 per axis: ``(F_prev + F)/2 * d xi`` (J), shape (6,).

    ``d xi`` is the {MRF} displacement from ``T_prev`` to ``T`` (4, 4 poses in {w}) in the axes of
    ``T_prev``: translation, and the rotation increment as a rotation vector. ``F_prev`` and ``F``
    are the contact wrenches at {MRF} in {MRF} (N, N m), (6,).
    """
    work = np.zeros(6)
    _add_work(T_prev, T, F_prev, F, work)
    return work


@njit(cache=True)
def _add_work(T_prev: Array, T: Array, F_prev: Array, F: Array, work: Array) -> None:
    """Add :func:`work_increment` to ``work`` (6,)."""
    R_prev = T_prev[0:3, 0:3]
    dxi = np.empty(6)
    for a in range(3):
        dxi[a] = (
            R_prev[0, a] * (T[0, 3] - T_prev[0, 3])
            + R_prev[1, a] * (T[1, 3] - T_prev[1, 3])
            + R_prev[2, a] * (T[2, 3] - T_prev[2, 3])
        )
    R_rel = np.empty((3, 3))  # R_prev^T R
    for a in range(3):
        for b in range(3):
            R_rel[a, b] = R_prev[0, a] * T[0, b] + R_prev[1, a] * T[1, b] + R_prev[2, a] * T[2, b]
    dxi[3:6] = rotation_log(R_rel)
    for a in range(6):
        work[a] += 0.5 * (F[a] + F_prev[a]) * dxi[a]


@njit(cache=True)
def _accumulate(
    acc: Array, tail: Array, T_prev: Array, F_prev: Array, T: Array, F: Array, tick: int, po_energy: float, pc: float
) -> None:
    """One tick of :class:`SessionMetrics`' sums, in ``acc`` (slots ``_WORK`` ... ``_PC_TICKS``);
    the contact force magnitude into the ring ``tail``; ``T_prev``, ``F_prev`` become ``T``, ``F``."""
    _add_work(T_prev, T, F_prev, F, acc[_WORK : _WORK + 6])
    T_prev[:] = T
    F_prev[:] = F
    f = math.sqrt(F[0] * F[0] + F[1] * F[1] + F[2] * F[2])
    m = math.sqrt(F[3] * F[3] + F[4] * F[4] + F[5] * F[5])
    acc[_PEAK_F] = max(acc[_PEAK_F], f)
    acc[_PEAK_M] = max(acc[_PEAK_M], m)
    acc[_SUM_F2] += f * f
    acc[_SUM_M2] += m * m
    tail[tick % tail.shape[0]] = f
    acc[_MIN_ENERGY] = min(acc[_MIN_ENERGY], po_energy)
    acc[_MAX_PC] = max(acc[_MAX_PC], pc)
    if pc > 0.0:
        acc[_PC_TICKS] += 1.0


# Slots of SessionMetrics' accumulator (see _accumulate).
_WORK, _PEAK_F, _PEAK_M, _SUM_F2, _SUM_M2, _MIN_ENERGY, _MAX_PC, _PC_TICKS = 0, 6, 7, 8, 9, 10, 11, 12


def _count_bits(flags: type[Fault] | type[ArmStatus], value: int, counts: dict[str, int]) -> None:
    """Add one tick to ``counts[name]`` for every flag of ``flags`` set in ``value``."""
    for flag in flags:
        if flag and value & flag:
            name = str(flag.name)
            counts[name] = counts.get(name, 0) + 1


class SessionMetrics:
    """Accumulates a session's summary tick by tick (a tick observer; no need to keep the log).

    Args:
        start: The loop's record at the start (its reset state): where the work integral starts.
        task: The scene's task, if it has one (its completion is reported).
        n_ticks: Ticks expected (sizes the timing table). dt: Servo period (s).

    The work metric is the paper's Eq 13, ``W = sum_i |integral F_MRF,i d xi_i|``: the contact
    wrench at {MRF} in {MRF} axes times the {MRF} displacement in its own axes (translation,
    and the rotation increment as a rotation vector), integrated with the trapezoid rule per
    axis; absolute values are taken per axis at the end.

    Settling (the oscillation criterion of ``frhc zwidth``): over the last :data:`SETTLE_WINDOW`
    seconds the contact force magnitude at {MRF} is settled when its peak-to-peak (ripple) is
    below :data:`SETTLE_RIPPLE` of its mean (and finite), the mean being at least
    :data:`SETTLE_MIN_FORCE` (the tool is in contact). (The felt stiffness needs two pushes:
    :class:`app.session.stability.FeltStiffness`.)
    """

    def __init__(self, start: TickRecord, task: TaskSpec | None, n_ticks: int, dt: float) -> None:
        self._dt = dt
        self._time = start.time
        self._acc = np.zeros(_PC_TICKS + 1)
        self._T_prev = start.T_w_MRF.copy()
        self._F_prev = start.contact_wrench_MRF.copy()
        self._contact_ticks = 0
        self._ticks = 0
        self._fault_ticks: dict[str, int] = {}
        self._saturated_ticks = 0
        self._ramping_ticks = 0
        self._watchdog_trips = 0
        self._slave_ticks: dict[str, int] = {}
        self._peak_link_force = 0.0
        self._stage_ns = np.zeros((n_ticks, len(STAGES)), dtype=np.int64)
        # The contact force of the last SETTLE_WINDOW of ticks (a ring).
        self._tail = np.full(max(1, round(SETTLE_WINDOW / dt)), np.nan)
        self.task_done_at: float | None = None
        self._task = task
        self._accumulate: Callable[..., None] | None = None
        if task is not None:
            # The task's test (TaskSpec.done) without its per-call typing: goal and tolerances kept.
            self._goal = (task.goal.matrix(), task.position_tolerance, math.radians(task.angle_tolerance_deg))
            self._within = entry_point(within_goal, self._T_prev, *self._goal)

    def on_tick(self, tick: TickRecord) -> None:
        out = tick.out
        T = tick.T_w_MRF
        self._time = tick.time
        args = (
            self._acc, self._tail, self._T_prev, self._F_prev, T, tick.contact_wrench_MRF, self._ticks,
            out.po_energy, out.pc_cut,
        )  # fmt: skip
        if self._accumulate is None:
            # The same kinds of arguments every tick: the compiled specialisation, once.
            self._accumulate = entry_point(_accumulate, *args)
        self._accumulate(*args)
        self._contact_ticks += tick.contact.count > 0
        if out.faults:
            _count_bits(Fault, int(out.faults), self._fault_ticks)
        self._saturated_ticks += out.saturation_scale < 1.0
        self._ramping_ticks += out.reflecting and out.ramp < 1.0
        self._watchdog_trips = tick.reading.watchdog_trips
        if tick.slave_status:
            _count_bits(ArmStatus, tick.slave_status, self._slave_ticks)
            # A link force comes with the LINK_CONTACT bit: the ticks without bits have none.
            self._peak_link_force = max(self._peak_link_force, tick.link_force)
        if self._ticks < len(self._stage_ns):
            self._stage_ns[self._ticks] = tick.stage_ns
        self._ticks += 1
        task = self._task
        if task is not None and self.task_done_at is None and self._within(T, *self._goal):
            self.task_done_at = tick.time

    @property
    def work_per_axis(self) -> Array:
        """``|integral F_MRF,i d xi_i|`` per axis (J for forces, J = N m rad for moments), (6,)."""
        return np.abs(self._acc[_WORK : _WORK + 6])

    def settling(self) -> dict[str, Any]:
        """Contact force over the last :data:`SETTLE_WINDOW` s, and the passivity trace."""
        tail = self._tail[: min(self._ticks, len(self._tail))]
        mean = float(np.mean(tail)) if len(tail) else math.nan
        ripple = float(np.ptp(tail)) if len(tail) else math.nan
        return {
            "window_s": SETTLE_WINDOW,
            "mean_force_N": mean,
            "ripple_N": ripple,
            "settled": bool(math.isfinite(ripple) and mean >= SETTLE_MIN_FORCE and ripple < SETTLE_RIPPLE * mean),
            "min_energy_J": float(self._acc[_MIN_ENERGY]),
            "max_pc_cut": float(self._acc[_MAX_PC]),
            "pc_active_ticks": int(self._acc[_PC_TICKS]),
        }

    def summary(self) -> dict[str, Any]:
        """The session summary as plain JSON-able values."""
        n = max(self._ticks, 1)
        stages = self._stage_ns[: self._ticks] / 1000.0
        timing = (
            {
                name: {"median_us": float(np.median(stages[:, i])), "p99_us": float(np.percentile(stages[:, i], 99))}
                for i, name in enumerate(STAGES)
            }
            if self._ticks
            else {}
        )
        tick_median_s = timing["tick"]["median_us"] * 1e-6 if timing else float("nan")
        return {
            "work_eq13": float(self.work_per_axis.sum()),
            "work_per_axis": self.work_per_axis.tolist(),
            "peak_contact_force_N": float(self._acc[_PEAK_F]),
            "peak_contact_moment_Nm": float(self._acc[_PEAK_M]),
            "rms_contact_force_N": math.sqrt(self._acc[_SUM_F2] / n),
            "rms_contact_moment_Nm": math.sqrt(self._acc[_SUM_M2] / n),
            "contact_fraction": self._contact_ticks / n,
            "task": None
            if self._task is None
            else {
                "description": self._task.description,
                "completed": self.task_done_at is not None,
                "time_s": self.task_done_at,
            },
            "faults": self._fault_ticks,
            "saturated_ticks": self._saturated_ticks,
            "ramping_ticks": self._ramping_ticks,
            "watchdog_trips": self._watchdog_trips,
            "settling": self.settling(),
            "slave_status_ticks": self._slave_ticks,
            "peak_link_force_N": self._peak_link_force,
            "ticks": self._ticks,
            "simulated_s": self._time,
            "timing": timing,
            "real_time_factor": (self._dt / tick_median_s) if timing else None,
        }
