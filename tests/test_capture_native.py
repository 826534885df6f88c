"""Native capture format: round trips, crash safety, corruption, versions, fuzzing."""

from __future__ import annotations

import json
import math
import struct
import zlib

import numpy as np
import pytest
from capture_helpers import drain, one_mouse_config
from conftest import run_mousedom
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mousedom.capture import CaptureError, DeviceInfo, DeviceStats, NativeWriter, open_capture
from mousedom.capture.native import CHUNK, MAGIC, NativeCapture
from mousedom.errors import UserError

DEVICES = [
    DeviceInfo(name="left mouse", vendor=0x46D, product=0xC077, mouse="left", rel_xy=True),
    DeviceInfo(name="right mouse", vendor=0x46D, product=0xC078, mouse="right", rel_xy=True),
    DeviceInfo(name="adns", kind="serial", mouse="floor", extra={"port": "/dev/ttyUSB0"}),
]


def _reports(seed: int, n: int, t0: float = 0.0):
    rng = np.random.default_rng(seed)
    t = t0 + np.cumsum(rng.uniform(0.0005, 0.01, n))
    return t, rng.integers(-(2**20), 2**20, n), rng.integers(-50, 50, n)


def _write(path, compress=True, chunk_reports=700, syncs=True):
    left = _reports(1, 3000)
    right = _reports(2, 2500)
    serial = [(0.01 * k, bytes([k % 256]) * (k % 7 + 1)) for k in range(300)]
    with NativeWriter(
        path,
        DEVICES,
        config_text="rate_hz: 100\n",
        time_base="monotonic",
        compress=compress,
        chunk_reports=chunk_reports,
    ) as w:
        for a in range(0, 3000, 500):
            w.motion(0, *(x[a : a + 500] for x in left))
            w.motion(1, *(x[a : a + 500] for x in right))
            w.serial_many(
                2,
                [s[0] for s in serial[a // 10 : a // 10 + 50]],
                [s[1] for s in serial[a // 10 : a // 10 + 50]],
            )
            if syncs:
                w.sync(min(left[0][min(a + 499, 2999)], right[0][min(a + 499, 2499)]))
        w.note(0, DeviceStats(skipped=12, dropped_frames=1, lost_x=3))
    return left, right, serial


@pytest.mark.parametrize("compress", [True, False])
def test_round_trip_every_source(tmp_path, compress):
    p = tmp_path / "rig.mdcap"
    left, right, serial = _write(p, compress=compress)
    cap = drain(p)
    assert isinstance(cap, NativeCapture)
    assert [d.name for d in cap.devices] == [d.name for d in DEVICES]
    assert cap.devices[2].kind == "serial" and cap.devices[2].extra == {"port": "/dev/ttyUSB0"}
    assert cap.config_text == "rate_hz: 100\n"
    assert cap.time_base == "monotonic"
    for dev, want in ((0, left), (1, right)):
        for got, exp in zip(cap.motion[dev], want, strict=True):
            np.testing.assert_array_equal(got, exp)
    assert cap.stats[0].skipped == 12 and cap.stats[0].lost_x == 3
    assert cap.stats[2].serial_bytes == sum(len(s[1]) for s in serial[:300])
    assert not cap.warnings


def test_serial_chunks_round_trip(tmp_path):
    p = tmp_path / "s.mdcap"
    _, _, serial = _write(p)
    cap = open_capture(p)
    pieces, times = [], []
    for f in cap.feeds():
        for b in f.batches:
            for s in b.serial:
                pieces += s.data
                times += s.t.tolist()
    assert pieces == [s[1] for s in serial]
    assert times == [s[0] for s in serial]


def test_batches_follow_sync_points(tmp_path):
    p = tmp_path / "w.mdcap"
    _write(p)
    marks = [b.complete for f in open_capture(p).feeds() for b in f.batches]
    finite = [m for m in marks if math.isfinite(m)]
    assert len(finite) == 6 and finite == sorted(finite) and marks[-1] == math.inf


def test_every_truncation_point_keeps_all_whole_chunks(tmp_path):
    """A crash can cut the file anywhere: all chunks before the cut stay readable."""
    p = tmp_path / "full.mdcap"
    left, right, _ = _write(p, chunk_reports=400)
    data = p.read_bytes()
    # Chunk boundaries, to know how many reports each prefix must hold.
    offsets, counts = [], []
    cap = open_capture(p)
    for kind, _source, count, _payload, off in cap._chunks(check_tail=True):
        offsets.append(off)
        counts.append(count if kind == 1 else 0)
    ends = offsets[1:] + [len(data)]
    header_end = offsets[0]
    rng = np.random.default_rng(5)
    cuts = sorted(set(rng.integers(header_end, len(data), 60).tolist()) | set(ends[:5]))
    for cut in cuts:
        q = tmp_path / "cut.mdcap"
        q.write_bytes(data[:cut])
        c = drain(q)
        whole = sum(n for n, e in zip(counts, ends, strict=True) if e <= cut)
        got = sum(len(m[0]) for m in c.motion.values())
        assert got == whole, cut
        torn = cut not in ends
        assert bool(c.warnings) == torn
        if torn:
            assert "unfinished chunk" in c.warnings[0]


def test_corrupted_chunk_in_the_middle_is_an_error(tmp_path):
    p = tmp_path / "c.mdcap"
    _write(p)
    data = bytearray(p.read_bytes())
    cap = open_capture(p)
    first = next(cap._chunks(check_tail=True))[4]
    data[first + CHUNK.size + 5] ^= 0xFF  # flip a payload byte of the first chunk
    p.write_bytes(bytes(data))
    with pytest.raises(UserError, match=r"byte offset \d+: chunk CRC mismatch.*corrupted"):
        drain(p)


def test_unknown_version_and_bad_header(tmp_path):
    p = tmp_path / "v.mdcap"
    body = json.dumps({"devices": [], "time_base": "relative"}).encode()
    p.write_bytes(
        MAGIC + struct.pack("<HHI", 3, 0, len(body)) + body + struct.pack("<I", zlib.crc32(body))
    )  # 2.0 is a file with a gyro (tests/test_capture_gyro.py)
    with pytest.raises(UserError, match=r"unknown native capture version 3.0 .*knows 1.x and 2.x"):
        open_capture(p)
    p.write_bytes(MAGIC + struct.pack("<HHI", 1, 0, len(body)) + body + b"\0\0\0\0")
    with pytest.raises(UserError, match="header CRC mismatch"):
        open_capture(p)
    p.write_bytes(MAGIC + b"\1\0")
    with pytest.raises(UserError, match="header cut short"):
        open_capture(p)


def test_time_going_backwards_is_an_error(tmp_path):
    p = tmp_path / "b.mdcap"
    with NativeWriter(p, DEVICES[:1]) as w:
        w.motion(0, [1.0, 2.0], [1, 1], [0, 0])
        w.flush()
        w.motion(0, [1.5], [1], [0])
    with pytest.raises(UserError, match="time goes backwards"):
        drain(p)


def test_chunk_for_unknown_source(tmp_path):
    p = tmp_path / "u.mdcap"
    with NativeWriter(p, DEVICES[:1]) as w:
        w.motion(0, [1.0], [1], [0])
        w.flush()
        w._chunk(1, 7, 1, np.array([2.0]).tobytes() + b"\1\0\0\0\0\0\0\0")
    with pytest.raises(UserError, match="source 7"):
        drain(p)


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300), st.integers(0, 2000))
def test_fuzz_damaged_files_never_crash(tmp_path, junk, at):
    p = tmp_path / "f.mdcap"
    if not (tmp_path / "base.mdcap").exists():
        _write(tmp_path / "base.mdcap", chunk_reports=300)
    base = (tmp_path / "base.mdcap").read_bytes()
    at = min(at, len(base))
    p.write_bytes(base[:at] + junk + base[at + len(junk) :])
    try:
        drain(p)
    except UserError as e:
        assert "f.mdcap" in str(e)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_times_are_refused_by_the_writer_too(tmp_path, bad):
    """The reader refuses a chunk with a non-finite time; the writer must not make one
    (the file would hold a chunk no one can read back)."""
    w = NativeWriter(tmp_path / "x.mdcap", [DeviceInfo(name="odd", mouse="m", rel_xy=True)])
    w.motion(0, [0.1], np.array([1]), np.array([2]))
    with pytest.raises(CaptureError, match=r"'odd': report 1 of a batch has time"):
        w.motion(0, [0.2, bad], np.array([1, 1]), np.array([0, 0]))
    w.close()
    cap = drain(tmp_path / "x.mdcap")
    assert cap.motion[0][0].tolist() == [0.1]


def test_counts_beyond_32_bits_are_refused_not_wrapped(tmp_path):
    """A frame's summed counts can exceed the i4 columns; wrapping them lost 2**32 counts
    silently (evemu -> convert -> replay gave 3 instead of 4294967299)."""
    w = NativeWriter(tmp_path / "x.mdcap", [DeviceInfo(name="big", mouse="m", rel_xy=True)])
    w.motion(0, [0.1, 0.2], np.array([2**31 - 1, -(2**31)]), np.array([0, 0]))  # the limits
    with pytest.raises(CaptureError, match=r"'big'.*t=0\.300000.*\(4294967294, 0\).*32 bits"):
        w.motion(0, [0.25, 0.3], np.array([-(2**31), 2**32 - 2]), np.array([0, 0]))
    w.close()
    cap = drain(tmp_path / "x.mdcap")
    assert cap.motion[0][1].tolist() == [2**31 - 1, -(2**31)]


def test_convert_refuses_a_frame_beyond_32_bits(tmp_path):
    ev = tmp_path / "sum.events"
    ev.write_text(
        "E: 0.010000 0002 0000 2147483647\nE: 0.010000 0002 0000 2147483647\n"
        "E: 0.010000 0000 0000 0000\nE: 0.020000 0002 0000 5\nE: 0.020000 0000 0000 0000\n"
    )
    out = tmp_path / "sum.mdcap"
    proc = run_mousedom("convert", "--capture", f"m={ev}", "-o", str(out))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "sum.events" in proc.stderr and "32 bits" in proc.stderr
    assert not out.exists()


KILLED_WRITER = r"""
import sys, time
import numpy as np
from mousedom.capture import DeviceInfo, NativeWriter

w = NativeWriter(sys.argv[1], [DeviceInfo(name="m", mouse="m", rel_xy=True)],
                 time_base="monotonic", chunk_reports=1000)
k = 0
while True:  # 100 reports per sync, like a recorder flushing every 100 ms at 1 kHz
    t = (k + np.arange(100)) * 1e-3
    w.motion(0, t, (k + np.arange(100)) % 7 - 3, np.ones(100, dtype=np.int64))
    w.sync(t[-1])
    k += 100
    print(k, flush=True)
    if k >= 20000:
        time.sleep(60)  # stay alive until killed
"""


def test_a_writer_killed_mid_recording_leaves_every_synced_report(tmp_path):
    """A real recording process gets SIGKILL: every report it had synced is read back,
    values intact, and a torn tail (if the kill hit a write) is only warned about."""
    import os
    import signal
    import subprocess
    import sys

    from conftest import mousedom_env

    p = tmp_path / "killed.mdcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", KILLED_WRITER, str(p)],
        stdout=subprocess.PIPE,
        text=True,
        env=mousedom_env(),
    )
    synced = 0
    for line in proc.stdout:
        synced = int(line)
        if synced >= 5000:  # mid-recording
            break
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    cap = drain(p)
    t, dx, dy = cap.motion[0]
    assert len(t) >= synced and len(t) % 100 == 0
    k = np.arange(len(t))
    np.testing.assert_array_equal(dx, k % 7 - 3)
    np.testing.assert_array_equal(dy, np.ones(len(t)))
    np.testing.assert_allclose(t, k * 1e-3, rtol=0, atol=1e-12)
    assert all("unfinished chunk" in w for w in cap.warnings)


def _raw_chunk(kind: int, source: int, count: int, payload: bytes) -> bytes:
    from mousedom.capture.native import _chunk_crc

    head = CHUNK.pack(b"MDCK", kind, 0, source, count, len(payload), 0)[:16]
    return head + struct.pack("<I", _chunk_crc(head, payload)) + payload


def _with_chunk(tmp_path, chunk: bytes):
    p = tmp_path / "h.mdcap"
    with NativeWriter(p, DEVICES[:1]) as w:
        w.motion(0, [1.0], [1], [0])
        w.flush()
        w._f.write(chunk)
    return p


@pytest.mark.parametrize(
    "chunk, words",
    [
        # MOTION whose count claims more reports than its payload holds (first_time read
        # past the payload: ValueError from numpy).
        (lambda: _raw_chunk(1, 0, 1000, np.array([2.0]).tobytes() + bytes(8)), "1000 reports"),
        (lambda: _raw_chunk(3, 0, 0, b'{"skipped": 1e999}'), "malformed note"),
        (lambda: _raw_chunk(3, 0, 0, b'{"skipped": -4}'), "malformed note"),
        (lambda: _raw_chunk(3, 0, 0, b"[" * 5000), "malformed note"),
        (lambda: _raw_chunk(4, 0, 1, struct.pack("<d", 1e300)), "malformed sync"),
        (lambda: _raw_chunk(1, 0, 1, struct.pack("<dii", 1e300, 1, 0)), "out of range"),
        (lambda: _raw_chunk(2, 0, 1, struct.pack("<dI", float("nan"), 1) + b"x"), "out of range"),
    ],
    ids=[
        "count>payload",
        "note-1e999",
        "note-negative",
        "note-deep",
        "sync-1e300",
        "motion-1e300",
        "serial-nan",
    ],  # fmt: skip
)
def test_hostile_chunks_are_one_clear_error(tmp_path, chunk, words):
    """Issue 11 item 5: each of these raised a traceback (or looped for ever in the
    window search); each is now a CaptureError naming the file and the byte offset."""
    p = _with_chunk(tmp_path, chunk())
    with pytest.raises(CaptureError, match=rf"h.mdcap: byte offset \d+: .*{words}"):
        cap = open_capture(p)
        cap.first_time()
        drain(p)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), 1e300])
def test_first_time_in_the_header_must_be_a_time(tmp_path, bad):
    p = tmp_path / "f.mdcap"
    with NativeWriter(p, DEVICES[:1], meta={"first_time": bad}) as w:
        w.motion(0, [1.0], [1], [0])
    with pytest.raises(CaptureError, match="first_time"):
        open_capture(p).first_time()


@pytest.mark.parametrize("bad", ["x", "0.1", True, False, [0.1], {"t": 0.1}])
def test_first_time_in_the_header_that_is_no_number_is_refused(tmp_path, bad):
    """A string was ignored (the first stamp used instead) and a bool read as 1.0 or 0.0:
    the key was not what the file says; refused naming file, byte offset and key."""
    p = tmp_path / "f.mdcap"
    with NativeWriter(p, DEVICES[:1], meta={"first_time": bad}) as w:
        w.motion(0, [1.0, 2.0], [1, 1], [0, 0])
    with pytest.raises(CaptureError, match=r"f.mdcap: byte offset 16: header: first_time .* "
                       "is not a number"):  # fmt: skip
        open_capture(p).first_time()
    with pytest.raises(CaptureError, match="first_time"):
        drain(p)


@pytest.mark.parametrize("first", [0.1, 0.0, -3.0, None])
@pytest.mark.parametrize("compress", [True, False])
def test_first_time_at_or_before_the_first_stamp_is_kept(tmp_path, first, compress):
    p = tmp_path / "f.mdcap"
    with NativeWriter(p, DEVICES[:1], meta={"first_time": first}, compress=compress) as w:
        w.motion(0, [0.1, 0.2, 6.0], [1, 2, 3], [1, 1, 1])
    assert open_capture(p).first_time() == (0.1 if first is None else first)
    assert drain(p).stats[0].net_x == 6


@pytest.mark.parametrize("first", [5.0, 1e9, 0.10000000001])
def test_first_time_after_the_first_stamp_is_refused(tmp_path, first):
    """first_time 1e9 with reports at 0.1 to 6 s replayed as one row at t = 1e9, exit 0
    (5.0: the grid began after two reports it must hold)."""
    p = tmp_path / "late.mdcap"
    with NativeWriter(p, DEVICES[:1], meta={"first_time": first}) as w:
        w.motion(0, [0.1, 0.2, 6.0], [1, 2, 3], [1, 1, 1])
        w.sync(math.inf)
    with pytest.raises(CaptureError, match=r"late.mdcap: byte offset 16: header: first_time "
                       r".* is later than the first stamp \(0.1, in the chunk at byte offset "
                       r"\d+\)"):  # fmt: skip
        open_capture(p).first_time()
    with pytest.raises(CaptureError, match="later than the first stamp"):
        drain(p)  # (feeds() without first_time() first, as a tool might call them)


def test_replay_refuses_a_late_first_time_in_one_line(tmp_path):
    p = tmp_path / "late.mdcap"
    with NativeWriter(p, [DeviceInfo(name="m", mouse="m", rel_xy=True)], time_base="relative",
                      meta={"first_time": 1e9}) as w:  # fmt: skip
        w.motion(0, [0.1, 0.2, 6.0], [1, 2, 3], [1, 1, 1])
        w.sync(math.inf)
    cfg = one_mouse_config(tmp_path)
    proc = run_mousedom("replay", "-c", str(cfg), "--capture", f"m={p}", "-o", "-")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"mousedom: error: {p}: byte offset 16: header: first_time 1000000000.0 is later than "
        "the first stamp (0.1, in the chunk at byte offset "
        + proc.stderr.split("chunk at byte offset ")[1].split(")")[0]
        + "): it would put the window grid after reports it must hold"
    ]


@pytest.mark.parametrize(
    "bad, said",
    [("x", "is not a number"), (True, "is not a number"), (float("nan"), "is not a time"),
     (1.11, r"is later than the first stamp \(0.1\) by more than 1.0 s")],
)  # fmt: skip
def test_a_grid_start_that_is_not_where_windows_can_begin_is_refused(tmp_path, bad, said):
    p = tmp_path / "g.mdcap"
    with NativeWriter(p, DEVICES[:1], meta={"grid_start": bad}) as w:
        w.motion(0, [0.1, 0.2, 6.0], [1, 2, 3], [1, 1, 1])
    with pytest.raises(CaptureError, match=r"g.mdcap: byte offset 16: header: grid_start .* "
                       + said):  # fmt: skip
        open_capture(p).grid_start()


def _windows_t(tmp_path, capture, tag: str) -> tuple[np.ndarray, str]:
    out = tmp_path / f"{tag}.csv"
    proc = run_mousedom("replay", "-c", str(one_mouse_config(tmp_path)), "--capture",
                        f"m={capture}", "-o", str(out))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    return np.array([float(ln.split(",")[0]) for ln in text.splitlines()[1:]]), text


@pytest.mark.parametrize("grid_start", [0.0937, 0.1005, -2.0])
def test_replay_windows_begin_at_the_recorders_grid_and_convert_keeps_it(tmp_path, grid_start):
    """A daemon's recording says where its windows began (grid_start, here before, after
    and well before the first report): replay's window ends are that plus whole periods,
    not the first stamp plus them; a converted copy replays to the very same rows."""
    p = tmp_path / "rec.mdcap"
    t = 0.1 + np.cumsum(np.full(200, 0.008))
    with NativeWriter(p, [DeviceInfo(name="m", mouse="m", rel_xy=True)], time_base="relative",
                      meta={"grid_start": grid_start}) as w:  # fmt: skip
        w.motion(0, t, np.full(200, 3), np.full(200, -1))
    ends, text = _windows_t(tmp_path, p, "rec")
    period = 0.01  # one_mouse_config's rate_hz: 100
    k = (ends - grid_start) / period
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)
    assert ends[0] - period <= t[0] + period
    copy = tmp_path / "copy.mdcap"
    proc = run_mousedom("convert", "--capture", str(p), "-o", str(copy))
    assert proc.returncode == 0, proc.stderr
    assert open_capture(str(copy)).grid_start() == pytest.approx(grid_start, abs=1e-12)
    assert _windows_t(tmp_path, copy, "copy")[1] == text


def test_the_writer_refuses_what_the_reader_refuses(tmp_path):
    w = NativeWriter(tmp_path / "w.mdcap", DEVICES)
    for call in (
        lambda: w.motion(0, [1e300], [1], [1]),
        lambda: w.serial_many(2, [float("nan")], [b"x"]),
        lambda: w.sync(float("nan")),
    ):
        with pytest.raises(CaptureError, match="time"):
            call()
    w.sync(float("inf"))  # the end of a recording is a valid sync
    w.close()
    drain(tmp_path / "w.mdcap")


def _serial_file(path, times):
    """A capture of one serial device whose reads are stamped ``times``, each chunk as a
    writer without the order check would write it (the bytes: one ADNS motion packet)."""
    from mousedom.capture.native_format import SERIAL
    from mousedom.sources import adns_protocol as P

    dev = DeviceInfo(name="adns", kind="serial", mouse="floor")
    motion = [P.Motion(seq=k, t_us=10_000 * k, dx=5, dy=7, frames=10, squal_min=50, flags=0)
              for k in range(len(times))]  # fmt: skip
    wire = [P.encode_packet(m) for m in motion]
    with NativeWriter(path, [dev], time_base="monotonic") as w:
        for t, piece in zip(times, wire, strict=True):
            head = np.asarray([t], "<f8").tobytes() + np.asarray([len(piece)], "<u4").tobytes()
            w._chunk(SERIAL, 0, 1, head + piece)


def test_serial_reads_back_in_time_are_refused_naming_the_offset(tmp_path):
    """A serial read stamped 50 s back was read without a word, and the decoder held every
    ADNS report after it at one instant (100.09 s, where they were 10 ms apart): the
    reader now refuses it as it refuses motion and gyro chunks that go back."""
    p = tmp_path / "back.mdcap"
    times = [100.0 + 0.01 * k for k in range(20)]
    times[10] = 50.0
    _serial_file(p, times)
    with pytest.raises(
        CaptureError, match=r"byte offset \d+: time goes backwards for device 'adns'"
    ):
        for f in open_capture(str(p)).feeds():
            for _ in f.batches:
                pass
    ok = tmp_path / "ok.mdcap"
    _serial_file(ok, sorted(times))
    for f in open_capture(str(ok)).feeds():
        for _ in f.batches:
            pass


def test_the_writer_refuses_serial_reads_back_in_time_or_for_another_kind(tmp_path):
    """Never write what the reader refuses: serial reads out of time order (within a call
    or across calls), serial bytes for an evdev device."""
    devs = [DeviceInfo(name="m", mouse="m", rel_xy=True),
            DeviceInfo(name="adns", kind="serial", mouse="floor")]  # fmt: skip
    with NativeWriter(tmp_path / "a.mdcap", devs) as w:
        w.serial_many(1, [1.0, 2.0], [b"\x01", b"\x02"])
        with pytest.raises(CaptureError, match="after one at 2.0"):
            w.serial_many(1, [1.5], [b"\x03"])
        with pytest.raises(CaptureError, match="after one at 2.5"):
            w.serial_many(1, [2.5, 2.4], [b"\x03", b"\x04"])
        with pytest.raises(ValueError, match="of kind 'evdev': no serial bytes"):
            w.serial_many(0, [3.0], [b"\x05"])


def test_chunks_of_another_kind_than_their_device_are_refused(tmp_path):
    """Serial bytes for an evdev device were decoded as ADNS-3080 packets, motion reports
    for a serial device taken as its reports: each kind of chunk is its kind of device's."""
    from mousedom.capture.native_format import MOTION, SERIAL

    devs = [DeviceInfo(name="m", mouse="m", rel_xy=True),
            DeviceInfo(name="adns", kind="serial", mouse="floor")]  # fmt: skip
    for kind, device, what in ((SERIAL, 0, "serial bytes"), (MOTION, 1, "motion reports")):
        p = tmp_path / f"{kind}-{device}.mdcap"
        with NativeWriter(p, devs) as w:
            if kind == SERIAL:
                head = np.asarray([1.0], "<f8").tobytes() + np.asarray([1], "<u4").tobytes()
                w._chunk(SERIAL, device, 1, head + b"\x01")
            else:
                body = (np.asarray([1.0], "<f8").tobytes() + np.asarray([1], "<i4").tobytes()
                        + np.asarray([2], "<i4").tobytes())  # fmt: skip
                w._chunk(MOTION, device, 1, body)
        with pytest.raises(CaptureError, match=rf"byte offset \d+: {what} for device"):
            for f in open_capture(str(p)).feeds():
                for _ in f.batches:
                    pass


def test_convert_keeps_what_a_native_capture_says_of_how_it_was_made(tmp_path):
    """``convert`` of one native capture (to recompress it, or to a file from a pipe)
    dropped the rig's config snapshot and the recorder's name and config path: a recorded
    file's ``config`` came out null.  Kept now, unless -c gives another config."""
    from mousedom.capture import DeviceInfo, NativeWriter, open_capture

    src = tmp_path / "rec.mdcap"
    config = "rate_hz: 50\nmice:\n  a: {cpi: 800, evdev: {path: /dev/input/event3}}\n"
    meta = {"recorder": "mousedom record", "config_path": "/etc/mousedom/rig.yaml"}
    with NativeWriter(str(src), [DeviceInfo(name="dev a", mouse="a")], config_text=config,
                      meta=meta) as w:  # fmt: skip
        w.motion(0, np.arange(5) * 0.008, np.ones(5, int), np.zeros(5, int))
    out = tmp_path / "out.mdcap"
    p = run_mousedom("convert", "--capture", str(src), "-o", str(out))
    assert p.returncode == 0, p.stderr
    got = open_capture(str(out))
    assert got.config_text == config
    assert {k: got.header.get(k) for k in meta} == meta
    other = tmp_path / "other.yaml"
    other.write_text("rate_hz: 20\nmodel: diff-drive\nmice:\n"
                     "  a: {cpi: 400, mount: {x: 0.1, y: 0}, evdev: {path: /dev/x}}\n")  # fmt: skip
    out2 = tmp_path / "out2.mdcap"
    p = run_mousedom("convert", "--capture", str(src), "-o", str(out2), "-c", str(other))
    assert p.returncode == 0, p.stderr
    assert open_capture(str(out2)).config_text == other.read_text()


def test_a_tail_of_chunk_markers_is_scanned_in_linear_time(tmp_path):
    """After a bad chunk the rest is searched for good data (corruption) or none (a torn
    tail).  Every marker whose head claims a large chunk had its claimed size checked: a
    1 MB file of them took 1.5 s, a 4 MB one 65 s.  The bytes checked are bounded by a
    multiple of the rest; past it the file is refused as corrupted, at once."""
    import time

    from mousedom.capture import CaptureError, DeviceInfo, NativeWriter
    from mousedom.capture.native_format import CHUNK, CHUNK_MAGIC

    base = tmp_path / "base.mdcap"
    with NativeWriter(str(base), [DeviceInfo(name="a", mouse="a")], time_base="relative") as w:
        w.motion(0, [0.1, 0.2], [1, 2], [0, 0])
        w.sync(0.2)
    head = CHUNK.pack(CHUNK_MAGIC, 1, 0, 0, 1, 2 << 20, 0)  # claims 2 MiB, CRC wrong
    path = tmp_path / "markers.mdcap"
    path.write_bytes(base.read_bytes() + b"XXXX" + head * ((4 << 20) // len(head)))
    start = time.monotonic()
    with pytest.raises(CaptureError, match="too many chunk markers .*corrupted"):
        drain(path)
    assert time.monotonic() - start < 10.0
