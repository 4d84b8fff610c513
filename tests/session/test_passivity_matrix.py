"""The stability matrix's judge (``bench/passivity_matrix.py``): worse than plain, and the vanish
bar under both felt-stiffness measures, on rows with known answers."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest


def _matrix() -> ModuleType:
    path = Path(__file__).resolve().parents[2] / "bench" / "passivity_matrix.py"
    spec = importlib.util.spec_from_file_location("passivity_matrix", path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


pm = _matrix()


def _row(multiple: float, verdict: str, felt: float, design: float) -> dict[str, Any]:
    return {
        "set": "tuned",
        "device": "kraft",
        "variant": "enc12",
        "hand": "default 400/10",
        "multiple": multiple,
        "design": design,
        "verdict": verdict,
        "stable": verdict == "stable",
        "felt": felt,
    }


# Plain holds the 0.25x wall (design 5 kN/m) and the joints' friction makes the secant read 7 kN/m;
# the 1x wall oscillates.
PLAIN = {pm.key(r): r for r in (_row(0.25, "stable", 7000.0, 5000.0), _row(1.0, "oscillating", 15000.0, 20000.0))}


@pytest.mark.parametrize(
    ("felt", "measure", "vanished"),
    [
        (3000.0, "secant", True),  # below half of the 7 kN/m secant
        (3000.0, "capped", False),  # the reference is capped at the 5 kN/m design: 3000 >= 2500
        (2000.0, "capped", True),
        (math.nan, "secant", False),  # no felt stiffness (a released press) is not a vanished wall
    ],
)
def test_the_vanish_bar_takes_plain_largest_stable_wall_at_no_larger_multiple(
    felt: float, measure: str, vanished: bool
) -> None:
    pc = _row(1.0, "stable", felt, 20000.0)
    assert pm.judge(PLAIN, PLAIN, pm.key(pc), pc, measure) == (False, vanished)


def test_a_pushed_wall_vanishes_and_a_wall_plain_holds_that_pc_does_not_is_worse() -> None:
    pushed = _row(1.0, "pushed", math.nan, 20000.0)
    assert pm.judge(PLAIN, PLAIN, pm.key(pushed), pushed, "capped") == (False, True)
    lost = _row(0.25, "oscillating", 6000.0, 5000.0)
    assert pm.judge(PLAIN, PLAIN, pm.key(lost), lost, "secant") == (True, False)
    # Plain's 1x wall is not stable, so it is no reference: only the 0.25x one is.
    soft = _row(0.25, "stable", 3000.0, 5000.0)
    assert pm.judge(PLAIN, PLAIN, pm.key(soft), soft, "secant") == (False, True)


def test_the_sets_have_the_documented_sizes() -> None:
    sizes = {s: len(pm.points((s,))) for s in ("tuned", "held", "enc")}
    assert sizes == {"tuned": 444, "held": 216, "enc": 420}
