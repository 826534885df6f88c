"""The shared input_event decoder and SYN_REPORT frame assembler (mousedom/sources/events.py)."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mousedom.sources.events import (
    EV_KEY,
    EV_MSC,
    EV_REL,
    EV_SYN,
    EVENT_DTYPE,
    EVENT_SIZE,
    REL_WHEEL,
    REL_WHEEL_HI_RES,
    REL_X,
    REL_Y,
    SYN_DROPPED,
    SYN_REPORT,
    FrameAssembler,
    MotionFrames,
    decode_input_events,
    encode_input_events,
    event_times,
)


@pytest.fixture(params=[0, 10**9], ids=["vectorised", "loop"])
def mk(request):
    """Both assembler paths: numpy for every chunk, and the per-event loop."""
    return lambda: FrameAssembler(request.param)


def ev(rows):
    """rows of (t, type, code, value) -> the four arrays."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return a[:, 0], a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint16), a[:, 3].astype(np.int64)


def reference_frames(rows):
    """Event-by-event reference of the kernel's rules (slow, obviously right)."""
    out, dx, dy, motion, dropped = [], 0, 0, False, False
    for t, typ, code, val in rows:
        if typ == EV_SYN and code == SYN_DROPPED:
            dropped = True
        elif typ == EV_SYN and code == SYN_REPORT:
            if motion and not dropped:
                out.append((t, dx, dy))
            dx, dy, motion, dropped = 0, 0, False, False
        elif typ == EV_REL and code == REL_X:
            dx, motion = dx + val, True
        elif typ == EV_REL and code == REL_Y:
            dy, motion = dy + val, True
    return out


def as_rows(frames: MotionFrames):
    return [
        (float(t), int(x), int(y)) for t, x, y in zip(frames.t, frames.dx, frames.dy, strict=True)
    ]


def test_dtype_is_the_kernel_struct():
    """struct input_event on 64-bit Linux: two longs, two u16, one s32 = 24 bytes."""
    assert EVENT_SIZE == 24 == struct.calcsize("@llHHi")
    raw = struct.pack("@llHHi", 1700000000, 123456, EV_REL, REL_Y, -7)
    events, rest = decode_input_events(raw + b"\x01\x02")
    assert rest == b"\x01\x02"
    assert len(events) == 1
    e = events[0]
    assert (e["sec"], e["usec"], e["type"], e["code"], e["value"]) == (
        1700000000,
        123456,
        EV_REL,
        REL_Y,
        -7,
    )
    assert event_times(events)[0] == pytest.approx(1700000000.123456, abs=1e-7)


def test_encode_decode_round_trip():
    t, ty, co, va = ev([(0.5, EV_REL, REL_X, 3), (0.5, EV_SYN, SYN_REPORT, 0)])
    events, rest = decode_input_events(encode_input_events(t, ty, co, va))
    assert rest == b""
    assert list(events["usec"]) == [500000, 500000]
    assert list(events["value"]) == [3, 0]


def test_frames_sum_repeated_codes_and_take_report_time(mk):
    rows = [
        (1.0, EV_REL, REL_X, 2),
        (1.0, EV_REL, REL_X, 3),  # repeated code in one frame: sums
        (1.0, EV_REL, REL_Y, -1),
        (1.001, EV_SYN, SYN_REPORT, 0),
        (1.002, EV_KEY, 0x110, 1),  # BTN_LEFT: not motion
        (1.002, EV_SYN, SYN_REPORT, 0),
        (1.003, EV_REL, REL_Y, 4),
        (1.003, EV_REL, REL_WHEEL_HI_RES, 120),
        (1.003, EV_REL, REL_WHEEL, 1),
        (1.003, EV_MSC, 4, 589825),
        (1.004, EV_SYN, SYN_REPORT, 0),
    ]
    a = mk()
    f = a.feed(*ev(rows))
    assert as_rows(f) == [(1.001, 5, -1), (1.004, 0, 4)]
    s = a.stats
    assert (s.events, s.frames, s.motion_frames, s.skipped) == (11, 3, 2, 4)
    assert (s.rel_x_in, s.rel_y_in) == (5, 3)


def test_syn_dropped_mid_frame_drops_both_halves_and_counts_them(mk):
    """Kernel rule: drop the partial frame, then discard up to and including the next
    SYN_REPORT; the frames before and after are untouched."""
    rows = [
        (1.0, EV_REL, REL_X, 1),
        (1.0, EV_SYN, SYN_REPORT, 0),
        (1.1, EV_REL, REL_X, 10),  # partial frame ...
        (1.1, EV_SYN, SYN_DROPPED, 0),  # ... overflow
        (1.2, EV_REL, REL_Y, 20),  # discarded up to ...
        (1.2, EV_SYN, SYN_REPORT, 0),  # ... and including this report
        (1.3, EV_REL, REL_Y, 2),
        (1.3, EV_SYN, SYN_REPORT, 0),
    ]
    a = mk()
    assert as_rows(a.feed(*ev(rows))) == [(1.0, 1, 0), (1.3, 0, 2)]
    s = a.stats
    assert (s.syn_dropped, s.dropped_frames, s.dropped_dx, s.dropped_dy) == (1, 1, 10, 20)
    assert s.dropped_events == 2  # the two REL events; SYN_DROPPED and SYN_REPORT are not
    assert s.frames == 3 and s.motion_frames == 2


def test_syn_dropped_straddling_chunks(mk):
    rows = [
        (1.1, EV_REL, REL_X, 10),
        (1.1, EV_SYN, SYN_DROPPED, 0),
        (1.2, EV_REL, REL_Y, 20),
        (1.2, EV_SYN, SYN_REPORT, 0),
        (1.3, EV_REL, REL_Y, 2),
        (1.3, EV_SYN, SYN_REPORT, 0),
    ]
    for cut in range(len(rows) + 1):
        a = mk()
        got = as_rows(a.feed(*ev(rows[:cut]))) + as_rows(a.feed(*ev(rows[cut:])))
        assert got == [(1.3, 0, 2)], cut
        assert a.stats.dropped_frames == 1


def test_flush_keeps_trailing_counts_and_says_so(mk):
    a = mk()
    f = a.feed(*ev([(2.0, EV_REL, REL_X, 4), (2.0, EV_SYN, SYN_REPORT, 0), (2.5, EV_REL, 0, 3)]))
    assert as_rows(f) == [(2.0, 4, 0)]
    assert a.open_frame_events == 1
    assert as_rows(a.flush()) == [(2.5, 3, 0)]
    assert (a.stats.incomplete_frames, a.stats.incomplete_events) == (1, 1)
    assert len(a.flush()) == 0  # nothing open any more
    # A trailing frame with SYN_DROPPED is dropped, and counted.
    b = mk()
    b.feed(*ev([(1.0, EV_REL, REL_Y, 9), (1.0, EV_SYN, SYN_DROPPED, 0)]))
    assert len(b.flush()) == 0
    assert (b.stats.incomplete_frames, b.stats.dropped_frames, b.stats.dropped_dy) == (1, 1, 9)


def test_empty_and_mismatched_input(mk):
    a = mk()
    assert len(a.feed(*ev([]))) == 0
    with pytest.raises(ValueError):
        a.feed(np.zeros(2), np.zeros(1), np.zeros(2), np.zeros(2))


# --------------------------------------------------------------------------- properties

CODES = [
    (EV_SYN, SYN_REPORT),
    (EV_SYN, SYN_DROPPED),
    (EV_SYN, 2),
    (EV_REL, REL_X),
    (EV_REL, REL_Y),
    (EV_REL, REL_WHEEL),
    (EV_REL, REL_WHEEL_HI_RES),
    (EV_KEY, 0x110),
    (EV_MSC, 4),
    (3, 0),  # EV_ABS
]

event_rows = st.lists(
    st.tuples(
        st.sampled_from(CODES),
        st.integers(-(2**31), 2**31 - 1) | st.integers(-50, 50),
    ),
    max_size=200,
).map(lambda xs: [(i * 0.001, c[0], c[1], v) for i, (c, v) in enumerate(xs)])


def feed_in_chunks(rows, cuts, small_chunk=0, block=10**9):
    a = FrameAssembler(small_chunk, block)
    bounds = sorted({0, len(rows), *(c % (len(rows) + 1) for c in cuts)})
    parts = [a.feed(*ev(rows[lo:hi])) for lo, hi in zip(bounds[:-1], bounds[1:], strict=False)]
    parts.append(a.flush())
    return a, MotionFrames.concat(parts)


@settings(max_examples=150, deadline=None)
@given(event_rows, st.lists(st.integers(0, 10_000), max_size=8))
def test_chunking_does_not_change_frames_and_counts_are_conserved(rows, cuts):
    whole, f_whole = feed_in_chunks(rows, [])
    split, f_split = feed_in_chunks(rows, cuts)
    assert as_rows(f_split) == as_rows(f_whole)
    assert split.stats == whole.stats
    # The per-event loop (small chunks) and the vectorised path agree exactly.
    for small in (10**9, 3):
        loop, f_loop = feed_in_chunks(rows, cuts, small_chunk=small)
        assert as_rows(f_loop) == as_rows(f_whole)
        assert loop.stats == whole.stats
    # Big chunks are assembled in blocks; tiny blocks must not change anything either.
    for block in (1, 7):
        blocked, f_blocked = feed_in_chunks(rows, cuts, block=block)
        assert as_rows(f_blocked) == as_rows(f_whole)
        assert blocked.stats == whole.stats
    # The complete frames match the event-by-event reference.
    n_complete = len(reference_frames(rows))
    assert as_rows(f_whole)[:n_complete] == [(t, x, y) for t, x, y in reference_frames(rows)]
    # Counts in == counts out + counts dropped (nothing lost without a trace).
    s = whole.stats
    assert s.rel_x_in == int(f_whole.dx.sum()) + s.dropped_dx
    assert s.rel_y_in == int(f_whole.dy.sum()) + s.dropped_dy
    assert s.rel_x_in == sum(v for _, ty, co, v in rows if ty == EV_REL and co == REL_X)


@settings(max_examples=150, deadline=None)
@given(
    st.binary(max_size=24 * 40),
    st.lists(st.integers(0, 24 * 40), max_size=6),
    st.sampled_from([0, 5, 10**9]),
    st.sampled_from([3, 10**9]),
)
def test_random_bytes_never_crash_and_conserve_counts(data, cuts, small_chunk, block):
    """Arbitrary bytes, cut anywhere (not on record boundaries), decode like one read."""
    bounds = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    a, parts, rest = FrameAssembler(small_chunk, block), [], b""
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=False):
        events, rest = decode_input_events(rest + data[lo:hi])
        parts.append(a.feed_events(events))
    parts.append(a.flush())
    frames = MotionFrames.concat(parts)
    assert len(rest) == len(data) % EVENT_SIZE
    whole = np.frombuffer(data[: len(data) - len(rest)], dtype=EVENT_DTYPE)
    assert a.stats.events == len(whole)
    rel = whole["type"] == EV_REL
    x_in = int(whole["value"][rel & (whole["code"] == REL_X)].astype(np.int64).sum())
    assert a.stats.rel_x_in == x_in == int(frames.dx.sum()) + a.stats.dropped_dx
    assert np.all(np.isfinite(frames.t))


def test_open_frame_time_is_its_last_event_across_chunks(mk):
    """An open frame of one event, closed, then another open frame of one event."""
    a = mk()
    a.feed(*ev([(1.0, EV_REL, REL_X, 1)]))
    f = a.feed(*ev([(2.0, EV_SYN, SYN_REPORT, 0), (3.0, EV_REL, REL_Y, 5)]))
    assert as_rows(f) == [(2.0, 1, 0)]
    assert as_rows(a.flush()) == [(3.0, 0, 5)]


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 2**40),
            st.integers(0, 999_999),
            st.sampled_from(CODES),
            st.integers(-(2**31), 2**31 - 1),
        ),
        max_size=60,
    )
)
def test_record_paths_give_bitwise_equal_times(rows):
    """feed_events: the per-event loop (Python floats) and numpy give the same times."""
    arr = np.array([(s, u, c[0], c[1], v) for s, u, c, v in rows], dtype=EVENT_DTYPE)
    outs = []
    for small in (0, 10**9):
        a = FrameAssembler(small)
        f = MotionFrames.concat([a.feed_events(arr), a.flush()])
        outs.append((f.t.tobytes(), f.dx.tolist(), f.dy.tolist(), a.stats))
    assert outs[0] == outs[1]
