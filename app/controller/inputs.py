"""Checks of the controller's public inputs, for the slow path after a cheap identity test fails.

:meth:`~app.controller.frhc.FRHCController.step` first tests types, dtypes and shapes by identity
(a fraction of a microsecond); only when that fails are the arguments converted or refused here,
with :class:`~app.errors.InputError` naming the argument. Non-finite values are not refused: they
are faults the compiled tick turns into the safe output.
"""

from __future__ import annotations

import numpy as np

from app.errors import InputError
from app.spatial import Array

SHAPE_3, SHAPE_6, SHAPE_33 = (3,), (6,), (3, 3)


def checked_arrays(
    arrays: tuple[object, ...], shapes: tuple[tuple[int, ...], ...], names: tuple[str, ...]
) -> tuple[Array, ...]:
    """``arrays`` as C-contiguous float64 of ``shapes``; :class:`InputError` naming the first bad one."""
    checked = []
    for a, shape, name in zip(arrays, shapes, names, strict=True):
        try:
            x = np.asarray(a)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name}: not an array of numbers ({exc})") from None
        if x.dtype.kind not in "iuf":
            raise InputError(f"{name}: expected real numbers, got dtype {x.dtype}")
        if x.shape != shape:
            raise InputError(f"{name}: expected shape {shape}, got {x.shape}")
        checked.append(np.ascontiguousarray(x, dtype=np.float64))
    return tuple(checked)


def checked_float(value: object, name: str) -> float:
    """``value`` as a float, or :class:`InputError` (a NaN stays NaN: the tick then faults)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise InputError(f"{name}: expected a number, got {type(value).__name__}")
    return float(value)
