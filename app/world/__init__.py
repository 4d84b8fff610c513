"""The virtual world that replaces the paper's slave environment: scenes, their meshes, the
contact wrench on the tool's sphere set, and the objects that move (:mod:`app.world.dynamics`:
one MuJoCo model; MuJoCo's collision between convex objects, python-fcl's where a mesh is not
convex, chosen and measured as that module's docstring says).

The slave that touches it (tool, arms, F/T sensor, NTRFC) is :mod:`app.slave`; the world never
imports it.

Public API::

    from app.world import load_scene, ContactModel, contact_wrench

    scene = load_scene("probe")
    result = contact_wrench(scene, T_w_MRF)  # result.wrench_S, result.points_w, result.valid
"""

from app.world.contact import ContactModel, ContactResult, contact_wrench
from app.world.scene import Scene, available_scenes, load_scene

__all__ = ["ContactModel", "ContactResult", "Scene", "available_scenes", "contact_wrench", "load_scene"]
