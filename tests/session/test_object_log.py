"""A dynamic object's pose in the session log and in its replay: a box in free fall."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.device.spec import load_device
from app.session.log import TickLog, loop_meta, read_log
from app.session.loop import LoopConfig, ServoLoop
from app.web.replay import LogReplay
from app.world.scene import SCENES_DIR, load_scene

G = 9.81  # m/s^2, box_push.toml's gravity
Z0 = 0.2  # m, the box's initial height (its bottom 17.5 cm above the table: 0.19 s of free fall)
X0 = 0.03  # m, clear of the tool (home 6 cm to the other side)


def test_the_log_and_its_replay_hold_a_falling_box_pose(tmp_path: Path) -> None:
    text = (SCENES_DIR / "box_push.toml").read_text()
    start = "pose = { position = [0.0, 0.0, 0.025] }"
    assert start in text
    scene_file = tmp_path / "box_drop.toml"
    scene_file.write_text(text.replace(start, f"pose = {{ position = [{X0}, 0.0, {Z0}] }}"))
    device = load_device("kraft")
    loop = ServoLoop(LoopConfig(device, load_scene(scene_file), device.data.gains))
    log_dir = tmp_path / "log"
    log = loop.observe(TickLog(log_dir, loop.controller.out.n, loop.dt, meta=loop_meta(loop.config), objects=("box",)))
    for _ in range(150):
        loop.tick()
    log.close()

    table = read_log(log_dir, loop.controller.out.n, ("box",))
    names = [c for c in table.column_names if c.startswith("object_")]
    assert names == [f"object_box_{a}" for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    t = table.column("t").to_numpy()
    z = table.column("object_box_z").to_numpy()
    # Free fall z0 - g t^2 / 2; MuJoCo's semi-implicit Euler step lags by g t h / 2 (0.74 mm at
    # 0.15 s with h = 1 ms).
    np.testing.assert_allclose(z, Z0 - 0.5 * G * t**2, atol=1e-3)
    assert z[-1] < Z0 - 0.1  # it did fall 11 cm
    np.testing.assert_allclose(table.column("object_box_x").to_numpy(), X0, atol=1e-9)
    np.testing.assert_allclose(table.column("object_box_qw").to_numpy(), 1.0, atol=1e-9)
    # The last row is the slave's pose after the last tick.
    np.testing.assert_allclose(
        [table.column(n).to_numpy()[-1] for n in names], loop.slave.object_poses()[0], atol=1e-12
    )

    replay = LogReplay(log_dir)
    assert replay.objects == ("box",)
    i = 100
    np.testing.assert_allclose(replay.snapshot(i).object_poses, [[X0, 0.0, z[i], 1.0, 0.0, 0.0, 0.0]], atol=1e-9)
