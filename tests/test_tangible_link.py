"""Simulated firmware → pseudo-terminal → SerialReader, live: accuracy under corruption, an echoing adapter,
the 2 s topology rule, unplugging, downlink commands, and the pyserial URL schemes. Every test checks that
it leaves no thread or file open. Corruption is injected on the host link, the only one where the host can
detect it (relaying pieces recompute CRCs without checking them)."""

import contextlib
import os
import socket
import threading
import time
from collections import defaultdict

import numpy as np
import pytest

from tangible import (
    SPLITTERS,
    Command,
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
from tangible.errors import DeviceError, ProtocolError
from tangible.protocol import MIN_ID, DataRecord, encode_record

HALF_DEGREE = np.radians(0.5)
J = MIN_ID


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
    """A joint, a T splitter, then an arm of joints on each slot; a cross with joints in all three slots
    at the end of the second arm."""
    pieces = [Piece(J + 1, "joint"), Piece(J + 2, "splitter", J + 1, 0, splitter=SPLITTERS["T"])]
    for arm, slot in ((10, 0), (20, 1)):
        parent, s = J + 2, slot
        for k in range(n_joints_per_arm):
            pieces.append(Piece(J + arm + k, "joint", parent, s))
            parent, s = J + arm + k, 0
    pieces += [
        Piece(J + 30, "splitter", J + 20 + n_joints_per_arm - 1, 0, splitter=SPLITTERS["cross"]),
        Piece(J + 31, "joint", J + 30, 0),
        Piece(J + 32, "joint", J + 30, 1),
        Piece(J + 33, "joint", J + 30, 2),
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
    received = defaultdict(list)
    sim = simulator(dev, motion=motion, faults=Faults.corrupt(0.05, garbage=0.05), seed=11)
    with SerialReader(sim.path, observer=lambda r, t: received[encode_record(r)].append(r)) as reader:
        sim.start()
        mid = reader.wait_for(lambda s: len(s.attached) == len(dev) and s.link.frames > 400, timeout=10)
        assert mid is not None
        time.sleep(1.0)
        drain(reader, sim)
        state = reader.state()
    sent = [s for s in sim.history if s.record is not None]
    intact = [s for s in sent if s.intact]
    damaged = [s for s in sent if s.fault not in ("", "lose")]
    assert len(sent) > 700 and 0.02 < len(damaged) / len(sent) < 0.08
    # No valid record lost, no damaged one accepted.
    want = defaultdict(int)
    for s in intact:
        want[encode_record(s.record)] += 1
    assert {k: len(v) for k, v in received.items()} == dict(want)
    # Every reading equals the simulated rotation within the device's accuracy (in fact to quantization).
    data = [s for s in intact if isinstance(s.record, DataRecord)]
    got = joint_rotation([received[encode_record(s.record)][0].angles for s in data])
    err = rot.angle(got, np.array([s.rotation for s in data]))
    assert len(data) > 300 and err.max() < np.radians(0.1) < HALF_DEGREE
    # The published state holds each joint's latest reading; the link counted the damage.
    last = {s.record.creator: s for s in data}
    for j in dev.joints:
        assert rot.angle(state.components[j].rotation, last[j].rotation) < HALF_DEGREE
    link = state.link
    assert link.frames == len(intact) and 0.7 * len(damaged) <= link.corrupt <= 1.3 * len(damaged)
    assert link.short > 0 and link.oversize > 0 and link.echoes == 0
    # Mapping to a bone: calibrated at the state seen mid-run, a binding returns the simulated rotation
    # relative to the calibration reading.
    j = dev.joints[3]
    binding = JointBinding(j, bone=0, rest=mid.components[j].rotation)
    calibrated = next(s for s in data if s.record.raw == mid.components[j].raw and s.record.creator == j)
    expect = rot.multiply(rot.conjugate(calibrated.rotation), last[j].rotation)
    assert rot.angle(binding.bone_rotation(state.components[j].rotation), expect) < HALF_DEGREE


def test_an_echoing_adapter(simulator):
    dev = device(1)
    sim = simulator(dev, motion=RandomMotion(len(dev.joints), seed=2), seed=3, echo=True)
    with SerialReader(sim.path) as reader:
        sim.start()
        state = reader.wait_for(lambda s: len(s.attached) == len(dev) and s.link.polls > 50, timeout=5)
        assert state is not None
        drain(reader, sim)
        link = reader.state().link
    # Every poll echoed back and skipped (but those after the device stopped); every record read.
    assert link.echoes == sim.stats.polls and link.corrupt == 0 and link.skipped == 0
    assert link.frames == sim.stats.intact


def test_topology_follows_power_loss_and_replugging_with_a_short_timeout(simulator):
    dev = device(2)
    sim = simulator(dev, seed=3)
    everything = {p.id for p in dev}
    with SerialReader(sim.path, timeout=0.5) as reader:
        sim.start()
        assert reader.wait_for(lambda s: len(s.attached) == len(dev), timeout=5)
        subtree = set(dev.subtree(J + 20))
        sim.set_power(J + 20, False)
        gone = reader.wait_for(lambda s: not subtree & set(s.attached), timeout=3)
        assert gone is not None and set(gone.attached) == everything - subtree
        sim.set_power(J + 20, True)
        back = reader.wait_for(lambda s: set(s.attached) == everything, timeout=3)
        assert back is not None
        sim.move(J + 32, J + 11, 0)  # the cross's middle joint below joint 11...
        sim.move(J + 11, J + 30, 1)  # ...and joint 11 (with it) from under joint 10 into that slot
        moved = reader.wait_for(
            lambda s: (
                s.children.get(J + 30) == (J + 31, J + 11, J + 33) and s.children.get(J + 11) == (J + 32,)
            ),
            timeout=3,
        )
        assert moved is not None and moved.components[J + 11].slot == 1 and moved.children.get(J + 10) is None


def test_the_default_rule_detaches_a_silent_subtree_after_two_seconds(simulator):
    dev = device(1)
    sim = simulator(dev, seed=4)
    with SerialReader(sim.path) as reader:
        sim.start()
        assert reader.wait_for(lambda s: len(s.attached) == len(dev), timeout=5)
        sim.set_power(J + 2, False)  # the T splitter: everything below joint 1
        early = reader.wait_for(lambda s: s.time - s.components[J + 2].last_heard > 1.9, timeout=3)
        assert early is not None and set(early.attached) == {p.id for p in dev}
        gone = reader.wait_for(lambda s: s.attached == (J + 1,), timeout=3)
        assert gone is not None
        # The splitter's silence takes its whole subtree with it (children reach the host through it).
        assert 2.0 <= gone.time - gone.components[J + 2].last_heard < 2.25


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
        frozen = reader.state().components[J + 1].angles
        sim.replug()
        back = reader.wait_for(lambda s: s.connected and len(s.attached) == len(dev), timeout=5)
        assert back is not None and back.link.reconnects == 1 and back.link.error == ""
        assert not np.array_equal(back.components[J + 1].angles, frozen)  # live again
        # Twice more, to be sure the reconnect loop is not a one-off.
        for k in (2, 3):
            sim.unplug()
            assert reader.wait_for(lambda s: not s.connected, timeout=3)
            sim.replug()
            assert reader.wait_for(lambda s, k=k: s.connected and s.link.reconnects == k, timeout=5)


def test_downlink_commands_reach_the_right_piece(simulator):
    dev = device(2)
    still = joint_rotation(np.tile([0.1, 0.3, -0.2, 0.5], (len(dev.joints), 1)))
    sim = simulator(dev, motion=lambda t: still, seed=6)
    target = J + 21
    with SerialReader(sim.path) as reader:
        sim.start()
        assert reader.wait_for(lambda s: len(s.attached) == len(dev), timeout=5)
        reader.send(Command.led(red=False, green=True, blue=False, target=target))
        reader.send(Command.zero(target=target))
        acked = reader.wait_for(lambda s: s.components[target].acks == 2, timeout=3)
        assert acked is not None and acked.link.commands == 2
        assert sim.firmware(target).leds[1] and not any(
            sim.firmware(j).leds[1] for j in dev.joints if j != target
        )
        zeroed = reader.wait_for(lambda s: np.abs(s.components[target].angles[:3]).max() < 2e-3, timeout=3)
        assert zeroed is not None
        assert np.abs(zeroed.components[J + 20].angles[1:3]).min() > 0.1  # the others are not
        reader.send(Command.set_id(J + 99))  # direct: the piece plugged into the host
        renamed = reader.wait_for(
            lambda s: J + 99 in s.attached and s.children.get(J + 99) == (J + 2,), timeout=3
        )
        assert renamed is not None and sim.firmware(J + 1).id == J + 99


def test_a_loop_url_hears_only_its_own_polls():
    with SerialReader("loop://") as reader:
        state = reader.wait_for(lambda s: s.link.polls > 10, timeout=3)
        assert state is not None and state.components == {}
        assert state.link.echoes >= state.link.polls - 2 and state.link.missing >= state.link.polls - 2


def test_socket_url(simulator):
    """A device server on a socket: the simulator stepped by hand, in time with the host's polls."""
    dev = device(1)
    sim = simulator(dev, motion=RandomMotion(len(dev.joints), seed=8), seed=8)
    stop = threading.Event()
    with socket.create_server(("127.0.0.1", 0)) as server:
        host, port = server.getsockname()

        def serve():
            conn, _ = server.accept()
            conn.settimeout(0.005)
            with conn:
                start = time.monotonic()
                while not stop.is_set():
                    with contextlib.suppress(TimeoutError):
                        data = conn.recv(4096)
                        if not data:
                            return
                        sim.step(max(0.0, time.monotonic() - start - sim.time))
                        sim.write(data)
                    out = sim.step(max(0.0, time.monotonic() - start - sim.time))
                    if out:
                        conn.sendall(out)

        feeder = threading.Thread(target=serve, name="test-device")
        feeder.start()
        try:
            with SerialReader(f"socket://{host}:{port}", timeout=5.0) as reader:
                state = reader.wait_for(
                    lambda s: len(s.attached) == len(dev) and s.link.frames > 100, timeout=5
                )
                assert state is not None and state.link.corrupt == 0
        finally:
            stop.set()
            feeder.join()


def test_list_ports_names_devices():
    ports = list_ports()
    assert all(isinstance(d, str) and d and isinstance(text, str) and text for d, text in ports)


def test_bad_urls_missing_ports_and_bad_commands():
    with pytest.raises(DeviceError, match="nonsense"):
        SerialReader("nonsense://x")
    with SerialReader("/dev/does-not-exist-tangible", backoff=(0.01, 0.05)) as reader:
        time.sleep(0.1)
        state = reader.state()
        assert not state.connected and "does-not-exist" in state.link.error
        assert state.components == {}
        with pytest.raises(ProtocolError, match="Command"):
            reader.send(b"R")
