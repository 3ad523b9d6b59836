"""The wire format: CRC, COBS, encode/decode, and a fuzzed streaming decoder."""

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tangible import protocol
from tangible.errors import FrameError, ProtocolError
from tangible.protocol import (
    ANGLE_UNIT,
    MAX_ENCODED,
    ChildMessage,
    DataMessage,
    Decoder,
    TypeMessage,
    cobs_decode,
    cobs_encode,
    crc16,
    decode_frame,
    encode,
)

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])

ids = st.integers(1, protocol.MAX_ID)
angles = st.tuples(*[st.floats(-math.pi, math.pi, allow_nan=False)] * 4)
quats = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(lambda q: sum(c * c for c in q) > 0.01)


@st.composite
def messages(draw):
    creator = draw(ids)
    parent = draw(st.one_of(st.just(0), ids.filter(lambda p: p != creator)))
    head = (creator, parent, draw(st.integers(0, 255)), draw(st.integers(0, 65535)))
    kind = draw(st.sampled_from(["data", "type", "child"]))
    if kind == "data":
        return DataMessage(*head, draw(angles))
    if kind == "type":
        colour = draw(st.tuples(*[st.integers(0, 255)] * 3))
        return TypeMessage(*head, draw(st.integers(0, 1)), colour)
    return ChildMessage(*head, tuple(draw(st.lists(quats, min_size=1, max_size=protocol.MAX_SLOTS))))


def same(a, b) -> bool:
    """Decoded message equals the encoded one up to angle and quaternion quantization."""
    if type(a) is not type(b) or (a.creator, a.parent, a.slot, a.seq) != (b.creator, b.parent, b.slot, b.seq):
        return False
    if isinstance(a, DataMessage):
        d = np.angle(np.exp(1j * (np.array(a.angles) - np.array(b.angles))))
        return bool(np.all(np.abs(d) <= ANGLE_UNIT / 2 + 1e-12))
    if isinstance(a, TypeMessage):
        return (a.kind, a.colour) == (b.kind, b.colour)
    qa = np.array(a.rotations)
    qa = qa / np.linalg.norm(qa, axis=1, keepdims=True)
    qa *= np.where(qa[:, :1] < 0, -1, 1)
    return bool(np.allclose(qa, np.array(b.rotations), atol=1e-4))


def test_crc_is_ccitt_false():
    assert crc16(b"123456789") == 0x29B1
    assert crc16(b"") == 0xFFFF


@pytest.mark.parametrize(
    ("raw", "encoded"),
    [
        (b"", b"\x01"),
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
        (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255)) + b"\x01"),
    ],
)
def test_cobs_matches_the_reference_examples(raw, encoded):
    # Examples from Cheshire & Baker's paper and the COBS Wikipedia page.
    assert cobs_encode(raw) == encoded
    assert cobs_decode(encoded) == raw


@given(st.binary(max_size=700))
@FUZZ
def test_cobs_round_trip_has_no_zero_and_bounded_overhead(raw):
    enc = cobs_encode(raw)
    assert 0 not in enc
    assert len(enc) <= len(raw) + 1 + len(raw) // 254
    assert cobs_decode(enc) == raw


@given(messages())
@FUZZ
def test_encode_decode_round_trip(m):
    wire = encode(m)
    assert wire[0] == 0 and wire[-1] == 0 and 0 not in wire[1:-1]
    assert len(wire) - 2 <= MAX_ENCODED
    assert same(m, decode_frame(wire[1:-1]))


def test_protocol_md_example_bytes_are_what_the_encoder_writes():
    text = (Path(protocol.__file__).parent / "PROTOCOL.md").read_text()
    wire = bytes.fromhex(re.search(r"wire = ([0-9a-f ]+)", text).group(1).replace(" ", ""))
    assert encode(DataMessage(5, 0, 0, 7, (0.1, -0.2, 3.0, -3.1))) == wire
    assert len(wire) == 26


def test_relaying_fills_the_parent_only_once():
    m = DataMessage(7, 0, 0, 1, (0.0, 0.0, 0.0, 0.0))
    once = m.relayed(3, slot=2)
    assert (once.parent, once.slot) == (3, 2)
    assert once.relayed(9, slot=0) is once


@pytest.mark.parametrize(
    ("message", "field"),
    [
        (DataMessage(0, 0, 0, 0, (0.0,) * 4), "creator"),
        (DataMessage(1, 1, 0, 0, (0.0,) * 4), "own parent"),
        (DataMessage(1, 0, 256, 0, (0.0,) * 4), "slot"),
        (DataMessage(1, 0, 0, 70000, (0.0,) * 4), "seq"),
        (DataMessage(1, 0, 0, 0, (0.0, float("nan"), 0.0, 0.0)), "bend_b"),
        (TypeMessage(1, 0, 0, 0, 2, (0, 0, 0)), "kind"),
        (TypeMessage(1, 0, 0, 0, 0, (0, 300, 0)), "colour"),
        (ChildMessage(1, 0, 0, 0, ()), "slots"),
        (ChildMessage(1, 0, 0, 0, ((0.0, 0.0, 0.0, 0.0),)), "slot 0"),
    ],
)
def test_encoding_bad_fields_names_them(message, field):
    with pytest.raises(ProtocolError, match=field):
        encode(message)


def test_decode_frame_names_cause_and_offset():
    wire = encode(DataMessage(5, 0, 0, 7, (0.1, 0.2, 0.3, 0.4)))
    body = bytearray(wire[1:-1])
    body[-1] ^= 0x40
    with pytest.raises(FrameError) as e:
        decode_frame(bytes(body))
    assert e.value.reason == "crc" and e.value.offset == 21
    with pytest.raises(FrameError) as e:
        decode_frame(b"\x05\x01")
    assert e.value.reason == "cobs" and e.value.offset == 0
    raw = bytearray(cobs_decode(wire[1:-1]))
    raw[0] = 2  # another version, CRC fixed up: intact but unsupported
    raw[-2:] = crc16(bytes(raw[:-2])).to_bytes(2, "little")
    with pytest.raises(FrameError) as e:
        decode_frame(cobs_encode(bytes(raw)))
    assert e.value.reason == "version"
    d = Decoder()
    assert d.feed(b"\x00" + cobs_encode(bytes(raw)) + b"\x00") == []
    assert (d.stats.unsupported, d.stats.corrupt, d.stats.frames) == (1, 0, 0)


def test_decoder_rejects_non_bytes_with_protocol_error():
    with pytest.raises(ProtocolError, match="bytes"):
        Decoder().feed("not bytes")
    with pytest.raises(ProtocolError, match="max_frame"):
        Decoder(max_frame=0)


# ---------------------------------------------------------------- fuzzing the streaming decoder


def feed_in_chunks(decoder, data, cuts):
    out = []
    points = sorted({min(c, len(data)) for c in cuts})
    start = 0
    for p in [*points, len(data)]:
        out += decoder.feed(data[start:p])
        start = p
    return out


@given(st.binary(max_size=4000), st.lists(st.integers(0, 4000), max_size=20))
@FUZZ
def test_random_bytes_never_raise_and_memory_stays_bounded(data, cuts):
    d = Decoder()
    out = feed_in_chunks(d, data, cuts)
    assert d.pending <= MAX_ENCODED
    assert d.stats.bytes == len(data)
    assert d.stats.frames == len(out)


@given(
    st.lists(messages(), min_size=1, max_size=8),
    st.lists(st.binary(max_size=60), min_size=9, max_size=9),
    st.lists(st.integers(0, 2000), max_size=12),
)
@FUZZ
def test_valid_frames_embedded_in_garbage_are_all_recovered(ms, garbage, cuts):
    stream = b"".join(g + encode(m) for g, m in zip(garbage, ms, strict=False)) + garbage[-1]
    out = feed_in_chunks(Decoder(), stream, cuts)
    # Every frame comes out, in order (garbage could in principle form an extra valid frame: allow it).
    it = iter(out)
    assert all(any(same(m, o) for o in it) for m in ms)


@given(st.lists(messages(), min_size=3, max_size=10), st.data())
@FUZZ
def test_damaging_one_frame_never_costs_its_neighbours(ms, data):
    frames = [encode(m) for m in ms]
    k = data.draw(st.integers(0, len(frames) - 1))
    f = bytearray(frames[k])
    how = data.draw(st.sampled_from(["flip", "truncate", "drop", "insert"]))
    if how == "flip":
        for bit in data.draw(st.lists(st.integers(0, 8 * len(f) - 1), min_size=1, max_size=4, unique=True)):
            f[bit // 8] ^= 1 << (bit % 8)
    elif how == "truncate":
        f = f[: data.draw(st.integers(0, len(f) - 2))]
    elif how == "drop":
        del f[data.draw(st.integers(0, len(f) - 1))]
    else:
        f.insert(data.draw(st.integers(1, len(f) - 1)), data.draw(st.integers(1, 255)))
    frames[k] = bytes(f)
    out = Decoder().feed(b"".join(frames))
    others = [m for i, m in enumerate(ms) if i != k]
    it = iter(out)
    assert all(any(same(m, o) for o in it) for m in others)
    assert len(out) <= len(ms)


@given(st.lists(messages(), max_size=6), st.lists(st.integers(0, 600), max_size=30))
@FUZZ
def test_chunking_never_changes_the_result(ms, cuts):
    stream = b"".join(encode(m) for m in ms) + b"\x00\x13\x37" + b"".join(encode(m) for m in ms)
    whole, pieces = Decoder(), Decoder()
    a = whole.feed(stream)
    b = feed_in_chunks(pieces, stream, cuts)
    assert a == b and whole.stats == pieces.stats
    assert len(a) == 2 * len(ms)


def test_a_long_run_without_delimiters_is_dropped_and_parsing_resumes():
    good = encode(DataMessage(9, 0, 0, 1, (0.1, 0.2, 0.3, 0.4)))
    d = Decoder()
    junk = bytes(np.random.default_rng(0).integers(1, 256, 1_000_000, dtype=np.uint8))
    for i in range(0, len(junk), 4096):
        assert d.feed(junk[i : i + 4096]) == []
        assert d.pending <= MAX_ENCODED
    assert d.stats.oversize == 1
    out = d.feed(good)
    assert len(out) == 1 and out[0].creator == 9
    assert d.stats.corrupt == 0  # the junk's tail, up to good's leading delimiter, was skipped uncounted


def test_bit_flips_are_always_caught_on_a_stream_of_data_frames():
    rng = np.random.default_rng(5)
    frames = [encode(DataMessage(3, 1, 0, i, tuple(rng.uniform(-1, 1, 4)))) for i in range(2000)]
    damaged = []
    for i, f in enumerate(frames):
        if i % 7 == 3:
            b = bytearray(f)
            for bit in rng.choice(8 * len(f), size=int(rng.integers(1, 4)), replace=False):
                b[bit // 8] ^= 1 << (bit % 8)
            f = bytes(b)
        damaged.append(f)
    d = Decoder()
    out = d.feed(b"".join(damaged))
    seqs = {m.seq for m in out}
    assert seqs == {i for i in range(2000) if i % 7 != 3}
    assert d.stats.frames == len(seqs) and d.stats.corrupt >= 2000 // 7
