"""Session metrics: the work of Eq 13, contact force statistics, task completion, faults, timing."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from app.controller.types import Fault
from app.session.tick import STAGES, TickRecord
from app.spatial import Array, rotation_log
from app.world.arm import ArmStatus
from app.world.scene import TaskSpec

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
    R_prev = T_prev[0:3, 0:3]
    dxi = np.concatenate((R_prev.T @ (T[0:3, 3] - T_prev[0:3, 3]), rotation_log(R_prev.T @ T[0:3, 0:3])))
    return 0.5 * (F + F_prev) * dxi


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
        self._work = np.zeros(6)
        self._T_prev = start.T_w_MRF.copy()
        self._F_prev = start.contact_wrench_MRF.copy()
        self._peak_force = 0.0
        self._peak_moment = 0.0
        self._sum_f2 = 0.0
        self._sum_m2 = 0.0
        self._contact_ticks = 0
        self._ticks = 0
        self._fault_ticks: dict[str, int] = {}
        self._saturated_ticks = 0
        self._ramping_ticks = 0
        self._watchdog_trips = 0
        self._slave_ticks: dict[str, int] = {}
        self._stage_ns = np.zeros((n_ticks, len(STAGES)), dtype=np.int64)
        # The contact force of the last SETTLE_WINDOW of ticks (a ring).
        self._tail = np.full(max(1, round(SETTLE_WINDOW / dt)), np.nan)
        self._min_energy = 0.0
        self._max_pc = 0.0
        self._pc_ticks = 0
        self.task_done_at: float | None = None
        self._task = task

    def on_tick(self, tick: TickRecord) -> None:
        out = tick.out
        T = tick.T_w_MRF
        F = tick.contact_wrench_MRF
        self._time = tick.time
        self._work += work_increment(self._T_prev, T, self._F_prev, F)
        self._T_prev[:] = T
        self._F_prev[:] = F
        f = math.sqrt(float(F[0:3] @ F[0:3]))
        m = math.sqrt(float(F[3:6] @ F[3:6]))
        self._peak_force = max(self._peak_force, f)
        self._peak_moment = max(self._peak_moment, m)
        self._sum_f2 += f * f
        self._sum_m2 += m * m
        self._contact_ticks += tick.contact.count > 0
        if out.faults:
            _count_bits(Fault, int(out.faults), self._fault_ticks)
        self._saturated_ticks += out.saturation_scale < 1.0
        self._ramping_ticks += out.reflecting and out.ramp < 1.0
        self._watchdog_trips = tick.reading.watchdog_trips
        if tick.slave_status:
            _count_bits(ArmStatus, tick.slave_status, self._slave_ticks)
        if self._ticks < len(self._stage_ns):
            self._stage_ns[self._ticks] = tick.stage_ns
        self._tail[self._ticks % len(self._tail)] = f
        self._min_energy = min(self._min_energy, out.po_energy)
        pc = out.pc_cut
        self._max_pc = max(self._max_pc, pc)
        self._pc_ticks += pc > 0.0

        self._ticks += 1
        if self._task is not None and self.task_done_at is None and self._task.done(T):
            self.task_done_at = tick.time

    @property
    def work_per_axis(self) -> Array:
        """``|integral F_MRF,i d xi_i|`` per axis (J for forces, J = N m rad for moments), (6,)."""
        return np.abs(self._work)

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
            "min_energy_J": self._min_energy,
            "max_pc_cut": self._max_pc,
            "pc_active_ticks": self._pc_ticks,
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
            "peak_contact_force_N": self._peak_force,
            "peak_contact_moment_Nm": self._peak_moment,
            "rms_contact_force_N": math.sqrt(self._sum_f2 / n),
            "rms_contact_moment_Nm": math.sqrt(self._sum_m2 / n),
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
            "ticks": self._ticks,
            "simulated_s": self._time,
            "timing": timing,
            "real_time_factor": (self._dt / tick_median_s) if timing else None,
        }
