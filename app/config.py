"""Strict conversion of parsed TOML (plain dicts) into frozen configuration dataclasses.

Every scene, session and device file goes through :func:`from_dict`, so all of them
reject unknown fields, wrong types and wrong lengths the same way: one
:class:`~app.errors.ConfigError` naming the file and the dotted field path.

Hand-written rather than a schema library because the messages must name the file
and field in our words, and the supported types are few: ``bool``, ``int``,
``float``, ``str``, ``Literal``, ``tuple[T, ...]``, fixed ``tuple[A, B]``,
``list[T]``, ``dict[str, T]``, ``T | None`` and nested dataclasses.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin, get_type_hints

from app.errors import ConfigError, InvalidField

T = TypeVar("T")


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning I/O and syntax errors into :class:`ConfigError`."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(p, "<file>", "file not found") from None
    except OSError as exc:
        raise ConfigError(p, "<file>", f"cannot read: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(p, "<file>", f"not valid TOML: {exc}") from None


def from_dict(cls: type[T], data: Any, source: str | Path, path: str = "") -> T:
    """Build dataclass ``cls`` from ``data``, strictly.

    Args:
        cls: A dataclass type whose fields carry type hints.
        data: The parsed mapping.
        source: File name used in error messages.
        path: Dotted prefix of ``data`` inside the file, for nested calls.

    Raises:
        ConfigError: Unknown field, missing required field, or a value of the wrong type.
    """
    return typing.cast(T, _convert(cls, data, source, path))


def _field_path(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _convert(tp: Any, value: Any, source: str | Path, path: str) -> Any:
    where = path or "<root>"
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if not isinstance(value, dict):
            raise ConfigError(source, where, f"expected a table, got {type(value).__name__}")
        hints = get_type_hints(tp)
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
        if math.isnan(value):
            raise ConfigError(source, where, "must not be NaN")
        return float(value)
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
