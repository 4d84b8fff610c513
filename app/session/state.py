"""The tick's state block: one preallocated row holding every per-tick value the observers read.

The log, the metrics (and any observer that wants the tick's values as numbers) read one row:
:meth:`~app.session.tick.TickRecord.state` fills it from the rooms' buffers with one compiled
call (:func:`fill_row`) the first time an observer asks for it in a tick, and hands the same
row to every later one. The log copies the row's first :attr:`StateBlock.n_logged` values (its
Parquet columns, in order); a session's metrics have it filled, then write the log's row and
reduce it in one compiled call of their own (:class:`~app.session.metrics.SessionMetrics`). The rooms'
buffers reach the compiled code as one :class:`~app.compiled.Arrays` bundle
(:meth:`StateBlock.fill_with`), and an observer's own compiled work on the row can run in the same
call (:meth:`StateBlock.kernel`).

The row is made of named blocks (:func:`state_layout`): the log's columns first, then values only
the observers use (the tool's rotation, the reflecting flag). To add a column, add a block to
:func:`state_layout` (before ``R_w_MRF`` if it is logged) and fill it in :func:`fill_row`, or,
for values outside the rooms' buffers, write :meth:`StateBlock.view` after the fill.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit, types
from numba.experimental import structref

from app.compiled import F8, I8, Arrays, ArraysType, array_type, entry_point
from app.controller.layout import SCALARS, TORQUE_ROWS, TWIST_AXES, VECTOR_ROWS, WRENCH_AXES
from app.device.boundary import HAND_OFF, HAND_ROTATED
from app.device.hand import rotate_wrench
from app.session.tick import STAGES
from app.spatial import Array, IntArray, quat_of

if TYPE_CHECKING:
    from app.session.tick import TickRecord

XYZ = ("x", "y", "z")
POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")
#: ``device_link`` is :class:`~app.device.boundary.LinkStatus` (0 OK, 1 ramping, 2 stalled: the
#: watchdog zeroed the force, 3 disconnected); 0 for a joint-space plant simulated in process.
INT_COLUMNS = (
    "deadman",
    "reference",
    "reflection",
    "contacts",
    "faults",
    "watchdog_trips",
    "slave_status",
    "device_link",
)
#: The first block the log does not write: the blocks before it are its columns.
FIRST_UNLOGGED = "R_w_MRF"


def _group(prefix: str, names: tuple[str, ...] | list[str]) -> list[str]:
    return [f"{prefix}_{s}" for s in names]


def state_layout(n_joints: int, objects: tuple[str, ...] = ()) -> list[tuple[str, list[str]]]:
    """The row's blocks in order: each block's name and its value names (the log's column names
    for the logged blocks).

    The controller's blocks (every row of its vectors and torques, and its scale factors) are
    named from :mod:`app.controller.layout`, so the columns follow the kernel's layout. The last
    logged block holds the pose in {w} of each dynamic object named in ``objects`` (the scene's
    ``bodies`` order): ``object_<name>_x, _y, _z, _qw, _qx, _qy, _qz``; none for a static scene.
    """
    joints = [f"{i}" for i in range(n_joints)]
    return [
        ("t", ["t"]),
        ("q", _group("q", joints)),
        ("grip", _group("grip", POSE)),
        ("hand_target", _group("hand_target", XYZ)),
        ("vectors", [c for name, axes in VECTOR_ROWS for c in _group(name, axes)]),
        ("cmd", _group("cmd", TWIST_AXES)),
        ("tool", _group("tool", POSE)),
        ("F_S", _group("F_S", WRENCH_AXES)),
        ("contact_MRF", _group("contact_MRF", WRENCH_AXES)),
        ("hand_G", _group("hand_G", WRENCH_AXES)),
        ("torques", [c for name in TORQUE_ROWS for c in _group(name, joints)]),
        ("counts", _group("counts", joints)),
        ("scalars", list(SCALARS)),
        ("switches", list(INT_COLUMNS)),
        ("link_force", ["link_force"]),
        ("stages", [f"{s}_us" for s in STAGES]),
        ("objects", [c for name in objects for c in _group(f"object_{name}", POSE)]),
        # Not logged: the tool's rotation R_w_MRF (row-major) and whether the wrench was reflected.
        (FIRST_UNLOGGED, [f"R_w_MRF_{a}{b}" for a in range(3) for b in range(3)]),
        ("reflecting", ["reflecting"]),
    ]


class StateBlock:
    """The state row of one loop (see the module docstring).

    Args:
        n_joints: Joints of the device (sets the blocks' sizes).
        objects: Names of the scene's dynamic objects (``scene.bodies`` order).

    Attributes:
        names: Every value's name, in row order. n_logged: How many of them the log writes.
        starts: Where each block of :func:`state_layout` starts, by name.
        at: The same starts as an array, in layout order (what the compiled writers take).
        serial: The :attr:`~app.session.tick.TickRecord.serial` of the tick the row holds (-1: none).
        row: The row (filled by :meth:`fill`).
    """

    def __init__(self, n_joints: int, objects: tuple[str, ...] = ()) -> None:
        layout = state_layout(n_joints, objects)
        self.names = [c for _, columns in layout for c in columns]
        self.starts: dict[str, int] = {}
        self._sizes = {name: len(columns) for name, columns in layout}
        at = 0
        for name, columns in layout:
            self.starts[name] = at
            at += len(columns)
        self.n_logged = self.starts[FIRST_UNLOGGED]
        self.at = np.array(list(self.starts.values()), dtype=np.int64)
        self.row = np.zeros(len(self.names))
        self._no_hand = np.full((4, 4), np.nan)
        self.serial = -1
        # The bundle of the rooms' buffers (_bundle) and what it was made from; rebuilt when a
        # room's output object or a reading's buffer is another than last tick's.
        self.sources: Arrays | None = None
        self._made_from: tuple[object, ...] = ()
        self._fill: Callable[..., None] | None = None

    def view(self, name: str) -> Array:
        """The block ``name`` of the row (a view)."""
        start = self.starts[name]
        return self.row[start : start + self._sizes[name]]

    def fill(self, tick: TickRecord, full: bool = True) -> Array:
        """The row of ``tick``: filled on the first call of each tick, the same row after that.

        ``full`` False writes only the values a session's metrics read (:func:`fill_row`) and
        does not count as the tick's fill: a later call fills the whole row."""
        if tick.serial == self.serial:
            return self.row
        if self._fill is None:
            self._fill = self.kernel(fill_row, None)
        self.fill_with(tick, full, self._fill, None, 0, 0)
        return self.row

    @staticmethod
    def kernel(kernel: Any, sinks: object) -> Callable[..., None]:
        """``kernel`` compiled for :meth:`fill_with`: it takes :func:`fill_row`'s arguments, the
        first three (``sinks``: an observer's own arrays, or None; two ints) its own, and calls
        :func:`fill_row` with them (then does its own work on the row); :func:`fill_row` itself is one."""
        return entry_point(kernel, sinks, types.int64, types.int64, _ROW_SOURCES, *_ROW_VALUE_TYPES)

    def fill_with(
        self, tick: TickRecord, full: bool, kernel: Callable[..., None], sinks: object, i: int, j: int
    ) -> None:
        """Call ``kernel`` (:meth:`kernel`) with ``sinks``, ``i``, ``j`` and :func:`fill_row`'s
        arguments for ``tick``: the bundle of the rooms' buffers (:attr:`sources`), then this tick's
        own values, passed as they are (the kernel's signature types them). A full fill counts as
        the tick's."""
        out, reading, ft = tick.out, tick.reading, tick.ft
        T_w_MRF = tick.pose_view()
        made = self._made_from
        if not made or out is not made[0] or reading is not made[1] or ft is not made[2] or T_w_MRF is not made[3]:
            self._bundle(tick, T_w_MRF)
        contact = tick.contact
        kernel(
            sinks, i, j, self.sources, contact.w, tick.time, tick.hand_on, tick.deadman, tick.reference,
            tick.reflection, len(contact.contacts), out.faults, reading.watchdog_trips, tick.slave_status,
            reading.status, tick.link_force, out.reflecting, full,
        )  # fmt: skip
        if full:
            self.serial = tick.serial

    def _bundle(self, tick: TickRecord, T_w_MRF: Array) -> None:
        """Bundle the buffers the rooms keep (their output objects' array attributes, views of the
        rooms' buffers assigned once; what the reading's grip pose and hand wrench are made of
        (:class:`~app.device.boundary.GripSources`); the F/T reading's wrench; the slave's pose;
        the loop's hand target; MuJoCo's coordinates of the dynamic objects)."""
        out, reading = tick.out, tick.reading
        grip = reading.grip_sources()
        arrays = {
            "q": reading.q, "vectors": out.vectors, "twist": out.command.twist, "torques": out.torques,
            "counts": out.counts, "stage_ns": tick.stage_ns, "scalars": out.scalars, "T_H": grip.T_H,
            "w_H": grip.w_H, "how": grip.how, "hand": tick.hand_buffer, "F_S": tick.ft.wrench_S, "T_w_MRF": T_w_MRF,
            "objects": tick.object_poses(),
        }  # fmt: skip
        for name, a in arrays.items():
            # The bundle's fields are C-contiguous arrays: another layout would be misread.
            if not (a.__class__ is np.ndarray and a.flags.c_contiguous and a.flags.writeable and a.dtype in (F8, I8)):
                raise TypeError(f"the state row's source '{name}' is not a writable C-contiguous numeric array")
        for name, a in (("grip R", grip.R), ("grip p", grip.p)):  # any layout (their field's is 'A')
            if not (a.__class__ is np.ndarray and a.dtype is F8):
                raise TypeError(f"the state row's source '{name}' is not a float64 array")
        values: list[Any] = list(arrays.values())
        self.sources = _bundle(self.row, self.at, self._no_hand, grip.R, grip.p, *values)
        self._made_from = (out, reading, tick.ft, T_w_MRF)


_F1, _F2, _I1 = array_type(1, F8), array_type(2, F8), array_type(1, I8)
# Field names and types (the row's own arrays, then those of StateBlock._bundle); the grip's
# rotation and position in any layout (a Cartesian reading's are views of its pose).
_ROW_FIELDS = {"row": _F1, "at": _I1, "no_hand": _F2, "R": types.Array(types.float64, 2, "A")}
_ROW_FIELDS |= {"p": types.Array(types.float64, 1, "A"), "q": _F1, "vectors": _F2, "twist": _F1, "torques": _F2}
_ROW_FIELDS |= {"counts": _I1, "stage_ns": _I1, "scalars": _F1, "T_H": _F2, "w_H": _F1, "how": _I1, "hand": _F2}
_ROW_SOURCES = ArraysType([*_ROW_FIELDS.items(), ("F_S", _F1), ("T_w_MRF", _F2), ("objects", _F2)])
#: The types of fill_row's arguments after its bundle: the contact result's ``w``, then the tick's
#: scalars. Declared, not taken from a first call: an int 0 on a first tick (a link force summed
#: over no link) would otherwise make the argument an integer and cut every later value.
_ROW_VALUE_TYPES = (
    _F1,
    types.float64,  # t
    *(types.boolean,) * 4,  # hand_on, deadman, reference, reflection
    *(types.int64,) * 5,  # contacts, faults, watchdog_trips, slave_status, device_link
    types.float64,  # link_force
    types.boolean,  # reflecting
    types.boolean,  # full
)


@njit(cache=True)
def _bundle(
    row: Array,
    at: IntArray,
    no_hand: Array,
    R: Array,
    p: Array,
    q: Array,
    vectors: Array,
    twist: Array,
    torques: Array,
    counts: IntArray,
    stage_ns: IntArray,
    scalars: Array,
    T_H: Array,
    w_H: Array,
    how: IntArray,
    hand: Array,
    F_S: Array,
    T_w_MRF: Array,
    objects: Array,
) -> Arrays:
    """The arrays (of exactly the types of ``_ROW_SOURCES``) as one :class:`Arrays`; no copy."""
    src: Any = structref.new(_ROW_SOURCES)  # type: ignore[call-arg]  # an intrinsic, typed by numba
    src.row = row
    src.at = at
    src.no_hand = no_hand
    src.R = R
    src.p = p
    src.q = q
    src.vectors = vectors
    src.twist = twist
    src.torques = torques
    src.counts = counts
    src.stage_ns = stage_ns
    src.scalars = scalars
    src.T_H = T_H
    src.w_H = w_H
    src.how = how
    src.hand = hand
    src.F_S = F_S
    src.T_w_MRF = T_w_MRF
    src.objects = objects
    return src


@njit(cache=True)
def _pose7(R: Array, p: Array, row: Array, at: int) -> None:
    """Position ``p`` (3,) and the wxyz quaternion of the rotation ``R`` (3, 3) into ``row`` from ``at``."""
    row[at], row[at + 1], row[at + 2] = p[0], p[1], p[2]
    _quat4(R, row, at + 3)


@njit(cache=True)
def _quat4(R: Array, row: Array, at: int) -> None:
    """The wxyz quaternion of the rotation in ``R[0:3, 0:3]`` (a (3, 3) rotation or a (4, 4) pose)
    into ``row`` from ``at``, by index: a view of either (a slice) costs its reference counting."""
    row[at], row[at + 1], row[at + 2], row[at + 3] = quat_of(R)


@njit(cache=True)
def _hand_wrench(how: int, T_H: Array, w_H: Array, row: Array, at: int) -> None:
    """The hand's wrench on the grip (:class:`~app.device.boundary.GripSources`) into ``row`` from
    ``at``: zero, ``w_H`` in the axes of ``T_H`` (:func:`~app.device.hand.rotate_wrench`, as
    :meth:`~app.device.hand.OperatorHand.wrench_G` computes it), or ``w_H``."""
    if how == HAND_ROTATED:
        rotate_wrench(T_H, w_H, row, at)
        return
    for a in range(6):
        row[at + a] = 0.0 if how == HAND_OFF else w_H[a]


@njit(cache=True)
def _put1(row: Array, at: int, values: Array | IntArray) -> None:
    """Copy ``values`` (n,) into ``row`` from ``at``. Element by element, with no view made: a
    view (a slice, ``ravel``) costs its reference counting, several times the copy of a block."""
    for k in range(values.shape[0]):
        row[at + k] = values[k]


@njit(cache=True)
def _put2(row: Array, at: int, values: Array) -> None:
    """Copy ``values`` (n, m) row-major into ``row`` from ``at`` (as :func:`_put1`)."""
    m = values.shape[1]
    for i in range(values.shape[0]):
        for j in range(m):
            row[at + i * m + j] = values[i, j]


@njit(cache=True)
def fill_row(
    sinks: object,
    i: int,
    j: int,
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
    """One state row (the blocks of :func:`state_layout`) from one tick's buffers (``src``) and
    values (:meth:`StateBlock.fill_with`); ``sinks``, ``i``, ``j`` are not read (the leading
    arguments of a :meth:`StateBlock.kernel`, which calls this first). ``contact_w`` is the contact result's ``w`` (15,):
    the wrench at {MRF} in {MRF} is its ``[6:12]``
    (:attr:`~app.world.contact.model.ContactResult.wrench_MRF`).

    ``full`` False writes only the blocks a session's metrics read (:mod:`app.session.metrics`):
    the time, the tool's position (not its quaternion) and rotation, the contact wrench, the
    controller's scalars, the switches and counters, the link force and the reflecting flag; the
    rest of the row is then stale (the metrics of a loop without a log).
    """
    a: Any = src
    row, starts, T_w_MRF = a.row, a.at, a.T_w_MRF
    row[starts[0]] = t
    for i in range(3):
        row[starts[6] + i] = T_w_MRF[i, 3]
    for i in range(6):
        row[starts[8] + i] = contact_w[6 + i]
    _put1(row, starts[12], a.scalars)
    at = starts[13]
    row[at], row[at + 1], row[at + 2] = 1.0 if deadman else 0.0, 1.0 if reference else 0.0, 1.0 if reflection else 0.0
    row[at + 3], row[at + 4], row[at + 5], row[at + 6] = contacts, faults, watchdog_trips, slave_status
    row[at + 7] = device_link
    row[starts[14]] = link_force
    at = starts[17]
    for i in range(3):
        for j in range(3):
            row[at + 3 * i + j] = T_w_MRF[i, j]
    row[starts[18]] = 1.0 if reflecting else 0.0
    if not full:
        return
    _put1(row, starts[1], a.q)
    _pose7(a.R, a.p, row, starts[2])
    hand = a.hand if hand_on else a.no_hand
    for i in range(3):
        row[starts[3] + i] = hand[i, 3]
    _put2(row, starts[4], a.vectors)
    _put1(row, starts[5], a.twist)
    _quat4(T_w_MRF, row, starts[6] + 3)  # its position is written above
    _put1(row, starts[7], a.F_S)
    _hand_wrench(a.how[0], a.T_H, a.w_H, row, starts[9])
    _put2(row, starts[10], a.torques)
    _put1(row, starts[11], a.counts)
    at = starts[15]
    for v in a.stage_ns:
        row[at] = v * 1e-3
        at += 1
    _put2(row, starts[16], a.objects)
