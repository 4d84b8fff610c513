"""Dynamic objects (app/world/dynamics.py) against known answers: Coulomb friction, momentum and
restitution of an impact, rest, FCL contact geometry, energy.

The tool here is kinematic (its pose prescribed) or a free point mass integrated in the test (for
the impact): the world's contact with it and the objects' motion are the real code.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh

from app.errors import ContactInputError
from app.world.contact import ContactModel
from app.world.dynamics import MovingWorld, _bvh, fcl_contacts
from app.world.scene import (
    DynamicSpec,
    ObjectSpec,
    Pose,
    SceneFile,
    SphereSpec,
    ToolSpec,
    build_scene,
    load_scene,
)

DT = 1e-3
TIP = 0.005  # tool sphere radius (m)


def tool_scene(objects: tuple[ObjectSpec, ...], gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)) -> SceneFile:
    """A scene of ``objects`` and a tool that is one 5 mm sphere centred on {MRF}."""
    tool = ToolSpec(
        mass=0.1,
        inertia=(1e-5, 1e-5, 1e-5, 0.0, 0.0, 0.0),
        home=Pose(position=(-0.5, 0.0, 0.5)),
        spheres=(SphereSpec(center=(0.0, 0.0, 0.0), radius=TIP),),
    )
    return SceneFile(name="test", tool=tool, objects=objects, gravity=gravity)


def pose(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[0:3, 3] = x, y, z
    return T


def test_box_pushed_at_constant_speed_needs_mu_m_g() -> None:
    scene = load_scene("box_push")
    box = scene.bodies[0]
    mu = box.object.friction
    world = MovingWorld(scene, DT)
    v = 0.05
    V = np.array([v, 0.0, 0.0, 0.0, 0.0, 0.0])
    fx, x = [], []
    for i in range(2500):  # contact after 0.1 s, then 2.4 s of sliding
        T = pose(-0.035 + v * i * DT, 0.0, 0.02)
        fx.append(world.wrench(T, V).force_w[0])
        world.step(DT)
        x.append(world.poses()[0][0, 3])
    steady = -np.mean(fx[1500:])
    # Elliptic cone, sliding: the friction is mu N exactly; the rest is the tip's own friction
    # on the face (the stylus slides up and down it as the box rocks) and the rocking.
    assert steady == pytest.approx(mu * box.mass * 9.81, rel=0.02)
    assert (x[-1] - x[1500]) / (998 * DT) == pytest.approx(v, rel=0.01)  # the box keeps the tool's pace


def _impact(damping: float) -> tuple[float, float, float, float, float]:
    """A free 0.1 kg tool at 0.2 m/s hits a free 0.2 kg box head on, no gravity. Returns the
    tool's and box's velocities after, the restitution of the linear spring-dashpot contact,
    and the momentum and kinetic energy before."""
    far = ObjectSpec(name="far", box=(0.1, 0.1, 0.1), stiffness=1000.0, pose=Pose(position=(10.0, 0.0, 0.0)))
    box = ObjectSpec(
        name="box",
        box=(0.05, 0.05, 0.05),
        stiffness=2000.0,
        damping=damping,
        dynamic=DynamicSpec(mass=0.2),
    )
    scene = build_scene(tool_scene((far, box), gravity=(0.0, 0.0, 0.0)))
    world = MovingWorld(scene, DT)
    m_t, m_o, v0 = 0.1, 0.2, 0.2
    x, v = -0.035, v0
    for _ in range(400):
        V = np.array([v, 0.0, 0.0, 0.0, 0.0, 0.0])
        f = world.wrench(pose(x, 0.0, 0.0), V).force_w[0]
        world.step(DT)
        v += f / m_t * DT  # the same semi-implicit Euler as MuJoCo's for the box
        x += v * DT
    m_red = m_t * m_o / (m_t + m_o)
    zeta = damping / (2.0 * math.sqrt(2000.0 * m_red))
    e = math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta**2))
    return v, float(world.twists()[0][0]), e, m_t * v0, 0.5 * m_t * v0**2


def test_elastic_impact_exchanges_momentum_and_keeps_energy() -> None:
    v_t, v_o, e, p0, k0 = _impact(damping=0.0)
    assert e == 1.0
    assert 0.1 * v_t + 0.2 * v_o == pytest.approx(p0, rel=1e-9)  # equal and opposite impulses
    # Elastic: v_o = 2 m_t / (m_t + m_o) v0 = 0.1333 m/s, v_t = -0.0667 m/s.
    assert v_o == pytest.approx(2 * 0.1 / 0.3 * 0.2, rel=0.01)
    # Semi-implicit Euler samples the spring: its energy error is of order (omega h)^2 / 4, omega
    # = sqrt(k / m_red) = 173 rad/s here (0.75 %); 0.2 % was measured.
    assert 0.5 * 0.1 * v_t**2 + 0.5 * 0.2 * v_o**2 <= k0 * (1.0 + (173.2 * DT) ** 2 / 4)


def test_damped_impact_rebounds_within_the_models_restitution() -> None:
    v_t, v_o, e, p0, _ = _impact(damping=4.0)
    assert 0.1 * v_t + 0.2 * v_o == pytest.approx(p0, rel=1e-9)
    # The separation speed over the approach speed: at least the linear spring-dashpot's
    # restitution (the clamp at zero force ends the impact before the dashpot would pull), at most 1.
    measured = (v_o - v_t) / 0.2
    assert e < 0.9
    assert e - 0.01 <= measured <= 1.0


def test_a_closed_sequence_of_impacts_does_not_gain_energy() -> None:
    """A free 50 g tool between two free 1 kg boxes, no gravity, damping and friction off: sent
    at 0.3 m/s towards the right box, 15 mm off its centre line (so the boxes spin), it bounces
    between them until all three separate. The system is closed: its momentum is constant and
    its energy (kinetic, the boxes' rotation included, measured whenever nothing touches) stays
    that of the start.

    Tolerance: semi-implicit Euler samples each contact's linear spring, and an impact's energy
    error depends on where the contact starts within a step: at most 1.01 (omega h)^2 / 4 of
    the energy, worst over the entry phase (computed for the one-dimensional spring), with omega
    = sqrt(k / m_red) largest for the smallest effective mass of a box at its face (the lever
    arm up to its half-diagonal). The bound is taken 1.05 times that per impact, summed.
    """
    m_t, mass, k, v0 = 0.05, 1.0, 1000.0, 0.3
    far = ObjectSpec(name="far", box=(0.1, 0.1, 0.1), stiffness=1000.0, pose=Pose(position=(10.0, 0.0, 0.0)))

    def box(name: str, x: float) -> ObjectSpec:
        return ObjectSpec(
            name=name,
            box=(0.05, 0.05, 0.05),
            stiffness=k,
            damping=0.0,
            friction=0.0,
            pose=Pose(position=(x, 0.0, 0.0)),
            dynamic=DynamicSpec(mass=mass),
        )

    scene = build_scene(tool_scene((far, box("left", -0.06), box("right", 0.06)), gravity=(0.0, 0.0, 0.0)))
    world = MovingWorld(scene, DT)
    p, v = np.array([0.0, 0.015, 0.0]), np.array([v0, 0.0, 0.0])

    def energy() -> float:
        T, twist = world.poses(), world.twists()
        e = 0.5 * m_t * v @ v
        for b, body in enumerate(scene.bodies):
            R, w = T[b][0:3, 0:3], twist[b, 3:6]
            v_c = twist[b, 0:3] + np.cross(w, R @ body.com_B)
            e += 0.5 * body.mass * v_c @ v_c + 0.5 * w @ (R @ body.inertia_B @ R.T) @ w
        return float(e)

    def momentum() -> np.ndarray:
        return m_t * v + sum(body.mass * (world.twists()[b, 0:3]) for b, body in enumerate(scene.bodies))

    e0, p0 = energy(), momentum()
    after, touching = [], False
    for _ in range(30_000):
        r = world.wrench(pose(*p), np.concatenate([v, np.zeros(3)]))
        if touching and not r.count:
            after.append(energy())
        touching = r.count > 0
        world.step(DT)
        v = v + r.force_w / m_t * DT  # the same semi-implicit Euler as MuJoCo's for the boxes
        p = p + v * DT
    assert not touching
    box_body = scene.bodies[0]
    i_min = float(np.linalg.eigvalsh(box_body.inertia_B).min())
    m_eff = 1.0 / (1.0 / mass + (0.025 * math.sqrt(3.0)) ** 2 / i_min)
    omega = math.sqrt(k * (1.0 / m_t + 1.0 / m_eff))
    per_impact = 1.05 * 1.01 * (omega * DT) ** 2 / 4  # 0.68 %
    assert len(after) == 3  # right, left, right again; then all three part
    for n, e in enumerate(after, start=1):
        assert abs(e / e0 - 1.0) <= n * per_impact  # measured 0.48 %, 0.39 %, 0.31 %
    assert momentum() == pytest.approx(p0, abs=1e-12 * m_t * v0 + 1e-15)
    assert abs(world.twists()[:, 5]).max() > 0.1  # the boxes spin: the reaction's torque is in play


def test_box_at_rest_on_the_table_does_not_drift_in_10_s() -> None:
    world = MovingWorld(load_scene("box_push"), DT)  # the tool at home, 3 cm away
    for _ in range(500):
        world.step(DT)
    start = world.poses()[0]
    for _ in range(10_000):
        world.step(DT)
    end = world.poses()[0]
    assert np.linalg.norm(end[0:3, 3] - start[0:3, 3]) < 1e-6
    assert np.linalg.norm(end[0:3, 0:3] - start[0:3, 0:3]) < 1e-6


def _fcl_pair(a: trimesh.Trimesh, T_a: np.ndarray, b: trimesh.Trimesh) -> np.ndarray:
    import fcl

    obj_a, obj_b = _bvh(a), _bvh(b)
    obj_a.setTransform(fcl.Transform(T_a[0:3, 0:3], T_a[0:3, 3]))
    return fcl_contacts(obj_a, obj_b, np.asarray(a.vertices, dtype=float), T_a)


def test_fcl_box_on_box_depth_normal_and_centre_of_pressure() -> None:
    lower = trimesh.creation.box(extents=(0.2, 0.2, 0.1))  # top face z = 0.05
    upper = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    # Sunk 2 mm, overhanging the lower box's edge by 3 cm in x: the overlap is x in [0.05, 0.1].
    rows = _fcl_pair(upper, pose(0.1, 0.02, 0.098), lower)
    assert len(rows) == 1
    p, n, depth = rows[0, 0:3], rows[0, 3:6], rows[0, 6]
    assert depth == pytest.approx(0.002, abs=1e-9)
    assert n == pytest.approx([0.0, 0.0, -1.0], abs=1e-9)  # from the upper box into the lower
    # Within the overlap x in [0.05, 0.1], y in [-0.03, 0.07] (FCL's points are the corners and
    # where triangle edges cross, so their mean is near, not at, its middle).
    assert 0.05 <= p[0] <= 0.1
    assert -0.03 <= p[1] <= 0.07


def test_fcl_sphere_on_plane_depth_and_normal() -> None:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    slab = trimesh.creation.box(extents=(1.0, 1.0, 0.1))  # top face z = 0.05
    rows = _fcl_pair(ball, pose(0.01, 0.02, 0.097), slab)  # sunk 3 mm
    assert len(rows) == 1
    assert rows[0, 3:6] == pytest.approx([0.0, 0.0, -1.0], abs=1e-9)
    # 3 mm to within the tessellation's sagitta: the depth is that of the deepest vertex over
    # FCL's patch (FCL's own, the triangles', was 1.3 mm), and the patch's box of points need not
    # hold the pole's vertex: one within 10 deg of it counts, r (1 - cos 10 deg) = 0.76 mm higher at most
    assert 0.003 - 0.05 * (1.0 - math.cos(math.radians(10.0))) <= rows[0, 6] <= 0.003


def test_the_slave_topples_the_stack_and_feels_it() -> None:
    """Through the ideal tool slave (the servo tick's path): the stylus driven along +x at 4 cm/s
    meets the middle block, the F/T sensor reads the push, and the tower falls."""
    from app.controller.types import SlaveCommand
    from app.slave.tool import VirtualSlave

    slave = VirtualSlave(load_scene("stack_topple"))
    slave.reset(pose(-0.025, 0.0, 0.11))  # the tip 5 mm short of the middle block
    world = slave.contact_model
    assert isinstance(world, MovingWorld)
    command = SlaveCommand(active=True, mode="rate", twist=np.array([0.04, 0.0, 0.0, 0.0, 0.0, 0.0]))
    felt = 0.0
    for _ in range(1200):
        felt = min(felt, slave.step(command).wrench_S[0])
    assert world.poses()[2][2, 3] < 0.05  # the top block (centre 0.15 m up at the start) is down
    assert felt < -0.05  # the sensor felt the push (the force on the tool is along -x)


def test_the_moving_world_reads_a_resting_object_as_the_static_model_does() -> None:
    """One compiled call evaluates the static model and each object's own (in its frame {B}):
    with the box at rest at its initial pose, the tool's wrench and contacts in {w} are those of
    the same scene with the box static (its object id shifted past the static objects)."""
    moving = load_scene("box_push")
    spec = moving.spec
    static = build_scene(
        dataclasses.replace(spec, objects=tuple(dataclasses.replace(o, dynamic=None) for o in spec.objects))
    )
    world, model = MovingWorld(moving, DT), ContactModel(static)
    # The stylus's tip 1 mm into the box's -x face, tilted 30 deg about y (so the capsule's
    # spheres touch too), moving along +x and turning.
    T = pose(-0.029, 0.005, 0.02)
    T[0:3, 0:3] = np.array([[0.866, 0.0, 0.5], [0.0, 1.0, 0.0], [-0.5, 0.0, 0.866]])
    T[0:3, 0:3] /= np.linalg.norm(T[0:3, 0:3], axis=0)
    V = np.array([0.01, 0.002, 0.0, 0.0, 0.3, 0.0])
    got, want = world.wrench(T, V), model.wrench(T, V)
    assert (want.object_ids == 1).sum() >= 2  # the tip and a capsule sphere on the box
    assert got.w == pytest.approx(want.w, abs=1e-12)

    def ordered(rows: np.ndarray) -> np.ndarray:  # by object, sphere, point (the models' orders differ)
        return rows[np.lexsort((*np.round(rows[:, 0:3].T, 9), rows[:, 7], rows[:, 8]))]

    # The box is object 1 in both: after the one static object, and second in the file.
    assert ordered(got.contacts) == pytest.approx(ordered(want.contacts), abs=1e-12)
    # The reaction on the box is the tool's force, opposite.
    assert world._xfrc[0, 0:3] == pytest.approx(-got.force_w, abs=1e-12)


def test_the_moving_world_refuses_bad_poses_as_the_contact_model_does() -> None:
    world = MovingWorld(load_scene("box_push"), DT)
    T = pose(-0.029, 0.0, 0.02)
    assert world.wrench(T.tolist()).w == pytest.approx(world.wrench(T).w)  # nested lists are read
    T_nan = T.copy()
    T_nan[0, 3] = np.nan
    bad = world.wrench(T_nan, np.zeros(6))
    assert not bad.valid
    assert bad.error == "non-finite tool pose"
    assert not bad.w.any()
    assert not world._xfrc.any()
    skew = T.copy()
    skew[0, 0] = 1.1
    with pytest.raises(ContactInputError, match="not a rigid transform"):
        world.wrench(skew)
    with pytest.raises(ContactInputError, match=r"V_w_MRF must have shape \(6,\)"):
        world.wrench(T, np.zeros(3))
