"""Simulated firmware → pseudo-terminal → SerialReader, live: accuracy under corruption, an echoing adapter,
the 2 s topology rule, unplugging, downlink commands, and the pyserial URL schemes. Every test checks that
it leaves no thread or file open. Corruption is injected on the host link, the only one where the host can
detect it (relaying pieces recompute CRCs without checking them).

Nothing here depends on how much wall time passes (the machine may be busy): the tests wait for states of
the reader, each with the generous :data:`WAIT`, and check what they see against the simulator's own
record of what it sent and against the rules by the reader's clock (the exact timing of the 2 s rule is
checked offline on the simulated clock, in ``test_tangible_topology.py``)."""

import contextlib
import os
import socket
import threading
import time
from collections import Counter, defaultdict
from difflib import SequenceMatcher

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
from tangible.errors import CommandError, DeviceError, ProtocolError
from tangible.protocol import EMPTY, MIN_ID, AckRecord, DataRecord, encode_record

HALF_DEGREE = np.radians(0.5)
J = MIN_ID
#: Longest wait for a state of the reader; a wait ends as soon as its state holds, so this only bounds how
#: long a broken build hangs (on an idle machine every state here comes within a second or two).
WAIT = 60.0
#: Times the reader sends a command before it gives up, where a busy machine may lose many.
RESEND = 50


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


def until(reader, predicate, what: str):
    """The reader's first state for which ``predicate`` holds (waiting up to :data:`WAIT`)."""
    state = reader.wait_for(predicate, timeout=WAIT)
    assert state is not None, f"waited {WAIT:g} s for {what}; the reader is at {reader.state()}"
    return state


def drain(reader, sim):
    """Stop the simulator and wait until the reader has read every byte it wrote and closed the reply
    windows they came in (records that damage shifted are recovered when a window closes, and the
    observer hears of them right after that publication: so three more polls)."""
    sim.stop()
    written = sim.stats.bytes
    read = until(reader, lambda s: s.link.bytes >= written, f"the {written} bytes the simulator wrote")
    polls = read.link.polls
    until(reader, lambda s: s.link.polls >= polls + 3, "three more polls")


def test_reader_reproduces_joint_rotations_within_half_a_degree_with_5_percent_corruption(simulator):
    dev = device()
    motion = RandomMotion(len(dev.joints), seed=7, max_bend=np.radians(80), speed=2.0)
    received = defaultdict(list)
    sim = simulator(dev, motion=motion, faults=Faults.corrupt(0.05, garbage=0.05), seed=11)
    with SerialReader(sim.path, observer=lambda r, t: received[encode_record(r)].append(r)) as reader:
        sim.start()
        mid = until(reader, lambda s: len(s.attached) == len(dev) and s.link.frames > 400, "400 records")
        # As many records again and more, with damage of both kinds on the way (a few per hundred replies).
        until(
            reader,
            lambda s: s.link.frames > 800 and s.link.short > 0 and s.link.oversize > 0,
            "800 records, a cut-off reply and one with garbage",
        )
        drain(reader, sim)
        state = reader.state()
    sent = [s for s in sim.history if s.record is not None]
    intact = [s for s in sent if s.intact]
    damaged = [s for s in sent if s.fault not in ("", "lose")]
    assert len(sent) > 700 and 0.02 < len(damaged) / len(sent) < 0.08
    # No valid record lost, and no damaged one accepted but by the chance CRC-8 leaves (1 in 256: a record a
    # bit flip passed, or one a dropped byte shifted onto the next record's first byte): at most two such in
    # a run (about one run in a hundred has one), each sharing 14 or more of its 18 bytes with a damaged
    # record, each taking at most the record after it with it.
    want = Counter(encode_record(s.record) for s in intact)
    got = Counter({k: len(v) for k, v in received.items()})
    chance, lost = got - want, want - got
    assert sum(chance.values()) <= 2 and sum(lost.values()) <= sum(chance.values()), (chance, lost)
    for k in chance:
        near = max(SequenceMatcher(None, k, encode_record(s.record)).ratio() for s in damaged)
        assert near >= 2 * 14 / 36, f"{k.hex()} was accepted, but no damaged record looks like it"
    # Every reading equals the simulated rotation within the device's accuracy (in fact to quantization).
    data = [s for s in intact if isinstance(s.record, DataRecord) and encode_record(s.record) in received]
    got_rotations = joint_rotation([received[encode_record(s.record)][0].angles for s in data])
    err = rot.angle(got_rotations, np.array([s.rotation for s in data]))
    assert len(data) > 300 and err.max() < np.radians(0.1) < HALF_DEGREE
    # The published state holds each joint's latest reading (unless a chance record came after it); the
    # link counted the records and the damage.
    last = {s.record.creator: s for s in data}
    chance_raw = {(r.creator, r.raw) for k in chance if isinstance(r := received[k][0], DataRecord)}
    for j in dev.joints:
        c = state.components[j]
        assert rot.angle(c.rotation, last[j].rotation) < HALF_DEGREE or (j, c.raw) in chance_raw
    link = state.link
    assert link.frames == len(intact) + sum(chance.values()) - sum(lost.values())
    assert 0.7 * len(damaged) <= link.corrupt <= 1.3 * len(damaged)
    assert link.short > 0 and link.oversize > 0 and link.echoes == 0

    # Mapping to a bone: calibrated at the state seen mid-run, a binding returns the simulated rotation
    # relative to the calibration reading (of the fourth joint, or the next whose readings were all sent).
    def reading(j, state):
        return next(
            (s for s in data if s.record.creator == j and s.record.raw == state.components[j].raw), None
        )

    j = next(j for j in dev.joints[3:] + dev.joints[:3] if reading(j, mid) and reading(j, state))
    binding = JointBinding(j, bone=0, rest=mid.components[j].rotation)
    expect = rot.multiply(rot.conjugate(reading(j, mid).rotation), last[j].rotation)
    assert rot.angle(binding.bone_rotation(state.components[j].rotation), expect) < HALF_DEGREE


def test_an_echoing_adapter(simulator):
    dev = device(1)
    sim = simulator(dev, motion=RandomMotion(len(dev.joints), seed=2), seed=3, echo=True)
    with SerialReader(sim.path) as reader:
        sim.start()
        until(reader, lambda s: len(s.attached) == len(dev) and s.link.polls > 50, "50 polls")
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
        until(reader, lambda s: set(s.attached) == everything, "the whole device")
        subtree = set(dev.subtree(J + 20))
        sim.set_power(J + 20, False)
        # The subtree goes, the rest stays (with a timeout this short, a reader held up for half a second
        # on a busy machine may briefly see more pieces silent: so wait for this picture, not the first
        # state without the subtree).
        until(reader, lambda s: set(s.attached) == everything - subtree, "the device without the subtree")
        sim.set_power(J + 20, True)
        until(reader, lambda s: set(s.attached) == everything, "the subtree back")
        sim.move(J + 32, J + 11, 0)  # the cross's middle joint below joint 11...
        sim.move(J + 11, J + 30, 1)  # ...and joint 11 (with it) from under joint 10 into that slot
        moved = until(
            reader,
            lambda s: (
                s.children.get(J + 30) == (J + 31, J + 11, J + 33) and s.children.get(J + 11) == (J + 32,)
            ),
            "joint 11 under the cross, with joint 32 below it",
        )
        assert moved.components[J + 11].slot == 1 and moved.children.get(J + 10) is None


def test_the_default_rule_detaches_a_silent_subtree_after_two_seconds(simulator):
    dev = device(1)
    sim = simulator(dev, seed=4)
    below = set(dev.subtree(J + 2)) - {J + 2}
    with SerialReader(sim.path) as reader:
        sim.start()
        until(reader, lambda s: len(s.attached) == len(dev), "the whole device")
        sim.set_power(J + 2, False)  # the T splitter: everything below joint 1
        seen = []  # every state the wait looks at: at each update of the reader, and every 20 ms
        gone = until(reader, lambda s: seen.append(s) or s.attached == (J + 1,), "joint 1 alone")
    # By the reader's own clock, in every state it published: the splitter is attached exactly while it
    # was heard within 2 s (and its parent is), and its silence takes its whole subtree with it (children
    # reach the host through it). So nothing went before its 2 s, however late the wait looked.
    assert len(seen) > 1
    for s in seen:
        splitter = s.components[J + 2]
        assert splitter.attached == (s.components[J + 1].attached and s.time - splitter.last_heard <= 2.0)
        assert splitter.attached or not any(s.components[c].attached for c in below)
    assert gone.time - gone.components[J + 2].last_heard > 2.0


def test_the_reader_survives_unplugging_and_replugging_the_port(tmp_path, simulator):
    link = tmp_path / "puppet"
    dev = device(1)
    sim = simulator(dev, motion=RandomMotion(len(dev.joints), seed=1), seed=5, link=link)
    with SerialReader(sim.path, timeout=0.5, backoff=(0.02, 0.2)) as reader:
        sim.start()
        until(reader, lambda s: len(s.attached) == len(dev), "the whole device")
        sim.unplug()
        lost = until(reader, lambda s: not s.connected, "the port to fail")
        assert lost.link.error
        until(reader, lambda s: not s.attached, "every piece detached")  # silent for 0.5 s
        frozen = reader.state().components[J + 1]
        sim.replug()
        back = until(
            reader,
            lambda s: (
                s.connected
                and len(s.attached) == len(dev)
                and s.components[J + 1].data_time > frozen.data_time
            ),
            "the device back, with new readings",
        )
        assert back.link.reconnects == 1 and back.link.error == ""
        assert not np.array_equal(back.components[J + 1].angles, frozen.angles)  # live again
        # Twice more, to be sure the reconnect loop is not a one-off.
        for k in (2, 3):
            sim.unplug()
            until(reader, lambda s: not s.connected, "the port to fail")
            sim.replug()
            until(reader, lambda s, k=k: s.connected and s.link.reconnects == k, f"reconnect {k}")


def test_downlink_commands_reach_the_right_piece(simulator):
    dev = device(2)
    still = joint_rotation(np.tile([0.1, 0.3, -0.2, 0.5], (len(dev.joints), 1)))
    sim = simulator(dev, motion=lambda t: still, seed=6)
    target = J + 21
    acks = []  # every acknowledgement the reader published, in order

    def observe(record, _time):
        if isinstance(record, AckRecord):
            acks.append(record)

    # The firmware drops a command now and then: a piece ignores a poll, and the command in it, while it
    # writes its flash or still answers the last poll (which is what a simulator in this busy process sees
    # when it reads two polls at once). The reader sends it again; on a busy machine, many times.
    with SerialReader(sim.path, observer=observe, attempts=RESEND) as reader:
        sim.start()
        until(reader, lambda s: len(s.attached) == len(dev), "the whole device")
        # Two commands queued at once go out in order, each once the one before is acknowledged.
        both = [Command.led(red=False, green=True, blue=False, target=target), Command.zero(target=target)]
        deliveries = [reader.send(c) for c in both]
        for d in deliveries:
            ack = d.wait(WAIT)
            assert ack is not None and ack.creator == target and d.status == "acknowledged"
        acked = reader.state()
        assert acked.components[target].acks >= 2
        assert acked.link.commands == 2 and acked.link.resent == sum(d.attempts - 1 for d in deliveries)
        # Only the target executed them (each perhaps more than once).
        assert {(a.creator, a.command) for a in acks} == {(target, c.encode()[:8]) for c in both}
        assert sim.firmware(target).leds[1] and not any(
            sim.firmware(j).leds[1] for j in dev.joints if j != target
        )
        zeroed = until(
            reader, lambda s: np.abs(s.components[target].angles[:3]).max() < 2e-3, "zero readings"
        )
        assert np.abs(zeroed.components[J + 20].angles[1:3]).min() > 0.1  # the others are not
        # Direct: the piece plugged into the host takes the id (and acknowledges under it).
        ack = reader.send(Command.set_id(J + 99)).wait(WAIT)
        assert ack is not None and ack.creator == J + 99
        until(reader, lambda s: J + 99 in s.attached and s.children.get(J + 99) == (J + 2,), "new id")
        assert sim.firmware(J + 1).id == J + 99


class SteppedPort:
    """A pyserial-like port onto a simulator stepped by hand from the reader's own thread: a read that
    finds no byte waiting steps the simulated clock by ``dt``. A reader given this port and
    ``clock=lambda: sim.time`` runs on the simulated clock: deterministic whatever the machine's load, and
    faster than real time. Before the first poll that carries a command, ``stall`` seconds pass on the
    simulated clock with nothing written (the host held up, as a busy machine or a USB hiccup does)."""

    def __init__(self, sim: Simulator, dt: float = 0.001, stall: float = 0.0):
        self.sim, self.dt, self.stall = sim, dt, stall
        self.buffer = bytearray()
        self.command_polls = []  # simulated times at which polls carrying a command were written

    @property
    def in_waiting(self) -> int:
        return len(self.buffer)

    def read(self, size: int = 1) -> bytes:
        if not self.buffer:
            self.buffer += self.sim.step(self.dt)
        out = bytes(self.buffer[:size])
        del self.buffer[:size]
        return out

    def write(self, data: bytes) -> int:
        if data[1] != EMPTY:
            if self.stall:
                self.buffer += self.sim.step(self.stall)
                self.stall = 0.0
            self.command_polls.append(self.sim.time)
        self.sim.write(data)
        return len(data)

    def close(self) -> None:
        pass


def stepped_reader(sim: Simulator, port: SteppedPort, **kwargs) -> SerialReader:
    return SerialReader("stepped://", open_port=lambda url: port, clock=lambda: sim.time, **kwargs)


@pytest.mark.parametrize("attempts", [3, 1])
def test_a_command_lost_to_a_watchdog_restart_is_sent_again(attempts):
    """A splitter not polled for 250 ms stops feeding its window watchdog and restarts (``main.c`` lines
    298-314); the first poll after a start only sets its direction (``bus.c`` lines 35-84 return before
    ``receivedUP``): no reply, and the command in it is lost. The reader sends it again when no ack comes
    within ``ack_timeout``; with one attempt the command vanishes, and the delivery says so."""
    root = J + 1
    dev = DeviceTree([Piece(root, "splitter", splitter=SPLITTERS["T"]), Piece(J + 2, "joint", root, 0)])
    sim = Simulator(dev, seed=4)
    port = SteppedPort(sim, stall=0.4)  # > 250 ms + the watchdog's 65 ms + the boot
    with stepped_reader(sim, port, ack_timeout=0.2, attempts=attempts) as reader:
        until(reader, lambda s: set(s.attached) == {root, J + 2}, "the device")
        assert sim.firmware(root).restarts == 0
        delivery = reader.send(Command.led(red=False, green=True, blue=False, target=root))
        if attempts == 1:
            with pytest.raises(CommandError, match="no acknowledgement after 1 attempt") as err:
                delivery.wait(WAIT)
            assert err.value.attempts == 1 and delivery.status == "failed"
            state = reader.state()
            assert (state.link.unacknowledged, state.link.resent) == (1, 0)
            assert not sim.firmware(root).leds[1]  # the firmware never ran it
        else:
            ack = delivery.wait(WAIT)
            assert ack is not None and ack.creator == root and ack.code == "l"
            assert delivery.status == "acknowledged" and delivery.attempts == 2
            state = reader.state()
            assert (state.link.commands, state.link.resent, state.link.unacknowledged) == (1, 1, 0)
            assert sim.firmware(root).leds[1]
            # Sent again one ack timeout (and at most a poll more) after the lost one (float sums of steps).
            assert 0.2 - 1e-9 <= port.command_polls[1] - port.command_polls[0] < 0.2 + 0.03
        assert sim.firmware(root).restarts == 1  # the stall did restart the splitter
        assert state.link.missing >= 1  # and the poll with the command got no reply


def test_a_command_nobody_acknowledges_fails_after_the_attempts_in_bounded_time():
    """A command for an id no piece has is flooded down the tree and acknowledged by nobody (``main.c``
    lines 461-476): the reader sends it ``attempts`` times, ``ack_timeout`` apart, then reports it
    failed (the delivery, the link counters, the log) and goes on with the next command."""
    dev = DeviceTree([Piece(J + 1, "joint"), Piece(J + 2, "joint", J + 1)])
    sim = Simulator(dev, seed=5)
    port = SteppedPort(sim)
    with stepped_reader(sim, port, ack_timeout=0.1, attempts=3) as reader:
        until(reader, lambda s: set(s.attached) == {J + 1, J + 2}, "the device")
        nobody = reader.send(Command.led(red=False, green=True, blue=False, target=J + 99))
        after = reader.send(Command.led(red=False, green=True, blue=False, target=J + 2))
        with pytest.raises(CommandError, match=f"piece {J + 99:#x} got no acknowledgement after 3"):
            nobody.wait(WAIT)
        assert nobody.attempts == 3
        assert after.wait(WAIT) is not None and after.attempts == 1  # the next command goes on
        # Bounded: three sends, each an ack timeout (and less than a poll more) after the last, then the
        # next command as soon as the third's ack timeout has passed.
        assert len(port.command_polls) == 4
        gaps = np.diff(port.command_polls)  # differences of float sums of the step: 0.1 may come out 0.0999…
        assert ((gaps >= 0.1 - 1e-9) & (gaps < 0.1 + 0.03)).all(), gaps
        link = reader.state().link
        assert (link.commands, link.resent, link.unacknowledged) == (2, 2, 1)
        assert "no acknowledgement" in link.command_error and link.error == ""
    assert sim.firmware(J + 2).leds[1]


def test_a_loop_url_hears_only_its_own_polls():
    with SerialReader("loop://") as reader:
        state = until(reader, lambda s: s.link.polls > 10, "ten polls")
        assert state.components == {}
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
                state = until(
                    reader, lambda s: len(s.attached) == len(dev) and s.link.frames > 100, "100 records"
                )
                assert state.link.corrupt == 0
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
