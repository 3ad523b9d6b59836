"""The published device firmware's wire protocol (``oliglauser/atamid``, ``Hardware/Firmware``; see
``tangible/PROTOCOL.md``): records, downlink commands, CRC-8, and a streaming reply parser.

The link is half duplex and the parent talks first: the host writes a **poll**, ``b"R"`` and a 10-byte
:class:`Command` (:data:`EMPTY_COMMAND` when it has nothing to say), and the piece plugged into it answers
with :data:`RECORDS_PER_REPLY` records of :data:`RECORD_SIZE` bytes, padded with empty (``'E'``) records.
A record is::

    kind u8 | creator u32 | relayer u32 (its top nibble: the relaying splitter's port) | payload 8 | crc u8

big-endian, the CRC-8 (:func:`crc8`) over bytes 0–16. Four kinds carry something: :class:`DataRecord`
(a joint's four sensor angles), :class:`InitRecord` (what a piece is), :class:`SplitterRecord` (one outlet
of a splitter) and :class:`AckRecord` (a command was executed).

* :func:`encode_record` / :func:`decode_record` turn one record into bytes and back;
  :func:`decode_record` raises :class:`~tangible.errors.RecordError` naming the byte offset and the cause.
* :class:`ReplyParser` is fed whatever chunks the port delivers; it is told of every poll the host writes
  (so that it can skip an adapter's echo and knows where a reply starts), yields the records, drops the
  empty ones, resynchronizes after short, long or garbled replies, and counts what it rejected. It never
  raises for bad bytes.

Angles: the firmware sends 14-bit values (:data:`ANGLE_LSB` = 360/16384°); a data record's angles here are
radians in record order — proximal twist, bend α, bend β, distal twist — with the bends' :data:`BEND_OFFSET`
removed and every angle wrapped to (−π, π]. A splitter record's three angles are signed whole degrees on
the wire (the firmware stores whatever the host wrote; see ``PROTOCOL.md``) and radians here.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from . import rotations as rot
from .errors import ProtocolError, RecordError

__all__ = [
    "ACK",
    "ANGLE_LSB",
    "BAUDRATE",
    "BEND_OFFSET",
    "BROADCAST_ID",
    "BYTE_TIME",
    "BY_ID",
    "COMMAND_SIZE",
    "CYCLE",
    "DATA",
    "DEFAULT_ID",
    "DIRECT",
    "EMPTY",
    "EMPTY_COMMAND",
    "EMPTY_RECORD",
    "INIT",
    "MAX_ID",
    "MIN_ID",
    "NODE_JOINT_TUT_T",
    "NODE_JOINT_TUT_TU",
    "NODE_SPLITTER_2",
    "NODE_SPLITTER_3",
    "NODE_SPLITTER_5",
    "NODE_SPLITTER_GENERIC",
    "NODE_UNDEFINED",
    "POLL",
    "POLL_SIZE",
    "RECORDS_PER_REPLY",
    "RECORD_SIZE",
    "REPLY_SIZE",
    "SPLITTER",
    "UNPOLLED_RESET",
    "AckRecord",
    "Command",
    "DataRecord",
    "InitRecord",
    "ParserStats",
    "Record",
    "ReplyParser",
    "SplitterRecord",
    "crc8",
    "decode_record",
    "encode_record",
    "poll_bytes",
    "splitter_angles",
    "splitter_rotation",
]

# ---------------------------------------------------------------------------- constants

#: The firmware's UART: 230400 baud, 8 data bits, no parity, 1 stop bit (``Src/main.c``,
#: ``MX_USART1_UART_Init`` / ``MX_USART2_UART_Init``, both ``HAL_HalfDuplex_Init``).
BAUDRATE = 230_400
#: Seconds one byte takes on the wire (start bit, 8 data bits, stop bit).
BYTE_TIME = 10.0 / BAUDRATE
#: Bytes of an upward record (``bus.h``: ``UP_MESSAGE_LENGTH``).
RECORD_SIZE = 18
#: Bytes of a downward command (``bus.h``: ``DOWN_MESSAGE_LENGTH``).
COMMAND_SIZE = 10
#: Bytes of a poll: ``'R'`` and a command (the child's DMA receives ``DOWN_MESSAGE_LENGTH + 1``).
POLL_SIZE = 1 + COMMAND_SIZE
#: Records in every reply (``Src/main.c``: ``UP_MESSAGES_MAX``).
RECORDS_PER_REPLY = 12
#: Bytes of every reply.
REPLY_SIZE = RECORDS_PER_REPLY * RECORD_SIZE
#: The host's poll period: the firmware re-arms its receiver every 20 ms without a poll (``get_up``) and a
#: joint polls its own child about every 18 ms (reply 9.4 ms, then ``DELAY`` > 7 ms).
CYCLE = 0.020
#: A piece not polled for this long resets its receiver (a splitter restarts; ``Src/main.c``).
UNPOLLED_RESET = 0.250

#: Record kinds and poll/command kinds (``bus.h``: ``LUEISART_POLL_KIND``).
POLL, DIRECT, BY_ID = ord("R"), ord("P"), ord("C")
DATA, ACK, INIT, SPLITTER, EMPTY = ord("D"), ord("A"), ord("I"), ord("S"), ord("E")

#: Node types (``utility.h``: ``NodeType``): low nibble 4 a joint, 8 a splitter; a splitter's high nibble is
#: its number of outputs.
NODE_COLLECTOR = 0x00
NODE_JOINT_TRT = 0xF4
NODE_JOINT_R = 0x94
NODE_JOINT_T = 0x54
NODE_JOINT_TUT_TU = 0x74
NODE_JOINT_TUT_T = 0x84
NODE_SPLITTER_GENERIC = 0x08
NODE_SPLITTER_2 = 0x28
NODE_SPLITTER_3 = 0x38
NODE_SPLITTER_5 = 0x58
NODE_UNDEFINED = 0xFF

#: A command to every piece (``utility.h``: ``BROADCAST_ID``).
BROADCAST_ID = 0xFFFFFFFF
#: The id of a piece never given one (``utility.c``: ``reset_joint``).
DEFAULT_ID = 0x0FFFFFFF
#: Ids a relaying piece can be named by: the port goes into the top nibble of byte 5, and a relayer only
#: fills in its id if byte 5 is still 0, so an id must have a non-zero byte in bits 24–27.
MIN_ID = 0x01000000
#: The largest such id below the default one.
MAX_ID = 0x0FFFFFFE

#: One step of a sensor angle (MLX90363, 14 bits), radians.
ANGLE_LSB = 2.0 * math.pi / 16384
#: What the firmware adds to both bends (≈ 90°) so that they stay clear of the wrap.
BEND_OFFSET = 0x0FFF
_ANGLE_MASK = 0x3FFF
#: Data payload positions that carry a bend.
_BENDS = (False, True, True, False)
#: Commands the firmware acknowledges (``process_uart_command`` returns 1).
_ACKED = frozenset(b"blsitdpxzgch")

_U32 = struct.Struct(">I")
_DATA = struct.Struct(">HHHH")
_SPLIT = struct.Struct(">BBhhh")

# ---------------------------------------------------------------------------- CRC-8


def _crc_table(poly: int) -> bytes:
    table = bytearray(256)
    for i in range(256):
        c = i
        for _ in range(8):
            c = ((c << 1) ^ poly) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        table[i] = c
    return bytes(table)


#: The firmware's table (``mlx90363.c``: ``CRCArray``, the MLX90363's SPI CRC): polynomial 0x2F.
CRC_TABLE = _crc_table(0x2F)


def crc8(data: bytes | bytearray | memoryview) -> int:
    """CRC-8/AUTOSAR of ``data`` (bytes-like, any length), an int in 0..255, as the firmware computes it
    (``mlx90363.c``: ``ComputeCRCN``): polynomial 0x2F, no reflection, initial value 0xFF, final
    complement. Check value: ``crc8(b"123456789") == 0xDF``."""
    c = 0xFF
    table = CRC_TABLE
    for b in data:
        c = table[c ^ b]
    return c ^ 0xFF


def _line(first: int) -> bytes:
    return bytes([first, *range(1, RECORD_SIZE - 1)])


#: The firmware's empty record (``Src/main.c``: ``empty_up_line``): ``'E'``, bytes 1 … 16, CRC.
EMPTY_RECORD = _line(EMPTY) + bytes([crc8(_line(EMPTY))])

# ---------------------------------------------------------------------------- records


def _check_int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or not lo <= value <= hi:
        raise ProtocolError(f"{name} must be an integer in {lo:#x}..{hi:#x}, got {value!r}")
    return int(value)


def _wrap(a: float) -> float:
    """``a`` wrapped to (−π, π]."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


@dataclass(frozen=True, slots=True)
class Record:
    """What every record carries.

    Attributes
    ----------
    creator : int
        Id of the piece that made the record (bytes 1–4).
    relayer : int
        28-bit id of the first piece that relayed it (bytes 5–8 without the top nibble of byte 5); 0 if
        none did: the creator is the piece the host polls.
    port : int
        The top nibble of byte 5: the port the creator hangs on when the first relayer is a splitter
        (the firmware ORs ``port << 4`` into byte 5), else 0.
    """

    creator: int
    relayer: int
    port: int

    KIND: ClassVar[int] = 0

    @property
    def relayed(self) -> bool:
        """Whether a piece relayed it (the creator is not the piece the host polls)."""
        return self.relayer != 0

    def payload(self) -> bytes:
        """Bytes 9–16."""
        raise NotImplementedError


@dataclass(frozen=True, slots=True)
class DataRecord(Record):
    """A joint's four sensed angles (``'D'``; ``utility.c``: ``update_sensor_messages``), radians in
    record order: proximal twist, bend α, bend β, distal twist; the bends without their offset, all
    wrapped to (−π, π]. On the wire: four u16, the 14-bit readings minus the zero offsets, bends plus
    :data:`BEND_OFFSET`, modulo 0x3FFF."""

    angles: tuple[float, float, float, float]

    KIND: ClassVar[int] = DATA

    @property
    def raw(self) -> tuple[int, int, int, int]:
        """The four u16 as on the wire."""
        if len(self.angles) != 4:
            raise ProtocolError(f"a data record carries 4 angles, got {len(self.angles)}")
        out = []
        for a, bend in zip(self.angles, _BENDS, strict=True):
            if not math.isfinite(a):
                raise ProtocolError(f"data record angles must be finite, got {self.angles!r}")
            out.append((round(a / ANGLE_LSB) + (BEND_OFFSET if bend else 0)) % 16384)
        return tuple(out)

    def payload(self) -> bytes:
        return _DATA.pack(*self.raw)


@dataclass(frozen=True, slots=True)
class InitRecord(Record):
    """What a piece is (``'I'``; ``utility.c``: ``part_init``), sent every second: its node type (low
    nibble 4: a joint, 8: a splitter; a splitter's high nibble is its number of outputs) and colour."""

    node_type: int
    colour: tuple[int, int, int]

    KIND: ClassVar[int] = INIT

    @property
    def is_joint(self) -> bool:
        return self.node_type & 0x0F == 0x04

    @property
    def is_splitter(self) -> bool:
        return self.node_type & 0x0F == 0x08

    @property
    def outputs(self) -> int:
        """A splitter's number of outputs (the high nibble), 1 for a joint."""
        return self.node_type >> 4 if self.is_splitter else 1

    def payload(self) -> bytes:
        _check_int("node type", self.node_type, 0, 255)
        if len(self.colour) != 3:
            raise ProtocolError(f"a colour is 3 bytes (RGB), got {self.colour!r}")
        return bytes([self.node_type, *(_check_int("colour", c, 0, 255) for c in self.colour), 0, 0, 0, 0])


@dataclass(frozen=True, slots=True)
class SplitterRecord(Record):
    """One outlet of a splitter (``'S'``; ``utility.c``: ``part_init``), sent every second for each of its
    outputs: the outlet ``slot`` and three angles the host wrote with the ``'g'`` command (roll, pitch,
    yaw in the firmware's names), radians here, signed whole degrees on the wire."""

    slot: int
    angles: tuple[float, float, float]

    KIND: ClassVar[int] = SPLITTER

    @property
    def degrees(self) -> tuple[int, int, int]:
        """The three angles as on the wire (signed 16-bit whole degrees)."""
        if len(self.angles) != 3 or not all(math.isfinite(a) for a in self.angles):
            raise ProtocolError(f"a splitter record carries 3 finite angles, got {self.angles!r}")
        return tuple((round(math.degrees(a)) + 32768) % 65536 - 32768 for a in self.angles)

    def payload(self) -> bytes:
        return _SPLIT.pack(0, _check_int("slot", self.slot, 0, 7), *self.degrees)


@dataclass(frozen=True, slots=True)
class AckRecord(Record):
    """A command was executed (``'A'``; ``Src/main.c``, the end of the main loop): the payload is the
    command's first 8 bytes (kind, address, code, two parameters)."""

    command: bytes

    KIND: ClassVar[int] = ACK

    @property
    def code(self) -> str:
        """The acknowledged command's letter."""
        return chr(self.command[5])

    @property
    def address(self) -> int:
        """The acknowledged command's bytes 1–4 (an id, or parameters of a direct command)."""
        return _U32.unpack_from(self.command, 1)[0]

    @property
    def direct(self) -> bool:
        """Whether it was a direct (``'P'``) command."""
        return self.command[0] == DIRECT

    def payload(self) -> bytes:
        if len(self.command) != 8:
            raise ProtocolError(f"an ack carries the command's first 8 bytes, got {len(self.command)}")
        return bytes(self.command)


_CLASSES: dict[int, type[Record]] = {
    DATA: DataRecord,
    INIT: InitRecord,
    SPLITTER: SplitterRecord,
    ACK: AckRecord,
}


def encode_record(record: Record) -> bytes:
    """The 18 bytes of ``record``.

    Raises
    ------
    ProtocolError
        For a field out of range, naming it.
    """
    if type(record) not in _CLASSES.values():
        raise ProtocolError(f"cannot encode {type(record).__name__}: not a record")
    creator = _check_int("creator", record.creator, 0, 0x0FFFFFFF)
    relayer = _check_int("relayer", record.relayer, 0, 0x0FFFFFFF)
    port = _check_int("port", record.port, 0, 7)
    head = bytes([record.KIND]) + _U32.pack(creator) + _U32.pack(relayer | port << 28)
    body = head + record.payload()
    return body + bytes([crc8(body)])


def decode_record(block: bytes | bytearray | memoryview) -> Record | None:
    """Decode one 18-byte record; None for an empty (``'E'``) record.

    Besides the CRC, the record must look like one the firmware makes: a known kind, 28-bit ids, the
    relaying port below 8, 14-bit angles, zero padding where the firmware writes zeros, an acknowledged
    command code. (These checks make a misaligned or garbled block pass by chance about once in 10⁸.)

    Raises
    ------
    RecordError
        With ``reason`` (``"length"``, ``"kind"``, ``"crc"``, ``"field"``) and the byte ``offset``.
    """
    if not isinstance(block, bytes | bytearray | memoryview):
        raise ProtocolError(f"decode_record takes bytes, got {type(block).__name__}")
    b = bytes(block)
    if len(b) != RECORD_SIZE:
        raise RecordError(f"a record is {RECORD_SIZE} bytes, got {len(b)}", reason="length", offset=len(b))
    kind = b[0]
    if kind != EMPTY and kind not in _CLASSES:
        raise RecordError(f"unknown record kind {kind:#04x} at offset 0", reason="kind", offset=0)
    if crc8(b[:17]) != b[17]:
        raise RecordError(
            f"bad CRC at offset 17: {b[17]:#04x}, expected {crc8(b[:17]):#04x}", reason="crc", offset=17
        )
    if kind == EMPTY:
        if b != EMPTY_RECORD:
            raise RecordError("an empty record must be bytes 1..16 after 'E'", reason="field", offset=1)
        return None
    if b[1] & 0xF0:
        raise RecordError(f"creator id {b[1:5].hex()} is wider than 28 bits", reason="field", offset=1)
    if b[5] & 0x80:
        raise RecordError(f"relaying port {b[5] >> 4} is above 7", reason="field", offset=5)
    creator = _U32.unpack_from(b, 1)[0]
    word = _U32.unpack_from(b, 5)[0]
    relayer, port = word & 0x0FFFFFFF, word >> 28
    if kind == DATA:
        raw = _DATA.unpack_from(b, 9)
        for i, v in enumerate(raw):
            if v > _ANGLE_MASK:
                raise RecordError(
                    f"angle {i} is {v:#06x}, wider than 14 bits", reason="field", offset=9 + 2 * i
                )
        angles = tuple(
            _wrap((v - BEND_OFFSET if bend else v) * ANGLE_LSB) for v, bend in zip(raw, _BENDS, strict=True)
        )
        return DataRecord(creator, relayer, port, angles)
    if kind == INIT:
        if any(b[13:17]):
            raise RecordError("an init record's bytes 13-16 must be 0", reason="field", offset=13)
        return InitRecord(creator, relayer, port, b[9], (b[10], b[11], b[12]))
    if kind == SPLITTER:
        zero, slot, *degrees = _SPLIT.unpack_from(b, 9)
        if zero != 0:
            raise RecordError("a splitter record's byte 9 must be 0", reason="field", offset=9)
        if slot > 7:
            raise RecordError(f"splitter slot {slot} is above 7", reason="field", offset=10)
        return SplitterRecord(creator, relayer, port, slot, tuple(math.radians(d) for d in degrees))
    command = b[9:17]
    if command[0] not in (DIRECT, BY_ID):
        raise RecordError(f"acknowledged command kind {command[0]:#04x}", reason="field", offset=9)
    if command[5] not in _ACKED:
        raise RecordError(f"acknowledged command code {command[5]:#04x}", reason="field", offset=14)
    return AckRecord(creator, relayer, port, command)


# ---------------------------------------------------------------------------- splitter geometry


def _about(axis: int, angle) -> np.ndarray:
    a = np.asarray(angle, dtype=np.float64)
    q = np.zeros((*a.shape, 4))
    q[..., 0] = np.cos(0.5 * a)
    q[..., 1 + axis] = np.sin(0.5 * a)
    return q


def splitter_rotation(angles) -> np.ndarray:
    """(..., 4) an outlet's rotation in the splitter's inlet frame from a splitter record's three angles
    (..., 3) radians. The authors' host code (``Software/RigReducer/puppet_things.h``,
    ``update_topology``) composes ``Rx(a1) · Ry(a2) · Rx(a3)`` with the bone along its ``x``; in our frames
    (bone along ``y``, their ``x, y, z`` our ``y, z, x``) that is ``Ry(a1) · Rz(a2) · Ry(a3)``: a turn about
    the incoming shaft, the outlet's bend, a turn about the outgoing shaft."""
    a = np.asarray(angles, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ProtocolError(f"splitter angles must have shape (..., 3), got {a.shape}")
    return rot.normalize(
        rot.multiply(rot.multiply(_about(1, a[..., 0]), _about(2, a[..., 1])), _about(1, a[..., 2]))
    )


def splitter_angles(rotation) -> np.ndarray:
    """(..., 3) the inverse of :func:`splitter_rotation`: the angles of quaternions ``rotation`` (..., 4)
    (radians; the middle angle in [0, π], the first 0 when the outlet is straight or reversed)."""
    q = rot.normalize(rotation)
    m = rot.to_matrix(q)
    bend = np.arccos(np.clip(m[..., 1, 1], -1.0, 1.0))
    s = np.sin(bend)
    straight = s < 1e-12
    a1 = np.where(straight, 0.0, np.arctan2(m[..., 2, 1], -m[..., 0, 1]))
    a3 = np.where(straight, np.arctan2(m[..., 0, 2], m[..., 0, 0]), np.arctan2(m[..., 1, 2], m[..., 1, 0]))
    return np.stack([a1, bend, a3], axis=-1)


# ---------------------------------------------------------------------------- commands


@dataclass(frozen=True, slots=True)
class Command:
    """A downlink command (``utility.c``: ``process_uart_command``), the 10 bytes after a poll's ``'R'``::

        kind u8 | address u32 | code u8 | p1 u8 | p2 u8 | p3 u8 | crc u8

    ``kind`` is ``'P'`` (direct: executed by the piece the host polls, whatever the address), ``'C'``
    (executed by the piece whose id is ``address``, or by every piece with :data:`BROADCAST_ID`) or ``'E'``
    (nothing). Build commands with the class methods; ``target=None`` means direct, an id means ``'C'``.
    """

    kind: int
    address: int
    code: int
    params: tuple[int, int, int]

    def encode(self) -> bytes:
        """The 10 bytes, CRC-8 over bytes 0–8 last."""
        kind = _check_int("command kind", self.kind, 0, 255)
        body = (
            bytes([kind])
            + _U32.pack(_check_int("address", self.address, 0, 0xFFFFFFFF))
            + bytes([_check_int("command code", self.code, 0, 255)])
            + bytes(_check_int("parameter", p, 0, 255) for p in self.params)
        )
        if len(body) != COMMAND_SIZE - 1:
            raise ProtocolError(f"a command has 3 parameters, got {self.params!r}")
        return body + bytes([crc8(body)])

    @classmethod
    def decode(cls, data: bytes | bytearray | memoryview) -> Command:
        """Parse 10 command bytes.

        Raises
        ------
        RecordError
            For a wrong length or a bad CRC, with the offset.
        """
        b = bytes(data)
        if len(b) != COMMAND_SIZE:
            raise RecordError(
                f"a command is {COMMAND_SIZE} bytes, got {len(b)}", reason="length", offset=len(b)
            )
        if crc8(b[:9]) != b[9]:
            raise RecordError(f"bad command CRC at offset 9: {b[9]:#04x}", reason="crc", offset=9)
        return cls(b[0], _U32.unpack_from(b, 1)[0], b[5], (b[6], b[7], b[8]))

    @property
    def target(self) -> int | None:
        """The addressed id; None for a direct or empty command."""
        return self.address if self.kind == BY_ID else None

    # ---------------------------------------------------------------- constructors

    @classmethod
    def _make(cls, code: str, params=(0, 0, 0), target: int | None = None, address: int = 0) -> Command:
        if target is None:
            return cls(DIRECT, address, ord(code), tuple(params))
        _check_int("target id", target, 0, BROADCAST_ID)
        return cls(BY_ID, target, ord(code), tuple(params))

    @classmethod
    def empty(cls) -> Command:
        """Nothing to do: the firmware's own ``empty_command_line`` (``'E'``, bytes 1 … 8, CRC)."""
        return cls(EMPTY, 0x01020304, 5, (6, 7, 8))

    @classmethod
    def zero(cls, target: int | None = None) -> Command:
        """``'z'``: take the current readings as the zero offsets (stored in flash)."""
        return cls._make("z", target=target)

    @classmethod
    def polarity(cls, inverted: bool, target: int | None = None) -> Command:
        """``'x'``: mirror both bend readings (p1 = 1) or not (0). The firmware (``utility.c`` lines
        198–208) stores the polarity, runs ``part_init`` (which clears the readings, lines 512–515) and
        falls through into ``'z'``, which copies those cleared readings: the zero offsets become 0, so the
        piece then sends its raw readings. Send :meth:`zero` after it to zero at the current pose."""
        return cls._make("x", (int(bool(inverted)), 0, 0), target)

    @classmethod
    def led(cls, red: bool, green: bool, blue: bool, target: int | None = None) -> Command:
        """``'l'``: set the LEDs; the firmware reads p1 as blue, p2 as red, p3 as green (non-zero = on).
        Its main loop turns blue off and toggles red every 250 ms, so only green stays as set."""
        return cls._make("l", (int(bool(blue)), int(bool(red)), int(bool(green))), target)

    @classmethod
    def set_id(cls, new_id: int) -> Command:
        """``'i'`` (direct only): the polled piece takes ``new_id`` (bytes 1–4), a joint's 0x74 half passes
        it on to its 0x84 brother. Use :data:`MIN_ID` … :data:`MAX_ID` so that relaying can name it."""
        return cls(DIRECT, _check_int("new id", new_id, 0, 0xFFFFFFFF), ord("i"), (0, 0, 0))

    @classmethod
    def set_type(cls, node_type: int) -> Command:
        """``'t'`` (direct only): the polled piece's node type, as two upper-case hex digits in p1, p2."""
        t = _check_int("node type", node_type, 0, 255)
        return cls(DIRECT, 0, ord("t"), (ord(f"{t:02X}"[0]), ord(f"{t:02X}"[1]), 0))

    @classmethod
    def data_mode(cls, mode: int, target: int | None = None) -> Command:
        """``'d'``: p1 = 0 normal; non-zero: a joint sends data even without fresh readings; 2: a joint's
        0x74 half relays its brother's records instead of merging them."""
        return cls._make("d", (_check_int("data mode", mode, 0, 255), 0, 0), target)

    @classmethod
    def colour(cls, rgb: Sequence[int], target: int | None = None) -> Command:
        """``'c'``: the piece's colour, R, G, B in p1, p2, p3 (sent back in its init records)."""
        if len(rgb) != 3:
            raise ProtocolError(f"a colour is 3 bytes (RGB), got {rgb!r}")
        return cls._make("c", tuple(_check_int("colour", c, 0, 255) for c in rgb), target)

    @classmethod
    def splitter_geometry(cls, slot: int, angles: Sequence[float]) -> Command:
        """``'g'`` (direct only): outlet ``slot``'s three angles (radians, sent as signed whole degrees):
        roll in bytes 1–2, pitch in bytes 3–4, yaw in p1–p2, the slot in p3."""
        _check_int("slot", slot, 0, 7)
        degrees = SplitterRecord(0, 0, 0, slot, tuple(float(a) for a in angles)).degrees
        roll, pitch, yaw = (d & 0xFFFF for d in degrees)
        return cls(DIRECT, roll << 16 | pitch, ord("g"), (yaw >> 8, yaw & 0xFF, slot))


#: The empty command's bytes, what a poll carries when the host has nothing to say.
EMPTY_COMMAND = Command.empty().encode()


def poll_bytes(command: Command | None = None) -> bytes:
    """The 11 bytes the host writes to poll: ``b"R"`` and ``command`` (empty by default)."""
    return bytes([POLL]) + (EMPTY_COMMAND if command is None else command.encode())


# ---------------------------------------------------------------------------- the reply parser


@dataclass
class ParserStats:
    """Counters of a :class:`ReplyParser` (cumulative).

    Attributes
    ----------
    bytes : int
        Bytes fed.
    records : int
        Valid records yielded (empty ones not counted).
    empty : int
        Valid empty (``'E'``) records dropped.
    corrupt : int
        Damaged spots: a record that failed its checks where a record belonged, or a stretch of bytes a
        dropped, inserted or cut-off byte made unreadable.
    skipped : int
        Bytes not part of any valid record (corrupt records and garbage included, echoes not).
    polls, echoes : int
        Polls announced, and echoes of them recognized and skipped.
    short, oversize, missing : int
        Replies shorter than :data:`REPLY_SIZE` (but not empty), longer, and polls with no reply at all.
    """

    bytes: int = 0
    records: int = 0
    empty: int = 0
    corrupt: int = 0
    skipped: int = 0
    polls: int = 0
    echoes: int = 0
    short: int = 0
    oversize: int = 0
    missing: int = 0

    def copy(self) -> ParserStats:
        return replace(self)


#: A reply window longer than this is cut (a device that streams without being polled, noise).
MAX_WINDOW = 4 * REPLY_SIZE


@dataclass
class _Window:
    solicited: bool = False
    echo: bytes = b""
    echo_seen: int = 0
    echo_match: bool = True
    echo_open: bool = False
    buf: bytearray = field(default_factory=bytearray)
    carry: bytes = b""
    pos: int = 0
    accepted: list[int] = field(default_factory=list)


class ReplyParser:
    """Split the bytes a host reads into records.

    The host calls :meth:`poll` with the bytes of every poll right before writing them, and
    :meth:`feed` with whatever it reads. Between two polls lies one reply window: an optional echo of the
    poll (a half-duplex adapter hears the host's own bytes; recognized by its first byte, ``'R'``, which
    no record starts with), then the reply. Records are read at their 18-byte positions from the start of
    the reply as they complete. When the window closes (the next poll), the stretches between the
    records found are searched byte by byte for records that a dropped or inserted byte, a cut-off reply
    or bytes arriving late shifted, and the window's last unread bytes are kept for the next one (a
    record split across two windows is found there). Empty records are dropped. Everything is counted in
    :attr:`stats`; nothing but a non-bytes argument raises.
    """

    def __init__(self) -> None:
        self.stats = ParserStats()
        self._w = _Window()
        self._carry = b""

    @property
    def reply_bytes(self) -> int:
        """Reply bytes received in the current window (the echo not counted)."""
        return len(self._w.buf)

    @property
    def complete(self) -> bool:
        """Whether the current window holds a whole reply (at least :data:`REPLY_SIZE` bytes)."""
        return len(self._w.buf) >= REPLY_SIZE

    def poll(self, sent: bytes | bytearray) -> list[Record]:
        """Close the current window (returning what the resynchronization recovers from it) and open the
        window of the poll ``sent`` the host is about to write."""
        out = self._finish()
        self.stats.polls += 1
        self._w = _Window(solicited=True, echo=bytes(sent), echo_open=bool(sent), carry=self._carry)
        return out

    def close(self) -> list[Record]:
        """Close the current window without announcing a poll (the port was closed); returns what the
        resynchronization recovers."""
        out = self._finish(carry=False)
        self._w = _Window()
        return out

    def feed(self, data: bytes | bytearray | memoryview) -> list[Record]:
        """Parse a chunk; returns the records it completes, in order.

        Raises
        ------
        ProtocolError
            Only if ``data`` is not bytes-like.
        """
        if not isinstance(data, bytes | bytearray | memoryview):
            raise ProtocolError(f"ReplyParser.feed takes bytes, got {type(data).__name__}")
        data = bytes(data)
        self.stats.bytes += len(data)
        out: list[Record] = []
        w = self._w
        i = 0
        if w.echo_open and data:
            if w.echo_seen == 0 and not w.buf and data[0] != w.echo[0]:
                w.echo_open = False  # no echo: this adapter does not hear itself
            else:
                take = min(len(data), len(w.echo) - w.echo_seen)
                if data[:take] != w.echo[w.echo_seen : w.echo_seen + take]:
                    w.echo_match = False
                w.echo_seen += take
                i = take
                if w.echo_seen == len(w.echo):
                    w.echo_open = False
                    if w.echo_match:
                        self.stats.echoes += 1
                    else:
                        self.stats.skipped += len(w.echo)
        while i < len(data):
            room = MAX_WINDOW - len(w.buf)
            w.buf += data[i : i + room]
            i += room
            self._head(out)
            if len(w.buf) >= MAX_WINDOW:  # nobody polls this much: cut, and read on unsolicited
                out += self._finish()
                w = self._w = _Window(carry=self._carry)
        return out

    def _accept(self, block: bytes, out: list[Record]) -> bool:
        if block[0] not in _STARTS:
            return False
        try:
            record = decode_record(block)
        except RecordError:
            return False
        if record is None:
            self.stats.empty += 1
        else:
            self.stats.records += 1
            out.append(record)
        return True

    def _head(self, out: list[Record]) -> None:
        w = self._w
        while len(w.buf) - w.pos >= RECORD_SIZE:
            if self._accept(bytes(w.buf[w.pos : w.pos + RECORD_SIZE]), out):
                w.accepted.append(w.pos)
            w.pos += RECORD_SIZE

    def _finish(self, carry: bool = True) -> list[Record]:
        """Close the window: count it, search it for shifted records, and keep its last unread bytes
        (up to a record's length less one) for the next window: the rest of a record may come late."""
        w, s = self._w, self.stats
        out: list[Record] = []
        if w.echo_seen and w.echo_open:  # an echo cut short
            s.skipped += w.echo_seen
        if w.echo:  # an echo behind late bytes, or echoes of polls a slow device read together: cut out
            e = len(w.echo)
            i = w.buf.find(w.echo)
            while i >= 0:
                if all(a + RECORD_SIZE <= i or a >= i + e for a in w.accepted):
                    del w.buf[i : i + e]
                    w.accepted = [a if a < i else a - e for a in w.accepted]
                    s.echoes += 1
                    i = w.buf.find(w.echo, i)
                else:
                    i = w.buf.find(w.echo, i + 1)
        n = len(w.buf)
        if w.solicited:
            if n == 0:
                s.missing += 1
            elif n < REPLY_SIZE:
                s.short += 1
            elif n > REPLY_SIZE:
                s.oversize += 1
        aligned = n == REPLY_SIZE and not w.carry
        k = len(w.carry)  # the last window's partial record may go on here
        buf = w.carry + bytes(w.buf)
        accepted = sorted(a + k for a in w.accepted)
        n = len(buf)
        # Search the gaps between the records found for records that a dropped or inserted byte, or a
        # reply split across windows, shifted (a gap of one record's length holds nothing new).
        found: list[int] = []
        start = 0
        for a in [*accepted, n]:
            o = start
            while o + RECORD_SIZE <= a:
                if self._accept(buf[o : o + RECORD_SIZE], out):
                    found.append(o)
                    o += RECORD_SIZE
                else:
                    o += 1
            start = a + RECORD_SIZE
        accepted = sorted(accepted + found)
        end = accepted[-1] + RECORD_SIZE if accepted else 0
        self._carry = buf[max(end, n - RECORD_SIZE + 1) :] if carry else b""
        start = 0
        for a in [*accepted, n - len(self._carry)]:
            gap = a - start
            if gap > 0:
                s.skipped += gap
                s.corrupt += gap // RECORD_SIZE if aligned else 1
            start = a + RECORD_SIZE
        return out


_STARTS = frozenset((DATA, INIT, SPLITTER, ACK, EMPTY))
