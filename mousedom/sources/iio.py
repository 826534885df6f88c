"""A gyro over Linux IIO: the yaw rate, stamped on CLOCK_MONOTONIC, from the kernel's buffer.

``open()`` finds the device the config's ``gyro:`` section names, by ``name`` (the device's
``name`` attribute, e.g. ``mpu6050``) or by ``path`` (``/sys/bus/iio/devices/iio:deviceN``,
``/dev/iio:deviceN`` or a udev link to it), then, in sysfs:

1. reads the channel's scale and offset: ``in_anglvel_<axis>_scale`` (rad/s per LSB) else
   the shared ``in_anglvel_scale``; ``in_anglvel_<axis>_offset`` else ``in_anglvel_offset``,
   else 0;
2. opens ``/dev/iio:deviceN`` (non-blocking; the kernel lets one reader at a time, so a
   device in use elsewhere is refused here, before anything is changed), and turns off a
   buffer left enabled by a reader that died;
3. writes ``current_timestamp_clock`` = ``monotonic``, read back: the records' stamps are
   then on the host's CLOCK_MONOTONIC like every other source's.  If it cannot be written
   the source refuses (SourceUnavailable, said in its health): stamps on another clock
   would put the turns at the wrong times;
4. writes ``sampling_frequency`` when the config gives ``sample_hz``;
5. enables the axis' scan element and ``in_timestamp``, disables the others, makes
   ``buffer/length`` at least ``BUFFER_SCANS`` and writes ``buffer/enable`` = 1;
6. reads back which elements are enabled, with their ``_index`` and ``_type``, and decodes
   records by that layout (``mousedom.sources.iio_layout``), never by an assumed one.

Every value it writes is remembered with the value it replaced; ``close()`` disables the
buffer and puts them back, newest first, so the device is left as it was found.

``read(now)`` returns a list of ``GyroSamples``: ``t`` (float64 seconds, CLOCK_MONOTONIC,
from the timestamp channel's nanoseconds) and ``rate`` (float64 rad/s about the body z
axis, counter-clockwise positive) = sign * (raw + offset) * scale.  Stamps far from ``now``
are re-stamped as base.py's ``bound_stamp_array`` does, then made non-decreasing as the
mice's are.  ``saturated`` marks the samples whose raw value is at either end of what the
channel's ``_type`` holds (``ScanType.raw_range``): the converter clipped them, so their
rate says only that the turn was at least that fast.  The polled fallback reads the range
from the same ``_type`` attribute where the device publishes scan elements at all; without
one it cannot tell (``raw_range`` None in SOURCE: docs/gyro.md).

Polled fallback: without a usable buffer (no scan elements or ``buffer/`` directory, no
``in_timestamp`` element, no character device, an empty ``trigger/current_trigger``, or no
``current_timestamp_clock``, which kernels before 4.5 lack while stamping CLOCK_REALTIME)
the source reads ``in_anglvel_<axis>_raw`` once per ``read`` at most ``sample_hz`` times a
second (``POLL_HZ`` unless given), stamped with the middle of the read on the injected
clock.  It has no descriptor (``fileno`` -1, ``paced``): the daemon calls it on its own
schedule.  What it costs: a stamp is late by the sensor's output period plus the bus
transfer (a few ms on I2C, unknown to us), samples come no faster than the daemon's loop,
and the rate between two reads is not seen at all (docs/gyro.md).

Hotplug: a read of a removed device's node gives ENODEV, and a polled attribute that
vanishes reads ENOENT: both raise ``SourceGone``; ``open()`` later finds the device again
by the same rule.  The buffer's poll does not report the removal (since Linux 4.x it
returns no event once the device is unregistered), so the buffered source is read at
every wake of the daemon (``probe``), and one that delivers nothing for ``silent_s``
(SILENT_S, or ten sample periods where ``sample_hz``, or the device's own
``sampling_frequency`` where the config gives none, is slower) is gone too: unplugged,
its driver unbound, or its buffer disabled by another program.  Its windows then take
the mice's heading, not a gyro that saw no turn.  Test hook: the character device may be
a FIFO (the tests' records, packed as the kernel documents); a FIFO whose writer closed is
an unplug.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import select
import stat
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import numpy as np

from mousedom.config import GyroConfig
from mousedom.sources.base import (
    MAX_RATE,
    Reports,
    Source,
    SourceGone,
    SourceUnavailable,
)
from mousedom.sources.iio_layout import (
    Element,
    LayoutError,
    RecordLayout,
    decode_records,
    parse_scan_type,
    record_layout,
)
from mousedom.sources.iio_sysfs import (
    TIMESTAMP,
    UDEV_HINT,
    Attributes,
    IioDevice,
    IioPaths,
    buffer_dir,
    calibration,
    find_device,
    first,
    int_or,
    no_buffer,
    read_text,
    scan_dir,
    write_attr,
)

log = logging.getLogger(__name__)

READ_RECORDS = 1024  # records per os.read: a second of a 1 kHz gyro
MAX_READS = 16  # per read() call, so that one busy source cannot starve the others
BUFFER_SCANS = 256  # buffer/length at least this: ~1 s at 256 Hz before the kernel drops
POLL_HZ = 100.0  # the polled fallback's rate when the config gives no sample_hz
# A buffered gyro that delivers nothing for this long (or ten sample periods, where
# sample_hz is slower) is gone: its poll does not say so (see the module).
SILENT_S = 0.5
CLOCK = "monotonic"  # the name current_timestamp_clock gives CLOCK_MONOTONIC


@dataclass(frozen=True)
class GyroSamples:
    """Yaw-rate samples of one read: what the fusion takes from a gyro.

    ``t``: float64 seconds on the host's CLOCK_MONOTONIC, non-decreasing.  ``rate``: float64
    rad/s about the body z axis (up, REP-103), counter-clockwise positive; the config's
    axis and sign are applied already.
    """

    gyro: str
    t: np.ndarray
    rate: np.ndarray
    # bool per sample: read at the limit of the raw range (the rate is then only a bound);
    # None: none was, or the source cannot tell
    saturated: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)


class GyroMode(Enum):
    BUFFERED = "buffered"  # records from /dev/iio:deviceN, stamped by the kernel
    POLLED = "polled"  # in_anglvel_<axis>_raw read on the daemon's schedule


class GyroSource(Source):
    """The configured gyro's yaw rate, from its IIO buffer (or polled, see the module)."""

    kind = "iio"
    bounds_own_stamps = True

    def __init__(
        self,
        config: GyroConfig,
        paths: IioPaths | None = None,
        *,
        name: str = "gyro",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``clock`` (CLOCK_MONOTONIC seconds) stamps the polled fallback's samples."""
        super().__init__(name)
        self.config = config
        self.paths = paths or IioPaths()
        self.channel = f"in_anglvel_{config.axis}"
        self.clock = clock
        self.device: IioDevice | None = None
        # the device's own sampling_frequency where the config gives no sample_hz: a slow
        # one (below 20 Hz) was declared silent every 0.5 s and reopened in a loop
        self._device_hz: float | None = None
        self.mode: GyroMode | None = None
        self.polled_because: str | None = None
        self.scale = math.nan  # rad/s per LSB
        self.offset = 0.0  # LSB, added before the scale
        self.layout: RecordLayout | None = None
        self.raw_range: tuple[int, int] | None = None  # the raw values' ends: saturation
        self.saturated = 0  # samples read at either end
        self._fd = -1
        self._stream = False  # the node is a FIFO (tests): EOF with POLLHUP is the unplug
        self._rest = b""
        self._gone: str | None = None
        self._heard_at: float | None = None  # when a read last gave records (None: not yet)
        self.sysfs = Attributes(name)  # what open wrote, and what close puts back
        self._due = -np.inf  # the polled fallback's next sample
        self.truncated_bytes = 0

    # ----------------------------------------------------------------- open / close

    def _open(self) -> None:
        self.close()
        self._gone, self._rest, self._due = None, b"", -np.inf
        dev = find_device(self.config, self.paths, self.name)
        self.device = dev
        try:
            self.scale, self.offset = calibration(self.sysfs, dev, self.config.axis)
            why = no_buffer(self.sysfs, dev, self.channel)
            if why is None:
                self._start_buffer(dev)
            else:
                self._start_polling(dev, why)
        except BaseException:
            self.close()
            raise
        self._update_health()
        log.info("%s: attached to %s (%s, %s)", self.name, dev.sysdir, dev.name, self.mode)

    def _set_rate(self, dev: IioDevice) -> None:
        """``sampling_frequency`` = the config's ``sample_hz``, if it gives one; else the
        device's own, read for the silence rule (``silent_s``)."""
        found = first(dev.sysdir, ("sampling_frequency", "in_anglvel_sampling_frequency"))
        if self.config.sample_hz is None:
            self._device_hz = None
            if found is not None:
                try:
                    hz = self.sysfs.number(found)
                except SourceUnavailable:  # ("1000 2000" lists, or unreadable: the default)
                    return
                self._device_hz = hz if hz > 0 else None
            return
        if found is None:
            raise SourceUnavailable(
                f"{self.name}: {dev.sysdir}: no sampling_frequency to write gyro.sample_hz to"
            )
        self.sysfs.set(found, f"{self.config.sample_hz:g}")

    def _start_buffer(self, dev: IioDevice) -> None:
        d = dev.sysdir
        scan, buffer = scan_dir(d, self.channel), buffer_dir(d)
        assert scan is not None and buffer is not None  # no_buffer said so
        self._open_node(dev)
        if self.sysfs.text(buffer / "enable") not in ("", "0"):
            # Nobody has the node open (we do): a stale buffer (a reader that died).  It
            # must be off while the clock and the elements change; not put back on at close.
            write_attr(buffer / "enable", "0", self.name)
        clock = d / "current_timestamp_clock"
        was = self.sysfs.text(clock)
        try:
            self.sysfs.set(clock, CLOCK)
        except SourceUnavailable as e:
            raise SourceUnavailable(
                f"{e}; the records would be stamped on {was or 'an unknown clock'}, not "
                "CLOCK_MONOTONIC: refused"
            ) from None
        if self.sysfs.text(clock) != CLOCK:
            raise SourceUnavailable(
                f"{self.name}: {clock}: reads {self.sysfs.text(clock)!r} after writing {CLOCK!r}"
            )
        self._set_rate(dev)
        for en in sorted(scan.glob("*_en")):
            channel = en.name[: -len("_en")]
            self.sysfs.set(en, "1" if channel in (self.channel, TIMESTAMP) else "0")
        length = buffer / "length"
        if length.exists() and int_or(self.sysfs.text(length), 0) < BUFFER_SCANS:
            self.sysfs.set(length, str(BUFFER_SCANS))
        # A watermark another program left high would hold samples back from the poll
        # until that many had come (the ABI's buffer/watermark): every record is wanted
        # as soon as it is there, for the window it belongs to.
        # (Not needed to read them: the daemon reads a buffered gyro at every wake, and a
        # non-blocking read returns what is there; so a rule that predates it is a warning.)
        watermark = buffer / "watermark"
        if watermark.exists() and int_or(self.sysfs.text(watermark), 1) != 1:
            try:
                self.sysfs.set(watermark, "1")
            except SourceUnavailable as e:
                log.warning("%s (samples may reach the daemon in bursts)", e)
        self.sysfs.set(buffer / "enable", "1")
        self.layout = self._layout(scan)
        self.raw_range = self.layout.field(self.channel).element.type.raw_range
        self.mode, self.polled_because = GyroMode.BUFFERED, None
        self.paced = False
        self.probe = True  # its poll does not report an unplug: read it at every wake
        self._heard_at = None  # silence is counted from the first read on

    def _open_node(self, dev: IioDevice) -> None:
        try:
            fd = os.open(dev.node, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except PermissionError:
            raise SourceUnavailable(
                f"{self.name}: {dev.node}: permission denied: {UDEV_HINT}"
            ) from None
        except OSError as e:
            why = "in use by another reader" if e.errno == errno.EBUSY else e.strerror
            raise SourceUnavailable(f"{self.name}: {dev.node}: {why}") from None
        self._fd = fd
        self._stream = stat.S_ISFIFO(os.fstat(fd).st_mode)

    def _layout(self, scan: Path) -> RecordLayout:
        """The record as the enabled elements say it is (read back, not assumed)."""
        elements = []
        for en in sorted(scan.glob("*_en")):
            if self.sysfs.text(en) != "1":
                continue
            channel = en.name[: -len("_en")]
            index_at, type_at = scan / f"{channel}_index", scan / f"{channel}_type"
            index = int_or(self.sysfs.text(index_at), -1)
            if index < 0:
                raise SourceUnavailable(
                    f"{self.name}: {index_at}: {self.sysfs.text(index_at)!r} is not a scan index"
                )
            try:
                elements.append(
                    Element(channel, index, parse_scan_type(self.sysfs.text(type_at), str(type_at)))
                )
            except LayoutError as e:
                raise SourceUnavailable(f"{self.name}: {e}") from None
        names = {e.name for e in elements}
        for channel in (self.channel, TIMESTAMP):
            if channel not in names:
                raise SourceUnavailable(
                    f"{self.name}: {scan / (channel + '_en')}: still not 1 after writing 1"
                )
        for el in elements:
            # one rate and one 64-bit nanosecond stamp per record, as the kernel publishes
            # them: anything else would decode into columns of another shape or meaning
            if el.name == self.channel and el.type.repeat != 1:
                raise SourceUnavailable(
                    f"{self.name}: {scan / (el.name + '_type')}: repeats {el.type.repeat} "
                    "values a record; a rate channel holds one"
                )
            if el.name == TIMESTAMP and (el.type.repeat != 1 or el.type.realbits != 64):
                raise SourceUnavailable(
                    f"{self.name}: {scan / (el.name + '_type')}: not one 64-bit timestamp "
                    "a record (the kernel's is s64 nanoseconds)"
                )
        try:
            return record_layout(elements)
        except LayoutError as e:
            raise SourceUnavailable(f"{self.name}: {scan}: {e}") from None

    def _start_polling(self, dev: IioDevice, why: str) -> None:
        raw = dev.sysdir / f"{self.channel}_raw"
        if not raw.exists():
            raise SourceUnavailable(
                f"{self.name}: {raw}: missing, and no buffer to read instead ({why})"
            )
        self.sysfs.text(raw)  # readable now, or refused now
        self.raw_range = self._polled_range(dev)
        self._set_rate(dev)
        self.mode, self.polled_because = GyroMode.POLLED, why
        self.paced = True  # no descriptor: read on the daemon's schedule
        self.probe = False
        log.warning("%s: polling %s: %s (docs/gyro.md)", self.name, raw, why)

    def _polled_range(self, dev: IioDevice) -> tuple[int, int] | None:
        """The raw range as the channel's scan type gives it, where the device publishes
        one without a usable buffer (no trigger, say); None where it does not."""
        scan = scan_dir(dev.sysdir, self.channel)
        if scan is None:
            return None
        at = scan / f"{self.channel}_type"
        try:
            return parse_scan_type(self.sysfs.text(at), str(at)).raw_range
        except LayoutError as e:
            log.warning("%s: %s: saturation is not detected", self.name, e)
            return None

    def fileno(self) -> int:
        return self._fd

    def identity(self) -> str | None:
        if self.device is None or self.mode is None:
            return None
        return os.path.realpath(self.device.sysdir)

    def close(self) -> None:
        if self._fd >= 0:
            try:
                os.close(self._fd)
            except OSError:
                pass
            self._fd = -1
        self.sysfs.restore()
        self.mode, self.layout, self.raw_range = None, None, None

    # ----------------------------------------------------------------- data plane

    def read(self, now: float) -> list[GyroSamples]:  # type: ignore[override]
        """The samples that are ready (see the module); SourceGone when the device went.

        A gyro gives ``GyroSamples``, not the mice's ``Reports``: the health bookkeeping
        of ``Source.read`` is done here for them."""
        try:
            batch = self._poll(now) if self.mode is GyroMode.POLLED else self._drain(now)
        except SourceGone as e:
            self.health.connected = False
            self.health.error = str(e)
            self.close()
            raise
        if batch is None or not len(batch):
            return []
        self._count(len(batch), float(batch.t[-1]), now)
        return [batch]

    def _read(self, now: float) -> list[Reports]:
        raise TypeError(f"{self.name}: a gyro gives GyroSamples: call read()")

    def _drain(self, now: float) -> GyroSamples | None:
        if self._gone is not None:
            raise SourceGone(self._gone)
        if self._fd < 0 or self.layout is None:
            raise SourceGone(f"{self.name}: not open")
        data, gone = self._read_bytes(self.layout.size * READ_RECORDS)
        if data is None:
            return None
        decoded = decode_records(data, self.layout)
        self._rest = decoded.rest
        if gone is not None:
            self.truncated_bytes += len(self._rest)  # a record cut by the unplug
            self._rest = b""
        self._gone = gone  # raised by the next call, after these samples are handed over
        if not decoded.records:
            self._update_health()
            if gone is not None:
                raise SourceGone(gone)
            self._check_silence(now)
            return None
        self._heard_at = now
        raw = decoded.columns[self.channel]
        stamps = decoded.columns[TIMESTAMP].astype(np.float64) / 1e9
        rate = self.config.sign * (raw.astype(np.float64) + self.offset) * self.scale
        return self._stamped(stamps, rate, now, self._at_limit(raw))

    @property
    def silent_s(self) -> float:
        """How long the buffer may deliver nothing before the device is taken to be gone."""
        hz = self.config.sample_hz or self._device_hz
        return max(SILENT_S, 10.0 / hz) if hz else SILENT_S

    def _check_silence(self, now: float) -> None:
        """SourceGone where the buffer has delivered nothing for ``silent_s``: its poll
        does not report an unplug (see the module), and a gyro that is live but silent
        would be fused as one that saw no turn."""
        if self._heard_at is None:
            self._heard_at = now
            return
        if now - self._heard_at <= self.silent_s:
            return
        node = self.device.node if self.device else "device"
        if self.device is not None and not self.device.sysdir.exists():
            why = f"device gone ({self.device.sysdir} went)"
        else:
            why = (f"no sample for {self.silent_s:g} s (unplugged, its driver unbound, or "
                   "its buffer disabled by another program?)")  # fmt: skip
        raise SourceGone(f"{self.name}: {node}: {why}")

    def _read_bytes(self, chunk: int) -> tuple[bytes | None, str | None]:
        """What the node holds (with the last read's partial record in front), and why
        it is gone, if it is; (None, None): nothing yet."""
        chunks = [self._rest] if self._rest else []
        gone = None
        for _ in range(MAX_READS):
            try:
                data = os.read(self._fd, chunk)
            except BlockingIOError:
                break
            except OSError as e:
                node = self.device.node if self.device else "device"
                gone = f"{self.name}: {node}: device gone ({e.strerror or e})"
                break
            if not data:
                if self._stream and not chunks and not _hung_up(self._fd):
                    return None, None  # a FIFO with no writer yet: not an unplug
                node = self.device.node if self.device else "device"
                gone = f"{self.name}: {node}: device gone (end of stream)"
                break
            chunks.append(data)
            if len(data) < chunk:
                break
        return b"".join(chunks), gone

    def _poll(self, now: float) -> GyroSamples | None:
        if now < self._due or self.device is None:
            return None
        period = 1.0 / (self.config.sample_hz or POLL_HZ)
        # On a grid of periods while the daemon keeps up; from now when it fell behind.
        self._due = self._due + period if now - self._due < period else now + period
        raw_at = self.device.sysdir / f"{self.channel}_raw"
        t0 = self.clock()
        try:
            text = read_text(raw_at)
        except OSError as e:
            if e.errno in (errno.ENOENT, errno.ENODEV):
                raise SourceGone(f"{self.name}: {raw_at}: device gone ({e.strerror})") from None
            self._dropped(f"{raw_at}: {e.strerror or e}")
            return None
        t1 = self.clock()
        try:
            raw = int(text)
        except ValueError:
            self._dropped(f"{raw_at}: {text[:40]!r} is not an integer")
            return None
        if abs(raw) >= 1 << 64:  # no converter gives it (and a float would overflow)
            self._dropped(f"{raw_at}: {text[:40]!r} is no reading of a converter")
            return None
        rate = self.config.sign * (raw + self.offset) * self.scale
        return self._stamped(np.array([(t0 + t1) / 2]), np.array([rate], dtype=np.float64), now,
                             self._at_limit(np.array([raw])))  # fmt: skip

    def _at_limit(self, raw: np.ndarray) -> np.ndarray | None:
        """Which raw values are at either end of the range (None: none, or no range)."""
        if self.raw_range is None:
            return None
        lo, hi = self.raw_range
        at = (raw <= lo) | (raw >= hi)
        return at if at.any() else None

    def _dropped(self, why: str) -> None:
        """A sample that could not be read (an I2C error): counted, said, not fatal."""
        self.health.dropped += 1
        self.health.error = f"{self.name}: {why} ({self.health.dropped} sample(s) lost)"

    def _stamped(
        self, stamps: np.ndarray, rate: np.ndarray, now: float, saturated: np.ndarray | None
    ) -> GyroSamples | None:
        bad = ~(np.abs(rate) < MAX_RATE)
        if bad.any():  # no gyro reads this: the scale or offset attribute is not its own
            k = int(np.argmax(bad))
            self._dropped(f"a rate of {float(rate[k])!r} rad/s (raw times scale {self.scale!r}"
                          f" plus offset): not a gyro's")  # fmt: skip
            self.health.dropped += int(bad.sum()) - 1
            keep = ~bad
            stamps, rate = stamps[keep], rate[keep]
            saturated = None if saturated is None else saturated[keep]
            if not len(stamps):
                self._update_health()
                return None
        if saturated is not None:  # (counted as handed over)
            self.saturated += int(saturated.sum())
        t = self._forward(stamps, now)
        self._update_health()
        return GyroSamples(self.name, t, rate, saturated)

    def _update_health(self) -> None:
        dev = self.device
        self.health.extra.update(
            node=str(dev.node) if dev and self.mode is GyroMode.BUFFERED else None,
            device=dev.name if dev else None,
            sysfs=str(dev.sysdir) if dev else None,
            mode=self.mode.value if self.mode else None,
            polled_because=self.polled_because,
            clock="monotonic" if self.mode is GyroMode.BUFFERED else "read time (polled)",
            axis=self.config.axis,
            sign=self.config.sign,
            scale=self.scale,
            offset=self.offset,
            record_bytes=self.layout.size if self.layout else None,
            raw_range=list(self.raw_range) if self.raw_range else None,
            saturated=self.saturated,
            time_backwards=self.time_backwards,
            truncated_bytes=self.truncated_bytes,
        )


def _hung_up(fd: int) -> bool:
    """A FIFO reads EOF before a writer came, too; only POLLHUP (one came and went) is an
    unplug (the evdev source tells them apart the same way)."""
    p = select.poll()
    p.register(fd, select.POLLIN)
    return bool(p.poll(0))
