"""The firmware's wire protocol: records and commands built byte by byte from the layout in
``Hardware/Firmware`` (``utility.c``: ``create_up_message``, ``process_uart_command``), the firmware's own
CRC table, and the streaming reply parser under damage and fuzzing."""

import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tangible import SPLITTERS
from tangible import rotations as rot
from tangible.errors import ProtocolError, RecordError
from tangible.protocol import (
    BROADCAST_ID,
    CRC_TABLE,
    EMPTY_COMMAND,
    EMPTY_RECORD,
    REPLY_SIZE,
    AckRecord,
    Command,
    DataRecord,
    InitRecord,
    ReplyParser,
    SplitterRecord,
    crc8,
    decode_record,
    encode_record,
    poll_bytes,
    splitter_angles,
    splitter_rotation,
)

LSB = 2 * math.pi / 16384

# mlx90363.c: CRCArray, first and last rows as published.
FIRMWARE_TABLE_HEAD = [0x00, 0x2F, 0x5E, 0x71, 0xBC, 0x93, 0xE2, 0xCD, 0x57, 0x78, 0x09, 0x26]
FIRMWARE_TABLE_TAIL = [
    0xD8,
    0xF7,
    0x86,
    0xA9,
    0x64,
    0x4B,
    0x3A,
    0x15,
    0x8F,
    0xA0,
    0xD1,
    0xFE,
    0x33,
    0x1C,
    0x6D,
    0x42,
]


def bitwise_crc(data: bytes) -> int:
    """CRC-8/AUTOSAR bit by bit, independent of the module's table."""
    c = 0xFF
    for byte in data:
        c ^= byte
        for _ in range(8):
            c = ((c << 1) ^ 0x2F) & 0xFF if c & 0x80 else (c << 1) & 0xFF
    return c ^ 0xFF


def line(kind: str, creator: int, relayer_bytes: bytes, payload: bytes) -> bytes:
    """A record as ``create_up_message`` lays it out, then a relayer's bytes 5-8."""
    body = kind.encode() + struct.pack(">I", creator) + relayer_bytes + payload
    assert len(body) == 17
    return body + bytes([bitwise_crc(body)])


def test_crc_is_the_firmwares_autosar_crc8():
    assert crc8(b"123456789") == 0xDF == bitwise_crc(b"123456789")
    assert list(CRC_TABLE[:12]) == FIRMWARE_TABLE_HEAD and list(CRC_TABLE[-16:]) == FIRMWARE_TABLE_TAIL
    rng = np.random.default_rng(0)
    for n in (0, 1, 9, 17):
        data = rng.integers(0, 256, n, np.uint8).tobytes()
        assert crc8(data) == bitwise_crc(data)


def test_golden_data_record():
    # Proximal twist +100 steps, bend a +200, bend b -300 (each bend + 0x0FFF), distal twist -50 (mod 16384).
    raw = (100, 0x0FFF + 200, 0x0FFF - 300, 16384 - 50)
    block = line("D", 0x01234567, bytes(4), struct.pack(">HHHH", *raw))
    assert block.hex() == "4401234567000000000064" + "10c70ed33fce" + f"{block[17]:02x}"
    r = decode_record(block)
    assert isinstance(r, DataRecord) and (r.creator, r.relayer, r.port, r.relayed) == (
        0x01234567,
        0,
        0,
        False,
    )
    np.testing.assert_allclose(r.angles, np.array([100, 200, -300, -50]) * LSB, atol=1e-12)
    assert r.raw == raw and encode_record(r) == block
    # Wrapping: a bend reading of 0 is -0x0FFF steps; a twist of 8192 steps is +pi, never -pi.
    r = decode_record(line("D", 0x01000001, bytes(4), struct.pack(">HHHH", 8192, 0, 0x0FFF, 0)))
    assert r.angles[0] == math.pi and r.angles[1] == pytest.approx(-0x0FFF * LSB) and r.angles[2] == 0


def test_relayer_and_port():
    # A splitter 0x0ABCDEF1 relays from its output 5: byte 5 = 0x0A | 5 << 4.
    block = line("D", 0x01000002, bytes([0x0A | 5 << 4, 0xBC, 0xDE, 0xF1]), struct.pack(">HHHH", 1, 2, 3, 4))
    r = decode_record(block)
    assert (r.relayer, r.port, r.relayed) == (0x0ABCDEF1, 5, True)
    assert encode_record(r) == block


def test_golden_init_splitter_ack_and_empty_records():
    block = line("I", 0x0FFFFFFF, bytes([0x01, 0, 0, 7]), bytes([0x74, 230, 25, 75, 0, 0, 0, 0]))
    r = decode_record(block)
    assert isinstance(r, InitRecord) and (r.node_type, r.colour) == (0x74, (230, 25, 75))
    assert r.is_joint and not r.is_splitter and r.outputs == 1 and (r.relayer, r.port) == (0x01000007, 0)
    assert encode_record(r) == block
    splitter = decode_record(line("I", 0x01000003, bytes(4), bytes([0x38, 1, 2, 3, 0, 0, 0, 0])))
    assert splitter.is_splitter and splitter.outputs == 3

    # 'S': a zero byte, the output, then roll, pitch, yaw as u16 (signed degrees).
    block = line("S", 0x01000003, bytes(4), struct.pack(">BBhhh", 0, 2, 0, 90, -45))
    r = decode_record(block)
    assert isinstance(r, SplitterRecord) and r.slot == 2 and r.degrees == (0, 90, -45)
    np.testing.assert_allclose(r.angles, np.radians([0, 90, -45]))
    assert encode_record(r) == block

    # 'A': the acknowledged command's first 8 bytes.
    command = Command.zero(target=0x01000002).encode()
    block = line("A", 0x01000002, bytes(4), command[:8])
    r = decode_record(block)
    assert isinstance(r, AckRecord) and r.code == "z" and r.address == 0x01000002 and not r.direct
    assert encode_record(r) == block

    assert b"E" + bytes(range(1, 17)) + bytes([bitwise_crc(b"E" + bytes(range(1, 17)))]) == EMPTY_RECORD
    assert decode_record(EMPTY_RECORD) is None


def test_decoding_names_the_offset_and_the_cause():
    good = line("D", 0x01000001, bytes(4), struct.pack(">HHHH", 1, 2, 3, 4))
    with pytest.raises(RecordError, match="offset 17") as e:
        decode_record(good[:17] + bytes([good[17] ^ 1]))
    assert (e.value.reason, e.value.offset) == ("crc", 17)
    with pytest.raises(RecordError, match="offset 0") as e:
        decode_record(b"X" + good[1:])
    assert (e.value.reason, e.value.offset) == ("kind", 0)
    with pytest.raises(RecordError) as e:
        decode_record(good[:10])
    assert e.value.reason == "length"
    with pytest.raises(RecordError, match="14 bits") as e:
        decode_record(line("D", 0x01000001, bytes(4), struct.pack(">HHHH", 1, 0x4000, 3, 4)))
    assert (e.value.reason, e.value.offset) == ("field", 11)
    with pytest.raises(RecordError, match="port") as e:
        decode_record(line("D", 0x01000001, bytes([0x80, 0, 0, 1]), bytes(8)))
    assert e.value.offset == 5
    with pytest.raises(RecordError, match="28 bits"):
        decode_record(line("D", 0x11000001, bytes(4), bytes(8)))
    with pytest.raises(RecordError, match="13-16"):
        decode_record(line("I", 0x01000001, bytes(4), bytes([0x74, 1, 2, 3, 0, 0, 9, 0])))
    with pytest.raises(RecordError, match="code"):
        decode_record(line("A", 0x01000001, bytes(4), b"P\x00\x00\x00\x00q\x00\x00"))
    with pytest.raises(ProtocolError, match="bytes"):
        decode_record("not bytes")
    with pytest.raises(ProtocolError, match="relayer"):
        encode_record(DataRecord(1, 0x10000000, 0, (0.0,) * 4))


def crc_line(*body: int) -> bytes:
    return bytes(body) + bytes([bitwise_crc(bytes(body))])


@pytest.mark.parametrize(
    ("command", "expected"),
    [
        # process_uart_command reads: [0] kind, [1..4] address, [5] letter, [6..8] parameters, [9] CRC.
        (Command.empty(), crc_line(ord("E"), 1, 2, 3, 4, 5, 6, 7, 8)),  # main.c: empty_command_line
        (Command.zero(), crc_line(ord("P"), 0, 0, 0, 0, ord("z"), 0, 0, 0)),
        (Command.zero(target=0x01020304), crc_line(ord("C"), 1, 2, 3, 4, ord("z"), 0, 0, 0)),
        (Command.zero(target=BROADCAST_ID), crc_line(ord("C"), 255, 255, 255, 255, ord("z"), 0, 0, 0)),
        (Command.polarity(True, target=0x0100000A), crc_line(ord("C"), 1, 0, 0, 10, ord("x"), 1, 0, 0)),
        # 'l': p1 blue, p2 red, p3 green.
        (Command.led(red=True, green=False, blue=False), crc_line(ord("P"), 0, 0, 0, 0, ord("l"), 0, 1, 0)),
        (Command.led(red=False, green=True, blue=True), crc_line(ord("P"), 0, 0, 0, 0, ord("l"), 1, 0, 1)),
        # 'i' (direct only): the new id in bytes 1-4.
        (Command.set_id(0x0ABCDEF0), crc_line(ord("P"), 0x0A, 0xBC, 0xDE, 0xF0, ord("i"), 0, 0, 0)),
        # 't' (direct only): two upper-case hex digits.
        (Command.set_type(0x74), crc_line(ord("P"), 0, 0, 0, 0, ord("t"), ord("7"), ord("4"), 0)),
        (Command.set_type(0x3A), crc_line(ord("P"), 0, 0, 0, 0, ord("t"), ord("3"), ord("A"), 0)),
        (Command.data_mode(2, target=0x01000001), crc_line(ord("C"), 1, 0, 0, 1, ord("d"), 2, 0, 0)),
        (Command.colour((230, 25, 75)), crc_line(ord("P"), 0, 0, 0, 0, ord("c"), 230, 25, 75)),
        # 'g' (direct only): roll in bytes 1-2, pitch in 3-4, yaw in 6-7, the output in 8.
        (
            Command.splitter_geometry(3, np.radians([10, -90, 300])),
            crc_line(ord("P"), 0, 10, 0xFF, 0xA6, ord("g"), 0x01, 0x2C, 3),
        ),
    ],
)
def test_golden_commands(command, expected):
    assert command.encode() == expected
    assert Command.decode(expected) == command
    assert poll_bytes(command) == b"R" + expected


def test_command_decoding_and_misuse():
    assert poll_bytes() == b"R" + EMPTY_COMMAND and len(poll_bytes()) == 11
    with pytest.raises(RecordError, match="offset 9"):
        Command.decode(EMPTY_COMMAND[:9] + bytes([EMPTY_COMMAND[9] ^ 0xFF]))
    with pytest.raises(ProtocolError, match="colour"):
        Command.colour((1, 2, 300))
    with pytest.raises(ProtocolError, match="slot"):
        Command.splitter_geometry(8, (0, 0, 0))
    assert Command.zero(target=7).target == 7 and Command.zero().target is None


def test_splitter_angles_compose_like_the_authors_host():
    rng = np.random.default_rng(1)
    a = np.column_stack([rng.uniform(-3, 3, 50), rng.uniform(0.01, 3.1, 50), rng.uniform(-3, 3, 50)])
    q = splitter_rotation(a)
    np.testing.assert_allclose(splitter_angles(q), a, atol=1e-9)
    # Ry(a1) Rz(a2) Ry(a3): the authors' Rx Ry Rx with their x, y, z our y, z, x.
    y, z = np.array([0, 1.0, 0]), np.array([0, 0, 1.0])
    expect = rot.multiply(rot.multiply(rot.from_axis_angle(y, a[:, 0]), rot.from_axis_angle(z, a[:, 1])),
                          rot.from_axis_angle(y, a[:, 2]))  # fmt: skip
    assert rot.angle(q, expect).max() < 1e-12
    # The planar splitters are turns about z: whole degrees, exact on the wire.
    for kind in SPLITTERS.values():
        angles = splitter_angles(kind.slots)
        assert rot.angle(splitter_rotation(angles), kind.slots).max() < 1e-9
        degrees = np.degrees(angles)
        np.testing.assert_allclose(degrees, np.round(degrees), atol=1e-9)


# ---------------------------------------------------------------------------- the reply parser


def records(n: int, seed: int = 0) -> list[bytes]:
    """n distinct valid records of every kind."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        creator = 0x01000000 + int(rng.integers(1, 1000))
        if i % 4 == 0:
            r = InitRecord(creator, 0, 0, 0x74, (i, 2, 3))
        elif i % 4 == 1:
            r = SplitterRecord(creator, 0x01000009, 1, i % 8, (0.0, math.radians(i), 0.0))
        else:
            r = DataRecord(creator, 0x01000005, 0, tuple(rng.uniform(-3, 3, 4)))
        out.append(encode_record(r))
    return out


def reply(blocks: list[bytes]) -> bytes:
    assert len(blocks) <= 12
    return b"".join(blocks) + EMPTY_RECORD * (12 - len(blocks))


def run(parser: ReplyParser, chunks, poll=None) -> list[bytes]:
    out = parser.poll(poll_bytes() if poll is None else poll)
    for c in chunks:
        out += parser.feed(bytes(c))
    out += parser.close()
    return [encode_record(r) for r in out]


def test_a_reply_in_any_chunks_gives_its_records_without_the_empty_ones():
    blocks = records(9)
    data = reply(blocks)
    rng = np.random.default_rng(3)
    cuts = np.sort(rng.choice(np.arange(1, REPLY_SIZE), 20, replace=False))
    parser = ReplyParser()
    assert run(parser, np.split(np.frombuffer(data, np.uint8), cuts)) == blocks
    s = parser.stats
    assert (s.records, s.empty, s.corrupt, s.skipped, s.short, s.missing, s.bytes) == (9, 3, 0, 0, 0, 0, 216)


def test_an_echo_of_the_poll_is_skipped():
    blocks = records(12, seed=1)
    parser = ReplyParser()
    poll = poll_bytes(Command.zero(target=0x01000001))
    assert run(parser, [poll[:5], poll[5:] + reply(blocks)[:30], reply(blocks)[30:]], poll) == blocks
    assert parser.stats.echoes == 1 and parser.stats.skipped == 0 and parser.stats.corrupt == 0


def test_a_flipped_bit_costs_one_record():
    blocks = records(12, seed=2)
    data = bytearray(reply(blocks))
    data[5 * 18 + 7] ^= 0x10
    parser = ReplyParser()
    assert run(parser, [bytes(data)]) == blocks[:5] + blocks[6:]
    assert parser.stats.corrupt == 1 and parser.stats.skipped == 18 and parser.stats.short == 0


@pytest.mark.parametrize("where", [0, 3 * 18 + 4, 11 * 18 + 17])
def test_a_dropped_byte_costs_one_record_and_the_rest_resynchronize(where):
    blocks = records(12, seed=3)
    data = bytearray(reply(blocks))
    del data[where]
    parser = ReplyParser()
    lost = where // 18
    assert run(parser, [bytes(data)]) == blocks[:lost] + blocks[lost + 1 :]
    assert parser.stats.short == 1 and parser.stats.corrupt == 1


def test_two_drops_and_garbage_in_one_reply():
    blocks = records(12, seed=4)
    data = bytearray(reply(blocks))
    del data[9 * 18 + 2]
    del data[2 * 18 + 11]
    data[6 * 18 - 1 : 6 * 18 - 1] = b"\x00garbage\xff" * 3  # between records 5 and 6 (shifted by one)
    parser = ReplyParser()
    assert run(parser, [bytes(data)]) == blocks[:2] + blocks[3:9] + blocks[10:]
    assert parser.stats.oversize == 1 and parser.stats.corrupt == 3


def test_a_cut_and_a_missing_reply_are_counted():
    blocks = records(12, seed=5)
    parser = ReplyParser()
    assert run(parser, [reply(blocks)[:100]]) == blocks[:5]
    assert parser.stats.short == 1 and parser.stats.skipped == 10
    parser.poll(poll_bytes())
    parser.poll(poll_bytes())  # nothing came back, twice
    parser.close()
    assert parser.stats.missing == 2 and parser.stats.polls == 3


def test_an_echo_behind_late_bytes_is_cut_out():
    blocks = records(24, seed=8)
    first, second = reply(blocks[:12]), reply(blocks[12:])
    parser = ReplyParser()
    poll = poll_bytes()
    out = parser.poll(poll) + parser.feed(first[:100])
    out += parser.poll(poll) + parser.feed(first[100:] + poll + second) + parser.close()
    assert [encode_record(r) for r in out] == blocks
    assert parser.stats.echoes == 1 and parser.stats.skipped == 0 and parser.stats.corrupt == 0


def test_late_bytes_of_a_reply_are_recovered_in_the_next_window():
    blocks = records(24, seed=6)
    first, second = reply(blocks[:12]), reply(blocks[12:])
    parser = ReplyParser()
    out = parser.poll(poll_bytes()) + parser.feed(first[:150])
    out += parser.poll(poll_bytes()) + parser.feed(first[150:] + second) + parser.close()
    assert [encode_record(r) for r in out] == blocks


def test_random_noise_gives_no_records():
    rng = np.random.default_rng(7)
    parser = ReplyParser()
    noise = rng.integers(0, 256, 400_000, np.uint8).tobytes()
    got = []
    for i in range(0, len(noise), 1000):
        if i % 5000 == 0:
            got += parser.poll(poll_bytes())
        got += parser.feed(noise[i : i + 1000])
    got += parser.close()
    assert got == [] and parser.stats.skipped > 390_000


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=0, max_size=40))
def test_decoding_raises_only_its_own_error(data):
    try:
        r = decode_record(data)
    except RecordError:
        return
    assert r is None or encode_record(r) == data


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 4), st.binary(max_size=60)),
        max_size=30,
    ),
    st.integers(0, 2**32 - 1),
)
def test_the_parser_never_raises_and_accounts_for_every_byte(script, seed):
    """Valid records, echoes, polls and garbage in any mix: no exception, and every valid aligned record
    of an undamaged reply comes out."""
    rng = np.random.default_rng(seed)
    parser = ReplyParser()
    fed = 0
    for op, junk in script:
        if op == 0:
            parser.poll(poll_bytes())
        elif op == 1:
            data = reply(records(int(rng.integers(0, 13)), seed=int(rng.integers(0, 1000))))
            parser.feed(data)
            fed += len(data)
        else:
            parser.feed(junk)
            fed += len(junk)
    parser.close()
    assert parser.stats.bytes == fed


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 12))
def test_valid_records_round_trip_through_the_parser_whatever_the_chunking(seed, n):
    rng = np.random.default_rng(seed)
    blocks = records(n, seed=seed % 1000)
    data = reply(blocks)
    cuts = np.sort(rng.choice(np.arange(1, REPLY_SIZE), int(rng.integers(0, 30)), replace=False))
    assert run(ReplyParser(), np.split(np.frombuffer(data, np.uint8), cuts)) == blocks


def test_the_parser_takes_only_bytes():
    with pytest.raises(ProtocolError, match="bytes"):
        ReplyParser().feed([1, 2, 3])
