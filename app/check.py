"""``frhc check``: load scene, device and session files without running anything."""

from __future__ import annotations

from pathlib import Path

from app.config import load_toml
from app.device.spec import load_device, resolve_device_path
from app.errors import ConfigError
from app.session.spec import load_session, resolve_session_path
from app.world.scene import SCENES_DIR, load_scene


def check_file(name: str) -> str:
    """Load ``name`` (a path, or a device/scene/session name) fully; return a one-line description.

    The kind is told by the file's keys: ``joints`` (device), ``tool`` (scene) or ``duration``
    (session). Raises :class:`ConfigError` naming the file and field on any problem.
    """
    path = Path(name)
    if not path.suffix:
        candidates = [resolve_device_path(name), SCENES_DIR / f"{name}.toml", resolve_session_path(name)]
        found = [c for c in candidates if c.is_file()]
        if not found:
            raise ConfigError(name, "<file>", "no such file, device, scene or session")
        path = found[0]
    data = load_toml(path)
    if "joints" in data:
        device = load_device(path)
        return f"device {device.name}: {device.n_joints} joints ({path})"
    if "tool" in data:
        scene = load_scene(path)
        return f"scene {scene.spec.name}: {len(scene.objects)} objects ({path})"
    if "duration" in data:
        session = load_session(path)
        return f"session {path.stem}: {session.scene.spec.name} with {session.device.name}, {session.data.mode} mode ({path})"
    raise ConfigError(path, "<file>", "not a device (joints), scene (tool) or session (duration) file")
