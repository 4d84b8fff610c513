"""Calling a numba kernel without numba's per-call typing.

A numba dispatcher works out the type of every argument on every call to pick the compiled
specialisation: about 0.1 us an argument on the machine this project is measured on, 2 us for a
kernel of twenty arguments, on a servo tick of a few tens. A room that calls the same kernel with
the same kinds of arguments every tick can instead fetch that specialisation once
(:func:`entry_point`) and call it directly.

Arrays a kernel reads every tick from buffers their owners keep can also travel as one argument,
an :class:`Arrays` bundle: numba unboxes each array argument (~0.09 us each on that machine) but a
bundle as one object (~0.1 us whatever it holds).

The entry point converts its arguments for the types it was compiled for *without checking them*:
an array of another dtype, dimension or layout (e.g. a transposed view) would be read as if it had
the compiled one. Callers therefore check, cheaply, at their boundary that what they pass is
exactly what the example had (a C-contiguous float64 array of the right shape, ...), and keep
passing their own preallocated arrays for everything else.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numba import typeof, types
from numba.experimental import structref

#: numpy's own dtype objects, for identity tests (``a.dtype is F8``).
F8 = np.dtype(np.float64)
I8 = np.dtype(np.int64)


def entry_point(kernel: Any, *example: object) -> Callable[..., Any]:
    """The compiled ``kernel`` (a numba dispatcher) for the types of ``example``, as a plain callable.

    An example may be a numba type (``types.float64``) instead of a value: the argument is then
    of that type whatever is passed, where a value's type would be the first call's (a Python
    int where the argument is a float would make it an integer and cut every later float). A
    scalar declared so is converted on each call (an int to float64, a bool-like to a boolean).

    Compiles the specialisation (or loads it from numba's cache) now. Call the result only with
    arguments of exactly the example's types (module docstring).
    """
    signature = tuple(a if isinstance(a, types.Type) else _type_of(a) for a in example)
    key = (kernel, signature)
    compiled = _ENTRY_POINTS.get(key)
    if compiled is None:
        compiled = _ENTRY_POINTS[key] = kernel.compile(signature)
    return compiled


#: The specialisations :func:`entry_point` fetched, by kernel and signature: a dispatcher's
#: ``compile`` of a specialisation it holds still takes its compile lock and sends its events
#: (~50 us), and a session's rooms fetch ~70 when they are built.
_ENTRY_POINTS: dict[tuple[Any, tuple[types.Type, ...]], Callable[..., Any]] = {}


#: numba's types of the arrays examples were, by what decides them (:func:`_type_of`).
_ARRAY_TYPES: dict[tuple[object, ...], types.Type] = {}


def _type_of(a: object) -> types.Type:
    """numba's ``typeof(a)``; a numpy array's looked up by its dtype, dimensions, layout and
    writability, all that numba's type of it holds: ``typeof`` builds and interns the type on
    every call (~20 us against ~1 us here), and a session's rooms give ~70 examples when they are
    built (a sweep or an experiment builds a session per point)."""
    if a.__class__ is not np.ndarray:
        return typeof(a)
    flags = a.flags
    key = (a.dtype, a.ndim, flags.c_contiguous, flags.f_contiguous, flags.writeable)
    found = _ARRAY_TYPES.get(key)
    if found is None:
        found = _ARRAY_TYPES[key] = typeof(a)
    return found


def is_f8(a: object, shape: tuple[int, ...]) -> bool:
    """Whether ``a`` is a C-contiguous float64 numpy array of ``shape`` (what a kernel compiled
    for such arrays may be handed)."""
    return a.__class__ is np.ndarray and a.dtype is F8 and a.shape == shape and a.flags.c_contiguous


def array_type(ndim: int, dtype: np.dtype) -> types.Array:
    """numba's type of a C-contiguous, writable ``ndim``-dimensional array of ``dtype`` (a field of
    an :class:`ArraysType`)."""
    return typeof(np.zeros((0,) * ndim, dtype=dtype))


@structref.register
class ArraysType(types.StructRef):
    """The numba type of an :class:`Arrays` bundle with the given ``(name, array type)`` fields.

    A module fixes its bundle's fields as a constant (``ArraysType([...])``) and builds bundles
    with a cached compiled constructor that assigns each field (``structref.new`` of the
    constant): the kernels taking it are then cached like every other.
    """

    def preprocess_fields(self, fields: tuple) -> tuple:
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class Arrays(structref.StructRefProxy):
    """Arrays held by reference as one compiled argument (module docstring); opaque in Python. It
    keeps its arrays alive; their owners must not replace them (a replaced array is not seen)."""


structref.define_boxing(ArraysType, Arrays)
