"""Suite-wide settings and fixtures.

Hypothesis deadlines are off: the first call of a numba-compiled function includes its
compilation (or cache load), and speed goals live in ``frhc bench``, not in timed tests.
``local_ray`` is one small local Ray instance (2 CPUs, no dashboard) shared by the tests that
run the point engine on Ray, shut down at the end.

``make test`` spreads the tests over one pytest-xdist worker process per CPU (``-n auto``), test
by test, except the modules of :data:`WORKER_GROUPS`.
"""

from collections.abc import Iterator

import pytest
from hypothesis import settings

settings.register_profile("frhc", deadline=None)
settings.load_profile("frhc")

#: Test modules that one xdist worker runs whole, one after the other, by group. "browser": each
#: module starts one demo and one headless chromium for all its tests (spread, each worker would
#: start its own), and chromium draws WebGL in software: two at once slow each other past the
#: tests' step timeouts on two CPUs. "ray": every module that starts Ray, so that ``local_ray`` is
#: one instance, not one per worker, and the cluster tests (which start heads of their own and
#: time how a sweep ends) do not share the machine with another Ray. (xdist's own ``xdist_group``
#: mark is not used: with pytest 9.2 it is silently ignored, pytest-dev/pytest-xdist#1386.)
WORKER_GROUPS = {
    "tests/web/test_web_browser.py": "browser",
    "tests/web/test_web_startup.py": "browser",
    "tests/web/test_web_tasks.py": "browser",
    "tests/sweep/test_ray_cluster.py": "ray",
    "tests/sweep/test_sweep_engine.py": "ray",
    "tests/session/test_operators.py": "ray",
    "tests/study/test_zwidth.py": "ray",
}


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """xdist's default scheduling (``load``: each test to the next free worker), the modules of
    :data:`WORKER_GROUPS` each group to one worker; the larger groups are sent first."""
    if config.getvalue("dist") != "load":
        return None  # another mode asked for on the command line
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return WORKER_GROUPS.get(nodeid.split("::", 1)[0], nodeid)

    return GroupScheduling(config, log)


@pytest.fixture(scope="session")
def local_ray() -> Iterator[None]:
    ray = pytest.importorskip("ray")
    from app.sweep.engine import init_local_ray

    init_local_ray(2)
    yield
    ray.shutdown()
