"""Suite-wide settings and fixtures.

Hypothesis deadlines are off: the first call of a numba-compiled function includes its
compilation (or cache load), and speed goals live in ``frhc bench``, not in timed tests.
``local_ray`` is one small local Ray instance (2 CPUs, no dashboard) shared by the tests that
run the point engine on Ray, shut down at the end.

``make test`` spreads the tests over one pytest-xdist worker process per CPU (``-n auto``), test
by test, except the modules of :data:`ONE_WORKER`.
"""

from collections.abc import Iterator

import pytest
from hypothesis import settings

settings.register_profile("frhc", deadline=None)
settings.load_profile("frhc")

#: Test modules that one xdist worker runs, whole and one after the other, while the other workers
#: share the rest test by test. Each of their tests keeps more than one CPU busy: the browser
#: tests a demo's real-time servo loop process and a headless chromium drawing WebGL in software
#: (spread over two workers on two CPUs, a page missed its 60 s step timeout), the Ray tests a local instance of two CPUs (``local_ray``, otherwise started once per
#: worker) or heads of their own whose sweeps' ends are timed. The browser modules also start one
#: demo and one chromium for all their tests, and a test may use what an earlier one left.
#: (xdist's ``xdist_group`` mark would do this, but pytest 9.2 silently ignores it:
#: pytest-dev/pytest-xdist#1386.)
ONE_WORKER = (
    "tests/web/test_web_browser.py",
    "tests/web/test_web_startup.py",
    "tests/web/test_web_tasks.py",
    "tests/sweep/test_ray_cluster.py",
    "tests/sweep/test_sweep_engine.py",
    "tests/session/test_operators.py",
    "tests/study/test_zwidth.py",
)


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """xdist's default scheduling (``load``: each test to the next free worker), except that the
    modules of :data:`ONE_WORKER` go together to one worker, first."""
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
