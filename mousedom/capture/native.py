"""mousedom's own capture format: every source of a rig in one append-only file.

Layout (all integers little-endian; full description in docs/captures.md)::

    file   = magic header chunk*
    magic  = b"MDCAP\\r\\n\\x1a"                      (8 bytes; catches text-mode mangling)
    header = u16 major, u16 minor, u32 n, n bytes of JSON, u32 crc32(JSON)
    chunk  = b"MDCK", u8 kind, u8 flags, u16 source, u32 count, u32 size, u32 crc,
             size bytes of payload                  (crc32 over the 16 bytes before it
                                                     and the payload as stored)

Chunk kinds: MOTION (count reports as columns: f8 t[count], i4 dx[count], i4 dy[count]),
SERIAL (count pieces of raw serial bytes: f8 t[count], u4 len[count], then the bytes),
NOTE (JSON counters of what a converted source skipped or dropped), SYNC (one f8: every
report of every source stamped at or before it is in the file by now; readers use it to
close windows while streaming).  Flag bit 0: the payload is zlib-compressed.

Why this shape: a crash can only tear the chunk being written, and each chunk is checked
by its CRC, so a reader keeps every whole chunk and reports the torn tail with its size.
A bad chunk followed by good ones is corruption, not a crash: that is an error, because
the counts in it would be silently lost.  Fixed-size columns load with numpy.frombuffer,
which is what makes the replay fast.
"""

from __future__ import annotations

import json
import os
import struct
import time
import zlib
from collections.abc import Iterator
from typing import Any, BinaryIO

import numpy as np

from mousedom.capture.base import (
    MAX_TIME_S,
    SOURCE_COUNTERS,
    TIME_BASES,
    Batch,
    Capture,
    CaptureError,
    DeviceInfo,
    DeviceStats,
    Feed,
    Motion,
    Serial,
)
from mousedom.capture.base import open_binary as _open
from mousedom.errors import located
from mousedom.safewrite import open_stream

MAGIC = b"MDCAP\r\n\x1a"
VERSION = (1, 0)
CHUNK_MAGIC = b"MDCK"
CHUNK = struct.Struct("<4sBBHIII")
MOTION, SERIAL, NOTE, SYNC = 1, 2, 3, 4
KINDS = (MOTION, SERIAL, NOTE, SYNC)
ZLIB = 1
MAX_CHUNK = 64 << 20  # larger payloads are corruption, not data
# A compressed chunk may inflate to at most this many times its stored size (and never past
# MAX_CHUNK).  What the writer stores inflates about 2:1 (motion columns) to 5:1 (serial
# bytes of an idle sensor); zlib itself reaches 1032:1, which is how a 1 MB file could
# claim a gigabyte of reports.  The bound makes what a file can cost follow its size.
MAX_INFLATE_RATIO = 100
INFLATE_SLACK = 4096  # tiny chunks (a NOTE, a SYNC) are not held to the ratio
NOTE_FIELDS = SOURCE_COUNTERS
# Counts inside dropped frames are sums of REL values: they carry a sign (a dropped frame
# of REL_X -7 is lost_x -7).  Every other counter counts things and is never negative.
SIGNED_NOTE_FIELDS = frozenset({"lost_x", "lost_y"})


# --------------------------------------------------------------------------- writer


class NativeWriter:
    """Append-only writer.  Call ``sync(t)`` whenever every source is complete up to t.

    Motion is buffered per source and written as one chunk per source at ``sync``, at
    ``flush`` or when a buffer holds ``chunk_reports`` reports; each chunk is flushed to the
    OS at once (and fsync'ed when ``fsync`` is true) so a crash loses only the buffers.
    """

    def __init__(
        self,
        file: str | os.PathLike[str] | BinaryIO,
        devices: list[DeviceInfo],
        *,
        config_text: str | None = None,
        time_base: str = "monotonic",
        compress: bool = True,
        chunk_reports: int = 65536,
        fsync: bool = False,
        meta: dict[str, Any] | None = None,
        inputs: tuple[str | None, ...] = (),
    ) -> None:
        if time_base not in TIME_BASES:
            raise ValueError(f"time_base must be one of {TIME_BASES}")
        if isinstance(file, (str, os.PathLike)):
            # No link followed, none of ``inputs`` (config, captures) clobbered.
            self._f: BinaryIO = open_stream(str(file), inputs)
            self._own = True
        else:
            self._f, self._own = file, False
        self.devices = list(devices)
        self.compress = compress
        self.chunk_reports = chunk_reports
        self.fsync = fsync
        self._buf: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = [[] for _ in devices]
        self._buffered = [0] * len(devices)
        self.reports_written = 0
        header = {
            "format": "mousedom-capture",
            "version": list(VERSION),
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "time_base": time_base,
            "devices": [d.as_dict() for d in devices],
            "config": config_text,
            **(meta or {}),
        }
        body = json.dumps(header, sort_keys=True).encode()
        self._f.write(MAGIC + struct.pack("<HHI", *VERSION, len(body)) + body)
        self._f.write(struct.pack("<I", zlib.crc32(body)))
        self._f.flush()

    def motion(self, device: int, t, dx, dy) -> None:
        t = np.ascontiguousarray(t, dtype="<f8")
        if not len(t):
            return
        bad = ~(np.abs(t) < MAX_TIME_S)
        if bad.any():  # the reader refuses them: never write them
            k = int(np.argmax(bad))
            raise CaptureError(
                f"device {self.devices[device].name!r}: report {k} of a batch has time "
                f"{t[k]!r}: the native format holds finite times below {MAX_TIME_S:g} s only"
            )
        dx, dy = np.asarray(dx), np.asarray(dy)
        for d in (dx, dy):
            # A frame's summed counts may exceed the i4 columns: refuse rather than wrap.
            if d.dtype.itemsize > 4 and len(d) and (d.min() < -(2**31) or d.max() >= 2**31):
                self._too_big(device, t, dx, dy)
        self._buf[device].append((t, dx.astype("<i4"), dy.astype("<i4")))
        self._buffered[device] += len(t)
        if self._buffered[device] >= self.chunk_reports:
            self._flush_motion(device)

    def _too_big(self, device: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        big = (dx < -(2**31)) | (dx >= 2**31) | (dy < -(2**31)) | (dy >= 2**31)
        k = int(np.argmax(big))
        dev = self.devices[device]
        src = dev.extra.get("converted_from")
        raise CaptureError(
            f"{src or dev.name}: device {dev.name!r}: the report at t={t[k]:.6f} holds "
            f"({int(dx[k])}, {int(dy[k])}) counts, beyond the native format's signed 32 bits"
        )

    def serial(self, device: int, t: float, data: bytes) -> None:
        """One read() of a serial port: its bytes and host time of arrival."""
        self.serial_many(device, [t], [data])

    def serial_many(self, device: int, ts: list[float], pieces: list[bytes]) -> None:
        if not pieces:
            return
        for t in ts:
            if not _plausible_time(t):
                raise CaptureError(
                    f"device {self.devices[device].name!r}: serial read at time {t!r}: "
                    f"the native format holds finite times below {MAX_TIME_S:g} s only"
                )
        head = np.asarray(ts, dtype="<f8").tobytes()
        head += np.asarray([len(p) for p in pieces], dtype="<u4").tobytes()
        self._chunk(SERIAL, device, len(pieces), head + b"".join(pieces))

    def note(self, device: int, stats: DeviceStats) -> None:
        """Record what the source skipped or dropped (for a converted capture's summary)."""
        body = {k: getattr(stats, k) for k in NOTE_FIELDS}
        try:
            note_counters(body)  # the reader's rule: never write what it would refuse
        except ValueError as e:
            raise CaptureError(
                f"device {self.devices[device].name!r}: its counters cannot be recorded: {e}"
            ) from None
        self._chunk(NOTE, device, 1, json.dumps(body, sort_keys=True).encode())

    def sync(self, complete: float) -> None:
        if not _plausible_time(complete) and complete != np.inf:
            raise CaptureError(f"sync at time {complete!r}: not a time the reader accepts")
        self.flush()
        self._chunk(SYNC, 0, 1, struct.pack("<d", complete))

    def flush(self) -> None:
        for d in range(len(self.devices)):
            self._flush_motion(d)
        self._f.flush()

    def close(self) -> None:
        if self._f.closed:
            return
        self.flush()
        if self.fsync:
            os.fsync(self._f.fileno())
        if self._own:
            self._f.close()

    def __enter__(self) -> NativeWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _flush_motion(self, device: int) -> None:
        parts = self._buf[device]
        if not parts:
            return
        t = np.concatenate([p[0] for p in parts])
        dx = np.concatenate([p[1] for p in parts])
        dy = np.concatenate([p[2] for p in parts])
        self._buf[device] = []
        self._buffered[device] = 0
        for s in range(0, len(t), self.chunk_reports):
            e = s + self.chunk_reports
            payload = t[s:e].tobytes() + dx[s:e].tobytes() + dy[s:e].tobytes()
            self._chunk(MOTION, device, len(t[s:e]), payload)
            self.reports_written += len(t[s:e])

    def _chunk(self, kind: int, source: int, count: int, payload: bytes) -> None:
        flags = 0
        if self.compress and len(payload) > 64:
            packed = zlib.compress(payload, 1)
            if len(packed) < len(payload):
                payload, flags = packed, ZLIB
        head = CHUNK.pack(CHUNK_MAGIC, kind, flags, source, count, len(payload), 0)[:16]
        crc = _chunk_crc(head, payload)
        self._f.write(head + struct.pack("<I", crc) + payload)
        self._f.flush()
        if self.fsync:
            os.fsync(self._f.fileno())


# --------------------------------------------------------------------------- reader


def is_native(prefix: bytes) -> bool:
    return prefix.startswith(MAGIC)


class NativeCapture(Capture):
    format = "native"

    def __init__(self, path: str, data_path: str | None = None) -> None:
        super().__init__(path, data_path)
        with _open(self.data_path) as f:
            self.header, self._body_offset = _read_header(path, f)
        h = self.header
        try:
            self.devices = [DeviceInfo.from_dict(d) for d in h["devices"]]
            self.time_base = h["time_base"]
            if self.time_base not in TIME_BASES:
                raise ValueError(f"unknown time_base {self.time_base!r}")
        except (KeyError, TypeError, ValueError) as e:
            raise CaptureError(located(path, None, f"header: {e}")) from None
        self.config_text: str | None = h.get("config")
        self.reset_stats()
        self._first: float | None | bool = False

    def first_time(self) -> float | None:
        stated = self.header.get("first_time")
        if self._first is False and isinstance(stated, (int, float)):
            if not _plausible_time(stated):
                raise CaptureError(
                    located(self.path, None, f"header: first_time {stated!r} is not a time")
                )
            self._first = float(stated)
        if self._first is False:
            first = None
            chunks = self._chunks(check_tail=False, head_only=8)
            for kind, _source, count, payload, offset in chunks:
                if kind in (MOTION, SERIAL) and count:  # both start with the f8 times
                    if len(payload) < 8:
                        raise CaptureError(
                            located(self.path, None, f"byte offset {offset}: chunk of "
                                    f"{count} reports holds only {len(payload)} bytes")
                        )  # fmt: skip
                    t0 = float(np.frombuffer(payload, "<f8", 1)[0])
                    if not _plausible_time(t0):
                        raise CaptureError(
                            located(
                                self.path, None, f"byte offset {offset}: time {t0!r} out of range"
                            )
                        )
                    first = t0 if first is None else min(first, t0)
                elif kind == SYNC and first is not None:
                    break  # everything before the first sync point has been seen
            self._first = first
        return self._first  # type: ignore[return-value]

    def feeds(self) -> list[Feed]:
        self.reset_stats()
        return [Feed(tuple(range(len(self.devices))), self._batches())]

    def _batches(self, max_pending: int = 1 << 20) -> Iterator[Batch]:
        motion: list[Motion] = []
        serial: list[Serial] = []
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
            st = self.stats[source]
            if kind == MOTION:
                t, dx, dy = _motion_columns(self.path, payload, count, offset)
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
                st.add_motion(t, dx, dy)
                motion.append(Motion(source, t, dx, dy))
                pending += count
            elif kind == SERIAL:
                t, pieces = _serial_pieces(self.path, payload, count, offset)
                st.serial_bytes += sum(map(len, pieces))
                serial.append(Serial(source, t, pieces))
                pending += count
            elif kind == NOTE:
                try:
                    st.merge(DeviceStats(**note_counters(json.loads(payload))))
                except (ValueError, RecursionError) as e:
                    raise CaptureError(
                        located(self.path, None, f"byte offset {offset}: malformed note: {e}")
                    ) from None
            elif kind == SYNC:
                (w,) = struct.unpack("<d", payload[:8]) if len(payload) == 8 else (np.nan,)
                if not _plausible_time(w) and w != np.inf:
                    raise CaptureError(
                        located(self.path, None, f"byte offset {offset}: malformed sync")
                    )
                yield Batch(motion, serial, w)
                motion, serial, pending = [], [], 0
            if pending >= max_pending:
                yield Batch(motion, serial, -np.inf)
                motion, serial, pending = [], [], 0
        yield Batch(motion, serial, np.inf)

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
                bad = _check_chunk_head(head)
                payload = b""
                if bad is None:
                    magic, kind, flags, source, count, size, crc = CHUNK.unpack(head)
                    payload = reader.read(size)
                    if len(payload) < size:
                        bad = "chunk cut short"
                    elif _chunk_crc(head, payload) != crc:
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
        if kind == MOTION:
            limit = min(limit, 16 * count)  # exactly this, or _motion_columns refuses it
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
                        f"{MAX_INFLATE_RATIO}x its size, {16 * count} for {count} reports): "
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
        at = rest.find(CHUNK_MAGIC)
        while at >= 0:
            head = rest[at : at + CHUNK.size]
            if len(head) == CHUNK.size and _check_chunk_head(head) is None:
                *_, size_, crc = CHUNK.unpack(head)
                payload = rest[at + CHUNK.size : at + CHUNK.size + size_]
                if len(payload) == size_ and _chunk_crc(head, payload) == crc:
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


def _chunk_crc(head: bytes, payload: bytes) -> int:
    """CRC-32 over the first 16 bytes of the chunk header and the payload as stored."""
    return zlib.crc32(payload, zlib.crc32(head[:16]))


def _check_chunk_head(head: bytes) -> str | None:
    if len(head) < CHUNK.size:
        return "chunk header cut short"
    magic, kind, flags, source, count, size, crc = CHUNK.unpack(head)
    if magic != CHUNK_MAGIC:
        return "no chunk marker"
    if kind not in KINDS or flags & ~ZLIB or size > MAX_CHUNK:
        return "malformed chunk header"
    return None


def _read_header(path: str, f: BinaryIO) -> tuple[dict[str, Any], int]:
    magic = f.read(len(MAGIC))
    if magic != MAGIC:
        raise CaptureError(located(path, None, "byte offset 0: not a mousedom native capture"))
    fixed = f.read(8)
    if len(fixed) < 8:
        raise CaptureError(located(path, None, "byte offset 8: header cut short"))
    major, minor, n = struct.unpack("<HHI", fixed)
    if major != VERSION[0]:
        raise CaptureError(
            located(
                path,
                None,
                f"byte offset 8: unknown native capture version {major}.{minor} "
                f"(this reader knows {VERSION[0]}.x)",
            )
        )
    if n > MAX_CHUNK:
        raise CaptureError(located(path, None, "byte offset 12: header length is implausible"))
    body = f.read(n)
    crc = f.read(4)
    if len(body) < n or len(crc) < 4:
        raise CaptureError(located(path, None, "byte offset 16: header cut short"))
    if zlib.crc32(body) != struct.unpack("<I", crc)[0]:
        raise CaptureError(located(path, None, "byte offset 16: header CRC mismatch"))
    try:
        header = json.loads(body)
        if not isinstance(header, dict) or not isinstance(header.get("devices"), list):
            raise ValueError("no device list")
    except ValueError as e:
        raise CaptureError(located(path, None, f"byte offset 16: bad header: {e}")) from None
    return header, len(MAGIC) + 8 + n + 4


def _motion_columns(path: str, payload: bytes, count: int, offset: int):
    if len(payload) != 16 * count:
        raise CaptureError(
            located(path, None, f"byte offset {offset}: motion chunk of {count} reports holds "
                    f"{len(payload)} bytes, not {16 * count}")
        )  # fmt: skip
    t = np.frombuffer(payload, "<f8", count)
    dx = np.frombuffer(payload, "<i4", count, 8 * count).astype(np.int64)
    dy = np.frombuffer(payload, "<i4", count, 12 * count).astype(np.int64)
    if not (np.abs(t) < MAX_TIME_S).all():  # NaN fails this too
        raise CaptureError(located(path, None, f"byte offset {offset}: time out of range"))
    return t, dx, dy


def _plausible_time(t: float) -> bool:
    return bool(abs(t) < MAX_TIME_S)  # False for NaN and inf


def note_counters(note: object) -> dict[str, int]:
    """A NOTE's counters, checked (ValueError naming the first bad one): the one rule that
    the writer applies before writing and the reader when reading.

    Each is an integer that floats hold exactly (below 2**53 in size); the counts lost in
    dropped frames may be negative, every other counter may not.  A missing key is 0."""
    if not isinstance(note, dict):
        raise ValueError("not a JSON object")
    out = {}
    for k in NOTE_FIELDS:
        v = note.get(k, 0)
        low = -(2**53) if k in SIGNED_NOTE_FIELDS else 0
        if isinstance(v, bool) or not isinstance(v, int) or not low <= v < 2**53:
            raise ValueError(f"{k}: not a counter: {v!r}")
        out[k] = v
    return out


def _serial_pieces(path: str, payload: bytes, count: int, offset: int):
    if len(payload) < 12 * count:
        raise CaptureError(located(path, None, f"byte offset {offset}: serial chunk too short"))
    t = np.frombuffer(payload, "<f8", count)
    if not (np.abs(t) < MAX_TIME_S).all():  # NaN fails this too
        raise CaptureError(located(path, None, f"byte offset {offset}: serial time out of range"))
    lens = np.frombuffer(payload, "<u4", count, 8 * count).astype(np.int64)
    if 12 * count + int(lens.sum()) != len(payload):
        raise CaptureError(
            located(path, None, f"byte offset {offset}: serial chunk lengths do not add up")
        )
    ends = 12 * count + np.cumsum(lens)
    starts = ends - lens
    pieces = [payload[s:e] for s, e in zip(starts.tolist(), ends.tolist(), strict=False)]
    return t, pieces
