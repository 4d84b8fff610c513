"""The declarative field rules of :mod:`app.config`: Range, Count, Checked and deferred warnings."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import pytest

from app.config import Count, Range, deferred_warnings, fmt_number, load_toml
from app.controller.gains import ControllerGains
from app.errors import ConfigError, InvalidField
from app.world.scene_file import CapsuleSpec, Pose, SphereSpec, ToolSpec


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (1e7, "1e7"),
        (1e-6, "1e-6"),
        (0.5, "0.5"),
        (65535, "65535"),
        (100000.0, "100000"),
        (2**70, "~1e21"),
        (-1.0, "-1"),
    ],
)
def test_numbers_are_written_as_the_documents_write_them(value: float, text: str) -> None:
    assert fmt_number(value) == text


def test_range_text_and_messages() -> None:
    r = Range(0.0, 1e7, "N/m", lo_open=True)
    assert r.text() == "(0, 1e7] N/m"
    r.check("k", 1e7)
    for bad, reason in [
        (0.0, "positive"),
        (1e300, "in (0, 1e7] N/m, got 1e300"),
        (math.inf, "finite"),
        (math.nan, "NaN"),
    ]:
        with pytest.raises(InvalidField, match="k") as info:
            r.check("k", bad)
        assert reason in info.value.reason
    with pytest.raises(InvalidField) as info:
        r.check("k", (1.0, 2.0, -3.0))
    assert info.value.field == "k[2]"
    with pytest.raises(InvalidField) as info:
        Range(0.0, 1.0, name_array=True).check("g", (0.5, 2.0))
    assert (info.value.field, info.value.reason) == ("g", "g[1] must be non-negative, in [0, 1], got 2")
    Range(0.0, 1.0, inf_ok=True).check("w", math.inf)
    with pytest.raises(InvalidField, match="entries"):
        Count(1, 2).check("joints", ())


def test_objects_built_in_code_are_held_to_the_same_ranges() -> None:
    with pytest.raises(InvalidField) as info:
        ControllerGains(k_t=(math.inf, 1.0, 1.0, 1.0, 1.0, 1.0))
    assert info.value.field == "k_t"
    with pytest.raises(InvalidField, match="expected 6 values"):
        ControllerGains(k_v=(1.0, 1.0))  # type: ignore[arg-type]
    capsule = CapsuleSpec((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.01, spacing=1e-5)
    with pytest.raises(InvalidField) as info:
        ToolSpec(1.0, (1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0), Pose(), capsules=(capsule,))
    assert info.value.field == "capsules[0].spacing"
    with pytest.raises(InvalidField) as info:
        SphereSpec((0.0, 0.0, math.nan), 0.01)
    assert info.value.field == "center[2]"


def warn_then_fail() -> None:
    with deferred_warnings():
        warnings.warn("held back", UserWarning, stacklevel=1)
        raise RuntimeError


def test_warnings_are_issued_only_if_the_block_succeeds() -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(RuntimeError):
            warn_then_fail()
        assert caught == []
        with deferred_warnings():
            warnings.warn("passed on", UserWarning, stacklevel=1)
            assert caught == []
        assert [str(w.message) for w in caught] == ["passed on"]


def test_a_folder_is_not_a_toml_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="directory"):
        load_toml(tmp_path)
