"""Whole-loop contact stability with the default gains and the hand model (issue: stability)."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from app.controller.passivity import PassivitySettings
from app.device.hand import HandParams
from app.device.spec import load_device
from app.device.variants import DeviceVariant, write_variant
from app.session.metrics import SETTLE_WINDOW
from app.session.run import run_session
from app.session.spec import Waypoint, load_session
from app.session.stability import (
    DRIFT_TOLERANCE,
    POSE_SECONDS,
    PUSH_DEPTHS,
    PressResult,
    design_stiffness,
    device_bound,
    grip_damping,
    passivity_bound,
    press,
    press_session,
    probe_scene_with_stiffness,
    push_depths,
    released_saturated,
)
from app.session.tick import TickRecord
from app.world.scene import available_scenes, load_scene

ENC20 = DeviceVariant("enc20", encoder_bits=20)

STIFFEST_SHIPPED = max(o.stiffness for name in available_scenes() for o in load_scene(name).objects)


@pytest.mark.parametrize("mode", ["rate", "pose"])
def test_pressing_the_stiffest_shipped_surface_settles(mode: str) -> None:
    r = press(STIFFEST_SHIPPED, mode)
    assert r.mean_force > 1.0  # really in contact, pushed by the operator
    assert r.settled, r


def test_rate_mode_force_is_set_by_the_accommodation_not_the_stiffness() -> None:
    """NTRFC: in steady contact F = v_cmd / K_acc whatever the surface stiffness (within 4 %: the
    grip comes to rest anywhere in its joints' Coulomb friction band, ~0.2 mm of Delta X here, and
    v_cmd follows Delta X; a pose-mode wall ten times stiffer would push ten times harder). The
    stiff wall is the stiffest shipped one (the peg block's cited 100 N/mm). At ten times that,
    1e6 N/m, the press rings in a limit cycle (17-23 N) with the contact's 225 Hz mode resolved
    (2 to 10 slave substeps): the accommodation term reaches the slave's velocity reference a
    tick late, through its PD damping, against that lightly damped mode, a loop of the model
    rather than of its integration. One implicit substep settles it only by damping the
    unresolved mode numerically, so it is not asserted here."""
    soft, stiff = press(STIFFEST_SHIPPED / 10, "rate"), press(STIFFEST_SHIPPED, "rate")
    assert stiff.settled
    assert stiff.mean_force == pytest.approx(soft.mean_force, rel=0.04)


def test_a_wall_well_past_the_passivity_bound_is_not_stable() -> None:
    """The stability check can fail: K_T = 16 in pose mode makes the felt wall ~4x stiffer than 2b/T.
    The loop bounces hard enough to trip the velocity brake and ends with the slave at its force
    limit: whether or not the force is steady there, it is not a wall."""
    r = press(1e5, "pose", gains={"k_t": [16.0, 16.0, 16.0, 1.0, 1.0, 1.0]})
    assert not r.stable
    assert r.felt_stiffness < 0.1 * passivity_bound("kraft")


def test_a_further_observer_sees_the_ticks_the_press_is_judged_on() -> None:
    """An observer passed to :func:`press` watches the same run: the contact force it records over
    the judged window (the last :data:`SETTLE_WINDOW` of a :data:`POSE_SECONDS` press) has the
    press's mean and peak-to-peak."""

    class Forces:
        def __init__(self) -> None:
            self.rows: list[tuple[float, float]] = []

        def on_tick(self, tick: TickRecord) -> None:
            self.rows.append((tick.time, float(np.linalg.norm(tick.contact_wrench_MRF[0:3]))))

    seen = Forces()
    r = press(1e5, "pose", observers=(seen,))
    judged = np.array([f for t, f in seen.rows if t >= POSE_SECONDS - SETTLE_WINDOW])
    assert len(judged) == round(SETTLE_WINDOW / 1e-3)
    assert r.mean_force > 1.0
    assert judged.mean() == pytest.approx(r.mean_force, rel=1e-12)
    assert np.ptp(judged) == pytest.approx(r.ripple, rel=1e-12, abs=1e-12)


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


@pytest.mark.parametrize("device", ["kraft", "jpl", "freflex"])
def test_as_shipped_at_3x_the_bound_plain_oscillates_and_the_pc_settles_a_softer_wall(device: str) -> None:
    """The shipped 13/14-bit encoders, pose mode, a wall designed at 3x 2b/T: plain rendering
    oscillates on every device (ripple kraft 34.7, jpl 7.4, freflex 11.4 N). PO/PC as shipped (the
    swing charge with the stateless passive law, issue 26) settles all three: ripple under 5 % of
    the mean force (main's crossed edge alone rang at 1.7 / 7.0 / 7.6 N), the slave not pushed
    through. The wall it settles is softer than plain's best: felt 4.0 / 2.6 / 9.2 kN/m, 0.19 /
    0.13 / 0.39 of the bound, where plain holds half the bound stably; so on the Kraft and the JPL
    this point is below issue 26's no-vanish bar (half of plain's best, a quarter of the bound).
    Asserted: the wall is still there, above a tenth of the bound."""
    bound = passivity_bound(device)
    gains = {"k_t": [3.0 * bound / design_stiffness(1.0, device=device)] * 3 + [1.0] * 3}
    plain = press(1e5, "pose", device=device, gains=gains)
    assert not plain.stable
    pc = press(1e5, "pose", device=device, gains=gains, passivity=PassivitySettings(enabled=True))
    assert pc.settled, (pc, plain)  # ripple under 5 % of the mean force
    assert not pc.pushed_through
    assert pc.felt_stiffness > 0.1 * bound, pc


def test_at_3x_the_passivity_bound_plain_oscillates_and_the_pc_settles_at_the_bound(tmp_path: Path) -> None:
    """Kraft with 20-bit encoders (so quantisation does not bind first), pose mode, a wall designed
    at 3x 2b/T: plain rendering oscillates; with PO/PC it settles, felt about as stiff as the bound
    (the PC removes exactly the energy the sampled wall would add, no more)."""
    device = str(write_variant("kraft", ENC20, tmp_path))
    bound = passivity_bound(device)
    k_t = 3.0 * bound / design_stiffness(1.0, device=device)
    gains = {"k_t": [k_t] * 3 + [1.0] * 3}
    plain = press(1e5, "pose", device=device, gains=gains)
    assert not plain.stable
    pc = press(1e5, "pose", device=device, gains=gains, passivity=PassivitySettings(enabled=True))
    assert pc.stable, pc
    assert pc.mean_force > 1.0
    assert 0.8 * bound < pc.felt_stiffness < 1.3 * bound


def test_a_saturated_plateau_is_not_a_stable_wall() -> None:
    """K_T 64 on the probe surface: the motors hold their limit, which settles like a constant
    force and renders no stiffness (zwidth and the bench must not count it)."""
    r = press(1e5, "pose", gains={"k_t": [64.0] * 3 + [1.0] * 3, "k_d": [16.0] * 3 + [0.02] * 3})
    assert r.settled  # the criterion alone would call it stable
    assert r.saturated
    assert not r.stable
    assert r.verdict == "saturated"


def test_where_plain_holds_the_wall_the_pc_leaves_it_alone(tmp_path: Path) -> None:
    """Kraft as shipped, a wall at half the bound: plain rendering holds it, and PO/PC renders the
    same wall (the touch's ~3 mJ comes out of the reserve). An 11-bit Kraft, a 250/2 hand, a wall
    at a quarter of its bound: plain holds it, and so does PO/PC at the same felt stiffness within
    20 % (with a 20 mJ reserve alone, less than its motors exchange over three 11-bit counts, the
    PC cut the still wall to 0.37x of plain's)."""
    k_t = 0.5 * passivity_bound("kraft") / design_stiffness(1.0)
    gains = {"k_t": [k_t] * 3 + [1.0] * 3}
    plain = press(1e5, "pose", gains=gains)
    assert plain.stable
    pc = press(1e5, "pose", gains=gains, passivity=PassivitySettings(enabled=True))
    assert pc.stable
    assert pc.felt_stiffness == pytest.approx(plain.felt_stiffness, rel=0.05)
    device = str(write_variant("kraft", DeviceVariant("enc11", encoder_bits=11), tmp_path))
    hand = HandParams(stiffness_trans=250.0, damping_trans=2.0)
    k_t = 0.25 * passivity_bound(device, hand=hand) / design_stiffness(1.0, device=device)
    gains = {"k_t": [k_t] * 3 + [1.0] * 3}
    plain = press(1e5, "pose", device=device, gains=gains, hand=hand)
    assert plain.stable
    pc = press(1e5, "pose", device=device, gains=gains, hand=hand, passivity=PassivitySettings(enabled=True))
    assert pc.stable
    assert pc.felt_stiffness == pytest.approx(plain.felt_stiffness, rel=0.2)


def test_a_wall_the_hand_pushed_through_is_not_stable(tmp_path: Path) -> None:
    """Freflex with 20-bit encoders at 3x the bound, a strict master-side PO/PC predicting steps of one 20-bit count:
    so short a step buys so little force per joule that once the touch has drawn the reserve the
    energy bound holds the force down, and the hand pushes the slave to its 40 N limit. The force
    is steady there, but that is the slave's limit, not a wall."""
    device = str(write_variant("freflex", ENC20, tmp_path))
    bound = passivity_bound(device)
    k_t = 3.0 * bound / design_stiffness(1.0, device=device)
    # A master-side bound alone: no hold, half the friction credited, none of the device's
    # dissipation observed (the layer before issue 26's third pass).
    settings = PassivitySettings(
        enabled=True,
        step=2.0 * math.pi / 2**20,
        step_counts=1,
        hold_slave=False,
        friction_credit=0.5,
        observe_device=False,
    )
    r = press(1e5, "pose", device=device, gains={"k_t": [k_t] * 3 + [1.0] * 3}, passivity=settings)
    assert r.settled
    assert r.pushed_through
    assert r.felt_stiffness < 0.05 * bound
    assert not r.stable
    assert r.saturated_share == 0.0  # the motors had the capacity: the PC let the wall go
    assert r.verdict == "pushed"


def test_the_device_only_bound_is_the_joints_damping_alone() -> None:
    """With the hand let go ``b`` is the joints' damping at the grip only: 0.40 / 0.17 / 1.88 N s/m,
    a bound of ~803 / 343 / 3,755 N/m on kraft / jpl / freflex, against ~20-24 kN/m with the
    default hand's 10 N s/m."""
    for device, expected in (("kraft", 803.0), ("jpl", 343.0), ("freflex", 3755.0)):
        assert device_bound(device) == pytest.approx(expected, rel=0.01)
        assert device_bound(device) == pytest.approx(passivity_bound(device, hand=HandParams(damping_trans=0.0)))


def test_a_released_press_is_judged_after_the_hand_lets_go(tmp_path: Path) -> None:
    """Pose mode, the hand holds the first push and lets go: on the Kraft at a quarter of the
    with-hand bound the rendering pushes the grip back off the surface and everything comes to
    rest; without the joints' Coulomb friction the same wall keeps bouncing the released tool
    (ripple of several newtons against the ~5 N the hand held)."""
    k_t = 0.25 * passivity_bound("kraft") / design_stiffness(1.0)
    gains = {"k_t": [k_t] * 3 + [1.0] * 3}
    held = press(1e5, "pose", gains=gains, released=True)
    assert held.stable
    assert math.isnan(held.felt_stiffness)
    assert held.summary["settling"]["ripple_N"] < 0.05
    no_friction = str(write_variant("kraft", DeviceVariant("nofric", friction=False), tmp_path))
    bouncing = press(1e5, "pose", device=no_friction, gains=gains, released=True)
    assert bouncing.ripple > 1.0
    assert not bouncing.stable


def test_a_released_tool_resting_at_zero_force_is_not_saturated_by_a_few_saturated_ticks() -> None:
    """The rule, with known answers: pressed (>= 0.1 N) any saturated tick counts; resting at 0 N
    only motors at their limit for half the window or more (the device driven, not resting).
    And a press: the shipped Kraft at 2x its with-hand bound, plain, let go: the tool comes to
    rest off the surface (0 N, no ripple) with the motors saturated on a few ticks of the judged
    window while it settled (share below 0.02): stable, where the any-tick rule said "saturated"."""
    assert released_saturated(2.0, 0.005)
    assert not released_saturated(2.0, 0.0)
    assert not released_saturated(0.0, 0.005)
    assert not released_saturated(0.05, 0.49)
    assert released_saturated(0.0, 0.83)
    k_t = 2.0 * passivity_bound("kraft") / design_stiffness(1.0)
    r = press(1e5, "pose", gains={"k_t": [k_t] * 3 + [1.0] * 3}, released=True)
    assert r.mean_force < 0.1, r
    assert r.ripple < 0.01, r
    assert 0.0 < r.saturated_share < 0.02, r.saturated_share
    assert not r.saturated
    # Not saturated; but not at rest either: the wall threw the grip off and it still creeps up
    # (3.7 mm since the release, ~0.5 mm over the judged window), so the honest verdict is "drifting".
    assert r.grip_drift > 3.0 * DRIFT_TOLERANCE, r.grip_drift
    assert r.verdict == "drifting"


def test_a_grip_not_at_rest_over_the_judged_window_is_not_a_stable_wall() -> None:
    """The verdict from the grip's travel, with known answers: a steady contact force with the
    grip still moving out of the surface is "drifting", on into it "pushed" (the wall gave way;
    "saturated" if the motors spent the window at their limit), within the tolerance "stable";
    out of contact (0 N) a grip moving either way is "drifting" (it is not on the wall)."""

    def judged(drift: float, share: float = 0.0, force: float = 3.0) -> PressResult:
        return PressResult(force, 0.01, True, 5e3, False, False, {}, share, drift)

    assert judged(0.5 * DRIFT_TOLERANCE).verdict == "stable"
    assert judged(-0.5 * DRIFT_TOLERANCE).stable
    assert judged(math.nan).stable  # rate mode records no grip travel
    assert judged(2.0 * DRIFT_TOLERANCE).verdict == "drifting"
    assert not judged(2.0 * DRIFT_TOLERANCE).stable
    assert judged(-2.0 * DRIFT_TOLERANCE).verdict == "pushed"
    assert not judged(-2.0 * DRIFT_TOLERANCE).stable
    assert judged(-2.0 * DRIFT_TOLERANCE, share=0.8).verdict == "saturated"
    assert judged(-2.0 * DRIFT_TOLERANCE, force=0.0).verdict == "drifting"
    assert judged(0.5 * DRIFT_TOLERANCE, force=0.0).verdict == "stable"


def test_a_released_grip_thrown_off_the_wall_is_drifting_not_resting(tmp_path: Path) -> None:
    """A 10-bit Kraft at its with-hand bound, PO/PC, the hand let go: the force over the judged
    window is 0 N with no ripple, which the force alone read as a tool resting on the wall; the
    grip's travel shows it was thrown off and still coasts up (~50 mm since the release, ~20 mm
    within the window). A held press at rest moves less than the tolerance."""
    device = str(write_variant("kraft", DeviceVariant("enc10", encoder_bits=10), tmp_path))
    k_t = passivity_bound(device) / design_stiffness(1.0, device=device)
    gains = {"k_t": [k_t] * 3 + [1.0] * 3}
    r = press(1e5, "pose", device=device, gains=gains, released=True, passivity=PassivitySettings(enabled=True))
    # The old judge: stable.
    assert r.settled
    assert not r.saturated
    assert not r.pushed_through
    assert r.mean_force < 0.1
    assert r.grip_drift > 0.01, r.grip_drift
    assert r.release_drift > 0.03, r.release_drift
    assert r.verdict == "drifting"
    held = press(1e5, "pose", gains={"k_t": [0.25 * passivity_bound("kraft") / design_stiffness(1.0)] * 3 + [1.0] * 3})
    assert abs(held.grip_drift) < 0.1 * DRIFT_TOLERANCE
    assert math.isnan(held.release_drift)
    assert held.stable


def test_a_stiff_hand_pushes_to_the_gap_plus_its_force_over_its_stiffness(tmp_path: Path) -> None:
    """The probe's grip travels 1 cm of deadband plus the tip's 2.5 cm over K_P = 2 to the surface
    (2.25 cm). The default hand keeps the fixed depths; a 1000 N/m hand pushes the default hand's
    3 and 9 N (2.55, 3.15 cm); at K_T 0.12 at most 25 % and 75 % of the slave's 40 N limit times
    K_T (1.2 and 3.6 N: 2.37, 2.61 cm). A softer hand keeps the fixed depths."""
    scene = probe_scene_with_stiffness(1e5, 3.0, tmp_path)

    def depths(k: float, k_t: float) -> tuple[float, float]:
        hand = HandParams(stiffness_trans=k)
        session = load_session("probe_rate").with_changes(
            scene=str(scene), mode="pose", hand=hand, gains={"k_t": [k_t] * 3 + [1.0] * 3}
        )
        return push_depths(session)

    assert depths(400.0, 1.0) == pytest.approx(PUSH_DEPTHS)
    assert depths(1000.0, 1.0) == pytest.approx((0.0255, 0.0315))
    assert depths(1000.0, 0.12) == pytest.approx((0.0237, 0.0261))
    assert depths(100.0, 0.12) == pytest.approx(PUSH_DEPTHS)


def test_a_stiff_hand_press_measures_the_wall_not_the_slave_limit() -> None:
    """Kraft, a 1000 N/m hand, a wall at a quarter of the bound: plain rendering holds it with the
    slave well inside its 40 N limit (at the fixed depths this hand pushed the slave to it)."""
    hand = HandParams(stiffness_trans=1000.0, damping_trans=10.0)
    k_t = 0.25 * passivity_bound("kraft", hand=hand) / design_stiffness(1.0)
    r = press(1e5, "pose", gains={"k_t": [k_t] * 3 + [1.0] * 3}, hand=hand)
    assert r.stable, r
    assert 2.0 < r.mean_force < 20.0


def test_on_a_coarse_encoder_the_hold_keeps_the_hand_from_pushing_the_slave_in(tmp_path: Path) -> None:
    """Kraft with 10-bit encoders, the default hand, a wall at the bound: with the PC as a
    master-side force bound alone the hand pushes the slave in to 34 N of its 40 N limit (a felt
    0.6 kN/m; before the crossed-edge observer, to the limit itself); with the hold on the
    slave's command the slave stays well inside it and the press settles. The bound alone is the
    PC without its passive law and swing charge; with them (as shipped) the cut force is itself a
    spring the hand cannot sink into, and the slave stays inside the limit without the hold too
    (17.7 N)."""
    device = str(write_variant("kraft", DeviceVariant("enc10", encoder_bits=10), tmp_path))
    k_t = passivity_bound(device) / design_stiffness(1.0, device=device)
    gains = {"k_t": [k_t] * 3 + [1.0] * 3}
    bound_alone = PassivitySettings(enabled=True, hold_slave=False, passive_law=False, swing_charge=False)
    alone = press(1e5, "pose", device=device, gains=gains, passivity=bound_alone)
    assert alone.mean_force > 0.75 * 40.0, alone
    law = press(1e5, "pose", device=device, gains=gains, passivity=PassivitySettings(enabled=True, hold_slave=False))
    assert law.mean_force < 0.5 * 40.0, law
    held = press(1e5, "pose", device=device, gains=gains, passivity=PassivitySettings(enabled=True))
    assert held.stable, held
    assert held.mean_force < 0.5 * 40.0


class _GripHeight:
    """Tick observer: the grip's true height (m, z of {0}) every tick."""

    def __init__(self) -> None:
        self.z: list[float] = []

    def on_tick(self, tick: TickRecord) -> None:
        self.z.append(float(tick.reading.T_0_G[2, 3]))


def test_a_heavy_link_variant_is_a_heavier_device_its_controller_compensates(tmp_path: Path) -> None:
    """Issue 26's heavy-link rows failed for every renderer because the variant made the Kraft's
    model wrong, not heavier: its links twice the MJCF's mass left ~6 N of weight uncompensated,
    and the grip sank 23 mm onto the surface before the hand pushed. As a heavier device its file
    describes, the hand holding the grip still for a second keeps it within a millimetre of where
    it started, and a soft hand's press at a quarter of the with-hand bound holds its wall."""
    heavy = str(write_variant("kraft", DeviceVariant("heavy2", mass_scale=2.0), tmp_path))
    height = _GripHeight()
    scene = probe_scene_with_stiffness(1e5, 3.0, tmp_path)
    still = press_session(scene, "pose", seconds=1.0, device=heavy, waypoints=(Waypoint(0.3),))
    run_session(still, out_dir=None, plots=False, observers=(height,))
    assert np.ptp(height.z) < 1e-3
    soft = HandParams(stiffness_trans=100.0, damping_trans=1.0)
    k_t = 0.25 * passivity_bound(heavy, hand=soft) / design_stiffness(1.0, device=heavy)
    held = press(1e5, "pose", device=heavy, gains={"k_t": [k_t] * 3 + [1.0] * 3}, hand=soft)
    assert held.stable
    assert not held.pushed_through


def test_a_device_whose_motors_cannot_carry_the_push_reads_saturated_not_pushed(tmp_path: Path) -> None:
    """A Kraft with links twice as heavy: at home, holding those links up and rendering the default
    hand's ~9 N second push asks the shoulder joint for more than its motor has (the model's
    gravity torque plus ``J^T f``: 1.15x its limit; 0.81x as shipped). The uniform saturation then
    scales gravity compensation down with the wall, the device sags and the hand pushes the slave
    to its limit: the bench must call that the device's capacity, not an unstable wall."""
    heavy = str(write_variant("kraft", DeviceVariant("heavy2", mass_scale=2.0), tmp_path))
    needed = []
    for name in ("kraft", heavy):
        device = load_device(name)
        model, data = device.model, mujoco.MjData(device.model)
        data.qpos[list(device.qpos_ids)] = device.data.home
        mujoco.mj_forward(model, data)
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, device.data.grip_site)
        J = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, J, None, site)
        dofs = list(device.dof_ids)
        torque = data.qfrc_bias[dofs] + J[:, dofs].T @ np.array([0.0, 0.0, 9.0])  # the wall pushes the grip up
        limit = np.asarray(device.data.motors.gear_ratio) * np.asarray(device.data.motors.torque_limit)
        needed.append(float(np.max(np.abs(torque) / limit)))
    assert needed[0] < 1.0 < needed[1]
    k_t = passivity_bound(heavy) / design_stiffness(1.0, device=heavy)
    r = press(1e5, "pose", device=heavy, gains={"k_t": [k_t] * 3 + [1.0] * 3})
    assert r.pushed_through
    assert r.saturated_share > 0.9
    assert r.verdict == "saturated"
