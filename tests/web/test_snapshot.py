"""What the page is sent about a tick, without a browser."""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
import viser

from app.controller.types import SlaveCommand
from app.session.loop import LoopConfig, ServoLoop
from app.session.script import OperatorScript
from app.session.spec import load_session
from app.slave.arm import ArmStatus
from app.spatial import invert_pose, make_pose
from app.web.controls import status_notes
from app.web.headless import free_port
from app.web.scene_view import (
    SHOWN_RESOLUTION,
    SHOWN_TURN,
    T_V_0,
    T_V_W,
    WORLD_ORIGIN_V,
    SceneView,
    turn_between,
    wxyz_position_to_pose,
)
from app.web.snapshot import MAX_SHOWN_CONTACTS, SNAPSHOT_BYTES, SharedSnapshot, Snapshot, take_snapshot


def test_an_arm_out_of_reach_is_flagged_in_the_snapshot() -> None:
    """The PUMA pushed up past its reach: the tick's slave status (TRACKING) reaches the page's data."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate").with_changes(slave="puma560")))
    assert take_snapshot(loop.tick(), np.eye(4)).slave_status == ArmStatus.NONE
    up = SlaveCommand(active=True, mode="rate", twist=np.array([0.0, 0.0, 0.25, 0.0, 0.0, 0.0]))
    for _ in range(3000):
        loop.slave.step(up)
    snap = take_snapshot(loop.tick(), np.eye(4))
    assert ArmStatus(snap.slave_status) & ArmStatus.TRACKING
    # The controller read the slave's reading, which carries the same bits into its output.
    assert ArmStatus(loop.controller.out.slave_status) & ArmStatus.TRACKING


def test_the_scene_view_draws_the_arm_links_where_the_arm_is() -> None:
    """A real viser server (no browser): every arm geom placed at the arm's own geom pose, drawn as
    instances of unit parts (a capsule: its shaft and a cap at each end, its axis through them)."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate").with_changes(slave="puma560")))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        view = SceneView(server, loop, on_hand_moved=lambda _T: None)
        model = loop.slave.model
        assert len(view.slave_geoms.meshes) == model.ngeom == 11  # pedestal and link capsules
        up = SlaveCommand(active=True, mode="rate", twist=np.array([0.05, 0.0, 0.05, 0.0, 0.0, 0.0]))
        for _ in range(300):
            loop.slave.step(up)
        view.update(take_snapshot(loop.tick(), np.eye(4)))
        xpos, xmat = loop.slave.geom_poses()
        for g, T_v_geom in view.slave_geoms.poses.items():
            np.testing.assert_allclose(T_v_geom[0:3, 3], xpos[g] + WORLD_ORIGIN_V, atol=1e-6)
            np.testing.assert_allclose(T_v_geom[0:3, 0:3], xmat[g].reshape(3, 3), atol=1e-5)
        capsules = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE]
        caps = np.asarray(server.scene.get_handle_by_name("/slave/cap").batched_positions)  # type: ignore[union-attr]
        shafts = np.asarray(server.scene.get_handle_by_name("/slave/shaft").batched_positions)  # type: ignore[union-attr]
        assert len(shafts) == len(capsules) > 0
        assert len(caps) == 2 * len(capsules)
        for i, g in enumerate(capsules):
            axis = xmat[g].reshape(3, 3)[:, 2] * model.geom_size[g][1]
            centre = xpos[g] + WORLD_ORIGIN_V
            np.testing.assert_allclose(shafts[i], centre, atol=1e-6)
            np.testing.assert_allclose(caps[2 * i : 2 * i + 2], [centre + axis, centre - axis], atol=1e-6)
    finally:
        server.stop()


def test_the_ideal_tool_has_no_links_to_draw() -> None:
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    snap = take_snapshot(loop.tick(), np.eye(4))
    assert snap.slave_geom_xpos.shape == (0, 3)
    assert snap.slave_geom_xmat.shape == (0, 3, 3)


def test_the_scene_view_sends_only_what_a_pixel_would_show() -> None:
    """A move under the space's resolution (half a pixel when the space fills 1000 px) and force
    noise under 0.1 N send nothing; a larger move, a larger force change, do."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        view = SceneView(server, loop, on_hand_moved=lambda _T: None)
        snap = take_snapshot(loop.tick(), np.eye(4))
        step = view.resolution["device"]
        assert step == pytest.approx(SHOWN_RESOLUTION * np.ptp(view.device_box_v, axis=0).max())

        def grip_raised(dz: float) -> Snapshot:
            T_0_G = snap.T_0_G.copy()
            T_0_G[2, 3] += dz
            return replace(snap, T_0_G=T_0_G)

        view.update(snap)
        sent = np.array(view.grip.position)
        view.update(grip_raised(0.4 * step))
        np.testing.assert_array_equal(view.grip.position, sent)
        view.update(grip_raised(1.5 * step))
        assert view.grip.position[2] == pytest.approx(sent[2] + 1.5 * step)

        def pushed(fz: float) -> Snapshot:
            return replace(snap, F_MRF=np.array([0.0, 0.0, fz, 0.0, 0.0, 0.0]))

        view.update(pushed(8.0))
        label, arrow = view.labels["task_MRF"], view.arrows["world"]
        assert label.text == "8.0 N"
        assert view.arrow_keys["world"] == ("task_MRF/force",)  # no moment: one arrow in the world's node
        np.testing.assert_array_equal(arrow.colors, [[230, 60, 40]])
        points = np.array(arrow.points)
        view.update(pushed(8.01))  # the tip moves 0.13e-3 of the space's size: under half a pixel
        np.testing.assert_array_equal(arrow.points, points)
        view.update(pushed(8.09))  # 1.2e-3 of the size: drawn, but the label keeps its text
        assert label.text == "8.0 N"
        assert not np.array_equal(arrow.points, points)
        view.update(pushed(8.3))
        assert label.text == "8.3 N"
    finally:
        server.stop()


def test_the_gizmo_moved_by_the_server_goes_out_with_the_scenes_redraw() -> None:
    """The hand-target gizmo put somewhere by the server (Reset, a script, the bench's drag) is sent
    with the next scene redraw, in the scene's websocket window, not at once in a window of its own."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        T_0_G = loop.reading.T_0_G.copy()
        view = SceneView(server, loop, on_hand_moved=lambda _T: None)  # the gizmo on the grip
        at_grip = T_V_0 @ T_0_G
        np.testing.assert_allclose(view.hand_target.position, at_grip[0:3, 3])
        snap = take_snapshot(loop.tick(), np.eye(4))
        T_0_H = T_0_G.copy()
        T_0_H[0, 3] += 0.02
        view.set_hand_target(T_0_H)
        np.testing.assert_allclose(view.hand_target.position, at_grip[0:3, 3])  # not yet
        view.update(snap)
        np.testing.assert_allclose(view.hand_target.position, (T_V_0 @ T_0_H)[0:3, 3])
    finally:
        server.stop()


def test_the_wrench_arrows_of_a_space_are_one_node_with_their_own_colours() -> None:
    """The world's force and moment arrows are drawn by one node: two arrows, the task wrench's red
    and its darker shade for the moment, each from {MRF}; with no wrench the node is hidden."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        view = SceneView(server, loop, on_hand_moved=lambda _T: None)
        snap = take_snapshot(loop.tick(), np.eye(4))
        zero = np.zeros(6)
        view.update(replace(snap, F_MRF=np.array([0.0, 0.0, 8.0, 0.5, 0.0, 0.0]), G_F_T=zero, G_F_RD=zero))
        world = view.arrows["world"]
        assert view.arrow_keys["world"] == ("task_MRF/force", "task_MRF/moment")
        np.testing.assert_array_equal(world.colors, [[230, 60, 40], [126, 33, 22]])  # 0.55 of the red
        points = np.asarray(world.points)
        assert points.shape == (2, 2, 3)
        assert world.visible
        np.testing.assert_allclose(points[:, 0], np.tile(view.mrf.position, (2, 1)), atol=1e-6)
        assert points[0, 1, 2] > points[0, 0, 2]
        assert points[1, 1, 0] > points[1, 0, 0]
        view.update(replace(snap, F_MRF=zero, G_F_T=zero, G_F_RD=zero))
        assert view.arrow_keys["world"] == ()
        assert not world.visible
    finally:
        server.stop()


def _turned_about_z(T: np.ndarray, angle: float, move: tuple[float, float, float]) -> np.ndarray:
    """``T`` turned by ``angle`` (rad) about {w}'s z at its origin and moved by ``move`` (m)."""
    c, s = np.cos(angle), np.sin(angle)
    return make_pose(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ T[0:3, 0:3], T[0:3, 3] + move)


def test_the_tool_moves_as_one_node_and_a_turn_is_sent_past_its_tolerance() -> None:
    """The tool and {S} ride on /mrf: moving the tool re-sends /mrf's pose only (the tool's own pose
    in /mrf stays as sent), it is drawn and picked where the snapshot has it; a move with a turn
    under :data:`SHOWN_TURN` sends the move and not the turn; a turn past it is sent."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        view = SceneView(server, loop, on_hand_moved=lambda _T: None)
        snap = take_snapshot(loop.tick(), loop.controller.slave.T_MRF_S)
        view.update(snap)
        tool_pose = wxyz_position_to_pose(view.tool.wxyz, view.tool.position)
        sensor_pose = wxyz_position_to_pose(view.sensor.wxyz, view.sensor.position)
        mrf_wxyz = np.array(view.mrf.wxyz)

        def moved(angle: float) -> Snapshot:
            T_w_MRF = _turned_about_z(snap.T_w_MRF, angle, (0.02, -0.01, 0.03))
            return replace(snap, T_w_MRF=T_w_MRF, T_w_S=T_w_MRF @ loop.controller.slave.T_MRF_S)

        small = 0.5 * SHOWN_TURN
        view.update(moved(small))
        np.testing.assert_array_equal(wxyz_position_to_pose(view.tool.wxyz, view.tool.position), tool_pose)
        np.testing.assert_array_equal(wxyz_position_to_pose(view.sensor.wxyz, view.sensor.position), sensor_pose)
        np.testing.assert_array_equal(view.mrf.wxyz, mrf_wxyz)  # the turn under the tolerance: not sent
        T_w_MRF = moved(small).T_w_MRF
        np.testing.assert_allclose(view.mrf.position, T_w_MRF[0:3, 3] + WORLD_ORIGIN_V, atol=1e-12)
        # Drawn: /mrf's pose then the tool's in it; off the snapshot's by the turn not sent (about
        # {MRF}: a point of the tool within tool_radius of it moves less than SHOWN_TURN * that).
        T_v_tool = wxyz_position_to_pose(view.mrf.wxyz, view.mrf.position) @ tool_pose
        expected = T_V_W @ T_w_MRF @ invert_pose(loop.slave.scene.tool.T_T_MRF)
        local = np.asarray(view.tool.vertices, dtype=float)
        vertices = local @ T_v_tool[0:3, 0:3].T + T_v_tool[0:3, 3]
        off = np.linalg.norm(vertices - (local @ expected[0:3, 0:3].T + expected[0:3, 3]), axis=1)
        assert 0.0 < off.max() <= small * view.tool_radius * (1.0 + 1e-6)
        # A click straight down through the moved tool lands on it (the ray test follows /mrf).
        centre = vertices.mean(axis=0)
        hit = view.pick(centre + np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0]))
        assert hit is not None
        assert vertices[:, 2].min() - 1e-4 <= hit[2] <= vertices[:, 2].max() + 1e-4

        view.update(moved(2.0 * SHOWN_TURN))
        assert turn_between(np.asarray(view.mrf.wxyz), mrf_wxyz) == pytest.approx(2.0 * SHOWN_TURN, rel=1e-6)
    finally:
        server.stop()


def _assert_same(read: Snapshot | None, taken: Snapshot) -> None:
    assert read is not None
    for f in fields(Snapshot):
        a, b = getattr(read, f.name), getattr(taken, f.name)
        if isinstance(b, np.ndarray):
            np.testing.assert_array_equal(a, b, err_msg=f.name)
            assert a.shape == b.shape, f.name
        else:
            assert a == b, f.name


def test_a_device_that_stopped_is_said_in_the_snapshot_and_the_status(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The plant's physics went unstable (a NaN joint speed): the snapshot carries the plant's
    reason and the page's status block says the device stopped; before, the page showed a device
    frozen at MuJoCo's reset angles without a word. A running device's is empty."""
    monkeypatch.chdir(tmp_path)
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    snap = take_snapshot(loop.tick(), np.eye(4))
    assert snap.device_fault == ""
    assert "device stopped" not in status_notes(snap, "")
    loop.plant.data.qvel[loop.plant.dof_slice.start] = np.nan
    snap = take_snapshot(loop.tick(), np.eye(4))
    assert "went unstable" in snap.device_fault
    assert f"**device stopped:** {snap.device_fault}" in status_notes(snap, "")


def test_a_published_snapshot_reads_back_as_taken() -> None:
    """Through the shared buffer (arrays in the float block, the rest pickled): every field equal,
    the hand target both held and let go, the free peg's pose and a contact's points included."""
    session = load_session("peg_carry")
    loop = ServoLoop(LoopConfig.from_session(session))
    script = OperatorScript.for_loop(session.data, loop)
    shared = SharedSnapshot()
    assert shared.read() is None
    for _ in range(session.data.n_ticks):
        script.before_tick(loop)
        if loop.tick().contact.count:
            break
    taken = take_snapshot(loop.record, np.eye(4), playing=Path("x.toml"), play_left=1.5, speed=2.0)
    assert taken.contact_points_w.shape[0] > 0
    assert taken.object_poses.shape == (1, 7)
    assert taken.T_0_H is not None
    shared.write(taken)
    _assert_same(shared.read(), taken)
    released = replace(taken, T_0_H=None, fault_message="stalled", paused=True)
    shared.write(released)
    _assert_same(shared.read(), released)


def test_contacts_beyond_the_buffer_are_trimmed_for_display() -> None:
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    many = np.ones((SNAPSHOT_BYTES // 8 // 3, 3))
    taken = replace(take_snapshot(loop.tick(), np.eye(4)), contact_points_w=many, contact_normals_w=many)
    shared = SharedSnapshot()
    shared.write(taken)
    read = shared.read()
    assert read is not None
    assert read.contact_points_w.shape == read.contact_normals_w.shape == (MAX_SHOWN_CONTACTS, 3)
    _assert_same(replace(read, contact_points_w=many, contact_normals_w=many), taken)
