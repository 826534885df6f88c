"""The IIO record layout (mousedom.sources.iio_layout): type strings, offsets and decoding,
held against records packed as the kernel documents them (tests/iio_fakes.py), and against
hostile type strings and bytes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from iio_fakes import pack_records

from mousedom.sources.iio_layout import (
    MAX_RECORD_BYTES,
    Element,
    LayoutError,
    ScanType,
    decode_records,
    parse_scan_type,
    record_layout,
)


def layout_of(*types: str, indices: list[int] | None = None):
    idx = indices or list(range(len(types)))
    return record_layout(
        [Element(f"c{i}", i, parse_scan_type(t)) for i, t in zip(idx, types, strict=True)]
    )


@pytest.mark.parametrize(
    "text, want",
    [
        ("le:s16/16>>0", ScanType(False, True, 16, 16, 0, 1)),
        ("be:s16/16>>0", ScanType(True, True, 16, 16, 0, 1)),
        ("le:s12/16>>4", ScanType(False, True, 12, 16, 4, 1)),  # buffers.rst's example
        ("le:u32/32X4>>0", ScanType(False, False, 32, 32, 0, 4)),  # a quaternion
        ("le:s64/64>>0", ScanType(False, True, 64, 64, 0, 1)),
        ("be:u8/8", ScanType(True, False, 8, 8, 0, 1)),  # no shift written
        ("le:s24/32>>8\n", ScanType(False, True, 24, 32, 8, 1)),  # sysfs ends with \n
        ("le:s16/16X0>>0", ScanType(False, True, 16, 16, 0, 1)),  # a repeat of 0 is 1
    ],
)
def test_parse_scan_type(text, want):
    assert parse_scan_type(text) == want
    assert want.storage_bytes == want.storagebits // 8 * want.repeat


@pytest.mark.parametrize(
    "text, words",
    [
        ("", "is not a scan type"),
        ("le:s16/16>>", "is not a scan type"),
        ("me:s16/16>>0", "is not a scan type"),
        ("le:f32/32>>0", "is not a scan type"),  # floats: not in the ABI this reads
        ("le:s16/12>>0", "storage of 12 bits"),
        ("le:s17/16>>0", "17 valid bits in 16"),
        ("le:s0/16>>0", "0 valid bits"),
        ("le:s12/16>>5", "overrun 16"),
        ("le:s16/16X3>>0", "not a power of two"),
        ("le:s16/16X100>>0", "at most 64"),
        ("le:s16/16>>0 garbage", "is not a scan type"),
        ("le:s" + "9" * 500 + "/16", "is not a scan type"),
    ],
)
def test_malformed_types_name_the_file(text, words):
    where = "/sys/bus/iio/devices/iio:device0/scan_elements/in_anglvel_z_type"
    with pytest.raises(LayoutError, match=words) as e:
        parse_scan_type(text, where)
    assert str(e.value).startswith(where + ": ")
    assert len(str(e.value)) < 300  # a hostile file is not echoed whole


@pytest.mark.parametrize(
    "types, offsets, size",
    [
        (("le:s16/16>>0", "le:s64/64>>0"), [0, 8], 16),  # s16 + timestamp: 6 bytes padding
        (("be:s16/16>>0",) * 3 + ("le:s64/64>>0",), [0, 2, 4, 8], 16),
        (("le:u8/8>>0", "le:s32/32>>0"), [0, 4], 8),
        (("le:s64/64>>0", "le:s16/16>>0"), [0, 8], 16),  # padded to the largest at the end
        (("le:s16/16>>0", "le:u32/32X4>>0", "le:s16/16>>0"), [0, 16, 32], 48),
        (("le:u8/8>>0",) * 3, [0, 1, 2], 3),
    ],
)
def test_record_layout_aligns_as_the_kernel(types, offsets, size):
    layout = layout_of(*types)
    assert [f.offset for f in layout.fields] == offsets
    assert layout.size == size


@pytest.mark.parametrize("ts_index", [7, 5, 0])
def test_layout_follows_scan_index_with_the_timestamp_last(ts_index):
    """Channels in scan-index order, not the order given; the timestamp last whatever its
    index: a driver may register its soft timestamp at 0 (IIO_CHAN_SOFT_TIMESTAMP(0)), and
    the kernel writes it into the record's last 8 bytes (iio_push_to_buffers_with_timestamp)."""
    z = Element("in_anglvel_z", 6, parse_scan_type("be:s16/16>>0"))
    ts = Element("in_timestamp", ts_index, parse_scan_type("le:s64/64>>0"))
    x = Element("in_anglvel_x", 4, parse_scan_type("be:s16/16>>0"))
    layout = record_layout([ts, z, x])
    assert layout.names() == ("in_anglvel_x", "in_anglvel_z", "in_timestamp")
    assert layout.field("in_timestamp").offset == 8 and layout.size == 16
    data = pack_records([(ts_index, "le:s64/64>>0"), (6, "be:s16/16>>0"), (4, "be:s16/16>>0")],
                        [(5_000_000_000_000, 1234, -7)], timestamp=0)  # fmt: skip
    d = decode_records(data, layout)
    assert d.columns["in_timestamp"].tolist() == [5_000_000_000_000]
    assert d.columns["in_anglvel_z"].tolist() == [1234]
    assert d.columns["in_anglvel_x"].tolist() == [-7]


def test_layout_refuses_what_no_kernel_publishes():
    with pytest.raises(LayoutError, match="no scan element is enabled"):
        record_layout([])
    a = Element("a", 3, parse_scan_type("le:s16/16"))
    with pytest.raises(LayoutError, match="a and b have the same scan index 3"):
        record_layout([a, a._replace(name="b")])
    many = [Element(f"c{i}", i, parse_scan_type("le:u64/64X64")) for i in range(9)]
    with pytest.raises(LayoutError, match=f"at most {MAX_RECORD_BYTES}"):
        record_layout(many)


def test_buffers_rst_example_12_bits_shifted_by_4():
    # le:s12/16>>4: D3..D0 in the low byte's upper nibble, D11..D4 in the high byte.
    layout = layout_of("le:s12/16>>4")
    data = bytes([0x50, 0x23, 0xF0, 0xFF, 0x0F, 0x80])  # 0x235, -1, -2048 with junk below
    decoded = decode_records(data, layout)
    assert decoded.columns["c0"].tolist() == [0x235, -1, -2048]


def test_decode_keeps_the_partial_tail_and_never_reads_past_it():
    layout = layout_of("be:s16/16>>0", "le:s64/64>>0")
    data = pack_records([(0, "be:s16/16>>0"), (1, "le:s64/64>>0")], [(-5, 10), (7, 20)])
    for cut in range(len(data) + 1):
        d = decode_records(data[:cut], layout)
        assert d.records == cut // 16 and d.rest == data[d.records * 16 : cut]
        assert len(d.columns["c0"]) == d.records
    whole = decode_records(data, layout)
    assert whole.columns["c0"].tolist() == [-5, 7] and whole.columns["c1"].tolist() == [10, 20]
    assert whole.columns["c0"].dtype == np.int64


def test_extremes_of_each_width():
    kinds = ["le:s64/64>>0", "be:u64/64>>0", "le:s8/8>>0", "be:u32/32>>0"]
    rows = [(-(2**63), 2**64 - 1, -128, 2**32 - 1), (2**63 - 1, 0, 127, 0)]
    data = pack_records(list(enumerate(kinds)), rows)
    d = decode_records(data, layout_of(*kinds))
    assert d.columns["c0"].tolist() == [-(2**63), 2**63 - 1]
    assert d.columns["c1"].dtype == np.uint64 and d.columns["c1"].tolist() == [2**64 - 1, 0]
    assert d.columns["c2"].tolist() == [-128, 127] and d.columns["c3"].tolist() == [2**32 - 1, 0]


# ------------------------------------------------------------------ properties

KIND = st.builds(
    lambda order, sign, storage, real_frac, shift_frac, repeat: _kind(
        order, sign, storage, real_frac, shift_frac, repeat
    ),
    st.sampled_from(["le", "be"]),
    st.sampled_from(["s", "u"]),
    st.sampled_from([8, 16, 32, 64]),
    st.floats(0, 1),
    st.floats(0, 1),
    st.sampled_from([1, 1, 1, 2, 4]),
)


def _kind(order, sign, storage, real_frac, shift_frac, repeat) -> str:
    real = max(1, round(real_frac * storage))
    shift = round(shift_frac * (storage - real))
    rep = f"X{repeat}" if repeat > 1 else ""
    return f"{order}:{sign}{real}/{storage}{rep}>>{shift}"


def _values(kind: str):
    t = parse_scan_type(kind)
    lo, hi = (-(2 ** (t.realbits - 1)), 2 ** (t.realbits - 1) - 1) if t.signed else (
        0, 2**t.realbits - 1)  # fmt: skip
    return st.lists(st.integers(lo, hi), min_size=t.repeat, max_size=t.repeat)


@settings(max_examples=150, deadline=None)
@given(st.lists(KIND, min_size=1, max_size=6), st.data(), st.booleans())
def test_any_layout_round_trips(kinds, data, junk):
    """Any channels at any scan indices, and a timestamp at any of them or none (the
    kernel packs it last whatever its index: a driver may register it at 0)."""
    stamped = data.draw(st.booleans())
    if stamped:
        kinds = [*kinds, "le:s64/64>>0"]
    indices = data.draw(st.permutations(range(0, 2 * len(kinds), 2)))
    names = [f"c{i}" for i in indices]
    if stamped:
        names[-1] = "in_timestamp"
    n = data.draw(st.integers(0, 5))
    rows = []
    for _ in range(n):
        row = []
        for k in kinds:
            row += data.draw(_values(k))
        rows.append(row)
    packed = pack_records(list(zip(indices, kinds, strict=True)), rows, junk,
                          timestamp=len(kinds) - 1 if stamped else None)  # fmt: skip
    layout = record_layout([Element(name, i, parse_scan_type(k))
                            for name, i, k in zip(names, indices, kinds, strict=True)])  # fmt: skip
    if stamped:
        assert layout.fields[-1].element.name == "in_timestamp"
    assert len(packed) == n * layout.size
    tail = data.draw(st.binary(max_size=layout.size - 1))
    d = decode_records(packed + tail, layout)
    assert d.records == n and d.rest == tail
    k = 0
    for name, kind in zip(names, kinds, strict=True):
        rep = parse_scan_type(kind).repeat
        got = d.columns[name]
        want = [r[k : k + rep] for r in rows]
        assert (got.tolist() if rep > 1 else [[v] for v in got.tolist()]) == want
        k += rep


@settings(max_examples=200, deadline=None)
@given(st.lists(KIND, min_size=1, max_size=4), st.binary(max_size=300), st.integers(1, 50))
def test_any_bytes_decode_in_any_chunks_the_same(kinds, blob, cut):
    layout = layout_of(*kinds)
    whole = decode_records(blob, layout)
    assert whole.records == len(blob) // layout.size
    # Fed in pieces with the tail carried over: the same values.
    rest, parts = b"", []
    for i in range(0, len(blob), cut):
        d = decode_records(rest + blob[i : i + cut], layout)
        rest = d.rest
        parts.append(d.columns["c0"])
    joined = np.concatenate(parts) if parts else whole.columns["c0"]
    assert joined.tolist() == whole.columns["c0"].tolist() and rest == whole.rest


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.text(max_size=40), st.from_regex(
    r"(be|le|xx):[sufx]\d{0,3}/\d{0,3}(X\d{0,4})?(>>\d{0,3})?", fullmatch=True)))  # fmt: skip
def test_any_type_string_parses_or_says_why(text):
    try:
        t = parse_scan_type(text, "f_type")
    except LayoutError as e:
        assert str(e).startswith("f_type: ")
        return
    assert t.storagebits in (8, 16, 32, 64) and 1 <= t.realbits <= t.storagebits
    assert t.shift + t.realbits <= t.storagebits
