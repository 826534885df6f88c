"""Writing the native capture format (see ``capture.native_format`` for its layout)."""

from __future__ import annotations

import json
import math
import os
import struct
import time
import zlib
from collections.abc import Iterable
from typing import Any, BinaryIO, cast

import numpy as np

from mousedom.capture.base import (
    GYRO_KIND,
    MAX_TIME_S,
    TIME_BASES,
    CaptureError,
    DeviceInfo,
    DeviceStats,
)
from mousedom.capture.native_format import (
    CHUNK,
    CHUNK_MAGIC,
    MAGIC,
    MOTION,
    NOTE,
    NOTE_FIELDS,
    RATE,
    RATE_SATURATED,
    SERIAL,
    SYNC,
    ZLIB,
    chunk_crc,
    note_counters,
    plausible_time,
    version_for,
)
from mousedom.errors import escaped
from mousedom.safewrite import open_stream
from mousedom.sources.base import MAX_RATE


def beyond_i4(dx, dy) -> int | None:
    """Index of the first report whose counts do not fit the native format's signed 32-bit
    columns, or None where all fit (the one rule: the writer refuses them, ``record`` stops
    at them)."""
    dx, dy = np.asarray(dx), np.asarray(dy)
    big = (dx < -(2**31)) | (dx >= 2**31) | (dy < -(2**31)) | (dy >= 2**31)
    return int(np.argmax(big)) if big.any() else None


class NativeWriter:
    """Append-only writer.  Call ``sync(t)`` whenever every source is complete up to t.

    Motion (and a gyro's samples) is buffered per source and written as one chunk per
    source at ``sync``, at ``flush`` or when a buffer holds ``chunk_reports`` reports; each
    chunk is flushed to the OS at once (and fsync'ed when ``fsync`` is true) so a crash
    loses only the buffers.  A file with a gyro device (kind "iio") is version 2.1, one
    without is 1.0 (native_format's docstring says why).
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
        inputs: Iterable[str | None] = (),
    ) -> None:
        if time_base not in TIME_BASES:
            raise ValueError(f"time_base must be one of {TIME_BASES}")
        if isinstance(file, (str, os.PathLike)):
            # No link followed, none of ``inputs`` (config, captures) clobbered.
            # Binary: open_stream opens text only when asked (text=True).
            self._f = cast(BinaryIO, open_stream(str(file), inputs))
            self._own = True
        else:
            self._f, self._own = file, False
        self.devices = list(devices)
        self.compress = compress
        self.chunk_reports = chunk_reports
        self.fsync = fsync
        # Per source, its columns (t, dx, dy) or, for a gyro, (t, rate, saturated), as given
        self._buf: list[list[tuple[np.ndarray, ...]]] = [[] for _ in devices]
        self._buffered = [0] * len(devices)
        self._serial_t = [-math.inf] * len(devices)  # each serial device's last read
        self.reports_written = 0
        self.samples_written = 0  # a gyro's
        version = version_for([d.kind for d in devices])
        header = {
            "format": "mousedom-capture",
            "version": list(version),
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "time_base": time_base,
            "devices": [d.as_dict() for d in devices],
            "config": config_text,
            **(meta or {}),
        }
        body = json.dumps(header, sort_keys=True).encode()
        self._f.write(MAGIC + struct.pack("<HHI", *version, len(body)) + body)
        self._f.write(struct.pack("<I", zlib.crc32(body)))
        self._f.flush()

    def motion(self, device: int, t, dx, dy) -> None:
        self._of_kind(device, motion=True)
        t = np.ascontiguousarray(t, dtype="<f8")
        if not len(t):
            return
        self._check_times(device, t, "report")
        dx, dy = np.asarray(dx), np.asarray(dy)
        # A frame's summed counts may exceed the i4 columns: refuse rather than wrap.
        if (dx.dtype.itemsize > 4 or dy.dtype.itemsize > 4) and beyond_i4(dx, dy) is not None:
            self._too_big(device, t, dx, dy)
        self._buffer(device, (t, dx.astype("<i4"), dy.astype("<i4")))

    def gyro(self, device: int, t, rate, saturated=None) -> None:
        """A gyro's samples (device of kind "iio"): stamps (s) and yaw rates (rad/s),
        stored as float64 exactly as given, and which were read at the converter's limit
        (``saturated``, bool per sample; None: none)."""
        self._of_kind(device, motion=False)
        t = np.ascontiguousarray(t, dtype="<f8")
        rate = np.ascontiguousarray(rate, dtype="<f8")
        if t.shape != rate.shape or t.ndim != 1:
            raise ValueError(f"gyro: t and rate must be 1-D of one length, got "
                             f"{t.shape}, {rate.shape}")  # fmt: skip
        sat = np.zeros(t.shape, "u1") if saturated is None else np.asarray(saturated, bool)
        if sat.shape != t.shape:
            raise ValueError(f"gyro: saturated must be as long as t, got {sat.shape}")
        if not len(t):
            return
        self._check_times(device, t, "sample")
        bad = ~(np.abs(rate) < MAX_RATE)
        if bad.any():  # the reader refuses them: never write them
            k = int(np.argmax(bad))
            raise CaptureError(
                f"device {self.devices[device].name!r}: sample {k} of a batch has rate "
                f"{float(rate[k])!r}: the native format holds finite rates below {MAX_RATE:g} rad/s"
            )
        # (copies: the caller may reuse its arrays)
        self._buffer(device, (t.copy(), rate.copy(), sat.astype("u1")))

    def _of_kind(self, device: int, *, motion: bool) -> None:
        """Motion for mice, samples for the gyro: the reader refuses anything else."""
        dev = self.devices[device]
        if (dev.kind == GYRO_KIND) == motion:
            what = "motion reports" if motion else "gyro samples"
            raise ValueError(f"device {dev.name!r} is of kind {dev.kind!r}: no {what}")

    def _check_times(self, device: int, t: np.ndarray, what: str) -> None:
        bad = ~(np.abs(t) < MAX_TIME_S)
        if bad.any():  # the reader refuses them: never write them
            k = int(np.argmax(bad))
            raise CaptureError(
                f"device {self.devices[device].name!r}: {what} {k} of a batch has time "
                f"{float(t[k])!r}: the native format holds finite times below {MAX_TIME_S:g} s only"
            )

    def _buffer(self, device: int, columns: tuple[np.ndarray, ...]) -> None:
        self._buf[device].append(columns)
        self._buffered[device] += len(columns[0])
        if self._buffered[device] >= self.chunk_reports:
            self._flush_motion(device)

    def _too_big(self, device: int, t: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> None:
        k = beyond_i4(dx, dy) or 0
        dev = self.devices[device]
        src = dev.extra.get("converted_from")
        raise CaptureError(
            f"{escaped(src or dev.name)}: device {dev.name!r}: the report at t={t[k]:.6f} holds "
            f"({int(dx[k])}, {int(dy[k])}) counts, beyond the native format's signed 32 bits"
        )

    def serial(self, device: int, t: float, data: bytes) -> None:
        """One read() of a serial port: its bytes and host time of arrival."""
        self.serial_many(device, [t], [data])

    def serial_many(self, device: int, ts: list[float], pieces: list[bytes]) -> None:
        dev = self.devices[device]
        if dev.kind != "serial":  # the reader refuses them: never write them
            raise ValueError(f"device {dev.name!r} is of kind {dev.kind!r}: no serial bytes")
        if not pieces:
            return
        last = self._serial_t[device]
        for t in ts:
            if not plausible_time(t):
                raise CaptureError(
                    f"device {dev.name!r}: serial read at time {t!r}: "
                    f"the native format holds finite times below {MAX_TIME_S:g} s only"
                )
            if t < last:
                raise CaptureError(
                    f"device {dev.name!r}: serial read at time {t!r} after one at {last!r}: "
                    "the native format holds a device's reads in time order"
                )
            last = t
        self._serial_t[device] = last
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
        if not plausible_time(complete) and complete != np.inf:
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
        """A source's buffered columns as chunks: MOTION (t, dx, dy), or for a gyro RATE
        (t, rate), RATE_SATURATED (t, rate, saturated) where a sample of the chunk is."""
        parts = self._buf[device]
        if not parts:
            return
        columns = [np.concatenate([p[i] for p in parts]) for i in range(len(parts[0]))]
        self._buf[device] = []
        self._buffered[device] = 0
        kind = RATE if self.devices[device].kind == GYRO_KIND else MOTION
        n = len(columns[0])
        for s in range(0, n, self.chunk_reports):
            e = s + self.chunk_reports
            part = [c[s:e] for c in columns]
            count = len(part[0])
            this = kind
            if kind == RATE:
                this = RATE_SATURATED if part[2].any() else RATE
                part = part if this == RATE_SATURATED else part[:2]
            self._chunk(this, device, count, b"".join(c.tobytes() for c in part))
            if kind == RATE:
                self.samples_written += count
            else:
                self.reports_written += count

    def _chunk(self, kind: int, source: int, count: int, payload: bytes) -> None:
        flags = 0
        if self.compress and len(payload) > 64:
            packed = zlib.compress(payload, 1)
            if len(packed) < len(payload):
                payload, flags = packed, ZLIB
        head = CHUNK.pack(CHUNK_MAGIC, kind, flags, source, count, len(payload), 0)[:16]
        crc = chunk_crc(head, payload)
        self._f.write(head + struct.pack("<I", crc) + payload)
        self._f.flush()
        if self.fsync:
            os.fsync(self._f.fileno())
