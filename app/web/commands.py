"""The commands the web server sends to the servo loop process, one small frozen dataclass each.

They travel over a pipe and are applied between two ticks by
:meth:`~app.web.loop_process.LoopHost.apply`. Anything that is not one of :data:`COMMANDS` is
refused with :class:`UnknownCommand` on both sides: the sender checks before sending, and the loop
process stops rather than ignore a command it does not know.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from app.errors import FrhcError, InvalidField

if TYPE_CHECKING:  # field types only: the first panel imports the speed range without the loop
    from app.controller.gains import ControllerGains
    from app.controller.passivity import PassivitySettings
    from app.session.spec import SessionFile
    from app.spatial import Array
    from app.teleop.channel import ChannelSettings

#: Range of :class:`SetSpeed` (simulated seconds per wall-clock second).
MIN_SPEED, MAX_SPEED = 0.1, 4.0


class UnknownCommand(FrhcError):
    """Something that is not a loop command was sent to the loop process."""


@dataclass(frozen=True)
class SetHandTarget:
    """The operator's hand pulls the grip toward ``T_0_H`` (4, 4, device base {0}); None lets go."""

    T_0_H: Array | None


@dataclass(frozen=True)
class SetDeadman:
    on: bool


@dataclass(frozen=True)
class SetReflection:
    on: bool


@dataclass(frozen=True)
class PressReference:
    """A momentary press of the reference switch: on for exactly one tick (Sec 4.1)."""


@dataclass(frozen=True)
class SetGains:
    gains: ControllerGains


@dataclass(frozen=True)
class Reset:
    """Device and slave home, switches off; the hand keeps its target. Stops a playing script."""


@dataclass(frozen=True)
class Record:
    """Start the per-tick Parquet log in ``directory``, or stop it (None)."""

    directory: Path | None


@dataclass(frozen=True)
class Play:
    """Reset and play a session's operator script to its end (``script`` None stops playing).

    The loop must have been built for that session (same scene, device, hand, rate); the sender
    parses the file, so the loop process only starts the script. With ``record`` the log of
    exactly the played ticks is written there.

    Attributes:
        script: The session file's contents (waypoints, events, tremor...).
        gains: The session's resolved gains.
        source: The session file (shown in the snapshot).
        record: Log directory, or None.
    """

    script: SessionFile | None
    gains: ControllerGains | None = None
    source: Path | None = None
    record: Path | None = None


@dataclass(frozen=True)
class Pause:
    """Hold the loop (no ticks: simulated time stops) or let it run again."""

    on: bool


@dataclass(frozen=True)
class SetSpeed:
    """Run ``factor`` simulated seconds per wall-clock second (0.1 to 4; the servo period in
    simulated time does not change, the pacing does)."""

    factor: float

    def __post_init__(self) -> None:
        if not MIN_SPEED <= self.factor <= MAX_SPEED:
            raise InvalidField("speed", f"must be between {MIN_SPEED} and {MAX_SPEED}, got {self.factor}")


@dataclass(frozen=True)
class SetPassivity:
    """Passivity controller settings (the observer always runs)."""

    settings: PassivitySettings


@dataclass(frozen=True)
class SetChannel:
    """A new master-slave channel (delay, jitter, loss, coupling) between controller and slave."""

    settings: ChannelSettings


@dataclass(frozen=True)
class Stop:
    """End the loop process after the current tick (closing any log)."""


LoopCommand = (
    SetHandTarget
    | SetDeadman
    | SetReflection
    | PressReference
    | SetGains
    | Reset
    | Record
    | Play
    | Pause
    | SetSpeed
    | SetPassivity
    | SetChannel
    | Stop
)
COMMANDS = (
    SetHandTarget,
    SetDeadman,
    SetReflection,
    PressReference,
    SetGains,
    Reset,
    Record,
    Play,
    Pause,
    SetSpeed,
    SetPassivity,
    SetChannel,
    Stop,
)


def check_command(command: object) -> LoopCommand:
    """``command`` if it is a loop command; raises :class:`UnknownCommand` otherwise."""
    if not isinstance(command, COMMANDS):
        raise UnknownCommand(f"not a loop command: {command!r} (known: {', '.join(c.__name__ for c in COMMANDS)})")
    return command
