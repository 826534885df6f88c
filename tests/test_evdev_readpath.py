"""The live read path (``FrameAssembler.feed_bytes``, ``EvdevSource`` small reads) gives
exactly what the bulk numpy path (``decode_input_events`` + ``feed_events``) gives: the
same frames, bit-identical times, the same statistics, clamp and leftover bytes, on
arbitrary event streams cut at arbitrary byte offsets."""

from __future__ import annotations

import os

import numpy as np
import pytest
from cores import names as core_names
from cores import using
from hypothesis import example, given, settings
from hypothesis import strategies as st
from test_evdev_fakes import stamps_on_their_own_clock  # noqa: F401 (a fixture, used by name)

from mousedom.config import EvdevMatch, Mount, MouseConfig
from mousedom.sources.base import Reports, SourceGone
from mousedom.sources.base import clamp_forward as _clamp_forward
from mousedom.sources.base import clamp_list as _clamp_list
from mousedom.sources.evdev import SMALL_READ, EvdevSource
from mousedom.sources.events import (
    EV_KEY,
    EV_MSC,
    EV_REL,
    EV_SYN,
    EVENT_DTYPE,
    REL_WHEEL,
    REL_X,
    REL_Y,
    SYN_DROPPED,
    SYN_REPORT,
    FrameAssembler,
    decode_input_events,
)

KINDS = [
    (EV_REL, REL_X),
    (EV_REL, REL_Y),
    (EV_SYN, SYN_REPORT),
    (EV_SYN, SYN_DROPPED),
    (EV_SYN, 2),  # SYN_MT_REPORT: a SYN event that is neither
    (EV_REL, REL_WHEEL),
    (EV_KEY, 0x110),
    (EV_MSC, 4),
]
# Mostly the kinds above (motion and SYN dominate, as from a mouse), sometimes any at all.
kind = st.one_of(
    *[st.sampled_from([*KINDS, *KINDS[:3] * 3])] * 7,
    st.tuples(st.integers(0, 0xFFFF), st.integers(0, 0xFFFF)),
)
value = st.integers(-50, 50) | st.integers(-(2**31), 2**31 - 1)
# Stamps: a few seconds with any microsecond (so they often run backwards), or huge ones.
stamp = st.tuples(st.integers(0, 3), st.integers(0, 999_999)) | st.tuples(
    st.integers(0, 2**40), st.integers(0, 999_999)
)
# Any events in any order, or mouse-like frames: a few events and (mostly) a SYN_REPORT,
# all with the frame's stamp, which often runs backwards from one frame to the next.
loose = st.lists(st.tuples(stamp, kind, value), max_size=120)
frame = st.tuples(
    stamp, st.lists(st.tuples(kind, value), max_size=4), st.sampled_from([True] * 5 + [False])
)
framed = st.lists(frame, max_size=30).map(
    lambda frames: [
        row
        for ts, events, report in frames
        for row in [(ts, k, v) for k, v in events] + ([(ts, (EV_SYN, SYN_REPORT), 0)] * report)
    ]
)
records = loose | framed


# Stamps on a clock of their own: the bound against the read's time is lifted here.
pytestmark = pytest.mark.usefixtures("stamps_on_their_own_clock")


def to_bytes(rows) -> bytes:
    a = np.zeros(len(rows), dtype=EVENT_DTYPE)
    for i, ((sec, usec), (ty, co), va) in enumerate(rows):
        a[i] = (sec, usec, ty, co, va)
    return a.tobytes()


def cut(data: bytes, offsets: list[int]) -> list[bytes]:
    bounds = sorted({0, len(data), *(o % (len(data) + 1) for o in offsets)})
    return [data[lo:hi] for lo, hi in zip(bounds[:-1], bounds[1:], strict=False)]


def bulk(a: FrameAssembler, buf: bytes):
    events, rest = decode_input_events(buf)
    f = a.feed_events(events)
    return f.t.tolist(), f.dx.tolist(), f.dy.tolist(), rest


# Reads of whole REL_X, REL_Y, SYN_REPORT frames (a mouse moving on both axes): what
# FrameAssembler._xy_frames slices apart.
# Each event's own stamp: the kernel gives a frame's events one, but the frame's time is
# its SYN_REPORT's whatever they hold.
stamps3 = stamp.map(lambda ts: (ts, ts, ts)) | st.tuples(stamp, stamp, stamp)
xy_frames = st.lists(st.tuples(stamps3, value, value), min_size=1, max_size=40).map(
    lambda frames: [
        row
        for (tx, ty, ts), vx, vy in frames
        for row in ((tx, (EV_REL, REL_X), vx), (ty, (EV_REL, REL_Y), vy),
                    (ts, (EV_SYN, SYN_REPORT), 0))
    ]
)  # fmt: skip


@settings(max_examples=200, deadline=None)
@given(xy_frames, st.lists(st.integers(0, 40), max_size=6), st.integers(0, 71), st.booleans())
def test_whole_xy_frames_are_sliced_exactly_as_the_loop_reads_them(rows, frame_cuts, skew, open_):
    """Reads cut at frame boundaries take the sliced path (checked), others and reads after
    an open frame the loop; frames, times (bit for bit), statistics and leftovers agree
    with the vectorised path either way."""
    with using("python"):  # the Python's own twin paths (the compiled core has one)
        _sliced_as_the_loop(rows, frame_cuts, skew, open_)


def _sliced_as_the_loop(rows, frame_cuts, skew, open_):
    data = to_bytes(rows)
    if open_:  # a frame left open by an earlier read: its REL_X joins the first frame
        data = to_bytes([((0, 5), (EV_REL, REL_X), 7)]) + data
    ref, new = FrameAssembler(0), FrameAssembler()
    sliced = []
    real = new._xy_frames
    new._xy_frames = lambda buf, n: sliced.append(real(buf, n)) or sliced[-1]
    rest_ref = rest_new = b""
    frames = len(data) // 72
    offsets = [72 * (c % (frames + 1)) + (skew if i == 0 else 0) for i, c in enumerate(frame_cuts)]
    for chunk in cut(data, offsets):
        t0, x0, y0, rest_ref = bulk(ref, rest_ref + chunk)
        t1, x1, y1, rest_new = new.feed_bytes(rest_new + chunk)
        assert np.array(t1, dtype=np.float64).tobytes() == np.array(t0).tobytes()
        assert (x1, y1, rest_new) == (x0, y0, rest_ref)
        assert all(type(v) is float for v in t1) and all(type(v) is int for v in x1 + y1)
        assert new.stats == ref.stats
        assert new.open_frame_events == ref.open_frame_events
    if not open_ and not skew:
        assert any(r is not None for r in sliced)  # the sliced path was taken


@settings(max_examples=300, deadline=None)
@given(records, st.lists(st.integers(0, 24 * 120), max_size=10), st.randoms())
def test_feed_bytes_equals_the_numpy_path(rows, offsets, rnd):
    """Chunk by chunk: frames, times (bit for bit), dx, dy, leftover bytes, statistics and
    the open frame agree with the vectorised path; also when one assembler alternates
    between both paths (the live source does when a read is big).  With each core."""
    for name in core_names():
        with using(name):
            _equal_to_the_numpy_path(rows, offsets, rnd)


def _equal_to_the_numpy_path(rows, offsets, rnd):
    data = to_bytes(rows)
    ref, new, mixed = FrameAssembler(0), FrameAssembler(), FrameAssembler(0)
    rest_ref = rest_new = rest_mix = b""
    for chunk in cut(data, offsets):
        t0, x0, y0, rest_ref = bulk(ref, rest_ref + chunk)
        t1, x1, y1, rest_new = new.feed_bytes(rest_new + chunk)
        if rnd.random() < 0.5:
            t2, x2, y2, rest_mix = mixed.feed_bytes(rest_mix + chunk)
        else:
            t2, x2, y2, rest_mix = bulk(mixed, rest_mix + chunk)
        assert np.array(t1, dtype=np.float64).tobytes() == np.array(t0).tobytes()
        assert (x1, y1, rest_new) == (x0, y0, rest_ref)
        assert (t2, x2, y2, rest_mix) == (t0, x0, y0, rest_ref)
        assert all(type(v) is float for v in t1) and all(type(v) is int for v in x1 + y1)
        assert new.stats == ref.stats == mixed.stats
        assert new.open_frame_events == ref.open_frame_events == mixed.open_frame_events
    # Flush after the small path: the open frame (sums, time, drop flag) was carried right.
    f0, f1, f2 = ref.flush(), new.flush(), mixed.flush()
    assert f1.t.tobytes() == f0.t.tobytes() == f2.t.tobytes()
    assert f1.dx.tolist() == f0.dx.tolist() == f2.dx.tolist()
    assert f1.dy.tolist() == f0.dy.tolist() == f2.dy.tolist()
    assert new.stats == ref.stats == mixed.stats


def test_feed_bytes_by_hand():
    """A worked example: a frame split mid-record, a SYN_DROPPED frame, a button."""
    rows = [
        ((1, 0), (EV_REL, REL_X), 3),
        ((1, 0), (EV_REL, REL_Y), -4),
        ((1, 500_000), (EV_SYN, SYN_REPORT), 0),
        ((2, 0), (EV_REL, REL_X), 10),
        ((2, 0), (EV_SYN, SYN_DROPPED), 0),
        ((2, 1), (EV_SYN, SYN_REPORT), 0),
        ((3, 0), (EV_KEY, 0x110), 1),
        ((3, 0), (EV_REL, REL_Y), 7),
    ]
    data = to_bytes(rows)
    a = FrameAssembler()
    t, dx, dy, rest = a.feed_bytes(data[:30])
    assert (t, dx, dy, rest) == ([], [], [], data[24:30])
    t, dx, dy, rest = a.feed_bytes(rest + data[30:])
    assert (t, dx, dy, rest) == ([1.5], [3], [-4], b"")
    s = a.stats
    assert (s.events, s.frames, s.motion_frames, s.skipped) == (8, 2, 1, 1)
    assert (s.syn_dropped, s.dropped_frames, s.dropped_dx, s.dropped_events) == (1, 1, 10, 1)
    assert (s.rel_x_in, s.rel_y_in) == (13, 3)
    assert a.open_frame_events == 2
    f = a.flush()
    assert (f.t.tolist(), f.dx.tolist(), f.dy.tolist()) == ([3.0], [0], [7])


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.floats(-10.0, 10.0, allow_nan=False), max_size=80),
    st.one_of(st.just(-np.inf), st.floats(-10.0, 10.0, allow_nan=False)),
)
def test_clamp_list_equals_clamp_forward(values, last):
    want, back = _clamp_forward(np.array(values, dtype=np.float64), last)
    got = list(values)
    assert _clamp_list(got, last) == back
    assert np.array(got, dtype=np.float64).tobytes() == np.asarray(want).tobytes()


# ------------------------------------------------------------------ the source, on pipes


def pipe_source(small_read: int) -> tuple[EvdevSource, int]:
    r, w = os.pipe()
    m = MouseConfig("left", 800.0, 800.0, Mount(), evdev=EvdevMatch(path=f"/proc/self/fd/{r}"))
    src = EvdevSource(m)
    src.small_read = small_read
    src.open()
    os.close(r)  # the source reopened the pipe through /proc
    return src, w


def read_once(src: EvdevSource):
    """One read's outcome: the reports as exact bytes, or that the source is gone."""
    try:
        batches = src.read(0.0)
    except SourceGone as e:
        return ("gone", str(e))
    return [
        (b.mouse, b.t.dtype, b.t.tobytes(), b.dx.dtype, b.dx.tobytes(), b.dy.tobytes())
        for b in batches
    ]


def state(src: EvdevSource):
    return (
        src.health.as_dict(),
        src.assembler.stats,
        src._rest,
        src._last_t,
        src.time_backwards,
        src.truncated_bytes,
    )


BACK_ACROSS_READS = [  # two frames in the first read, then one stamped between them
    ((3, 0), (EV_REL, REL_X), 1),
    ((3, 0), (EV_SYN, SYN_REPORT), 0),
    ((4, 0), (EV_REL, REL_Y), 2),
    ((4, 0), (EV_SYN, SYN_REPORT), 0),
    ((3, 500_000), (EV_REL, REL_X), 3),
    ((3, 500_000), (EV_SYN, SYN_REPORT), 0),
]


@settings(max_examples=100, deadline=None)
@given(records, st.lists(st.integers(0, 24 * 120), max_size=8), st.booleans())
@example(BACK_ACROSS_READS, [96], False)
def test_source_small_reads_equal_the_bulk_path_through_pipes(rows, offsets, tail):
    """Two sources on real pipes, one on the small path and one forced onto the bulk path,
    get the same writes (cut anywhere, stamps running backwards, SYN_DROPPED, other event
    types): every read hands out the same reports and leaves the same health, statistics,
    clamp and leftover bytes; the unplug (the writer closes, maybe mid-record) too."""
    data = to_bytes(rows) + (b"\x01\x00\x00" if tail else b"")
    small, w_small = pipe_source(SMALL_READ)
    big, w_big = pipe_source(0)
    try:
        for chunk in cut(data, offsets):
            assert len(chunk) + 23 <= SMALL_READ  # so each read takes the small path
            os.write(w_small, chunk)
            os.write(w_big, chunk)
            assert read_once(small) == read_once(big)
            assert state(small) == state(big)
        os.close(w_small)
        os.close(w_big)
        w_small = w_big = -1
        for _ in range(3):  # frames of the open frame, then gone; or gone at once
            out = read_once(small)
            assert out == read_once(big)
            assert state(small) == state(big)
            if out and out[0] == "gone":
                break
        else:
            pytest.fail("the closed pipe was not seen as an unplug")
    finally:
        for fd in (w_small, w_big):
            if fd >= 0:
                os.close(fd)
        small.close()
        big.close()


def test_small_reads_do_not_touch_numpy_assembly():
    """The live path is really taken: a read of a few frames never calls feed_events,
    and a read past ``small_read`` does."""
    src, w = pipe_source(SMALL_READ)
    calls = []
    real = src.assembler.feed_events
    src.assembler.feed_events = lambda ev: calls.append(len(ev)) or real(ev)
    rows = [((5, 1000 * i), (EV_REL, REL_X), i) for i in range(3)]
    rows += [((5, 9000), (EV_SYN, SYN_REPORT), 0)]
    try:
        os.write(w, to_bytes(rows))
        (b,) = src.read(1.0)
        assert calls == []
        assert b.t.tolist() == [5.009] and b.dx.tolist() == [3.0] and b.dy.tolist() == [0.0]
        assert b.t.dtype == b.dx.dtype == b.dy.dtype == np.float64
        src.small_read = 24
        os.write(w, to_bytes(rows))
        (b,) = src.read(2.0)
        assert calls == [4] and b.dx.tolist() == [3.0]
        assert src.health.reports == 2 and src.health.last_t == 5.009
    finally:
        os.close(w)
        src.close()


def test_reports_from_lists_keep_the_lists_and_give_float64_arrays():
    """The list form hands its lists on untouched (``columns``) and still honours the
    array contract (``t``, ``dx``, ``dy`` float64 arrays) for every other consumer."""
    t, dx, dy = [1.0, 1.5], [3, -2], [0, 7]
    r = Reports.from_lists("m", t, dx, dy)
    cols = r.columns()
    assert cols[0] is t and cols[1] is dx and cols[2] is dy
    assert len(r) == 2 and r.mouse == "m"
    assert r.t.dtype == r.dx.dtype == r.dy.dtype == np.float64
    assert r.t.tolist() == t and r.dx.tolist() == [3.0, -2.0] and r.dy.tolist() == [0.0, 7.0]
    assert r.dx is r.dx  # made once
    a = Reports("m", np.array([2.0]), np.array([1], dtype=np.int64), [4])
    assert a.dx.dtype == a.dy.dtype == np.float64 and len(a) == 1
    assert all(isinstance(c, np.ndarray) for c in a.columns())
    assert "Reports('m'" in repr(r)


def test_feed_small_path_keeps_times_bit_for_bit():
    """``feed`` (times given as floats) runs the shared loop as ``t + -0.0 * 1e-6``:
    that is t itself, sign of zero included, as the numpy path hands it out."""
    t = np.array([-0.0, -0.0, 1e-300, 1e-300, 7.1, 7.1])
    ty = np.array([EV_REL, EV_SYN, EV_REL, EV_SYN, EV_REL, EV_SYN])
    co = np.array([REL_X, SYN_REPORT, REL_Y, SYN_REPORT, REL_X, SYN_REPORT])
    va = np.array([1, 0, 2, 0, 3, 0])
    loop, vec = FrameAssembler(10**9).feed(t, ty, co, va), FrameAssembler(0).feed(t, ty, co, va)
    assert loop.t.tobytes() == vec.t.tobytes() == t[1::2].tobytes()
    assert np.signbit(loop.t[0])
