"""What a scene redraw sends the page, without a browser: how many messages, and the frames' axes and
contact normals drawn in shared nodes where they are."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest
import viser
from viser._messages import MeshMessage
from viser.infra._messages import Message

from app.session.loop import LoopConfig, ServoLoop
from app.session.script import OperatorScript
from app.session.spec import load_session
from app.spatial import matrix_to_quat
from app.web.headless import free_port
from app.web.scene_view import (
    CONTACT_COLOR,
    CONTACT_NORMAL_UNITS,
    DEVICE_ORIGIN_V,
    WORLD_ORIGIN_V,
    SceneView,
    drawn_mesh,
    turn_between,
    wxyz_position_to_pose,
)
from app.web.snapshot import Snapshot, take_snapshot

#: Servo ticks between two redraws: the page's 40 Hz at the session's 1 kHz.
TICKS_PER_REDRAW = 25


def recorded_messages(server: viser.ViserServer) -> list[Message]:
    """A list every scene message ``server`` queues from now on is appended to (and still sent)."""
    sent: list[Message] = []
    interface = server.scene._websock_interface
    queue = interface.queue_message

    def counted(message: Message) -> None:
        sent.append(message)
        queue(message)

    interface.queue_message = counted  # type: ignore[method-assign]
    return sent


@contextmanager
def _viewed(session_name: str = "probe_rate") -> Iterator[tuple[ServoLoop, OperatorScript, SceneView, list[Message]]]:
    """A loop of ``session_name`` with its script, pressed into contact, its view on a real viser
    server (no browser), and the list each scene message the view queues is appended to."""
    session = load_session(session_name)
    loop = ServoLoop(LoopConfig.from_session(session))
    script = OperatorScript.for_loop(session.data, loop)
    for _ in range(session.data.n_ticks):
        script.before_tick(loop)
        if loop.tick().contact.count:
            break
    assert loop.record.contact.count, "the script never made contact"
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        view = SceneView(server, loop, on_hand_moved=lambda _T: None)
        sent = recorded_messages(server)
        yield loop, script, view, sent
    finally:
        server.stop()


def _redraw(loop: ServoLoop, script: OperatorScript | None = None) -> Snapshot:
    """The snapshot a redraw shows after the ticks between two redraws (the script's, if given)."""
    for _ in range(TICKS_PER_REDRAW):
        if script is not None:
            script.before_tick(loop)
        loop.tick()
    return take_snapshot(loop.record, loop.controller.slave.T_MRF_S)


def test_a_redraw_sends_at_most_one_message_per_moving_thing() -> None:
    """Pressed on the surface with the hand circling 2 cm a second (everything moves every redraw):
    a redraw sends at most the gizmo's pose (2), the links' three batches (2 arrays each), {G} and
    {G0} (2 each), /mrf (2), the contact points, each space's arrows (points and, when the set of
    arrows changes, colours) and four force labels (position and text): 26. The contact normals
    and the frames {0}, {w}, {S} send nothing of their own. The same snapshot again sends nothing."""
    with _viewed() as (loop, script, view, sent):
        view.update(_redraw(loop, script))
        centre = loop.reading.T_0_G.copy()
        counts = []
        for i in range(40):
            T_0_H = centre.copy()
            T_0_H[0:2, 3] += 0.02 * np.array([np.cos(i * np.pi / 20), np.sin(i * np.pi / 20)])
            T_0_H[2, 3] -= 0.03
            loop.set_hand_target(T_0_H)  # the script's hand no more: the hand circles
            view.set_hand_target(T_0_H)
            snap = _redraw(loop)
            sent.clear()
            view.update(snap)
            counts.append(len(sent))
        assert max(counts) <= 26, counts
        assert not any(getattr(m, "name", "").startswith(("/contact_normals", "/base_frames", "/mrf/")) for m in sent)
        sent.clear()
        view.update(snap)
        assert sent == []


def test_frames_share_axes_nodes_at_their_poses() -> None:
    """{0} and {w}: two instances of one node at the spaces' origins; {MRF} and {S}: two instances of
    one node in /mrf, {S}'s at its pose in {MRF} (and the /mrf/sensor group holding its label there)."""
    with _viewed() as (loop, script, view, _sent):
        snap = _redraw(loop, script)
        view.update(snap)
        base = view.server.scene.get_handle_by_name("/base_frames")
        assert isinstance(base, viser.BatchedAxesHandle)
        np.testing.assert_allclose(base.batched_positions, [DEVICE_ORIGIN_V, WORLD_ORIGIN_V], atol=1e-7)
        T_MRF_S = loop.controller.slave.T_MRF_S
        axes = view.mrf_axes
        sensor = wxyz_position_to_pose(axes.batched_wxyzs[1], axes.batched_positions[1])
        np.testing.assert_allclose(sensor[0:3, 3], T_MRF_S[0:3, 3], atol=1e-6)
        assert turn_between(np.asarray(axes.batched_wxyzs[1], dtype=float), matrix_to_quat(T_MRF_S[0:3, 0:3])) < 1e-6
        np.testing.assert_allclose(view.sensor.position, T_MRF_S[0:3, 3], atol=1e-12)
        np.testing.assert_allclose(axes.batched_positions[0], np.zeros(3))
        scales = np.asarray(axes.batched_scales)
        assert scales.shape == (2,)
        assert scales[1] == pytest.approx(0.75 * scales[0])


def test_contact_normals_are_arrows_of_the_worlds_node() -> None:
    """In contact, the world's arrows node draws each contact's normal in magenta: from the contact
    point, :data:`CONTACT_NORMAL_UNITS` arrow units along its normal (viser frame); the task wrench's
    force arrow is drawn beside them in red; without contact there are none."""
    with _viewed() as (loop, script, view, _sent):
        snap = _redraw(loop, script)
        view.update(snap)
        k = len(snap.contact_points_w)
        assert k > 0
        arrows = view.arrows["world"]
        keys = view.arrow_keys["world"]
        normals = [keys.index(f"contact/{i}") for i in range(k)]
        assert "task_MRF/force" in keys
        points = np.asarray(arrows.points, dtype=float)
        starts = snap.contact_points_w + WORLD_ORIGIN_V
        unit = view.units["world"]
        np.testing.assert_allclose(points[normals, 0], starts, atol=1e-6)
        np.testing.assert_allclose(
            points[normals, 1], starts + CONTACT_NORMAL_UNITS * unit * snap.contact_normals_w, atol=1e-6
        )
        colors = np.asarray(arrows.colors)
        assert (colors[normals] == CONTACT_COLOR).all()
        assert tuple(colors[keys.index("task_MRF/force")]) == (230, 60, 40)
        assert view.contacts.visible
        assert arrows.visible

        free = replace(snap, contact_points_w=np.zeros((0, 3)), contact_normals_w=np.zeros((0, 3)))
        view.update(free)
        assert not any(key.startswith("contact/") for key in view.arrow_keys["world"])
        assert not view.contacts.visible


def test_a_scenes_static_objects_are_one_mesh_node() -> None:
    """peg_carry's nine static objects are sent as one mesh node (one draw a frame, not nine), with
    every one of their drawn triangles."""
    session = load_session("peg_carry")
    loop = ServoLoop(LoopConfig.from_session(session))
    assert len(loop.slave.scene.objects) == 9
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        sent = recorded_messages(server)
        SceneView(server, loop, on_hand_moved=lambda _T: None)
    finally:
        server.stop()
    meshes = [m for m in sent if isinstance(m, MeshMessage) and m.name.startswith("/world/")]
    static = [m for m in meshes if not m.name.startswith("/world/body_")]
    assert [m.name for m in static] == ["/world/objects"]
    faces = sum(len(drawn_mesh(obj.mesh).faces) for obj in loop.slave.scene.objects)
    assert len(static[0].props.faces) == faces
