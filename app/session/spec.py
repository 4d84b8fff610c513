"""Session files: ``sessions/<name>.toml`` — scene, device, mode, gains, rate, duration, seed, script.

Everything is checked before anything runs: unknown fields, unknown scene or device names,
non-monotonic waypoint times, a value outside its range (``sessions/README.md``) or a run longer
than :data:`MAX_TICKS` raise one :class:`~app.errors.ConfigError` naming the file and the field.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from app.config import Checked, Count, Range, field_range, from_dict, load_toml, named_toml
from app.controller.gains import ControllerGains
from app.controller.layout import Mode
from app.controller.passivity import PassivitySettings
from app.device.hand import HandParams
from app.device.spec import DeviceSpec, load_device
from app.errors import ConfigError, InvalidField
from app.session.files import SESSIONS_DIR
from app.teleop.channel import ChannelSettings
from app.world.scene import Scene, load_scene, with_slave
from app.world.scene_file import check_slave_kind

#: Most servo ticks (``duration * servo_rate``) of one session: an hour at 1 kHz. The run keeps
#: per-tick stage timings in memory (32 bytes a tick) and logs every tick to Parquet.
MAX_TICKS = 3_600_000
#: Longest time (s) anywhere in a session file: one day.
MAX_TIME = 86_400.0
#: Most waypoints, and most switch events, of one session: as many as fit, both lists full, in the
#: 4 MiB file limit (:data:`~app.config.MAX_FILE_BYTES`) in the most verbose form a program writes:
#: one ``[[waypoints]]``/``[[events]]`` table per entry, one key per line with CRLF endings, every
#: number at 17 significant digits (``-1.2345678901234567e-300``) and every switch given. That is
#: 225 + 125 bytes a waypoint and an event, about 12,000 pairs in 4 MiB; 10,000 leaves 0.7 MiB for the
#: rest of the file. (100,000, the limit before, fitted only in the inline form with short numbers.)
MAX_SCRIPT_ENTRIES = 10_000

TIME = Range(0.0, MAX_TIME, "s")


@dataclass(frozen=True)
class Waypoint(Checked):
    """One hand-target pose, relative to where the grip started.

    Attributes:
        t: Time (s) the hand reaches this pose.
        position: Offset (m) from the grip's start position, base-frame axes.
        zyx_deg: Z-Y-X angles ``[gamma, beta, alpha]`` (deg) of the rotation from the grip's
            start orientation, applied in the grip's start frame.
    """

    t: Annotated[float, TIME]
    position: Annotated[tuple[float, float, float], Range(-2.0, 2.0, "m")] = (0.0, 0.0, 0.0)
    zyx_deg: Annotated[tuple[float, float, float], Range(-360.0, 360.0, "deg")] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class SwitchEvent(Checked):
    """Switch changes at time ``t`` (s). ``reference = true`` is a press: it releases one tick later.

    ``hand = false`` lets go of the grip (the hand target is ignored until ``hand = true``).
    ``grip = true`` closes the slave tool's grip on the dynamic object it touches, ``false`` opens
    it (:meth:`~app.session.loop.ServoLoop.set_grip`; the session summary's ``grips`` says what
    each did).
    """

    t: Annotated[float, TIME]
    deadman: bool | None = None
    reflection: bool | None = None
    reference: bool | None = None
    hand: bool | None = None
    grip: bool | None = None


@dataclass(frozen=True)
class SessionFile(Checked):
    """The schema of a session file (see ``sessions/probe_rate.toml`` for a commented example).

    Attributes:
        scene: Scene name (in ``scenes/``) or path.
        device: Device name (in ``devices/``) or path.
        duration: Simulated time (s) to run.
        mode: ``"rate"`` or ``"pose"``; overrides the device's default gains.
        servo_rate: Servo rate (Hz) of plant, controller and slave.
        seed: Seed of the operator's tremor (and anything else random).
        accommodation: NTRFC rate-to-force accommodation on the slave (Sec 4.3).
        slave: Replaces the scene's ``[slave] kind``: ``"tool"`` (the ideal Cartesian tool) or an
            arm in ``slaves/`` (``"puma560"``, ``"redundant7"``) carrying the tool.
        tremor: Standard deviation (m) of a smoothed random hand tremor added to the targets.
        time_scale: Stretches every waypoint and event time (a slower or faster operator).
        gains: Overrides of the device's default :class:`ControllerGains` fields.
        hand: The operator's hand impedance.
        passivity: The passivity observer/controller on the device port.
        channel: The master-slave channel (delay, jitter, loss, wave variables).
        waypoints: Hand-target poses, interpolated smoothly between their times.
        events: Switch events.
    """

    scene: str
    device: str
    duration: Annotated[float, Range(0.0, MAX_TIME, "s", lo_open=True)]
    mode: Mode = "rate"
    servo_rate: Annotated[float, Range(100.0, 20000.0, "Hz")] = 1000.0
    seed: Annotated[int, Range(0, 2**32 - 1)] = 0
    accommodation: bool = True
    slave: str | None = None
    tremor: Annotated[float, Range(0.0, 0.01, "m")] = 0.0
    time_scale: Annotated[float, Range(1e-3, 1e3)] = 1.0
    gains: dict[str, Any] = field(default_factory=dict)
    hand: HandParams = field(default_factory=HandParams)
    passivity: PassivitySettings = field(default_factory=PassivitySettings)
    channel: ChannelSettings = field(default_factory=ChannelSettings)
    waypoints: Annotated[tuple[Waypoint, ...], Count(0, MAX_SCRIPT_ENTRIES)] = ()
    events: Annotated[tuple[SwitchEvent, ...], Count(0, MAX_SCRIPT_ENTRIES)] = ()

    def validate(self) -> None:
        if self.slave is not None:
            check_slave_kind(self.slave, "slave")
        if self.n_ticks > MAX_TICKS:
            raise InvalidField(
                "duration",
                f"{self.duration:g} s at {self.servo_rate:g} Hz is {self.n_ticks} ticks (at most {MAX_TICKS})",
            )
        times = [w.t for w in self.waypoints]
        for i in range(1, len(times)):
            if not times[i] > times[i - 1]:
                raise InvalidField(
                    f"waypoints[{i}].t", f"waypoint times must increase ({times[i]} after {times[i - 1]})"
                )

    @property
    def n_ticks(self) -> int:
        """Servo ticks in ``duration`` at ``servo_rate`` (the epsilon keeps 5.0 s at 1 kHz at 5000)."""
        return math.ceil(self.duration * self.servo_rate - 1e-9)


@dataclass(frozen=True)
class Session:
    """A checked session: the file's data with its scene, device and gains resolved."""

    path: Path | None
    data: SessionFile
    device: DeviceSpec
    scene: Scene
    gains: ControllerGains

    @property
    def notices(self) -> tuple[str, ...]:
        """One line per switch event that never fires, naming the file and field: due
        (``t * time_scale``) at or after the run's end, ``duration``. Not an error: a sweep or
        ``--rate`` may shorten a run on purpose; a file written that way is likely a mistake."""
        data, source = self.data, self.path or "<session>"
        return tuple(
            f"{source}: field 'events[{i}].t': due at {e.t * data.time_scale:g} s, at or after the run's end "
            f"({data.duration:g} s): it never fires"
            for i, e in enumerate(data.events)
            if e.t * data.time_scale >= data.duration
        )

    def with_changes(self, **changes: Any) -> Session:
        """A copy with fields of the session file replaced (e.g. ``accommodation=False``)."""
        return resolve_session(dataclasses.replace(self.data, **changes), self.path)


def check_servo_rate(rate: float) -> None:
    """Raise :class:`~app.errors.InvalidField` (``servo_rate``) for a rate (Hz) outside the range
    a session file accepts."""
    rule = field_range(SessionFile, "servo_rate")
    assert rule is not None
    rule.check("servo_rate", rate)


def resolve_session_path(name_or_path: str | Path) -> Path:
    """A session name (``"probe_rate"``, in ``sessions/``) or a path."""
    return named_toml(name_or_path, SESSIONS_DIR)


def load_session(name_or_path: str | Path) -> Session:
    """Load and check a session file (name in ``sessions/`` or a path)."""
    path = resolve_session_path(name_or_path)
    data = from_dict(SessionFile, load_toml(path), path)
    return resolve_session(data, path)


def resolve_session(data: SessionFile, path: Path | None) -> Session:
    """Resolve scene, device and gains of a session, naming the session file's field on error."""
    source: str | Path = path if path is not None else "<session>"
    device = _resolve(load_device, data.device, source, "device")
    scene = _resolve(load_scene, data.scene, source, "scene")
    if data.slave is not None:
        scene = with_slave(scene, data.slave)
    base = dataclasses.asdict(device.data.gains)
    gains = from_dict(ControllerGains, {**base, **data.gains, "mode": data.mode}, source, "gains")
    if gains.max_period * data.servo_rate < 1.0:
        raise ConfigError(
            source,
            "gains.max_period",
            f"{gains.max_period:g} s is shorter than the servo period 1/{data.servo_rate:g} Hz: every tick would overrun",
        )
    if data.passivity.enabled and device.data.interface == "cartesian":
        raise passivity_on_cartesian(source, device.name)
    return Session(path, data, device, scene, gains)


def passivity_on_cartesian(source: str | Path, device: str) -> ConfigError:
    """The error of a session whose ``[passivity] enabled`` meets ``device`` driven through its
    Cartesian interface: the controller observes and damps joint ports, which such a device keeps
    to itself."""
    return ConfigError(
        source,
        "passivity.enabled",
        f"the passivity controller needs a device driven joint by joint; {device} is driven through its Cartesian interface",
    )


def _resolve(loader: Any, name: str, source: str | Path, field_name: str) -> Any:
    try:
        return loader(name)
    except ConfigError as exc:
        if exc.field == "<file>":
            raise ConfigError(source, field_name, f"cannot load '{name}': {exc.reason}") from None
        raise
