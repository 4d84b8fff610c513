"""Helpers shared by the device tests."""

from __future__ import annotations

import shutil
from pathlib import Path

from app.controller.types import Switches
from app.device.haply import HaplyClient
from app.device.spec import DEVICES_DIR, load_device
from app.session.cartesian_loop import CartesianServoLoop
from app.session.loop import LoopConfig, ServoLoop
from app.world.scene import load_scene


def copy_device(folder: Path, name: str) -> Path:
    """Path of ``device.toml`` in a fresh copy of ``devices/<name>`` (MJCF and calibration
    included) under ``folder``."""
    dest = folder / name
    shutil.copytree(DEVICES_DIR / name, dest)
    return dest / "device.toml"


def replace_in(path: Path, old: str, new: str) -> None:
    """Replace one exact occurrence of ``old`` in the file (fails loudly if it is not there once)."""
    text = path.read_text()
    assert text.count(old) == 1, f"{old!r} occurs {text.count(old)} times in {path}"
    path.write_text(text.replace(old, new))


def make_served_loop(port: int) -> CartesianServoLoop:
    """A loop driving the server of this process at one period's wait. Its client blocks for the
    reply: polling would hold the GIL the server's thread needs (up to Python's 5 ms switch
    interval), which a server in its own process, as deployed, does not need."""
    spec = load_device("touch3")
    loop = ServoLoop(LoopConfig(spec, load_scene("probe"), spec.data.gains, device_url=f"ws://127.0.0.1:{port}"))
    assert isinstance(loop, CartesianServoLoop)
    assert isinstance(loop.device, HaplyClient)
    loop.device.spin = 0.0
    return loop


def press_into_contact(loop: CartesianServoLoop) -> None:
    """Deadman and reflection on, hand 3 cm below the start: 1.5 s later the tool is in contact."""
    loop.switches = Switches(deadman=True, reflection=True)
    target = loop.reading.T_0_G.copy()
    target[2, 3] -= 0.03
    for _ in range(1500):
        loop.set_hand_target(target)
        loop.tick()
    assert loop.slave.contact.count > 0
    assert loop.reading.fresh
    assert loop.wrench[2] > 0.0  # the device pushes the hand back up
