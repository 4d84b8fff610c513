"""MuJoCo's C functions, callable from numba-compiled code.

A servo tick crosses from Python into compiled code several times a room: the MuJoCo binding
(``mujoco.mj_step``), then each numba kernel. On the 2-core machine this project is measured on,
every crossing costs 1-3 us of argument checking and unboxing, more than the arithmetic it
guards (a free body's ``mj_step`` is ~2 us). Calling MuJoCo's C entry points *from inside* a
kernel lets a room's whole tick be one crossing.

The MuJoCo Python package ships the same ``libmujoco`` its bindings use; :func:`address` loads it
with ctypes and returns a function's address, and :func:`call_model_data` calls a
``void f(const mjModel*, mjData*)`` at such an address from a kernel. ``mujoco.MjModel._address``
and ``MjData._address`` give the struct pointers (the bindings' own objects: their numpy views
see every change). The addresses are runtime arguments rather than constants baked into the
kernel, so the kernels stay cacheable (``cache=True``) across processes.

Hand-written (a dozen lines of llvmlite) because numba has no typed call through an integer
address that it can also cache: a ``WrapperAddressProtocol`` argument works but costs ~45 us a
call to type, and a ctypes function object referenced as a global cannot be cached.

Keep the calls to functions that cannot fail on valid models: ``mj_step``, ``mj_step1``,
``mj_step2``, ``mj_kinematics``. MuJoCo reports instability through ``mjData.warning`` (which
the bindings' readers still see), not by raising. Its default warning handler would also print
the warning on stdout (into ``frhc run --json``'s output) and append it to ``MUJOCO_LOG.TXT`` in
the working folder; :func:`pointers`, which every caller of compiled MuJoCo steps goes through,
puts a native handler in its place that does neither (:func:`quiet_warnings`): the counters stay
the record, and the rooms that step MuJoCo read them and say what went wrong in their own words.
"""

from __future__ import annotations

import ctypes
import functools
import math
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, cast

import mujoco
from llvmlite import ir
from numba import cfunc, types
from numba.core import cgutils
from numba.extending import intrinsic

from app.errors import ConfigError

_LIBRARY_PATTERNS = {"linux": "libmujoco.so*", "darwin": "libmujoco*.dylib", "win32": "mujoco*.dll"}


@contextmanager
def file_warnings() -> Iterator[list[str]]:
    """MuJoCo's warnings while a model file is read (``XML contains a 'NaN'``), into the list
    yielded, for the caller to refuse the file with (:func:`refuse_warned`).

    MuJoCo's default warning handler prints to stdout and writes ``MUJOCO_LOG.TXT`` in the
    working folder; this handler takes the messages instead, only while the block runs (kernels
    call ``mj_step`` from compiled code, where a Python handler must not be entered).
    """
    warned: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(warned.append)
    try:
        yield warned
    finally:
        mujoco.set_mju_user_warning(previous)


def refuse_warned(warned: list[str], source: str | Path, field: str) -> None:
    """Raise a :class:`ConfigError` naming ``source`` and ``field`` with MuJoCo's words, if it warned."""
    if warned:
        raise ConfigError(source, field, "MuJoCo warns: " + "; ".join(" ".join(w.split()) for w in warned))


#: The servo period (s) the device and scene files' ``substeps`` are counted at.
SUBSTEP_PERIOD = 1e-3


def substeps_for(dt: float, substeps: int) -> int:
    """MuJoCo steps in a servo period of ``dt`` (s) for a file's ``substeps`` per 1 ms period.

    A simulation's step is what its stiffest part (a slave's PD, an arm's joint servos, the
    operator's hand on a device's grip) was chosen stable at: ``1 ms / substeps``. A slower servo
    takes proportionally more steps so the step never exceeds that one (at 100 Hz a 10 ms step sent
    the 7-dof arm 41 mm off its path); a faster one keeps ``substeps``.
    """
    return max(substeps, math.ceil(dt * substeps / SUBSTEP_PERIOD - 1e-9))


@functools.cache
def _library() -> ctypes.CDLL:
    folder = Path(mujoco.__file__).parent
    pattern = _LIBRARY_PATTERNS.get(sys.platform, "libmujoco.so*")
    found = sorted(folder.glob(pattern))
    if not found:
        raise ConfigError(str(folder), "libmujoco", f"no MuJoCo library matching {pattern} next to the bindings")
    return ctypes.CDLL(str(found[0]))


@functools.cache
def address(name: str) -> int:
    """Address of MuJoCo's C function ``name`` (e.g. ``"mj_step"``) in the library the bindings use."""
    return int(ctypes.cast(getattr(_library(), name), ctypes.c_void_p).value or 0)


@cfunc(types.void(types.voidptr), cache=True)
def _ignore_warning(message: int) -> None:
    """MuJoCo's ``void mju_user_warning(const char*)``, native: enters no Python (kernels call MuJoCo
    from compiled code) and drops the text; the count is in ``mjData.warning``."""


@functools.cache
def quiet_warnings() -> None:
    """Install :func:`_ignore_warning` as MuJoCo's warning handler, once per process.

    :func:`file_warnings` swaps its own handler in and this one back while a file is read.
    """
    mujoco.set_mju_user_warning(_ignore_warning.ctypes)


def pointers(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[int, int]:
    """``(mjModel*, mjData*)`` of the bindings' objects, as integers for a kernel's arguments.

    MuJoCo stepped from a kernel warns through ``mjData.warning`` alone from now on
    (:func:`quiet_warnings`).
    """
    quiet_warnings()
    return int(model._address), int(data._address)


def _call_model_data(typingctx: object, fn: types.Integer, m: types.Integer, d: types.Integer) -> tuple[object, object]:

    def codegen(context: Any, builder: ir.IRBuilder, signature: object, args: list[ir.Value]) -> ir.Value:
        ptr = cgutils.voidptr_t
        fnty = ir.FunctionType(ir.VoidType(), [ptr, ptr])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(f, [builder.inttoptr(args[1], ptr), builder.inttoptr(args[2], ptr)])
        return context.get_dummy_value()

    return types.void(types.intp, types.intp, types.intp), codegen


#: In a kernel: ``call_model_data(fn, m, d)`` calls ``void fn(const mjModel* m, mjData* d)``;
#: all three are integer addresses (:func:`address`, :func:`pointers`).
call_model_data = cast(Callable[[int, int, int], None], intrinsic(_call_model_data))
