"""Whole-loop contact stability with the default gains and the hand model (issue: stability)."""

from __future__ import annotations

import pytest

from app.device.hand import HandParams
from app.session.run import run_session
from app.session.spec import load_session
from app.session.stability import grip_damping, passivity_bound, press
from app.world.scene import available_scenes, load_scene

STIFFEST_SHIPPED = max(o.stiffness for name in available_scenes() for o in load_scene(name).objects)


@pytest.mark.parametrize("mode", ["rate", "pose"])
def test_pressing_the_stiffest_shipped_surface_settles(mode: str) -> None:
    r = press(STIFFEST_SHIPPED, mode)
    assert r.mean_force > 1.0  # really in contact, pushed by the operator
    assert r.settled, r


def test_rate_mode_force_is_set_by_the_accommodation_not_the_stiffness() -> None:
    """NTRFC: in steady contact F = v_cmd / K_acc whatever the surface stiffness (within 4 %: the
    grip comes to rest anywhere in its joints' Coulomb friction band, ~0.2 mm of Delta X here, and
    v_cmd follows Delta X; a pose-mode wall ten times stiffer would push ten times harder)."""
    soft, stiff = press(STIFFEST_SHIPPED, "rate"), press(10 * STIFFEST_SHIPPED, "rate")
    assert stiff.settled
    assert stiff.mean_force == pytest.approx(soft.mean_force, rel=0.04)


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


def test_the_bound_counts_the_hand_damping_once_and_the_device_damping_at_the_grip() -> None:
    """``b`` is the hand's damping plus the joints' damping seen at the grip (positive, small on
    these backdrivable devices: under 2 N s/m)."""
    for device in ("kraft", "jpl", "freflex"):
        bare = grip_damping(device, HandParams(damping_trans=0.0))
        assert 0.0 < bare < 2.0
        assert grip_damping(device, HandParams(damping_trans=10.0)) == pytest.approx(bare + 10.0, abs=1e-9)
        assert passivity_bound(device, 2000.0, HandParams(damping_trans=0.0)) == pytest.approx(4000.0 * bare)
