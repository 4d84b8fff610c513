"""Eq 7 and the gravity sum against independent computations: finite differences and MuJoCo.

Every shipped device is checked, and a variant with a slide joint and two joints in one body
(listed out of MuJoCo's order), which the compiled Jacobian and gravity sums must also handle.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from app.controller.frhc import FRHCController
from app.controller.kinematics import DeviceKinematics
from app.controller.safety import SafetyLimits
from app.controller.types import FTReading, SlaveModel, Switches
from app.device.spec import DeviceSpec, load_device
from app.spatial import rotation_log

DEVICES = ["kraft", "jpl", "freflex", "variant"]

#: The paper's controller as printed (ticks jump; each checks its equations): no ramp, no brake.
PAPER = SafetyLimits.paper_only()


@pytest.fixture(params=DEVICES)
def device(request: pytest.FixtureRequest) -> DeviceSpec:
    if request.param == "variant":
        spec: DeviceSpec = request.getfixturevalue("variant")
        return spec
    return load_device(request.param)


def random_configs(spec: DeviceSpec, count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ranges = spec.model.jnt_range[list(spec.joint_ids)]
    return rng.uniform(ranges[:, 0] * 0.8, ranges[:, 1] * 0.8, size=(count, spec.n_joints))


def grip_pose(kin: DeviceKinematics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    kin.update(q)
    return kin.p_0_G.copy(), kin.R_0_G.copy()


def mujoco_at(spec: DeviceSpec, q: np.ndarray) -> mujoco.MjData:
    """A fresh MjData at ``q`` after MuJoCo's full forward pass (independent of the controller's)."""
    data = mujoco.MjData(spec.model)
    data.qpos[list(spec.qpos_ids)] = q
    mujoco.mj_forward(spec.model, data)
    return data


def test_jacobian_transpose_matches_virtual_work(device: DeviceSpec) -> None:
    """tau = J^T F at {W} equals dW/dq by central differences of the wrist pose (virtual work)."""
    kin = DeviceKinematics(device)
    rng = np.random.default_rng(1)
    J = np.zeros((6, device.n_joints))
    h = 1e-6
    for q in random_configs(device, 10):
        F = rng.normal(size=6)
        kin.update(q)
        tau = kin.jacobian_W(J).T @ F
        for i in range(device.n_joints):
            dq = np.zeros_like(q)
            dq[i] = h
            kin.update(q + dq)
            p1, R1 = kin.p_0_W.copy(), kin.R_0_W.copy()
            kin.update(q - dq)
            p0, R0 = kin.p_0_W.copy(), kin.R_0_W.copy()
            # Small rotation in base coordinates: log(R1 R0^T).
            work = F[0:3] @ (p1 - p0) + F[3:6] @ rotation_log(R1 @ R0.T)
            assert tau[i] == pytest.approx(work / (2 * h), abs=1e-6)


def test_jacobian_matches_mujoco_jac_site(device: DeviceSpec) -> None:
    """The wrist Jacobian equals MuJoCo's own ``mj_jacSite``, columns of the controlled dofs."""
    kin = DeviceKinematics(device)
    m = device.model
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, device.data.wrist_site)
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    J = np.zeros((6, device.n_joints))
    dofs = list(device.dof_ids)
    for q in random_configs(device, 10, seed=6):
        kin.update(q)
        mujoco.mj_jacSite(m, mujoco_at(device, q), jacp, jacr, site)
        np.testing.assert_allclose(kin.jacobian_W(J), np.vstack((jacp[:, dofs], jacr[:, dofs])), atol=1e-12)


def test_controller_task_torques_render_the_grip_wrench(device: DeviceSpec, slave: SlaveModel) -> None:
    """The whole G -> W -> base -> J^T chain: tau_T does the virtual work of G_F_T (in {G}) on the grip."""
    gains = device.data.gains.with_changes(k_d=(0.0,) * 6, rtc="off", remove_payload=False)
    ctrl = FRHCController(device, gains, slave, safety=PAPER)
    kin = DeviceKinematics(device)
    rng = np.random.default_rng(2)
    h = 1e-6
    for q in random_configs(device, 6, seed=3):
        ctrl.reset(q)
        ft = FTReading(wrench_S=rng.normal(size=6))
        out = ctrl.step(q, Switches(deadman=True, reflection=True), ft, 1e-3)
        G_F = out.G_F_T.copy()
        _, R = grip_pose(kin, q)
        f0, m0 = R @ G_F[0:3], R @ G_F[3:6]
        for i in range(device.n_joints):
            dq = np.zeros_like(q)
            dq[i] = h
            p1, R1 = grip_pose(kin, q + dq)
            p0, R0 = grip_pose(kin, q - dq)
            work = f0 @ (p1 - p0) + m0 @ rotation_log(R1 @ R0.T)
            assert out.tau_T[i] == pytest.approx(work / (2 * h), abs=1e-6)


def test_gravity_compensation_matches_mujoco_rne(device: DeviceSpec) -> None:
    """tau_G equals MuJoCo's gravity forces (RNE at zero velocity) at random configurations."""
    kin = DeviceKinematics(device)
    tau = np.zeros(device.n_joints)
    for q in random_configs(device, 20, seed=4):
        kin.update(q)
        expected = mujoco_at(device, q).qfrc_bias[list(device.dof_ids)]
        np.testing.assert_allclose(kin.gravity_torque(tau), expected, atol=1e-10)


def test_gravity_compensation_is_the_papers_per_link_sum(device: DeviceSpec) -> None:
    """tau_G = sum over links of J_i^T m_i (-g), each link's COM Jacobian taken separately."""
    kin = DeviceKinematics(device)
    m = device.model
    jacp = np.zeros((3, m.nv))
    tau = np.zeros(device.n_joints)
    for q in random_configs(device, 5, seed=5):
        kin.update(q)
        data = mujoco_at(device, q)
        expected = np.zeros(device.n_joints)
        for body in range(1, m.nbody):
            mujoco.mj_jacBodyCom(m, data, jacp, None, body)
            expected += jacp[:, list(device.dof_ids)].T @ (-m.body_mass[body] * m.opt.gravity)
        np.testing.assert_allclose(kin.gravity_torque(tau), expected, atol=1e-10)


def test_variant_exercises_what_it_claims(variant: DeviceSpec) -> None:
    """The variant really has a slide joint and motor columns out of MuJoCo's dof order."""
    assert mujoco.mjtJoint.mjJNT_SLIDE in variant.model.jnt_type[list(variant.joint_ids)]
    assert list(variant.dof_ids) != sorted(variant.dof_ids)
