"""The tick's state block: the row every observer reads holds this tick's values, once a tick."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from app.controller.types import Fault
from app.session.log import TickLog, read_log
from app.session.loop import LoopConfig, ServoLoop
from app.session.metrics import SessionMetrics, _bit_counts
from app.session.run import play, run_session
from app.session.script import OperatorScript
from app.session.spec import SessionFile, SwitchEvent, Waypoint, load_session
from app.session.state import StateBlock
from app.session.tick import TickRecord
from app.slave.arm import ArmStatus
from app.spatial import matrix_to_quat


def test_the_row_holds_each_ticks_values_even_when_only_one_observer_reads_it() -> None:
    """Read on every tick (and by nothing else), the row's grip pose, hand wrench, tool pose and
    contact wrench are the record's of that tick: the reading's pose and hand wrench are computed
    on access, so a row that kept last tick's arrays would fall behind as the hand moves."""
    session = load_session("probe_rate")
    loop = ServoLoop(LoopConfig.from_session(session))
    op = OperatorScript.for_loop(session.data, loop)
    block = loop.record.block
    assert block is not None
    grip, hand, tool, contact = (block.starts[k] for k in ("grip", "hand_G", "tool", "contact_MRF"))
    moved = 0
    last = None
    for _ in range(1500):
        op.before_tick(loop)
        rec = loop.tick()
        row = rec.state()
        T_0_G = rec.reading.T_0_G
        np.testing.assert_array_equal(row[grip : grip + 3], T_0_G[0:3, 3])
        np.testing.assert_allclose(row[grip + 3 : grip + 7], matrix_to_quat(T_0_G[0:3, 0:3]), atol=1e-12)
        np.testing.assert_array_equal(row[hand : hand + 6], rec.reading.wrench_G)
        np.testing.assert_array_equal(row[tool : tool + 3], rec.T_w_MRF[0:3, 3])
        np.testing.assert_array_equal(row[contact : contact + 6], rec.contact_wrench_MRF)
        assert row[block.starts["t"]] == rec.time
        # The blocks past the logged ones, and every switch, at their own names.
        R = block.starts["R_w_MRF"]
        np.testing.assert_array_equal(row[R : R + 9], rec.T_w_MRF[0:3, 0:3].ravel())
        assert row[block.starts["reflecting"]] == float(rec.out.reflecting)
        assert row[block.starts["link_force"]] == rec.link_force
        moved += last is not None and not np.array_equal(last, row[grip : grip + 3])
        last = row[grip : grip + 3].copy()
    assert moved > 100  # the script moves the grip: the comparison above saw changing values


def test_the_row_is_filled_once_a_tick_and_again_after_a_reset() -> None:
    session = load_session("probe_rate")
    loop = ServoLoop(LoopConfig.from_session(session))
    t = loop.record.block.starts["t"]  # type: ignore[union-attr]
    loop.tick()
    row = loop.record.state()
    assert row[t] == loop.dt
    row[t] = -1.0  # a second read in the same tick does not fill it again
    assert loop.record.state()[t] == -1.0
    loop.reset()
    assert loop.record.state()[t] == 0.0


def test_a_scenes_dynamic_objects_are_a_logged_block_of_the_row() -> None:
    """box_push has one dynamic object: its pose is in the row (logged) as the slave has it."""
    session = load_session("box_push")
    loop = ServoLoop(LoopConfig.from_session(session))
    block = loop.record.block
    assert block is not None
    at = block.starts["objects"]
    assert block.names[at : at + 7] == [f"object_box_{a}" for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    assert at + 7 == block.n_logged
    for _ in range(50):
        rec = loop.tick()
    np.testing.assert_array_equal(rec.state()[at : at + 7], loop.slave.object_poses()[0])
    assert rec.state()[block.starts["reflecting"]] == float(rec.out.reflecting)


def test_the_logged_columns_come_first_and_the_rest_is_named() -> None:
    block = StateBlock(3)
    assert block.names[0] == "t"
    assert block.names[block.n_logged :] == [f"R_w_MRF_{a}{b}" for a in range(3) for b in range(3)] + ["reflecting"]
    assert len(block.view("q")) == 3
    assert len(block.row) == len(block.names)


def test_bit_counts_name_the_flags_seen() -> None:
    counts = np.zeros(63, dtype=np.int64)
    counts[int(Fault.BAD_PERIOD).bit_length() - 1] = 4
    counts[int(Fault.OVERSPEED).bit_length() - 1] = 1
    assert _bit_counts(Fault, counts) == {"BAD_PERIOD": 4, "OVERSPEED": 1}
    assert _bit_counts(ArmStatus, np.zeros(63, dtype=np.int64)) == {}


def test_metrics_without_a_log_sum_what_they_sum_with_one() -> None:
    """Without a log the metrics write only the values they read (fill_observed); the summary is
    the one computed from the whole row a log fills, to the bit: probe_rate's press (contact in
    about a quarter of its ticks) and its work included."""
    session = load_session("probe_rate").with_changes(duration=2.0)
    with tempfile.TemporaryDirectory() as tmp:
        logged = run_session(session, out_dir=Path(tmp), plots=False).summary
    alone = run_session(session, out_dir=None, plots=False).summary
    assert logged["contact_fraction"] > 0.1
    assert logged["work_eq13"] > 0.0
    for s in (logged, alone):
        del s["timing"], s["real_time_factor"]
    assert alone == logged


def test_an_observer_after_metrics_alone_still_reads_the_whole_row() -> None:
    """The metrics' partial write does not count as the tick's fill: a later observer asking for
    the row gets the grip pose and the hand wrench of this tick."""
    session = load_session("probe_rate")
    loop = ServoLoop(LoopConfig.from_session(session))
    loop.observe(SessionMetrics(loop.record, None, 600, loop.dt))
    block = loop.record.block
    assert block is not None
    grip, hand = block.starts["grip"], block.starts["hand_G"]
    seen: list[bool] = []

    class Reader:
        def on_tick(self, tick: TickRecord) -> None:
            row = tick.state()
            seen.append(
                np.array_equal(row[grip : grip + 3], tick.reading.T_0_G[0:3, 3])
                and np.array_equal(row[hand : hand + 6], tick.reading.wrench_G)
            )

    loop.observe(Reader())
    op = OperatorScript.for_loop(session.data, loop)
    for _ in range(600):
        op.before_tick(loop)
        loop.tick()
    assert len(seen) == 600
    assert all(seen)


def test_the_scripts_compiled_pull_moves_the_hand_as_set_hand_target_does() -> None:
    """While the hand holds, the script blends its pose and pulls the simulated hand in one
    compiled call (ServoLoop.hand_pull); a loop driven through ``set_hand_target`` every tick
    sees the same rows to the bit: rotated waypoints, the hand let go and taken again."""
    data = SessionFile(
        scene="probe",
        device="kraft",
        duration=0.8,
        waypoints=(
            Waypoint(0.0),
            Waypoint(0.3, position=(0.01, 0.0, -0.02), zyx_deg=(10.0, -5.0, 3.0)),
            Waypoint(0.6, position=(0.0, 0.01, -0.01), zyx_deg=(-4.0, 6.0, 0.0)),
        ),
        events=(
            SwitchEvent(0.0, deadman=True, reflection=True),
            SwitchEvent(0.2, hand=False),
            SwitchEvent(0.35, hand=True),
        ),
    )
    session = load_session("probe_rate")
    compiled, plain = (ServoLoop(LoopConfig.from_session(session)) for _ in range(2))
    op_compiled, op_plain = OperatorScript.for_loop(data, compiled), OperatorScript.for_loop(data, plain)
    block = compiled.record.block
    assert block is not None
    stages = block.starts["stages"]
    hand_off = 0
    for _ in range(data.n_ticks):
        op_compiled.before_tick(compiled)
        op_plain.apply_events(plain)
        plain.set_hand_target(op_plain.hand_target(plain.time, plain.ticks) if op_plain.hand_on else None)
        a, b = compiled.tick().state(), plain.tick().state()
        np.testing.assert_array_equal(a[:stages], b[:stages])
        hand_off += bool(np.isnan(a[block.starts["hand_target"]]))
    assert 100 < hand_off < 200  # the hand was let go for 0.15 s, then held again
    assert compiled.hand_pull() is not None  # held at the end: the compiled path was open to the script


def test_metrics_write_the_logs_rows_as_the_log_does() -> None:
    """A session's metrics write the log's rows in their own compiled pass (run_session): the
    rows are those a log observing the loop by itself writes, to the bit (its stage timings
    aside), across several flushes."""
    session = load_session("probe_rate").with_changes(duration=0.75)
    with tempfile.TemporaryDirectory() as tmp:
        run_session(session, out_dir=Path(tmp) / "fused", plots=False, flush_interval=0.1)
        loop = ServoLoop(LoopConfig.from_session(session))
        log = loop.observe(TickLog(Path(tmp) / "alone", loop.controller.out.n, loop.dt, 0.1))
        for _ in play(session, loop):
            pass
        log.close()
        fused, alone = read_log(Path(tmp) / "fused" / "log"), read_log(Path(tmp) / "alone")
    assert fused.num_rows == alone.num_rows == session.data.n_ticks
    for name in alone.column_names:
        if not name.endswith("_us"):
            np.testing.assert_array_equal(fused.column(name).to_numpy(), alone.column(name).to_numpy(), err_msg=name)


@pytest.mark.parametrize("device", ["kraft", "touch3"])
def test_the_rows_grip_pose_and_hand_wrench_follow_the_reading_as_the_hand_lets_go_and_takes_hold(
    device: str,
) -> None:
    """The row builds the grip pose and the hand's wrench from the reading's buffers
    (GripSources) in compiled code: for a joint-space plant (the hand's force rotated, zero when
    let go) and for a Cartesian device (its pose and wrench as they are), every tick equals the
    reading's own properties, through a let-go and a new hold."""
    session = load_session("probe_rate").with_changes(device=device)
    loop = ServoLoop(LoopConfig.from_session(session))
    op = OperatorScript.for_loop(session.data, loop)
    block = loop.record.block
    assert block is not None
    grip, hand = block.starts["grip"], block.starts["hand_G"]
    held_force = let_go = 0
    for i in range(600):
        if 200 <= i < 300:
            loop.set_hand_target(None)
        else:
            op.before_tick(loop)
        row = loop.tick().state()
        T_0_G, wrench_G = loop.reading.T_0_G, loop.reading.wrench_G
        np.testing.assert_array_equal(row[grip : grip + 3], T_0_G[0:3, 3])
        np.testing.assert_array_equal(row[grip + 3 : grip + 7], matrix_to_quat(T_0_G[0:3, 0:3]))
        np.testing.assert_array_equal(row[hand : hand + 6], wrench_G)
        held_force += bool(np.any(row[hand : hand + 3] != 0.0))
        let_go += bool(200 <= i < 300 and not np.any(row[hand : hand + 6]))
    assert held_force > 400  # the hand pulls: the compared wrenches were not all zero
    assert let_go == 100  # and it pulled nothing while let go


def test_the_rows_scalars_keep_their_declared_types_whatever_the_first_tick_passes() -> None:
    """The row's kernel is compiled for declared argument types, not for its first call's: a link
    force that is the integer 0 on the first tick (a sum over no touching link) does not make the
    later forces integers (which would cut 2.75 N to 2)."""
    loop = ServoLoop(LoopConfig.from_session(load_session("probe_rate")))
    loop.slave.link_force = 0  # type: ignore[misc]  # an int, as a sum over no link gives
    at = loop.record.block.starts["link_force"]  # type: ignore[union-attr]
    assert loop.tick().state()[at] == 0.0
    loop.slave.link_force = 2.75  # type: ignore[misc]
    assert loop.tick().state()[at] == 2.75


class ReadsEverything:
    """An observer that reads every value a tick record offers, the ones computed on access too."""

    def __init__(self) -> None:
        self.ticks = 0

    def on_tick(self, record: TickRecord) -> None:
        self.ticks += 1
        record.state()
        record.reading.T_0_G.copy()
        record.reading.wrench_G.copy()
        record.T_w_MRF.copy()
        record.contact_wrench_MRF.copy()
        float(record.link_force)


@pytest.mark.parametrize("slave", [None, "redundant7"])
def test_an_observer_does_not_change_the_run(tmp_path: Path, slave: str | None) -> None:
    """The logs of one session run with and without an observer that reads everything are equal in
    every column but the wall-clock timings (the 7-dof arm: a run once looked different under two
    logging scripts; traced to the scripts, this pins that observing is passive)."""
    session = load_session("probe_rate").with_changes(duration=1.0)
    if slave is not None:
        session = session.with_changes(slave=slave)
    logs = []
    reader = ReadsEverything()
    for name, observers in (("bare", ()), ("observed", (reader,))):
        result = run_session(session, out_dir=tmp_path / name, plots=False, observers=observers)
        assert result.log_dir is not None
        logs.append(read_log(result.log_dir))
    bare, observed = logs
    assert bare.num_rows == observed.num_rows == reader.ticks == 1000
    timings = {c for c in bare.column_names if c.endswith("_us")}
    assert timings  # the columns left out are there
    for column in sorted(set(bare.column_names) - timings):
        assert bare[column].equals(observed[column]), column
