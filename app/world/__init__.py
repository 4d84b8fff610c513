"""The virtual world: scenes, FCL contact on trimesh objects, and the virtual slave tool.

Public API::

    from app.world import load_scene, ContactModel, contact_wrench, VirtualSlave

    scene = load_scene("probe")
    result = contact_wrench(scene, T_w_MRF)  # result.wrench_S, result.points_w, result.valid
"""

from app.world.contact import ContactModel, ContactResult, contact_wrench
from app.world.scene import Scene, available_scenes, load_scene
from app.world.slave import VirtualSlave

__all__ = ["ContactModel", "ContactResult", "Scene", "VirtualSlave", "available_scenes", "contact_wrench", "load_scene"]
