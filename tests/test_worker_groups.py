"""``make test`` keeps every test module that starts Ray or headless chromium on one xdist worker
(``tests/worker_groups.py``), and that list names only modules that exist."""

from __future__ import annotations

from pathlib import Path

from worker_groups import ONE_WORKER

ROOT = Path(__file__).resolve().parents[1]


def _modules_with(*marks: str) -> set[str]:
    return {
        p.relative_to(ROOT).as_posix()
        for p in sorted((ROOT / "tests").rglob("test_*.py"))
        if p.name != Path(__file__).name and any(m in p.read_text() for m in marks)
    }


def test_every_module_that_starts_ray_or_chromium_is_on_one_worker() -> None:
    ray = _modules_with("local_ray", '"start", "--head"')
    browser = _modules_with("pytest.mark.browser")
    assert len(ray) >= 2, ray  # the search finds them (the cluster tests and local_ray's)
    assert browser, "no browser module: the search is wrong"
    assert (ray | browser) - set(ONE_WORKER) == set()


def test_every_module_on_one_worker_exists() -> None:
    assert all((ROOT / m).is_file() for m in ONE_WORKER), ONE_WORKER
