"""The passivity observer's energy against an independent sum from what the session logged
(issue 26): the motors' rendered torques and the encoder motion, on a whole pose-mode press."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from app.controller.frhc import Fault
from app.controller.passivity import PassivitySettings, device_dissipation
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


def test_the_observer_equals_an_independent_sum_of_torque_times_encoder_motion() -> None:
    """Kraft, a wall at 3x its bound (plain oscillates): E(n) = -sum_k tau_r(k-1) . (q(k) - q(k-1))
    from the logged torques and encoder angles, to rounding, over the whole press."""
    ledger = _ledger(PassivitySettings(enabled=False), k_t=16.0)
    q, tau = np.array(ledger.q), np.array(ledger.rendered)
    independent = -np.cumsum(np.einsum("ij,ij->i", tau[:-1], np.diff(q, axis=0)))
    observed = np.array(ledger.energy[1:]) - ledger.energy[0]
    assert np.abs(observed).max() > 1e-3  # the rendering moved real energy
    assert ledger.faults > 0  # the velocity brake acted too (its torque is not the port's)
    np.testing.assert_allclose(observed, independent, rtol=1e-9, atol=1e-12)


def test_with_the_pc_no_300_ms_window_gives_out_more_than_the_bank_bound() -> None:
    """With the PC on as shipped (the bank capped at the reserve, ``energy_cap`` =
    ``energy_reserve`` = 20 mJ), the energy the port gave out over any 300 ms window,
    E(t) - E(t + 0.3 s), is at most cap + reserve plus the friction credit of the travel, each
    joint's own Coulomb friction (module docstring of app.controller.passivity)."""
    settings = PassivitySettings(enabled=True)
    assert settings.energy_cap == settings.energy_reserve == 0.02
    ledger = _ledger(settings, k_t=16.0)
    e, t = np.array(ledger.energy), np.array(ledger.time)
    device = load_device("kraft")
    friction, _ = device_dissipation(device)
    travel = np.concatenate(([0.0], np.cumsum(np.abs(np.diff(np.array(ledger.q), axis=0)) @ friction)))
    late = np.searchsorted(t, t + 0.3)
    ok = late < len(t)
    given_out = e[ok] - e[late[ok]]
    credit = settings.friction_credit * (travel[late[ok]] - travel[ok])
    bound = settings.energy_cap + settings.energy_reserve + credit
    assert given_out.max() > 0.0
    assert np.all(given_out <= bound + 1e-9), float((given_out - bound).max())
