"""Replay a recorded log in the browser: every tick's view rebuilt from its log row.

A log (``frhc run``, or the demo's Record button) holds per tick the encoder angles, grip and tool
poses, Delta X, every wrench the view draws and the switches, plus ``_meta.json`` naming the scene
and device (:class:`~app.session.log.TickLog`). :class:`LogReplay` turns row ``i`` into the same
:class:`~app.web.snapshot.Snapshot` the live loop publishes; what the log does not store is
recomputed deterministically from what it does:

- device link poses: MuJoCo forward kinematics of the device model at the logged angles (the
  encoder angles, within one count of the true ones); a Cartesian device's log holds its grip
  pose, not its angles (its ``q_*`` columns are the pose's coordinates), and its links are not
  shown;
- the reference pose {G0}: from the grip pose and Delta X (Eq 2-4 inverted);
- the hand target's orientation: the grip's (the log keeps the target's position);
- a Cartesian device's link state: logged per tick (``device_link``), shown as live;
- contact points: the scene's contact at the logged tool pose, evaluated afresh (stateless: a
  pop-through memory of the live run is not reproduced, the drawn points may then differ); only
  the static objects' contacts: the dynamic objects are drawn at their logged poses
  (``object_<name>_*`` columns) but their contact with the tool is not re-evaluated.

The live servo loop is never touched: the replay has its own never-ticked copy of the loop for the
geometry and kinematics.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from app.controller.layout import DELTA_X_AXES, WRENCH_AXES
from app.device.boundary import LinkStatus
from app.device.spec import load_device
from app.errors import ConfigError
from app.session.log import META_FILE, read_log
from app.session.loop import LoopConfig, ServoLoop
from app.session.state import POSE
from app.spatial import Array, make_pose, quat_to_matrix, zyx_to_matrix
from app.web.controls import PLOT_SAMPLES
from app.web.snapshot import Snapshot
from app.world import contact_wrench
from app.world.scene import load_scene

# The log keeps no arm joint angles (nor a Cartesian device's): a replay shows the tool and the
# grip, not those links.
_NO_GEOM_XPOS = np.zeros((0, 3))
_NO_GEOM_XMAT = np.zeros((0, 3, 3))


def _pose(row: dict[str, Array], prefix: str, i: int) -> Array:
    """The pose logged as ``<prefix>_x..z, _qw..qz`` at row ``i``, (4, 4)."""
    q = np.array([row[f"{prefix}_{k}"][i] for k in ("qw", "qx", "qy", "qz")])
    p = np.array([row[f"{prefix}_{k}"][i] for k in ("x", "y", "z")])
    return make_pose(quat_to_matrix(q / np.linalg.norm(q)), p)


def _six(row: dict[str, Array], prefix: str, axes: tuple[str, ...], i: int) -> Array:
    return np.array([row[f"{prefix}_{a}"][i] for a in axes])


class LogReplay:
    """A recorded log, ready to be shown tick by tick.

    Args:
        directory: The log directory (``.../log`` with ``part-*.parquet`` and ``_meta.json``), or
            the run directory holding it.

    Attributes:
        directory: The log directory.
        loop: A never-ticked loop of the logged scene and device (geometry for the view).
        t: Simulated time of each row (s), (n,).

    Raises:
        ConfigError: naming the directory or ``_meta.json`` when the log cannot be replayed.
    """

    def __init__(self, directory: Path) -> None:
        directory = directory / "log" if (directory / "log" / META_FILE).is_file() else directory
        meta_path = directory / META_FILE
        if not meta_path.is_file():
            raise ConfigError(
                directory, "<file>", f"not a replayable log (no {META_FILE}: recorded by an older version?)"
            )
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(meta_path, "<file>", f"cannot read: {exc}") from None
        if not isinstance(meta, dict):
            raise ConfigError(meta_path, "<file>", f"expected a JSON object, got {type(meta).__name__}")
        for name in ("device", "scene"):
            if not isinstance(meta.get(name), str) or not meta[name]:
                raise ConfigError(meta_path, name, "missing: the log does not name the file it was run with")
        device, scene = load_device(meta["device"]), load_scene(meta["scene"])
        #: What of the log's files could not be checked (a log from before ``device_identity`` or
        #: ``scene_identity``), or "".
        self.unchecked = " · ".join(
            note
            for note in (
                self._check_identity(meta_path, meta, "device", device.path, device.identity),
                self._check_identity(meta_path, meta, "scene", scene.path, scene.identity),
            )
            if note
        )
        cartesian = meta.get("cartesian", device.data.interface == "cartesian")  # not in older logs
        if not isinstance(cartesian, bool):
            raise ConfigError(meta_path, "cartesian", f"expected true or false, got {cartesian!r}")
        #: The log is of a Cartesian device (its links are not shown).
        self.cartesian = cartesian
        self.directory = directory
        self.mode = str(meta.get("mode", "rate"))
        self.loop = ServoLoop(LoopConfig(device, scene, device.data.gains))
        # A Cartesian device's controller has six "joints", the wrench axes (docs/conventions.md).
        self._n_joints = len(WRENCH_AXES) if cartesian else device.n_joints
        #: Names of the scene's dynamic objects, whose poses the log holds.
        self.objects = self.loop.objects
        table = read_log(directory, self._n_joints, self.objects)
        if table.num_rows == 0:
            raise ConfigError(directory, "<file>", "the log has no ticks")
        t = table.column("t").to_numpy()
        if not np.isfinite(t).all():
            raise ConfigError(
                directory, "t", f"{np.count_nonzero(~np.isfinite(t))} of {len(t)} rows have no finite time"
            )
        order = np.argsort(t, kind="stable")
        self._cols: dict[str, Array] = {name: table.column(name).to_numpy()[order] for name in table.column_names}
        self.t: Array = self._cols["t"]
        self._T_MRF_S = self.loop.controller.slave.T_MRF_S
        # Every row's object poses, (rows, n, 7): a snapshot takes one row.
        self._object_poses = np.empty((len(self.t), len(self.objects), len(POSE)))
        for b, name in enumerate(self.objects):
            for k, axis in enumerate(POSE):
                self._object_poses[:, b, k] = self._cols[f"object_{name}_{axis}"]

    @staticmethod
    def _check_identity(meta_path: Path, meta: dict[str, Any], kind: str, path: Path | None, identity: str) -> str:
        """Hold the ``kind`` file (``"device"`` or ``"scene"``) the log names, at ``path``, to the
        one it was run with: the log's ``<kind>_identity`` against the file's ``identity`` (see
        :attr:`~app.device.spec.DeviceSpec.identity`, :attr:`~app.world.scene.Scene.identity`).
        A log written before the identity was kept is replayed with the note returned (shown
        beside the replay), not refused; "" when checked.

        Raises:
            ConfigError: the logged identity is not a string, or differs from ``identity``.
        """
        field = f"{kind}_identity"
        logged = meta.get(field)
        if logged is None:
            return f"{meta_path} has no {field} (an older log): {path} is taken as the {kind} it ran"
        if not isinstance(logged, str):
            raise ConfigError(meta_path, field, f"expected a string, got {logged!r}")
        if logged != identity:
            raise ConfigError(
                meta_path,
                kind,
                f"{path} is not the {kind} this log was run on (its {field} is {logged}, "
                f"the file's is {identity}): the file was edited since, or the log names another {kind}",
            )
        return ""

    def __len__(self) -> int:
        return len(self.t)

    @property
    def columns(self) -> list[str]:
        """Names of the logged columns."""
        return list(self._cols)

    def index_at(self, t: float) -> int:
        """The last row at or before time ``t`` (s) (the first row before the log starts)."""
        return int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1))

    def column(self, name: str) -> Array:
        """One logged column over the whole log (time order)."""
        return self._cols[name]

    def snapshot(self, i: int) -> Snapshot:
        """The view of row ``i``, as the live loop would have published it."""
        c = self._cols
        if self.cartesian:
            geom_xpos, geom_xmat = _NO_GEOM_XPOS, _NO_GEOM_XMAT
        else:
            plant = self.loop.plant
            data = plant.data
            data.qpos[plant.qpos_slice] = [c[f"q_{j}"][i] for j in range(self._n_joints)]
            mujoco.mj_kinematics(plant.model, data)
            geom_xpos, geom_xmat = data.geom_xpos.copy(), data.geom_xmat.reshape(-1, 3, 3).copy()
        T_0_G = _pose(c, "grip", i)
        dx = _six(c, "delta_x", DELTA_X_AXES, i)
        R_0_G0 = T_0_G[0:3, 0:3] @ zyx_to_matrix(dx[3], dx[4], dx[5]).T
        T_0_G0 = make_pose(R_0_G0, T_0_G[0:3, 3] - dx[0:3])
        hand = np.array([c[f"hand_target_{a}"][i] for a in ("x", "y", "z")])
        T_0_H = None if np.isnan(hand).any() else make_pose(T_0_G[0:3, 0:3], hand)
        T_w_MRF = _pose(c, "tool", i)
        deadman, reflection = bool(c["deadman"][i]), bool(c["reflection"][i])
        contact = contact_wrench(self.loop.slave.scene, T_w_MRF)
        return Snapshot(
            time=float(c["t"][i]),
            ticks=i + 1,
            geom_xpos=geom_xpos,
            geom_xmat=geom_xmat,
            T_0_G=T_0_G,
            T_0_G0=T_0_G0,
            T_0_H=T_0_H,
            T_w_MRF=T_w_MRF,
            T_w_S=T_w_MRF @ self._T_MRF_S,
            contact_points_w=contact.points_w.copy(),
            contact_normals_w=contact.normals_w.copy(),
            F_MRF=_six(c, "F_MRF", WRENCH_AXES, i),
            G_F_T=_six(c, "G_F_T", WRENCH_AXES, i),
            G_F_RD=_six(c, "G_F_RD", WRENCH_AXES, i),
            hand_wrench_0=_six(c, "hand_G", WRENCH_AXES, i),
            delta_x=dx,
            deadman=deadman,
            reflection=reflection,
            reflecting=deadman and reflection,
            mode=self.mode,
            faults=int(c["faults"][i]),
            fault_message="",
            saturation_scale=float(c["saturation_scale"][i]),
            ramp=float(c["ramp"][i]),
            po_energy=float(c["po_energy"][i]) if "po_energy" in c else 0.0,
            pc_cut=float(c["pc_cut"][i]) if "pc_cut" in c else 0.0,
            watchdog_trips=int(c["watchdog_trips"][i]),
            slave_status=int(c["slave_status"][i]) if "slave_status" in c else 0,
            # As live, a Cartesian device's link only (not in logs before columns_version 4).
            device_link=LinkStatus(int(c["device_link"][i])).name if self.cartesian and "device_link" in c else "",
            slave_geom_xpos=_NO_GEOM_XPOS,
            slave_geom_xmat=_NO_GEOM_XMAT,
            object_poses=self._object_poses[i].copy(),
        )


class ReplayPlayer:
    """A cursor over a :class:`LogReplay`: seek, play at a speed, and the plots' window.

    Attributes:
        replay: The log. cursor: Simulated time shown (s). playing: Advancing with the clock.
        speed: Simulated seconds per wall-clock second.
    """

    def __init__(self, replay: LogReplay) -> None:
        self.replay = replay
        self.cursor = float(replay.t[0])
        self.playing = False
        self.speed = 1.0
        c = replay.column

        def norm(prefix: str) -> Array:
            return np.linalg.norm(np.vstack([c(f"{prefix}_f{a}") for a in "xyz"]), axis=0)

        energy = c("po_energy") if "po_energy" in replay.columns else np.zeros(len(replay))
        # The rows of app.web.controls.PlotRow.
        self._plot_rows = np.vstack(
            (
                replay.t,
                c("F_MRF_fx"),
                c("F_MRF_fy"),
                c("F_MRF_fz"),
                norm("G_F_T"),
                norm("hand_G"),
                *(1000.0 * c(f"delta_x_{a}") for a in DELTA_X_AXES[0:3]),
                energy,
            )
        )

    @property
    def duration(self) -> float:
        return float(self.replay.t[-1])

    def seek(self, t: float) -> None:
        """Show time ``t`` (s), clipped to the log; a non-finite ``t`` (no time) is ignored."""
        if math.isfinite(t):
            self.cursor = float(np.clip(t, self.replay.t[0], self.replay.t[-1]))

    def advance(self, wall_seconds: float) -> None:
        """Move the cursor on by ``wall_seconds`` of playing (stops at the end)."""
        if self.playing:
            self.seek(self.cursor + self.speed * wall_seconds)
            self.playing = self.cursor < self.replay.t[-1]

    def snapshot(self) -> Snapshot:
        return self.replay.snapshot(self.replay.index_at(self.cursor))

    def window(self, seconds: float) -> Array:
        """Plot samples (10, k) of the ``seconds`` before the cursor, thinned to at most
        :data:`~app.web.controls.PLOT_SAMPLES`, as a live window holds (the last one is the
        cursor's row): a replay sends no more plot data than the live page."""
        t = self.replay.t
        lo, hi = int(np.searchsorted(t, self.cursor - seconds)), self.replay.index_at(self.cursor) + 1
        step = -(-(hi - lo) // PLOT_SAMPLES)
        return self._plot_rows[:, hi - 1 - ((hi - 1 - lo) // step) * step : hi : step]
