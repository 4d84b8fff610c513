"""The parameter table of ``docs/experiment.md`` ("At a glance") holds the code's values.

Each row names where its value lives (``module:NAME``, ``module:NAME[key]``, ``file.toml:a.b``) and
gives the value; a row whose value differs from the code's, or whose place no longer exists, fails.
"""

from __future__ import annotations

import importlib
import re
import tomllib
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "experiment.md"
BEGIN, END = "<!-- parameter-table:begin -->", "<!-- parameter-table:end -->"
#: The columns of the table, in order.
COLUMNS = ["parameter", "class", "what it models", "value", "unit", "code", "source", "status"]


def table_rows(text: str) -> list[dict[str, str]]:
    """The rows of the marked table in ``text`` as {column: cell}, header and rule left out."""
    body = text.split(BEGIN, 1)[1].split(END, 1)[0]
    lines = [ln for ln in body.splitlines() if ln.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == COLUMNS, header
    return [dict(zip(COLUMNS, (c.strip() for c in ln.strip("|").split("|")), strict=True)) for ln in lines[2:]]


def _flat(value: Any) -> list[float]:
    """A number, or a (nested) sequence of numbers, as a flat list of floats."""
    if isinstance(value, (list, tuple)):
        return [x for v in value for x in _flat(v)]
    return [float(value)]


def locate(ref: str) -> list[float]:
    """The value at a place named as in the table's "code" column, flattened."""
    where, name = ref.split(":", 1)
    if where.endswith(".toml"):
        node: Any = tomllib.loads((ROOT / where).read_text())
        for key in name.split("."):
            node = node[int(key)] if isinstance(node, list) else node[key]
        return _flat(node)
    match = re.fullmatch(r"([\w.]+)(?:\[(\w+)\])?", name)
    assert match, ref
    node = importlib.import_module(where)
    for attr in match.group(1).split("."):
        node = getattr(node, attr)
    if match.group(2) is not None:
        node = node[match.group(2)]
    return _flat(node)


def mismatch(row: dict[str, str]) -> str | None:
    """Why ``row``'s value is not the code's, or None when it is.

    The value cell lists the numbers of every place in the code cell, in order; when all places
    hold the same numbers they may be given once."""
    refs = re.findall(r"`([^`]+)`", row["code"])
    if not refs:
        return f"{row['parameter']}: no place in the code named"
    got = [x for ref in refs for x in locate(ref)]
    want = [float(v) for v in row["value"].split(",")]
    if len(got) % len(want) == 0 and got == pytest.approx(want * (len(got) // len(want)), rel=1e-6):
        return None
    return f"{row['parameter']}: the table says {want}, the code holds {got} ({', '.join(refs)})"


def test_every_row_of_the_parameter_table_is_the_codes_value() -> None:
    rows = table_rows(DOC.read_text())
    assert len(rows) >= 30
    assert [m for m in map(mismatch, rows) if m] == []


def test_a_row_that_differs_from_the_code_is_caught() -> None:
    """Known answers of the checker: a changed value, a missing place, an unchanged row."""
    row = dict.fromkeys(COLUMNS, "")
    row.update(parameter="V_DB", value="0.002", code="`app.session.operator_kernel:V_DB`")
    assert mismatch(row) is None
    assert "holds [0.002]" in str(mismatch({**row, "value": "0.003"}))
    friction = {**row, "value": "0.47", "code": "`scenes/peg_in_hole.toml:objects.0.friction`"}
    assert mismatch(friction) is None
    assert mismatch({**friction, "value": "0.5"}) is not None
    both = {**row, "value": "1.51"}
    both["code"] = "`sessions/peg_ntrfc.toml:hand.stiffness_rot`, `sessions/peg_blind.toml:hand.stiffness_rot`"
    assert mismatch(both) is None
    with pytest.raises(AttributeError):
        mismatch({**row, "code": "`app.session.operator_kernel:NO_SUCH_NAME`"})
