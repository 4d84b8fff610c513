"""Calling a numba kernel without numba's per-call typing.

A numba dispatcher works out the type of every argument on every call to pick the compiled
specialisation: about 0.1 us an argument on the machine this project is measured on, 2 us for a
kernel of twenty arguments, on a servo tick of a few tens. A room that calls the same kernel with
the same kinds of arguments every tick can instead fetch that specialisation once
(:func:`entry_point`) and call it directly.

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
from numba import typeof

#: numpy's own dtype objects, for identity tests (``a.dtype is F8``).
F8 = np.dtype(np.float64)
I8 = np.dtype(np.int64)


def entry_point(kernel: Any, *example: object) -> Callable[..., Any]:
    """The compiled ``kernel`` (a numba dispatcher) for the types of ``example``, as a plain callable.

    Compiles the specialisation (or loads it from numba's cache) now. Call the result only with
    arguments of exactly the example's types (module docstring).
    """
    compiled: Callable[..., Any] = kernel.compile(tuple(typeof(a) for a in example))
    return compiled


def is_f8(a: object, shape: tuple[int, ...]) -> bool:
    """Whether ``a`` is a C-contiguous float64 numpy array of ``shape`` (what a kernel compiled
    for such arrays may be handed)."""
    return a.__class__ is np.ndarray and a.dtype is F8 and a.shape == shape and a.flags.c_contiguous
