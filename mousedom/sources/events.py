"""Decode Linux ``struct input_event`` streams into mouse motion reports, in bulk.

Pure functions and one small state machine, no I/O: the live evdev source, the
capture readers (evemu, libinput record, native) and the benches all feed this.

Two steps:

1. ``decode_input_events(buf)`` views raw bytes as an array of ``EVENT_DTYPE`` records
   (one ``np.frombuffer``, no Python object per event) and hands back the bytes of a
   trailing incomplete record so that the next read can complete it.
2. ``FrameAssembler.feed(t, type, code, value)`` groups events into SYN_REPORT frames and
   returns one motion report per frame that holds REL_X and/or REL_Y.  It keeps the
   partial frame at the end of a chunk as a few running sums, so a frame may straddle
   any number of reads and the result does not depend on where the chunks were cut.

A live read of a few frames skips both numpy steps: ``FrameAssembler.feed_bytes`` runs
the same rules in one Python loop straight over the bytes (``struct.iter_unpack``) and
returns Python lists, because numpy's fixed cost per call is most of a small read's cost.

The kernel's SYN_DROPPED rule (Documentation/input/event-codes.rst): the client's
buffer overflowed, so the frame being assembled is incomplete; discard it and every
event up to and including the next SYN_REPORT.  Both halves are the one frame (from the
previous SYN_REPORT to the next) that contains the SYN_DROPPED, so such frames are
dropped whole, and their REL_X/REL_Y counts are added to ``dropped_dx``/``dropped_dy``
rather than vanishing: ``counts in == counts out + dropped counts`` always holds.
"""

from __future__ import annotations

import struct
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from itertools import repeat
from operator import add, mul
from typing import Any

import numpy as np

from mousedom import core

# struct input_event on 64-bit Linux (x86_64, aarch64, ...): struct timeval
# {long tv_sec; long tv_usec}, __u16 type, __u16 code, __s32 value = 24 bytes, no padding.
# (32-bit ABIs use 16-byte records; mousedom targets 64-bit hosts only.)
EVENT_DTYPE = np.dtype(
    [("sec", "<i8"), ("usec", "<i8"), ("type", "<u2"), ("code", "<u2"), ("value", "<i4")]
)
EVENT_SIZE = EVENT_DTYPE.itemsize
assert EVENT_SIZE == 24
# The same record for the struct module, with type and code read as one u32 key (below):
# iter_unpack makes one (sec, usec, key, value) tuple per record, in C.
EVENT_STRUCT = struct.Struct("<qqIi")
assert EVENT_STRUCT.size == EVENT_SIZE

# Chunks up to this many events take a plain loop: for small chunks numpy's fixed cost
# per call is more than the loop's (bench/decode.py prints per-read figures).
SMALL_CHUNK = 48
# Larger chunks are assembled this many events at a time (temporaries stay in cache).
BLOCK = 65536

EV_SYN, EV_KEY, EV_REL, EV_MSC = 0x00, 0x01, 0x02, 0x04
SYN_REPORT, SYN_CONFIG, SYN_MT_REPORT, SYN_DROPPED = 0, 1, 2, 3
REL_X, REL_Y, REL_WHEEL, REL_HWHEEL = 0x00, 0x01, 0x08, 0x06
REL_WHEEL_HI_RES, REL_HWHEEL_HI_RES = 0x0B, 0x0C
# type | code << 16: the two little-endian u16 at byte 16 of a record, read as one u32
KEY_SYN_REPORT = EV_SYN | SYN_REPORT << 16
KEY_SYN_DROPPED = EV_SYN | SYN_DROPPED << 16
KEY_REL_X = EV_REL | REL_X << 16
KEY_REL_Y = EV_REL | REL_Y << 16

# The keys of reads whose every frame is REL_X, REL_Y, SYN_REPORT (a mouse moving on both
# axes, the usual live read): ``FrameAssembler._xy_frames`` takes them apart by slicing.
_XY_FRAMES = [KEY_REL_X, KEY_REL_Y, KEY_SYN_REPORT] * 1024
# Slicing reads the records in the host's byte order; the records are little-endian.
_SLICE_RECORDS = sys.byteorder == "little"


def decode_input_events(buf: bytes | bytearray | memoryview) -> tuple[np.ndarray, bytes]:
    """View ``buf`` as input_event records; return (events, leftover bytes).

    ``leftover`` is the tail shorter than one record (0 to 23 bytes): prepend it to the
    next read.  The returned array is a read-only view when ``buf`` is immutable.
    """
    mv = memoryview(buf).cast("B")
    n = len(mv) // EVENT_SIZE
    events = np.frombuffer(mv, dtype=EVENT_DTYPE, count=n)
    return events, bytes(mv[n * EVENT_SIZE :])


def encode_input_events(
    t: np.ndarray, type: np.ndarray, code: np.ndarray, value: np.ndarray
) -> bytes:
    """The inverse of ``decode_input_events``: arrays (t in seconds) -> raw bytes.

    For tests, benches and FIFO feeders.  ``t`` is split into whole seconds and
    microseconds (rounded to the nearest microsecond, as the kernel's timeval holds).
    """
    t = np.asarray(t, dtype=np.float64)
    us = np.round(t * 1e6).astype(np.int64)
    out = np.empty(len(t), dtype=EVENT_DTYPE)
    out["sec"], out["usec"] = np.divmod(us, 1_000_000)
    out["type"], out["code"], out["value"] = type, code, value
    return out.tobytes()


def event_times(events: np.ndarray) -> np.ndarray:
    """Seconds (float64) from the records' timeval: sec + usec * 1e-6."""
    return events["sec"].astype(np.float64) + events["usec"].astype(np.float64) * 1e-6


@dataclass
class MotionFrames:
    """One report per SYN_REPORT frame with motion: t (s), dx = sum REL_X, dy = sum REL_Y."""

    t: np.ndarray = field(default_factory=lambda: np.empty(0, np.float64))
    dx: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    dy: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))

    def __len__(self) -> int:
        return len(self.t)

    @staticmethod
    def concat(parts: list[MotionFrames]) -> MotionFrames:
        if not parts:
            return MotionFrames()
        return MotionFrames(
            np.concatenate([p.t for p in parts]),
            np.concatenate([p.dx for p in parts]),
            np.concatenate([p.dy for p in parts]),
        )


@dataclass
class AssemblerStats:
    """Everything the assembler saw, so that no count is ever lost without a trace."""

    events: int = 0  # events fed, all types
    frames: int = 0  # SYN_REPORT frames closed (motion or not, dropped or not)
    motion_frames: int = 0  # frames returned as motion reports
    skipped: int = 0  # non-motion events: buttons, wheels (incl. hi-res), MSC_SCAN, ...
    syn_dropped: int = 0  # SYN_DROPPED events seen
    dropped_frames: int = 0  # frames discarded because they held a SYN_DROPPED
    dropped_dx: int = 0  # REL_X counts inside discarded frames
    dropped_dy: int = 0  # REL_Y counts inside discarded frames
    dropped_events: int = 0  # non-SYN events inside discarded frames
    incomplete_frames: int = 0  # trailing frames without SYN_REPORT closed by flush()
    incomplete_events: int = 0  # events in those frames
    rel_x_in: int = 0  # sum of every REL_X value fed
    rel_y_in: int = 0  # sum of every REL_Y value fed

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


# The AssemblerStats fields the compiled core's feed_bytes adds to, in the order it returns
# them (csrc/decode.c, the ST_ constants).
_STAT_FIELDS = ("events", "frames", "motion_frames", "skipped", "syn_dropped", "dropped_frames",
                "dropped_dx", "dropped_dy", "dropped_events", "rel_x_in", "rel_y_in")  # fmt: skip


def _as_frames(lists: tuple[list[float], list[int], list[int]]) -> MotionFrames:
    t, dx, dy = lists
    if not t:
        return MotionFrames()
    return MotionFrames(
        np.array(t, dtype=np.float64),
        np.array(dx, dtype=np.int64),
        np.array(dy, dtype=np.int64),
    )


class FrameAssembler:
    """Streaming SYN_REPORT frame assembler (vectorised per chunk; state between chunks).

    State carried from one ``feed`` to the next is just the open frame's running sums:
    REL_X/REL_Y totals and presence, whether it holds a SYN_DROPPED, and the time of its
    last event.  ``flush()`` closes that open frame at the end of a finite input.
    """

    def __init__(self, small_chunk: int = SMALL_CHUNK, block: int = BLOCK) -> None:
        self.stats = AssemblerStats()
        self.small_chunk = small_chunk
        self.block = max(1, block)
        self._reset_open()

    def _reset_open(self) -> None:
        self._open_dx = 0
        self._open_dy = 0
        self._open_motion = False  # the open frame holds REL_X or REL_Y
        self._open_dropped = False  # the open frame holds a SYN_DROPPED
        self._open_events = 0
        self._open_nonsyn = 0  # events of the open frame that are not EV_SYN
        self._open_t = 0.0

    @property
    def open_frame_events(self) -> int:
        """Events in the frame not yet closed by a SYN_REPORT."""
        return self._open_events

    def feed_events(self, events: np.ndarray) -> MotionFrames:
        """``feed`` for an ``EVENT_DTYPE`` array (as ``decode_input_events`` returns).

        Reads type and code as one 32-bit word per record, with no copy, and converts
        only the SYN_REPORT records' times to float.
        """
        if events.dtype != EVENT_DTYPE:
            raise TypeError(f"expected EVENT_DTYPE records, got {events.dtype}")
        if not events.flags.c_contiguous:
            events = np.ascontiguousarray(events)
        words = events.view("<u4")  # 6 words per record: sec, usec, type | code << 16, value
        sec, usec = events["sec"], events["usec"]
        if 0 < len(events) <= self.small_chunk:
            # Python floats: the same IEEE operations as numpy's, so the same times.
            records = zip(
                sec.tolist(),
                usec.tolist(),
                words[4::6].tolist(),
                words[5::6].view("<i4").tolist(),
                strict=True,
            )
            return _as_frames(self._feed_loop(records, len(events)))
        return self._feed(words[4::6], words[5::6].view("<i4"), lambda i: sec[i] + usec[i] * 1e-6)

    def feed_bytes(
        self, buf: bytes | bytearray | memoryview
    ) -> tuple[list[float], list[int], list[int], bytes]:
        """The live source's path for one small read: raw bytes in, Python lists out.

        Returns the motion frames closed in ``buf`` as three lists (times, REL_X sums,
        REL_Y sums) and the bytes of a trailing incomplete record (prepend them to the next
        read), with the same rules, statistics and times as ``decode_input_events`` +
        ``feed_events``: ``struct.iter_unpack`` makes the per-record tuples in C, and
        neither numpy's fixed cost per call (~1 us, several calls) nor arrays the caller
        would convert back to lists are paid.  Meant for reads of up to a few hundred
        records; bulk input takes ``feed_events``.
        """
        if core.native is not None:
            done = self._feed_native(buf)
            if done is not None:
                return done
        n = len(buf) // EVENT_SIZE
        end = n * EVENT_SIZE
        if end == len(buf):
            rest = b""
        else:
            rest = bytes(buf[end:])
            buf = memoryview(buf)[:end]
        if not n:
            return [], [], [], rest
        if not n % 3 and not self._open_events and _SLICE_RECORDS:
            frames = self._xy_frames(buf, n)
            if frames is not None:
                return (*frames, rest)
        t, dx, dy = self._feed_loop(EVENT_STRUCT.iter_unpack(buf), n)
        return t, dx, dy, rest

    def _feed_native(
        self, buf: bytes | bytearray | memoryview
    ) -> tuple[list[float], list[int], list[int], bytes] | None:
        """``feed_bytes`` in the compiled core (csrc/decode.c, the same rules as
        ``_feed_loop``), or None where its int64 sums would overflow (the Python then
        runs: a frame of 2^32 reports of the largest count; no device gets there)."""
        native = core.native
        assert native is not None  # (feed_bytes asks first)
        out = native.feed_bytes(buf, (
            self._open_dx, self._open_dy, self._open_motion, self._open_dropped,
            self._open_events, self._open_nonsyn, self._open_t,
        ), self.stats, _STAT_FIELDS)  # fmt: skip
        if out is None:
            return None
        t, dx, dy, rest, open_frame, _ = out  # (the statistics were added to self.stats)
        (self._open_dx, self._open_dy, self._open_motion, self._open_dropped,
         self._open_events, self._open_nonsyn, self._open_t) = open_frame  # fmt: skip
        return t, dx, dy, rest

    def _xy_frames(
        self, buf: bytes | bytearray | memoryview, n: int
    ) -> tuple[list[float], list[int], list[int]] | None:
        """``_feed_loop`` for ``n`` records that are whole REL_X, REL_Y, SYN_REPORT frames
        with no frame open before them (None if they are not): the columns are sliced out
        of the records in C, with no Python work per report.  A frame's time is its
        SYN_REPORT's ``sec + usec * 1e-6``, the same operations as the loop's.

        Record r is 6 int32 words (sec, usec as two each, type | code << 16, value) or 3
        int64 words, so frame f's keys are words 18f + 4, 10, 16, its REL_X and REL_Y
        values words 18f + 5 and 18f + 11, and its SYN_REPORT's sec and usec int64 words
        9f + 6 and 9f + 7.
        """
        if n > len(_XY_FRAMES):
            return None
        words = memoryview(buf).cast("i")
        if words[4::6].tolist() != _XY_FRAMES[:n]:
            return None
        wide = memoryview(buf).cast("q")
        t = list(map(add, wide[6::9].tolist(), map(mul, wide[7::9].tolist(), repeat(1e-6))))
        dx, dy = words[5::18].tolist(), words[11::18].tolist()
        k = n // 3
        st = self.stats
        st.events += n
        st.frames += k
        st.motion_frames += k
        st.rel_x_in += sum(dx)
        st.rel_y_in += sum(dy)
        return t, dx, dy

    def feed(
        self, t: np.ndarray, type: np.ndarray, code: np.ndarray, value: np.ndarray
    ) -> MotionFrames:
        """Add a chunk of events; return the motion frames closed by its SYN_REPORTs."""
        t = np.asarray(t, dtype=np.float64)
        if not (len(type) == len(code) == len(value) == len(t)):
            raise ValueError("t, type, code and value must have the same length")
        key = np.asarray(type).astype(np.uint32) | (np.asarray(code).astype(np.uint32) << 16)
        value = np.asarray(value, dtype=np.int64)
        if 0 < len(t) <= self.small_chunk:
            # x + -0.0 is x, bit for bit (even for -0.0): the loop's ``sec + usec * 1e-6``
            # then hands back each t unchanged.
            records = zip(t.tolist(), repeat(-0.0), key.tolist(), value.tolist(), strict=False)
            return _as_frames(self._feed_loop(records, len(t)))
        return self._feed(key, value, t.__getitem__)

    def _feed(
        self, key: np.ndarray, value: np.ndarray, time_at: Callable[[Any], np.ndarray]
    ) -> MotionFrames:
        """``key`` = type | code << 16 per event (one compare per event kind); numpy."""
        n = len(key)
        if n == 0:
            return MotionFrames()
        if n > self.block:
            # Blocks that stay in cache, with the open frame carried between them as
            # between chunks: big temporaries would cost page faults and memory traffic.
            parts = []
            for lo in range(0, n, self.block):
                hi = min(lo + self.block, n)

                def block_time(i: Any, lo: int = lo) -> np.ndarray:
                    return time_at(i + lo)

                parts.append(self._feed_block(key[lo:hi], value[lo:hi], block_time))
            return MotionFrames.concat(parts)
        return self._feed_block(key, value, time_at)

    def _feed_block(
        self, key: np.ndarray, value: np.ndarray, time_at: Callable[[Any], np.ndarray]
    ) -> MotionFrames:
        n = len(key)
        st = self.stats
        st.events += n

        is_x = key == KEY_REL_X
        is_y = key == KEY_REL_Y
        is_motion = is_x | is_y
        ends = np.flatnonzero(key == KEY_SYN_REPORT)
        # Prefix sums over events [0, i) at row i.  Frame k of this chunk spans
        # (r[k-1], r[k]] where r are the SYN_REPORT indices, so its sums are differences
        # of rows just after those; the events after the last one open a frame.
        cut = np.empty(len(ends) + 1, dtype=np.intp)
        cut[0] = 0
        cut[1:] = ends + 1
        last = int(cut[-1])

        def prefix(x: np.ndarray, dtype: type) -> np.ndarray:
            c: np.ndarray = np.empty(n + 1, dtype=dtype)
            c[0] = 0
            np.cumsum(x, dtype=dtype, out=c[1:])
            return c

        cx = prefix(np.where(is_x, value, 0), np.int64)
        cy = prefix(np.where(is_y, value, 0), np.int64)
        cm = prefix(is_motion, np.intp)
        dx = cx[cut[1:]] - cx[cut[:-1]]
        dy = cy[cut[1:]] - cy[cut[:-1]]
        has_motion = cm[cut[1:]] > cm[cut[:-1]]
        drops = np.flatnonzero(key == KEY_SYN_DROPPED)  # rare: handled apart, by index
        st.rel_x_in += int(cx[n])
        st.rel_y_in += int(cy[n])
        st.syn_dropped += len(drops)
        st.skipped += n - len(ends) - int(cm[n]) - len(drops)

        has_drop = np.zeros(len(ends), dtype=bool)
        nonsyn = None
        if len(drops):
            # The frame of each SYN_DROPPED: how many SYN_REPORTs come before it.
            has_drop[np.searchsorted(ends, drops[drops < last])] = True
            nonsyn = prefix((key & 0xFFFF) != EV_SYN, np.intp)
        if len(ends):
            # The frame left open by the previous chunk is closed by this chunk's first
            # SYN_REPORT: fold its sums into frame 0.
            dx[0] += self._open_dx
            dy[0] += self._open_dy
            has_motion[0] |= self._open_motion
            has_drop[0] |= self._open_dropped
            open_nonsyn = self._open_nonsyn
            self._reset_open()
        if last < n:  # the events after the last SYN_REPORT open (or extend) a frame
            self._open_dx += int(cx[n] - cx[last])
            self._open_dy += int(cy[n] - cy[last])
            self._open_motion |= bool(cm[n] > cm[last])
            self._open_dropped |= bool(len(drops) and drops[-1] >= last)
            self._open_nonsyn += int(np.count_nonzero((key[last:] & 0xFFFF) != EV_SYN))
            self._open_events += n - last
            self._open_t = float(time_at(n - 1))

        st.frames += len(ends)
        if has_drop.any():
            st.dropped_frames += int(np.count_nonzero(has_drop))
            st.dropped_dx += int(dx[has_drop].sum())
            st.dropped_dy += int(dy[has_drop].sum())
            if nonsyn is None:  # only the carried-over frame held a SYN_DROPPED
                nonsyn = prefix((key & 0xFFFF) != EV_SYN, np.intp)
            per_nonsyn = nonsyn[cut[1:]] - nonsyn[cut[:-1]]
            per_nonsyn[0] += open_nonsyn
            st.dropped_events += int(per_nonsyn[has_drop].sum())
        keep = has_motion & ~has_drop
        idx = ends[keep]
        st.motion_frames += len(idx)
        return MotionFrames(time_at(idx), dx[keep], dy[keep])

    def _feed_loop(
        self, records: Iterable[tuple[Any, Any, int, int]], n: int
    ) -> tuple[list[float], list[int], list[int]]:
        """The same rules event by event, for the few events of one live read.

        ``records`` yields ``n`` tuples (sec, usec, key, value), key = type | code << 16;
        a frame's time is ``sec + usec * 1e-6``, the IEEE operations numpy does.  numpy
        costs ~25 us per call whatever the size, which is more than this loop over the 3
        to 30 events a live mouse delivers per wake-up; the property tests check that both
        paths give identical frames and statistics.

        Per common event the loop does one compare chain and two additions; everything
        else is derived once per call.  The open frame is held as counts: ``m`` motion
        events, ``other`` other non-SYN events, ``synx`` SYN events that are not
        SYN_REPORT (its event count is their sum, its non-SYN count ``m + other``).
        """
        st = self.stats
        st.events += n
        out_t: list[float] = []
        out_dx: list[int] = []
        out_dy: list[int] = []
        dx0, dy0 = dx, dy = self._open_dx, self._open_dy
        dropped = self._open_dropped
        # The carried frame's counts in this form (only m > 0 and m + other are used).
        m = 1 if self._open_motion else 0
        other = self._open_nonsyn - m
        synx = self._open_events - self._open_nonsyn
        frames = skipped = lost_x = lost_y = 0
        sec = usec = 0
        for sec, usec, k, v in records:
            # Branches ordered by frequency.
            if k == KEY_REL_X:
                dx += v
                m += 1
            elif k == KEY_REL_Y:
                dy += v
                m += 1
            elif k == KEY_SYN_REPORT:
                frames += 1
                if dropped:
                    st.dropped_frames += 1
                    lost_x += dx
                    lost_y += dy
                    st.dropped_events += m + other
                    dropped = False
                elif m:
                    out_t.append(sec + usec * 1e-6)
                    out_dx.append(dx)
                    out_dy.append(dy)
                dx = dy = m = other = synx = 0
            elif k == KEY_SYN_DROPPED:
                st.syn_dropped += 1
                dropped = True
                synx += 1
            else:
                skipped += 1
                if k & 0xFFFF != EV_SYN:
                    other += 1
                else:
                    synx += 1
        st.frames += frames
        st.skipped += skipped
        st.motion_frames += len(out_t)
        if lost_x or lost_y:
            st.dropped_dx += lost_x
            st.dropped_dy += lost_y
        # Every REL_X count fed lands in exactly one place: a frame handed out, a dropped
        # frame, or the open frame (whose sum went from dx0 to dx).
        st.rel_x_in += sum(out_dx) + lost_x + dx - dx0
        st.rel_y_in += sum(out_dy) + lost_y + dy - dy0
        self._open_dx, self._open_dy = dx, dy
        self._open_motion, self._open_dropped = m > 0, dropped
        self._open_nonsyn = m + other
        self._open_events = m + other + synx
        if self._open_events:  # then the last record belongs to the open frame
            self._open_t = sec + usec * 1e-6
        return out_t, out_dx, out_dy

    def flush(self) -> MotionFrames:
        """End of a finite input: close the open frame, if any, and count it incomplete.

        A frame without its SYN_REPORT comes from a capture cut short (a recorder that was
        killed) or a device unplugged mid-frame.  Its counts did happen, so they are kept:
        it is reported as one motion frame stamped with the time of its last event (unless
        it holds a SYN_DROPPED, in which case it is dropped and counted like any other).
        ``stats.incomplete_frames`` says how many frames were closed this way.
        """
        if self._open_events == 0:
            return MotionFrames()
        st = self.stats
        st.incomplete_frames += 1
        st.incomplete_events += self._open_events
        out = MotionFrames()
        if self._open_dropped:
            st.dropped_frames += 1
            st.dropped_dx += self._open_dx
            st.dropped_dy += self._open_dy
            st.dropped_events += self._open_nonsyn
        elif self._open_motion:
            st.motion_frames += 1
            out = MotionFrames(
                np.array([self._open_t]),
                np.array([self._open_dx], dtype=np.int64),
                np.array([self._open_dy], dtype=np.int64),
            )
        self._reset_open()
        return out
