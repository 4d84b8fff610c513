"""The virtual world: scenes, FCL contact on trimesh objects, and the virtual slave tool.

Public API::

    from app.world import load_scene, ContactModel, contact_wrench, VirtualSlave
"""

from app.world.contact import ContactModel, ContactResult, contact_wrench
from app.world.scene import Scene, available_scenes, load_scene

__all__ = ["ContactModel", "ContactResult", "Scene", "available_scenes", "contact_wrench", "load_scene"]
