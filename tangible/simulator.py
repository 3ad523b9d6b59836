"""A device simulator that speaks the wire protocol over a real serial port.

::

    device = DeviceTree([Piece(1, "joint"), Piece(2, "splitter", 1, splitter=SPLITTERS["T"]), ...])
    with Simulator(device, motion=RandomMotion(len(device.joints), seed=1), faults=Faults.corrupt(0.05),
                   seed=3) as sim, SerialReader(sim.path) as reader:
        ...

By default the simulator writes to the master end of a pseudo-terminal (``os.openpty``, created on first
use of :attr:`Simulator.path` or :meth:`Simulator.start`); the slave's path (or a stable symlink ``link``
that survives :meth:`unplug` / :meth:`replug`) is what a :class:`~tangible.reader.SerialReader` opens.
It can also write to any pyserial URL or port object.

Every joint sends a data message at ``data_rate`` (50 Hz), every piece a type message and every splitter
a child message at ``info_rate`` (2 Hz), each stream with its own random phase, and each message is
relayed up the tree as Appendix A says (the first relaying piece fills the parent and slot fields).

Determinism: the byte stream is a function of the device, the motion, the faults and the seed alone —
motion is evaluated at each frame's scheduled time and faults are drawn in schedule order — so
:meth:`Simulator.stream` reproduces offline exactly what a run writes (as long as no :meth:`set_power`,
:meth:`move` or :meth:`unplug` intervenes at run time).
"""

from __future__ import annotations

import heapq
import os
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import serial

from .device import DeviceTree
from .errors import DeviceError
from .joint import BEND_LIMIT
from .protocol import (
    KIND_JOINT,
    KIND_SPLITTER,
    ChildMessage,
    DataMessage,
    Message,
    TypeMessage,
    encode,
)

__all__ = ["Faults", "KeyframeMotion", "RandomMotion", "Sent", "Simulator", "SimulatorStats"]

#: A motion gives the angles of every joint (in ``DeviceTree.joints`` order) at time t: (n, 4) radians.
Motion = Callable[[float], np.ndarray]


@dataclass(frozen=True)
class Faults:
    """Faults injected on the host link, as probabilities per frame (at most one corruption per frame).

    Attributes
    ----------
    bit_flip : float
        1–3 bits of the frame (delimiters included) inverted.
    drop_bytes : float
        1–3 bytes of the frame body left out.
    truncate : float
        The frame cut off part way (at least its last body byte and closing delimiter missing).
    lose : float
        The frame lost whole inside the device (a sequence gap on the host).
    garbage : float
        A burst of 1 … ``garbage_length`` random bytes written before the frame.
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
        """``rate`` of frames corrupted, shared equally by bit flips, dropped bytes and truncation."""
        return cls(bit_flip=rate / 3, drop_bytes=rate / 3, truncate=rate / 3, **others)


class RandomMotion:
    """Smooth random joint motion: each hinge angle a sum of three sinusoids, each twist a sinusoid plus
    a drift (the rings turn without end), all with seeded frequencies and phases.

    Parameters
    ----------
    n : int
        Number of joints.
    seed : int
    max_bend : float
        Bound on each joint's bend (radians, below 90°).
    speed : float
        Scales every frequency (1: components between 0.1 and 0.8 Hz).
    """

    def __init__(self, n: int, seed: int = 0, max_bend: float = np.radians(60.0), speed: float = 1.0):
        if not 0 < max_bend < BEND_LIMIT:
            raise DeviceError(f"max_bend must lie in (0, {BEND_LIMIT:.4f}) radians, got {max_bend!r}")
        rng = np.random.default_rng(seed)
        self.n = n
        self._freq = speed * rng.uniform(0.1, 0.8, (n, 4, 3))
        self._phase = rng.uniform(0.0, 2.0 * np.pi, (n, 4, 3))
        amp = rng.dirichlet([2.0, 2.0, 2.0], (n, 4))
        amp[:, :2] *= max_bend / np.sqrt(2.0)
        amp[:, 2:] *= np.pi
        self._amp = amp
        self._drift = np.zeros((n, 4))
        self._drift[:, 2:] = speed * rng.uniform(-0.5, 0.5, (n, 2))

    def __call__(self, t: float) -> np.ndarray:
        """(n, 4) angles at time ``t`` seconds."""
        wave = np.sum(self._amp * np.sin(2.0 * np.pi * self._freq * t + self._phase), axis=-1)
        return wave + self._drift * t


class KeyframeMotion:
    """Scripted motion: angles linearly interpolated between keys, held before the first and after the last.

    Parameters
    ----------
    times : (k,) array_like
        Increasing key times (seconds).
    angles : (k, n, 4) array_like
        Joint angles at the keys.
    """

    def __init__(self, times, angles):
        self.times = np.asarray(times, dtype=np.float64).reshape(-1)
        self.angles = np.asarray(angles, dtype=np.float64)
        if self.angles.ndim != 3 or self.angles.shape[0] != self.times.size or self.angles.shape[2] != 4:
            raise DeviceError(
                f"keyframe angles must have shape ({self.times.size}, n, 4), got {self.angles.shape}"
            )
        if np.any(np.diff(self.times) <= 0):
            raise DeviceError("keyframe times must increase")

    def __call__(self, t: float) -> np.ndarray:
        """(n, 4) angles at time ``t`` seconds."""
        i = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, self.times.size - 1))
        if i + 1 >= self.times.size or t <= self.times[0]:
            return self.angles[i].copy()
        u = (t - self.times[i]) / (self.times[i + 1] - self.times[i])
        return (1.0 - u) * self.angles[i] + u * self.angles[i + 1]


@dataclass(frozen=True)
class Sent:
    """One frame the simulator produced.

    Attributes
    ----------
    time : float
        Scheduled time, seconds since the start.
    written : float
        Clock time when its bytes, the last one included, were handed to the port in one write (taken
        just before the call, so latencies measured from it are upper bounds); nan if not written.
    message : Message
        What it carries (angles as simulated, before quantization).
    fault : str
        ``""`` (intact), ``"bit_flip"``, ``"drop_bytes"``, ``"truncate"``, ``"lose"`` (never sent) or
        ``"unsent"`` (the port would not take it).
    """

    time: float
    written: float
    message: Message
    fault: str

    @property
    def intact(self) -> bool:
        """Whether the frame reached the port unharmed."""
        return self.fault == ""


@dataclass
class SimulatorStats:
    """Counters of frames produced, by outcome, and of bytes written."""

    frames: int = 0
    intact: int = 0
    corrupted: int = 0
    lost: int = 0
    unsent: int = 0
    garbage_bytes: int = 0
    bytes: int = 0


_STREAMS = {"data": 0, "type": 1, "child": 2}


class Simulator:
    """Emulate a device tree on a serial port.

    Parameters
    ----------
    device : DeviceTree
    motion : callable, optional
        ``motion(t) -> (n_joints, 4)`` angles in ``device.joints`` order (default: all joints straight).
    faults : Faults
    seed : int
        Seeds stream phases and faults.
    port : str or serial.SerialBase, optional
        Write to this pyserial URL or port instead of a pseudo-terminal. Writes to it may block while it
        is full (a reader must drain it); writes to the pty never block (a full pty drops frames).
    link : path, optional
        With a pseudo-terminal: keep a symlink here to the current slave (like ``/dev/serial/by-id``).
    data_rate, info_rate : float
        Hz of data messages (per joint) and of type/child messages (per piece).
    history : int
        How many :class:`Sent` records to keep in :attr:`history`.
    clock : callable
        Monotonic clock shared with the reader for latency measurements.
    """

    def __init__(
        self,
        device: DeviceTree,
        *,
        motion: Motion | None = None,
        faults: Faults = Faults(),
        seed: int = 0,
        port: str | serial.SerialBase | None = None,
        link: str | os.PathLike | None = None,
        data_rate: float = 50.0,
        info_rate: float = 2.0,
        history: int = 100_000,
        clock: Callable[[], float] = time.monotonic,
    ):
        if not isinstance(device, DeviceTree):
            raise DeviceError(f"the simulator needs a DeviceTree, got {type(device).__name__}")
        if not (data_rate > 0 and info_rate > 0):
            raise DeviceError(f"rates must be positive, got data {data_rate!r}, info {info_rate!r}")
        self._device = device
        self._motion = motion
        self.faults = faults
        self.seed = seed
        self.data_rate = float(data_rate)
        self.info_rate = float(info_rate)
        self.stats = SimulatorStats()
        self.history: deque[Sent] = deque(maxlen=history)
        self._clock = clock
        self._lock = threading.Lock()
        self._unpowered: set[int] = set()
        self._seq: dict[int, int] = {}
        self._plugged = True
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_path = ""
        self._link = Path(link) if link is not None else None
        self._port: serial.SerialBase | None = None
        self._owns_port = False
        self._pty = port is None  # opened on first use (path or start), so streaming needs no pty
        self._closed = False
        if isinstance(port, str):
            try:
                self._port = serial.serial_for_url(port, timeout=0)
            except (ValueError, serial.SerialException) as e:
                raise DeviceError(f"cannot open {port!r} for the simulator: {e}") from None
            self._owns_port = True
        elif port is not None:
            self._port = port

    # ------------------------------------------------------------------ the port

    def _ensure_pty(self) -> None:
        with self._lock:
            if self._pty and self._plugged and self._master is None and not self._closed:
                self._open_pty()

    def _open_pty(self) -> None:
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
        if not self._pty:
            raise DeviceError("this simulator writes to a pyserial port, not to a pseudo-terminal")
        self._ensure_pty()
        return str(self._link) if self._link is not None else self._slave_path

    @property
    def device(self) -> DeviceTree:
        """The device as currently assembled."""
        return self._device

    def unplug(self) -> None:
        """Pull the USB cable: the pty disappears (the reader's port fails) and every piece loses power."""
        if not self._pty:
            raise DeviceError("only a pseudo-terminal simulator can be unplugged")
        with self._lock:
            self._plugged = False
            self._close_pty()

    def replug(self) -> None:
        """Plug back in: a new pty (the link, if any, points to it) and every piece restarts."""
        if not self._pty:
            raise DeviceError("only a pseudo-terminal simulator can be replugged")
        with self._lock:
            if not self._plugged:
                self._seq.clear()
                self._plugged = True
        self._ensure_pty()

    def set_power(self, piece: int, on: bool) -> None:
        """Cut or restore power to ``piece``: it and its subtree fall silent; back on, they restart."""
        if piece not in self._device:
            raise DeviceError(f"the simulated device has no piece {piece}")
        with self._lock:
            if on and piece in self._unpowered:
                self._unpowered.discard(piece)
                for p in self._device.subtree(piece):
                    self._seq.pop(p, None)
            elif not on:
                self._unpowered.add(piece)

    def move(self, piece: int, parent: int, slot: int = 0) -> None:
        """Unplug ``piece`` with its subtree and plug it into ``parent``'s ``slot`` (0: the host)."""
        with self._lock:
            self._device = self._device.moved(piece, parent, slot)

    # ------------------------------------------------------------------ frames

    def _powered(self, piece: int) -> bool:
        if not self._plugged or piece in self._unpowered:
            return False
        return not any(a in self._unpowered for a in self._device.ancestors(piece))

    def _schedule(self, rng: np.random.Generator) -> Iterator[tuple[float, int, str]]:
        heap: list[tuple[float, int, int, str]] = []
        for p in self._device:
            kinds = ["type"] + (["data"] if p.kind == "joint" else ["child"])
            for kind in kinds:
                period = 1.0 / (self.data_rate if kind == "data" else self.info_rate)
                heap.append((rng.uniform(0.0, period), p.id, _STREAMS[kind], kind))
        heapq.heapify(heap)
        while heap:
            t, pid, order, kind = heapq.heappop(heap)
            yield t, pid, kind
            period = 1.0 / (self.data_rate if kind == "data" else self.info_rate)
            heapq.heappush(heap, (t + period, pid, order, kind))

    def _message(
        self, t: float, pid: int, kind: str, joint_index: dict[int, int], counters: dict[int, int]
    ) -> Message | None:
        if not self._powered(pid):
            return None
        piece = self._device[pid]
        seq = counters.get(pid, 0)
        counters[pid] = (seq + 1) % 65536
        if kind == "data":
            if self._motion is None:
                angles = (0.0, 0.0, 0.0, 0.0)
            else:
                angles = tuple(float(a) for a in np.asarray(self._motion(t))[joint_index[pid]])
            m: Message = DataMessage(pid, 0, 0, seq, angles)
        elif kind == "type":
            code = KIND_SPLITTER if piece.kind == "splitter" else KIND_JOINT
            m = TypeMessage(pid, 0, 0, seq, code, tuple(int(c) for c in piece.colour))
        else:
            m = ChildMessage(pid, 0, 0, seq, tuple(tuple(float(c) for c in q) for q in piece.splitter.slots))
        return m.relayed(piece.parent, piece.slot) if piece.parent != 0 else m

    def _damage(self, frame: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
        f = self.faults
        if f.lose and rng.random() < f.lose:
            return b"", "lose"
        r = rng.random()
        body = len(frame) - 2
        if r < f.bit_flip:
            b = bytearray(frame)
            for pos in rng.choice(len(frame) * 8, size=int(rng.integers(1, 4)), replace=False):
                b[pos // 8] ^= 1 << (pos % 8)
            return bytes(b), "bit_flip"
        r -= f.bit_flip
        if r < f.drop_bytes:
            k = min(int(rng.integers(1, 4)), body)
            keep = np.ones(len(frame), bool)
            keep[1 + rng.choice(body, size=k, replace=False)] = False
            return bytes(np.frombuffer(frame, np.uint8)[keep]), "drop_bytes"
        r -= f.drop_bytes
        if r < f.truncate:
            return frame[: 1 + int(rng.integers(0, body))], "truncate"
        return frame, ""

    def _frames(
        self, rng: np.random.Generator, counters: dict[int, int]
    ) -> Iterator[tuple[float, Message | None, bytes, str]]:
        """(time, message, bytes to write, fault) in schedule order, forever; ``counters`` holds the
        pieces' sequence numbers. Slots of unpowered pieces come as (time, None, b"", "") so that a
        real-time player keeps pace while nothing is sent."""
        device, joint_index = None, {}
        for t, pid, kind in self._schedule(rng):
            with self._lock:
                if device is not self._device:
                    device = self._device
                    joint_index = {j: i for i, j in enumerate(device.joints)}
                m = self._message(t, pid, kind, joint_index, counters)
            if m is None:
                yield t, None, b"", ""
                continue
            frame, fault = self._damage(encode(m), rng)
            if self.faults.garbage and rng.random() < self.faults.garbage:
                junk = rng.integers(0, 256, int(rng.integers(1, self.faults.garbage_length + 1)), np.uint8)
                self.stats.garbage_bytes += junk.size
                frame = junk.tobytes() + frame
            yield t, m, frame, fault

    def stream(self, duration: float) -> Iterator[tuple[Sent, bytes]]:
        """The frames of the first ``duration`` seconds, without a port or a clock: ``(record, bytes)``
        pairs in order (``record.written`` is nan). A fresh simulator streams exactly what it would write."""
        rng = np.random.default_rng(self.seed)
        for t, m, frame, fault in self._frames(rng, {}):
            if t >= duration:
                return
            if m is None:
                continue
            yield Sent(t, float("nan"), m, fault), frame

    # ------------------------------------------------------------------ the thread

    def _write(self, data: bytes) -> bool:
        with self._lock:
            master, port = self._master, self._port
            if master is not None:  # non-blocking: a full pty drops the frame, as a device would
                try:
                    return os.write(master, data) == len(data)
                except OSError:
                    return False
        if port is None:
            return False
        try:  # a pyserial port may block while full (back-pressure); stop() cancels where it can
            return port.write(data) == len(data)
        except (OSError, serial.SerialException):
            return False

    def _count(self, sent: Sent, nbytes: int) -> None:
        s = self.stats
        s.frames += 1
        if sent.fault == "":
            s.intact += 1
        elif sent.fault == "lose":
            s.lost += 1
        elif sent.fault == "unsent":
            s.unsent += 1
        else:
            s.corrupted += 1
        s.bytes += nbytes
        self.history.append(sent)

    def _run(self) -> None:
        rng = np.random.default_rng(self.seed)
        start = self._clock()
        for t, m, frame, fault in self._frames(rng, self._seq):
            delay = start + t - self._clock()
            if delay > 0 and self._stop.wait(delay):
                return
            if self._stop.is_set():
                return
            if m is None:
                continue
            written = self._clock()
            ok = not frame or self._write(frame)
            if not ok:
                fault = "unsent"
            self._count(Sent(t, written if frame and ok else float("nan"), m, fault), len(frame) if ok else 0)

    def start(self) -> Simulator:
        """Start emitting in a background thread (once); returns self."""
        self._ensure_pty()
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="tangible-simulator", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop emitting (the port stays open, so a reader can drain what was written)."""
        self._stop.set()
        if self._port is not None and hasattr(self._port, "cancel_write"):
            self._port.cancel_write()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join()

    def close(self) -> None:
        """Stop emitting and close the pty or the port it opened (idempotent)."""
        self.stop()
        with self._lock:
            self._closed = True
            self._close_pty()
            if self._port is not None and self._owns_port:
                self._port.close()
            self._port = None

    def __enter__(self) -> Simulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
