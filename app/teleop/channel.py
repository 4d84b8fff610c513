"""The master-slave channel: a delay line in each direction between the controller and the slave.

A teleoperator's controller (master side) and its robot (slave side) exchange one message per
servo tick each way: the slave command forward, the F/T reading back. :class:`DelayLine` carries
fixed-size float64 messages with

- a constant delay of ``delay`` ticks: a message sent at tick k arrives at tick ``k + delay``
  (0 = the same tick, as without a channel);
- optional jitter: each message is late by a further 0..``jitter`` ticks, drawn uniformly;
- optional loss: each message is dropped with probability ``loss``;
- in-order delivery: a message never overtakes the one sent before it (a late message holds
  back those behind it, as on a stream transport); the receiver uses the newest message arrived
  and holds it until a newer one arrives (zero-order hold across losses).

Jitter and loss come from a seeded :class:`numpy.random.Generator`, drawn in blocks so the tick
costs no per-message generator call; the same seed gives the same deliveries.

Hand-written rather than taken from a networking library: the channel is simulated in the servo
tick, in ticks, deterministically; a ring buffer of preallocated rows is all it needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Literal, get_args

import numpy as np

from app.config import Checked, Range
from app.filters import lowpass_gain
from app.spatial import Array

Coupling = Literal["direct", "wave"]
COUPLINGS: tuple[str, ...] = get_args(Coupling)
"""How force reflection crosses the channel: the F/T reading as it is, or wave variables
(:mod:`app.teleop.wave`)."""

#: Random draws made at once for jitter and loss (amortises the generator's call overhead).
_BLOCK = 1024


@dataclass(frozen=True)
class ChannelSettings(Checked):
    """The channel between controller and slave (the defaults are no channel at all).

    Attributes:
        delay_ms: Constant one-way delay in each direction (ms); the round trip is twice this.
            Rounded to whole servo ticks.
        jitter_ms: Each message is late by a further uniform 0..``jitter_ms`` (ms), in ticks.
        loss: Probability that a message is dropped (-).
        seed: Seed of the jitter and loss draws.
        coupling: ``"direct"`` (the F/T reading is reflected as it arrives) or ``"wave"``
            (wave variables on the translational force, pose mode: :mod:`app.teleop.wave`).
        wave_impedance: The wave impedance b (N s/m) of the wave coupling.
        wave_filter_ms: Time constant (ms) of the low-pass on the master velocity the wave
            encoder uses: an encoder count a tick would otherwise be a force spike of b times
            its velocity.
        wave_cutoff_hz: Cutoff (Hz) of the first-order low-pass each end puts on the wave it
            receives (0 = none): removes wave energy, never adds it, and damps the echoes between
            the two ends (:func:`app.filters.lowpass`).
    """

    delay_ms: Annotated[float, Range(0.0, 1000.0, "ms")] = 0.0
    jitter_ms: Annotated[float, Range(0.0, 100.0, "ms")] = 0.0
    loss: Annotated[float, Range(0.0, 0.5)] = 0.0
    seed: Annotated[int, Range(0, 2**32 - 1)] = 0
    coupling: Coupling = "direct"
    wave_impedance: Annotated[float, Range(1.0, 1e4, "N s/m")] = 50.0
    wave_filter_ms: Annotated[float, Range(0.0, 100.0, "ms")] = 10.0
    wave_cutoff_hz: Annotated[float, Range(0.0, 500.0, "Hz")] = 2.0

    @property
    def active(self) -> bool:
        """False for the defaults: the loop then joins controller and slave directly."""
        idle = ChannelSettings(
            seed=self.seed,
            wave_impedance=self.wave_impedance,
            wave_filter_ms=self.wave_filter_ms,
            wave_cutoff_hz=self.wave_cutoff_hz,
        )
        return self != idle

    def delay_ticks(self, servo_rate: float) -> int:
        """The one-way delay in whole ticks at ``servo_rate`` (Hz)."""
        return round(self.delay_ms * 1e-3 * servo_rate)

    @property
    def wave_lag(self) -> float:
        """Time constant (s) of the arriving waves' low-pass, ``1 / (2 pi wave_cutoff_hz)``; 0 for none."""
        return 1.0 / (2.0 * math.pi * self.wave_cutoff_hz) if self.wave_cutoff_hz > 0.0 else 0.0

    def wave_smoothing(self, dt: float) -> float:
        """The gain ``a`` of the arriving waves' low-pass per tick of ``dt`` (s): 1 passes them as they are."""
        return lowpass_gain(dt, self.wave_lag)

    def jitter_ticks(self, servo_rate: float) -> int:
        """The most extra delay in whole ticks at ``servo_rate`` (Hz)."""
        return round(self.jitter_ms * 1e-3 * servo_rate)


class DelayLine:
    """One direction of the channel: messages of ``width`` floats, one sent and one received a tick.

    Args:
        width: Floats per message.
        delay: Constant delay (ticks, >= 0). ``jitter``: most extra delay (ticks, >= 0).
        loss: Drop probability in [0, 1). ``rng``: the generator for jitter and loss.
        initial: What the receiver holds before the first message arrives, (width,).

    Attributes:
        out: The newest message delivered (or ``initial``), (width,): overwritten in place, so
            views of it stay valid.
        delivered, lost: Messages delivered and dropped so far.
    """

    def __init__(
        self, width: int, delay: int, jitter: int, loss: float, rng: np.random.Generator, initial: Array
    ) -> None:
        if delay < 0 or jitter < 0 or not 0.0 <= loss < 1.0:
            raise ValueError(f"need delay, jitter >= 0 and 0 <= loss < 1, got {delay}, {jitter}, {loss}")
        self.delay, self.jitter, self.loss = delay, jitter, loss
        self._rng = rng
        self._size = delay + jitter + 2  # the most messages in flight, plus one
        self._buf = np.zeros((self._size, width))
        self._arrival = np.zeros(self._size, dtype=np.int64)
        self._dropped = np.zeros(self._size, dtype=bool)
        self.out = np.array(initial, dtype=float)
        self._sent = 0
        self._next = 0
        self._last_arrival = -1
        self._extra = np.zeros(_BLOCK, dtype=np.int64)
        self._drop = np.zeros(_BLOCK, dtype=bool)
        self.delivered = self.lost = 0

    def send(self) -> Array:
        """Reserve the next message (sent this tick): returns its row to fill, (width,)."""
        k = self._sent
        slot = k % self._size
        i = k % _BLOCK
        if i == 0 and (self.jitter or self.loss):
            self._extra[:] = self._rng.integers(0, self.jitter + 1, _BLOCK) if self.jitter else 0
            self._drop[:] = self._rng.random(_BLOCK) < self.loss if self.loss else False
        # In order: never before the message sent just before it.
        arrival = max(k + self.delay + int(self._extra[i]), self._last_arrival)
        self._arrival[slot] = self._last_arrival = arrival
        self._dropped[slot] = self._drop[i]
        self._sent = k + 1
        return self._buf[slot]

    def receive(self) -> bool:
        """Deliver every message due by this tick (the tick of the last :meth:`send`) into :attr:`out`.

        Returns whether a new message was delivered.
        """
        now = self._sent - 1
        got = False
        while self._next < self._sent:
            slot = self._next % self._size
            if self._arrival[slot] > now:
                break
            if self._dropped[slot]:
                self.lost += 1
            else:
                self.out[:] = self._buf[slot]
                self.delivered += 1
                got = True
            self._next += 1
        return got
