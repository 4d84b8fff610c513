"""The contact model's arrays as one compiled argument (:class:`KernelArrays`).

Entering a compiled function costs about 0.04 us per array argument (numba unboxes each one);
the step takes eleven arrays besides the pose and twist. A numba StructRef holding them is
unboxed as one object, about 0.45 us less per call. Its type is fixed here from the record
layouts, so the constructor and the step taking it are cached like every other kernel.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, typeof, types
from numba.experimental import structref

from app.world.contact import layout


@structref.register
class _KernelArraysType(types.StructRef):
    def preprocess_fields(self, fields: tuple) -> tuple:
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class KernelArrays(structref.StructRefProxy):
    """The arrays of one :class:`~app.world.contact.model.ContactModel` for the compiled step
    (built by :func:`bundle`; opaque in Python)."""


structref.define_boxing(_KernelArraysType, KernelArrays)


def _array(dtype: np.dtype, ndim: int = 1) -> types.Array:
    return typeof(np.zeros((0,) * ndim, dtype=dtype))


# Field names and types: C-contiguous, writable arrays of the layouts' records.
_KERNEL_ARRAYS = _KernelArraysType(
    [
        ("tool", _array(layout.TOOL)),
        ("objs", _array(layout.OBJECT)),
        ("pairs", _array(layout.PAIR)),
        ("pool", _array(layout.CANDIDATE, 2)),
        ("out", _array(layout.CONTACT)),
        ("verts", _array(layout.VERTEX)),
        ("tris", _array(layout.TRIANGLE)),
        ("edges", _array(layout.EDGE)),
        ("cells", _array(layout.CELL)),
        ("lists", _array(np.dtype(np.int64))),
        ("stamp", _array(np.dtype(np.int64))),
    ]
)


@njit(cache=True)
def bundle(
    tool: np.ndarray,
    objs: np.ndarray,
    pairs: np.ndarray,
    pool: np.ndarray,
    out: np.ndarray,
    verts: np.ndarray,
    tris: np.ndarray,
    edges: np.ndarray,
    cells: np.ndarray,
    lists: np.ndarray,
    stamp: np.ndarray,
) -> KernelArrays:
    """The arrays (of exactly the types above) as one :class:`KernelArrays`; it refers to them, no copy."""
    a: Any = structref.new(_KERNEL_ARRAYS)  # type: ignore[call-arg]  # an intrinsic, typed by numba
    a.tool = tool
    a.objs = objs
    a.pairs = pairs
    a.pool = pool
    a.out = out
    a.verts = verts
    a.tris = tris
    a.edges = edges
    a.cells = cells
    a.lists = lists
    a.stamp = stamp
    return a
