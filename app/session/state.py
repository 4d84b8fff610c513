"""The tick's state block: one preallocated row holding every per-tick value the observers read.

The log, the metrics (and any observer that wants the tick's values as numbers) read one row:
:meth:`~app.session.tick.TickRecord.state` fills it from the rooms' buffers with one compiled
call (:func:`_fill_state`) the first time an observer asks for it in a tick, and hands the same
row to every later one. The log copies the row's first :attr:`StateBlock.n_logged` values (its
Parquet columns, in order); the metrics reduce the row in their own compiled pass.

The row is made of named blocks (:func:`state_layout`): the log's columns first, then values only
the observers use (the tool's rotation, the reflecting flag). To add a column, add a block to
:func:`state_layout` (before ``R_w_MRF`` if it is logged) and fill it in :func:`_fill_state`, or,
for values outside the rooms' buffers, write :meth:`StateBlock.view` after the fill.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from app.compiled import entry_point, is_f8
from app.controller.layout import SCALARS, TORQUE_ROWS, TWIST_AXES, VECTOR_ROWS, WRENCH_AXES
from app.session.tick import STAGES
from app.spatial import Array, IntArray, quat_into

#: What :meth:`StateBlock.observed` returns and :func:`fill_observed` takes (see there).
Observed = tuple[Array, Array, Array, float, bool, bool, bool, int, int, int, int, int, float, bool]

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
        self._hand = np.empty((4, 4))
        self._hand_checked: Array | None = self._no_hand
        self._fill: Callable[..., None] | None = None
        self.serial = -1
        self._sources: tuple[object, ...] = (None, None, None)
        self._arrays: tuple[object, ...] = ()
        self._objects = self.view("objects").reshape(len(objects), len(POSE)) if objects else None

    def view(self, name: str) -> Array:
        """The block ``name`` of the row (a view)."""
        start = self.starts[name]
        return self.row[start : start + self._sizes[name]]

    def fill(self, tick: TickRecord) -> Array:
        """The row of ``tick``: filled on the first call of each tick, the same row after that."""
        if tick.serial == self.serial:
            return self.row
        self.serial = tick.serial
        out, reading, ft = tick.out, tick.reading, tick.ft
        if out is not self._sources[0] or reading is not self._sources[1] or ft is not self._sources[2]:
            # The rooms keep their output objects and those their array attributes (views of the
            # rooms' buffers, assigned once): fetch these again only when an object changes. The
            # reading's pose and hand wrench are properties that compute on access: every tick.
            self._sources = (out, reading, ft)
            self._arrays = (
                self.row, self.at, reading.q, out.vectors, out.command.twist, ft.wrench_S, out.torques,
                out.counts, tick.stage_ns,
            )  # fmt: skip
        hand_on = tick.hand_on
        hand = tick.hand_target if hand_on else self._no_hand
        if hand is not self._hand_checked:
            # The loop passes its own (4, 4) array every tick: checked once, not every tick.
            if is_f8(hand, (4, 4)):
                self._hand_checked = hand
            else:
                self._hand[:] = hand
                hand = self._hand
        args = (
            *self._arrays, reading.T_0_G, reading.wrench_G, hand, hand_on, *self.observed(tick),
        )  # fmt: skip
        if self._fill is None:
            # The same kinds of arguments every tick: the compiled row writer for their types, once.
            self._fill = entry_point(_fill_state, *args)
        self._fill(*args)
        if self._objects is not None:
            # A (n, 7) view of MuJoCo's coordinates; only scenes with dynamic objects pay the copy.
            np.copyto(self._objects, tick.object_poses())
        return self.row

    def observed(self, tick: TickRecord) -> tuple[object, ...]:
        """The values of ``tick`` a session's metrics read, as :func:`fill_observed` takes them
        (its ``observed``)."""
        out = tick.out
        return (
            out.scalars, tick.T_w_MRF, tick.contact_wrench_MRF, tick.time, tick.deadman, tick.reference,
            tick.reflection, tick.contact.count, int(out.faults), tick.reading.watchdog_trips, tick.slave_status,
            int(tick.device_link), tick.link_force, out.reflecting,
        )  # fmt: skip


@njit(cache=True)
def _pose7(T: Array, out: Array) -> None:
    """Position and wxyz quaternion of the pose ``T`` (4, 4) into ``out`` (7,)."""
    out[0], out[1], out[2] = T[0, 3], T[1, 3], T[2, 3]
    quat_into(T[0:3, 0:3], out[3:7])


@njit(cache=True)
def _put(row: Array, at: int, values: Array | IntArray) -> int:
    """Copy ``values`` (any shape, row-major) into ``row`` from ``at``; return the next index."""
    for v in values.ravel():
        row[at] = v
        at += 1
    return at


@njit(cache=True)
def _fill_state(
    row: Array,
    starts: IntArray,
    q: Array,
    vectors: Array,
    twist: Array,
    F_S: Array,
    torques: Array,
    counts: IntArray,
    stage_ns: IntArray,
    T_0_G: Array,
    wrench_G: Array,
    hand: Array,
    hand_on: bool,
    scalars: Array,
    T_w_MRF: Array,
    contact_MRF: Array,
    t: float,
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
) -> None:
    """One state row (the blocks of :func:`state_layout`, starting at ``starts``) from one tick's
    arrays: :func:`fill_observed`'s blocks, then the others. The observed values come as separate
    arguments: a tuple argument costs ~0.3 us more to unbox on every call."""
    observed = (
        scalars, T_w_MRF, contact_MRF, t, deadman, reference, reflection, contacts, faults, watchdog_trips,
        slave_status, device_link, link_force, reflecting,
    )  # fmt: skip
    fill_observed(row, starts, observed)
    _put(row, starts[1], q)
    _pose7(T_0_G, row[starts[2] : starts[2] + 7])
    for a in range(3):
        row[starts[3] + a] = hand[a, 3] if hand_on else np.nan
    _put(row, starts[4], vectors)
    _put(row, starts[5], twist)
    _pose7(T_w_MRF, row[starts[6] : starts[6] + 7])
    _put(row, starts[7], F_S)
    _put(row, starts[9], wrench_G)
    _put(row, starts[10], torques)
    _put(row, starts[11], counts)
    at = starts[15]
    for v in stage_ns:
        row[at] = v * 1e-3
        at += 1
    # starts[16], the dynamic objects' poses, is filled by StateBlock.fill after this call.


@njit(cache=True)
def fill_observed(row: Array, starts: IntArray, observed: Observed) -> None:
    """The blocks of the row a session's metrics read (:mod:`app.session.metrics`): the time, the
    tool's position (not its quaternion) and rotation, the contact wrench, the controller's
    scalars, the switches and counters, the link force and the reflecting flag. The metrics of a
    loop without a log write only these (the rest of the row is then stale).

    ``observed`` is :meth:`StateBlock.observed`: ``(scalars, T_w_MRF, contact_MRF, t, deadman,
    reference, reflection, contacts, faults, watchdog_trips, slave_status, device_link,
    link_force, reflecting)``. One tuple: the callers pass it on without naming its parts.
    """
    scalars, T_w_MRF, contact_MRF, t, deadman, reference, reflection = observed[0:7]
    contacts, faults, watchdog_trips, slave_status, device_link, link_force, reflecting = observed[7:14]
    row[starts[0]] = t
    for a in range(3):
        row[starts[6] + a] = T_w_MRF[a, 3]
    _put(row, starts[8], contact_MRF)
    _put(row, starts[12], scalars)
    at = starts[13]
    row[at], row[at + 1], row[at + 2] = 1.0 if deadman else 0.0, 1.0 if reference else 0.0, 1.0 if reflection else 0.0
    row[at + 3], row[at + 4], row[at + 5], row[at + 6] = contacts, faults, watchdog_trips, slave_status
    row[at + 7] = device_link
    row[starts[14]] = link_force
    at = starts[17]
    for a in range(3):
        for b in range(3):
            row[at + 3 * a + b] = T_w_MRF[a, b]
    row[starts[18]] = 1.0 if reflecting else 0.0
