"""The slave interface the servo loop uses, and the one place a slave is chosen.

Two implementations: the ideal Cartesian tool (:class:`~app.slave.tool.VirtualSlave`) and a
robot arm carrying it (:class:`~app.slave.arm.ArmSlave`); the scene file's ``[slave] kind``
chooses (``"tool"`` or an arm in ``slaves/``).
"""

from __future__ import annotations

from typing import Protocol

import mujoco

from app.controller.types import FTReading, SlaveCommand, SlaveModel
from app.slave.arm import ArmSlave
from app.slave.tool import DEFAULT_PERIOD, VirtualSlave
from app.spatial import Array
from app.world.contact import ContactResult
from app.world.scene import Scene


class Slave(Protocol):
    """A simulated slave robot with an F/T sensor at {S}, commanded in Cartesian space.

    Attributes:
        scene: The world it moves in (objects, tool, gains).
        model: Its MuJoCo model: the geoms drawn for it (an arm's links; none for the ideal tool,
            whose spheres are the scene's tool).
    """

    scene: Scene
    model: mujoco.MjModel

    def reset(self, T_w_MRF: Array | None = None) -> None:
        """At rest with {MRF} at ``T_w_MRF`` (4, 4, {w}; default the scene's home)."""

    def step(self, command: SlaveCommand, dt: float = DEFAULT_PERIOD) -> FTReading:
        """Advance one servo period ``dt`` (s) under ``command``; the F/T reading."""

    def reading(self) -> FTReading:
        """The current F/T reading without stepping (new arrays)."""

    def slave_model(self) -> SlaveModel:
        """What the controller may know about the tool."""

    def pose_view(self) -> Array:
        """Pose of {MRF} in {w} (4, 4): the slave's own buffer, overwritten by the next step."""

    def geom_poses(self) -> tuple[Array, Array]:
        """Positions (ngeom, 3) and orientations (ngeom, 9, row-major) in {w} of :attr:`model`'s
        geoms: views, overwritten by the next step."""

    def object_poses(self) -> Array:
        """The dynamic objects' poses in {w}, rows ``[x, y, z, qw, qx, qy, qz]``, (n, 7) (a view,
        overwritten by the next step; (0, 7) when every object is static)."""

    def grip(self, on: bool) -> int:
        """Close the grip on the dynamic object the tool touches (``on`` False: open it); the
        index in ``scene.bodies`` of the object held, or -1."""

    @property
    def T_w_MRF(self) -> Array:
        """Pose of {MRF} in {w} (4, 4), a new array."""

    @property
    def V_w_MRF(self) -> Array:
        """Twist ``[v; w]`` of {MRF} in {w} (6,), a new array."""

    @property
    def contact(self) -> ContactResult:
        """The tool's last contact evaluation."""

    @property
    def status(self) -> int:
        """Why the slave did not follow the command exactly (bits of :class:`~app.slave.arm.ArmStatus`; 0 for the tool)."""

    @property
    def fault(self) -> str | None:
        """Why every reading is invalid until a reset, or None."""

    @property
    def link_force(self) -> float:
        """The world's force on the slave's links (not its tool) at the last step (N); 0 for the tool.

        It loads the arm, never the F/T sensor, so the operator does not feel it."""


def make_slave(scene: Scene, accommodation: bool = True, period: float = DEFAULT_PERIOD) -> Slave:
    """The slave the scene asks for (``scene.spec.slave.kind``)."""
    if scene.spec.slave.kind == "tool":
        return VirtualSlave(scene, accommodation, period)
    return ArmSlave(scene, accommodation, period)
