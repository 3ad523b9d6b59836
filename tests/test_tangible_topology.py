"""The simulated firmware, polled offline on its simulated clock, and the host's topology table built from
its replies: relayer ids and ports, the 2 s rule, the firmware's schedule, downlink commands."""

import numpy as np
import pytest

from tangible import (
    SPLITTERS,
    Command,
    DeviceTopology,
    DeviceTree,
    Faults,
    KeyframeMotion,
    Piece,
    RandomMotion,
    Simulator,
    joint_angles,
    joint_rotation,
)
from tangible import rotations as rot
from tangible.errors import DeviceError, RigError
from tangible.protocol import (
    BROADCAST_ID,
    EMPTY_RECORD,
    MIN_ID,
    NODE_JOINT_TUT_TU,
    NODE_SPLITTER_2,
    NODE_SPLITTER_3,
    REPLY_SIZE,
    DataRecord,
    InitRecord,
    ReplyParser,
    SplitterRecord,
    decode_record,
    poll_bytes,
    splitter_angles,
)

J = MIN_ID  # piece ids: J + 1, J + 2, ...


def make_device() -> DeviceTree:
    """host - 1 joint - 2 T splitter -+- slot 0: 3 joint - 4 joint
    +- slot 1: 5 joint - 6 cross -+- slot 0: 7 joint
                                  +- slot 2: 8 joint"""
    return DeviceTree(
        [
            Piece(J + 1, "joint", 0, 0, (230, 25, 75)),
            Piece(J + 2, "splitter", J + 1, 0, (60, 180, 75), SPLITTERS["T"]),
            Piece(J + 3, "joint", J + 2, 0),
            Piece(J + 4, "joint", J + 3, 0),
            Piece(J + 5, "joint", J + 2, 1),
            Piece(J + 6, "splitter", J + 5, 0, splitter=SPLITTERS["cross"]),
            Piece(J + 7, "joint", J + 6, 0),
            Piece(J + 8, "joint", J + 6, 2),
        ]
    )


class Host:
    """A host polling a simulator offline: parser and table on the simulated clock."""

    def __init__(self, sim: Simulator, timeout: float = 2.0):
        self.sim = sim
        self.parser = ReplyParser()
        self.topology = DeviceTopology(timeout)
        self.records: list[tuple[float, object]] = []

    def run(self, duration: float, **kwargs) -> DeviceTopology:
        for t, poll, data in self.sim.polled(duration, **kwargs):
            for r in self.parser.poll(poll):
                self._apply(r, t)
            for r in self.parser.feed(data):
                self._apply(r, self.sim.time)
        return self.topology

    def _apply(self, r, t) -> None:
        self.topology.observe(r, t)
        self.records.append((t, r))

    def state(self):
        return self.topology.snapshot(self.sim.time)


def test_device_tree_validation_names_the_piece():
    with pytest.raises(RigError, match="piece 3"):
        DeviceTree([Piece(1, "joint"), Piece(3, "joint", 1, 1)])
    with pytest.raises(RigError, match="both plugged"):
        DeviceTree(
            [Piece(1, "splitter", splitter=SPLITTERS["T"]), Piece(2, "joint", 1), Piece(3, "joint", 1)]
        )
    with pytest.raises(RigError, match="cycle"):
        DeviceTree([Piece(1, "joint"), Piece(2, "joint", 3), Piece(3, "joint", 2)])
    with pytest.raises(RigError, match="host slot"):
        DeviceTree([Piece(1, "joint", 0, 1)])
    with pytest.raises(RigError, match="outside"):
        DeviceTree([Piece(0x10000000, "joint")])


def test_the_simulator_refuses_ids_the_firmware_cannot_relay():
    with pytest.raises(DeviceError, match="byte 5"):
        Simulator(DeviceTree([Piece(11, "joint")]))


def test_table_rebuilds_the_device_from_relayers_and_ports():
    host = Host(Simulator(make_device(), seed=0))
    host.run(2.0)
    state = host.state()
    assert state.attached == tuple(J + i for i in range(1, 9))
    assert dict(state.children) == {
        0: (J + 1,),
        J + 1: (J + 2,),
        J + 2: (J + 3, J + 5),
        J + 3: (J + 4,),
        J + 5: (J + 6,),
        J + 6: (J + 7, J + 8),
    }
    c = state.components
    assert [c[J + i].slot for i in (3, 5, 7, 8)] == [0, 1, 0, 2]
    assert c[J + 1].colour == (230, 25, 75) and c[J + 1].node_type == NODE_JOINT_TUT_TU
    assert (c[J + 2].kind, c[J + 2].node_type, c[J + 6].node_type) == (
        "splitter",
        NODE_SPLITTER_2,
        NODE_SPLITTER_3,
    )
    assert rot.angle(c[J + 6].slot_rotations, SPLITTERS["cross"].slots).max() < 1e-9
    assert list(c[J + 6].slot_angles) == [0, 1, 2]
    # Straight joints read straight (the pieces come zeroed at their sensors' mounting offsets).
    rotations = state.joint_rotations([J + 1, J + 4, J + 8])
    assert rot.angle(rotations, rot.IDENTITY).max() < np.radians(0.05)
    # The 0x84 halves never show: their records stop at their 0x74 brothers.
    assert {x.kind for x in c.values()} == {"joint", "splitter"}
    s = host.parser.stats
    assert s.corrupt == 0 and s.skipped == 0 and s.missing <= 2  # the first poll only sets the direction


def test_the_firmwares_schedule():
    sim = Simulator(make_device(), motion=RandomMotion(6, seed=1), seed=4)
    host = Host(sim)
    host.run(6.0)
    by = {}
    for t, r in host.records:
        by.setdefault((r.creator, type(r).__name__), []).append(t)
    # The piece the host polls sends a data record after every poll it answers: one per 20 ms cycle.
    root = np.diff(by[J + 1, "DataRecord"])
    assert np.median(root) == pytest.approx(0.02) and len(by[J + 1, "DataRecord"]) > 280
    # Deeper joints arrive at the rate their parents poll them and the host drains the queues.
    for j in (J + 4, J + 8):
        assert 10 < len(by[j, "DataRecord"]) / 6.0 < 55
    # Init records: one at power-on, then one a little over every second; one splitter record per outlet.
    for piece in (J + 1, J + 2, J + 7):
        assert 5 <= len(by[piece, "InitRecord"]) <= 7
    outlets = [r.slot for _, r in host.records if isinstance(r, SplitterRecord) and r.creator == J + 6]
    assert sorted(set(outlets)) == [0, 1, 2] and 15 <= len(outlets) <= 21
    assert (J + 2, "DataRecord") not in by  # splitters sense nothing


def test_stepped_by_hand_a_piece_answers_its_second_poll_10_ms_after_it():
    sim = Simulator(DeviceTree([Piece(J + 1, "joint")]), seed=0)
    assert sim.step(0.05) == b""  # nobody speaks unpolled
    assert sim.exchange() == b""  # the first 'R' after power-up only tells the piece which side is up
    sim.write(poll_bytes())
    # 11 bytes in (0.48 ms), a main-loop turn, 216 bytes out (9.4 ms) at 230400 baud.
    assert sim.step(0.0100) == b""
    reply = sim.step(0.0001)
    assert len(reply) == REPLY_SIZE and reply.endswith(EMPTY_RECORD)
    first = decode_record(reply[:18])
    assert isinstance(first, InitRecord) and (first.creator, first.node_type) == (J + 1, NODE_JOINT_TUT_TU)
    assert sim.stats.polls == 2 and sim.stats.replies == 1


def test_stepping_is_deterministic():
    def stream(seed):
        sim = Simulator(make_device(), motion=RandomMotion(6, seed=1), faults=Faults.corrupt(0.1), seed=seed)
        return [data for _, _, data in sim.polled(1.0)]

    a, b, c = stream(4), stream(4), stream(5)
    assert a == b and a != c


def test_data_records_carry_the_motion():
    """Every data record decodes to the rotation its sensors were read at (within a quantization step or
    two), and that is the motion's: the distal twist is one 0x74→0x84 poll older than the rest."""
    rng = np.random.default_rng(3)
    keys = rot.normalize(rng.normal(size=(2, 6, 4)) * [4, 1, 1, 1])
    sim = Simulator(make_device(), motion=KeyframeMotion([0.0, 40.0], keys), seed=2)
    Host(sim).run(4.0)
    data = [s for s in sim.history if s.angles is not None]
    assert len(data) > 500
    got = joint_rotation([s.record.angles for s in data])
    # Four 14-bit steps of 0.022° each, and the firmware's wrap modulo 0x3FFF adds one to negative twists.
    assert rot.angle(got, np.array([s.rotation for s in data])).max() < np.radians(0.1)
    joints = sim.device.joints
    truth = KeyframeMotion([0.0, 40.0], keys)
    for s in data[::25]:
        expect = truth(s.sampled)[joints.index(s.record.creator)]
        assert rot.angle(s.rotation, expect) < np.radians(0.5)  # this slow motion: < 0.5° in 40 ms


def test_a_subtree_losing_power_detaches_after_two_seconds_and_reattaches():
    sim = Simulator(make_device(), seed=1)
    host = Host(sim)
    host.run(1.0)
    sim.set_power(J + 5, False)
    off = sim.time
    host.run(1.5)
    topo = host.topology
    heard = {i: topo.snapshot(sim.time).components[i].last_heard for i in (J + 5, J + 6, J + 7, J + 8)}
    assert off - 0.1 < max(heard.values()) <= off + 0.2  # records queued above drain after the cut
    assert topo.attached(sim.time) == {J + i for i in range(1, 9)}  # nobody detached before 2 s
    host.run(1.0)
    # The 2 s rule: 2 s after its last record each piece of the subtree is gone, the rest stays.
    for i in heard:
        assert i in topo.attached(heard[i] + 2.0 - 1e-6)
    assert topo.attached(max(heard.values()) + 2.0 + 1e-6) == {J + i for i in range(1, 5)}
    assert host.state().children[J + 2] == (J + 3,)
    sim.set_power(J + 5, True)
    back = sim.time
    host.run(1.5)
    state = host.state()
    assert state.attached == tuple(J + i for i in range(1, 9))
    # Back once the pieces booted and their parents polled them: the splitter tries an output that
    # stopped answering only every 200 ms, then the records climb three hops.
    assert state.components[J + 5].attached_since - back < 0.5
    assert state.components[J + 6].attachments == 2  # attached, then re-attached once


def test_replugging_a_subtree_elsewhere_moves_it_in_the_table():
    sim = Simulator(make_device(), seed=2)
    host = Host(sim)
    host.run(1.0)
    sim.move(J + 8, J + 6, 1)  # cross slot 2 -> 1
    sim.move(J + 3, J + 6, 2)  # 3 (with 4): T slot 0 -> cross slot 2
    host.run(3.5)  # stale links go after 2 s
    state = host.state()
    assert dict(state.children) == {
        0: (J + 1,),
        J + 1: (J + 2,),
        J + 2: (J + 5,),
        J + 5: (J + 6,),
        J + 6: (J + 7, J + 8, J + 3),
        J + 3: (J + 4,),
    }
    assert [state.components[J + i].slot for i in (7, 8, 3)] == [0, 1, 2]


def test_corruption_on_the_host_link_is_counted_and_never_accepted():
    sim = Simulator(
        make_device(),
        motion=RandomMotion(6, seed=0),
        faults=Faults.corrupt(0.05, lose=0.02, garbage=0.02),
        seed=3,
    )
    host = Host(sim)
    host.run(5.0)
    sent = [s for s in sim.history if s.record is not None]
    intact = [s.record for s in sent if s.intact]
    got = [r for _, r in host.records]
    assert sorted(map(repr, got)) == sorted(map(repr, intact))  # every intact record, nothing else
    damaged = sum(s.fault not in ("", "lose") for s in sent)
    s = host.parser.stats
    assert damaged > 50 and s.missing >= 0.01 * s.polls and s.short > 0 and s.oversize > 0
    assert 0.7 * damaged <= s.corrupt <= 1.3 * damaged


def test_an_echoing_adapter_changes_nothing_but_the_echo_count():
    plain, echo = Host(Simulator(make_device(), seed=5)), Host(Simulator(make_device(), seed=5, echo=True))
    plain.run(1.0)
    echo.run(1.0)
    assert [repr(r) for _, r in plain.records] == [repr(r) for _, r in echo.records]
    assert echo.parser.stats.echoes == echo.parser.stats.polls == 50 and echo.parser.stats.corrupt == 0


def test_commands_reach_the_right_piece():
    sim = Simulator(
        make_device(), motion=KeyframeMotion([0.0], joint_rotation(np.full((1, 6, 4), 0.3))), seed=6
    )
    host = Host(sim)
    host.run(0.5)
    deep = J + 8
    assert sim.firmware(deep).leds[1] is False
    commands = [
        (0.6, Command.led(red=False, green=True, blue=False, target=deep)),
        (0.7, Command.zero(target=J + 4)),
        (0.8, Command.colour((1, 2, 3), target=J + 3)),
        (0.85, Command.colour((4, 5, 6), target=J + 7)),  # stuck: see below
        (0.9, Command.set_id(J + 100)),  # direct: only the piece the host polls (and its brother)
    ]
    host.run(2.0, commands=commands)
    assert sim.firmware(deep).leds == (False, True, False) and sim.firmware(J + 7).leds[1] is False
    state = host.state()
    # Zeroed at the current pose: the proximal twist and the bends read 0; the firmware's zeroing
    # happens right after the distal reading was cleared, so the distal twist keeps no zero offset.
    zeroed = state.components[J + 4].angles
    np.testing.assert_allclose(zeroed[:3], 0.0, atol=2e-3)
    assert abs(zeroed[3] - state.components[J + 3].angles[3]) > 0.01
    assert sim.firmware(J + 4).zero[3] == 0 and sim.firmware(J + 3).zero[3] != 0
    assert state.components[J + 3].colour == (1, 2, 3)
    # The cross splitter above J + 7 has an empty output, which never answers: it passed on the first
    # command it got (the LED one) to every output and waits for ever for the empty one to take it.
    assert state.components[J + 7].colour == (200, 200, 200) and sim.firmware(J + 6).commands >= 2
    assert J + 100 in state.attached and state.components[J + 100].kind == "joint"
    assert sim.firmware(J + 1).id == J + 100 and state.children[J + 100] == (J + 2,)
    acks = {cid: c.last_ack.code for cid, c in state.components.items() if c.acks}
    assert acks == {deep: "l", J + 4: "z", J + 3: "c", J + 100: "i"}


def test_broadcast_and_polarity():
    device = DeviceTree(
        [
            Piece(J + 1, "joint"),
            Piece(J + 2, "splitter", J + 1, splitter=SPLITTERS["T"]),
            Piece(J + 3, "joint", J + 2, 0),
            Piece(J + 4, "joint", J + 3, 0),
            Piece(J + 5, "joint", J + 2, 1),
        ]
    )  # no empty splitter output: every command gets through
    pose = joint_rotation(np.full((4, 4), 0.2))
    sim = Simulator(device, motion=KeyframeMotion([0.0], pose[None]), seed=7)
    host = Host(sim)
    host.run(0.5)
    before = host.state().joint_angles(sim.device.joints)
    np.testing.assert_allclose(before, joint_angles(pose), atol=2e-3)
    factory = np.array([sim.firmware(j).zero for j in sim.device.joints])
    host.run(1.0, commands=[(0.6, Command.polarity(True, target=BROADCAST_ID))])
    # utility.c 198-201: 'x' stores the polarity and calls part_init, which clears angles[0..3] (lines
    # 512-515), then falls through into 'z' (202-208), which copies the cleared angles: every zero offset
    # is 0, not the current reading (the factory zero is the sensors' mounting offset, never all 0).
    assert all(sim.firmware(j).polarity == 1 for j in sim.device.joints)
    assert all(sim.firmware(j).zero == (0, 0, 0, 0) for j in sim.device.joints)
    assert (factory != 0).all()
    # So the joints now send their raw readings (update_sensor_messages, lines 611-622): the twists as
    # read, the bends mirrored (0x3FFF - a); the host's angles are those steps wrapped to (-pi, pi].
    step = 2 * np.pi / 16384
    raw = np.mod(factory + np.round(before / step), 16384)  # what each sensor reads in this pose
    raw[:, 1:3] = 0x3FFF - raw[:, 1:3]
    expected = (raw * step + np.pi) % (2 * np.pi) - np.pi
    mirrored = host.state().joint_angles(sim.device.joints)
    np.testing.assert_allclose((mirrored - expected + np.pi) % (2 * np.pi) - np.pi, 0.0, atol=2e-3)
    # A 'z' after it zeroes them at the current pose.
    host.run(1.0, commands=[(1.6, Command.zero(target=BROADCAST_ID))])
    after = host.state().joint_angles(sim.device.joints)
    np.testing.assert_allclose(after[:, :3], 0.0, atol=2e-3)


def test_splitter_geometry_is_written_by_a_direct_command():
    device = DeviceTree([Piece(J + 1, "splitter", splitter=SPLITTERS["Y"]), Piece(J + 2, "joint", J + 1, 1)])
    sim = Simulator(device, seed=8)
    host = Host(sim)
    host.run(0.5)
    np.testing.assert_allclose(
        host.state().components[J + 1].slot_angles[1], splitter_angles(SPLITTERS["Y"].slots)[1]
    )
    angles = np.radians([30.0, 60.0, -10.0])
    host.run(2.0, commands=[(0.6, Command.splitter_geometry(1, angles))])
    assert sim.firmware(J + 1).geometry[1] == (30, 60, 0x10000 - 10)
    np.testing.assert_allclose(host.state().components[J + 1].slot_angles[1], angles, atol=1e-12)


def test_a_splitter_hearing_no_child_restarts():
    """Its watchdog is fed only while children answer: with every output empty it restarts about every
    320 ms (and announces itself anew)."""
    sim = Simulator(DeviceTree([Piece(J + 1, "splitter", splitter=SPLITTERS["T"])]), seed=9)
    host = Host(sim)
    host.run(3.0)
    inits = [t for t, r in host.records if isinstance(r, InitRecord)]
    assert 7 <= len(inits) <= 11
    assert host.parser.stats.missing >= len(inits)  # the first poll after each restart is not answered


def test_stale_links_that_would_form_a_cycle_are_broken():
    topo = DeviceTopology(timeout=2.0)
    init = (0x74, (1, 2, 3))
    topo.observe(InitRecord(10, 0, 0, *init), 0.0)
    topo.observe(InitRecord(11, 10, 0, *init), 0.0)
    topo.observe(InitRecord(12, 11, 0, *init), 0.0)
    # The user re-plugs: 10 now hangs below 12, and 12 is plugged into the host.
    topo.observe(InitRecord(10, 12, 1, *init), 0.1)
    assert topo.parent(10) == 12 and topo.parent(11) is None  # the stale link 11 -> 10 is cut
    assert topo.attached(0.1) == set()  # nothing reaches the host until 12 speaks
    topo.observe(InitRecord(12, 0, 0, *init), 0.2)
    assert topo.attached(0.2) == {12, 10}
    topo.observe(InitRecord(11, 10, 1, *init), 0.3)
    assert topo.attached(0.3) == {12, 10, 11}
    assert topo.children(12) == (10,) and topo.children(10) == (11,)


def test_a_newer_claim_on_a_slot_unplugs_the_old_occupant_and_self_relayed_records_place_nothing():
    topo = DeviceTopology()
    topo.observe(DataRecord(1, 0, 0, (0.0,) * 4), 0.0)
    topo.observe(DataRecord(2, 1, 0, (0.0,) * 4), 0.0)
    topo.observe(DataRecord(3, 1, 0, (0.0,) * 4), 0.5)
    assert topo.children(1) == (3,) and topo.parent(2) is None
    assert topo.attached(0.5) == {1, 3}
    topo.observe(DataRecord(3, 3, 0, (0.1,) * 4), 0.6)  # a joint's distal half in data mode 2
    assert topo.parent(3) == 1 and topo.snapshot(0.6).components[3].angles[0] == 0.0


def test_queries_name_unknown_components():
    topo = DeviceTopology()
    with pytest.raises(DeviceError, match="component 4"):
        topo.parent(4)
    with pytest.raises(DeviceError, match="positive"):
        DeviceTopology(timeout=0)
    state = topo.snapshot(0.0)
    with pytest.raises(DeviceError, match="never heard"):
        state.joint_angles([4])
