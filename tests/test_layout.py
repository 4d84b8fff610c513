"""The rooms of ``app/`` import one way: a room never imports one that sits above it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

APP = Path(__file__).resolve().parents[1] / "app"

# room -> rooms it must not import (directly, at any depth of the file).
FORBIDDEN: dict[str, tuple[str, ...]] = {
    "world": ("app.slave", "app.session", "app.sweep", "app.study", "app.web"),
    "controller": ("app.world", "app.slave", "app.session", "app.sweep", "app.study", "app.web"),
    "slave": ("app.session", "app.sweep", "app.study", "app.web"),
    "session": ("app.sweep", "app.study", "app.web"),
    "sweep": ("app.study", "app.web"),
}


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


@pytest.mark.parametrize("room", sorted(FORBIDDEN))
def test_room_imports_only_downwards(room: str) -> None:
    files = sorted((APP / room).rglob("*.py"))
    assert files, f"app/{room}/ has no modules"
    bad = [
        f"{path.relative_to(APP.parent)} imports {name}"
        for path in files
        for name in sorted(_imports(path))
        if any(name == f or name.startswith(f + ".") for f in FORBIDDEN[room])
    ]
    assert not bad, "\n".join(bad)
