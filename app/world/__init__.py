"""The virtual world that replaces the paper's slave environment: scenes, their meshes, the
contact wrench on the tool's sphere set, and the objects that move (:mod:`app.world.dynamics`:
one MuJoCo model; MuJoCo's collision between convex objects, python-fcl's where a mesh is not
convex, chosen and measured as that module's docstring says).

The free peg (``peg_carry``) goes into a hole through MuJoCo's collision, with the holed part
authored as convex pieces (eight boxes around the bore) and the peg a MuJoCo cylinder: a step
with the peg in the bore takes 8.7 us (median, measured), where python-fcl's BVH on the holed
mesh took 10-20 ms a step and its 32 contacts on the hole's floor, as springs at the 1 ms step,
threw the peg through the wall. The tool carries it in a grip (``MovingWorld.grip``): a
critically damped spring computed with the tool's contacts, so the F/T sensor reads the held
peg's weight and its contacts at the same instant the peg feels them (a MuJoCo weld to a mocap
body would be solved implicitly, but its force is known only after the step, inside MuJoCo's
constraint forces; not measured against this). A session closes and opens it with ``grip``
events (``sessions/peg_carry.toml``), through the loop's ``set_grip`` and the slave's ``grip``.

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
