"""Whole-loop contact stability with the default gains and the hand model (issue: stability)."""

from __future__ import annotations

import pytest

from app.session.run import run_session
from app.session.spec import load_session
from app.session.stability import press
from app.world.scene import available_scenes, load_scene

STIFFEST_SHIPPED = max(o.stiffness for name in available_scenes() for o in load_scene(name).objects)


@pytest.mark.parametrize("mode", ["rate", "pose"])
def test_pressing_the_stiffest_shipped_surface_settles(mode: str) -> None:
    r = press(STIFFEST_SHIPPED, mode)
    assert r.mean_force > 1.0  # really in contact, pushed by the operator
    assert r.settled, r


def test_rate_mode_force_is_set_by_the_accommodation_not_the_stiffness() -> None:
    """NTRFC: in steady contact F = v_cmd / K_acc whatever the surface stiffness (within 2 %)."""
    soft, stiff = press(STIFFEST_SHIPPED, "rate"), press(10 * STIFFEST_SHIPPED, "rate")
    assert stiff.settled
    assert stiff.mean_force == pytest.approx(soft.mean_force, rel=0.02)


def test_a_felt_stiffness_well_past_the_passivity_bound_oscillates() -> None:
    """The stability check can fail: K_T = 16 in pose mode makes the felt wall ~4x stiffer than 2b/T."""
    r = press(1e5, "pose", gains={"k_t": [16.0, 16.0, 16.0, 1.0, 1.0, 1.0]})
    assert not r.settled


def test_a_run_that_never_touches_is_not_settled() -> None:
    """Zero ripple around a zero mean is free space, not a settled contact."""
    s = run_session(load_session("probe_rate").with_changes(duration=0.8), out_dir=None).summary
    assert s["contact_fraction"] == 0.0
    assert s["settling"]["ripple_N"] == 0.0
    assert not s["settling"]["settled"]
