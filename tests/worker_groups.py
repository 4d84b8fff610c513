"""Which test modules ``make test`` keeps on one xdist worker (``tests/conftest.py`` schedules them)."""

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
