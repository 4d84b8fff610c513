"""The numba cache folder is keyed by every compiled module's source (app/__init__.py): numba
itself re-checks only a function's own file, so a kernel whose module the key missed runs stale
from the cache inside every caller compiled before the edit."""

from __future__ import annotations

import re
from pathlib import Path

import app

# A function compiled by numba: decorated with njit (or jit), or with an alias bound to one.
_DECORATOR = re.compile(rb"^@(\w+)", re.MULTILINE)
_ALIAS = re.compile(rb"^(\w+) = (?:numba\.)?n?jit\(", re.MULTILINE)


def test_every_module_with_a_compiled_function_keys_the_cache() -> None:
    root = Path(app.__file__).resolve().parent
    sources = [p.read_bytes() for p in sorted(root.rglob("*.py"))]
    compilers = {b"njit", b"jit"} | {m for text in sources for m in _ALIAS.findall(text)}
    compiled = {p for p in sorted(root.rglob("*.py")) if compilers & set(_DECORATOR.findall(p.read_bytes()))}
    assert root / "world" / "contact" / "track.py" in compiled  # it uses only the alias
    assert compiled <= set(app.compiled_sources())
