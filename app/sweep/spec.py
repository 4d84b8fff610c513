"""Sweep files: ``sweeps/<name>.toml`` -> a checked :class:`SweepPlan` of points.

A sweep is a base session (name or path) and dotted fields to vary (format: ``sweeps/README.md``).
A field addresses the session file (``duration``, ``servo_rate``, ``device``, ``seed``), its
``hand.*`` and ``gains.*`` tables (a six-vector gain takes a list, or one number for all six or
for an index or slice: ``gains.k_t[0:3]``), or the base session's scene (``scene.slave.kp_lin``,
``scene.objects.<name>.stiffness``: objects are addressed by name).

Everything that can be checked without running is checked when the file is loaded: the schema
and ranges of the sweep file itself, every field name, and every value written in the file
(each ``values`` entry and both ends of a ``range``), by applying it to the base session and
checking the result against the session, gain and scene schemas with their ranges. A refusal
is one :class:`~app.errors.ConfigError` naming the sweep file and the sweep field
(``vary[1].values[2]``). Values drawn from a ``normal`` distribution can only be checked when
drawn: an out-of-range draw fails that point alone, with the same one-line message.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import hashlib
import itertools
import json
import math
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin, get_type_hints

import numpy as np

from app.config import Checked, Count, Range, from_dict, load_toml
from app.controller.gains import ControllerGains
from app.device.hand import HandParams
from app.device.spec import load_device
from app.errors import ConfigError, InvalidField
from app.session.spec import Session, SessionFile, resolve_session, resolve_session_path
from app.world.scene import SceneFile, build_scene, resolve_scene_path

#: Most points of one sweep (grid product or samples): a resource limit on the plan held in memory.
MAX_POINTS = 10_000_000
#: Most fields varied in one sweep, and most values listed for one field.
MAX_FIELDS = 16
MAX_VALUES = 100_000

#: Session-file fields that take one scalar value (tables and arrays of tables cannot be varied).
SESSION_SCALARS = ("scene", "device", "duration", "mode", "servo_rate", "seed", "accommodation", "tremor", "time_scale")

_INDEX = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?:\[(?P<a>\d+)(?::(?P<b>\d+))?\])?$")


@dataclass(frozen=True)
class Vary(Checked):
    """One varied field: exactly one of ``values``, ``range`` or ``normal``.

    Attributes:
        field: Dotted field of the base session (``gains.k_t``, ``scene.objects.surface.stiffness``).
        values: The values themselves (any type the field takes). Grid: each; random: drawn uniformly.
        range: ``[lo, hi]`` (the field's unit). Grid: ``steps`` values from lo to hi inclusive;
            random: drawn uniformly (log-uniformly with ``log``).
        normal: ``[mean, standard deviation]`` (the field's unit), drawn; a grid draws ``steps`` values.
        steps: Number of grid values of a ``range`` or ``normal``.
        log: Geometric spacing (grid) or log-uniform draws (random) over ``range``; needs lo > 0.
    """

    field: str
    values: Annotated[tuple[Any, ...] | None, Count(1, MAX_VALUES)] = None
    range: Annotated[tuple[float, float] | None, Range(-1e12, 1e12)] = None
    normal: Annotated[tuple[float, float] | None, Range(-1e12, 1e12)] = None
    steps: Annotated[int | None, Range(1, MAX_VALUES)] = None
    log: bool = False

    def validate(self) -> None:
        given = [k for k in ("values", "range", "normal") if getattr(self, k) is not None]
        if len(given) != 1:
            raise InvalidField("values", f"give exactly one of values, range, normal (got {given or 'none'})")
        if self.range is not None:
            lo, hi = self.range
            if not lo < hi:
                raise InvalidField("range", f"need lo < hi, got [{lo:g}, {hi:g}] (an empty range)")
            if self.log and not lo > 0.0:
                raise InvalidField("range", f"a log range needs lo > 0, got {lo:g}")
        if self.normal is not None and not self.normal[1] > 0.0:
            raise InvalidField("normal", f"the standard deviation must be positive, got {self.normal[1]:g}")
        if self.log and self.range is None:
            raise InvalidField("log", "log applies to a range only")
        if self.steps is not None and self.values is not None:
            raise InvalidField("steps", "steps applies to a range or normal, not to values")


@dataclass(frozen=True)
class SweepFile(Checked):
    """The schema of a sweep file (``sweeps/README.md``).

    Attributes:
        base: Base session: a name in ``sessions/`` or a path (relative to the working directory).
        vary: The varied fields.
        samples: 0 for the full grid (the product of every field's values); N > 0 for N random
            points, each field drawn independently.
        seed: Seed of every random draw (the points are the same on every run).
        metric: Summary metric plotted by default (a column of the results).
    """

    base: str
    vary: Annotated[tuple[Vary, ...], Count(1, MAX_FIELDS)]
    samples: Annotated[int, Range(0, MAX_POINTS)] = 0
    seed: Annotated[int, Range(0, 2**32 - 1)] = 0
    metric: str = "work_eq13"


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


def _broadcast(target: Target, value: Any, gains: dict[str, Any]) -> Any:
    """A number given for a whole vector gain sets all its components."""
    vector = target.table == "gains" and target.index is None and isinstance(gains.get(target.keys[0]), list | tuple)
    if vector and isinstance(value, int | float) and not isinstance(value, bool):
        return [value] * len(gains[target.keys[0]])
    return value


@dataclass(frozen=True)
class SweepPlan:
    """A checked sweep: what every point is built from (pickles small, for workers).

    Attributes:
        path: The sweep file.
        spec: Its parsed content.
        base_path: The base session file.
        session: The base session file's parsed TOML.
        targets: One per varied field, in file order.
        fingerprint: Hash of the sweep's content and base session: an output directory holds one sweep.
    """

    path: Path
    spec: SweepFile
    base_path: Path
    session: dict[str, Any]
    targets: tuple[Target, ...]
    fingerprint: str

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(t.field for t in self.targets)

    def n_points(self) -> int:
        """Points of the sweep: the grid product, or ``samples``."""
        if self.spec.samples:
            return self.spec.samples
        return math.prod(len(self._grid_values(i)) for i in range(len(self.targets)))

    def _grid_values(self, i: int) -> list[Any]:
        v = self.spec.vary[i]
        if v.values is not None:
            return list(v.values)
        n = v.steps or 1
        if v.range is not None:
            lo, hi = v.range
            xs = np.geomspace(lo, hi, n) if v.log else np.linspace(lo, hi, n)
        else:
            mean, std = v.normal or (0.0, 1.0)
            xs = self._rng(i).normal(mean, std, n)
        return [self._cast(i, float(x)) for x in xs]

    def _rng(self, i: int) -> np.random.Generator:
        return np.random.default_rng([self.spec.seed, i])

    def _cast(self, i: int, x: float) -> Any:
        return round(x) if self.targets[i].kind is int else x

    def points(self) -> list[tuple[Any, ...]]:
        """Every point's values, in the order of :attr:`fields` (deterministic in the seed)."""
        if not self.spec.samples:
            grids = [self._grid_values(i) for i in range(len(self.targets))]
            return list(itertools.product(*grids))
        n = self.spec.samples
        columns = []
        for i, v in enumerate(self.spec.vary):
            rng = self._rng(i)
            if v.values is not None:
                picks = rng.integers(0, len(v.values), n)
                columns.append([v.values[int(k)] for k in picks])
                continue
            if v.range is not None:
                lo, hi = v.range
                xs = np.exp(rng.uniform(math.log(lo), math.log(hi), n)) if v.log else rng.uniform(lo, hi, n)
            else:
                mean, std = v.normal or (0.0, 1.0)
                xs = rng.normal(mean, std, n)
            columns.append([self._cast(i, float(x)) for x in xs])
        return list(zip(*columns, strict=True))

    def _parse_at(self, values: tuple[Any, ...]) -> tuple[SessionFile, SceneFile | None]:
        """The session file and (when a scene field varies) the scene file with ``values`` applied,
        checked against their schemas and ranges (and the gains against theirs) without building."""
        source = self.path
        raw = copy.deepcopy(self.session)
        pairs = list(zip(self.targets, values, strict=True))
        for t, v in pairs:
            if t.table == "session":
                assign(t, v, raw, {}, {})
        data = from_dict(SessionFile, raw, source)
        gains = _device_gains(data.device, source)
        scene_raw = load_toml(resolve_scene_path(data.scene)) if any(t.table == "scene" for t in self.targets) else None
        for t, v in pairs:
            if t.table == "session":
                continue
            try:
                assign(t, _broadcast(t, v, gains), raw, scene_raw or {}, gains)
            except ValueError as exc:
                raise ConfigError(source, t.field, str(exc)) from None
        data = from_dict(SessionFile, raw, source)
        from_dict(ControllerGains, {**gains, **data.gains, "mode": data.mode}, source, "gains")
        scene = from_dict(SceneFile, scene_raw, source, "scene") if scene_raw is not None else None
        return data, scene

    def session_at(self, values: tuple[Any, ...]) -> Session:
        """The base session with ``values`` applied (one per field), checked and resolved.

        Raises:
            ConfigError: naming the sweep file and the session, gain or scene field a value breaks.
        """
        data, scene_spec = self._parse_at(values)
        session = dataclasses.replace(resolve_session(data, self.path), path=self.base_path)
        if scene_spec is None:
            return session
        return dataclasses.replace(session, scene=build_scene(scene_spec, self.path))


@functools.lru_cache(maxsize=16)
def _device_gains(device: str, source: Path) -> dict[str, Any]:
    """The default gains of ``device`` (a worker loads each device once)."""
    try:
        return dataclasses.asdict(load_device(device).data.gains)
    except ConfigError as exc:
        raise ConfigError(source, "device", f"cannot load '{device}': {exc.reason}") from None


def load_sweep(path: str | Path) -> SweepPlan:
    """Load and check a sweep file (see the module docstring for what is checked).

    Raises:
        ConfigError: naming the sweep file and the sweep field.
    """
    path = Path(path)
    spec = from_dict(SweepFile, load_toml(path), path)
    base_path = resolve_session_path(spec.base)
    try:
        raw = load_toml(base_path)
        base = resolve_session(from_dict(SessionFile, raw, base_path), base_path)
    except ConfigError as exc:
        raise ConfigError(path, "base", f"session '{spec.base}': {exc}") from None
    scene_raw = load_toml(resolve_scene_path(base.data.scene))
    targets = []
    for i, v in enumerate(spec.vary):
        try:
            targets.append(parse_target(v.field, scene_raw))
        except ValueError as exc:
            raise ConfigError(path, f"vary[{i}].field", str(exc)) from None
    if len({t.field for t in targets}) != len(targets):
        raise ConfigError(path, "vary", "a field is varied twice")
    n_grid = 1
    for i, v in enumerate(spec.vary):
        if not spec.samples and v.normal is not None and v.steps is None:
            raise ConfigError(path, f"vary[{i}].steps", "a grid needs the number of values drawn from normal")
        if not spec.samples and v.range is not None and v.steps is None:
            raise ConfigError(path, f"vary[{i}].steps", "a grid needs the number of values over the range")
        n_grid *= len(v.values) if v.values is not None else (v.steps or 1)
    if not spec.samples and n_grid > MAX_POINTS:
        raise ConfigError(path, "vary", f"the grid has {n_grid} points (at most {MAX_POINTS})")
    fingerprint = hashlib.sha256(
        json.dumps([dataclasses.asdict(spec), raw], sort_keys=True, default=str).encode()
    ).hexdigest()[:16]
    plan = SweepPlan(path, spec, base_path, raw, tuple(targets), fingerprint)
    _check_values(plan)
    if spec.metric not in METRICS:
        raise ConfigError(path, "metric", f"unknown metric '{spec.metric}' (known: {', '.join(METRICS)})")
    return plan


def _check_values(plan: SweepPlan) -> None:
    """Apply every value written in the file to the base session alone and check the result."""
    base = tuple(_base_value(plan, t) for t in plan.targets)
    for i, v in enumerate(plan.spec.vary):
        if v.values is not None:
            written = [(f"vary[{i}].values[{j}]", x) for j, x in enumerate(v.values)]
        elif v.range is not None:
            written = [(f"vary[{i}].range", plan._cast(i, x)) for x in v.range]
        else:
            continue
        for name, x in written:
            values = (*base[:i], x, *base[i + 1 :])
            try:
                plan._parse_at(values)
            except ConfigError as exc:
                raise ConfigError(plan.path, name, f"{v.field} = {x!r}: field '{exc.field}': {exc.reason}") from None
            except ValueError as exc:
                raise ConfigError(plan.path, name, f"{v.field} = {x!r}: {exc}") from None


def _base_value(plan: SweepPlan, target: Target) -> Any:
    """A value of ``target`` that leaves the base session as it is: its first written value when
    the base value cannot be read back (so each checked value is checked against the base alone)."""
    i = plan.targets.index(target)
    v = plan.spec.vary[i]
    first = v.values[0] if v.values is not None else plan._cast(i, v.range[0] if v.range else v.normal[0])  # type: ignore[index]
    if target.table == "session":
        return plan.session.get(target.keys[0], first)
    return first


#: Summary metrics of a point: the results' columns after the varied fields, with their types.
METRICS: dict[str, type] = {
    "work_eq13": float,
    "peak_contact_force_N": float,
    "peak_contact_moment_Nm": float,
    "rms_contact_force_N": float,
    "contact_fraction": float,
    "task_completed": bool,
    "task_time_s": float,
    "fault_ticks": int,
    "saturated_ticks": int,
    "watchdog_trips": int,
    "simulated_s": float,
}


def metrics_row(summary: dict[str, Any]) -> dict[str, Any]:
    """The :data:`METRICS` of a session summary (``task_*`` None without a task)."""
    task = summary.get("task") or {}
    return {
        "work_eq13": summary["work_eq13"],
        "peak_contact_force_N": summary["peak_contact_force_N"],
        "peak_contact_moment_Nm": summary["peak_contact_moment_Nm"],
        "rms_contact_force_N": summary["rms_contact_force_N"],
        "contact_fraction": summary["contact_fraction"],
        "task_completed": task.get("completed"),
        "task_time_s": task.get("time_s"),
        "fault_ticks": sum(summary["faults"].values()),
        "saturated_ticks": summary["saturated_ticks"],
        "watchdog_trips": summary["watchdog_trips"],
        "simulated_s": summary["simulated_s"],
    }


__all__ = ["METRICS", "SweepFile", "SweepPlan", "Target", "Vary", "load_sweep", "metrics_row"]
