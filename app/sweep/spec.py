"""Sweep files: ``sweeps/<name>.toml`` -> a checked :class:`SweepPlan` of points.

A sweep is a base session (name or path) and dotted fields to vary (format: ``sweeps/README.md``;
how a dotted field addresses the session, its gains and hand, and its scene: :mod:`app.sweep.fields`).
This module holds the sweep file's schema, the values of its points (grid or seeded random draws)
and the session each point runs.

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
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from app.config import Checked, Count, Range, from_dict, load_toml, named_toml, repeated
from app.controller.gains import ControllerGains
from app.device.spec import load_device
from app.errors import ConfigError, InvalidField
from app.session.spec import Session, SessionFile, resolve_session, resolve_session_path
from app.sweep.fields import Target, assign, broadcast, parse_target
from app.sweep.results import METRICS
from app.world.scene import ROOT_DIR, SceneFile, build_scene, resolve_scene_path

#: Where sweep files given by name (``frhc check probe_stiffness``) are found.
SWEEPS_DIR = ROOT_DIR / "sweeps"

#: Most points of one sweep (grid product or samples), checked on the count before any point is
#: built: the plan holds every point in memory (1e6 points of 3 fields: 0.44 GB peak, 2.5 s to
#: build; the former 1e7 took 2.1 GB and over 60 s). A million 0.1 s sessions is a day of cores.
MAX_POINTS = 1_000_000
#: Most fields varied in one sweep, and most values listed for one field.
MAX_FIELDS = 16
MAX_VALUES = 100_000


@dataclass(frozen=True)
class Vary(Checked):
    """One varied field: exactly one of ``values``, ``range`` or ``normal``.

    Attributes:
        field: Dotted field of the base session (``gains.k_t``, ``scene.objects.surface.stiffness``).
        values: The values themselves (any type the field takes). Grid: each, given once; random:
            drawn uniformly (a repeat weights a value).
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
        base: Base session: a name in ``sessions/`` or a path to a ``.toml`` (relative to the sweep file).
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
                assign(t, broadcast(t, v, gains), raw, scene_raw or {}, gains)
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


def resolve_sweep_path(name_or_path: str | Path) -> Path:
    """A sweep name (``"probe_stiffness"``, in ``sweeps/``) or a path."""
    return named_toml(name_or_path, SWEEPS_DIR)


def load_sweep(path: str | Path) -> SweepPlan:
    """Load and check a sweep file, by name (in ``sweeps/``) or path (see the module docstring
    for what is checked).

    Raises:
        ConfigError: naming the sweep file and the sweep field.
    """
    path = resolve_sweep_path(path)
    spec = from_dict(SweepFile, load_toml(path), path)
    # A path is the sweep file's neighbour, wherever the sweep is run from; a name is in sessions/.
    base_path = (path.parent / spec.base).absolute() if spec.base.endswith(".toml") else resolve_session_path(spec.base)
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
        # A random sweep may weight a value by giving it twice; a grid would run its points twice.
        again = repeated(v.values) if not spec.samples and v.values is not None else None
        if again is not None:
            raise ConfigError(path, f"vary[{i}].values", f"value {again[0] + 1} repeats an earlier one ({again[1]!r})")
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


__all__ = ["SweepFile", "SweepPlan", "Vary", "load_sweep"]
