"""Strict conversion of parsed TOML (plain dicts) into frozen configuration dataclasses.

Every scene, session and device file goes through :func:`from_dict`, so all of them
reject unknown fields, wrong types and wrong lengths the same way: one
:class:`~app.errors.ConfigError` naming the file and the dotted field path.

Physical ranges are stated once, beside the field, as ``typing.Annotated`` metadata::

    stiffness: Annotated[float, Range(0.0, 1e7, "N/m", lo_open=True)]
    objects: Annotated[tuple[ObjectSpec, ...], Count(0, 1000)]

A :class:`Range` on an array applies to every number in it (the error names ``field[i]``).
Every schema dataclass derives from :class:`Checked`, whose ``__post_init__`` enforces the
fixed tuple lengths, :class:`Count` and :class:`Range` of its fields and then calls the class's
own :meth:`Checked.validate` for cross-field rules, so a dataclass built in code (the web
panel's gains) is held to the same ranges as one read from a file. The file-format documents
(``scenes/README.md``, ``devices/README.md``, ``sessions/README.md``) show ``Range.text()``
for every field; a test checks they agree.

Hand-written rather than a schema library (pydantic v2, msgspec) because the messages must
name the file and the field in our words, on one line (``FILE: field 'a.b[2]': reason``),
ranges must also hold for objects built in code without a separate validation pass, and the
supported types are few: ``bool``, ``int``, ``float``, ``str``, ``Literal``, ``tuple[T, ...]``,
fixed ``tuple[A, B]``, ``list[T]``, ``dict[str, T]``, ``T | None``, ``Annotated[T, ...]`` and
nested dataclasses. Adapting a library's error objects to that line would be as much code.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import re
import tomllib
import types
import typing
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, get_args, get_origin, get_type_hints

import numpy as np

from app.errors import ConfigError, InvalidField

T = TypeVar("T")

#: Largest TOML file read (bytes): every shipped file is far smaller; this bounds parse time and memory.
MAX_FILE_BYTES = 4 * 1024 * 1024
#: Most parts of one dotted key (``a.b.c`` has 3). CPython's ``tomllib`` spends time quadratic in the
#: parts of a key (a 20,000-part key: 55 s, 1.6 GB); shipped files use at most 3.
MAX_KEY_PARTS = 32
#: Deepest nesting of arrays and inline tables; shipped files nest at most 3 deep.
MAX_NESTING = 32
#: Longest run of digits (and ``_``) in a number: Python refuses to convert an integer of over 4300
#: digits (a ``ValueError`` from inside ``tomllib``); shorter ones reach the field, which names them.
MAX_DIGITS = 1000

# One token of the structure scan: a string or comment (skipped whole, so nothing inside counts),
# a dot, an opening or closing bracket, a separator ending a key, or an over-long digit run.
_STRUCTURE = re.compile(
    r'(?P<skip>"""(?:[^\\]|\\.)*?"""|' + r"'''[\s\S]*?'''|" + r'"(?:[^"\\\n]|\\.)*"|' + r"'[^'\n]*'|#[^\n]*)"
    r"|(?P<dot>\.)|(?P<open>[\[{])|(?P<close>[\]}])|(?P<sep>[=,\n])"
    rf"|(?P<digits>[0-9_]{{{MAX_DIGITS + 1},}})"
)


def fmt_number(v: float) -> str:
    """A number as the documents write it: ``1e7``, ``0.5``, ``-1e-6``, ``65535``."""
    if isinstance(v, int) and not isinstance(v, bool):
        digits = str(abs(v))
        return str(v) if len(digits) <= 15 else f"{'-' if v < 0 else ''}~1e{len(digits) - 1}"
    text = f"{v:g}"
    return text.replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


@dataclass(frozen=True)
class Range:
    """The physical range of a number field, or of every number in an array field.

    Attributes:
        lo, hi: Bounds, inclusive unless ``lo_open``/``hi_open``. Values must also be finite.
        unit: Unit shown in messages and documents (empty for a pure number).
        lo_open, hi_open: Exclude the bound.
        inf_ok: ``+inf`` is accepted too (it means "none", e.g. no workspace wall).
        name_array: For an array, name the whole field and give the element's index in the
            reason (``field 'k_d': k_d[1] must be ...``) rather than naming ``k_d[1]``. Used where
            the array is one quantity per axis or joint (gains, motors).
    """

    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False
    hi_open: bool = False
    inf_ok: bool = False
    name_array: bool = False

    def text(self) -> str:
        """``(0, 1e7] N/m``: the form used in messages and in the file-format documents."""
        lo = "(" if self.lo_open else "["
        hi = ")" if self.hi_open else "]"
        unit = f" {self.unit}" if self.unit else ""
        extra = " or inf" if self.inf_ok else ""
        return f"{lo}{fmt_number(self.lo)}, {fmt_number(self.hi)}{hi}{unit}{extra}"

    def check(self, name: str, value: Any) -> None:
        """Raise :class:`InvalidField` naming ``name`` (or ``name[i]...``) for a value outside the range."""
        if isinstance(value, tuple | list):
            for i, v in enumerate(value):
                try:
                    self.check(f"{name}[{i}]", v)
                except InvalidField as exc:
                    if not self.name_array:
                        raise
                    raise InvalidField(name, f"{exc.field} {exc.reason}") from None
            return
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InvalidField(name, f"expected a number, got {type(value).__name__}")
        if isinstance(value, float) and math.isnan(value):
            raise InvalidField(name, "must not be NaN")
        if value == math.inf and self.inf_ok:
            return
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        if not (above and below):
            sign = "positive, " if self.lo == 0 and self.lo_open else "non-negative, " if self.lo == 0 else ""
            finite = "finite, " if isinstance(value, float) and math.isinf(value) else ""
            raise InvalidField(name, f"must be {finite}{sign}in {self.text()}, got {fmt_number(value)}")


@dataclass(frozen=True)
class Count:
    """Bounds on the number of entries of an array field (a resource limit or a shape rule)."""

    lo: int
    hi: int

    def text(self) -> str:
        return f"{self.lo}..{self.hi} entries"

    def check(self, name: str, value: Any) -> None:
        if value is not None and not self.lo <= len(value) <= self.hi:
            raise InvalidField(name, f"expected {self.text()}, got {len(value)}")


@dataclass(frozen=True)
class OneOf:
    """The choices of a ``Literal`` field, checked on construction too (not only when a file is
    read): a value that reaches a dataclass from the page or a call is held to the same choices."""

    choices: tuple[Any, ...]

    def check(self, name: str, value: Any) -> None:
        if value not in self.choices:
            raise InvalidField(name, f"must be one of {', '.join(repr(c) for c in self.choices)}, got {value!r}")


Rule = Range | Count | OneOf


class Checked:
    """Base of every schema dataclass: shapes, counts and ranges are checked on construction.

    Subclasses put cross-field rules in :meth:`validate`, which runs after the per-field checks
    and raises :class:`InvalidField` naming the field (relative to the dataclass).
    """

    def __post_init__(self) -> None:
        for name, length, rules in field_rules(type(self)):
            value = getattr(self, name)
            if value is None:
                continue
            if length is not None and (not isinstance(value, tuple | list) or len(value) != length):
                got = len(value) if isinstance(value, tuple | list) else type(value).__name__
                raise InvalidField(name, f"expected {length} values, got {got}")
            for rule in rules:
                rule.check(name, value)
        self.validate()

    def validate(self) -> None:
        """Cross-field rules (override); the per-field checks have passed when this runs."""


#: One field's checks: its name, its fixed tuple length (or None) and its rules.
FieldRules = tuple[str, int | None, tuple[Rule, ...]]
_RULES: dict[type, tuple[FieldRules, ...]] = {}


def field_rules(cls: type) -> tuple[FieldRules, ...]:
    """The checks of every field of dataclass ``cls`` that has any (computed once per class)."""
    cached = _RULES.get(cls)
    if cached is None:
        cached = _RULES[cls] = _field_rules(cls)
    return cached


def _field_rules(cls: type) -> tuple[FieldRules, ...]:
    hints = get_type_hints(cls, include_extras=True)
    out = []
    for f in dataclasses.fields(cls):
        tp = _strip_optional(hints[f.name])
        rules: tuple[Rule, ...] = ()
        if get_origin(tp) is Annotated:
            tp, *meta = get_args(tp)
            rules = tuple(m for m in meta if isinstance(m, Range | Count))
            tp = _strip_optional(tp)
        if get_origin(tp) is Literal:
            rules = (*rules, OneOf(get_args(tp)))
        args = get_args(tp)
        length = len(args) if get_origin(tp) is tuple and Ellipsis not in args else None
        if rules or length is not None:
            out.append((f.name, length, rules))
    return tuple(out)


def _strip_optional(tp: Any) -> Any:
    if get_origin(tp) in (typing.Union, types.UnionType):
        inner = [a for a in get_args(tp) if a is not type(None)]
        if len(inner) == 1:
            return inner[0]
    return tp


def field_range(cls: type, name: str) -> Range | Count | None:
    """The :class:`Range` (or else :class:`Count`) of field ``name`` of ``cls``, for documents and tests."""
    for fname, _, rules in field_rules(cls):
        bounds = [r for r in rules if isinstance(r, Range | Count)]
        if fname == name and bounds:
            ranges = [r for r in bounds if isinstance(r, Range)]
            return ranges[0] if ranges else bounds[0]
    return None


def repeated(values: Sequence[Any]) -> tuple[int, Any] | None:
    """The first value given again among ``values``, as ``(index of the repeat, value)``, or None.

    For lists that are an axis of a grid or a study, where a repeat is a typo that runs the same
    point twice and tabulates it twice. Numbers compare as numbers (``1`` and ``1.0`` are the same),
    lists and tables element by element.
    """
    seen = set()
    for i, value in enumerate(values):
        key = _comparable(value)
        if key in seen:
            return i, value
        seen.add(key)
    return None


def _comparable(value: Any) -> Any:
    """``value`` made hashable, with every number a float (bools stay bools)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, list | tuple):
        return tuple(_comparable(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, _comparable(v)) for k, v in value.items()))
    return value


def identity_digest(*parts: object) -> str:
    """A short digest of what a loaded file makes (``"sha256:"`` + 16 hex digits), for a log to
    tell the file it names from the one it was run with.

    Args:
        parts: Each a NumPy array (digested as contiguous float64 bytes) or a JSON-able value or
            dataclass (digested as canonical JSON: sorted keys, arrays as lists).
    """
    digest = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            digest.update(np.ascontiguousarray(part, dtype=np.float64).tobytes())
            continue
        fields = dataclasses.asdict(part) if dataclasses.is_dataclass(part) and not isinstance(part, type) else part
        digest.update(json.dumps(fields, sort_keys=True, default=lambda o: np.asarray(o).tolist()).encode())
    return f"sha256:{digest.hexdigest()[:16]}"


def require_file(path: Path, source: str | Path, field: str, missing: str) -> Path:
    """``path`` if it names a regular file; else a :class:`ConfigError` on ``field`` of ``source``.

    The one check of every file a file refers to (a mesh, an MJCF, a calibration) and of a named
    file itself: ``missing`` is the reason when there is no such file; something else there (a
    folder) is named; any other failure of the look-up (a name longer than the file system allows,
    a permission) gives the system's reason.
    """
    shown = str(path) if len(str(path)) <= 120 else f"{str(path)[:100]}...({len(str(path))} characters)"
    try:
        kind = path.stat().st_mode & 0o170000
    except (FileNotFoundError, NotADirectoryError):
        raise ConfigError(source, field, missing) from None
    except OSError as exc:
        raise ConfigError(source, field, f"cannot read {shown}: {exc.strerror}") from None
    if kind == 0o100000:  # S_IFREG
        return path
    raise ConfigError(
        source, field, f"{shown} is {'a folder, not a file' if kind == 0o040000 else 'not a regular file'}"
    )


def named_toml(name_or_path: str | Path, folder: Path) -> Path:
    """A file given by name (``name`` is ``folder/name.toml``) or by path (a ``.toml`` name, or
    anything that exists): how sessions and sweeps are found."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    return folder / f"{name_or_path}.toml"


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file (UTF-8, with or without a byte-order mark), turning I/O, size, encoding and
    syntax errors into :class:`ConfigError`."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(p, "<file>", "file not found") from None
    except IsADirectoryError:
        raise ConfigError(p, "<file>", "is a directory, not a file") from None
    except OSError as exc:
        raise ConfigError(p, "<file>", f"cannot read: {exc.strerror}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(p, "<file>", f"file larger than {MAX_FILE_BYTES // 1024 // 1024} MiB")
    try:
        # A leading byte-order mark (Windows editors write one) is skipped: tomllib refuses it as an
        # invalid statement at line 1, column 1, a character nobody sees.
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        body = exc.object  # the bytes after the mark: where exc.start counts from
        line = body[: exc.start].count(b"\n") + 1
        raise ConfigError(p, "<file>", f"not UTF-8 text (byte 0x{body[exc.start]:02x} on line {line})") from None
    check_structure(text, p)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(p, "<file>", f"not valid TOML: {exc}") from None
    except (RecursionError, ValueError) as exc:
        # Structure the scan let through (it bounds, it does not parse): still one line.
        raise ConfigError(p, "<file>", f"not valid TOML: {exc}") from None


def check_structure(text: str, source: str | Path) -> None:
    """Refuse TOML whose structure would make ``tomllib`` slow, or fail outside its own errors.

    One linear regular-expression pass (strings and comments skipped whole) bounds the parts of
    every dotted key (:data:`MAX_KEY_PARTS`), the nesting of arrays and inline tables
    (:data:`MAX_NESTING`) and the digits of every number (:data:`MAX_DIGITS`) before the parser
    sees the text. A key's dots are those between two separators (``=``, ``,``, a newline or a
    bracket); a value holds at most one (``1.5``, ``07:32:00.5``). Text the scan misreads is
    invalid TOML, which ``tomllib`` refuses itself.

    Raises:
        ConfigError: Naming the file and the line of the first excess.
    """
    dots = depth = 0
    for m in _STRUCTURE.finditer(text):
        kind = m.lastgroup
        if kind == "dot":
            dots += 1
            if dots < MAX_KEY_PARTS:
                continue
            reason = f"a dotted key of more than {MAX_KEY_PARTS} parts"
        elif kind == "open":
            dots = 0
            depth += 1
            if depth <= MAX_NESTING:
                continue
            reason = f"arrays or tables nested more than {MAX_NESTING} deep"
        elif kind == "digits":
            reason = f"a number of more than {MAX_DIGITS} digits"
        else:
            if kind == "close":
                depth -= 1
            if kind != "skip":
                dots = 0
            continue
        line = text.count("\n", 0, m.start()) + 1
        raise ConfigError(source, "<file>", f"not valid TOML: {reason} (line {line})")


@contextmanager
def deferred_warnings() -> Iterator[None]:
    """Hold back warnings raised inside the block; re-issue them only if the block succeeds.

    Loading a file may warn (a mesh that is not watertight) before a later field fails; the
    user must then see the one-line error alone, not warnings about a file that was refused.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)


def from_dict(cls: type[T], data: Any, source: str | Path, path: str = "") -> T:
    """Build dataclass ``cls`` from ``data``, strictly.

    Args:
        cls: A dataclass type whose fields carry type hints.
        data: The parsed mapping.
        source: File name used in error messages.
        path: Dotted prefix of ``data`` inside the file, for nested calls.

    Raises:
        ConfigError: Unknown field, missing required field, a value of the wrong type or shape,
            or one outside its :class:`Range`.
    """
    return typing.cast(T, _convert(cls, data, source, path))


def _field_path(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """``cls``'s resolved field types: resolving string annotations is a third of building a
    session, and a sweep builds one per point."""
    return get_type_hints(cls)


def _convert(tp: Any, value: Any, source: str | Path, path: str) -> Any:
    where = path or "<root>"
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if not isinstance(value, dict):
            raise ConfigError(source, where, f"expected a table, got {type(value).__name__}")
        hints = _hints(tp)
        fields = {f.name: f for f in dataclasses.fields(tp) if f.init}
        unknown = sorted(set(value) - set(fields))
        if unknown:
            raise ConfigError(
                source,
                _field_path(path, unknown[0]),
                f"unknown field (known: {', '.join(sorted(fields))})",
            )
        kwargs = {}
        for name, f in fields.items():
            if name in value:
                kwargs[name] = _convert(hints[name], value[name], source, _field_path(path, name))
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(source, _field_path(path, name), "required field is missing")
        try:
            return tp(**kwargs)
        except ConfigError:
            raise
        except InvalidField as exc:
            raise ConfigError(source, _field_path(path, exc.field), exc.reason) from None
        except (ValueError, TypeError) as exc:
            raise ConfigError(source, where, str(exc)) from None

    origin = get_origin(tp)
    args = get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _convert(inner[0], value, source, path)
        raise TypeError(f"unsupported union {tp}")
    if origin is Literal:
        if value not in args:
            choices = ", ".join(repr(a) for a in args)
            raise ConfigError(source, where, f"must be one of {choices}, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(source, where, f"expected an array, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, source, f"{path}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(source, where, f"expected {len(args)} values, got {len(value)}")
        return tuple(_convert(a, v, source, f"{path}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True)))
    if origin is list:
        if not isinstance(value, list):
            raise ConfigError(source, where, f"expected an array, got {type(value).__name__}")
        return [_convert(args[0], v, source, f"{path}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(source, where, f"expected a table, got {type(value).__name__}")
        return {k: _convert(args[1], v, source, _field_path(path, k)) for k, v in value.items()}
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(source, where, f"expected a number, got {type(value).__name__}")
        try:
            number = float(value)
        except OverflowError:
            raise ConfigError(source, where, f"number too large for a float ({fmt_number(value)})") from None
        if math.isnan(number):
            raise ConfigError(source, where, "must not be NaN")
        return number
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(source, where, f"expected an integer, got {type(value).__name__}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(source, where, f"expected true or false, got {type(value).__name__}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(source, where, f"expected a string, got {type(value).__name__}")
        return value
    if tp is Any:
        return value
    raise TypeError(f"unsupported config type {tp!r} at {where}")
