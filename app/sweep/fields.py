"""Where a dotted sweep field lands: its name resolved against the schemas, and a value written there.

A field addresses the session file (``duration``, ``servo_rate``, ``device``, ``seed``), its
``hand.*`` and ``gains.*`` tables (a six-vector gain takes a list, or one number for all six or
for an index or slice: ``gains.k_t[0:3]``), or the base session's scene (``scene.slave.kp_lin``,
``scene.objects.<name>.stiffness``: objects are addressed by name). Split from
:mod:`app.sweep.spec` (the sweep file and its points) because this half knows the session,
gain and scene schemas and nothing of sweeps.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from dataclasses import dataclass
from typing import Annotated, Any, Literal, get_args, get_origin, get_type_hints

from app.controller.gains import ControllerGains
from app.device.hand import HandParams
from app.session.spec import SessionFile
from app.world.scene import SceneFile

#: Session-file fields that take one scalar value (tables and arrays of tables cannot be varied).
SESSION_SCALARS = ("scene", "device", "duration", "mode", "servo_rate", "seed", "accommodation", "tremor", "time_scale")

_INDEX = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?:\[(?P<a>\d+)(?::(?P<b>\d+))?\])?$")


@dataclass(frozen=True)
class Target:
    """Where a dotted sweep field lands.

    Attributes:
        field: The field as written (the results column).
        table: ``"session"``, ``"hand"``, ``"gains"`` or ``"scene"``.
        keys: Keys inside that table; in a scene, ``objects`` is followed by an object's name.
        index: The components a number sets in a vector field, or None for the whole field.
        kind: Python type of one value: ``float``, ``int``, ``bool``, ``str`` or ``list`` (a vector).
    """

    field: str
    table: Literal["session", "hand", "gains", "scene"]
    keys: tuple[str, ...]
    index: slice | None
    kind: type


def _leaf(tp: Any) -> Any:
    """``tp`` without ``Annotated`` and ``| None``."""
    if get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    if get_origin(tp) in (typing.Union, types.UnionType):
        inner = [a for a in get_args(tp) if a is not type(None)]
        tp = inner[0] if len(inner) == 1 else tp
    if get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    return tp


def _kind(tp: Any, index: slice | None) -> type:
    if get_origin(tp) is tuple:
        return float if index is not None else list
    if get_origin(tp) is Literal:
        return str
    if tp in (float, int, bool, str):
        return typing.cast(type, tp)
    raise ValueError("is a table or an array of tables, not a value")


def _field_of(cls: type, name: str) -> Any:
    hints = get_type_hints(cls, include_extras=True)
    if name not in hints:
        raise ValueError(f"unknown field '{name}' of {cls.__name__} (known: {', '.join(sorted(hints))})")
    return hints[name]


def parse_target(text: str, scene: dict[str, Any]) -> Target:
    """Resolve dotted field ``text`` against the schemas and the base scene's object names.

    Raises:
        ValueError: with the reason (the caller names the sweep file and field).
    """
    parts = text.split(".")
    m = _INDEX.match(parts[-1])
    if not m or not all(parts):
        raise ValueError(f"not a dotted field name: '{text}'")
    parts[-1] = m["name"]
    index = None
    if m["a"] is not None:
        a = int(m["a"])
        index = slice(a, int(m["b"]) if m["b"] is not None else a + 1)
        if not index.stop > index.start:
            raise ValueError(f"empty slice in '{text}'")
    head = parts[0]
    if head in ("hand", "gains") and len(parts) == 2:
        cls: type = HandParams if head == "hand" else ControllerGains
        if parts[1] == "mode":
            raise ValueError("vary the session's 'mode', not 'gains.mode'")
        tp = _leaf(_field_of(cls, parts[1]))
        table: Literal["hand", "gains"] = "hand" if head == "hand" else "gains"
        return _target(text, table, tuple(parts[1:]), index, tp)
    if head == "scene" and len(parts) > 1:
        return _target(text, "scene", tuple(parts[1:]), index, _scene_type(parts[1:], scene))
    if len(parts) == 1 and head in SESSION_SCALARS:
        return _target(text, "session", (head,), index, _leaf(_field_of(SessionFile, head)))
    raise ValueError(
        f"unknown field '{text}' (vary {', '.join(SESSION_SCALARS)}, hand.<field>, gains.<field> or scene.<path>)"
    )


def _target(text: str, table: Any, keys: tuple[str, ...], index: slice | None, tp: Any) -> Target:
    if index is not None:
        n = len(get_args(tp)) if get_origin(tp) is tuple else 0
        if Ellipsis in get_args(tp) or index.stop > n:
            raise ValueError(f"'{text}': index out of a field of {n} values")
    return Target(text, table, keys, index, _kind(tp, index))


def _scene_type(keys: list[str], scene: dict[str, Any]) -> Any:
    """The type of scene field ``keys`` (``objects`` is followed by an object's name)."""
    tp: Any = SceneFile
    rest = list(keys)
    while rest:
        key = rest.pop(0)
        if not (dataclasses.is_dataclass(tp) and isinstance(tp, type)):
            raise ValueError(f"'{key}' is below a value, not a table")
        tp = _leaf(_field_of(tp, key))
        if key == "objects":
            names = [str(o.get("name")) for o in scene.get("objects", [])]
            if not rest or rest[0] not in names:
                raise ValueError(f"scene.objects needs an object's name (the base scene has: {', '.join(names)})")
            rest.pop(0)
            tp = get_args(tp)[0]
    return tp


def assign(target: Target, value: Any, session: dict[str, Any], scene: dict[str, Any], gains: dict[str, Any]) -> None:
    """Write ``value`` into the raw (parsed TOML) ``session`` or ``scene`` table.

    ``gains`` holds the device's default gains, the starting vector when an index is set.
    """
    if target.table == "session":
        session[target.keys[0]] = value
        return
    if target.table == "scene":
        node = scene
        keys = list(target.keys)
        while len(keys) > 1:
            key = keys.pop(0)
            if key == "objects":
                name = keys.pop(0)
                found = [o for o in node.get("objects", []) if o.get("name") == name]
                if not found:
                    raise ValueError(f"the scene has no object '{name}'")
                node = found[0]
            else:
                node = node.setdefault(key, {})
        parent, leaf = node, keys[0]
        start = parent.get(leaf)
    else:
        parent = session.setdefault(target.table, {})
        leaf = target.keys[0]
        start = parent.get(leaf, gains.get(leaf))
    if target.index is None:
        parent[leaf] = value
        return
    vector = list(start) if isinstance(start, list | tuple) else []
    if len(vector) < target.index.stop:
        raise ValueError(f"'{target.field}': the base has no {target.index.stop} values to index")
    vector[target.index] = [value] * (target.index.stop - target.index.start)
    parent[leaf] = vector


def broadcast(target: Target, value: Any, gains: dict[str, Any]) -> Any:
    """A number given for a whole vector gain sets all its components."""
    vector = target.table == "gains" and target.index is None and isinstance(gains.get(target.keys[0]), list | tuple)
    if vector and isinstance(value, int | float) and not isinstance(value, bool):
        return [value] * len(gains[target.keys[0]])
    return value
