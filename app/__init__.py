"""frhc: Cartesian control of force-reflecting hand controllers (Williams 1997) in a virtual world.

Rooms, in the order data flows through one servo tick: :mod:`app.device` (the simulated FRHC and
the operator's hand), :mod:`app.controller` (the paper's Fig. 3), :mod:`app.world` (the virtual
slave and its contact), :mod:`app.session` (the loop, scripts, logs, metrics) and
:mod:`app.web` (the browser UI).
"""

import hashlib
import os
from pathlib import Path

# What marks a module whose functions numba compiles: numba itself, or the contact package's
# alias of ``njit`` (:data:`app.world.contact.bundle.tick_kernel`), which a module may use without
# naming numba (``app/world/contact/track.py``: an edit to it once ran against the stale cached
# step that inlines it).
_COMPILED_MARKS = (b"numba", b"tick_kernel")


def compiled_sources() -> list[Path]:
    """Every module of the package that numba compiles or that compiles what it imports, sorted.

    The slave's and the device's kernels were left out once, and an arm kernel cached against an
    older version of the tool's implicit step it calls crashed the process (a segmentation fault).
    """
    here = Path(__file__).resolve().parent
    return [src for src in sorted(here.rglob("*.py")) if any(m in src.read_bytes() for m in _COMPILED_MARKS)]


def _numba_cache_dir() -> str:
    """A numba cache folder keyed by the source of every compiled module.

    numba invalidates a cached function only when its own file changes, not when a compiled
    function it calls (in another module) does; keying the folder by all of their sources makes
    any edit start a fresh cache instead of running a stale kernel.
    """
    digest = hashlib.sha1()
    for src in compiled_sources():
        digest.update(src.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "frhc" / "numba"
    return str(base / digest.hexdigest()[:16])


os.environ.setdefault("NUMBA_CACHE_DIR", _numba_cache_dir())
