"""``make test``'s xdist groups (``tests/conftest.py``) hold every test module that starts Ray or
headless chromium, and name only modules that exist."""

from __future__ import annotations

from pathlib import Path

from conftest import WORKER_GROUPS

ROOT = Path(__file__).resolve().parents[1]


def _modules_with(*marks: str) -> set[str]:
    return {
        p.relative_to(ROOT).as_posix()
        for p in sorted((ROOT / "tests").rglob("test_*.py"))
        if any(m in p.read_text() for m in marks)
    }


def test_every_module_that_starts_ray_or_chromium_is_grouped() -> None:
    ray = _modules_with("local_ray", '"start", "--head"') - {"tests/test_worker_groups.py"}
    browser = _modules_with("pytest.mark.browser") - {"tests/test_worker_groups.py"}
    assert ray, "no module starts Ray: the search is wrong"
    assert browser, "no browser module: the search is wrong"
    assert {m: WORKER_GROUPS.get(m) for m in ray} == dict.fromkeys(ray, "ray")
    assert {m: WORKER_GROUPS.get(m) for m in browser} == dict.fromkeys(browser, "browser")


def test_every_grouped_module_exists() -> None:
    assert all((ROOT / m).is_file() for m in WORKER_GROUPS), WORKER_GROUPS
