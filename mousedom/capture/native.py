"""Reading mousedom's own capture format (every source of a rig in one append-only file):
``NativeCapture`` streams its chunks as batches, keeps every whole chunk of a torn file,
and refuses corruption.  The layout, and why it has that shape, is in
``capture.native_format``; the writer is ``capture.native_writer``.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Iterator

import numpy as np

from mousedom.capture.base import (
    GYRO_KIND,
    TIME_BASES,
    Batch,
    Capture,
    CaptureError,
    DeviceInfo,
    DeviceStats,
    Feed,
    Motion,
    Rates,
    Serial,
)
from mousedom.capture.base import open_binary as _open
from mousedom.capture.native_format import (
    CHUNK,
    CHUNK_MAGIC,
    FIXED_KINDS,
    GYRO_VERSION,
    HEADER_JSON_OFFSET,
    INFLATE_SLACK,
    MAGIC,
    MAX_CHUNK,
    MAX_INFLATE_RATIO,
    MOTION,
    NOTE,
    RATE,
    RATE_SATURATED,
    RECORD_BYTES,
    SERIAL,
    SYNC,
    VERSION,
    ZLIB,
    check_chunk_head,
    chunk_crc,
    is_native,
    motion_columns,
    note_counters,
    plausible_time,
    rate_columns,
    read_header,
    serial_pieces,
)
from mousedom.capture.native_writer import NativeWriter
from mousedom.errors import located

# Re-exported: the format's names that importers (tests, fuzzers, the recorder) take from
# here; the layout lives in native_format, the writer in native_writer.
_chunk_crc = chunk_crc
__all__ = ["CHUNK", "GYRO_VERSION", "MAGIC", "MOTION", "RATE", "VERSION", "ZLIB",
           "NativeCapture", "NativeWriter", "is_native", "note_counters"]  # fmt: skip

# How far after the first stamp a header's grid_start may be: a live source's reports come
# stamped from the daemon's start less its read latency (milliseconds), never a second.
GRID_START_LEAD = 1.0


# A bad chunk's scan for good data after it checks at most this many times the rest's
# bytes (``_bad_chunk``).
SCAN_BUDGET = 8


class NativeCapture(Capture):
    format = "native"

    def __init__(self, path: str, data_path: str | None = None) -> None:
        super().__init__(path, data_path)
        with _open(self.data_path) as f:
            self.header, self.major, self._body_offset = read_header(path, f)
        h = self.header
        try:
            self.devices = [DeviceInfo.from_dict(d) for d in h["devices"]]
            self.time_base = h["time_base"]
            if self.time_base not in TIME_BASES:
                raise ValueError(f"unknown time_base {self.time_base!r}")
            gyros = [d.name for d in self.devices if d.kind == GYRO_KIND]
            if gyros and self.major < GYRO_VERSION[0]:
                raise ValueError(
                    f"device {gyros[0]!r} is a gyro ({GYRO_KIND!r}), which a version "
                    f"{self.major}.x file cannot hold (gyros came with {GYRO_VERSION[0]}.0)"
                )
        except (KeyError, TypeError, ValueError) as e:
            raise CaptureError(located(path, None, f"header: {e}")) from None
        self.config_text: str | None = h.get("config")
        self.reset_stats()
        self._first_known = False  # the first time is found once, then kept
        self._first: float | None = None

    def first_time(self) -> float | None:
        """The header's ``first_time`` (the sources' first event, which anchors the window
        grid: at or before the first stamp), else the first stamp; both as the window grid
        reads them, from the chunks up to the first sync point (a writer's sync point
        promises that every earlier stamp is in the file before it)."""
        if not self._first_known:
            stated = self._stated_first_time()
            scanned, offset = self._scan_first_time()
            if stated is not None and scanned is not None and stated > scanned:
                raise CaptureError(
                    located(self.path, None, f"byte offset {HEADER_JSON_OFFSET}: header: "
                            f"first_time {stated!r} is later than the first stamp "
                            f"({scanned!r}, in the chunk at byte offset {offset}): it "
                            "would put the window grid after reports it must hold")
                )  # fmt: skip
            self._first = stated if stated is not None else scanned
            self._first_known = True
        return self._first

    def grid_start(self) -> float | None:
        """The header's ``grid_start`` (``run --record`` writes the daemon's window grid's
        start): absent or null, or a time at most GRID_START_LEAD after the first stamp
        (the daemon takes reports from its start less its sources' latency: a grid begun
        later would lump earlier reports into its first window); CaptureError otherwise."""
        stated = self._header_time("grid_start")
        first = self.first_time() if stated is not None else None
        if stated is None or first is None or stated <= first + GRID_START_LEAD:
            return stated
        raise self._header_error("grid_start", stated, f"is later than the first stamp "
                                 f"({first!r}) by more than {GRID_START_LEAD} s")  # fmt: skip

    def _stated_first_time(self) -> float | None:
        """The header's ``first_time``: absent (or null), or a finite number of seconds
        (not a bool, not a string); CaptureError naming it otherwise."""
        return self._header_time("first_time")

    def _header_time(self, key: str) -> float | None:
        """A header time (``first_time``, ``grid_start``): absent (or null), or a finite
        number of seconds (not a bool, not a string); CaptureError naming it otherwise."""
        stated = self.header.get(key)
        if stated is None:
            return None
        if isinstance(stated, bool) or not isinstance(stated, (int, float)):
            raise self._header_error(key, stated, "is not a number")
        if not plausible_time(stated):
            raise self._header_error(
                key, stated, "is not a time (a finite number of seconds below 1e10)"
            )
        return float(stated)

    def _header_error(self, key: str, stated: object, what: str) -> CaptureError:
        return CaptureError(
            located(self.path, None, f"byte offset {HEADER_JSON_OFFSET}: header: {key} "
                    f"{stated!r:.40} {what}")
        )  # fmt: skip

    def _scan_first_time(self) -> tuple[float | None, int]:
        """The earliest stamp and the byte offset of its chunk, read from the chunks up to
        the first sync point that follows one."""
        first = None
        first_at = 0
        for kind, _source, count, payload, offset in self._chunks(check_tail=False, head_only=8):
            if kind in (MOTION, SERIAL, RATE, RATE_SATURATED) and count:  # f8 times first
                if len(payload) < 8:
                    raise CaptureError(
                        located(self.path, None, f"byte offset {offset}: chunk of "
                                f"{count} reports holds only {len(payload)} bytes")
                    )  # fmt: skip
                t0 = float(np.frombuffer(payload, "<f8", 1)[0])
                if not plausible_time(t0):
                    raise CaptureError(
                        located(
                            self.path, None, f"byte offset {offset}: time out of range ({t0!r})"
                        )
                    )
                if first is None or t0 < first:
                    first, first_at = t0, offset
            elif kind == SYNC and first is not None:
                break  # everything before the first sync point has been seen
        return first, first_at

    def feeds(self) -> list[Feed]:
        self.first_time()  # a header's first_time that is none is refused before any report
        self.reset_stats()
        return [Feed(tuple(range(len(self.devices))), self._batches())]

    def _batches(self, max_pending: int = 1 << 20) -> Iterator[Batch]:
        out = Batch([], [], -np.inf)
        pending = 0
        last = [-np.inf] * len(self.devices)
        for kind, source, count, payload, offset in self._chunks(check_tail=True):
            if source >= len(self.devices):
                raise CaptureError(
                    located(
                        self.path,
                        None,
                        f"byte offset {offset}: chunk for source "
                        f"{source}, but the header lists {len(self.devices)} devices",
                    )
                )
            self._check_kind(kind, source, offset)
            st = self.stats[source]
            if kind == MOTION:
                t, dx, dy = motion_columns(self.path, payload, count, offset)
                self._in_order(t, last, source, offset)
                st.add_motion(t, dx, dy)
                out.motion.append(Motion(source, t, dx, dy))
                pending += count
            elif kind in (RATE, RATE_SATURATED):
                t, rate, saturated = rate_columns(self.path, payload, count, offset, kind)
                self._in_order(t, last, source, offset)
                st.add_rates(t, saturated)
                out.gyro.append(Rates(source, t, rate, saturated))
                pending += count
            elif kind == SERIAL:
                t, pieces = serial_pieces(self.path, payload, count, offset)
                # (host times of the reads: the decoder maps the firmware's clock onto
                # them, and one read stamped back held every later report at one instant)
                self._in_order(t, last, source, offset)
                st.serial_bytes += sum(map(len, pieces))
                out.serial.append(Serial(source, t, pieces))
                pending += count
            elif kind == NOTE:
                self._note(st, payload, offset)
            elif kind == SYNC:
                (w,) = struct.unpack("<d", payload[:8]) if len(payload) == 8 else (np.nan,)
                if not plausible_time(w) and w != np.inf:
                    raise CaptureError(
                        located(self.path, None, f"byte offset {offset}: malformed sync")
                    )
                out.complete = w
                yield out
                out, pending = Batch([], [], -np.inf), 0
            if pending >= max_pending:
                yield out
                out, pending = Batch([], [], -np.inf), 0
        out.complete = np.inf
        yield out

    def _check_kind(self, kind: int, source: int, offset: int) -> None:
        """A device's data chunks are of its kind: a gyro's are RATE (or RATE_SATURATED)
        and such a chunk is a gyro's (a file of version 2 or later, which the header's
        devices have been checked for); SERIAL bytes are a serial device's (an evdev
        device's were decoded as ADNS-3080 packets) and it has no motion reports."""
        if kind not in (MOTION, RATE, RATE_SATURATED, SERIAL):
            return
        device_kind = self.devices[source].kind
        wanted = {MOTION: "evdev", RATE: GYRO_KIND, RATE_SATURATED: GYRO_KIND, SERIAL: "serial"}
        if device_kind != wanted[kind]:
            what = {MOTION: "motion reports", SERIAL: "serial bytes"}.get(kind, "gyro samples")
            raise CaptureError(
                located(self.path, None, f"byte offset {offset}: {what} for device "
                        f"{self.devices[source].name!r}, which is of kind "
                        f"{self.devices[source].kind!r}")
            )  # fmt: skip

    def _in_order(self, t: np.ndarray, last: list[float], source: int, offset: int) -> None:
        """A device's stamps never go backwards, within a chunk or from one to the next."""
        if len(t) and (t[0] < last[source] or (np.diff(t) < 0).any()):
            raise CaptureError(
                located(
                    self.path,
                    None,
                    f"byte offset {offset}: time goes "
                    f"backwards for device {self.devices[source].name!r}",
                )
            )
        if len(t):
            last[source] = float(t[-1])

    def _note(self, st: DeviceStats, payload: bytes, offset: int) -> None:
        try:
            st.merge(DeviceStats(**note_counters(json.loads(payload))))
        except (ValueError, RecursionError) as e:
            raise CaptureError(
                located(self.path, None, f"byte offset {offset}: malformed note: {e}")
            ) from None

    def _chunks(
        self, *, check_tail: bool, head_only: int | None = None
    ) -> Iterator[tuple[int, int, int, bytes, int]]:
        """(kind, source, count, payload, offset) of each whole chunk, in file order.

        ``head_only``: a compressed payload is inflated only up to that many bytes (what
        ``first_time`` reads: one stamp); the full read checks the rest of its data."""
        with _open(self.data_path) as f:
            f.seek(self._body_offset)
            reader = f
            offset = self._body_offset
            while True:
                head = reader.read(CHUNK.size)
                if not head:
                    return
                bad = check_chunk_head(head)
                payload = b""
                if bad is None:
                    magic, kind, flags, source, count, size, crc = CHUNK.unpack(head)
                    payload = reader.read(size)
                    if len(payload) < size:
                        bad = "chunk cut short"
                    elif chunk_crc(head, payload) != crc:
                        bad = "chunk CRC mismatch"
                if bad is not None:
                    if check_tail:
                        self._bad_chunk(offset, bad)
                    return
                if flags & ZLIB:
                    payload = self._inflate(payload, kind, count, offset, head_only)
                yield kind, source, count, payload, offset
                offset += CHUNK.size + size
                if check_tail:
                    self.bytes_done = offset

    def _inflate(
        self, stored: bytes, kind: int, count: int, offset: int, head_only: int | None
    ) -> bytes:
        """A compressed payload inflated, never past what its kind and stored size allow
        (CaptureError naming the offset otherwise): the work a chunk causes is bounded by
        its size on disk, not by what it claims."""
        limit = min(MAX_CHUNK, MAX_INFLATE_RATIO * len(stored) + INFLATE_SLACK)
        if kind in FIXED_KINDS:
            # exactly this, or their columns are refused
            limit = min(limit, RECORD_BYTES[kind] * count)
        d = zlib.decompressobj()
        try:
            if head_only is not None:
                return d.decompress(stored, head_only)
            out = d.decompress(stored, limit + 1)
        except zlib.error:
            raise CaptureError(
                located(self.path, None, f"byte offset {offset}: bad zlib data")
            ) from None
        if len(out) > limit or d.unconsumed_tail:
            raise CaptureError(
                located(self.path, None, f"byte offset {offset}: a chunk of {len(stored)} "
                        f"compressed bytes inflates past {limit} bytes (at most "
                        f"{MAX_INFLATE_RATIO}x its size, {RECORD_BYTES.get(kind, 16) * count} for "
                        f"{count} reports): "
                        "a decompression bomb, not a capture")
            )  # fmt: skip
        if not d.eof:
            raise CaptureError(
                located(self.path, None, f"byte offset {offset}: bad zlib data (cut short)")
            )
        return out

    def _bad_chunk(self, offset: int, why: str) -> None:
        """A torn tail is a warning; a bad chunk with good ones after it is an error."""
        size = os.path.getsize(self.data_path)
        with _open(self.data_path) as f:
            f.seek(offset + 1)
            rest = f.read()
        # Each candidate's checksum reads what its head claims: a file of markers each
        # claiming a large chunk cost a scan quadratic in its size (4 MB: 65 s).  The
        # bytes checked are bounded by a multiple of the rest; past it, which it is
        # cannot be told cheaply, and the file is refused rather than guessed at.
        budget = SCAN_BUDGET * len(rest) + (1 << 20)
        view = memoryview(rest)
        at = rest.find(CHUNK_MAGIC)
        while at >= 0:
            head = rest[at : at + CHUNK.size]
            if len(head) == CHUNK.size and check_chunk_head(head) is None:
                *_, size_, crc = CHUNK.unpack(head)
                payload = view[at + CHUNK.size : at + CHUNK.size + size_]
                budget -= len(payload)
                if budget < 0:
                    raise CaptureError(
                        located(self.path, None, f"byte offset {offset}: {why}, and the "
                                "rest holds too many chunk markers to tell whether good "
                                "data follows: the file is corrupted")
                    )  # fmt: skip
                if len(payload) == size_ and chunk_crc(head, payload) == crc:
                    raise CaptureError(
                        located(
                            self.path,
                            None,
                            f"byte offset {offset}: {why}, and good data follows at byte "
                            f"offset {offset + 1 + at}: the file is corrupted, not just cut "
                            "short",
                        )
                    )
            at = rest.find(CHUNK_MAGIC, at + 1)
        torn = size - offset
        for st in self.stats[:1]:
            st.torn_bytes += torn
        self.warnings.append(
            f"{self.path}: byte offset {offset}: {why}; the last {torn} bytes are an "
            "unfinished chunk (recording interrupted) and were skipped"
        )
