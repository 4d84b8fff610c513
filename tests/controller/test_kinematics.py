"""Eq 7 and the gravity sum against independent computations: finite differences and MuJoCo's RNE."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from app.controller.frhc import FRHCController
from app.controller.kinematics import DeviceKinematics
from app.controller.types import FTReading, SlaveModel, Switches
from app.device.spec import DeviceSpec
from app.spatial import rotation_log


def random_configs(spec: DeviceSpec, count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ranges = spec.model.jnt_range[list(spec.joint_ids)]
    return rng.uniform(ranges[:, 0] * 0.8, ranges[:, 1] * 0.8, size=(count, spec.n_joints))


def grip_pose(kin: DeviceKinematics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    kin.update(q)
    return kin.p_0_G.copy(), kin.R_0_G.copy()


def test_jacobian_transpose_matches_virtual_work(kraft: DeviceSpec) -> None:
    """tau = J^T F at {W} equals dW/dq by central differences of the wrist pose (virtual work)."""
    kin = DeviceKinematics(kraft)
    rng = np.random.default_rng(1)
    J = np.zeros((6, kraft.n_joints))
    h = 1e-6
    for q in random_configs(kraft, 10):
        F = rng.normal(size=6)
        kin.update(q)
        tau = kin.jacobian_W(J).T @ F
        for i in range(kraft.n_joints):
            dq = np.zeros_like(q)
            dq[i] = h
            kin.update(q + dq)
            p1, R1 = kin.p_0_W.copy(), kin.R_0_W.copy()
            kin.update(q - dq)
            p0, R0 = kin.p_0_W.copy(), kin.R_0_W.copy()
            # Small rotation in base coordinates: log(R1 R0^T).
            work = F[0:3] @ (p1 - p0) + F[3:6] @ rotation_log(R1 @ R0.T)
            assert tau[i] == pytest.approx(work / (2 * h), abs=1e-6)


def test_controller_task_torques_render_the_grip_wrench(kraft: DeviceSpec, slave: SlaveModel) -> None:
    """The whole G -> W -> base -> J^T chain: tau_T does the virtual work of G_F_T (in {G}) on the grip."""
    gains = kraft.data.gains.with_changes(k_d=(0.0,) * 6, rtc="off", remove_payload=False)
    ctrl = FRHCController(kraft, gains, slave)
    kin = DeviceKinematics(kraft)
    rng = np.random.default_rng(2)
    h = 1e-6
    for q in random_configs(kraft, 6, seed=3):
        ctrl.reset(q)
        ft = FTReading(wrench_S=rng.normal(size=6))
        out = ctrl.step(q, Switches(deadman=True, reflection=True), ft, 1e-3)
        G_F = out.G_F_T.copy()
        _, R = grip_pose(kin, q)
        f0, m0 = R @ G_F[0:3], R @ G_F[3:6]
        for i in range(kraft.n_joints):
            dq = np.zeros_like(q)
            dq[i] = h
            p1, R1 = grip_pose(kin, q + dq)
            p0, R0 = grip_pose(kin, q - dq)
            work = f0 @ (p1 - p0) + m0 @ rotation_log(R1 @ R0.T)
            assert out.tau_T[i] == pytest.approx(work / (2 * h), abs=1e-6)


def test_gravity_compensation_matches_mujoco_rne(kraft: DeviceSpec) -> None:
    """tau_G equals MuJoCo's gravity forces (RNE at zero velocity) at random configurations."""
    kin = DeviceKinematics(kraft)
    data = mujoco.MjData(kraft.model)
    tau = np.zeros(kraft.n_joints)
    for q in random_configs(kraft, 20, seed=4):
        kin.update(q)
        data.qpos[:] = q
        mujoco.mj_forward(kraft.model, data)
        np.testing.assert_allclose(kin.gravity_torque(tau), data.qfrc_bias[list(kraft.dof_ids)], atol=1e-10)


def test_gravity_compensation_is_the_papers_per_link_sum(kraft: DeviceSpec) -> None:
    """tau_G = sum over links of J_i^T m_i (-g), each link's COM Jacobian taken separately."""
    kin = DeviceKinematics(kraft)
    m = kraft.model
    jacp = np.zeros((3, m.nv))
    tau = np.zeros(kraft.n_joints)
    for q in random_configs(kraft, 5, seed=5):
        kin.update(q)
        expected = np.zeros(kraft.n_joints)
        for body in range(1, m.nbody):
            mujoco.mj_jacBodyCom(m, kin.data, jacp, None, body)
            expected += jacp[:, list(kraft.dof_ids)].T @ (-m.body_mass[body] * m.opt.gravity)
        np.testing.assert_allclose(kin.gravity_torque(tau), expected, atol=1e-10)
