"""The compiled entry points' types: the arrays' looked-up types are numba's own."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit, typeof

from app.compiled import _type_of, entry_point


def _examples() -> list[np.ndarray]:
    base = np.arange(24.0).reshape(2, 3, 4)
    readonly = np.zeros((4, 4))
    readonly.flags.writeable = False
    return [
        np.zeros(6),
        np.zeros((4, 4)),
        np.zeros(3, dtype=np.int64),
        np.zeros((2, 5), dtype=np.int32),
        base,
        np.asfortranarray(np.zeros((3, 4))),
        np.zeros((4, 4))[:, 1],  # neither C nor F contiguous
        np.zeros((4, 4)).T,  # F contiguous
        np.zeros((1, 4)),  # both C and F contiguous
        readonly,
        base[:, 1:, :],
    ]


@pytest.mark.parametrize("a", _examples(), ids=lambda a: f"{a.dtype}{a.shape}{a.strides}")
def test_an_arrays_type_is_numbas_typeof(a: np.ndarray) -> None:
    # Twice: the first call fills the table, the second reads it.
    assert _type_of(a) == typeof(a)
    assert _type_of(a) == typeof(a)


def test_arrays_of_one_kind_but_another_layout_get_their_own_specialisation() -> None:
    @njit
    def total(a: np.ndarray) -> float:
        return float(a.sum())

    c = np.arange(12.0).reshape(3, 4)
    f = np.asfortranarray(c)
    on_c, on_f = entry_point(total, c), entry_point(total, f)
    assert on_c is entry_point(total, c.copy())  # kept, not fetched again
    assert on_f is not on_c
    assert on_f(f) == on_c(c) == 66.0
