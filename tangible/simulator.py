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

What each piece does is what ``Hardware/Firmware/Src/main.c`` and ``utility.c`` do (``PROTOCOL.md`` says
where):

* A joint is two controllers with one id: the 0x74 half (``NODE_JOINT_TUT_TU``: proximal twist and both
  bends) and, as its only child on the bus, the 0x84 half (``NODE_JOINT_TUT_T``: distal twist), whose own
  child is whatever is plugged into the joint. A splitter (type ``outputs << 4 | 8``) switches its one
  down UART across its outputs (the 74HC4051 multiplexer) and polls them in turn.
* Polled (``'R'`` and a 10-byte command), a piece answers with 12 records from its queue, padded with
  ``'E'`` records, runs the command if it is for it (or queues it for its children), and a joint then reads
  its sensors into a new data record (replacing the queued one). The first poll after power-on only sets
  the piece's direction and gets no answer.
* Each piece polls its children: a joint its one child, then waits > 7 ms; a splitter its outputs one
  after the other without a pause, skipping for 200 ms an output that did not answer more than 10 times.
  A poll not answered within 13 ms times out. Relayed records get the relayer's id (and a splitter's
  port) if byte 5 is still 0 and a fresh CRC; data and init records replace a queued record of the same
  creator and kind, acks and splitter records are appended; a queue holds 31 records and drops its
  oldest. The 0x74 half keeps its brother's records to itself (the distal twist goes into its own data).
* Every 1000 ms a piece queues its init record (and a splitter one splitter record per output). A
  splitter not polled, or hearing no child, for 250 ms stops feeding its watchdog and restarts.
* Commands change the piece's flash (zero offsets, polarity, id, type, colour, splitter geometry) and
  its LEDs; a command that writes flash makes the piece deaf for the page erase.

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
import struct
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import rotations as rot
from .device import DeviceTree
from .errors import DeviceError, RecordError
from .joint import BEND_LIMIT, joint_angles, joint_rotation
from .protocol import (
    ACK,
    BROADCAST_ID,
    BY_ID,
    BYTE_TIME,
    COMMAND_SIZE,
    CYCLE,
    DATA,
    DIRECT,
    EMPTY,
    EMPTY_COMMAND,
    EMPTY_RECORD,
    INIT,
    MAX_ID,
    MIN_ID,
    NODE_JOINT_TUT_T,
    NODE_JOINT_TUT_TU,
    POLL,
    POLL_SIZE,
    RECORD_SIZE,
    RECORDS_PER_REPLY,
    SPLITTER,
    Command,
    Record,
    crc8,
    decode_record,
    poll_bytes,
    splitter_angles,
)

__all__ = ["Faults", "FirmwareState", "KeyframeMotion", "RandomMotion", "Sent", "Simulator", "SimulatorStats"]

#: A motion gives the rotation of every joint (in ``DeviceTree.joints`` order) at time t: (n, 4).
Motion = Callable[[float], np.ndarray]

# The firmware's timing (TIM16 counts milliseconds; comparisons are "counter - then > N").
_RESPONSE = 0.0002  # main-loop latency before a polled piece starts its reply
_CHILD_TIMEOUT_MS = 13  # RECEIVING gives up
_DELAY_MS = 7  # a joint's pause after polling its child
_INIT_MS = 1000  # init and splitter records
_RESET_MS = 250  # unpolled / no child heard: a splitter stops feeding its watchdog
_SILENT_UP_MS = 500  # no reply sent for this long: the same
_SKIP_MS = 200  # a splitter skips an output that timed out more than 10 times
_LOOP = 20e-6  # one main-loop iteration (a splitter stepping past skipped outputs)
_BOOT = 0.010  # power-on to the main loop
_WATCHDOG = 4096 * 2 * (127 - 63) / 8e6  # WWDG at 8 MHz, prescaler 2, counter 127 → reset at 63
_FLASH = 0.025  # a page erase and the setup words, interrupts off
_QUEUE = 31  # uart_queue: 32 slots, one always free
_SAMPLE = 0.002  # the simulated sensors' sampling grid
_BLOCK = 10  # sampling instants computed at once
_MASK = 0x3FFF
_U32 = struct.Struct(">I")


def _tick(t: float) -> int:
    return math.floor(t * 1000.0 + 1e-6)


def _after(t: float, ms: int) -> float:
    """The first time at which the firmware's ``counter - tick(t) > ms`` holds."""
    return (_tick(t) + ms + 1) / 1000.0


# ---------------------------------------------------------------------------- faults and motions


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


class RandomMotion:
    """Smooth random joint motion: in record order, each twist a sum of three sinusoids plus a drift (the
    rings turn without end) and each bend a sum of three sinusoids, with seeded frequencies and phases,
    as rotations (:func:`tangible.joint.joint_rotation`).

    Parameters
    ----------
    n : int
        Number of joints.
    seed : int
    max_bend : float
        Bound on each hinge angle (radians, below 90°).
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
        amp[:, 1:3] *= max_bend / np.sqrt(2.0)
        amp[:, [0, 3]] *= np.pi
        self._amp = amp
        self._drift = np.zeros((n, 4))
        self._drift[:, [0, 3]] = speed * rng.uniform(-0.5, 0.5, (n, 2))

    def angles(self, t) -> np.ndarray:
        """(..., n, 4) the joints' angles at time(s) ``t`` (seconds, any shape), record order."""
        t = np.asarray(t, dtype=np.float64)[..., None, None]
        wave = np.sum(self._amp * np.sin(2.0 * np.pi * self._freq * t[..., None] + self._phase), axis=-1)
        return wave + self._drift * t

    def __call__(self, t) -> np.ndarray:
        """(..., n, 4) rotations at time(s) ``t``."""
        return joint_rotation(self.angles(t))


class KeyframeMotion:
    """Scripted motion: rotations slerped between keys, held before the first and after the last.

    Parameters
    ----------
    times : (k,) array_like
        Increasing key times (seconds).
    rotations : (k, n, 4) array_like
        Joint rotations (quaternions) at the keys.
    """

    def __init__(self, times, rotations):
        self.times = np.asarray(times, dtype=np.float64).reshape(-1)
        self.rotations = np.asarray(rotations, dtype=np.float64)
        r = self.rotations
        if r.ndim != 3 or r.shape[0] != self.times.size or r.shape[2] != 4:
            raise DeviceError(f"keyframe rotations must have shape ({self.times.size}, n, 4), got {r.shape}")
        if np.any(np.diff(self.times) <= 0):
            raise DeviceError("keyframe times must increase")

    def __call__(self, t) -> np.ndarray:
        """(..., n, 4) rotations at time(s) ``t`` (seconds, any shape)."""
        t = np.asarray(t, dtype=np.float64)
        last = self.times.size - 1
        i = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, last)
        j = np.minimum(i + 1, last)
        span = np.where(j > i, self.times[j] - self.times[i], 1.0)
        u = np.clip((t - self.times[i]) / span, 0.0, 1.0)[..., None]
        return rot.slerp(self.rotations[i], self.rotations[j], u)


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


@dataclass(frozen=True)
class FirmwareState:
    """A piece's firmware as it stands (its 0x74 half for a joint): its flash and RAM that a test may
    want to see.

    ``leds`` is ``(red, green, blue)`` as last set; the firmware's main loop also turns blue off on every
    iteration once the piece has been polled, and toggles red every 250 ms (not modelled). ``queued``
    counts the records waiting to go up, ``commands`` the commands waiting to go down.
    """

    id: int
    node_type: int
    colour: tuple[int, int, int]
    zero: tuple[int, int, int, int]
    polarity: int
    data_mode: int
    leds: tuple[bool, bool, bool]
    geometry: dict[int, tuple[int, int, int]]
    powered: bool
    polled: bool
    queued: int
    commands: int


# ---------------------------------------------------------------------------- one controller


@dataclass
class _Flash:
    """What ``config_data_flash_struct`` keeps across power cycles."""

    id: int
    node_type: int
    colour: list[int]
    zero: list[int]
    polarity: int = 0
    hardware: int = 2
    outputs: list[int] = field(default_factory=lambda: [0] * 8)
    geometry: list[list[int]] = field(default_factory=lambda: [[0, 0, 0] for _ in range(8)])


def _line(kind: int, ident: int, payload: bytes) -> bytes:
    """``create_up_message``: kind, id, four zero bytes, payload, CRC."""
    body = bytes([kind]) + _U32.pack(ident & 0xFFFFFFFF) + bytes(4) + payload
    return body + bytes([crc8(body)])


def _with_crc(line: bytearray | bytes) -> bytes:
    b = bytes(line[: len(line) - 1])
    return b + bytes([crc8(b)])


class _Host:
    """The host as a parent: where the root piece's replies go."""

    def __init__(self, sim: Simulator):
        self.sim = sim

    def on_reply(self, t, token, port, lines, metas):
        self.sim._to_host(t, lines, metas)

    def on_timeout(self, t, token, port):
        pass


class _Node:
    """One microcontroller running the firmware."""

    def __init__(self, sim: Simulator, piece: int, role: str, flash: _Flash):
        self.sim, self.piece, self.role, self.flash = sim, piece, role, flash
        self.ports: list[_Node | None] = [None] * (8 if role == "splitter" else 1)
        self.parent: _Node | _Host | None = None
        self.port_at_parent = 0
        self.powered = False
        self.epoch = 0
        self.alive = False
        self.direction = False
        self.q_in: list[list] = []
        self.q_out: list[bytes] = []
        self.leds = (True, False, True)
        self.token = 0  # numbers this controller's polls across restarts, so stale answers are ignored

    # ------------------------------------------------------------ power

    def power(self, on: bool, t: float) -> None:
        if on == self.powered:
            return
        self.powered = on
        self.epoch += 1
        self.alive = False
        if on:
            self.sim._at(t + _BOOT, self, self._start)

    def _reboot(self, t: float) -> None:
        self.epoch += 1
        self.alive = False
        self.sim._at(t + _BOOT, self, self._start)

    def _start(self, t: float) -> None:
        """``main``: RAM from scratch, the setup from flash, the first records queued."""
        self.alive, self.direction = True, False
        self.q_in, self.q_out, self.commands = [], [], []
        self.angles = [0, 0, 0, 0]
        self.twist_truth: float | None = None
        self.data_mode = 0
        self.i_p = 0
        self.kids = [0] * 8
        self.kids_timer: list[float | None] = [None] * 8
        self.skc = [0] * 8
        self.send_down = bytes(COMMAND_SIZE)  # a zero-initialised global: fails the child's CRC check
        self.send_down_now = EMPTY_COMMAND
        self.waiting: int | None = None
        self.last_poll = self.last_down = self.last_up = t
        self.up_busy = self.flash_until = t
        self.init_pending = False
        self.leds = (True, False, True)  # led_set(1, 1, 0): red and blue on
        self._part_init(t)
        self._push(self.init_line)
        if self.role == "splitter":
            for s in range(8):
                if self.flash.outputs[s]:
                    self._push(self.splitter_lines[s])
                    self.skc[s] = 1
        self._update_sensors(t)
        self.sim._at(_after(t, _INIT_MS), self, self._init_timer)
        if self.role == "splitter":
            self.sim._at(_after(t, _RESET_MS), self, self._watch)

    def _part_init(self, t: float) -> None:
        f = self.flash
        self.n_ports = (f.node_type >> 4) if f.node_type & 0x0F == 0x08 else 1
        self.n_ports = max(1, min(self.n_ports, len(self.ports)))
        self.angles = [0, 0, 0, 0]
        self.twist_truth = None
        self.init_line = _line(INIT, f.id, bytes([f.node_type & 0xFF, *f.colour, 0, 0, 0, 0]))
        self.splitter_lines = {}
        if f.node_type & 0x0F == 0x08:
            for s in range(8):
                if f.outputs[s]:
                    payload = struct.pack(">BBHHH", 0, s, *f.geometry[s])
                    self.splitter_lines[s] = _line(SPLITTER, f.id, payload)
        self.sensor_line = bytearray(_line(DATA, f.id, bytes(8)))
        self.i_p = 0

    # ------------------------------------------------------------ queues

    def _push(self, line: bytes, meta=None) -> None:
        self.q_in.append([line, meta])
        if len(self.q_in) > _QUEUE:
            del self.q_in[0]

    def _replace_push(self, line: bytes, meta=None) -> None:
        for entry in self.q_in:
            q = entry[0]
            if q[0] == line[0] and q[1:5] == line[1:5]:
                entry[0], entry[1] = line, meta
                return
        self._push(line, meta)

    def _push_down(self, command: bytes) -> None:
        self.q_out.append(command)
        if len(self.q_out) > _QUEUE:
            del self.q_out[0]

    # ------------------------------------------------------------ timers

    def _init_timer(self, t: float) -> None:
        if not self.direction:  # the loop checks this timer only once the direction is known
            self.init_pending = True
            return
        self._replace_push(self.init_line)
        for s in range(8):
            if s in self.splitter_lines:
                self._push(self.splitter_lines[s])
        self.sim._at(_after(t, _INIT_MS), self, self._init_timer)

    def _watch(self, t: float) -> None:
        """A splitter's window watchdog: fed only while polls come and children answer."""
        due = min(_after(self.last_poll, _RESET_MS), _after(self.last_down, _RESET_MS))
        due = min(due, _after(self.last_up, _SILENT_UP_MS))
        if t + 1e-9 >= due:  # WDGO: the refresh stops, the watchdog resets the controller
            self.sim._at(t + _WATCHDOG, self, self._reboot)
        else:
            self.sim._at(due, self, self._watch)

    # ------------------------------------------------------------ sensors

    def _update_sensors(self, t: float) -> None:
        """``update_sensor_messages``."""
        if self.role == "tu":
            ints, floats = self.sim._read(self.piece, t, (0, 1, 2))
            self.angles[0:3] = ints
            if all(self.angles) or self.data_mode != 0:
                f = self.flash
                twist = float(self.angles[3]) if self.twist_truth is None else self.twist_truth
                truth = [*floats, twist]
                if f.polarity == 1:
                    self.angles[1] = _MASK - self.angles[1]
                    self.angles[2] = _MASK - self.angles[2]
                    truth[1], truth[2] = _MASK - truth[1], _MASK - truth[2]
                z = []
                angles = []
                for i in range(4):
                    off = 0x0FFF if i in (1, 2) else 0
                    z.append((self.angles[i] - f.zero[i] + _MASK + off) % _MASK)
                    d = math.remainder(truth[i] - f.zero[i], 16384.0)
                    angles.append(d * 2.0 * math.pi / 16384)
                self.sensor_line[9:17] = struct.pack(">HHHH", *z)
                self.angles[3] = 0
                self.twist_truth = None
                line = _with_crc(self.sensor_line)
                self.sensor_line[17] = line[17]
                self._replace_push(line, (t, tuple(angles)))
        elif self.role == "t":
            ints, floats = self.sim._read(self.piece, t, (3,))
            if ints[0] != 0:
                self.angles[3] = ints[0]
                self.sensor_line[15:17] = struct.pack(">H", ints[0])
                line = _with_crc(self.sensor_line)
                self.sensor_line[17] = line[17]
                self._replace_push(line, floats[0])
            elif self.data_mode != 0:
                self._replace_push(_with_crc(self.sensor_line), None)

    # ------------------------------------------------------------ the up side: answering a poll

    def on_poll(self, t: float, poll: bytes, parent, token) -> None:
        """The 11 bytes of a poll arrived (``HAL_UART_RxCpltCallback``, then the UP state machine)."""
        sim = self.sim
        if not (self.powered and self.alive) or t < self.up_busy or t < self.flash_until:
            sim._at(_after(t, _CHILD_TIMEOUT_MS), None, parent.on_timeout, token, self.port_at_parent)
            return
        self.last_poll = t
        if not self.direction:
            if poll[0] == POLL:  # the first 'R' tells which UART is up: no answer yet
                self.direction = True
                self.last_up = t
                self.leds = (self.leds[0], self.leds[1], False)
                sim._at(t + _LOOP, self, self._down_idle)
                if self.init_pending:
                    self.init_pending = False
                    sim._at(t + _LOOP, self, self._init_timer)
            sim._at(_after(t, _CHILD_TIMEOUT_MS), None, parent.on_timeout, token, self.port_at_parent)
            return
        if poll[0] != POLL:
            sim._at(_after(t, _CHILD_TIMEOUT_MS), None, parent.on_timeout, token, self.port_at_parent)
            return
        lines, metas = [], []
        while self.q_in and len(lines) < RECORDS_PER_REPLY:
            line, meta = self.q_in.pop(0)
            lines.append(line)
            metas.append(meta)
        while len(lines) < RECORDS_PER_REPLY:
            lines.append(EMPTY_RECORD)
            metas.append(None)
        end = t + _RESPONSE + RECORDS_PER_REPLY * RECORD_SIZE * BYTE_TIME
        self.up_busy = end
        self.last_up = end
        sim._at(end, None, parent.on_reply, token, self.port_at_parent, lines, metas)
        command = bytes(poll[1:POLL_SIZE])
        if command[0] != EMPTY and crc8(command[:9]) == command[9]:
            address = _U32.unpack_from(command, 1)[0]
            if command[0] == DIRECT or address == self.flash.id:
                self.commands.append(command)
                if command[0] == BY_ID and self.flash.node_type == NODE_JOINT_TUT_TU:
                    self._push_down(command)
            elif address == BROADCAST_ID:
                self.commands.append(command)
                self._push_down(command)
            else:
                self._push_down(command)
        if self.role != "splitter":
            self._update_sensors(t)
        while self.commands:
            command = self.commands.pop(0)
            if self._execute(command, t):
                self._push(_line(ACK, self.flash.id, command[:8]))

    # ------------------------------------------------------------ commands

    def _execute(self, c: bytes, t: float) -> bool:
        """``process_uart_command``; True when the firmware acknowledges."""
        f, code, direct = self.flash, chr(c[5]), c[0] == DIRECT
        flash = False
        if code == "b":
            pass
        elif code == "l":  # p1 blue, p2 red, p3 green; the main loop turns blue off again at once
            self.leds = (c[7] != 0, c[8] != 0, False)
        elif code == "s":
            pass  # a debugging leftover (an unchecked 'S' line of ASCII); not modelled
        elif code == "i":
            if direct:
                f.id = _U32.unpack_from(c, 1)[0]
                if f.node_type == NODE_JOINT_TUT_TU:
                    self._push_down(_with_crc(bytes([DIRECT, *c[1:5], ord("i"), 0, 0, 0, 0])))
                flash = True
        elif code == "t":
            if direct:
                f.node_type = (_hex(c[6]) << 4 & 0xF0) + (_hex(c[7]) & 0x0F)
                if f.node_type & 0x0F == 0x08:
                    n = f.node_type >> 4
                    f.outputs = [1 if i < n else 0 for i in range(8)]
                if f.node_type == NODE_JOINT_TUT_TU:
                    self._push_down(
                        _with_crc(bytes([DIRECT, 0, 0, 0, 0, ord("t"), ord("8"), ord("4"), 0, 0]))
                    )
                flash = True
        elif code == "d":
            self.data_mode = c[6]
        elif code == "p":
            pass  # reprogramming the 2-D sensor: not modelled
        elif code in "xz":
            if code == "x":
                f.polarity = c[6]  # and on into 'z': the firmware has no break here
            f.zero = list(self.angles)
            flash = True
        elif code == "g":
            if direct and c[8] < 8:
                f.geometry[c[8]] = [c[1] << 8 | c[2], c[3] << 8 | c[4], c[6] << 8 | c[7]]
                flash = True
        elif code == "c":
            f.colour = [c[6], c[7], c[8]]
            flash = True
        elif code == "h":
            if direct:
                f.hardware = c[6]
                flash = True
        else:
            return False
        if flash:
            self._part_init(t)
            self.flash_until = max(self.up_busy, t) + _FLASH
        return True

    # ------------------------------------------------------------ the down side: polling the children

    def _down_idle(self, t: float) -> None:
        """The DOWN state machine's IDLE: pick the output and the command, send the poll."""
        sim = self.sim
        if t < self.flash_until:
            sim._at(self.flash_until, self, self._down_idle)
            return
        p = self.i_p
        if self.role == "splitter":
            if self.kids[p] > 10:
                self.kids[p] = 9
                self.kids_timer[p] = (_tick(t) + _SKIP_MS) / 1000.0
            if self.kids_timer[p] is not None and self.kids_timer[p] > t + 1e-9:
                self.last_down = t
                self._down_end(t, skipped=True)
                return
            self.send_down = self.send_down_now if self.skc[p] == 0 else EMPTY_COMMAND
        n = self.n_ports
        if sum(self.skc[:n]) >= n:
            if self.q_out:
                self.send_down_now = self.q_out.pop(0)
                self.send_down = self.send_down_now
                self.skc[:n] = [0] * n
            else:
                self.send_down = EMPTY_COMMAND
                self.skc[:n] = [1] * n
        poll = bytes([POLL]) + self.send_down
        arrive = t + POLL_SIZE * BYTE_TIME
        self.token += 1
        self.waiting = self.token
        child = self.ports[p]
        if child is not None and child.powered:
            sim._at(arrive, None, child.on_poll, poll, self, self.token)
        else:
            sim._at(_after(arrive, _CHILD_TIMEOUT_MS), None, self.on_timeout, self.token, p)

    def on_timeout(self, t: float, token: int, port: int) -> None:
        if token != self.waiting or not self.alive:
            return
        self.waiting = None
        self.kids[port] += 1
        self._down_end(t)

    def on_reply(self, t: float, token: int, port: int, lines: list[bytes], metas: list) -> None:
        """The child's 216 bytes are in (RECEIVING): relay its records up."""
        if token != self.waiting or not self.alive:
            return
        self.waiting = None
        self.kids[port] = 0
        self.skc[port] = 1
        self.kids_timer[port] = None
        self.last_down = t
        f = self.flash
        me = _U32.pack(f.id & 0xFFFFFFFF)
        for line, meta in zip(lines, metas, strict=True):
            if line[0] == EMPTY:
                break
            if line[1:5] == me and f.node_type == NODE_JOINT_TUT_TU and self.data_mode != 2:
                if line[0] == DATA:
                    self.angles[3] = line[15] << 8 | line[16]
                    self.twist_truth = meta if isinstance(meta, float) else None
                continue
            out = bytearray(line)
            if out[5] == 0:
                out[5:9] = me
                if self.role == "splitter":
                    out[5] |= (port << 4) & 0xF0
            out = _with_crc(out)
            if out[0] in (ACK, SPLITTER):
                self._push(out, meta)
            else:
                self._replace_push(out, meta)
        self._down_end(t)

    def _down_end(self, t: float, skipped: bool = False) -> None:
        sim = self.sim
        self.i_p = (self.i_p + 1) % self.n_ports
        if self.i_p != 0:
            sim._at(t + _LOOP, self, self._down_idle)
        elif self.role == "splitter":
            if skipped and all(
                self.kids_timer[p] is not None and self.kids_timer[p] > t + 1e-9 for p in range(self.n_ports)
            ):  # every output is being skipped: sleep until the first comes back
                until = min(self.kids_timer[p] for p in range(self.n_ports))
                self.last_down = until
                sim._at(until, self, self._down_idle)
            else:
                sim._at(t + _LOOP, self, self._down_idle)
        else:
            sim._at(_after(t, _DELAY_MS), self, self._down_idle)

    def state(self) -> FirmwareState:
        f = self.flash
        return FirmwareState(
            id=f.id,
            node_type=f.node_type,
            colour=tuple(f.colour),
            zero=tuple(f.zero),
            polarity=f.polarity,
            data_mode=getattr(self, "data_mode", 0),
            leds=self.leds,
            geometry={s: tuple(f.geometry[s]) for s in range(8) if f.outputs[s]},
            powered=self.powered,
            polled=self.direction,
            queued=len(self.q_in),
            commands=len(self.q_out),
        )


def _hex(c: int) -> int:
    """``charToHexDigit``: upper-case letters and digits."""
    return c - ord("A") + 10 if c >= ord("A") else c - ord("0")


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
        self._host = _Host(self)
        self._host_due: list[float] = []
        self._angle_block: tuple[int, np.ndarray] | None = None
        self._unpowered: set[int] = set()
        self._plugged = True
        # The sensors: per joint a mounting offset per angle (raw units), the factory zero at it.
        joints = device.joints
        mrng = np.random.default_rng([seed, 0])
        self._mount = mrng.uniform(1.0, 16383.0, (len(joints), 4))
        self._joint_index = {j: i for i, j in enumerate(joints)}
        self._nodes: dict[int, tuple[_Node, ...]] = {}
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

    def _make(self, p) -> tuple[_Node, ...]:
        colour = [int(c) for c in p.colour]
        if p.kind == "joint":
            m = self._mount[self._joint_index[p.id]]
            zero = [round(x) % 16384 for x in m]
            tu = _Node(self, p.id, "tu", _Flash(p.id, NODE_JOINT_TUT_TU, colour, list(zero)))
            t = _Node(self, p.id, "t", _Flash(p.id, NODE_JOINT_TUT_T, colour, list(zero)))
            return tu, t
        n = p.splitter.valence
        flash = _Flash(p.id, (n << 4) | 0x08, colour, [0, 0, 0, 0])
        angles = splitter_angles(p.splitter.slots)
        for s in range(n):
            flash.outputs[s] = 1
            flash.geometry[s] = [(round(math.degrees(a)) & 0xFFFF) for a in angles[s]]
        return (_Node(self, p.id, "splitter", flash),)

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

    def _at(self, t: float, node: _Node | None, fn, *args) -> None:
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
        if self._host_in and t - self._host_in_time > _RESET_MS / 1000.0:
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

    def _poll_root(self, t: float, root: _Node, poll: bytes) -> None:
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
