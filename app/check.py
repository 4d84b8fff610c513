"""``frhc check``: load scene, device, session and sweep files and build what ``frhc run`` would, without running.

A file passes only if everything a run builds from it builds: the parsed and range-checked
file, its meshes, MJCF and calibration, the device plant (the MJCF perturbed by ``[plant]``
plus the operator's hand), the virtual slave's MuJoCo model (tool mass and inertia) and the
controller. A scene is built with the default device and a device with the default scene, at
their default gains. A sweep file is checked as ``frhc sweep`` checks it before running
(:func:`app.sweep.spec.load_sweep`: its fields, ranges and every value written in it) and its
base session is built. So ``check`` ok means ``run`` (or ``sweep``) starts.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from app.config import deferred_warnings, load_toml
from app.device.hand import HandParams
from app.device.spec import DEFAULT_DEVICE, DeviceFile, load_device, resolve_device_path
from app.errors import ConfigError
from app.session.loop import LoopConfig, ServoLoop
from app.session.spec import SessionFile, load_session, resolve_session_path
from app.sweep.spec import SweepFile, load_sweep, resolve_sweep_path
from app.world.scene import DEFAULT_SCENE, SceneFile, load_scene, resolve_scene_path

#: The schema of each kind of file; a file's kind is the one whose fields its keys match best.
KINDS: dict[str, type] = {"device": DeviceFile, "scene": SceneFile, "session": SessionFile, "sweep": SweepFile}


def file_kind(path: Path, data: dict[str, Any]) -> str:
    """``"device"``, ``"scene"``, ``"session"`` or ``"sweep"``: the schema sharing the most top-level keys with ``data``.

    Raises:
        ConfigError: No schema matches any key, or two match equally well.
    """
    scores = {kind: len(set(data) & {f.name for f in dataclasses.fields(cls)}) for kind, cls in KINDS.items()}
    best = max(scores.values())
    winners = [kind for kind, score in scores.items() if score == best]
    if best == 0 or len(winners) > 1:
        raise ConfigError(path, "<file>", "cannot tell whether this is a device, scene, session or sweep file")
    return winners[0]


@contextmanager
def _model_errors(path: Path) -> Iterator[None]:
    """Turn MuJoCo's refusal of a model (e.g. a mass below mjMINVAL) while building into a ConfigError."""
    try:
        yield
    except ValueError as exc:
        raise ConfigError(path, "<model>", f"MuJoCo refuses the model: {' '.join(str(exc).split())}") from None


def check_file(name: str) -> str:
    """Load ``name`` (a path, or a device/scene/session/sweep name) fully; return a one-line description
    (a session's then one ``warning:`` line per switch event that never fires, :attr:`Session.notices`).

    Raises:
        ConfigError: naming the file and field on any problem.
    """
    path = Path(name)
    if not path.suffix:
        candidates = [
            resolve_device_path(name),
            resolve_scene_path(name),
            resolve_session_path(name),
            resolve_sweep_path(name),
        ]
        found = [c for c in candidates if c.is_file()]
        if not found:
            # A folder that is not a device's (no device.toml) is there, not missing.
            why = "a folder with no device.toml" if path.is_dir() else "no such file, device, scene, session or sweep"
            raise ConfigError(name, "<file>", why)
        path = found[0]
    kind = file_kind(path, load_toml(path))
    with deferred_warnings():
        if kind == "sweep":
            plan = load_sweep(path)
            with _model_errors(plan.base_path):
                ServoLoop(LoopConfig.from_session(load_session(plan.base_path)))
            return f"sweep {path.stem}: {plan.n_points()} points of {plan.base_path.stem} varying {', '.join(plan.fields)} ({path})"
        if kind == "session":
            session = load_session(path)
            with _model_errors(path):
                ServoLoop(LoopConfig.from_session(session))
            return (
                f"session {path.stem}: {session.scene.spec.name} with {session.device.name}, "
                f"{session.data.mode} mode, {session.data.n_ticks} ticks ({path})"
            ) + "".join(f"\nwarning: {notice}" for notice in session.notices)
        if kind == "device":
            device = load_device(path)
            scene = load_scene(DEFAULT_SCENE)
            what = f"device {device.name}: {device.n_joints} joints"
            if device.data.cartesian is not None:
                what += f"; Cartesian: {device.data.cartesian.figures()}"
        else:
            scene = load_scene(path)
            device = load_device(DEFAULT_DEVICE)
            moving = f" ({len(scene.bodies)} dynamic)" if scene.bodies else ""
            what = (
                f"scene {scene.spec.name}: {len(scene.objects) + len(scene.bodies)} objects{moving}, "
                f"{len(scene.tool.radii)} tool spheres"
            )
        with _model_errors(path):
            ServoLoop(LoopConfig(device, scene, device.data.gains, HandParams()))
        return f"{what} ({path})"
