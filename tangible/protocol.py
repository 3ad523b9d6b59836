"""The device's wire format (see ``tangible/PROTOCOL.md``): messages, frame encoding, a streaming decoder.

A frame on the wire is ``0x00 · COBS(raw) · 0x00`` where ``raw`` is a 13-byte header, a payload and a
CRC-16/CCITT-FALSE of both, all little-endian::

    version u8 | type u8 | creator u32 | parent u32 | slot u8 | seq u16 | payload | crc u16

* :func:`encode` turns a message into wire bytes; :func:`decode_frame` turns one frame's COBS bytes
  (without delimiters) back into a message or raises :class:`~tangible.errors.FrameError` naming the
  cause and byte offset.
* :class:`Decoder` is the streaming parser a host feeds with whatever chunks the port delivers. It never
  raises for bad bytes (it counts them in :attr:`Decoder.stats`), works in time linear in the input, and
  holds at most :data:`MAX_ENCODED` bytes of an unfinished frame.

Angles travel as signed 16-bit binary angles (one unit = 2π/65536 rad ≈ 0.0055°); splitter slot rotations
as unit quaternions ``(w, x, y, z)`` in Q15 fixed point.
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass, replace

from .errors import FrameError, ProtocolError

__all__ = [
    "ANGLE_UNIT",
    "CHILD",
    "DATA",
    "HEADER_SIZE",
    "KIND_JOINT",
    "KIND_SPLITTER",
    "MAX_ENCODED",
    "MAX_ID",
    "MAX_SLOTS",
    "TYPE",
    "VERSION",
    "ChildMessage",
    "DataMessage",
    "Decoder",
    "DecoderStats",
    "Message",
    "TypeMessage",
    "cobs_decode",
    "cobs_encode",
    "crc16",
    "decode_frame",
    "encode",
]

#: The protocol version this module speaks (the first byte of every frame).
VERSION = 1
#: Message types (the second byte).
DATA, TYPE, CHILD = 1, 2, 3
#: Component kinds in a type message.
KIND_JOINT, KIND_SPLITTER = 0, 1
#: Largest valid component id; 0 means "no parent yet" (or: the host) and ``0xFFFFFFFF`` is reserved.
MAX_ID = 0xFFFFFFFE
#: Most slots a splitter may describe in one child message.
MAX_SLOTS = 8
#: One unit of an encoded angle, in radians.
ANGLE_UNIT = 2.0 * math.pi / 65536.0

_HEADER = struct.Struct("<BBIIBH")
HEADER_SIZE = _HEADER.size  # 13
_CRC = struct.Struct("<H")
_DATA = struct.Struct("<hhhh")
_TYPE = struct.Struct("<BBBB")
_QUAT = struct.Struct("<hhhh")
_PAYLOAD_SIZE = {DATA: _DATA.size, TYPE: _TYPE.size}
_MAX_RAW = HEADER_SIZE + 1 + MAX_SLOTS * _QUAT.size + _CRC.size  # 80
#: Longest valid frame between its delimiters (COBS adds one byte per started 254).
MAX_ENCODED = _MAX_RAW + (_MAX_RAW + 253) // 254
#: A decoded quaternion whose norm is off by more than this is treated as corrupt.
_QUAT_NORM_TOLERANCE = 0.01


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: polynomial 0x1021, initial value 0xFFFF, no reflection, no final xor.

    Check value: ``crc16(b"123456789") == 0x29B1``.
    """
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: the result contains no zero byte."""
    out = bytearray()
    for part in bytes(data).split(b"\x00"):
        while len(part) >= 254:
            out.append(0xFF)
            out += part[:254]
            part = part[254:]
        out.append(len(part) + 1)
        out += part
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Invert :func:`cobs_encode`; raises :class:`FrameError` (reason ``"cobs"``) on malformed input."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise FrameError(f"zero byte inside a COBS frame at offset {i}", reason="cobs", offset=i)
        end = i + code
        if end > n:
            raise FrameError(
                f"COBS block at offset {i} claims {code - 1} bytes but only {n - i - 1} follow",
                reason="cobs",
                offset=i,
            )
        out += data[i + 1 : end]
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


@dataclass(frozen=True, slots=True)
class Message:
    """Fields every message carries.

    Attributes
    ----------
    creator : int
        Id of the component that created the message (1 … :data:`MAX_ID`).
    parent : int
        Id of the first component that relayed it, 0 if none has (then the creator is plugged into the
        host directly).
    slot : int
        The parent's slot the creator is plugged into (0 for a joint parent), filled with ``parent``.
    seq : int
        The creator's message counter (0 … 65535, wrapping), one count per message of any type.
    """

    creator: int
    parent: int
    slot: int
    seq: int

    def relayed(self, by: int, slot: int = 0) -> Message:
        """The message as it leaves relaying component ``by`` having arrived on ``slot``: the parent
        fields are filled in if still empty, and left alone otherwise."""
        return self if self.parent != 0 else replace(self, parent=by, slot=slot)


@dataclass(frozen=True, slots=True)
class DataMessage(Message):
    """A joint's sensed angles (≈ 50 Hz), radians: ``(bend_a, bend_b, twist_proximal, twist_distal)``,
    see :mod:`tangible.joint` for their meaning."""

    angles: tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class TypeMessage(Message):
    """What a component is (≈ 2 Hz): ``kind`` (:data:`KIND_JOINT` or :data:`KIND_SPLITTER`) and its
    ``colour`` as 8-bit RGB."""

    kind: int
    colour: tuple[int, int, int]


@dataclass(frozen=True, slots=True)
class ChildMessage(Message):
    """A splitter's slot geometry (≈ 2 Hz): for each slot, the unit quaternion ``(w, x, y, z)`` of the
    rotation from the splitter's inlet frame to the slot's outlet frame."""

    rotations: tuple[tuple[float, float, float, float], ...]


def _check_int(name: str, value, lo: int, hi: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise ProtocolError(f"{name} must be an integer in {lo}..{hi}, got {value!r}")
    return value


def _angle_units(value: float, what: str) -> int:
    if not math.isfinite(value):
        raise ProtocolError(f"{what} must be finite, got {value!r}")
    return (round(value / ANGLE_UNIT) + 32768) % 65536 - 32768


def encode(message: Message) -> bytes:
    """Wire bytes of one message: ``0x00 · COBS(header · payload · crc) · 0x00``.

    Raises
    ------
    ProtocolError
        For a field out of range (naming it) or an unknown message class.
    """
    m = message
    _check_int("creator", m.creator, 1, MAX_ID)
    _check_int("parent", m.parent, 0, MAX_ID)
    if m.parent == m.creator:
        raise ProtocolError(f"component {m.creator} cannot be its own parent")
    _check_int("slot", m.slot, 0, 255)
    _check_int("seq", m.seq, 0, 65535)
    if isinstance(m, DataMessage):
        if len(m.angles) != 4:
            raise ProtocolError(f"a data message carries 4 angles, got {len(m.angles)}")
        names = ("bend_a", "bend_b", "twist_proximal", "twist_distal")
        kind = DATA
        payload = _DATA.pack(*(_angle_units(float(a), n) for a, n in zip(m.angles, names, strict=True)))
    elif isinstance(m, TypeMessage):
        _check_int("kind", m.kind, KIND_JOINT, KIND_SPLITTER)
        if len(m.colour) != 3:
            raise ProtocolError(f"colour must be 3 bytes (RGB), got {len(m.colour)} values")
        kind = TYPE
        payload = _TYPE.pack(m.kind, *(_check_int("colour", int(c), 0, 255) for c in m.colour))
    elif isinstance(m, ChildMessage):
        k = len(m.rotations)
        if not 1 <= k <= MAX_SLOTS:
            raise ProtocolError(f"a child message describes 1..{MAX_SLOTS} slots, got {k}")
        kind = CHILD
        parts = [bytes([k])]
        for i, q in enumerate(m.rotations):
            q = [float(c) for c in q]
            norm = math.sqrt(sum(c * c for c in q)) if len(q) == 4 else 0.0
            if not (math.isfinite(norm) and norm > 0.0):
                raise ProtocolError(f"slot {i} rotation must be a finite non-zero quaternion, got {q!r}")
            sign = -1.0 if q[0] < 0 else 1.0
            parts.append(_QUAT.pack(*(round(32767.0 * sign * c / norm) for c in q)))
        payload = b"".join(parts)
    else:
        raise ProtocolError(f"cannot encode {type(m).__name__}: not a protocol message")
    raw = _HEADER.pack(VERSION, kind, m.creator, m.parent, m.slot, m.seq) + payload
    raw += _CRC.pack(crc16(raw))
    return b"\x00" + cobs_encode(raw) + b"\x00"


def decode_frame(frame: bytes) -> Message:
    """Decode one frame given as its COBS bytes between two delimiters.

    Raises
    ------
    FrameError
        With ``reason`` and ``offset`` naming what is wrong and where.
    """
    if len(frame) > MAX_ENCODED:
        raise FrameError(
            f"frame of {len(frame)} bytes is longer than the longest valid frame ({MAX_ENCODED})",
            reason="oversize",
            offset=MAX_ENCODED,
        )
    raw = cobs_decode(frame)
    n = len(raw)
    if n < HEADER_SIZE + _CRC.size:
        raise FrameError(
            f"frame of {n} bytes is shorter than header and checksum ({HEADER_SIZE + _CRC.size})",
            reason="length",
            offset=n,
        )
    (crc,) = _CRC.unpack_from(raw, n - 2)
    if crc16(raw[:-2]) != crc:
        raise FrameError(f"checksum mismatch at offset {n - 2}", reason="crc", offset=n - 2)
    version, kind, creator, parent, slot, seq = _HEADER.unpack_from(raw, 0)
    if version != VERSION:
        raise FrameError(
            f"protocol version {version} is not supported (this host speaks {VERSION})",
            reason="version",
            offset=0,
        )
    body = raw[HEADER_SIZE:-2]
    if creator == 0 or creator > MAX_ID or parent > MAX_ID or parent == creator:
        raise FrameError(f"invalid ids (creator {creator}, parent {parent})", reason="field", offset=2)
    if kind == CHILD:
        k = body[0] if body else 0
        if not 1 <= k <= MAX_SLOTS or len(body) != 1 + k * _QUAT.size:
            raise FrameError(
                f"child payload of {len(body)} bytes does not hold {k} slots",
                reason="length",
                offset=HEADER_SIZE,
            )
        rotations = []
        for i in range(k):
            q = [c / 32767.0 for c in _QUAT.unpack_from(body, 1 + i * _QUAT.size)]
            norm = math.sqrt(sum(c * c for c in q))
            if abs(norm - 1.0) > _QUAT_NORM_TOLERANCE:
                raise FrameError(
                    f"slot {i} quaternion has norm {norm:.3f}",
                    reason="field",
                    offset=HEADER_SIZE + 1 + i * _QUAT.size,
                )
            rotations.append(tuple(c / norm for c in q))
        return ChildMessage(creator, parent, slot, seq, tuple(rotations))
    size = _PAYLOAD_SIZE.get(kind)
    if size is None:
        raise FrameError(f"unknown message type {kind}", reason="type", offset=1)
    if len(body) != size:
        raise FrameError(
            f"payload of type {kind} must be {size} bytes, got {len(body)}",
            reason="length",
            offset=HEADER_SIZE,
        )
    if kind == DATA:
        return DataMessage(creator, parent, slot, seq, tuple(a * ANGLE_UNIT for a in _DATA.unpack(body)))
    component, r, g, b = _TYPE.unpack(body)
    if component not in (KIND_JOINT, KIND_SPLITTER):
        raise FrameError(f"unknown component kind {component}", reason="field", offset=HEADER_SIZE)
    return TypeMessage(creator, parent, slot, seq, component, (r, g, b))


@dataclass
class DecoderStats:
    """Counters of a :class:`Decoder` (all cumulative).

    Attributes
    ----------
    bytes : int
        Bytes fed.
    frames : int
        Valid frames decoded.
    corrupt : int
        Non-empty segments between delimiters that failed COBS, length, checksum or field checks.
    oversize : int
        Segments longer than :data:`MAX_ENCODED` (dropped as soon as they outgrow the cap).
    unsupported : int
        Intact frames of another protocol version or an unknown message type.
    """

    bytes: int = 0
    frames: int = 0
    corrupt: int = 0
    oversize: int = 0
    unsupported: int = 0

    def copy(self) -> DecoderStats:
        return replace(self)


_REASON_COUNTER = {"version": "unsupported", "type": "unsupported", "oversize": "oversize"}


class Decoder:
    """Streaming frame parser: feed it byte chunks of any size, get the messages completed by each.

    Parameters
    ----------
    max_frame : int
        Cap on the bytes kept for an unfinished frame (default :data:`MAX_ENCODED`); longer segments are
        dropped and counted as oversize, and parsing resumes at the next delimiter.
    """

    def __init__(self, max_frame: int = MAX_ENCODED):
        if not isinstance(max_frame, int) or max_frame < 1:
            raise ProtocolError(f"max_frame must be a positive integer, got {max_frame!r}")
        self.max_frame = max_frame
        self.stats = DecoderStats()
        self._pending = bytearray()
        self._skipping = False

    @property
    def pending(self) -> int:
        """Bytes held for the frame in progress (never more than ``max_frame``)."""
        return len(self._pending)

    def reset(self) -> None:
        """Forget a partial frame (after the port was reopened); counters are kept."""
        self._pending.clear()
        self._skipping = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Message]:
        """Parse ``data`` and return the messages of every frame it completes, in order.

        Raises
        ------
        ProtocolError
            Only if ``data`` is not a bytes-like object.
        """
        if not isinstance(data, bytes | bytearray | memoryview):
            raise ProtocolError(f"Decoder.feed takes bytes, got {type(data).__name__}")
        data = bytes(data)
        self.stats.bytes += len(data)
        out: list[Message] = []
        start = 0
        while True:
            end = data.find(0, start)
            if end < 0:
                self._hold(data, start)
                return out
            if self._skipping:
                self._skipping = False
            elif self._pending:
                self._pending += data[start:end]
                self._segment(bytes(self._pending), out)
                self._pending.clear()
            elif end > start:
                self._segment(data[start:end], out)
            start = end + 1

    def _hold(self, data: bytes, start: int) -> None:
        if self._skipping or start == len(data):
            return
        if len(self._pending) + len(data) - start > self.max_frame:
            self._pending.clear()
            self._skipping = True
            self.stats.oversize += 1
        else:
            self._pending += data[start:]

    def _segment(self, segment: bytes, out: list[Message]) -> None:
        if len(segment) > self.max_frame:
            self.stats.oversize += 1
            return
        try:
            out.append(decode_frame(segment))
        except FrameError as e:
            counter = _REASON_COUNTER.get(e.reason, "corrupt")
            setattr(self.stats, counter, getattr(self.stats, counter) + 1)
        else:
            self.stats.frames += 1
