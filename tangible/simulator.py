"""The published firmware, simulated: every piece a state machine that answers its parent's polls and polls
its children, on a simulated clock, behind a pseudo-terminal or stepped by hand.

::

    device = DeviceTree([Piece(0x1000001, "joint"), Piece(0x1000002, "splitter", 0x1000001, ...), ...])
    with Simulator(device, motion=RandomMotion(len(device.joints), seed=1), faults=Faults.corrupt(0.05),
                   seed=3) as sim, SerialReader(sim.path) as reader:
        ...

    sim = Simulator(device, seed=3)          # or without wall time: the host's bytes in, the device's out
    sim.write(poll_bytes())
    reply = sim.step(0.02)                   # 216 bytes (after the device has booted and been polled)

Each piece runs the published firmware's state machines (:mod:`tangible.firmware`: a joint is two
controllers, a splitter one), polled by the host through the root piece.

Sensors: the motion gives each joint's rotation; :func:`tangible.joint.joint_angles` turns it into the
four angles in record order (all twist on the distal ring), and each sensor reads its angle plus its
mounting offset, 14 bits. Out of the box every piece is zeroed at its mounting offsets (as if ``'z'``
had been sent with the joint straight), so the host reads the motion's angles.

Faults are injected on the link to the host only: inside the device a relayer does not check CRCs and
recomputes them, so damage on an inner link reaches the host as a valid record that nothing can detect.

Determinism: everything is a function of the device, the motion, the faults, the seed and the host's
bytes with their times; stepped by hand, the same calls give the same bytes.
"""

from __future__ import annotations

import heapq
import math
import os
import select
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .device import DeviceTree
from .errors import DeviceError, RecordError
from .firmware import RESET_MS, Controller, FirmwareState, Flash, Host
from .joint import joint_angles, joint_rotation
from .motions import KeyframeMotion, Motion, RandomMotion
from .protocol import (
    BYTE_TIME,
    CYCLE,
    DATA,
    EMPTY,
    MAX_ID,
    MIN_ID,
    NODE_JOINT_TUT_T,
    NODE_JOINT_TUT_TU,
    POLL_SIZE,
    RECORD_SIZE,
    Command,
    Record,
    decode_record,
    poll_bytes,
    splitter_angles,
)

__all__ = ["Faults", "FirmwareState", "KeyframeMotion", "RandomMotion", "Sent", "Simulator", "SimulatorStats"]

_SAMPLE = 0.002  # the simulated sensors' sampling grid
_BLOCK = 10  # sampling instants computed at once


# ---------------------------------------------------------------------------- faults


@dataclass(frozen=True)
class Faults:
    """Faults injected on the link to the host.

    Attributes
    ----------
    bit_flip : float
        Per record (not empty ones): a noise burst inverts 1–3 bits within two adjacent bytes.
    drop_bytes : float
        Per record: 1–3 of its bytes are lost.
    truncate : float
        Per record: the reply is cut off inside it (the rest of the reply is lost).
    lose : float
        Per reply: it is lost whole (the host's poll goes unanswered).
    garbage : float
        Per reply: a burst of 1 … ``garbage_length`` random bytes is inserted between two of its records.
    garbage_length : int
    """

    bit_flip: float = 0.0
    drop_bytes: float = 0.0
    truncate: float = 0.0
    lose: float = 0.0
    garbage: float = 0.0
    garbage_length: int = 64

    def __post_init__(self):
        p = (self.bit_flip, self.drop_bytes, self.truncate, self.lose, self.garbage)
        if not all(0.0 <= x <= 1.0 for x in p) or self.bit_flip + self.drop_bytes + self.truncate > 1.0:
            raise DeviceError(f"fault probabilities must lie in [0, 1] and corruptions sum to ≤ 1, got {p}")
        if self.garbage_length < 1:
            raise DeviceError(f"garbage_length must be at least 1, got {self.garbage_length}")

    @classmethod
    def corrupt(cls, rate: float, **others) -> Faults:
        """``rate`` of the records damaged, shared equally by bit flips, dropped bytes and truncation."""
        return cls(bit_flip=rate / 3, drop_bytes=rate / 3, truncate=rate / 3, **others)


# ---------------------------------------------------------------------------- what the host sees


@dataclass(frozen=True)
class Sent:
    """One record the simulated device sent to the host (empty records not included).

    Attributes
    ----------
    time : float
        Simulated time the reply's last byte left the device.
    written : float
        Clock time just before the reply was written to the pseudo-terminal (nan when stepped by hand),
        so latencies measured from it are upper bounds.
    record : Record or None
        What the record says, decoded from its bytes before any fault (None if the firmware made a record
        the host cannot decode).
    fault : str
        ``""`` (intact), ``"bit_flip"``, ``"drop_bytes"``, ``"truncate"`` (the reply was cut inside it) or
        ``"lose"`` (never reached the host: the reply was lost or cut before it).
    angles : (4,) tuple or None
        For a joint's data record, the angles it stands for, unquantized (record order, radians): the
        sensors' readings as sampled (the distal twist one poll of the 0x74 half older than the rest),
        minus the zero offsets.
    sampled : float or None
        When a data record's proximal sensors were read (simulated time).
    """

    time: float
    written: float
    record: Record | None
    fault: str
    angles: tuple[float, float, float, float] | None = None
    sampled: float | None = None

    @property
    def intact(self) -> bool:
        """Whether the record reached the host unharmed."""
        return self.fault == ""

    @property
    def rotation(self) -> np.ndarray | None:
        """(4,) the joint rotation (unit quaternion) :attr:`angles` stand for
        (:func:`tangible.joint.joint_rotation`); None without angles."""
        return None if self.angles is None else joint_rotation(np.array(self.angles))


@dataclass
class SimulatorStats:
    """What went to the host: polls answered, records (not empty ones) by outcome, bytes."""

    polls: int = 0
    replies: int = 0
    records: int = 0
    intact: int = 0
    corrupted: int = 0
    lost: int = 0
    garbage_bytes: int = 0
    echoes: int = 0
    bytes: int = 0


# ---------------------------------------------------------------------------- the simulator


class Simulator:
    """Emulate a device tree running the published firmware.

    Parameters
    ----------
    device : DeviceTree
        Piece ids are the firmware's ids, :data:`~tangible.protocol.MIN_ID` …
        :data:`~tangible.protocol.MAX_ID` (the firmware cannot name a relayer with a smaller id).
    motion : callable, optional
        ``motion(t) -> (n_joints, 4)`` rotations in ``device.joints`` order (default: all joints straight).
    faults : Faults
        On the link to the host.
    seed : int
        Seeds the sensors' mounting offsets and the faults.
    echo : bool
        Simulate a half-duplex adapter that sends the host's own bytes back.
    link : path, optional
        With a pseudo-terminal: keep a symlink here to the current slave (like ``/dev/serial/by-id``).
    history : int
        How many :class:`Sent` records to keep in :attr:`history`.
    clock : callable
        Monotonic clock of the real-time mode, shared with the reader for latency measurements.
    """

    def __init__(
        self,
        device: DeviceTree,
        *,
        motion: Motion | None = None,
        faults: Faults = Faults(),
        seed: int = 0,
        echo: bool = False,
        link: str | os.PathLike | None = None,
        history: int = 100_000,
        clock: Callable[[], float] = time.monotonic,
    ):
        if not isinstance(device, DeviceTree):
            raise DeviceError(f"the simulator needs a DeviceTree, got {type(device).__name__}")
        for p in device:
            if not MIN_ID <= p.id <= MAX_ID:
                raise DeviceError(
                    f"piece {p.id}: the firmware's ids run from {MIN_ID:#x} to {MAX_ID:#x} (a relaying piece "
                    "fills in its id only if byte 5 of a record is 0, so smaller ids lose the topology)"
                )
        self._device = device
        self._motion = motion
        self._vectorized = isinstance(motion, RandomMotion | KeyframeMotion)
        self.faults = faults
        self.seed = seed
        self.echo = bool(echo)
        self.stats = SimulatorStats()
        self.history: deque[Sent] = deque(maxlen=history)
        self._clock = clock
        self._lock = threading.RLock()
        self._rng = np.random.default_rng([seed, 1])
        self._events: list = []
        self._seq = 0
        self._time = 0.0
        self._out: list[tuple[float, bytes, list]] = []  # (time, bytes, history records) for the host
        self._host_in = bytearray()
        self._host_in_time = 0.0
        self._host = Host(self)
        self._host_due: list[float] = []
        self._angle_block: tuple[int, np.ndarray] | None = None
        self._unpowered: set[int] = set()
        self._plugged = True
        # The sensors: per joint a mounting offset per angle (raw units), the factory zero at it.
        joints = device.joints
        mrng = np.random.default_rng([seed, 0])
        self._mount = mrng.uniform(1.0, 16383.0, (len(joints), 4))
        self._joint_index = {j: i for i, j in enumerate(joints)}
        self._nodes: dict[int, tuple[Controller, ...]] = {}
        for p in device:
            self._nodes[p.id] = self._make(p)
        self._wire()
        for p in device:
            for node in self._nodes[p.id]:
                node.power(True, 0.0)
        # The real-time mode.
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_path = ""
        self._link = Path(link) if link is not None else None
        self._closed = False
        self._t0: float | None = None

    # ------------------------------------------------------------------ building

    def _make(self, p) -> tuple[Controller, ...]:
        colour = [int(c) for c in p.colour]
        if p.kind == "joint":
            m = self._mount[self._joint_index[p.id]]
            zero = [round(x) % 16384 for x in m]
            tu = Controller(self, p.id, "tu", Flash(p.id, NODE_JOINT_TUT_TU, colour, list(zero)))
            t = Controller(self, p.id, "t", Flash(p.id, NODE_JOINT_TUT_T, colour, list(zero)))
            return tu, t
        n = p.splitter.valence
        flash = Flash(p.id, (n << 4) | 0x08, colour, [0, 0, 0, 0])
        angles = splitter_angles(p.splitter.slots)
        for s in range(n):
            flash.outputs[s] = 1
            flash.geometry[s] = [(round(math.degrees(a)) & 0xFFFF) for a in angles[s]]
        return (Controller(self, p.id, "splitter", flash),)

    def _wire(self) -> None:
        """Connect the controllers as the device tree says."""
        for nodes in self._nodes.values():
            for node in nodes:
                node.ports = [None] * len(node.ports)
                node.parent = None
            if len(nodes) == 2:  # a joint: the 0x84 half is the 0x74 half's child
                nodes[0].ports[0] = nodes[1]
                nodes[1].parent, nodes[1].port_at_parent = nodes[0], 0
        self._root = None
        for p in self._device:
            up = self._nodes[p.id][0]
            if p.parent == 0:
                self._root = up
                up.parent, up.port_at_parent = self._host, 0
            else:
                below = self._nodes[p.parent][-1]
                below.ports[p.slot] = up
                up.parent, up.port_at_parent = below, p.slot

    # ------------------------------------------------------------------ events

    def _at(self, t: float, node: Controller | None, fn, *args) -> None:
        if getattr(fn, "__self__", None) is self._host:
            self._host_due.append(t)
        self._seq += 1
        heapq.heappush(self._events, (t, self._seq, node, node.epoch if node else 0, fn, args))

    def _advance(self, until: float) -> None:
        ev = self._events
        while ev and ev[0][0] <= until:
            t, _, node, epoch, fn, args = heapq.heappop(ev)
            self._time = max(self._time, t)
            if node is not None and (node.epoch != epoch or not node.powered):
                continue
            fn(t, *args)
        self._time = max(self._time, until)

    # ------------------------------------------------------------------ sensors

    def _angles_at(self, t: float) -> np.ndarray:
        """(n, 4) every joint's angles (record order) at the sensors' sampling instant for ``t``: the motion
        is sampled on a :data:`_SAMPLE` grid, :data:`_BLOCK` instants at a time (so a motion that changes
        at run time shows within 20 ms)."""
        g = math.floor(t / _SAMPLE + 1e-6)
        block = self._angle_block
        if block is None or not block[0] <= g < block[0] + _BLOCK:
            n = len(self._joint_index)
            if self._motion is None or n == 0:
                a = np.zeros((_BLOCK, n, 4))
            else:
                times = (g + np.arange(_BLOCK)) * _SAMPLE
                q = np.asarray(self._motion(times), dtype=np.float64) if self._vectorized else None
                if q is None or q.shape != (_BLOCK, n, 4):
                    q = np.stack([np.asarray(self._motion(x), dtype=np.float64).reshape(n, 4) for x in times])
                a = joint_angles(q)
            block = self._angle_block = (g, a)
        return block[1][g - block[0]]

    def _read(self, piece: int, t: float, which: Iterable[int]) -> tuple[list[int], list[float]]:
        """The 14-bit readings (and their unrounded values) of ``piece``'s sensors ``which`` at ``t``."""
        j = self._joint_index[piece]
        a = self._angles_at(t)[j]
        m = self._mount[j]
        floats = [float((m[i] + a[i] * 16384 / (2 * math.pi)) % 16384) for i in which]
        return [round(x) % 16384 for x in floats], floats

    # ------------------------------------------------------------------ the host link

    def _to_host(self, t: float, lines: list[bytes], metas: list) -> None:
        """The root piece's reply, through the faults, onto the host's wire."""
        f, rng = self.faults, self._rng
        self.stats.replies += 1
        faults = [""] * len(lines)
        real = [i for i, line in enumerate(lines) if line[0] != EMPTY]
        out = bytearray()
        if f.lose and rng.random() < f.lose:
            faults = ["lose"] * len(lines)
        else:
            blocks: list[bytes] = []
            cut = False
            for i, line in enumerate(lines):
                if cut:
                    faults[i] = "lose"
                    continue
                if line[0] == EMPTY:
                    blocks.append(line)
                    continue
                r = rng.random()
                if r < f.bit_flip:
                    b = bytearray(line)
                    start = int(rng.integers(0, RECORD_SIZE * 8 - 15))
                    for bit in rng.choice(16, size=int(rng.integers(1, 4)), replace=False):
                        pos = start + int(bit)
                        b[pos // 8] ^= 0x80 >> (pos % 8)
                    blocks.append(bytes(b))
                    faults[i] = "bit_flip"
                elif r < f.bit_flip + f.drop_bytes:
                    keep = np.ones(RECORD_SIZE, bool)
                    keep[rng.choice(RECORD_SIZE, size=int(rng.integers(1, 4)), replace=False)] = False
                    blocks.append(bytes(np.frombuffer(line, np.uint8)[keep]))
                    faults[i] = "drop_bytes"
                elif r < f.bit_flip + f.drop_bytes + f.truncate:
                    blocks.append(line[: int(rng.integers(1, RECORD_SIZE))])
                    faults[i] = "truncate"
                    cut = True
                else:
                    blocks.append(line)
            if f.garbage and rng.random() < f.garbage:
                junk = rng.integers(0, 256, int(rng.integers(1, f.garbage_length + 1)), np.uint8).tobytes()
                blocks.insert(int(rng.integers(0, len(blocks) + 1)), junk)
                self.stats.garbage_bytes += len(junk)
            out = bytearray(b"".join(blocks))
        sent = []
        for i in real:
            try:
                record = decode_record(lines[i])
            except RecordError:
                record = None
            meta = metas[i]
            angles = sampled = None
            if lines[i][0] == DATA and isinstance(meta, tuple):
                sampled, angles = meta
            sent.append([t, record, faults[i], angles, sampled])
            self.stats.records += 1
            if faults[i] == "":
                self.stats.intact += 1
            elif faults[i] == "lose":
                self.stats.lost += 1
            else:
                self.stats.corrupted += 1
        self._out.append((t, bytes(out), sent))

    def _receive(self, data: bytes, t: float) -> None:
        """Bytes from the host arrive at the root (its DMA takes 11 at a time)."""
        if not data:
            return
        if self.echo:
            self._out.append((t, bytes(data), []))
            self.stats.echoes += 1
        if not self._plugged:
            return
        if self._host_in and t - self._host_in_time > RESET_MS / 1000.0:
            self._host_in.clear()  # a partial poll: the receiver is reset after 250 ms
        start = t
        for k, byte in enumerate(data):
            if not self._host_in:
                self._host_in_time = start + k * BYTE_TIME
            self._host_in.append(byte)
            if len(self._host_in) == POLL_SIZE:
                poll = bytes(self._host_in)
                self._host_in.clear()
                arrive = start + (k + 1) * BYTE_TIME
                root = self._root
                self.stats.polls += 1
                if root is not None:
                    self._at(arrive, None, self._poll_root, root, poll)

    def _poll_root(self, t: float, root: Controller, poll: bytes) -> None:
        if root is self._root and root.powered:
            root.on_poll(t, poll, self._host, 0)

    def _collect(self, until: float) -> bytes:
        out = bytearray()
        keep = []
        for t, data, sent in self._out:
            if t <= until + 1e-12:
                out += data
                self.stats.bytes += len(data)
                for s in sent:
                    self.history.append(Sent(s[0], float("nan"), s[1], s[2], s[3], s[4]))
            else:
                keep.append((t, data, sent))
        self._out = keep
        return bytes(out)

    # ------------------------------------------------------------------ stepping by hand

    @property
    def time(self) -> float:
        """The simulated clock, seconds since the device was powered."""
        return self._time

    @property
    def clock_origin(self) -> float | None:
        """In real time: the ``clock`` time of simulated time 0 (None until :meth:`start`)."""
        return self._t0

    def _manual(self) -> None:
        if self._thread is not None:
            raise DeviceError("the simulator runs in real time; stop it before stepping it by hand")

    def write(self, data: bytes) -> None:
        """The host writes ``data`` at the current simulated time (it reaches the device one byte every
        :data:`~tangible.protocol.BYTE_TIME`)."""
        self._manual()
        with self._lock:
            self._receive(bytes(data), self._time)

    def step(self, dt: float) -> bytes:
        """Advance the simulated clock by ``dt`` seconds; returns what the device sent the host meanwhile
        (replies that were complete by then, and echoes)."""
        self._manual()
        if not dt >= 0:
            raise DeviceError(f"cannot step by {dt!r} seconds")
        with self._lock:
            until = self._time + dt
            self._advance(until)
            return self._collect(until)

    def exchange(self, command: Command | None = None, wait: float = CYCLE) -> bytes:
        """Poll once, as a host would: write ``b"R"`` and ``command`` (empty by default), wait ``wait``
        seconds, return what came back."""
        self.write(poll_bytes(command))
        return self.step(wait)

    def polled(
        self,
        duration: float,
        period: float = CYCLE,
        commands: Iterable[tuple[float, Command]] = (),
    ) -> Iterator[tuple[float, bytes, bytes]]:
        """Play a host that polls every ``period`` for ``duration`` seconds: yields ``(time, poll, received)``
        per poll. ``commands`` are ``(time, Command)``, each sent in the first poll at or after its time."""
        pending = sorted(commands, key=lambda c: c[0])
        end = self._time + duration
        while self._time < end - 1e-12:
            command = pending.pop(0)[1] if pending and self._time >= pending[0][0] - 1e-12 else None
            t = self._time
            poll = poll_bytes(command)
            self.write(poll)
            yield t, poll, self.step(period)

    # ------------------------------------------------------------------ the pieces

    @property
    def device(self) -> DeviceTree:
        """The device as currently assembled."""
        return self._device

    def firmware(self, piece: int) -> FirmwareState:
        """The firmware state of ``piece`` (a joint: its 0x74 half)."""
        if piece not in self._nodes:
            raise DeviceError(f"the simulated device has no piece {piece}")
        with self._lock:
            return self._nodes[piece][0].state()

    def _now(self) -> float:
        if self._thread is not None and self._t0 is not None:
            return max(self._time, self._clock() - self._t0)
        return self._time

    def _apply_power(self, t: float) -> None:
        for p in self._device:
            on = self._plugged and p.id not in self._unpowered
            on = on and not any(a in self._unpowered for a in self._device.ancestors(p.id))
            for node in self._nodes[p.id]:
                node.power(on, t)

    def set_power(self, piece: int, on: bool) -> None:
        """Cut or restore power to ``piece``: it and its subtree fall silent; back on, they boot."""
        if piece not in self._device:
            raise DeviceError(f"the simulated device has no piece {piece}")
        with self._lock:
            if on:
                self._unpowered.discard(piece)
            else:
                self._unpowered.add(piece)
            self._apply_power(self._now())

    def move(self, piece: int, parent: int, slot: int = 0) -> None:
        """Unplug ``piece`` with its subtree and plug it into ``parent``'s ``slot`` (0: the host); the
        moved pieces restart."""
        with self._lock:
            self._device = self._device.moved(piece, parent, slot)
            t = self._now()
            moved = self._device.subtree(piece)
            for p in moved:
                for node in self._nodes[p]:
                    node.power(False, t)
            self._wire()
            self._apply_power(t)

    # ------------------------------------------------------------------ the pseudo-terminal

    def _ensure_pty(self) -> None:
        with self._lock:
            if self._plugged and self._master is None and not self._closed:
                master, slave = os.openpty()
                tty.setraw(slave)
                os.set_blocking(master, False)
                self._master, self._slave = master, slave
                self._slave_path = os.ttyname(slave)
                if self._link is not None:
                    tmp = self._link.with_name(self._link.name + ".new")
                    tmp.unlink(missing_ok=True)
                    os.symlink(self._slave_path, tmp)
                    os.replace(tmp, self._link)

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None
        if self._link is not None and self._link.is_symlink():
            self._link.unlink()

    @property
    def path(self) -> str:
        """What a reader should open: the link if one was asked for, else the pty slave's path (the pty
        is created on first use)."""
        self._ensure_pty()
        return str(self._link) if self._link is not None else self._slave_path

    def unplug(self) -> None:
        """Pull the USB cable: the pty disappears (the reader's port fails) and every piece loses power."""
        with self._lock:
            self._plugged = False
            self._close_pty()
            self._host_in.clear()
            self._apply_power(self._now())

    def replug(self) -> None:
        """Plug back in: a new pty (the link, if any, points to it) and every piece boots."""
        with self._lock:
            if not self._plugged:
                self._plugged = True
                self._apply_power(self._now())
        self._ensure_pty()

    # ------------------------------------------------------------------ real time

    def _run(self) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            with self._lock:
                master = self._master
                now = self._clock() - self._t0
                if master is not None:
                    try:
                        while True:
                            chunk = os.read(master, 4096)
                            if not chunk:
                                break
                            buf += chunk
                    except (BlockingIOError, InterruptedError):
                        pass
                    except OSError:
                        pass
                if buf:
                    self._receive(bytes(buf), now)
                    buf.clear()
                self._advance(now)
                due = [item for item in self._out if item[0] <= now + 1e-12]
                self._out = [item for item in self._out if item[0] > now + 1e-12]
                for _, data, sent in due:
                    written = self._clock()
                    ok = True
                    if data and master is not None:
                        try:
                            ok = os.write(master, data) == len(data)
                        except OSError:
                            ok = False
                    self.stats.bytes += len(data) if ok else 0
                    for s in sent:
                        self.history.append(Sent(s[0], written if ok else float("nan"), *s[1:]))
                # Wake for the next reply due, else every 5 ms to keep the pieces' clocks close.
                self._host_due = [d for d in self._host_due if d > now]
                wake = min([item[0] for item in self._out] + self._host_due + [now + 0.005])
            timeout = max(0.0, wake - (self._clock() - self._t0))
            if master is not None:
                try:
                    select.select([master], [], [], timeout)
                except (OSError, ValueError):
                    self._stop.wait(timeout)
            else:
                self._stop.wait(timeout)

    def start(self) -> Simulator:
        """Run in real time in a background thread (once), behind the pseudo-terminal; returns self."""
        self._ensure_pty()
        if self._thread is None:
            self._t0 = self._clock() - self._time
            self._thread = threading.Thread(target=self._run, name="tangible-simulator", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the device (the pty stays open, so a reader can drain what was written)."""
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join()

    def close(self) -> None:
        """Stop and close the pty (idempotent)."""
        self.stop()
        with self._lock:
            self._closed = True
            self._close_pty()

    def __enter__(self) -> Simulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
