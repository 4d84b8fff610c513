"""3-vector helpers for the servo hot path.

``numpy.cross`` costs tens of microseconds per call on 3-vectors (axis normalisation and
``moveaxis`` in Python); on Python floats a cross product costs well under one.
"""

from __future__ import annotations

import numpy as np

from app.spatial import Array


def cross3(a: Array, b: Array) -> Array:
    """``a x b`` for two vectors of shape (3,)."""
    ax, ay, az = a.tolist()
    bx, by, bz = b.tolist()
    return np.array((ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx))
