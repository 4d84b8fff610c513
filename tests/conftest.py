"""Suite-wide settings and fixtures.

Hypothesis deadlines are off: the first call of a numba-compiled function includes its
compilation (or cache load), and speed goals live in ``frhc bench``, not in timed tests.
``local_ray`` is one small local Ray instance (2 CPUs, no dashboard) shared by the tests that
run the point engine on Ray, shut down at the end.

``make test`` spreads the tests over one pytest-xdist worker process per CPU (``-n auto``), test
by test, except the modules of ``worker_groups.ONE_WORKER``.
"""

from collections.abc import Iterator

import pytest
from hypothesis import settings
from worker_groups import ONE_WORKER

settings.register_profile("frhc", deadline=None)
settings.load_profile("frhc")


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """xdist's default scheduling (``load``: each test to the next free worker), except that the
    modules of ``ONE_WORKER`` go together to one worker, first."""
    if config.getvalue("dist") != "load":
        return None  # another mode asked for on the command line
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return "one worker" if nodeid.split("::", 1)[0] in ONE_WORKER else nodeid

    return GroupScheduling(config, log)


@pytest.fixture(scope="session")
def local_ray() -> Iterator[None]:
    ray = pytest.importorskip("ray")
    from app.sweep.engine import init_local_ray

    init_local_ray(2)
    yield
    ray.shutdown()
