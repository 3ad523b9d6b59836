"""One controller of the published firmware, simulated: a state machine that answers its parent's polls
and polls its children, run by a :class:`~tangible.simulator.Simulator` on its simulated clock.

What each controller does is what ``Hardware/Firmware/Src/main.c`` and ``utility.c`` do (``PROTOCOL.md``
says where):

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
  its LEDs; a command that writes flash makes the piece deaf for the page erase. ``'x'`` (polarity)
  clears the readings before it falls through into ``'z'``, so it sets the zero offsets to 0.

A :class:`Controller` is one microcontroller (a joint is two: its 0x74 and 0x84 halves); its parent is
another controller or the :class:`Host`. It runs inside its simulator, which schedules its events
(``Simulator._at``), reads its sensors (``Simulator._read``) and takes the root's replies to the host
(``Simulator._to_host``). :class:`FirmwareState` is what a test may want to see of it.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from .protocol import (
    ACK,
    BROADCAST_ID,
    BY_ID,
    BYTE_TIME,
    COMMAND_SIZE,
    DATA,
    DIRECT,
    EMPTY,
    EMPTY_COMMAND,
    EMPTY_RECORD,
    INIT,
    NODE_JOINT_TUT_TU,
    POLL,
    POLL_SIZE,
    RECORD_SIZE,
    RECORDS_PER_REPLY,
    SPLITTER,
    crc8,
)

if TYPE_CHECKING:  # pragma: no cover
    from .simulator import Simulator

__all__ = ["RESET_MS", "Controller", "FirmwareState", "Flash", "Host"]

# The firmware's timing (TIM16 counts milliseconds; comparisons are "counter - then > N").
_RESPONSE = 0.0002  # main-loop latency before a polled piece starts its reply
_CHILD_TIMEOUT_MS = 13  # RECEIVING gives up
_DELAY_MS = 7  # a joint's pause after polling its child
_INIT_MS = 1000  # init and splitter records
RESET_MS = 250  # unpolled / no child heard: a splitter stops feeding its watchdog
_SILENT_UP_MS = 500  # no reply sent for this long: the same
_SKIP_MS = 200  # a splitter skips an output that timed out more than 10 times
_LOOP = 20e-6  # one main-loop iteration (a splitter stepping past skipped outputs)
_BOOT = 0.010  # power-on to the main loop
_WATCHDOG = 4096 * 2 * (127 - 63) / 8e6  # WWDG at 8 MHz, prescaler 2, counter 127 → reset at 63
_FLASH = 0.025  # a page erase and the setup words, interrupts off
_QUEUE = 31  # uart_queue: 32 slots, one always free
_MASK = 0x3FFF
_U32 = struct.Struct(">I")


def _tick(t: float) -> int:
    return math.floor(t * 1000.0 + 1e-6)


def _after(t: float, ms: int) -> float:
    """The first time at which the firmware's ``counter - tick(t) > ms`` holds."""
    return (_tick(t) + ms + 1) / 1000.0


@dataclass(frozen=True)
class FirmwareState:
    """A piece's firmware as it stands (its 0x74 half for a joint): its flash and RAM that a test may
    want to see.

    ``leds`` is ``(red, green, blue)`` as last set; the firmware's main loop also turns blue off on every
    iteration once the piece has been polled, and toggles red every 250 ms (not modelled). ``queued``
    counts the records waiting to go up, ``commands`` the commands waiting to go down. ``restarts``
    counts its watchdog resets (a splitter's, ``main.c`` lines 298–314); after each, as after power-on,
    it takes the next poll for the direction and drops it with its command (``bus.c`` lines 35–84).
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
    restarts: int = 0


# ---------------------------------------------------------------------------- one controller


@dataclass
class Flash:
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


class Host:
    """The host as a parent: where the root piece's replies go."""

    def __init__(self, sim: Simulator):
        self.sim = sim

    def on_reply(self, t, token, port, lines, metas):
        self.sim._to_host(t, lines, metas)

    def on_timeout(self, t, token, port):
        pass


class Controller:
    """One microcontroller running the firmware."""

    def __init__(self, sim: Simulator, piece: int, role: str, flash: Flash):
        self.sim, self.piece, self.role, self.flash = sim, piece, role, flash
        self.ports: list[Controller | None] = [None] * (8 if role == "splitter" else 1)
        self.parent: Controller | Host | None = None
        self.port_at_parent = 0
        self.powered = False
        self.epoch = 0
        self.alive = False
        self.direction = False
        self.q_in: list[list] = []
        self.q_out: list[bytes] = []
        self.leds = (True, False, True)
        self.token = 0  # numbers this controller's polls across restarts, so stale answers are ignored
        self.restarts = 0

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
        """The window watchdog resets the controller: it starts again with its direction unknown."""
        self.restarts += 1
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
            self.sim._at(_after(t, RESET_MS), self, self._watch)

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
        due = min(_after(self.last_poll, RESET_MS), _after(self.last_down, RESET_MS))
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
            # bus.c 35-84: the first 'R' after a start (power-on or watchdog) tells which UART is up and
            # returns before receivedUP is set: no answer, and the command in it is never looked at.
            if poll[0] == POLL:
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
                # utility.c 198-201: 'x' stores the polarity and runs part_init, which clears angles[0..3]
                # (lines 512-515), then falls through (no break) into 'z' (lines 202-208), which copies
                # those cleared angles: the zero offsets become 0, 0, 0, 0, not the current readings.
                f.polarity = c[6]
                self._part_init(t)
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
            restarts=self.restarts,
        )


def _hex(c: int) -> int:
    """``charToHexDigit``: upper-case letters and digits."""
    return c - ord("A") + 10 if c >= ord("A") else c - ord("0")
