"""The topology table (Appendix A), driven offline by the simulator's byte stream on a virtual clock."""

import numpy as np
import pytest

from tangible import SPLITTERS, DeviceTopology, DeviceTree, Faults, Piece, RandomMotion, Simulator
from tangible.errors import DeviceError, RigError
from tangible.protocol import DataMessage, Decoder, TypeMessage


def make_device() -> DeviceTree:
    """host - 1 joint - 2 T splitter -+- slot 0: 3 joint - 4 joint
    +- slot 1: 5 joint - 6 cross -+- slot 0: 7 joint
                                  +- slot 2: 8 joint"""
    return DeviceTree(
        [
            Piece(1, "joint", 0, 0, (230, 25, 75)),
            Piece(2, "splitter", 1, 0, (60, 180, 75), SPLITTERS["T"]),
            Piece(3, "joint", 2, 0),
            Piece(4, "joint", 3, 0),
            Piece(5, "joint", 2, 1),
            Piece(6, "splitter", 5, 0, splitter=SPLITTERS["cross"]),
            Piece(7, "joint", 6, 0),
            Piece(8, "joint", 6, 2),
        ]
    )


def replay(sim, until, topology=None, decoder=None, actions=()):
    """Decode ``sim``'s stream up to time ``until`` into ``topology``, stamping each frame with its
    scheduled time; ``actions`` are (time, callable) run once the stream passes that time."""
    topology = topology or DeviceTopology(timeout=2.0)
    decoder = decoder or Decoder()
    pending = sorted(actions, key=lambda a: a[0])
    for sent, data in sim.stream(until):
        while pending and sent.time >= pending[0][0]:
            pending.pop(0)[1]()
        for m in decoder.feed(data):
            topology.observe(m, sent.time)
    return topology, decoder


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


def test_simulator_stream_is_deterministic_and_at_the_paper_rates():
    a = [(s.time, d) for s, d in Simulator(make_device(), motion=RandomMotion(6, seed=1), seed=4).stream(4.0)]
    b = [(s.time, d) for s, d in Simulator(make_device(), motion=RandomMotion(6, seed=1), seed=4).stream(4.0)]
    c = [(s.time, d) for s, d in Simulator(make_device(), motion=RandomMotion(6, seed=1), seed=5).stream(4.0)]
    assert a == b and a != c
    sim = Simulator(make_device(), seed=4)
    kinds = {}
    for sent, _ in sim.stream(4.0):
        kinds.setdefault((sent.message.creator, type(sent.message).__name__), []).append(sent.time)
    sim.close()
    assert len(kinds[1, "DataMessage"]) == 200  # 50 Hz for 4 s
    assert np.allclose(np.diff(kinds[1, "DataMessage"]), 0.02)
    assert len(kinds[2, "TypeMessage"]) == 8 and len(kinds[2, "ChildMessage"]) == 8  # 2 Hz
    assert (2, "DataMessage") not in kinds  # splitters sense nothing


def test_table_rebuilds_the_device_with_kinds_colours_and_slots():
    sim = Simulator(make_device(), seed=0)
    topo, dec = replay(sim, 1.0)
    state = topo.snapshot(1.0)
    assert state.attached == (1, 2, 3, 4, 5, 6, 7, 8)
    assert dict(state.children) == {0: (1,), 1: (2,), 2: (3, 5), 3: (4,), 5: (6,), 6: (7, 8)}
    assert [state.components[i].slot for i in (3, 5, 7, 8)] == [0, 1, 0, 2]
    assert state.components[1].colour == (230, 25, 75) and state.components[2].kind == "splitter"
    np.testing.assert_allclose(
        state.joint_rotations([1, 3]), [c.rotation for c in map(state.components.get, (1, 3))]
    )
    assert state.joint_angles([4]).shape == (1, 4)
    np.testing.assert_allclose(state.components[6].slot_rotations, SPLITTERS["cross"].slots, atol=1e-4)
    assert dec.stats.corrupt == 0 and all(c.dropped == 0 for c in state.components.values())
    sim.close()


def test_a_subtree_losing_power_detaches_after_the_timeout_and_reattaches_when_it_speaks():
    sim = Simulator(make_device(), seed=1)
    topo, dec = DeviceTopology(timeout=2.0), Decoder()
    off, back = False, None
    for sent, data in sim.stream(6.0):
        if not off and sent.time >= 1.0:
            sim.set_power(5, False)
            off = True
        if off and back is None and sent.time >= 4.0:
            heard = {i: topo.snapshot(sent.time).components[i].last_heard for i in (5, 6, 7, 8)}
            assert 0.98 <= max(heard.values()) < 1.02  # the frame that triggered the cut may be theirs
            # The 2 s rule: nobody is detached before 2 s of its own (and its parent's) silence...
            for i in (5, 6, 7, 8):
                assert i in topo.attached(min(heard[i], heard[5]) + 2.0 - 1e-6)
            # ... and 2 s after the subtree's last message all of it is gone, the rest stays.
            assert topo.attached(max(heard.values()) + 2.0 + 1e-6) == {1, 2, 3, 4}
            sim.set_power(5, True)
            back = sent.time
        for m in dec.feed(data):
            topo.observe(m, sent.time)
    state = topo.snapshot(6.0)
    assert state.attached == (1, 2, 3, 4, 5, 6, 7, 8)
    assert state.components[5].attached_since - back < 0.021  # its next data frame, within 20 ms
    assert state.components[6].attachments == 2  # attached, then re-attached once
    assert state.components[5].restarts == 0 and state.components[5].dropped == 0
    sim.close()


def test_replugging_a_subtree_elsewhere_moves_it_in_the_table():
    sim = Simulator(make_device(), seed=2)
    moves = [(1.0, lambda: sim.move(8, 6, 1)), (1.0, lambda: sim.move(3, 6, 2))]
    topo, _ = replay(sim, 2.0, actions=moves)  # 8: cross slot 2 -> 1; 3 (with 4): T slot 0 -> cross slot 2
    state = topo.snapshot(2.0)
    assert dict(state.children) == {0: (1,), 1: (2,), 2: (5,), 5: (6,), 6: (7, 8, 3), 3: (4,)}
    assert [state.components[i].slot for i in (7, 8, 3)] == [0, 1, 2]
    sim.close()


def test_lost_frames_are_counted_per_component_from_sequence_gaps():
    sim = Simulator(make_device(), motion=RandomMotion(6, seed=0), faults=Faults(lose=0.1), seed=3)
    topo, dec = DeviceTopology(), Decoder()
    lost, first, last = [], {}, {}
    for sent, data in sim.stream(3.0):
        if sent.fault == "lose":
            lost.append((sent.message.creator, sent.message.seq))
        for m in dec.feed(data):
            topo.observe(m, sent.time)
            first.setdefault(m.creator, m.seq)
            last[m.creator] = m.seq
    state = topo.snapshot(3.0)
    # A lost frame shows as a gap between two frames of its creator that did arrive.
    for cid in last:
        expect = sum(c == cid and first[cid] < q < last[cid] for c, q in lost)
        assert state.components[cid].dropped == expect
        assert state.components[cid].restarts == 0
    assert len(lost) > 50
    sim.close()


def test_stale_links_that_would_form_a_cycle_are_broken():
    topo = DeviceTopology(timeout=2.0)
    topo.observe(TypeMessage(10, 0, 0, 0, 0, (1, 2, 3)), 0.0)
    topo.observe(TypeMessage(11, 10, 0, 0, 0, (1, 2, 3)), 0.0)
    topo.observe(TypeMessage(12, 11, 0, 0, 0, (1, 2, 3)), 0.0)
    # The user re-plugs: 10 now hangs below 12, and 12 is plugged into the host.
    topo.observe(TypeMessage(10, 12, 0, 1, 0, (1, 2, 3)), 0.1)
    assert topo.parent(10) == 12 and topo.parent(11) is None  # the stale link 11 -> 10 is cut
    assert topo.attached(0.1) == set()  # nothing reaches the host until 12 speaks
    topo.observe(TypeMessage(12, 0, 0, 1, 0, (1, 2, 3)), 0.2)
    assert topo.attached(0.2) == {12, 10}
    topo.observe(TypeMessage(11, 10, 0, 1, 0, (1, 2, 3)), 0.3)
    assert topo.attached(0.3) == {12, 10, 11}
    assert topo.children(12) == (10,) and topo.children(10) == (11,)


def test_a_newer_claim_on_a_slot_unplugs_the_old_occupant():
    topo = DeviceTopology()
    topo.observe(DataMessage(1, 0, 0, 0, (0.0,) * 4), 0.0)
    topo.observe(DataMessage(2, 1, 0, 0, (0.0,) * 4), 0.0)
    topo.observe(DataMessage(3, 1, 0, 0, (0.0,) * 4), 0.5)
    assert topo.children(1) == (3,) and topo.parent(2) is None
    assert topo.attached(0.5) == {1, 3}


def test_queries_name_unknown_components():
    topo = DeviceTopology()
    with pytest.raises(DeviceError, match="component 4"):
        topo.parent(4)
    with pytest.raises(DeviceError, match="positive"):
        DeviceTopology(timeout=0)
    state = topo.snapshot(0.0)
    with pytest.raises(DeviceError, match="never heard"):
        state.joint_angles([4])
