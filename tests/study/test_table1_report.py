"""The Table I report: medians, quartiles, the work split and the ratio, on rows with known answers."""

from __future__ import annotations

from typing import Any

import pytest

from app.study.experiment import BLIND, NTRFC, _summary, _table


def _row(op: str, cond: str, axial: float, other: float, peak: float, completed: bool = True) -> dict[str, Any]:
    return {
        "operator": op,
        "condition": cond,
        "status": "ok",
        "completed": completed,
        "work_eq13": axial + other,
        "work_axial_J": axial,
        "work_other_J": other,
        "peak_contact_force_N": peak,
        "completion_time_s": 2.0,
    }


ROWS = [
    _row("A", NTRFC, 0.3, 0.1, 5.0),
    _row("A", BLIND, 1.5, 0.5, 20.0),  # ratio 5
    _row("B", NTRFC, 0.1, 0.1, 3.0),
    _row("B", BLIND, 0.3, 0.1, 10.0),  # ratio 2
    _row("C", NTRFC, 0.5, 0.5, 4.0),
    _row("C", BLIND, 7.0, 1.0, 30.0),  # ratio 8
    _row("D", NTRFC, 1.0, 0.0, 4.0),
    _row("D", BLIND, 0.0, 0.0, 0.0, completed=False),  # failed: in no median, no ratio
]


def test_the_population_summary_has_known_medians_quartiles_and_split() -> None:
    s = _summary(ROWS)
    ntrfc, blind = s[NTRFC], s[BLIND]
    assert (ntrfc["completed"], ntrfc["runs"], blind["completed"]) == (4, 4, 3)
    # NTRFC work 0.4, 0.2, 1.0, 1.0: median 0.7, quartiles (numpy's linear) 0.35 and 1.0.
    assert ntrfc["work_J"] == pytest.approx({"median": 0.7, "p25": 0.35, "p75": 1.0})
    assert blind["work_J"]["median"] == pytest.approx(2.0)
    # Share along the insertion of all the work: (0.3 + 0.1 + 0.5 + 1.0) / 2.6.
    assert ntrfc["axial_share"] == pytest.approx(1.9 / 2.6)
    assert blind["work_axial_J"]["median"] == pytest.approx(1.5)
    assert blind["peak_force_N"]["median"] == pytest.approx(20.0)
    r = s["ratio_blind_over_ntrfc"]
    assert r["operators"] == 3
    assert (r["median"], r["p25"], r["p75"]) == pytest.approx((5.0, 3.5, 6.5))
    assert r["iqr_factor"] == pytest.approx(6.5 / 3.5)
    assert r["fraction_above_1"] == 1.0
    assert r["paper"] == pytest.approx([1.66 / 0.59, 2.55 / 0.61, 1.51 / 0.42])


def test_the_table_lists_every_operator_with_the_split() -> None:
    text = _table(ROWS, _summary(ROWS))
    lines = {line.split()[0]: line for line in text.split("Per operator")[1].splitlines()[3:]}
    assert set(lines) == {"A", "B", "C", "D"}
    assert "0.4 J (    0.3 +     0.1)" in lines["A"]
    assert lines["A"].endswith(" 5")
    assert "failed" in lines["D"]
    assert lines["D"].endswith(" -")
    assert "73 % of all work along the insertion" in text  # NTRFC: 1.9 / 2.6
    assert "a factor 1.86" in text
