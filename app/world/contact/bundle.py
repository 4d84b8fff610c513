"""The contact model's arrays as one compiled argument (:class:`KernelArrays`), :func:`borrowed`
views of them, and the decorator of the kernels that take them (:data:`tick_kernel`).

Entering a compiled function costs about 0.04 us per array argument (numba unboxes each one);
the step takes eleven arrays besides the pose and twist. A numba StructRef holding them is
unboxed as one object, about 0.45 us less per call. Its type is fixed here from the record
layouts, so the constructor and the step taking it are cached like every other kernel.

An array handed in from Python carries a reference count (its meminfo), and in compiled code
every view of it, down to a record's array field (``tris[t].n``, ``cand.ref``), takes and drops
a reference with two atomic operations: a scan of a pair's cache does that a few times per
candidate, and on a hole's wall it was a third of the time of a contact evaluation. The step
therefore works on borrowed views, which the model's own references keep alive throughout, and
every kernel it calls is compiled without numba's runtime (:data:`tick_kernel`), so no view
refers to the reference count at all: with the runtime, each view still called its functions
(never inlined) to find that there was none to count, and every such call spilled the
floating-point values live across it: on peg_in_hole's walk, 1.2 us of a median evaluation of
10.3 us, and 2.3 us of its 99th percentile.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numpy as np
from numba import njit, typeof, types
from numba.core import cgutils
from numba.experimental import structref
from numba.extending import intrinsic
from numba.np.arrayobj import populate_array

from app.world.contact import layout

#: Decorator of the kernels of a contact evaluation (:func:`~app.world.contact.step.contact_step`
#: and what it calls): cached, and compiled without numba's runtime (module docstring). They
#: therefore allocate nothing: no ``np.empty``, and no assignment of one array to a slice of
#: another (numba copies through a temporary where the two may overlap); they copy element by
#: element instead. (``_nrt`` is numba's own option, which its type stubs leave out.)
_NO_RUNTIME: dict[str, Any] = {"_nrt": False}
tick_kernel = njit(cache=True, **_NO_RUNTIME)


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


@intrinsic
def _borrowed(typingctx: Any, arr: types.Array) -> tuple:
    """A view of array ``arr`` (same type, data, shape and strides) without its reference count:
    views taken from it skip the atomic reference counting. Only for use while ``arr``'s owner
    keeps the memory alive (the duration of a call that was handed ``arr``)."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        src = context.make_array(sig.args[0])(context, builder, args[0])
        view = context.make_array(sig.return_type)(context, builder)
        populate_array(
            view,
            data=src.data,
            shape=cgutils.unpack_tuple(builder, src.shape),
            strides=cgutils.unpack_tuple(builder, src.strides),
            itemsize=src.itemsize,
            meminfo=None,
        )
        return view._getvalue()

    return arr(arr), codegen


# What compiled code calls: the intrinsic, typed for mypy as the function it is to numba.
borrowed = cast(Callable[[np.ndarray], np.ndarray], _borrowed)
