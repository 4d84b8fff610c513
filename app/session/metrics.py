"""Session metrics: the work of Eq 13, contact force statistics, task completion, faults, timing."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit
from numba.experimental import structref

from app.compiled import F8, I8, Arrays, ArraysType, array_type, entry_point
from app.controller.layout import SCALARS
from app.controller.types import Fault
from app.device.boundary import LinkStatus
from app.session.state import fill_row
from app.session.tick import STAGES, TickRecord
from app.slave.arm import ArmStatus
from app.spatial import Array, IntArray, rotation_log_into
from app.world.scene import TaskSpec
from app.world.scene_file import within_goal

if TYPE_CHECKING:
    from app.session.log import TickLog

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
    _add_work(T_prev, T, F_prev, F, 0, work, np.empty((3, 3)), np.empty(3))
    return work


@njit(cache=True)
def _add_work(T_prev: Array, T: Array, F_prev: Array, F: Array, f: int, work: Array, R_rel: Array, rot: Array) -> None:
    """Add :func:`work_increment` to ``work`` (6,), the wrench ``F`` being ``F[f : f + 6]``, in
    the scratch ``R_rel`` (3, 3) and ``rot`` (3,): no allocation and no view per tick (a view's
    reference counting costs more than this arithmetic)."""
    for a in range(3):  # the translation in the axes of T_prev
        d = (
            T_prev[0, a] * (T[0, 3] - T_prev[0, 3])
            + T_prev[1, a] * (T[1, 3] - T_prev[1, 3])
            + T_prev[2, a] * (T[2, 3] - T_prev[2, 3])
        )
        work[a] += 0.5 * (F[f + a] + F_prev[a]) * d
    for a in range(3):  # R_prev^T R
        for b in range(3):
            R_rel[a, b] = T_prev[0, a] * T[0, b] + T_prev[1, a] * T[1, b] + T_prev[2, a] * T[2, b]
    rotation_log_into(R_rel, rot)
    for a in range(3):
        work[3 + a] += 0.5 * (F[f + 3 + a] + F_prev[3 + a]) * rot[a]


# Slots of SessionMetrics' accumulator (see _reduce): the work per axis, then the sums and peaks,
# then the task's position (m) and angle (rad) tolerances (NaN without a task).
_WORK, _PEAK_F, _PEAK_M, _SUM_F2, _SUM_M2, _MIN_ENERGY, _MAX_PC, _PC_TICKS = 0, 6, 7, 8, 9, 10, 11, 12
_CONTACT_TICKS, _SATURATED, _RAMPING, _WATCHDOG, _PEAK_LINK, _DONE_AT, _TIME = 13, 14, 15, 16, 17, 18, 19
_TOL_P, _TOL_A, _N_ACC = 20, 21, 22
# Where _reduce finds its values in the state row (SessionMetrics fills these from the block).
_AT_T, _AT_TOOL, _AT_R, _AT_F, _AT_SCALARS, _AT_SWITCHES, _AT_LINK, _AT_REFLECTING, _N_AT = range(9)
# Then, in the same int array, the ticks per bit of the controller's faults and the slave's status,
# and the ticks per state of a Cartesian device's link (LinkStatus).
_N_BITS = 63
_FAULT_BITS, _STATUS_BITS, _LINK_TICKS = _N_AT, _N_AT + _N_BITS, _N_AT + 2 * _N_BITS
_N_INTS = _LINK_TICKS + len(LinkStatus)
_SATURATION_SCALE, _RAMP, _PO_ENERGY, _PC_CUT = (
    SCALARS.index(name) for name in ("saturation_scale", "ramp", "po_energy", "pc_cut")
)


@njit(cache=True)
def _count_bits_into(value: int, counts: IntArray, at: int) -> None:
    """Add one to ``counts[at + b]`` for every bit b (< :data:`_N_BITS`) set in ``value``."""
    b = 0
    while value and b < _N_BITS:
        if value & 1:
            counts[at + b] += 1
        value >>= 1
        b += 1


# The metrics' arrays (see _reduce) and the log's row buffer (rows, columns).
_F1, _F2, _I1, _I2 = array_type(1, F8), array_type(2, F8), array_type(1, I8), array_type(2, I8)
_SINK_FIELDS = {"acc": _F1, "tail": _F1, "ints": _I1, "stage_table": _I2, "log": _F2, "T_prev": _F2, "T_now": _F2}
_METRIC_SINKS = ArraysType([*_SINK_FIELDS.items(), ("goal", _F2), ("F_prev", _F1), ("R_rel", _F2), ("rot", _F1)])


@njit(cache=True)
def _sinks(
    acc: Array,
    tail: Array,
    ints: IntArray,
    stage_table: IntArray,
    log: Array,
    T_prev: Array,
    T_now: Array,
    goal: Array,
    F_prev: Array,
    R_rel: Array,
    rot: Array,
) -> Arrays:
    """The metrics' arrays (see :func:`_reduce`) and the log's row buffer (rows, columns) as one
    :class:`Arrays`; no copy."""
    sinks: Any = structref.new(_METRIC_SINKS)  # type: ignore[call-arg]  # an intrinsic, typed by numba
    sinks.acc = acc
    sinks.tail = tail
    sinks.ints = ints
    sinks.stage_table = stage_table
    sinks.log = log
    sinks.T_prev = T_prev
    sinks.T_now = T_now
    sinks.goal = goal
    sinks.F_prev = F_prev
    sinks.R_rel = R_rel
    sinks.rot = rot
    return sinks


@njit(cache=True)
def _reduce(sinks: Arrays, row: Array, tick: int, stage_ns: IntArray) -> None:
    """One tick of :class:`SessionMetrics` from the tick's state row ``row``: the sums in the
    bundle's ``acc`` (slots ``_WORK`` ... ``_TIME``), the contact force magnitude into the ring
    ``tail``, the stage durations into ``stage_table[tick]``, the fault and slave-status bits
    counted in ``ints``.

    ``T_prev`` and ``F_prev`` hold the last pose and contact wrench (they become this tick's),
    ``T_now`` this tick's pose, ``goal`` the task's goal pose (with the tolerances in ``acc``),
    ``R_rel`` and ``rot`` :func:`_add_work`'s scratch; ``ints`` holds where the row's blocks start
    (``_AT_*``) and the per-bit tick counts (``_FAULT_BITS``, ``_STATUS_BITS``). Indexed, never
    sliced: each view costs its reference counting.
    """
    b: Any = sinks
    acc, ints, T_prev, F_prev, T = b.acc, b.ints, b.T_prev, b.F_prev, b.T_now
    p, r, af = ints[_AT_TOOL], ints[_AT_R], ints[_AT_F]
    for i in range(3):
        T[i, 3] = row[p + i]
        for j in range(3):
            T[i, j] = row[r + 3 * i + j]
    _add_work(T_prev, T, F_prev, row, af, acc, b.R_rel, b.rot)
    for i in range(4):
        for j in range(4):
            T_prev[i, j] = T[i, j]
    for i in range(6):
        F_prev[i] = row[af + i]
    f = math.sqrt(row[af] * row[af] + row[af + 1] * row[af + 1] + row[af + 2] * row[af + 2])
    m = math.sqrt(row[af + 3] * row[af + 3] + row[af + 4] * row[af + 4] + row[af + 5] * row[af + 5])
    acc[_PEAK_F] = max(acc[_PEAK_F], f)
    acc[_PEAK_M] = max(acc[_PEAK_M], m)
    acc[_SUM_F2] += f * f
    acc[_SUM_M2] += m * m
    tail = b.tail
    tail[tick % tail.shape[0]] = f
    scalars = ints[_AT_SCALARS]
    acc[_MIN_ENERGY] = min(acc[_MIN_ENERGY], row[scalars + _PO_ENERGY])
    pc = row[scalars + _PC_CUT]
    acc[_MAX_PC] = max(acc[_MAX_PC], pc)
    if pc > 0.0:
        acc[_PC_TICKS] += 1.0
    sw = ints[_AT_SWITCHES]
    if row[sw + 3] > 0.0:
        acc[_CONTACT_TICKS] += 1.0
    _count_bits_into(int(row[sw + 4]), ints, _FAULT_BITS)
    if row[scalars + _SATURATION_SCALE] < 1.0:
        acc[_SATURATED] += 1.0
    if row[ints[_AT_REFLECTING]] > 0.0 and row[scalars + _RAMP] < 1.0:
        acc[_RAMPING] += 1.0
    acc[_WATCHDOG] = row[sw + 5]
    ints[_LINK_TICKS + int(row[sw + 7])] += 1
    status = int(row[sw + 6])
    if status:
        _count_bits_into(status, ints, _STATUS_BITS)
        # A link force comes with the LINK_CONTACT bit: the ticks without bits have none.
        acc[_PEAK_LINK] = max(acc[_PEAK_LINK], row[ints[_AT_LINK]])
    stage_table = b.stage_table
    if tick < stage_table.shape[0]:
        for i in range(stage_ns.shape[0]):
            stage_table[tick, i] = stage_ns[i]
    acc[_TIME] = row[ints[_AT_T]]
    # Not done yet (NaN), with a task (finite tolerances), and within its goal now.
    if math.isnan(acc[_DONE_AT]) and not math.isnan(acc[_TOL_P]) and within_goal(T, b.goal, acc[_TOL_P], acc[_TOL_A]):
        acc[_DONE_AT] = acc[_TIME]


@njit(cache=True)
def _reduce_row(src: Arrays, sinks: Arrays, tick: int, log_row: int) -> None:
    """:func:`_reduce` of the row ``src`` holds (filled), after copying its logged values into
    row ``log_row`` of the log's buffer (none when negative)."""
    a: Any = src
    b: Any = sinks
    row, log = a.row, b.log
    if log_row >= 0:
        for c in range(log.shape[1]):
            log[log_row, c] = row[c]
    _reduce(sinks, row, tick, a.stage_ns)


@njit(cache=True)
def _fill_and_reduce(
    sinks: Arrays,
    tick: int,
    log_row: int,
    src: Arrays,
    contact_w: Array,
    t: float,
    hand_on: bool,
    deadman: bool,
    reference: bool,
    reflection: bool,
    contacts: int,
    faults: int,
    watchdog_trips: int,
    slave_status: int,
    device_link: int,
    link_force: float,
    reflecting: bool,
    full: bool,
) -> None:
    """The state row filled (:func:`~app.session.state.fill_row`), then :func:`_reduce_row` into
    ``sinks`` as tick ``tick`` (``log_row``: see there): one compiled call a tick
    (:meth:`~app.session.state.StateBlock.kernel`)."""
    fill_row(
        sinks, tick, log_row, src, contact_w, t, hand_on, deadman, reference, reflection, contacts, faults,
        watchdog_trips, slave_status, device_link, link_force, reflecting, full,
    )  # fmt: skip
    _reduce_row(src, sinks, tick, log_row)


def _bit_counts(flags: type[Fault] | type[ArmStatus], counts: IntArray) -> dict[str, int]:
    """Ticks per flag of ``flags`` (single-bit flags) from per-bit tick counts, the flags seen only."""
    return {
        str(flag.name): int(counts[int(flag).bit_length() - 1])
        for flag in flags
        if flag and counts[int(flag).bit_length() - 1]
    }


class SessionMetrics:
    """Accumulates a session's summary tick by tick (a tick observer; no need to keep the log).

    Args:
        start: The loop's record at the start (its reset state): where the work integral starts.
        task: The scene's task, if it has one (its completion is reported).
        n_ticks: Ticks expected (sizes the timing table). dt: Servo period (s).
        log: A log whose rows these metrics write, in the same compiled call as their own sums
            (a session's log and metrics: the row's fill and this call, where a log observing by
            itself adds a copy and its Python); the log is then not observed itself (its
            :meth:`~app.session.log.TickLog.close` is still the caller's).

    The work metric is the paper's Eq 13, ``W = sum_i |integral F_MRF,i d xi_i|``: the contact
    wrench at {MRF} in {MRF} axes times the {MRF} displacement in its own axes (translation,
    and the rotation increment as a rotation vector), integrated with the trapezoid rule per
    axis; absolute values are taken per axis at the end. The paper integrates the F/T reading
    with the payload's weight removed and its inertial load left in (Sec 3.2); that load's term
    is the tool's kinetic-energy change (zero from rest to rest), while integrating the simulated
    reading would add the integrator's residue ``~ m sum (h a)^2`` instead, so the contact wrench
    is counted (docs/experiment.md, "What Eq 13 counts, against the paper").

    Settling (the oscillation criterion of ``frhc zwidth``): over the last :data:`SETTLE_WINDOW`
    seconds the contact force magnitude at {MRF} is settled when its peak-to-peak (ripple) is
    below :data:`SETTLE_RIPPLE` of its mean (and finite), the mean being at least
    :data:`SETTLE_MIN_FORCE` (the tool is in contact). (The felt stiffness needs two pushes:
    :class:`app.session.stability.FeltStiffness`.)
    """

    def __init__(
        self, start: TickRecord, task: TaskSpec | None, n_ticks: int, dt: float, log: TickLog | None = None
    ) -> None:
        self._dt = dt
        self._acc = acc = np.zeros(_N_ACC)
        acc[_DONE_AT] = math.nan
        acc[_TIME] = start.time
        acc[_TOL_P] = acc[_TOL_A] = math.nan
        goal = np.zeros((4, 4))
        if task is not None:
            goal[:] = task.goal.matrix()
            acc[_TOL_P], acc[_TOL_A] = task.position_tolerance, math.radians(task.angle_tolerance_deg)
        self._ticks = 0
        self._stage_ns = np.zeros((n_ticks, len(STAGES)), dtype=np.int64)
        # The contact force of the last SETTLE_WINDOW of ticks (a ring).
        self._tail = np.full(max(1, round(SETTLE_WINDOW / dt)), np.nan)
        self._task = task
        assert start.block is not None, "the loop sets the record's state block"
        # The loop's block, set once with its record: bound here rather than looked up a tick.
        self._block = start.block
        starts = start.block.starts
        self._ints = ints = np.zeros(_N_INTS, dtype=np.int64)
        ints[_AT_T], ints[_AT_TOOL], ints[_AT_R] = starts["t"], starts["tool"], starts["R_w_MRF"]
        ints[_AT_F], ints[_AT_SCALARS], ints[_AT_SWITCHES] = (
            starts["contact_MRF"],
            starts["scalars"],
            starts["switches"],
        )
        ints[_AT_LINK], ints[_AT_REFLECTING] = starts["link_force"], starts["reflecting"]
        self._log = log
        log_rows = np.zeros((0, 0)) if log is None else log.buffer
        poses = (start.T_w_MRF.copy(), np.zeros((4, 4)), goal, start.contact_wrench_MRF.copy())
        self._sinks = _sinks(acc, self._tail, ints, self._stage_ns, log_rows, *poses, np.zeros((3, 3)), np.zeros(3))
        # Called every tick with the same kinds of arguments: the compiled specialisations, once.
        self._fill_and_reduce = start.block.kernel(_fill_and_reduce, self._sinks)
        self._reduce: Callable[..., None] | None = None

    def on_tick(self, tick: TickRecord) -> None:
        """Reduce the tick's state row (:func:`_reduce_row`) in the compiled call that fills it
        (:meth:`~app.session.state.StateBlock.fill_with`): with a log, the whole row, its logged
        part written to the log's buffer in the same call; without, only the values the reduction
        reads (the whole row costs ~2 us more). A row an observer before filled is only reduced."""
        block = self._block
        log = self._log
        log_row = -1 if log is None else log.rows
        if tick.serial != block.serial:
            block.fill_with(tick, log_row >= 0, self._fill_and_reduce, self._sinks, self._ticks, log_row)
        else:
            if self._reduce is None:
                self._reduce = entry_point(_reduce_row, block.sources, self._sinks, 0, 0)
            self._reduce(block.sources, self._sinks, self._ticks, log_row)
        self._ticks += 1
        if log is not None:
            log.row_written()

    @property
    def task_done_at(self) -> float | None:
        """Simulated time (s) at which the tool was first within the task's goal, or None."""
        done = float(self._acc[_DONE_AT])
        return None if math.isnan(done) else done

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
            "contact_fraction": int(self._acc[_CONTACT_TICKS]) / n,
            "task": None
            if self._task is None
            else {
                "description": self._task.description,
                "completed": self.task_done_at is not None,
                "time_s": self.task_done_at,
            },
            "faults": _bit_counts(Fault, self._ints[_FAULT_BITS : _FAULT_BITS + _N_BITS]),
            "saturated_ticks": int(self._acc[_SATURATED]),
            "ramping_ticks": int(self._acc[_RAMPING]),
            "watchdog_trips": int(self._acc[_WATCHDOG]),
            # A Cartesian device's link: ticks per state other than OK (stalled: no sample that
            # period, zero force sent), the states seen only.
            "device_link_ticks": {
                s.name: int(self._ints[_LINK_TICKS + s]) for s in LinkStatus if s and self._ints[_LINK_TICKS + s]
            },
            "settling": self.settling(),
            "slave_status_ticks": _bit_counts(ArmStatus, self._ints[_STATUS_BITS : _STATUS_BITS + _N_BITS]),
            "peak_link_force_N": float(self._acc[_PEAK_LINK]),
            "ticks": self._ticks,
            "simulated_s": float(self._acc[_TIME]),
            "timing": timing,
            "real_time_factor": (self._dt / tick_median_s) if timing else None,
        }
