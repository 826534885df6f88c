"""The downsampler's wire protocol on the host: framing, CRC, layouts, and a parser that
survives anything (hypothesis feeds it random bytes and damaged streams)."""

from __future__ import annotations

import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mousedom.sources import adns_protocol as P

FUZZ = settings(
    max_examples=300, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)

# Any number of frames a packet can sum (K up to 255, or more when the UART was busy),
# with counts up to what that many frames can hold: the plausibility limit scales with
# the frames, so the strategy must vary them.
motions = st.integers(1, 0xFFFF).flatmap(
    lambda frames: st.builds(
        P.Motion,
        seq=st.integers(0, 0xFFFF),
        t_us=st.integers(0, 0xFFFFFFFF),
        dx=st.integers(-128 * P.DRAIN_MAX_READS * frames, 128 * P.DRAIN_MAX_READS * frames),
        dy=st.integers(-128 * P.DRAIN_MAX_READS * frames, 128 * P.DRAIN_MAX_READS * frames),
        frames=st.just(frames),
        squal_min=st.integers(0, 255),
        flags=st.integers(0, P.FLAGS_KNOWN),
    )
)
statuses = st.builds(
    P.Status,
    seq=st.integers(0, 0xFFFF),
    t_us=st.integers(0, 0xFFFFFFFF),
    state=st.sampled_from([0, 1, 2]),
    reason=st.integers(0, 4),
    product_id=st.integers(0, 255),
    config_bits=st.integers(0, 255),
    k=st.integers(1, 255),
    cpi=st.sampled_from([400, 1600]),
    poll_us=st.integers(1, 0xFFFF),
    overflows=st.integers(0, 0xFFFF),
    rx_errors=st.integers(0, 0xFFFF),
    retries=st.integers(0, 0xFFFF),
)
packets = st.one_of(motions, statuses)


def test_crc_check_value():
    """CRC-16/CCITT-FALSE catalogue check value, the same the firmware's unit test uses."""
    assert P.crc16(b"123456789") == 0x29B1
    assert P.crc16(b"") == 0xFFFF


@given(st.binary(max_size=64))
def test_crc_matches_the_firmware_algorithm(data):
    assert P.crc16(data) == P.crc16_bitwise(data)


@given(st.binary(max_size=600))
def test_cobs_roundtrip(data):
    enc = P.cobs_encode(data)
    assert 0 not in enc
    assert P.cobs_decode(enc) == data


def test_cobs_rejects_broken_groups():
    with pytest.raises(ValueError):
        P.cobs_decode(bytes([5, 1, 2]))  # group promises 4 bytes, has 2
    with pytest.raises(ValueError):
        P.cobs_decode(bytes([3, 0, 1]))


def test_motion_layout_matches_firmware():
    """The byte offsets of firmware/src/proto.c, checked on a hand-built body."""
    body = bytes([P.PKT_MOTION]) + struct.pack("<HIiiHBB", 7, 1000, -5, 300, 12, 40, 0x11)
    wire = P.frame(body)
    (p,) = P.Parser().feed(wire)
    assert p == P.Motion(7, 1000, -5, 300, 12, 40, 0x11)
    assert P.encode_packet(p) == wire
    assert len(wire) <= 26  # PROTO_MAX_WIRE


def test_commands_roundtrip_and_validation():
    data = (
        P.encode_command(P.CMD_SET_K, 5)
        + P.encode_command(P.CMD_SET_CPI, 400)
        + P.encode_command(P.CMD_GET_STATUS)
        + P.encode_command(P.CMD_GET_VERSION)
    )
    assert P.parse_commands(data) == [
        (P.CMD_SET_K, 5),
        (P.CMD_SET_CPI, 400),
        (P.CMD_GET_STATUS, None),
        (P.CMD_GET_VERSION, None),
    ]
    for bad in [(P.CMD_SET_K, 0), (P.CMD_SET_K, 256), (P.CMD_SET_CPI, 800), (0x99, None)]:
        with pytest.raises(ValueError):
            P.encode_command(*bad)


def test_parser_stamps_and_splits_anywhere():
    wire = b"".join(P.encode_packet(P.Motion(i, i * 15000, i, -i, 12, 80, 0)) for i in range(5))
    parser = P.Parser()
    got = []
    for i in range(0, len(wire), 7):
        got += parser.feed(wire[i : i + 7], host_t=float(i))
    assert [p.seq for p in got] == [0, 1, 2, 3, 4]
    assert all(p.host_t is not None for p in got)
    assert parser.stats.packets == 5 and parser.stats.lost_seq == 0


def test_sequence_gaps_and_reboot():
    parser = P.Parser()
    seqs = [10, 11, 14, 15, 0, 1, 3]  # 12, 13 lost; reboot; 2 lost
    wire = b"".join(P.encode_packet(P.Motion(s, 0, 0, 0, 12, 80, 0)) for s in seqs)
    parser.feed(wire)
    assert parser.stats.lost_seq == 3
    assert parser.stats.reboots == 1


def test_sequence_wraps_without_loss():
    parser = P.Parser()
    wire = b"".join(
        P.encode_packet(P.Motion(s % 65536, 0, 0, 0, 12, 80, 0)) for s in range(65534, 65539)
    )
    parser.feed(wire)
    assert parser.stats.lost_seq == 0 and parser.stats.reboots == 0


def test_overlong_garbage_resyncs():
    good = P.encode_packet(P.Motion(1, 2, 3, 4, 12, 80, 0))
    parser = P.Parser()
    got = parser.feed(bytes(range(1, 200)) + b"\0" + good)
    assert len(got) == 1
    assert parser.stats.resyncs == 1 and parser.stats.discarded_bytes == 199


def test_crc_error_counted():
    wire = bytearray(P.encode_packet(P.Motion(1, 2, 3, 4, 12, 80, 0)))
    i = next(i for i in range(3, len(wire) - 1) if wire[i] not in (0x00, 0x01))
    wire[i] ^= 0x01  # still a non-zero byte: framing intact, payload damaged
    parser = P.Parser()
    assert parser.feed(bytes(wire)) == []
    assert parser.stats.crc_errors == 1


def test_impossible_values_refused_even_with_good_crc():
    for p in [
        P.Motion(1, 0, 0, 0, 0, 80, 0),  # zero frames
        P.Motion(1, 0, 10**6, 0, 12, 80, 0),  # more than 8 full-scale reads per frame
        P.Motion(1, 0, 0, 0, 12, 80, 0x80),  # unknown flag
        P.Status(1, 0, 9, 0, 0x17, 0x19, 12, 1600, 1250, 0, 0, 0),  # unknown state
        P.Status(1, 0, 1, 0, 0x17, 0x19, 12, 800, 1250, 0, 0, 0),  # impossible CPI
    ]:
        parser = P.Parser()
        assert parser.feed(P.encode_packet(p)) == []
        assert parser.stats.bad_frames == 1


@FUZZ
@given(st.binary(max_size=2000), st.integers(1, 64))
def test_random_bytes_never_crash(data, chunk):
    """Any input: no exception, and every accepted packet is a frame that was really
    in the input, byte for byte (its encoding appears there)."""
    parser = P.Parser()
    got = []
    for i in range(0, len(data), chunk):
        got += parser.feed(data[i : i + chunk], host_t=0.0)
    for p in got:
        assert P.encode_packet(p)[:-1] in data
    s = parser.stats
    assert s.bytes == len(data)


@FUZZ
@given(
    st.lists(packets, min_size=1, max_size=20),
    st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), max_size=8),
)
def test_damaged_stream_loses_only_damaged_frames(pkts, hits):
    """Byte substitutions: no packet that was not sent comes out, and every frame whose
    bytes and both delimiters were untouched is recovered (the parser resyncs)."""
    frames = [P.encode_packet(p) for p in pkts]
    wire = bytearray(b"".join(frames))
    touched = set()
    for pos, xor in hits:
        pos %= len(wire)
        wire[pos] ^= xor
        touched.add(pos)
    got = P.Parser().feed(bytes(wire))
    for p in got:
        assert p in pkts
    start = 0
    expected = []
    for p, f in zip(pkts, frames, strict=True):
        span = range(start - 1 if start else 0, start + len(f))
        if not touched.intersection(span):
            expected.append(p)
        start += len(f)
    for p in expected:
        assert p in got


@FUZZ
@given(
    st.lists(packets, min_size=1, max_size=12),
    st.lists(st.tuples(st.integers(0, 10**6), st.binary(min_size=0, max_size=5)), max_size=5),
    st.lists(st.integers(0, 10**6), max_size=5),
)
def test_inserted_and_deleted_bytes_never_yield_a_bad_packet(pkts, inserts, deletes):
    wire = bytearray(b"".join(P.encode_packet(p) for p in pkts))
    for pos in deletes:
        if wire:
            del wire[pos % len(wire)]
    for pos, blob in inserts:
        at = pos % (len(wire) + 1)
        wire[at:at] = blob
    parser = P.Parser()
    for p in parser.feed(bytes(wire)):
        assert p in pkts


@pytest.mark.parametrize("frames", [1, 12, 255, 4000])
def test_the_plausibility_limit_scales_with_the_frames(frames):
    """A packet may sum at most 128 counts per motion read, DRAIN_MAX_READS reads per
    frame: exactly at that limit it is accepted, one count past it refused (hand-computed:
    128 * 8 * frames)."""
    limit = 128 * 8 * frames
    for dx, dy, ok in ((limit, 0, True), (0, -limit, True), (limit + 1, 0, False),
                       (0, -limit - 1, False)):  # fmt: skip
        parser = P.Parser()
        got = parser.feed(P.encode_packet(P.Motion(0, 1000, dx, dy, frames, 80, 0)))
        assert (len(got) == 1) == ok and parser.stats.bad_frames == (0 if ok else 1)
