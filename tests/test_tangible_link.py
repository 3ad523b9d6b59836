"""Simulator → serial port → SerialReader, live: accuracy under corruption, the 2 s topology rule,
unplugging, and the pyserial URL schemes. Every test checks that it leaves no thread or file open."""

import contextlib
import os
import socket
import threading
import time

import numpy as np
import pytest
import serial

from tangible import (
    SPLITTERS,
    DeviceTree,
    Faults,
    JointBinding,
    Piece,
    RandomMotion,
    SerialReader,
    Simulator,
    joint_rotation,
    list_ports,
)
from tangible import rotations as rot
from tangible.errors import DeviceError
from tangible.protocol import DataMessage

HALF_DEGREE = np.radians(0.5)


@pytest.fixture(autouse=True)
def nothing_left_open():
    before = open_files()
    yield
    left = [t.name for t in threading.enumerate() if t.name.startswith("tangible-")]
    assert not left, f"threads left running: {left}"
    assert open_files() <= before, f"left open: {open_files() - before}"


def open_files() -> set[str]:
    out = set()
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):  # the directory's own descriptor is gone by now
            out.add(f"{fd} -> {os.readlink(f'/proc/self/fd/{fd}')}")
    return out


@pytest.fixture
def simulator():
    """Make simulators that are closed at teardown even when the test fails."""
    made = []

    def make(*args, **kwargs):
        made.append(Simulator(*args, **kwargs))
        return made[-1]

    yield make
    for sim in made:
        sim.close()


def device(n_joints_per_arm=3) -> DeviceTree:
    """A joint, a T splitter, then an arm of joints on each slot and a cross with two more joints."""
    pieces = [Piece(1, "joint"), Piece(2, "splitter", 1, 0, splitter=SPLITTERS["T"])]
    for arm, slot in ((10, 0), (20, 1)):
        parent, s = 2, slot
        for k in range(n_joints_per_arm):
            pieces.append(Piece(arm + k, "joint", parent, s))
            parent, s = arm + k, 0
    pieces += [
        Piece(30, "splitter", 20 + n_joints_per_arm - 1, 0, splitter=SPLITTERS["cross"]),
        Piece(31, "joint", 30, 0),
        Piece(32, "joint", 30, 2),
    ]
    return DeviceTree(pieces)


def drain(reader, sim, quiet=0.15):
    """Stop the simulator and wait until the reader has read everything written."""
    sim.stop()
    seen = -1
    while seen != reader.state().link.bytes:
        seen = reader.state().link.bytes
        time.sleep(quiet)


def test_reader_reproduces_joint_rotations_within_half_a_degree_with_5_percent_corruption(simulator):
    dev = device()
    motion = RandomMotion(len(dev.joints), seed=7, max_bend=np.radians(80), speed=2.0)
    received = {}
    sim = simulator(dev, motion=motion, faults=Faults.corrupt(0.05, garbage=0.01), seed=11)
    with SerialReader(sim.path, observer=lambda m, t: received.setdefault((m.creator, m.seq), m)) as reader:
        sim.start()
        mid = reader.wait_for(lambda s: len(s.attached) == len(dev) and s.link.frames > 700, timeout=10)
        assert mid is not None
        drain(reader, sim)
        state = reader.state()
    sent = list(sim.history)
    intact = [s for s in sent if s.intact]
    corrupted = [s for s in sent if not s.intact]
    assert len(sent) > 700 and 0.02 < len(corrupted) / len(sent) < 0.08
    # No valid frame lost, no corrupted one accepted.
    assert all((s.message.creator, s.message.seq) in received for s in intact)
    assert not any((s.message.creator, s.message.seq) in received for s in corrupted)
    # Every reading equals the simulated rotation within the device's accuracy (in fact to quantization).
    data = [s for s in intact if isinstance(s.message, DataMessage)]
    truth = joint_rotation([s.message.angles for s in data])
    got = joint_rotation([received[s.message.creator, s.message.seq].angles for s in data])
    err = rot.angle(got, truth)
    assert err.max() < np.radians(0.01) < HALF_DEGREE
    # The published state holds each joint's latest reading, and counts the gaps corruption left.
    by_seq = {(s.message.creator, s.message.seq): s.message for s in data}
    for j in dev.joints:
        c = state.components[j]
        assert rot.angle(c.rotation, joint_rotation(by_seq[j, c.data_seq].angles)) < HALF_DEGREE
        seqs = [q for (cid, q) in received if cid == j]
        between = [s for s in corrupted if s.message.creator == j and min(seqs) < s.message.seq < max(seqs)]
        assert c.dropped == len(between)
    assert state.link.corrupt >= 0.8 * len(corrupted)
    assert state.link.frames == len(received)
    # Mapping to a bone: calibrated at the state seen mid-run, a binding returns the simulated rotation
    # relative to the calibration reading.
    j = dev.joints[3]
    binding = JointBinding(j, bone=0, rest=mid.components[j].rotation)
    last = [s for s in data if s.message.creator == j][-1]
    got = binding.bone_rotation(state.components[j].rotation)
    expect = rot.multiply(
        rot.conjugate(joint_rotation(by_seq[j, mid.components[j].data_seq].angles)),
        joint_rotation(last.message.angles),
    )
    assert rot.angle(got, expect) < HALF_DEGREE


def test_topology_follows_power_loss_and_replugging_with_a_short_timeout(simulator):
    dev = device(2)
    sim = simulator(dev, seed=3)
    with SerialReader(sim.path, timeout=0.3) as reader:
        sim.start()
        assert reader.wait_for(lambda s: len(s.attached) == len(dev), timeout=5)
        subtree = set(dev.subtree(20))
        sim.set_power(20, False)
        gone = reader.wait_for(lambda s: not subtree & set(s.attached), timeout=3)
        assert gone is not None
        assert 0.3 <= gone.time - gone.components[20].last_heard < 0.3 + 0.25  # polled every 20 ms
        assert set(gone.attached) == {p.id for p in dev} - subtree
        sim.set_power(20, True)
        t = time.monotonic()
        back = reader.wait_for(lambda s: set(s.attached) == {p.id for p in dev}, timeout=3)
        assert back is not None and back.time - t < 0.25
        sim.move(11, 30, 1)  # joint 11 from under joint 10 into the cross's free slot
        moved = reader.wait_for(lambda s: s.children.get(30) == (31, 11, 32), timeout=3)
        assert moved is not None and moved.components[11].slot == 1 and moved.children.get(10) is None


def test_the_default_rule_detaches_a_silent_subtree_after_two_seconds(simulator):
    dev = device(1)
    sim = simulator(dev, seed=4)
    with SerialReader(sim.path) as reader:
        sim.start()
        assert reader.wait_for(lambda s: len(s.attached) == len(dev), timeout=5)
        sim.set_power(2, False)  # the T splitter: everything below joint 1
        early = reader.wait_for(lambda s: s.time - s.components[2].last_heard > 1.9, timeout=3)
        assert early is not None and set(early.attached) == {p.id for p in dev}
        gone = reader.wait_for(lambda s: s.attached == (1,), timeout=3)
        assert gone is not None
        # The splitter's silence takes its whole subtree with it (children reach the host through it).
        assert 2.0 <= gone.time - gone.components[2].last_heard < 2.25


def test_the_reader_survives_unplugging_and_replugging_the_port(tmp_path, simulator):
    link = tmp_path / "puppet"
    dev = device(1)
    sim = simulator(dev, motion=RandomMotion(len(dev.joints), seed=1), seed=5, link=link)
    with SerialReader(sim.path, timeout=0.5, backoff=(0.02, 0.2)) as reader:
        sim.start()
        assert reader.wait_for(lambda s: len(s.attached) == len(dev), timeout=5)
        sim.unplug()
        lost = reader.wait_for(lambda s: not s.connected, timeout=3)
        assert lost is not None and lost.link.error
        assert reader.wait_for(lambda s: not s.attached, timeout=3)  # silent: all detached after 0.5 s
        frozen = reader.state().components[1].angles
        sim.replug()
        back = reader.wait_for(lambda s: s.connected and len(s.attached) == len(dev), timeout=5)
        assert back is not None and back.link.reconnects == 1 and back.link.error == ""
        assert not np.array_equal(back.components[1].angles, frozen)  # live again
        # Twice more, to be sure the reconnect loop is not a one-off.
        for k in (2, 3):
            sim.unplug()
            assert reader.wait_for(lambda s: not s.connected, timeout=3)
            sim.replug()
            assert reader.wait_for(lambda s, k=k: s.connected and s.link.reconnects == k, timeout=5)


def test_loop_url_with_a_shared_port(simulator):
    port = serial.serial_for_url("loop://", timeout=0.02)
    dev = device(1)
    sim = simulator(dev, port=port, seed=6)
    with SerialReader("loop://", open_port=lambda url: port) as reader:
        sim.start()
        state = reader.wait_for(lambda s: len(s.attached) == len(dev), timeout=5)
        assert state is not None and state.children[0] == (1,)
    port.close()


def test_a_live_run_writes_exactly_the_offline_stream(simulator):
    dev = device(2)
    port = serial.serial_for_url("loop://", timeout=0.02)
    written = bytearray()
    done = threading.Event()

    def drain():
        while not done.is_set() or port.in_waiting:
            written.extend(port.read(port.in_waiting or 1))

    drainer = threading.Thread(target=drain, name="test-drain")
    drainer.start()
    motion = RandomMotion(len(dev.joints), seed=3)
    faults = Faults.corrupt(0.05, lose=0.02)
    sim = simulator(dev, port=port, motion=motion, faults=faults, seed=9)
    sim.start()
    time.sleep(0.6)
    sim.stop()
    done.set()
    drainer.join()
    port.close()
    live = [(s.time, s.message, s.fault) for s in sim.history]
    offline = list(Simulator(dev, motion=motion, faults=faults, seed=9).stream(1.0))
    assert len(live) > 200 and live == [(s.time, s.message, s.fault) for s, _ in offline[: len(live)]]
    assert bytes(written) == b"".join(d for _, d in offline[: len(live)])


def test_socket_url():
    dev = device(1)
    frames = b"".join(data for _, data in Simulator(dev, seed=8).stream(1.5))
    with socket.create_server(("127.0.0.1", 0)) as server:
        host, port = server.getsockname()

        def serve():
            conn, _ = server.accept()
            time.sleep(0.2)  # pyserial's socket:// flushes its input right after connecting
            with conn:
                for i in range(0, len(frames), 512):
                    conn.sendall(frames[i : i + 512])
                    time.sleep(0.005)
                time.sleep(0.3)

        feeder = threading.Thread(target=serve, name="test-feeder")
        feeder.start()
        try:
            with SerialReader(f"socket://{host}:{port}", timeout=5.0) as reader:
                state = reader.wait_for(lambda s: s.link.bytes == len(frames), timeout=5)
                assert state is not None and len(state.attached) == len(dev)
                assert state.link.corrupt == 0 and state.link.frames > 300
        finally:
            feeder.join()


def test_list_ports_names_devices():
    ports = list_ports()
    assert all(isinstance(d, str) and d and isinstance(text, str) and text for d, text in ports)


def test_bad_urls_and_missing_ports():
    with pytest.raises(DeviceError, match="nonsense"):
        SerialReader("nonsense://x")
    with SerialReader("/dev/does-not-exist-tangible", backoff=(0.01, 0.05)) as reader:
        time.sleep(0.1)
        state = reader.state()
        assert not state.connected and "does-not-exist" in state.link.error
        assert state.components == {}
