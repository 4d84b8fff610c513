"""The passivity observer's energy against an independent sum from what the session logged
(issue 26): the motors' rendered torques and the encoder motion, on a whole pose-mode press."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from app.controller.frhc import Fault
from app.controller.passivity import PassivitySettings, bank_bounds, device_dissipation
from app.device.spec import load_device
from app.session.run import run_session
from app.session.stability import press_session, probe_scene_with_stiffness
from app.session.tick import TickRecord


class _Ledger:
    """Tick observer: encoder angles, the torque the motors rendered (gravity compensation aside,
    after the uniform saturation; none on a faulted tick, whose brake the observer does not
    credit) and the observer's energy, every tick."""

    def __init__(self) -> None:
        self.q: list[np.ndarray] = []
        self.rendered: list[np.ndarray] = []
        self.energy: list[float] = []
        self.time: list[float] = []
        self.faults = 0

    def on_tick(self, tick: TickRecord) -> None:
        out = tick.out
        self.q.append(tick.reading.q.copy())
        faulted = out.faults != Fault.NONE
        self.rendered.append(np.zeros(out.n) if faulted else out.saturation_scale * (out.tau - out.tau_G))
        self.faults += faulted
        self.energy.append(out.po_energy)
        self.time.append(tick.time)


def _ledger(passivity: PassivitySettings, k_t: float) -> _Ledger:
    ledger = _Ledger()
    with tempfile.TemporaryDirectory() as tmp:
        scene = probe_scene_with_stiffness(1e5, 3.0, Path(tmp))
        session = press_session(scene, "pose", gains={"k_t": [k_t] * 3 + [1.0] * 3}, passivity=passivity)
        run_session(session, out_dir=None, plots=False, observers=(ledger,))
    return ledger


def _angles(ledger: _Ledger) -> np.ndarray:
    """The observer's joint angles (rad) each tick, rebuilt from the logged encoder angles alone
    (app.controller.passivity, "Quantization"): the first tick starts at the reading; a count
    that changed up puts the angle on the edge below the reading, one that changed down on the
    edge above, ``q -+ count / 2``; while no count changes the angle stays."""
    q = np.array(ledger.q)
    half = 0.5 * load_device("kraft").encoder_step
    edge = q.copy()
    for k in range(1, len(q)):
        dq = q[k] - q[k - 1]
        edge[k] = np.where(dq >= half, q[k] - half, np.where(dq <= -half, q[k] + half, edge[k - 1]))
    return edge


def _credit(ledger: _Ledger, settings: PassivitySettings, q_obs: np.ndarray) -> np.ndarray:
    """What the device's own hardware surely dissipated each tick (J), from the device file and the
    logged encoder motion alone: its friction (times the credit) per unit of the observed
    angles' travel and its damping's least dissipation over the counts beyond one,
    d (|dq| - count)^2 / dt on the encoder difference ``dq``."""
    device = load_device("kraft")
    friction, damping, _ = device_dissipation(device)
    dq, dt = np.abs(np.diff(np.array(ledger.q), axis=0)), np.diff(np.array(ledger.time))
    sure = np.maximum(dq - device.encoder_step, 0.0)
    return np.abs(np.diff(q_obs, axis=0)) @ (settings.friction_credit * friction) + (sure**2 @ damping) / dt


def _swing(ledger: _Ledger, settings: PassivitySettings, q_obs: np.ndarray, share: float) -> np.ndarray:
    """The swing charge each tick (J), from the logged encoder angles and torques alone
    (app.controller.passivity, "The swing's turn"): where a joint's count changes against the
    direction of a run of two or more counts, ``share`` of what the encoder difference charges
    beyond the observed angle's motion, ``-tau (dq - dq_e) + f (|dq| - |dq_e|)``; the run counts
    the counts moved one way since the last reversal."""
    device = load_device("kraft")
    friction, count = settings.friction_credit * device_dissipation(device)[0], device.encoder_step
    dq, dq_e = np.diff(np.array(ledger.q), axis=0), np.diff(q_obs, axis=0)
    tau = np.array(ledger.rendered)
    charge = np.zeros(len(dq))
    run = np.zeros(dq.shape[1])
    for k in range(len(dq)):
        for j in range(dq.shape[1]):
            n = round(dq[k, j] / count[j])
            if n * run[j] < 0:
                if abs(run[j]) >= 2:
                    moved = dq[k, j] - dq_e[k, j]
                    charge[k] += share * (-tau[k, j] * moved + friction[j] * (abs(dq[k, j]) - abs(dq_e[k, j])))
                run[j] = n
            else:
                run[j] += n
    return charge


@pytest.mark.parametrize("swing_charge", [False, True])
def test_the_observer_equals_an_independent_sum_of_torque_times_encoder_motion(swing_charge: bool) -> None:
    """Kraft, a wall at 3x its bound (plain oscillates): E(n) = sum_k [-tau_r(k-1) . (q_e(k) -
    q_e(k-1)) + the device's sure dissipation (+ the swing charge, :func:`_swing`)] from the
    logged torques and encoder angles and the device file, to rounding, over the whole press (the
    bank uncapped), ``q_e`` the angle on the edge each joint last crossed, rebuilt from the logged
    encoder angles alone (:func:`_angles`). That angle's work differs from the work over the
    encoder differences by at most what the derivation allows, c/2 per joint times the torque's
    first and last values and every change of it: ``|sum_k tau(k-1) . (h(k) - h(k-1))| <= sum_j
    c_j/2 (|tau_j(0)| + |tau_j(n-1)| + sum_k |tau_j(k) - tau_j(k-1)|)`` with ``h = q_e - q``."""
    settings = PassivitySettings(enabled=False, energy_cap=math.inf, swing_charge=swing_charge)
    ledger = _ledger(settings, k_t=16.0)
    q, tau = np.array(ledger.q), np.array(ledger.rendered)
    q_edge = _angles(ledger)
    work = -np.einsum("ij,ij->i", tau[:-1], np.diff(q_edge, axis=0))
    swing = _swing(ledger, settings, q_edge, 0.5 if swing_charge else 0.0)
    assert (np.abs(swing).max() > 1e-5) == swing_charge  # the oscillation turns after multi-count swings
    independent = np.cumsum(work + _credit(ledger, settings, q_edge) + swing)
    observed = np.array(ledger.energy[1:]) - ledger.energy[0]
    assert np.abs(np.cumsum(work)).max() > 1e-3  # the rendering moved real energy
    assert ledger.faults > 0  # the velocity brake acted too (its torque is not the port's)
    np.testing.assert_allclose(observed, independent, rtol=1e-9, atol=1e-12)
    encoder_work = np.cumsum(-np.einsum("ij,ij->i", tau[:-1], np.diff(q, axis=0)))
    half = 0.5 * load_device("kraft").encoder_step
    changes = np.cumsum(np.abs(np.diff(tau[:-1], axis=0, prepend=tau[:1])), axis=0)
    allowance = (np.abs(tau[:1]) + np.abs(tau[:-1]) + changes) @ half
    difference = np.abs(np.cumsum(work) - encoder_work)
    assert difference.max() > 1e-4  # the observed angle moved otherwise than the encoders
    assert np.all(difference <= allowance + 1e-12)


def test_with_the_pc_no_300_ms_window_gives_the_hand_more_than_the_bank_bound() -> None:
    """With the PC on as shipped, what the port gave out over any 300 ms window beyond what the
    device's own hardware surely dissipated, E(t) - E(t + 0.3 s), is at most the applied cap
    plus the applied reserve (:func:`~app.controller.passivity.bank_bounds`: for the Kraft the
    energy its motors' limits exchange over three counts, 27.6 mJ, each)."""
    settings = PassivitySettings(enabled=True)
    device = load_device("kraft")
    limit = np.array(device.data.motors.gear_ratio) * np.array(device.data.motors.torque_limit)
    step = np.maximum(settings.step, settings.step_counts * device.encoder_step)
    reserve, cap = bank_bounds(settings, limit, step)
    assert reserve == cap == pytest.approx(0.0276, abs=1e-4)
    ledger = _ledger(settings, k_t=16.0)
    e, t = np.array(ledger.energy), np.array(ledger.time)
    late = np.searchsorted(t, t + 0.3)
    ok = late < len(t)
    given_out = e[ok] - e[late[ok]]
    assert given_out.max() > 0.01  # the wall gave real energy back
    assert given_out.max() <= cap + reserve + 1e-9, float(given_out.max())
