"""The controller's behaviour: switches, commands, reference/indexing, wrench path, faults."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from app.config import from_dict
from app.controller.frhc import FRHCController
from app.controller.gains import ControllerGains
from app.controller.safety import SafetyLimits
from app.controller.types import Fault, FTReading, SlaveModel, Switches
from app.device.spec import DeviceSpec, load_device
from app.errors import ConfigError
from app.spatial import body_rate_from_euler, tmat_difference, wrench_transform, zyx_to_matrix

DT = 1e-3

#: The paper's controller as printed (ticks jump; each checks its equations): no ramp, no brake.
PAPER = SafetyLimits.paper_only()


def home(spec: DeviceSpec) -> np.ndarray:
    return np.array(spec.data.home)


def contact_reading(slave: SlaveModel) -> FTReading:
    """A reading of payload weight (sensor level, R_w_S = I) plus a 3 N contact force along +z."""
    ft = FTReading()
    ft.wrench_S[0:3] = slave.payload_mass * slave.gravity_w + np.array([0.0, 0.0, 3.0])
    ft.wrench_S[3:6] = np.cross(slave.payload_com_S, slave.payload_mass * slave.gravity_w)
    return ft


@pytest.mark.parametrize(("deadman", "reflection"), list(itertools.product([False, True], repeat=2)))
def test_switch_truth_table(controller: FRHCController, kraft: DeviceSpec, slave: SlaveModel, deadman, reflection):
    """Sec 4.1: commands need the deadman; task wrench, RTC and damping need deadman and reflection;
    gravity compensation is always on."""
    q = home(kraft)
    controller.step(q, Switches(deadman=deadman, reflection=reflection), contact_reading(slave), DT)
    q2 = q + np.array([0.05, 0.08, -0.06, 0.2, 0.1, -0.2])
    out = controller.step(q2, Switches(deadman=deadman, reflection=reflection), contact_reading(slave), DT)
    assert out.command.active == deadman
    assert (np.abs(out.command.twist).max() > 0) == deadman
    assert (np.abs(out.tau_T).max() > 0) == (deadman and reflection)
    assert (np.abs(out.G_F_R).max() > 0) == (deadman and reflection)
    assert (np.abs(out.G_F_D).max() > 0) == (deadman and reflection)
    assert np.abs(out.tau_G).max() > 0.1
    assert out.faults == Fault.NONE


def test_reference_switch_sets_g0_at_any_time(controller: FRHCController, kraft: DeviceSpec) -> None:
    q = home(kraft) + 0.1
    out = controller.step(q, Switches(deadman=True), FTReading(), DT)
    assert np.abs(out.delta_x).max() > 0.01
    out = controller.step(q, Switches(deadman=True, reference=True), FTReading(), DT)
    np.testing.assert_allclose(out.T_0_G0, out.T_0_G)
    np.testing.assert_allclose(out.delta_x, 0.0, atol=1e-12)
    # Holding the button does not re-reference every tick: it is the press (rising edge) that counts.
    out = controller.step(q + 0.05, Switches(deadman=True, reference=True), FTReading(), DT)
    assert np.abs(out.delta_x).max() > 0.01


def test_rate_command_applies_kv_deadband_and_eq5(controller: FRHCController, kraft: DeviceSpec) -> None:
    q0 = home(kraft)
    controller.reset(q0)
    T_0_G0 = controller.out.T_0_G.copy()
    q = q0 + np.array([0.1, 0.1, -0.1, 0.2, 0.15, 0.3])
    out = controller.step(q, Switches(deadman=True), FTReading(), DT)
    g = kraft.data.gains
    dx = tmat_difference(T_0_G0, out.T_0_G[0:3, 0:3], out.T_0_G[0:3, 3], np.empty(6))
    dxc = np.sign(dx) * np.maximum(np.abs(dx) - np.array(g.deadband), 0.0)
    np.testing.assert_allclose(out.delta_x_cmd, dxc, atol=1e-12)
    np.testing.assert_allclose(out.command.twist[0:3], np.array(g.k_v[0:3]) * dxc[0:3], atol=1e-12)
    w = np.array(body_rate_from_euler(dxc[3], dxc[4], (dxc[3], dxc[4], dxc[5])))
    np.testing.assert_allclose(out.command.twist[3:6], np.array(g.k_v[3:6]) * w, atol=1e-12)


def test_inside_the_deadband_nothing_is_commanded(controller: FRHCController, kraft: DeviceSpec) -> None:
    out = controller.step(home(kraft) + 1e-3, Switches(deadman=True), FTReading(), DT)
    assert np.abs(out.delta_x).max() > 0
    np.testing.assert_array_equal(out.command.twist, 0.0)


def test_rate_rotation_tapers_to_zero_near_gimbal_lock(kraft: DeviceSpec, slave: SlaveModel) -> None:
    """Near cos(beta) = 0 the angles are ill-defined: the rotational command fades out, continuously."""
    ctrl = FRHCController(kraft, kraft.data.gains.with_changes(deadband=(0.0,) * 6), slave, safety=PAPER)
    T_0_G0 = ctrl.out.T_0_G0
    weights = []
    for beta_deg in np.linspace(60, 89.9, 300):
        # Put G0 so that the grip is rotated by beta about G0's y axis (reference set by hand).
        T_0_G0[:] = ctrl.out.T_0_G
        T_0_G0[0:3, 0:3] = ctrl.kin.R_0_G @ zyx_to_matrix(0.2, math.radians(beta_deg), 0.1).T
        out = ctrl.step(home(kraft), Switches(deadman=True), FTReading(), DT)
        assert np.isfinite(out.command.twist).all()
        weights.append(out.rot_weight)
        if beta_deg >= 85.0:
            np.testing.assert_array_equal(out.command.twist[3:6], 0.0)
    assert weights[0] == 1.0
    assert np.all(np.diff(weights) <= 0)
    assert np.max(np.abs(np.diff(weights))) < 0.02  # no jump: a fade over the 75-85 degree band


def test_pose_mode_needs_unit_rotational_gains() -> None:
    with pytest.raises(ConfigError, match=r"gains.toml: field 'k_p': rotational pose gains"):
        from_dict(ControllerGains, {"k_p": [2.0, 2.0, 2.0, 1.0, 2.0, 1.0]}, "gains.toml")


def test_pose_command_and_indexing_never_jump(kraft: DeviceSpec, slave: SlaveModel) -> None:
    gains = kraft.data.gains.with_changes(mode="pose", deadband=(0.0,) * 6)
    ctrl = FRHCController(kraft, gains, slave, safety=PAPER)
    q0 = home(kraft)
    step = np.array([0.05, 0.05, -0.05, 0.1, 0.1, 0.1])
    out = ctrl.step(q0, Switches(deadman=True), FTReading(), DT)
    np.testing.assert_allclose(out.command.T_w_MRF, slave.T_w_MRF_home, atol=1e-12)
    out = ctrl.step(q0 + step, Switches(deadman=True), FTReading(), DT)
    dx = out.delta_x
    T = out.command.T_w_MRF
    np.testing.assert_allclose(T[0:3, 3], slave.T_w_MRF_home[0:3, 3] + np.array(gains.k_p[0:3]) * dx[0:3])
    np.testing.assert_allclose(T[0:3, 0:3], slave.T_w_MRF_home[0:3, 0:3] @ zyx_to_matrix(*dx[3:6]), atol=1e-12)
    held = T.copy()
    # Index: release the deadman, move the grip back, press the reference: the slave stays put.
    ctrl.step(q0 + step, Switches(deadman=False), FTReading(), DT)
    out = ctrl.step(q0, Switches(deadman=False), FTReading(), DT)
    np.testing.assert_allclose(out.command.T_w_MRF, held)
    out = ctrl.step(q0, Switches(deadman=True, reference=True), FTReading(), DT)
    np.testing.assert_allclose(out.command.T_w_MRF, held, atol=1e-12)
    # Moving again continues from the held pose: the slave covers twice the translation.
    out = ctrl.step(q0 + step, Switches(deadman=True), FTReading(), DT)
    expected = slave.T_w_MRF_home[0:3, 3] + 2 * np.array(gains.k_p[0:3]) * dx[0:3]
    np.testing.assert_allclose(out.command.T_w_MRF[0:3, 3], expected, atol=1e-9)


def test_return_to_centre_only_in_rate_mode(kraft: DeviceSpec, slave: SlaveModel) -> None:
    q = home(kraft) + np.array([0.1, 0.1, 0.1, 0.3, 0.3, 0.3])
    for mode, expect in (("rate", True), ("pose", False)):
        ctrl = FRHCController(kraft, kraft.data.gains.with_changes(mode=mode), slave, safety=PAPER)
        ctrl.step(q, Switches(deadman=True, reflection=True), FTReading(), DT)
        out = ctrl.step(q, Switches(deadman=True, reflection=True), FTReading(), DT)
        assert (np.abs(out.G_F_R).max() > 0) == expect
        np.testing.assert_array_equal(out.G_F_D, 0.0)  # static grip: no damping


def test_payload_removal_leaves_the_contact_wrench(kraft: DeviceSpec, slave: SlaveModel) -> None:
    """Weight of the payload, seen by a tilted sensor, is removed; a contact wrench passes through Eq 6."""
    ctrl = FRHCController(kraft, kraft.data.gains, slave, safety=PAPER)
    R_w_S = zyx_to_matrix(0.4, -0.3, 1.1)
    g_S = R_w_S.T @ slave.gravity_w
    weight = np.concatenate((slave.payload_mass * g_S, np.cross(slave.payload_com_S, slave.payload_mass * g_S)))
    contact = np.array([1.0, -2.0, 3.0, 0.1, 0.2, -0.3])
    out = ctrl.step(home(kraft), Switches(True, False, True), FTReading(weight + contact, R_w_S), DT)
    np.testing.assert_allclose(out.F_S_task, contact, atol=1e-12)
    X = wrench_transform(slave.T_MRF_S[0:3, 0:3], slave.T_MRF_S[0:3, 3])
    np.testing.assert_allclose(out.F_MRF, X @ contact, atol=1e-12)
    # Kraft's grip is level at home (R_0_G = I): the force crosses in world axes, the moment as Eq 6.
    k_t = np.array(kraft.data.gains.k_t)
    np.testing.assert_allclose(out.G_F_T[0:3], k_t[0:3] * (R_w_S @ contact[0:3]), atol=1e-12)
    np.testing.assert_allclose(out.G_F_T[3:6], k_t[3:6] * (X @ contact)[3:6], atol=1e-12)
    kept = FRHCController(kraft, kraft.data.gains.with_changes(remove_payload=False), slave, safety=PAPER)
    out = kept.step(home(kraft), Switches(True, False, True), FTReading(weight + contact, R_w_S), DT)
    np.testing.assert_allclose(out.F_S_task, weight + contact, atol=1e-12)


@pytest.mark.parametrize("mode", ["rate", "pose"])
def test_forces_cross_in_world_axes_on_a_tilted_grip(slave: SlaveModel, mode: str) -> None:
    """On JPL's grip (tilted 28.6 deg at home) the felt force is K_T times the slave's force in
    world axes, re-expressed in {G}, as translations cross in {0}/{w} axes; and the return-to-centre
    force pushes the grip back toward the reference in {0}: both are passive with the motion."""
    jpl = load_device("jpl")
    gains = jpl.data.gains.with_changes(mode=mode)
    ctrl = FRHCController(jpl, gains, slave, safety=PAPER)
    R_w_S = zyx_to_matrix(0.3, 0.2, -0.5)
    contact = np.array([1.0, -2.0, 3.0, 0.0, 0.0, 0.0])
    weight = np.concatenate((slave.payload_mass * (R_w_S.T @ slave.gravity_w), np.zeros(3)))
    weight[3:6] = np.cross(slave.payload_com_S, weight[0:3])
    q0 = home(jpl)
    ctrl.step(q0, Switches(True, False, True), FTReading(weight + contact, R_w_S), DT)
    out = ctrl.step(q0, Switches(True, False, True), FTReading(weight + contact, R_w_S), DT)
    R_0_G = out.T_0_G[0:3, 0:3]
    assert np.degrees(np.arccos((np.trace(R_0_G) - 1) / 2)) > 20  # the case Eq 6 read literally misses
    k_t = np.array(gains.k_t)
    np.testing.assert_allclose(R_0_G @ out.G_F_T[0:3], k_t[0:3] * (R_w_S @ contact[0:3]), atol=1e-12)
    if mode == "rate":
        # Displace the grip along base x (j1 swings it sideways); the RTC force opposes that, in {0}.
        q = q0 + np.array([0.05, 0, 0, 0, 0, 0])
        ctrl.step(q, Switches(deadman=True, reflection=True), FTReading(weight, R_w_S), DT)
        out = ctrl.step(q, Switches(deadman=True, reflection=True), FTReading(weight, R_w_S), DT)
        f_0 = out.T_0_G[0:3, 0:3] @ out.G_F_R[0:3]
        dx = out.delta_x[0:3]
        assert dx[2] == 0.0
        assert abs(dx[1]) > 0.02
        assert f_0[1] * dx[1] < 0
        assert f_0[0] * dx[0] <= 0
        assert abs(f_0[2]) < 1e-12  # nothing leaks into {0}'s z, along which the grip did not move


def test_inertial_removal(kraft: DeviceSpec, slave: SlaveModel) -> None:
    """An accelerating, spinning payload with no contact reads back as zero task wrench."""
    ctrl = FRHCController(kraft, kraft.data.gains.with_changes(remove_inertia=True), slave, safety=PAPER)
    R_w_S = zyx_to_matrix(0.2, 0.1, -0.4)
    a_S_w, alpha_w, omega_w = np.array([1.0, -2.0, 0.5]), np.array([3.0, 1.0, -2.0]), np.array([0.5, -1.0, 2.0])
    c, m, I = slave.payload_com_S, slave.payload_mass, slave.payload_inertia_S
    w, al = R_w_S.T @ omega_w, R_w_S.T @ alpha_w
    a_com = R_w_S.T @ a_S_w + np.cross(al, c) + np.cross(w, np.cross(w, c))
    f = m * (R_w_S.T @ slave.gravity_w) - m * a_com
    moment = np.cross(c, f) - (I @ al + np.cross(w, I @ w))
    ft = FTReading(np.concatenate((f, moment)), R_w_S, np.concatenate((a_S_w, alpha_w)), omega_w)
    out = ctrl.step(home(kraft), Switches(True, False, True), ft, DT)
    np.testing.assert_allclose(out.F_S_task, 0.0, atol=1e-12)


@pytest.mark.parametrize(
    ("acc_w", "omega_w"),
    [
        (np.array([np.nan, 0.0, 0.0, 0.0, 0.0, 0.0]), np.zeros(3)),
        (np.array([0.0, 0.0, 0.0, 0.0, np.inf, 0.0]), np.zeros(3)),
        (np.zeros(6), np.array([0.0, -np.inf, 0.0])),
    ],
)
def test_non_finite_motion_is_a_fault_when_inertia_is_removed(
    kraft: DeviceSpec, slave: SlaveModel, acc_w: np.ndarray, omega_w: np.ndarray
) -> None:
    """The acceleration and angular velocity feed the wrench only with ``remove_inertia``: then a
    non-finite one is a fault (safe output, named); without it they are unused and harmless."""
    on = Switches(True, False, True)
    bad = FTReading(acc_w=acc_w, omega_w=omega_w)
    ctrl = FRHCController(kraft, kraft.data.gains.with_changes(remove_inertia=True), slave, safety=PAPER)
    ctrl.step(home(kraft), on, FTReading(), DT)
    out = ctrl.step(home(kraft), on, bad, DT)
    assert out.faults == Fault.NONFINITE_INPUT
    assert "inertia removal" in out.fault_message
    np.testing.assert_array_equal(out.tau_T, 0.0)
    np.testing.assert_allclose(out.tau, out.tau_G)
    plain = FRHCController(kraft, kraft.data.gains, slave, safety=PAPER)
    assert plain.step(home(kraft), on, bad, DT).faults == Fault.NONE


def test_assist_torques_are_scaled_to_their_share_of_capacity(kraft: DeviceSpec, slave: SlaveModel) -> None:
    gains = kraft.data.gains.with_changes(rtc="hooke", k_r=(1e5,) * 6, assist_fraction=0.25)
    ctrl = FRHCController(kraft, gains, slave, safety=PAPER)
    q = home(kraft) + 0.2
    out = ctrl.step(q, Switches(deadman=True, reflection=True), FTReading(), DT)
    limit = np.array(ctrl.joint_limit)
    assert out.assist_scale < 1.0
    assert np.all(np.abs(out.tau_RDs) <= 0.25 * limit + 1e-12)
    assert np.isclose(np.max(np.abs(out.tau_RDs) / limit), 0.25)
    np.testing.assert_allclose(out.tau_RDs, out.assist_scale * out.tau_RD)


def test_total_torque_saturates_uniformly_and_counts_follow_the_curve(kraft: DeviceSpec, slave: SlaveModel) -> None:
    ctrl = FRHCController(kraft, kraft.data.gains.with_changes(k_t=(1e6,) * 6), slave, safety=PAPER)
    out = ctrl.step(home(kraft), Switches(True, False, True), contact_reading(slave), DT)
    limit = np.array(ctrl.joint_limit)
    assert out.saturation_scale < 1e-3
    assert np.all(np.abs(out.tau_sat) <= limit)
    np.testing.assert_allclose(out.tau_sat, out.saturation_scale * out.tau, rtol=1e-12)
    np.testing.assert_allclose(out.tau_motor, out.tau_sat / np.array(kraft.data.motors.gear_ratio))
    expected = ctrl.curve.counts(out.tau_motor)
    np.testing.assert_array_equal(out.counts, expected)


@pytest.mark.parametrize(
    ("q_bad", "ft", "dt", "fault"),
    [
        (True, FTReading(), DT, Fault.NONFINITE_INPUT),
        (False, FTReading(wrench_S=np.array([np.nan, 0, 0, 0, 0, 0])), DT, Fault.NONFINITE_INPUT),
        (False, FTReading(R_w_S=np.full((3, 3), np.inf)), DT, Fault.NONFINITE_INPUT),
        (False, FTReading(valid=False), DT, Fault.FT_INVALID),
        (False, FTReading(), 0.5, Fault.BAD_PERIOD),
        (False, FTReading(), float("nan"), Fault.BAD_PERIOD),
        (False, FTReading(), 0.0, Fault.BAD_PERIOD),
    ],
)
def test_bad_input_gives_a_safe_output_and_names_the_fault(controller, kraft, q_bad, ft, dt, fault) -> None:
    q = home(kraft) + 0.1
    controller.step(q, Switches(True, False, True), FTReading(), DT)
    if q_bad:
        q = q.copy()
        q[2] = np.nan
    out = controller.step(q, Switches(True, False, True), ft, dt)
    assert out.faults & fault
    assert out.fault_message
    assert not out.command.active
    np.testing.assert_array_equal(out.command.twist, 0.0)
    assert np.isfinite(out.torques).all()
    np.testing.assert_array_equal(out.tau_T, 0.0)
    np.testing.assert_array_equal(out.tau_RDs, 0.0)
    if q_bad:
        np.testing.assert_array_equal(out.counts, 0)  # nothing is known: no torque at all
    else:
        np.testing.assert_allclose(out.tau, out.tau_G)  # gravity compensation only
        assert np.abs(out.tau_G).max() > 0.1
    # The next good tick recovers without a damping kick from the skipped Delta X.
    out = controller.step(home(kraft) + 0.1, Switches(True, False, True), FTReading(), DT)
    assert out.faults == Fault.NONE
    np.testing.assert_array_equal(out.G_F_D, 0.0)


def test_huge_finite_inputs_never_make_nan_torque(controller: FRHCController, kraft: DeviceSpec) -> None:
    ft = FTReading(wrench_S=np.full(6, 1e300))
    out = controller.step(home(kraft), Switches(True, False, True), ft, DT)
    assert np.isfinite(out.torques).all()
    assert np.all(np.abs(out.tau_sat) <= np.array(controller.joint_limit))
