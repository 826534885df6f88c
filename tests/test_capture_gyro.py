"""Issue 30 item 4: a gyro's samples in the native capture format (an "iio" device and its
RATE chunks): bit-exact round trips, the version rules, hostile bytes with clear errors."""

from __future__ import annotations

import json
import math
import struct
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mousedom.capture import Batch, CaptureError, DeviceInfo, NativeWriter, open_capture
from mousedom.capture.native import CHUNK, GYRO_VERSION, MAGIC, MOTION, RATE, VERSION, ZLIB
from mousedom.capture.native_format import MAX_RATE, chunk_crc

MOUSE = DeviceInfo(name="left mouse", mouse="left", rel_xy=True)
GYRO = DeviceInfo(
    name="mpu6050",
    kind="iio",
    rel_xy=False,
    extra={"node": "/dev/iio:device0", "axis": "z", "sign": -1, "scale": 0.001064724},
)


def read_all(path) -> tuple[object, list[Batch]]:
    cap = open_capture(str(path))
    batches = [b for feed in cap.feeds() for b in feed.batches]
    return cap, batches


def rates_of(batches: list[Batch]) -> tuple[np.ndarray, np.ndarray]:
    g = [r for b in batches for r in b.gyro]
    return np.concatenate([r.t for r in g] or [[]]), np.concatenate([r.rate for r in g] or [[]])


def _samples(seed: int, n: int, t0: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return t0 + np.cumsum(rng.uniform(0.001, 0.01, n)), rng.normal(0.0, 2.0, n)


# ------------------------------------------------------------------ round trips


@pytest.mark.parametrize("compress", [True, False])
def test_mice_and_gyro_round_trip_bit_exact(tmp_path, compress):
    p = tmp_path / "g.mdcap"
    t, rate = _samples(1, 5000)
    mt = t[::3] + 1e-4
    with NativeWriter(p, [MOUSE, GYRO], compress=compress, chunk_reports=700) as w:
        for a in range(0, 5000, 999):
            w.gyro(1, t[a : a + 999], rate[a : a + 999])
            sel = (mt >= t[a]) & (mt < t[min(a + 999, 4999)])
            w.motion(0, mt[sel], np.ones(sel.sum(), int), -np.ones(sel.sum(), int))
            w.sync(t[min(a + 998, 4999)])
    assert w.samples_written == 5000
    cap, batches = read_all(p)
    assert cap.major == GYRO_VERSION[0] and cap.header["version"] == list(GYRO_VERSION)
    dev = cap.devices[1]
    assert (dev.kind, dev.name, dev.rel_xy, dev.extra) == ("iio", GYRO.name, False, GYRO.extra)
    got_t, got_rate = rates_of(batches)
    # bit for bit: no rounding anywhere on the way
    assert got_t.tobytes() == t.tobytes() and got_rate.tobytes() == rate.tobytes()
    assert cap.stats[1].reports == 5000 and cap.stats[1].first_t == t[0]
    assert cap.stats[1].net_x == cap.stats[1].net_y == 0
    assert cap.stats[0].reports == len(mt)
    assert cap.first_time() == t[0]  # a gyro's sample counts for the window grid's start


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(
    rates=st.lists(
        st.floats(min_value=-MAX_RATE, max_value=MAX_RATE, exclude_min=True, exclude_max=True,
                  allow_subnormal=True),
        min_size=0, max_size=300,
    ),
    gaps=st.lists(st.floats(min_value=0.0, max_value=1.0), min_size=300, max_size=300),
    start=st.floats(min_value=-1e9, max_value=1e9),
    chunk=st.integers(min_value=1, max_value=50),
    compress=st.booleans(),
)  # fmt: skip
def test_any_samples_round_trip_bit_exact(tmp_path, rates, gaps, start, chunk, compress):
    p = tmp_path / "h.mdcap"
    rate = np.array(rates, dtype=np.float64)
    t = start + np.cumsum(np.array(gaps[: len(rates)], dtype=np.float64))
    with NativeWriter(p, [GYRO], compress=compress, chunk_reports=chunk) as w:
        for a in range(0, len(t), 7):
            w.gyro(0, t[a : a + 7], rate[a : a + 7])
    _, batches = read_all(p)
    got_t, got_rate = rates_of(batches)
    assert got_t.tobytes() == t.tobytes() and got_rate.tobytes() == rate.tobytes()


# ------------------------------------------------------------------ versions


def test_a_file_without_gyro_stays_version_1_and_one_with_is_version_2(tmp_path):
    a, b = tmp_path / "a.mdcap", tmp_path / "b.mdcap"
    with NativeWriter(a, [MOUSE]) as w:
        w.motion(0, [1.0], [1], [0])
    with NativeWriter(b, [MOUSE, GYRO]) as w:
        w.gyro(1, [1.0], [0.5])
    # What a reader of 1.x checks first: the major version at byte offset 8; it refuses
    # 2.0 by name ("unknown native capture version 2.0 (this reader knows 1.x)").
    assert struct.unpack("<HH", a.read_bytes()[8:12]) == VERSION == (1, 0)
    assert struct.unpack("<HH", b.read_bytes()[8:12]) == GYRO_VERSION == (2, 1)
    n = struct.unpack("<I", a.read_bytes()[12:16])[0]
    assert json.loads(a.read_bytes()[16 : 16 + n])["version"] == [1, 0]


def _file(version: tuple[int, int], devices: list[dict], chunks: bytes = b"") -> bytes:
    body = json.dumps({"devices": devices, "time_base": "monotonic"}).encode()
    return (MAGIC + struct.pack("<HHI", *version, len(body)) + body
            + struct.pack("<I", zlib.crc32(body)) + chunks)  # fmt: skip


def _chunk(kind: int, source: int, count: int, payload: bytes, flags: int = 0) -> bytes:
    head = CHUNK.pack(b"MDCK", kind, flags, source, count, len(payload), 0)[:16]
    return head + struct.pack("<I", chunk_crc(head, payload)) + payload


def _rate_payload(t, rate) -> bytes:
    return np.asarray(t, "<f8").tobytes() + np.asarray(rate, "<f8").tobytes()


def test_a_version_1_file_cannot_hold_a_gyro(tmp_path):
    p = tmp_path / "v1.mdcap"
    p.write_bytes(_file((1, 0), [GYRO.as_dict()]))
    with pytest.raises(CaptureError, match=r"header: device 'mpu6050' is a gyro .*version 1.x"):
        open_capture(str(p))
    # and a version 1 file's evdev device with gyro samples: refused at the chunk
    p.write_bytes(_file((1, 0), [MOUSE.as_dict()], _chunk(RATE, 0, 1, _rate_payload([1.0], [0.1]))))
    with pytest.raises(CaptureError, match=r"byte offset \d+: gyro samples for device 'left "):
        read_all(p)


def test_old_files_still_read(tmp_path):
    """A 1.0 file as the writer made it before the gyro (the bundled demo): unchanged."""
    from importlib.resources import files

    demo = files("mousedom") / "data" / "demo-rig.mdcap"
    cap, batches = read_all(demo)
    assert cap.major == 1 and not any(b.gyro for b in batches)
    assert sum(s.reports for s in cap.stats) == 8968


# ------------------------------------------------------------------ hostile bytes


def _gyro_file(tmp_path, chunk: bytes, good_after: bool = False):
    p = tmp_path / "hostile.mdcap"
    after = _chunk(RATE, 0, 1, _rate_payload([9.0], [0.0])) if good_after else b""
    first = _chunk(RATE, 0, 2, _rate_payload([1.0, 1.5], [0.1, 0.2]))
    p.write_bytes(_file(GYRO_VERSION, [GYRO.as_dict()], first + chunk + after))
    return p, len(_file(GYRO_VERSION, [GYRO.as_dict()], first))


@pytest.mark.parametrize(
    ("payload", "count", "needle"),
    [
        (_rate_payload([2.0], [0.1])[:12], 1, "gyro chunk of 1 samples holds 12 bytes, not 16"),
        (_rate_payload([2.0, 3.0], [0.1, 0.2]), 3, "gyro chunk of 3 samples holds 32 bytes"),
        (_rate_payload([2.0], [math.nan]), 1, "gyro sample 0 has rate nan: not a rate"),
        (_rate_payload([2.0, 3.0], [0.0, -math.inf]), 2, "gyro sample 1 has rate -inf"),
        (_rate_payload([2.0], [2e6]), 1, "gyro sample 0 has rate 2000000.0"),
        (_rate_payload([math.inf], [0.0]), 1, "time out of range"),
        (_rate_payload([1e11], [0.0]), 1, "time out of range"),
        (_rate_payload([3.0, 2.0], [0.0, 0.0]), 2, "time goes backwards for device 'mpu6050'"),
        (_rate_payload([1.2], [0.0]), 1, "time goes backwards for device 'mpu6050'"),
    ],
)
def test_malformed_gyro_chunks_are_errors_at_their_offset(tmp_path, payload, count, needle):
    p, offset = _gyro_file(tmp_path, _chunk(RATE, 0, count, payload))
    with pytest.raises(CaptureError, match=rf"hostile.mdcap: byte offset {offset}: "):
        read_all(p)
    with pytest.raises(CaptureError, match=re_escape(needle)):
        read_all(p)


def re_escape(s: str) -> str:
    import re

    return re.escape(s)


def test_gyro_samples_for_a_mouse_and_motion_for_the_gyro_are_refused(tmp_path):
    p = tmp_path / "mixed.mdcap"
    motion = np.array([2.0], "<f8").tobytes() + np.array([1, 1], "<i4").tobytes()
    p.write_bytes(_file(GYRO_VERSION, [GYRO.as_dict()], _chunk(MOTION, 0, 1, motion)))
    with pytest.raises(CaptureError, match="motion reports for device 'mpu6050', which is of kind"):
        read_all(p)
    p.write_bytes(_file(GYRO_VERSION, [GYRO.as_dict(), MOUSE.as_dict()],
                        _chunk(RATE, 1, 1, _rate_payload([1.0], [0.0]))))  # fmt: skip
    with pytest.raises(CaptureError, match="gyro samples for device 'left mouse'"):
        read_all(p)


def test_a_torn_gyro_chunk_at_the_end_is_a_warning_and_one_before_good_data_an_error(tmp_path):
    whole = _chunk(RATE, 0, 2, _rate_payload([2.0, 2.5], [0.3, 0.4]))
    p, offset = _gyro_file(tmp_path, whole[:-5])
    cap, batches = read_all(p)
    t, _ = rates_of(batches)
    assert t.tolist() == [1.0, 1.5]
    assert cap.warnings and f"byte offset {offset}: chunk cut short; the last " in cap.warnings[0]
    assert "unfinished chunk" in cap.warnings[0]
    bad = bytearray(whole)
    bad[-1] ^= 1  # wrong CRC, good chunk after it
    p, offset = _gyro_file(tmp_path, bytes(bad), good_after=True)
    with pytest.raises(CaptureError, match=rf"byte offset {offset}: chunk CRC mismatch, and good"):
        read_all(p)


def test_an_oversized_or_bomb_gyro_chunk_is_refused(tmp_path):
    # a compressed RATE chunk that inflates past the 16 bytes per sample its count states
    packed = zlib.compress(b"\0" * 16 * 1000, 9)
    p, offset = _gyro_file(tmp_path, _chunk(RATE, 0, 10, packed, ZLIB))
    with pytest.raises(CaptureError, match=rf"byte offset {offset}: .*inflates past 160 bytes"):
        read_all(p)
    # a size past the format's bound: a malformed header, so the tail is torn
    head = CHUNK.pack(b"MDCK", RATE, 0, 0, 1, (64 << 20) + 1, 0)[:16]
    p, offset = _gyro_file(tmp_path, head + b"\0\0\0\0")
    cap, _ = read_all(p)
    assert f"byte offset {offset}: malformed chunk header" in cap.warnings[0]


def test_the_writer_refuses_what_the_reader_would(tmp_path):
    with NativeWriter(tmp_path / "w.mdcap", [MOUSE, GYRO]) as w:
        with pytest.raises(CaptureError, match="sample 1 of a batch has rate nan"):
            w.gyro(1, [1.0, 2.0], [0.0, math.nan])
        with pytest.raises(CaptureError, match="sample 0 of a batch has time inf"):
            w.gyro(1, [math.inf], [0.0])
        with pytest.raises(ValueError, match="is of kind 'iio': no motion reports"):
            w.motion(1, [1.0], [1], [1])
        with pytest.raises(ValueError, match="is of kind 'evdev': no gyro samples"):
            w.gyro(0, [1.0], [1.0])
        with pytest.raises(ValueError, match="one length"):
            w.gyro(1, [1.0, 2.0], [1.0])
