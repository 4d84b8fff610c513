"""Suite-wide settings and fixtures.

Hypothesis deadlines are off: the first call of a numba-compiled function includes its
compilation (or cache load), and speed goals live in ``frhc bench``, not in timed tests.
``local_ray`` is one small local Ray instance (2 CPUs, no dashboard) shared by the tests that
run the point engine on Ray, shut down at the end.
"""

from collections.abc import Iterator

import pytest
from hypothesis import settings

settings.register_profile("frhc", deadline=None)
settings.load_profile("frhc")


@pytest.fixture(scope="session")
def local_ray() -> Iterator[None]:
    ray = pytest.importorskip("ray")
    from app.sweep.engine import init_local_ray

    init_local_ray(2)
    yield
    ray.shutdown()
